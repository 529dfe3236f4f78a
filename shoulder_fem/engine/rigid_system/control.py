"""Travel control: a prescribed body slides along a line until a measured quantity hits a target.

The shoulder is driven by its rotation angle, not by the actuator's travel: the travel ``d`` of
the actuator plate along a unit ``direction`` is an unknown and ``measure(state) = target`` is
its equation. Both enter the Newton system of :class:`~.problem.ReducedProblem` in place of the
plate's three translation rows (its rotation stays prescribed):

    row t_1:  s (m(x) - target) = 0        (the control equation, scaled by ``scale``)
    row t_2:  p_1 · (t - t_0) = 0          (the plate stays on its line through ``t_0``)
    row t_3:  p_2 · (t - t_0) = 0

with (``direction``, p_1, p_2) an orthonormal basis. The plate's translation t thus carries
``d = direction · (t - t_0)``, and the Jacobian is the ordinary one with these three rows, so
the bordered system is solved by the same LU inside the same SNES (line searches, monitors,
options and converged reasons as everywhere). The measure's gradient row has an entry per
reduced unknown it depends on (the FE nodes through the prolongation Pᵀ, the bodies' six
DOFs directly). After a converged solve, ``dx/dtarget = J⁻¹ (s e_1)`` is one back-substitution
with the last factorization: the tangent predictor of the next target.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from petsc4py import PETSc

from shoulder_fem.engine.rigid_system.layout import ReducedLayout
from shoulder_fem.engine.rigid_system.terms import left_jacobian
from shoulder_fem.engine.rigid_system.uncondensed import operator

__all__ = [
    "ControlledSystem",
    "MeasureGradient",
    "TravelControl",
    "control_tangent",
    "set_control_rows",
]


@dataclass
class MeasureGradient:
    """A measured scalar and its derivatives at the current state.

    Attributes:
        value: The measure (its own unit, e.g. rad).
        fe: d value / d u at the owned FE entries (3 per owned node, the layout of ``u``'s
            owned array), or None if it does not depend on the FE displacement.
        bodies: Per body index, d value / d(t, ω) (6,): translation (1/m) and *spatial*
            rotation increment ω, ``R → exp(hat ω) R`` (1/rad).
    """

    value: float
    fe: np.ndarray | None = None
    bodies: dict[int, np.ndarray] = field(default_factory=dict)


@dataclass
class TravelControl:
    """Body ``body`` travels along ``direction`` so that ``measure`` equals ``target``.

    Attributes:
        body: The index of the controlled body (a prescribed one; its rotation stays its target).
        direction: Unit direction of its travel.
        measure: Callable(with_gradient) -> :class:`MeasureGradient` at the current state
            (collective; without the gradient the fields ``fe`` and ``bodies`` may be left empty).
        scale: Residual units per unit of the measure (e.g. N/rad): sets how the control row
            weighs in the residual norm. With ``snes_atol`` a, the measure converges to a / scale.
        origin: A point of the line (the body's translation at travel 0, m).
        target: The value the measure must take (set before each solve).
    """

    body: int
    direction: np.ndarray
    measure: Callable[[bool], MeasureGradient]
    scale: float
    origin: np.ndarray
    target: float = 0.0

    def __post_init__(self) -> None:
        d = np.asarray(self.direction, dtype=float)
        n = float(np.linalg.norm(d))
        if not (np.isfinite(n) and n > 0):
            raise ValueError(f"TravelControl: direction must be a nonzero vector, got {d}")
        if not (np.isfinite(self.scale) and self.scale > 0):
            raise ValueError(f"TravelControl: scale must be finite and > 0, got {self.scale}")
        self.direction = d / n
        self.origin = np.asarray(self.origin, dtype=float).copy()
        # the two directions normal to the line: (direction, p1, p2) orthonormal
        helper = np.eye(3)[int(np.argmin(np.abs(self.direction)))]
        p1 = np.cross(self.direction, helper)
        p1 /= np.linalg.norm(p1)
        self.normals = np.array([p1, np.cross(self.direction, p1)])

    def travel(self, translation: np.ndarray) -> float:
        """The travel ``d`` (m) of a translation along the line."""
        return float(self.direction @ (np.asarray(translation) - self.origin))

    def residual(self, value: float, translation: np.ndarray) -> np.ndarray:
        """The three rows (scaled control equation, the two line conditions (m))."""
        off_line = self.normals @ (np.asarray(translation) - self.origin)
        return np.concatenate([[self.scale * (value - self.target)], off_line])


def set_control_rows(
    J: PETSc.Mat,
    control: TravelControl,
    layout: ReducedLayout,
    P: PETSc.Mat | None,
    work: tuple[PETSc.Vec, PETSc.Vec] | None,
    phi: np.ndarray,
) -> None:
    """Replace the controlled body's translation rows of the assembled ``J`` (collective).

    Row 1: ``scale`` x the measure's gradient in the reduced unknowns (FE entries through Pᵀ,
    bodies' rotations mapped from ω to φ by ``J_l(φ)ᵀ``); rows 2-3: the line's normals.

    Args:
        J: The assembled reduced Jacobian (re-assembled here).
        control: The control (its measure is evaluated at the current state).
        layout: The reduced layout.
        P: The prolongation (filled at the current state), or None without FE.
        work: (reduced, FE) work vectors of P's layout, or None without FE.
        phi: The bodies' rotation vectors (nb, 3).
    """
    comm = layout.comm
    grad = control.measure(True)
    cols, vals = [np.zeros(0, dtype=PETSc.IntType)], [np.zeros(0)]
    if work is not None and grad.fe is not None:
        g_red, g_fe = work
        g_fe.array[:] = grad.fe
        P.multTranspose(g_fe, g_red)  # d/du -> d/d(reduced): tied nodes through P
        nz = np.flatnonzero(g_red.array_r)
        cols.append((layout.start + nz).astype(PETSc.IntType))
        vals.append(g_red.array_r[nz])
    for b, d6 in grad.bodies.items() if comm.rank == 0 else ():  # the same on every rank
        cols.append(layout.rigid_cols(b))  # spatial ω -> φ: δω = J_l(φ) δφ
        vals.append(np.concatenate([d6[:3], left_jacobian(phi[b]).T @ d6[3:]]))
    gathered = comm.gather((np.concatenate(cols), np.concatenate(vals)), root=0)
    rows = layout.rigid_cols(control.body)[:3] if comm.rank == 0 else []
    # the gradient row widens the pattern the first time (a contact merge may have replaced
    # the matrix's options since: set them each time)
    J.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, False)
    J.setOption(PETSc.Mat.Option.KEEP_NONZERO_PATTERN, True)
    J.zeroRows(np.asarray(rows, dtype=PETSc.IntType), diag=0.0)
    if comm.rank == 0:
        # a rigid column can come both through P (tied nodes) and directly: sum them
        keys, where = np.unique(np.concatenate([g[0] for g in gathered]), return_inverse=True)
        row = np.zeros(len(keys))
        np.add.at(row, where, control.scale * np.concatenate([g[1] for g in gathered]))
        add = PETSc.InsertMode.ADD_VALUES
        J.setValues(rows[:1], keys.astype(PETSc.IntType), row, addv=add)
        J.setValues(
            rows[1:], layout.rigid_cols(control.body)[:3], control.normals.ravel(), addv=add
        )
    J.assemble()


def control_tangent(ksp: PETSc.KSP, J: PETSc.Mat, layout: ReducedLayout, control: TravelControl):
    """``v = J⁻¹ (scale e)`` with ``ksp``'s factorization of ``J`` (collective; a new Vec).

    ``e`` is the control row: the derivative of the state with respect to the target.
    """
    rhs, v = J.createVecs()
    rhs.set(0.0)
    if layout.comm.rank == 0:
        rhs.setValue(layout.rigid_cols(control.body)[0], control.scale)
    rhs.assemble()
    ksp.solve(rhs, v)
    rhs.destroy()
    return v


#: Halvings of a predictor step whose state the model's admissibility test refuses.
PREDICTOR_HALVINGS = 12


class ControlledSystem:
    """The travel-control methods of :class:`~.system.RigidSystem` (a mixin; all collective)."""

    def set_control(
        self,
        body: str,
        direction: np.ndarray,
        measure: Callable[[bool], MeasureGradient],
        scale: float,
    ) -> TravelControl:
        """Make prescribed body ``body``'s travel along ``direction`` an unknown (collective).

        From now on every solve also satisfies ``measure = control.target`` (set the target
        before each solve); the body's rotation stays its prescribed one, its translation moves
        on the line through its current translation (module docstring).

        Returns:
            The control (its ``target`` is the current measure).
        """
        b = self._index[body]
        if not self.bodies[b].prescribed:
            raise ValueError(f"{self.prefix}: set_control needs a prescribed body, '{body}' is not")
        origin = self.bodies[b].translation.copy()
        control = TravelControl(b, direction, measure, scale, origin)
        control.target = measure(False).value
        self._problem.set_control(control)
        return control

    @property
    def control(self) -> TravelControl | None:
        """The travel control (:meth:`set_control`), or None."""
        return self._problem.control

    def control_tangent(self, refresh: bool = False) -> PETSc.Vec:
        """d(reduced state)/d(target) after a converged controlled solve (collective).

        One back-substitution with the factorization of the solve's last Jacobian:
        ``J v = s e`` where ``e`` is the control row and ``s`` its scale (the derivative of the
        control residual with respect to the target is ``-s``). Counted as a linear solve, its
        time in the Newton time. ``refresh``: evaluate and factorize J at the current state
        first (e.g. after :meth:`set_control`, when the last Jacobian had no control row).
        """
        control = self._problem.control
        if control is None:
            raise ValueError(f"{self.prefix}: control_tangent needs set_control first")
        t0 = time.perf_counter()
        if refresh:
            A, J = operator(self._problem), self._problem.J
            x = self._problem.x_from_state(targets=False).copy()
            self.snes.computeJacobian(x, A, J)
            self.snes.getKSP().setOperators(A, J)
            x.destroy()
        v = control_tangent(self.snes.getKSP(), self._problem.J, self._problem.layout, control)
        self.stats.snes_s += time.perf_counter() - t0
        self.stats.linear_solves += 1
        return v

    def predict(self, tangent: PETSc.Vec, step: float) -> float:
        """Move the state by ``step`` x ``tangent`` (:meth:`control_tangent`) (collective).

        The predictor of the next controlled solve, whose target is ``step`` further.
        The tangent's rotation entries are taken as increments of the current rotations (they
        were of the rotations at the solve's last Jacobian, an O(step) difference). A predicted
        state that the model's admissibility test refuses (the test of the Newton trial states,
        :class:`~.guard.TrialGuard`) is not taken: the move is halved until it passes, at most
        :data:`PREDICTOR_HALVINGS` times, else the state stays. A Newton solve started from a
        refused state cannot leave it: every trial step near it is refused too. Measured on the
        incompressible shoulder's part 1 at ``coarse``: near 39.8 deg, where the tangent is
        large (Newton steps of 0.03-9 rad of the humerus for increments of 0.006-0.03 deg), its
        predictors landed in refused states and the solves made no progress. Returns the
        fraction of the move taken.
        """
        problem = self._problem
        x0 = problem.x_from_state(targets=False).copy()
        x = x0.duplicate()
        admissible = self._guard.admissible
        scale = 1.0
        for _ in range(PREDICTOR_HALVINGS):
            x0.copy(x)
            x.axpy(scale * step, tangent)
            problem.update_state(x)
            if admissible is None or admissible():
                break
            scale *= 0.5
        else:
            scale = 0.0
            problem.update_state(x0)
        x.destroy()
        x0.destroy()
        problem.commit()  # the predicted rotations become R₀ (φ = 0)
        return scale
