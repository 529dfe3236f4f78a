"""Rigid-body dynamics: the state, the Newton–Euler integrator, a prescribed spin-up.

The rigid part of the paper's eq. (10), ``m a_G = F``, ``I_G dΩ/dt + Ω × I_G Ω = M_G``, with the
body-frame angular velocity Ω (rad/s) and the body-frame inertia about the centre of mass I_G
(kg m²). Pure numpy: nothing here knows about meshes or dolfinx. The SO(3) maps and the frame
conventions are in :mod:`shoulder_fem.engine.so3`.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from shoulder_fem.engine.so3 import (
    EPS,
    I3,
    FloatArray,
    as_matrix3,
    as_vector3,
    exp_so3_unchecked,
    hat_unchecked,
    is_rotation,
    norm3,
    project_to_so3,
    right_jacobian_unchecked,
    rotation_about,
)

logger = logging.getLogger(__name__)

LoadFunction = Callable[[float, "RigidState"], ArrayLike | None]

__all__ = ["LoadFunction", "NewtonEuler", "RigidState", "SpinUp"]


# --------------------------------------------------------------------------------------------
# State
# --------------------------------------------------------------------------------------------


def _as_inertia(inertia_body: ArrayLike) -> FloatArray:
    """Return the body inertia as a (3, 3) array; a (3,) input is taken as principal moments."""
    a = np.asarray(inertia_body, dtype=float)
    return np.diag(a) if a.shape == (3,) else a


@dataclass(eq=False)
class RigidState:
    """Kinematic state of a rigid body at time ``t``.

    Attributes:
        t: Time (s).
        x_g: Position of the centre of mass G in the inertial frame (m), shape (3,).
        v_g: Velocity of G in the inertial frame (m/s), shape (3,).
        R: Rotation body → inertial (dimensionless), shape (3, 3): ``x = x_g + R X_body``.
        omega: **Body-frame** angular velocity (rad/s), shape (3,): ``Ṙ = R hat(omega)``.
    """

    t: float = 0.0
    x_g: FloatArray = field(default_factory=lambda: np.zeros(3))
    v_g: FloatArray = field(default_factory=lambda: np.zeros(3))
    R: FloatArray = field(default_factory=lambda: np.eye(3))
    omega: FloatArray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        self.t = float(self.t)
        if not math.isfinite(self.t):
            raise ValueError(f"t must be finite, got {self.t}")
        self.x_g = as_vector3(self.x_g, "x_g").copy()
        self.v_g = as_vector3(self.v_g, "v_g").copy()
        self.R = as_matrix3(self.R, "R").copy()
        self.omega = as_vector3(self.omega, "omega").copy()
        if not is_rotation(self.R, tol=1e-8):
            raise ValueError("R must be a rotation matrix (orthogonal, det 1) to 1e-8")

    @property
    def omega_spatial(self) -> FloatArray:
        """Angular velocity in the inertial frame, ``R omega`` (rad/s), shape (3,)."""
        return self.R @ self.omega

    def angular_momentum(self, inertia_body: ArrayLike) -> FloatArray:
        """Spatial angular momentum about G, ``L = R I_G omega`` (kg m²/s), shape (3,).

        Args:
            inertia_body: Body-frame inertia about G (kg m²), (3, 3) or (3,) principal moments.
        """
        return self.R @ (_as_inertia(inertia_body) @ self.omega)

    def kinetic_energy(self, mass: float, inertia_body: ArrayLike) -> float:
        """Kinetic energy ``m |v_g|²/2 + omega · I_G omega / 2`` (J).

        Args:
            mass: Mass (kg).
            inertia_body: Body-frame inertia about G (kg m²), (3, 3) or (3,) principal moments.
        """
        rot = float(self.omega @ (_as_inertia(inertia_body) @ self.omega))
        return 0.5 * float(mass) * float(self.v_g @ self.v_g) + 0.5 * rot

    def point_position(self, r_body: ArrayLike) -> FloatArray:
        """Inertial position (m) of the body point at body-frame offset ``r_body`` (m) from G."""
        return self.x_g + self.R @ as_vector3(r_body, "r_body")

    def point_velocity(self, r_body: ArrayLike) -> FloatArray:
        """Inertial velocity (m/s) of the body point at body-frame offset ``r_body`` (m) from G."""
        return self.v_g + self.R @ np.cross(self.omega, as_vector3(r_body, "r_body"))

    def copy(self) -> RigidState:
        """Independent copy (arrays copied)."""
        return RigidState._trusted(
            self.t, self.x_g.copy(), self.v_g.copy(), self.R.copy(), self.omega.copy()
        )

    @classmethod
    def _trusted(
        cls, t: float, x_g: FloatArray, v_g: FloatArray, R: FloatArray, omega: FloatArray
    ) -> RigidState:
        """Build a state from arrays known to be valid, skipping the checks (inner loops)."""
        state = cls.__new__(cls)
        state.t, state.x_g, state.v_g, state.R, state.omega = float(t), x_g, v_g, R, omega
        return state


# --------------------------------------------------------------------------------------------
# Newton–Euler integrator
# --------------------------------------------------------------------------------------------


class NewtonEuler:
    """Energy–momentum integrator for the rigid-body equations (10) of the paper.

    **Scheme.** One step from ``t_n`` to ``t_{n+1} = t_n + h`` with body rotation increment θ
    (rad, body frame) is the Simo–Wong energy–momentum algorithm (J.C. Simo, K.K. Wong, IJNME 31,
    1991) with loads sampled at the mid-step state::

        R_{n+1}  = R_n exp(hat(θ)),               θ = h (Ω_n + Ω_{n+1}) / 2
        L_{n+1}  = L_n + h M̄,                     L = R I_G Ω   (spatial angular momentum)
        x_{n+1}  = x_n + h (v_n + v_{n+1}) / 2
        m v_{n+1} = m v_n + h F̄

    with ``F̄ = force(t_{n+½}, s_{n+½})`` and ``M̄ = moment(t_{n+½}, s_{n+½})`` evaluated at the
    mid-step state ``x = (x_n + x_{n+1})/2``, ``v = (v_n + v_{n+1})/2``, ``R = R_n exp(hat(θ/2))``,
    ``Ω = θ/h``. In body components the rotational equation is::

        I_G Ω_{n+1} = exp(-hat(θ)) (I_G Ω_n + h R_nᵀ M̄),   Ω_{n+1} = 2θ/h - Ω_n,

    three nonlinear equations for θ, solved by Newton's method with the exact Jacobian
    ``(2/h) I_G - exp(-hat θ) hat(a) J_r(-θ)``, ``a = I_G Ω_n + h R_nᵀ M̄``; state-dependent
    loads are re-evaluated at every iterate (a Newton/fixed-point hybrid: it contracts when
    ``h`` is small against the load's time scales, e.g. ``h² k/m ≪ 1`` for a spring of stiffness
    k; stiffer loads need a smaller step or raise the convergence error).

    **Why this scheme.** It is second order, symmetric (time-reversible), and exactly
    conservative, which an explicit scheme or a plain Lie-group midpoint scheme is not; exact
    energy conservation also makes it nonlinearly stable (bounded) for torque-free motion at any
    step for which the per-step solve converges:

    * spatial angular momentum: ``L_{n+1} - L_n = h M̄`` exactly, because
      ``R_{n+1} exp(-hat θ) = R_n``; torque-free, the vector L (hence |L|) is conserved to
      round-off;
    * |Π| = |I_G Ω| (a Casimir) is conserved torque-free to round-off (Π is rotated);
    * energy: θ is an eigenvector of ``exp(-hat θ)``, so ``θ · (Π_{n+1} - exp(-hat θ) Π_n) =
      h θ·R_nᵀ M̄`` gives the exact discrete work balance
      ``E_{n+1} - E_n = h (F̄ · v_{n+½} + M̄ · ω_{n+½})`` with ``ω_{n+½} = R_n θ / h`` the spatial
      mid-step angular velocity. Torque- and force-free, E is conserved to the nonlinear-solve
      tolerance;
    * translation (implicit midpoint = trapezoid): exact for a constant force.

    Args:
        mass: Mass m (kg), finite and > 0.
        inertia_body: Inertia tensor about G in the body frame I_G (kg m²): symmetric
            positive-definite (3, 3), or (3,) principal moments.
        rtol: Relative tolerance of the per-step nonlinear solve (on the Newton increment).
        max_iterations: Iteration cap of the per-step solve.
    """

    def __init__(
        self,
        mass: float,
        inertia_body: ArrayLike,
        *,
        rtol: float = 1e-14,
        max_iterations: int = 50,
    ) -> None:
        m = float(mass)
        if not (math.isfinite(m) and m > 0.0):
            raise ValueError(f"mass must be finite and positive (kg), got {mass}")
        inertia = _as_inertia(inertia_body)
        if inertia.shape != (3, 3) or not np.all(np.isfinite(inertia)):
            raise ValueError(
                f"inertia_body must be a finite (3, 3) matrix or (3,) principal moments (kg m²),"
                f" got shape {np.shape(inertia_body)}"
            )
        scale = float(np.max(np.abs(inertia)))
        if scale == 0.0 or np.max(np.abs(inertia - inertia.T)) > 1e-12 * scale:
            raise ValueError("inertia_body must be symmetric (to 1e-12 relative) and nonzero")
        inertia = 0.5 * (inertia + inertia.T)
        eig = np.linalg.eigvalsh(inertia)
        if eig[0] <= 1e-14 * eig[-1]:
            raise ValueError(
                f"inertia_body must be positive-definite, got eigenvalues {eig} (kg m²)"
            )
        if not (0.0 < rtol < 1.0):
            raise ValueError(f"rtol must be in (0, 1), got {rtol}")
        if int(max_iterations) < 1:
            raise ValueError(f"max_iterations must be >= 1, got {max_iterations}")
        self.mass = m
        self.inertia_body = inertia
        self.inertia_inverse = np.linalg.inv(inertia)
        self.rtol = float(rtol)
        self.max_iterations = int(max_iterations)
        #: Iterations taken by the last call of :meth:`step`.
        self.last_iterations = 0

    # ---- diagnostics -------------------------------------------------------------------------

    def kinetic_energy(self, state: RigidState) -> float:
        """Kinetic energy of ``state`` (J)."""
        return state.kinetic_energy(self.mass, self.inertia_body)

    def angular_momentum(self, state: RigidState) -> FloatArray:
        """Spatial angular momentum of ``state`` about G (kg m²/s), shape (3,)."""
        return state.angular_momentum(self.inertia_body)

    def linear_momentum(self, state: RigidState) -> FloatArray:
        """Linear momentum ``m v_g`` of ``state`` (kg m/s), shape (3,)."""
        return self.mass * state.v_g

    # ---- time stepping -----------------------------------------------------------------------

    @staticmethod
    def _load(fun: LoadFunction | None, t: float, state: RigidState, name: str) -> FloatArray:
        """Evaluate an optional load callable; None (callable or result) means zero."""
        if fun is None:
            return np.zeros(3)
        value = fun(t, state)
        if value is None:
            return np.zeros(3)
        return as_vector3(value, f"{name}(t={t:g})")

    def step(
        self,
        state: RigidState,
        dt: float,
        force: LoadFunction | None = None,
        moment: LoadFunction | None = None,
    ) -> RigidState:
        """Advance ``state`` by one step ``dt``.

        Args:
            state: State at ``t_n`` (not modified).
            dt: Time step h (s), > 0.
            force: ``force(t, state)`` → total external force on the body (N), inertial frame,
                or None (zero). Called at the mid-step time and state.
            moment: ``moment(t, state)`` → total external moment about G (N·m), inertial frame,
                or None (zero). Called at the mid-step time and state.

        Returns:
            New state at ``t_n + dt``.

        Raises:
            ValueError: ``dt`` not finite and positive, or a load of the wrong shape.
            RuntimeError: The per-step nonlinear solve did not converge.
        """
        h = float(dt)
        if not (math.isfinite(h) and h > 0.0):
            raise ValueError(f"dt must be finite and positive (s), got {dt}")
        inertia, inertia_inv, m = self.inertia_body, self.inertia_inverse, self.mass
        t0, v0, w0 = state.t, state.v_g, state.omega
        pi0 = inertia @ w0
        has_loads = force is not None or moment is not None

        # Initial guess: second-order Taylor of the torque-free motion.
        theta = h * w0 + 0.5 * h * h * (inertia_inv @ np.cross(pi0, w0))
        v1 = v0.copy()
        f_bar = np.zeros(3)
        m_body = np.zeros(3)  # R_nᵀ M̄, body components at t_n
        converged = False
        res_norm = dtheta_norm = dv = math.inf
        it = 0
        for it in range(1, self.max_iterations + 1):
            if has_loads:
                f_bar, m_body = self._mid_step_loads(state, h, v1, theta, force, moment)
            v1_new = v0 + (h / m) * f_bar
            dv = norm3(v1_new - v1)
            v1 = v1_new

            # Rotation: Newton step on r(θ) = I_G (2θ/h - Ω_n) - exp(-hat θ) a.
            a = pi0 + h * m_body
            theta, residual, dtheta = self._rotation_newton_step(theta, w0, a, h)

            res_norm = norm3(residual)
            dtheta_norm = norm3(dtheta)
            res_scale = norm3(a) + (2.0 / h) * norm3(inertia @ theta)
            small_step = dtheta_norm <= self.rtol * norm3(theta)
            at_round_off = res_norm <= 8.0 * EPS * res_scale
            v_ok = dv <= self.rtol * norm3(v1)
            # With loads, iterate at least twice so the loads are seen at an updated iterate.
            if (small_step or at_round_off) and v_ok and (it > 1 or not has_loads):
                converged = True
                break
        self.last_iterations = it
        if not converged:
            raise RuntimeError(
                f"NewtonEuler.step from t={t0:.9g} s with dt={h:.3g} s did not converge in "
                f"{self.max_iterations} iterations (rotation residual {res_norm:.3e} kg m²/s,"
                f" |dθ|={dtheta_norm:.3e} rad, |dv|={dv:.3e} m/s)"
            )
        return self._end_state(state, h, theta, v1, pi0 + h * m_body)

    def _mid_step_loads(
        self,
        state: RigidState,
        h: float,
        v1: FloatArray,
        theta: FloatArray,
        force: LoadFunction | None,
        moment: LoadFunction | None,
    ) -> tuple[FloatArray, FloatArray]:
        """The loads at the mid-step state of the iterate (v_{n+1}, θ) from ``state`` at t_n.

        Returns:
            F̄ (N, inertial frame) and R_nᵀ M̄ (N·m, body components at t_n).
        """
        t0, x0, v0, R0 = state.t, state.x_g, state.v_g, state.R
        x1 = x0 + 0.5 * h * (v0 + v1)
        mid = RigidState._trusted(
            t0 + 0.5 * h,
            0.5 * (x0 + x1),
            0.5 * (v0 + v1),
            R0 @ exp_so3_unchecked(0.5 * theta),
            theta / h,
        )
        f_bar = self._load(force, mid.t, mid, "force")
        m_body = R0.T @ self._load(moment, mid.t, mid, "moment")
        return f_bar, m_body

    def _rotation_newton_step(
        self, theta: FloatArray, w0: FloatArray, a: FloatArray, h: float
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """One Newton step on r(θ) = I_G (2θ/h - Ω_n) - exp(-hat θ) a (kg m²/s).

        Returns:
            The updated θ (rad), the residual r at the old θ, and the increment dθ (rad).
        """
        inertia = self.inertia_body
        E = exp_so3_unchecked(-theta)
        residual = inertia @ ((2.0 / h) * theta - w0) - E @ a
        jac = (2.0 / h) * inertia - E @ hat_unchecked(a) @ right_jacobian_unchecked(-theta)
        dtheta = -np.linalg.solve(jac, residual)
        theta = theta + dtheta
        return theta, residual, dtheta

    def _end_state(
        self, state: RigidState, h: float, theta: FloatArray, v1: FloatArray, a: FloatArray
    ) -> RigidState:
        """The state at t_n + h from the converged θ, v_{n+1} and a = I_G Ω_n + h R_nᵀ M̄."""
        t0, x0, v0, R0 = state.t, state.x_g, state.v_g, state.R
        pi1 = exp_so3_unchecked(-theta) @ a
        R1 = R0 @ exp_so3_unchecked(theta)
        if float(np.max(np.abs(R1.T @ R1 - I3))) > 1e-13:
            R1 = project_to_so3(R1)
        return RigidState._trusted(
            t0 + h, x0 + 0.5 * h * (v0 + v1), v1, R1, self.inertia_inverse @ pi1
        )

    def integrate(
        self,
        state: RigidState,
        dt: float,
        n_steps: int,
        force: LoadFunction | None = None,
        moment: LoadFunction | None = None,
    ) -> list[RigidState]:
        """Take ``n_steps`` steps of size ``dt`` from ``state``.

        Args:
            state: Initial state (not modified).
            dt: Time step (s), > 0.
            n_steps: Number of steps, >= 0.
            force: See :meth:`step`.
            moment: See :meth:`step`.

        Returns:
            The ``n_steps + 1`` states at ``t_0, t_0 + dt, ...`` (the first is a copy of ``state``).

        Raises:
            ValueError: Bad ``dt`` or ``n_steps``.
            RuntimeError: A step did not converge; the message names the step.
        """
        if not (math.isfinite(float(dt)) and float(dt) > 0.0):
            raise ValueError(f"dt must be finite and positive (s), got {dt}")
        if int(n_steps) != n_steps or n_steps < 0:
            raise ValueError(f"n_steps must be a non-negative integer, got {n_steps}")
        states = [state.copy()]
        for i in range(int(n_steps)):
            try:
                states.append(self.step(states[-1], dt, force=force, moment=moment))
            except RuntimeError as err:
                raise RuntimeError(f"step {i + 1} of {n_steps}: {err}") from err
        return states


# --------------------------------------------------------------------------------------------
# Prescribed motion
# --------------------------------------------------------------------------------------------


class SpinUp:
    """Smooth spin-up about a fixed axis through G, for prescribed-motion scenes.

    Angular rate (rad/s), with ``T`` the ramp time and ``Ωs`` the final rate::

        Ω(t) = (Ωs/T) (t - T/(2π) sin(2πt/T))      0 <= t < T
        Ω(t) = Ωs                                   t >= T
        Ω(t) = 0                                    t < 0 (at rest before the ramp)

    so the angular acceleration ``(Ωs/T)(1 - cos(2πt/T))`` is zero at both ends of the ramp
    (C¹ rate, continuous acceleration). The angle is the exact integral::

        θ(t) = (Ωs/T) (t²/2 + T²/(4π²) (cos(2πt/T) - 1))    0 <= t < T
        θ(t) = θ(T) + Ωs (t - T) = Ωs T/2 + Ωs (t - T)      t >= T

    For a rotation about a fixed axis the body-frame and inertial-frame angular velocities are the
    same vector, ``Ω(t) axis``.

    Args:
        omega_s: Final angular rate Ωs (rad/s), finite (may be negative or zero).
        ramp_time: Ramp duration T (s), finite and > 0.
        axis: Rotation axis (any nonzero length), normalised here.
    """

    def __init__(self, omega_s: float, ramp_time: float, axis: ArrayLike = (0.0, 0.0, 1.0)) -> None:
        omega_s = float(omega_s)
        ramp_time = float(ramp_time)
        if not math.isfinite(omega_s):
            raise ValueError(f"omega_s must be finite (rad/s), got {omega_s}")
        if not (math.isfinite(ramp_time) and ramp_time > 0.0):
            raise ValueError(f"ramp_time must be finite and positive (s), got {ramp_time}")
        n = as_vector3(axis, "axis")
        norm = float(np.linalg.norm(n))
        if norm == 0.0:
            raise ValueError("axis must be nonzero")
        self.omega_s = omega_s
        self.ramp_time = ramp_time
        self.axis = n / norm

    def __repr__(self) -> str:
        return (
            f"SpinUp(omega_s={self.omega_s!r}, ramp_time={self.ramp_time!r}, "
            f"axis={tuple(self.axis.tolist())!r})"
        )

    def rate(self, t: ArrayLike) -> float | FloatArray:
        """Angular rate Ω(t) (rad/s); ``t`` (s) scalar or array."""
        t_arr = np.asarray(t, dtype=float)
        T, ws = self.ramp_time, self.omega_s
        tc = np.clip(t_arr, 0.0, T)
        ramp = ws / T * (tc - T / (2.0 * np.pi) * np.sin(2.0 * np.pi * tc / T))
        out = np.where(t_arr >= T, ws, np.where(t_arr <= 0.0, 0.0, ramp))
        return float(out) if out.ndim == 0 else out

    def acceleration(self, t: ArrayLike) -> float | FloatArray:
        """Angular acceleration dΩ/dt (rad/s²); ``t`` (s) scalar or array."""
        t_arr = np.asarray(t, dtype=float)
        T, ws = self.ramp_time, self.omega_s
        tc = np.clip(t_arr, 0.0, T)
        # 1 - cos(2πt/T) = 2 sin²(πt/T): exact zeros at both ends of the ramp.
        ramp = ws / T * 2.0 * np.sin(np.pi * tc / T) ** 2
        out = np.where((t_arr > 0.0) & (t_arr < T), ramp, 0.0)
        return float(out) if out.ndim == 0 else out

    def angle(self, t: ArrayLike) -> float | FloatArray:
        """Rotation angle θ(t) = ∫₀ᵗ Ω (rad); ``t`` (s) scalar or array."""
        t_arr = np.asarray(t, dtype=float)
        T, ws = self.ramp_time, self.omega_s
        tc = np.clip(t_arr, 0.0, T)
        # cos(2πt/T) - 1 = -2 sin²(πt/T), without cancellation for small t.
        ramp = ws / T * (0.5 * tc**2 - T**2 / (2.0 * np.pi**2) * np.sin(np.pi * tc / T) ** 2)
        out = np.where(t_arr >= T, 0.5 * ws * T + ws * (t_arr - T), ramp)
        out = np.where(t_arr <= 0.0, 0.0, out)
        return float(out) if out.ndim == 0 else out

    def rotation(self, t: float) -> FloatArray:
        """Rotation matrix (3, 3) at time ``t`` (s): ``angle(t)`` about ``axis``."""
        return rotation_about(self.axis, float(self.angle(float(t))))

    def omega_vector(self, t: float) -> FloatArray:
        """Angular velocity vector ``Ω(t) axis`` (rad/s), body = inertial frame, shape (3,)."""
        return float(self.rate(float(t))) * self.axis

    def domega_vector(self, t: float) -> FloatArray:
        """Angular acceleration vector ``dΩ/dt axis`` (rad/s²), shape (3,)."""
        return float(self.acceleration(float(t))) * self.axis

    def state(self, t: float, x_g: ArrayLike = (0.0, 0.0, 0.0)) -> RigidState:
        """Rigid state at time ``t`` (s) for a body spinning about a fixed centre ``x_g`` (m)."""
        return RigidState(
            t=float(t), x_g=x_g, v_g=np.zeros(3), R=self.rotation(t), omega=self.omega_vector(t)
        )
