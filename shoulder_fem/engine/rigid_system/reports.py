"""What a :class:`~.system.RigidSystem` reports about its current state.

Forces and moments on each body, the springs' lengths and tensions, energies, reactions on fixed
surfaces and the tied nodes' positions: read-only measures of the state that the solves left,
mixed into :class:`~.system.RigidSystem` (which owns the problem, the FE part and the step state
they read).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from petsc4py import PETSc

from shoulder_fem.engine.rigid_system.bodies import BodyBalance
from shoulder_fem.engine.rigid_system.terms import spring_load_on
from shoulder_fem.engine.springs import spring_response

__all__ = ["SystemReports"]


class SystemReports:
    """The report methods of :class:`~.system.RigidSystem` (a mixin; all collective)."""

    @property
    def volumetric(self):
        """The deformable part's condensed volumetric terms, or ``None``."""
        return self._fe.volumetric if self._fe is not None else None

    def balance(self, name: str) -> BodyBalance:
        """Forces and moments on body ``name`` at the current state (collective).

        Tie forces are those the deformable body exerts on the rigid body (minus the FE
        residual at its tied nodes); moments are about the body's current reference point.
        A prescribed body also receives the (unreported) reaction of its prescription.
        """
        problem, b = self._problem, self._index[name]
        body = problem.bodies[b]
        if problem.fe is not None:
            problem.fe.assemble_residual()
        tie_f, tie_m, _ = problem.tie_loads()
        states = problem.end_states()
        spring_f, spring_m = spring_load_on(b, problem.springs, problem.ends, states)
        last = self._step.last_inertia
        inertia = np.zeros(6) if last is None else -last[b]
        return BodyBalance(
            -tie_f[b],
            -tie_m[b],
            spring_f,
            spring_m,
            body.force.copy(),
            body.moment.copy(),
            inertia[:3].copy(),
            inertia[3:].copy(),
        )

    def energy(self) -> dict[str, float]:
        """Kinetic energy of the bodies with a mass and elastic energy of the springs (J)."""
        kinetic = sum(b.kinetic_energy() for b in self.bodies if b.mass is not None)
        springs = 0.0
        for spring, out in zip(self.springs, self.spring_forces().values(), strict=True):
            if out["tension"] != 0.0 or not spring.tension_only:
                springs += 0.5 * spring.stiffness * (out["length"] - spring.rest_length) ** 2
        return {"kinetic": float(kinetic), "springs": float(springs)}

    def spring_forces(self) -> dict[str, dict[str, float]]:
        """Per spring: length (m), tension (N, positive when stretched) (collective)."""
        states = self._problem.end_states()
        out = {}
        for j, spring in enumerate(self._problem.springs):
            resp = spring_response(spring, states[2 * j][0], states[2 * j + 1][0])
            out[spring.name] = {"length": resp.length, "tension": resp.tension}
        return out

    def assembled_residual(self) -> PETSc.Vec:
        """The FE residual (N) at the current state, without conditions (collective; read only)."""
        self._fe.assemble_residual()
        return self._fe.F

    def reaction(
        self, surface: str | Sequence[str], point: np.ndarray | None = None
    ) -> tuple[np.ndarray, ...]:
        """Force (N) and moment about ``point`` (m, default origin, N·m) on fixed ``surface``.

        ``surface``: a name, or several (a node they share counted once).
        """
        return self._fe.reaction(surface, point)

    def tied_positions(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """Reference and current positions (m) of the nodes tied to ``name``, on every rank."""
        return self._fe.tied_positions(self._index[name])
