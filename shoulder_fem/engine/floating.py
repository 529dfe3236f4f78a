"""The coupled floating-frame solver of the paper's eq. (14) for a free deformable body.

:class:`FloatingBody` owns the state (frame and straining), the time step (rigid predictor,
Newton iterations on one bordered system, update of positions and velocities) and the measures.
Its forms are in :mod:`~shoulder_fem.engine.floating_forms`, the block elimination in
:mod:`~shoulder_fem.engine.bordered`. SI units: m, s, kg, N, Pa, rad.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import dolfinx
import numpy as np
import ufl
from mpi4py import MPI

from shoulder_fem.engine.floating_forms import FloatingForms
from shoulder_fem.engine.floating_newton import FloatingNewtonSystem, NewtonResidual
from shoulder_fem.engine.mass import mass_properties
from shoulder_fem.engine.motion_measures import MotionMeasures
from shoulder_fem.engine.so3 import I3, exp_so3, log_so3, project_to_so3
from shoulder_fem.engine.solver import ConvergenceError
from shoulder_fem.forms.materials import Hyperelastic

logger = logging.getLogger(__name__)

__all__ = ["FloatingBody", "FloatingState"]


@dataclass
class FloatingState:
    """State of the floating body at the end of a step.

    Attributes:
        t: time (s).
        x_g: centre of mass, inertial frame (m).
        R: rotation body → inertial frame.
        multipliers: the six frame-condition multipliers λ (N, N·m); zero at convergence.
        history: residual norms (N) of the last step's Newton iterations.
    """

    t: float = 0.0
    x_g: np.ndarray = field(default_factory=lambda: np.zeros(3))
    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    multipliers: np.ndarray = field(default_factory=lambda: np.zeros(6))
    history: list[float] = field(default_factory=list)


class FloatingBody:
    """The coupled floating-frame solver: frame (x_G, R) and straining ũ in one Newton solve.

    The unknowns are the frame and the straining displacement ũ (body-frame components, m) of a
    body with no supports and no external load, ``x = x_G + R (Y + ũ)``; the split is made
    unique by the six mean-axes conditions in their linear (Buckens) form, ∫ρ ũ = 0 and
    ∫ρ Y × ũ = 0, with six Lagrange multipliers λ (with ∫ρ Y = 0 the first three make x_G the
    true centre of mass). The residual, the time integrator (Simo–Tarnow energy–momentum
    midpoint rule) and its conservation properties are documented on :class:`FloatingForms`.
    Each step is a rigid predictor, Newton iterations on :class:`FloatingNewtonSystem` and the
    update of the nodal positions and velocities.

    Args:
        mesh: reference mesh (m).
        degree: Lagrange degree of ũ.
        density: ρ (kg/m³), uniform.
        material: a hyperelastic law (Saint Venant–Kirchhoff for bone).
        quadrature_degree: quadrature of every form (mass term exact for 2·degree).
        rtol: Newton stops when the residual norm drops below ``rtol`` × the step's initial
            residual, or below ``atol``.
        atol: absolute residual tolerance (N); by default 1e-11 × (2 m ℓ/Δt² + the
            ``force_scale`` of :meth:`set_initial_state`), ℓ = √(tr I_G / m) the body's size: about
            1e5 times the round-off floor of the inertia and internal forces.
        max_iterations: Newton iteration cap per step.
        name: options-prefix stem.
    """

    def __init__(
        self,
        mesh: dolfinx.mesh.Mesh,
        degree: int,
        density: float,
        material: Hyperelastic,
        *,
        quadrature_degree: int | None = None,
        rtol: float = 1e-10,
        atol: float | None = None,
        max_iterations: int = 12,
        name: str = "floating",
    ):
        self.mesh = mesh
        self.comm = mesh.comm
        self.rho = float(density)
        self.material = material
        self.rtol = float(rtol)
        self.atol = atol
        self.max_iterations = int(max_iterations)
        qd = quadrature_degree or 2 * degree
        dx = ufl.Measure("dx", domain=mesh, metadata={"quadrature_degree": qd})
        self.dx = dx
        V = dolfinx.fem.VectorFunctionSpace(mesh, ("Lagrange", degree))
        self.V = V
        self.props = mass_properties(mesh, self.rho, dx)
        self.n_owned = V.dofmap.index_map.size_local * 3
        self.length = math.sqrt(float(np.trace(self.props.inertia)) / self.props.mass)

        self.forms = FloatingForms(mesh, V, self.rho, material, self.props.centre, dx, qd)
        self.u = self.forms.u
        self.x_n = self.forms.x_n  # inertial nodal positions at t_n
        self.v_n = self.forms.v_n  # inertial nodal velocities at t_n
        self.von_mises = self.forms.von_mises
        self.system = FloatingNewtonSystem(self.forms, self.n_owned, self.length, name)
        self.linear = self.system.linear
        self.measures = MotionMeasures(V, self.rho, dx)
        self.state = FloatingState(x_g=self.props.centre.copy())
        self.newton_iterations = 0
        self.steps = 0
        self._omega_spatial = np.zeros(3)
        self._v_g = np.zeros(3)
        self._force_scale = 0.0

    def _positions(self) -> np.ndarray:
        """Inertial nodal positions x = x_G + R(Y + ũ) (local + ghost nodes, (n, 3))."""
        return self.forms.positions(self.state.x_g, self.state.R)

    # -- state ------------------------------------------------------------------------------
    def set_initial_state(
        self,
        omega_body: np.ndarray,
        R: np.ndarray | None = None,
        v_g: np.ndarray | None = None,
        force_scale: float = 0.0,
        u0: np.ndarray | None = None,
    ) -> None:
        """Start from a rigid motion of the body strained by ``u0`` (ũ = 0 by default).

        The initial velocity is rigid, v = v_G + ω × (x − x_G), and the straining velocity zero.

        Args:
            omega_body: body-frame angular velocity Ω (rad/s).
            R: initial rotation (identity by default).
            v_g: velocity of G (m/s), zero by default.
            force_scale: a force (N) typical of the internal forces, e.g. E ℓ² ε for the
                expected strain ε; used only for the default absolute tolerance.
            u0: initial straining displacement ũ (m), local + ghost entries of the blocked
                array; it should satisfy the mean-axes conditions (the first step enforces them).
        """
        s = self.state
        s.R = np.eye(3) if R is None else project_to_so3(R)
        s.x_g = self.props.centre.copy()
        s.multipliers = np.zeros(6)
        v_g = np.zeros(3) if v_g is None else np.asarray(v_g, dtype=float)
        self.u.x.array[:] = 0.0 if u0 is None else u0
        self._omega_spatial = s.R @ np.asarray(omega_body, dtype=float)
        x = self._positions()
        self.x_n.x.array[:] = x.ravel()
        self.v_n.x.array[:] = (v_g + np.cross(self._omega_spatial, x - s.x_g)).ravel()
        self._v_g = v_g.copy()
        self._force_scale = float(force_scale)

    def save(self) -> tuple:
        """Snapshot of the state (for a step cut-back)."""
        s = self.state
        return (
            s.t,
            s.x_g.copy(),
            s.R.copy(),
            s.multipliers.copy(),
            self.u.x.array.copy(),
            self.x_n.x.array.copy(),
            self.v_n.x.array.copy(),
            self._omega_spatial.copy(),
            self._v_g.copy(),
        )

    def restore(self, snap: tuple) -> None:
        """Put a :meth:`save` snapshot back."""
        s = self.state
        s.t, x_g, R, lam, u, xn, vn, om, v_g = snap
        s.x_g, s.R, s.multipliers = x_g.copy(), R.copy(), lam.copy()
        self.u.x.array[:] = u
        self.x_n.x.array[:] = xn
        self.v_n.x.array[:] = vn
        self._omega_spatial = om.copy()
        self._v_g = v_g.copy()

    # -- one step ---------------------------------------------------------------------------
    def step(self, dt: float) -> list[float]:
        """Advance by ``dt`` (s); return the Newton residual norms (N) of the step.

        Raises:
            ConvergenceError: Newton did not converge in ``max_iterations`` (the state is left
                at the last iterate: restore a snapshot).
        """
        h = float(dt)
        self.forms.dt.value = h
        R_start = self.state.R.copy()
        self._predict(h)
        history, lam = self._newton(h)
        self._close_step(h, R_start, history, lam)
        return history

    def _predict(self, h: float) -> None:
        """Predictor: rigid drift of the frame over ``h`` (s), same ũ."""
        s = self.state
        s.x_g = s.x_g + h * self._v_g
        s.R = exp_so3(h * self._omega_spatial) @ s.R

    def _newton(self, h: float) -> tuple[list[float], np.ndarray]:
        """Newton iterations of the step ``h`` (s) from the predicted state.

        Returns:
            The residual norms (N) and the converged multipliers λ.
        """
        s = self.state
        atol = self.atol
        if atol is None:  # ~1e5 × the round-off floor of the inertia and internal forces
            atol = 1e-11 * (2.0 * self.props.mass * self.length / h**2 + self._force_scale)
        lam = s.multipliers
        history: list[float] = []
        r0 = None
        step_name = f"t = {s.t + h:.6g} s"
        for it in range(self.max_iterations + 1):
            res = self.system.residual(s.x_g, s.R, lam, h)
            norm = res.norm
            history.append(norm)
            if not math.isfinite(norm):
                raise ConvergenceError(step_name, "non-finite residual", it, self.linear.prefix)
            if r0 is None:
                r0 = norm
            if norm <= max(self.rtol * r0, atol) and (it > 0 or norm <= atol):
                break
            if it == self.max_iterations:
                raise ConvergenceError(
                    step_name,
                    f"residual {norm:.3e} N > {max(self.rtol * r0, atol):.3e} N",
                    it,
                    self.linear.prefix,
                )
            lam = self._correct(res, lam)
        return history, lam

    def _correct(self, res: NewtonResidual, lam: np.ndarray) -> np.ndarray:
        """Solve the bordered system at the iterate, apply the increment; return the new λ."""
        s = self.state
        du, q = self.system.solve(res, s.R)
        self.u.x.array[: self.n_owned] += du
        self.u.x.scatter_forward()
        s.x_g = s.x_g + q[:3]
        s.R = exp_so3(q[3:6]) @ s.R
        return lam + q[6:]

    def _close_step(
        self, h: float, R_start: np.ndarray, history: list[float], lam: np.ndarray
    ) -> None:
        """Store the converged iterate and close the step: x_{n+1}, v_{n+1}, v_G, ω, t."""
        s = self.state
        iterations = len(history) - 1
        self.newton_iterations += iterations
        self.steps += 1
        s.multipliers = lam
        s.history = history
        if float(np.max(np.abs(s.R.T @ s.R - I3))) > 1e-13:
            s.R = project_to_so3(s.R)
        # Close the step: x_{n+1}, v_{n+1} = 2(x_{n+1} − x_n)/Δt − v_n.
        x1 = self._positions().ravel()
        v1 = 2.0 * (x1 - self.x_n.x.array) / h - self.v_n.x.array
        self.x_n.x.array[:] = x1
        self.v_n.x.array[:] = v1
        self._v_g = self._mean_velocity()
        self._omega_spatial = log_so3(s.R @ R_start.T) / h
        s.t += h

    def advance(self, t0: float, t1: float) -> None:
        """Take the state from ``t0`` to ``t1`` (s) in one step (for :func:`solver.march`)."""
        self.step(t1 - t0)

    def _mean_velocity(self) -> np.ndarray:
        """Velocity of the centre of mass, P/m (m/s)."""
        self.measures.v.x.array[:] = self.v_n.x.array
        return self.measures.linear_momentum() / self.props.mass

    # -- measures ---------------------------------------------------------------------------
    def kinetic_energy(self) -> float:
        """½∫ρ|v|² at t_n (J)."""
        self.measures.v.x.array[:] = self.v_n.x.array
        return self.measures.kinetic_energy()

    def strain_energy(self) -> float:
        """∫W(E(ũ)) at t_n (J)."""
        return self.comm.allreduce(
            dolfinx.fem.assemble_scalar(self.forms.strain_energy), op=MPI.SUM
        )

    def momenta(self) -> tuple[np.ndarray, np.ndarray]:
        """(linear momentum kg m/s, angular momentum about the origin kg m²/s) at t_n."""
        self.measures.x.x.array[:] = self.x_n.x.array
        self.measures.v.x.array[:] = self.v_n.x.array
        return self.measures.linear_momentum(), self.measures.angular_momentum()

    def measure(self) -> tuple[float, float, np.ndarray, np.ndarray]:
        """(kinetic energy J, strain energy J, P kg m/s, L about the origin kg m²/s) at t_n."""
        self.measures.x.x.array[:] = self.x_n.x.array
        self.measures.v.x.array[:] = self.v_n.x.array
        kinetic, P, L, extra = self.measures.evaluate(self.forms.strain_energy)
        return kinetic, float(extra[0]), P, L

    def max_von_mises(self) -> float:
        """Largest cell-midpoint von Mises stress of S (Pa) (collective)."""
        self.von_mises.interpolate(self.forms.von_mises_expr)
        n = self.mesh.topology.index_map(3).size_local
        local = float(np.max(self.von_mises.x.array[:n])) if n else 0.0
        return self.comm.allreduce(local, op=MPI.MAX)

    def destroy(self) -> None:
        """Free the PETSc objects."""
        self.system.destroy()
