"""The humerus's floating-frame deformation, for the compliant decoupling (:mod:`.correction`).

Part 1 takes the humerus as rigid. The coupled humerus is not: the glenohumeral pressure and
the muscles' pull deform its head and shaft, and the joint's contact (its peak pressure above
all) sees that. The compliant decoupling gives part 1 the humerus's elastic displacement as it
gives it the scapula's: the humerus alone, linear elastic in its floating frame (paper eq. 13,
as :mod:`.part2` does for the scapula), loaded by part 1's forces on it at each output angle.

Its frame. The humerus hangs on its distal springs, which act on a rigid plate tied to its
distal section (the coupled method's; :func:`interactions.spring_plates`). This problem's
frame is that plate's: the section is fixed (u = 0 there) and its reaction is the springs'
force, which part 1 balanced against the soft tissues' (the check
:attr:`HumerusDeformation.worst`). The coupled method measures the humerus's rotation as the
best rigid fit of its nodes' motion (:func:`geometry.best_fit_rotation`); so that part 1's
rigid humerus is turned as that fit is, the displacement handed to part 1 is taken in the
frame of the best fit of the humerus's nodes. A rigid part of the offsets would only re-place
the humerus, which part 1's re-solve undoes; the fit keeps the humeral angle the coupled one.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from shoulder_fem.engine.rigid_system import RigidSystem
from shoulder_fem.engine.springs import spring_response
from shoulder_fem.families.base import RunContext
from shoulder_fem.families.shoulder.correction import NodalValues, Offsets
from shoulder_fem.families.shoulder.geometry import best_rigid_fit, marker_names
from shoulder_fem.families.shoulder.interactions import DISTAL_SECTION, surfaces
from shoulder_fem.families.shoulder.model import ShoulderModel
from shoulder_fem.families.shoulder.part2 import (
    FloatingBone,
    NodalLoads,
    SurfaceForces,
    solver_options,
)
from shoulder_fem.meshes import shoulder as S

__all__ = ["HumerusDeformation", "HumerusLoads", "HumerusRecorder", "humerus_offsets"]


@dataclass
class HumerusLoads:
    """Part 1's loads on the humerus and its rigid motion at each output angle.

    Attributes:
        points: The loaded nodes (m, reference geometry), gathered on every rank.
        forces: Per output, the nodal forces (N, (n, 3), world frame) at ``points``.
        translation: Per output, the humerus's translation (m) (of its reference point, the
            origin).
        rotation: Per output, its rotation (3 x 3).
        angles: The output angles (rad).
    """

    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    forces: list = field(default_factory=list)
    translation: list = field(default_factory=list)
    rotation: list = field(default_factory=list)
    angles: list = field(default_factory=list)


class HumerusRecorder:
    """Records part 1's loads on the humerus into :class:`HumerusLoads` at each output."""

    def __init__(self, V, ft, humerus, tied: tuple, params):
        """``tied``: the surfaces tied to the humerus, which its soft tissues load."""
        self.humerus = humerus
        tags = [S.MARKERS[n].id for n in tied]
        if params.humeral_head_contact:  # the muscles' pressure on the head
            tags.append(S.HUMERUS_HEAD_SURFACE.id)
        self.forces = SurfaceForces(V, ft, tags)
        self.loads = HumerusLoads(points=self.forces.points)

    def __call__(self, target: float, residual) -> None:
        """Record at output angle ``target`` (rad) from part 1's FE ``residual`` (collective)."""
        loads = self.loads
        loads.forces.append(self.forces(residual))
        loads.translation.append(self.humerus.translation.copy())
        loads.rotation.append(self.humerus.rotation.copy())
        loads.angles.append(target)


class HumerusDeformation(FloatingBone):
    """The humerus alone, linear elastic in its floating frame, at part 1's outputs (collective).

    Args:
        model: The decoupled model (its ``humerus`` mesh).
        run: The run's context (its PETSc options).
        loads: Part 1's loads on the humerus (:class:`HumerusRecorder`).
        springs: Part 1's springs on the humerus (their forces at the recorded poses are the
            check of the fixed section's reaction; their points lie on that section).
    """

    def __init__(
        self,
        model: ShoulderModel,
        run: RunContext,
        loads: HumerusLoads,
        springs: list,
    ):
        p = model.params
        ref = np.zeros(3)  # part 1's humerus turns about the origin, the articular centre
        super().__init__(
            model, "humerus", ref, loads.angles, loads.translation, loads.rotation,
            name="humerus_displacement",
        )  # fmt: skip
        V = self.V
        self.loads_in, self.springs = loads, springs
        self.nodal = NodalLoads(V, loads.points, "compliant decoupling: the humerus's loads")
        self.section = section = marker_names(DISTAL_SECTION)
        options, iterative = solver_options(p, run)
        self.system = RigidSystem(
            [],
            u=self.u,
            residual=self.residual,
            surfaces=surfaces(self.ft, section),
            fixed=section,
            name="shoulder_humerus",
            options=options,
            form_compiler_params=p.quadrature(),
            contact=self.nodal,
            linear_ties=True,
            near_nullspace=iterative,
        )
        n_owned = V.dofmap.index_map.size_local
        self._X = V.tabulate_dof_coordinates()[:n_owned]
        #: The largest mismatch of the fixed section's reaction and part 1's spring forces
        #: over the outputs solved, relative to the loads' magnitude (sum of |f|), or in N where
        #: that is below 1 N (the open unloaded joint's loads are about 1e-3 N: their round-off
        #: relative to them read 1.1e-6 at 0 deg, against 1e-7 on loaded joints).
        self.worst = 0.0
        self.iterations = 0

    def solve(self, k: int) -> None:
        """The humerus's displacement at output ``k`` (floating frame of its distal section)."""
        f = np.asarray(self.loads_in.forces[k])
        self.nodal.forces[:] = f @ self.R[k]  # R^T f per row
        self.frame_motion(k)
        self.inertia.relieve()
        angle = np.degrees(self.loads_in.angles[k])
        self.iterations += self.system.solve(step=f"humerus {angle:.0f} deg")
        self.u_prev.x.array[:] = self.u.x.array
        self._check(k, f)

    def _check(self, k: int, f: np.ndarray) -> None:
        """The section's reaction against the springs' forces at the recorded pose."""
        Rk, tk = self.R[k], self.T[k]
        force, moment = self.system.reaction(self.section)
        spring_f, spring_m = np.zeros(3), np.zeros(3)
        for sp in self.springs:  # the springs' forces on the humerus, floating frame
            P = np.asarray(sp.point_a)
            g = spring_response(sp, tk + Rk @ P, np.asarray(sp.point_b)).gradient
            spring_f, spring_m = spring_f - Rk.T @ g, spring_m + np.cross(P, -Rk.T @ g)
        scale = max(float(np.abs(f).sum()), 1.0)
        lever = float(np.linalg.norm(self.loads_in.points, axis=1).max())
        mismatch = max(
            float(np.linalg.norm(force - spring_f)) / scale,
            float(np.linalg.norm(moment - spring_m)) / (scale * lever),
        )
        self.worst = max(self.worst, mismatch)

    def offsets(self, X: np.ndarray, uX: np.ndarray) -> tuple[np.ndarray, dict]:
        """The displacement in the frame of the best rigid fit of the humerus's nodes.

        Args:
            X: Points part 1 needs (m, (n, 3), reference positions).
            uX: The displacement there (m, (n, 3); :class:`.correction.NodalValues`).

        Returns:
            (the offsets at ``X`` (m, (n, 3)), {spring name: the offset at its point}).
        """
        x = self._X + self.u.x.array.reshape(-1, 3)[: len(self._X)]
        C, c, Rf = best_rigid_fit(self._X, x, self.comm)

        def framed(Y: np.ndarray, uY: np.ndarray) -> np.ndarray:
            return (Y + uY - c) @ Rf - (Y - C)  # R^T (y - c) + C - Y per row

        springs = {}
        for sp in self.springs:  # on the fixed section: u = 0 there
            P = np.asarray(sp.point_a, dtype=float)[None]
            springs[sp.name] = framed(P, np.zeros_like(P))[0]
        return framed(X, uX), springs

    def destroy(self) -> None:
        """Free the solver."""
        self.system.destroy()


def humerus_offsets(model: ShoulderModel, run: RunContext, part1, X: np.ndarray) -> list[Offsets]:
    """The humerus's displacement where part 1 needs it, at each output angle (collective).

    Args:
        model: The decoupled model (its ``humerus`` mesh).
        run: The run's context: its recorder gets the probes ``humerus_iterations`` (chord
            iterations), ``humerus_section_balance`` (:attr:`HumerusDeformation.worst`) and
            the solver counters.
        part1: The rigid part 1 after its run (with ``keep``: its humerus loads).
        X: Part 1's nodes tied to the humerus (m; gathered).

    Returns:
        Per output angle, the offsets of those nodes and of the humerus's springs.
    """
    rec = run.recorder
    springs = [sp for sp in part1.springs if sp.body_a == "humerus"]
    hum = HumerusDeformation(model, run, part1.humerus.loads, springs)
    try:
        probe = NodalValues(hum.V, X, "part 1's humerus nodes")
        out = []
        for k in range(len(part1.humerus.loads.angles)):
            hum.solve(k)
            nodes, at_springs = hum.offsets(X, probe(hum.u))
            out.append(Offsets(nodes, at_springs))
        rec.set_probe("humerus_iterations", hum.iterations, "1")
        rec.set_probe("humerus_section_balance", hum.worst, "1")
        rec.add_solver_counts(hum.system.stats)
        rec.extra("dofs_humerus", hum.V.dofmap.index_map.size_global * 3)
    finally:
        hum.destroy()
    return out
