"""Time integration of the rigid bodies that have a mass: the step being solved and its state.

:class:`StepState` holds what a dynamic step of a :class:`RigidSystem` starts from (the
bodies' motions, velocities and loads at t_n); the driver arms it, the reduced residual reads it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from shoulder_fem.engine.rigid_system.bodies import RigidBody
from shoulder_fem.engine.rigid_system.terms import inertia_terms
from shoulder_fem.engine.so3 import exp_so3

__all__ = ["StepState"]


@dataclass
class StepState:
    """The dynamic step of a system: its size, and the state and loads it starts from.

    A body given a mass m and a body-frame inertia I_G about its centre of mass G
    (:meth:`RigidBody.set_mass_properties`, e.g. from :func:`mass_properties`) is integrated in
    time; the deformable body stays quasi-static (its residual carries no inertia), massless
    bodies stay quasi-static too, and prescribed bodies follow their prescription. The scheme is
    the Simo–Wong energy–momentum algorithm of :class:`~shoulder_fem.engine.rigid.NewtonEuler`
    with the loads averaged over the step (trapezoidal rule) instead of sampled at the mid-step
    state, so that the quasi-static FE equilibrium and the tie forces are those of the end of
    the step. From state n (centre x_n, velocity v_n, rotation R_n, body angular velocity Ω_n,
    spatial angular momentum L_n = R_n I_G Ω_n, loads F_n and M_n about G) to n+1, with
    R_{n+1} = R_n exp(hat θ) (θ = R_nᵀ φ: body increment; the reduced DOFs are unchanged)::

        m (v_{n+1} - v_n) = h (F_n + F_{n+1}) / 2,      x_{n+1} = x_n + h (v_n + v_{n+1}) / 2,
        L_{n+1} - L_n     = h (M_n + M_{n+1}) / 2,      θ = h (Ω_n + Ω_{n+1}) / 2.

    Eliminating v_{n+1} and Ω_{n+1}, the body's residual rows (2/h times the momentum
    balances) are

        f_I = (4m/h²)(x_{n+1} - x_n - h v_n) - F_n,
        m_I = (2/h)(R_{n+1} I_G (2θ/h - Ω_n) - L_n) - M_n,

    added to the static rows as ``(f_I, m_I + ρ × f_I)`` (ρ = x_G - x_ref: the moment rows are
    about the reference point), whose static part is ``-(F_{n+1}, M_{n+1} + ρ × F_{n+1})``.
    Their exact derivatives with respect to (t, φ) enter the same reduced Jacobian
    (:func:`shoulder_fem.engine.rigid_system.terms.inertia_terms`). Properties (tested): second
    order; a constant moment about a principal axis gives θ = M t²/(2I) to round-off;
    torque-free, L and the kinetic energy are conserved to the solver tolerance (θ is an
    eigenvector of exp(-hat θ), as in Simo–Wong); a linear spring oscillator conserves its
    energy and has the trapezoidal rule's period error (ωh)²/12.

    Attributes:
        dynamic: The system integrates bodies in time (``RigidSystem(dynamic=True)``).
        dt: Step size (s) while a dynamic step is being solved, else ``None``.
        start: Per body ``(x_G, v, R, Ω, L)`` at the step's start.
        loads: Per body F (N) and M about G (N·m) at t_n, (nb, 2, 3); ``None`` before
            the integration starts.
        last_inertia: Per body ``(f_I, m_I + ρ × f_I)`` of the last step, (nb, 6), or ``None``.
    """

    dynamic: bool = False
    dt: float | None = None
    start: list | None = None
    loads: np.ndarray | None = None
    last_inertia: np.ndarray | None = None

    def inertial(self, bodies: Sequence[RigidBody]) -> list[int]:
        """Indices of the bodies integrated in time (with a mass, not prescribed; dynamic)."""
        if not self.dynamic:
            return []
        return [i for i, b in enumerate(bodies) if b.mass is not None and not b.prescribed]

    def begin(self, bodies: Sequence[RigidBody], h: float) -> None:
        """Record the bodies' state as the start of a step of ``h`` (s)."""
        self.start = []
        for body in bodies:
            R = body.rotation.copy()
            L = R @ (body.inertia @ body.omega) if body.mass is not None else np.zeros(3)
            self.start.append(
                (body.centre_position(), body.velocity.copy(), R, body.omega.copy(), L)
            )
        self.dt = h

    def predictor(self, b: int, body: RigidBody) -> tuple[np.ndarray, np.ndarray]:
        """Body b's start of the Newton iteration: θ = h Ω_n, x_G = x_n + h v_n + h² F_n/(2m).

        Returns its translation t (m) and rotation increment φ (rad).
        """
        h = self.dt
        xg, v, R, w, _ = self.start[b]
        phi = R @ (h * w)
        R1 = exp_so3(phi) @ R
        xg1 = xg + h * v + 0.5 * h * h * self.loads[b, 0] / body.mass
        t = xg1 - body.reference_point - R1 @ (body.centre - body.reference_point)
        return t, phi

    def rows(self, b: int, body: RigidBody, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Body b's inertia rows and their derivative at rotation increment ``phi`` (rad)."""
        return inertia_terms(body, self.dt, self.start[b], self.loads[b], phi)

    def inertia_rows(self, bodies: Sequence[RigidBody], phi: np.ndarray) -> np.ndarray:
        """Every body's inertia rows (zero for a body not integrated), (nb, 6)."""
        inertia = np.zeros((len(bodies), 6))
        for b in self.inertial(bodies):
            inertia[b] = self.rows(b, bodies[b], phi[b])[0]
        return inertia

    def set_velocities(self, bodies: Sequence[RigidBody], phi: np.ndarray, h: float) -> None:
        """The trapezoidal-rule velocities of the step's end from its motion (``phi``, rad)."""
        for b, body in enumerate(bodies):
            xg_n, v_n, R_n, w_n, _ = self.start[b]
            theta = R_n.T @ phi[b]
            body.velocity = (2.0 / h) * (body.centre_position() - xg_n) - v_n
            body.omega = (2.0 / h) * theta - w_n

    def snapshot(self, bodies: Sequence[RigidBody], time: float) -> tuple:
        """The dynamic state (velocities, loads, inertia rows, ``time`` s) for :meth:`restore`."""
        return (
            [(b.velocity.copy(), b.omega.copy()) for b in bodies],
            None if self.loads is None else self.loads.copy(),
            None if self.last_inertia is None else self.last_inertia.copy(),
            time,
        )

    def restore(self, bodies: Sequence[RigidBody], snapshot: tuple) -> float:
        """Put back a :meth:`snapshot`; return its time (s)."""
        velocities, loads, inertia, time = snapshot
        for body, (v, w) in zip(bodies, velocities, strict=True):
            body.velocity, body.omega = v.copy(), w.copy()
        self.loads = None if loads is None else loads.copy()
        self.last_inertia = None if inertia is None else inertia.copy()
        return time
