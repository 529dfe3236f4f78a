"""PETSc SNES wrapper for dolfinx 0.5.2, time/load stepping with cut-back, linear solver choices.

dolfinx 0.5.2 has no SNES problem class: :class:`NonlinearSolver` assembles the residual and
the Jacobian of UFL forms in SNES callbacks, applies Dirichlet conditions by lifting, and checks
the converged reason of every solve (:class:`ConvergenceError` names the step, the reason and the
iteration count). Each solver owns a unique PETSc options prefix; its options are set under the
prefix and removed again after ``setFromOptions()`` so that nothing leaks into the global
options database.

Linear problems (the decoupled method's floating-frame stress) use the same class with
``linear=True``: SNES ``ksponly``, and the Jacobian is assembled (and factorized) only when the
caller says the operator changed, so one LU factorization serves every step with the same
operator.
"""

from __future__ import annotations

import itertools
import logging
from collections.abc import Callable, Mapping
from contextlib import ExitStack
from dataclasses import dataclass, field

import dolfinx
import dolfinx.fem.petsc as fem_petsc
import numpy as np
import ufl
from petsc4py import PETSc

from shoulder_fem.engine.fem import JIT_PARAMS, identity_rows
from shoulder_fem.engine.petsc_lib import options_used
from shoulder_fem.engine.progress import Progress

logger = logging.getLogger(__name__)

_prefix_counter = itertools.count()


class ConvergenceError(RuntimeError):
    """A nonlinear (or linear) solve did not converge.

    Attributes:
        step: label of the step that failed (e.g. ``"t=0.0125 s"``).
        reason: PETSc converged-reason name.
        iterations: Newton iterations done before giving up.
        prefix: options prefix of the solver.
    """

    def __init__(self, step: str, reason: str, iterations: int, prefix: str):
        super().__init__(
            f"solver '{prefix}' did not converge at {step}: {reason} after {iterations} "
            "Newton iteration(s)"
        )
        self.step = step
        self.reason = reason
        self.iterations = iterations
        self.prefix = prefix


def unique_prefix(name: str) -> str:
    """Return a PETSc options prefix unique in this process, ending in ``_``."""
    return f"{name}{next(_prefix_counter)}_"


#: Option families a solver reads after its set-up (MUMPS's, at each factorization): a
#: solver's own options of these stay in PETSc's database under its prefix until
#: :func:`release_options`, instead of being removed once the solver is set up (which left
#: them unread).
LATE_OPTIONS = ("mat_mumps_",)
_KEPT: dict[str, set[str]] = {}

#: The user's PETSc options (``--petsc``, :func:`set_user_options`): key (no dash) -> value.
_USER_OPTIONS: dict[str, str] = {}
#: Where they were placed: prefixed name in PETSc's database -> the user's key.
_PLACED: dict[str, str] = {}


def set_user_options(options: Mapping[str, object] | None) -> None:
    """Options every solver of the run reads under its own prefix (``None``: none).

    Unlike a solver's own options (:func:`set_from_options` removes them once read), these
    stay in PETSc's database under each solver's prefix until :func:`clear_user_options`, so
    that what PETSc reads late (a line search's, MUMPS's at the factorization, ``ksp_view``
    at the solve) reaches it too; they win over the code's values of the same key.
    """
    clear_user_options()
    for key, value in (options or {}).items():
        _USER_OPTIONS[str(key).lstrip("-")] = "" if value is None else str(value)


def user_options() -> dict[str, str]:
    """The user's PETSc options (:func:`set_user_options`), a copy: name without "-" -> value."""
    return dict(_USER_OPTIONS)


def clear_user_options() -> None:
    """Take the user's options out of PETSc's database."""
    db = PETSc.Options()
    for name in _PLACED:
        db.delValue(name)
    _PLACED.clear()
    _USER_OPTIONS.clear()


def unused_user_options() -> list[str] | None:
    """The user's options that no solver read so far (misspelt, or of no solver of the run).

    None when PETSc's library cannot be asked (its ``PetscOptionsUsed``).
    """
    used = options_used()
    if used is None:
        return None
    read = {key for name, key in _PLACED.items() if used(name)}
    return sorted(set(_USER_OPTIONS) - read)


def set_from_options(
    solver: PETSc.SNES | PETSc.KSP, options: Mapping[str, object], ksp: bool = True
) -> None:
    """Let ``solver`` read ``options`` under its own prefix, then remove them again.

    The one place where options enter PETSc's global database, so that nothing leaks into
    another solver. For a SNES, its KSP reads them too (unless ``ksp`` is False). The user's
    options (:func:`set_user_options`) are placed under the same prefix and stay.
    """
    prefix = solver.getOptionsPrefix() or ""
    db = PETSc.Options()
    for key, value in options.items():
        db[f"{prefix}{key}"] = value
        if key.startswith(LATE_OPTIONS):  # read at the factorization: kept for it
            _KEPT.setdefault(prefix, set()).add(key)
    for key, value in _USER_OPTIONS.items():
        db[f"{prefix}{key}"] = value
        _PLACED[f"{prefix}{key}"] = key
    try:
        solver.setFromOptions()
        if ksp and isinstance(solver, PETSc.SNES):
            solver.getKSP().setFromOptions()
    finally:
        for key in options:
            if key not in _USER_OPTIONS and not key.startswith(LATE_OPTIONS):
                db.delValue(f"{prefix}{key}")


def release_options(prefix: str) -> None:
    """Remove the options kept for the factorizations of the solver of ``prefix``.

    Called when the solver is destroyed (:data:`LATE_OPTIONS`).
    """
    db = PETSc.Options()
    for key in _KEPT.pop(prefix, ()):
        if key not in _USER_OPTIONS:
            db.delValue(f"{prefix}{key}")


def default_snes_options() -> dict:
    """Newton with a full step, MUMPS LU: a fresh dict each call."""
    return {
        "snes_type": "newtonls",
        "snes_linesearch_type": "basic",
        "snes_rtol": 1e-10,
        "snes_atol": 1e-12,
        "snes_stol": 0.0,
        "snes_max_it": 25,
        "snes_error_if_not_converged": False,
        **direct_solver_options(),
    }


def direct_solver_options() -> dict:
    """MUMPS LU (the default linear solver)."""
    return {"ksp_type": "preonly", "pc_type": "lu", "pc_factor_mat_solver_type": "mumps"}


def iterative_solver_options(rtol: float = 1e-10) -> dict:
    """CG with smoothed-aggregation AMG (GAMG) for large elasticity problems.

    Pair it with :func:`rigid_body_modes` as the matrix's near-nullspace (done by
    :class:`NonlinearSolver` when ``near_nullspace=True``).
    """
    return {
        "ksp_type": "cg",
        "ksp_rtol": rtol,
        "ksp_max_it": 1000,
        "pc_type": "gamg",
        "pc_gamg_type": "agg",
        "pc_gamg_coarse_eq_limit": 1000,
        "mg_levels_ksp_type": "chebyshev",
        "mg_levels_pc_type": "jacobi",
    }


def linear_solver_options(kind: str | None) -> dict:
    """Options for ``kind`` in {"direct", "iterative"}; None: none (each solver's own)."""
    if kind is None:
        return {}
    if kind == "direct":
        return direct_solver_options()
    if kind == "iterative":
        return iterative_solver_options()
    raise ValueError(f"linear solver '{kind}' is not one of: direct, iterative")


def rigid_body_modes(V: dolfinx.fem.FunctionSpace) -> PETSc.NullSpace:
    """The six rigid-body modes of a 3D vector space, orthonormalised (GAMG near-nullspace)."""
    index_map = V.dofmap.index_map
    bs = V.dofmap.index_map_bs
    vectors = [dolfinx.la.create_petsc_vector(index_map, bs) for _ in range(6)]
    with ExitStack() as stack:
        local = [np.asarray(stack.enter_context(v.localForm())) for v in vectors]
        dofs = [V.sub(i).dofmap.list.array for i in range(3)]
        for i in range(3):
            local[i][dofs[i]] = 1.0
        x = V.tabulate_dof_coordinates()
        blocks = V.dofmap.list.array
        x0, x1, x2 = x[blocks, 0], x[blocks, 1], x[blocks, 2]
        local[3][dofs[0]], local[3][dofs[1]] = -x1, x0
        local[4][dofs[0]], local[4][dofs[2]] = x2, -x0
        local[5][dofs[2]], local[5][dofs[1]] = x1, -x2
    dolfinx.la.orthonormalize(vectors)
    return PETSc.NullSpace().create(vectors=vectors)


@dataclass
class SolveStats:
    """Counters of one solver (summed over its solves)."""

    solves: int = 0
    newton_iterations: int = 0
    linear_solves: int = 0
    factorizations: int = 0
    krylov_iterations: int = 0
    history: list[int] = field(default_factory=list)


class NonlinearSolver:
    """Solve F(u; w) = 0 for ``u`` with PETSc SNES.

    Args:
        residual: UFL 1-form F(u; w).
        u: the unknown (its current value is the initial guess; it holds the solution).
        bcs: Dirichlet conditions; their values are imposed on the solution.
        jacobian: UFL 2-form; ``ufl.derivative(residual, u)`` if omitted.
        name: a short name; the options prefix is ``<name><n>_``.
        options: PETSc options overriding :func:`default_snes_options`.
        linear: the problem is linear in ``u``: SNES ``ksponly`` and the Jacobian is
            assembled only on the first solve and after :meth:`operator_changed`.
        operator: for ``linear`` problems, a callback ``operator(A)`` that fills the matrix
            instead of assembling ``jacobian`` (e.g. A = A0 + Ω G from pre-assembled parts).
        lagged_factorization: keep the LU factorization of an earlier operator as the
            preconditioner of a Krylov method (set ``ksp_type``, e.g. gmres) after the operator
            changes; re-factorize only when a solve needed more than ``max_lagged_iterations``
            Krylov iterations or failed. For operators that drift slowly (a Coriolis term).
        near_nullspace: attach the rigid-body modes (done anyway when ``pc_type`` is gamg).
        form_compiler_params: passed to ``dolfinx.fem.form`` (e.g. quadrature_degree).
        contact: a :class:`~shoulder_fem.engine.contact.Contact` on ``u``: its forces are added
            to every residual and its tangent to every Jacobian (built with the same ``bcs``).
        volumetric: a :class:`~shoulder_fem.engine.mean_dilatation.MeanDilatation` on ``u``
            whose :meth:`residual` is part of ``residual``: updated before every residual and
            Jacobian, its cell-mean tangent added to every Jacobian. The ``bcs`` then clear
            the rows of the Jacobian only (no lifting: the Dirichlet columns stay, so a Newton
            step moves the other DOFs with the prescribed ones; the matrix is not symmetric).
    """

    def __init__(
        self,
        residual: ufl.Form,
        u: dolfinx.fem.Function,
        bcs: list | None = None,
        jacobian: ufl.Form | None = None,
        name: str = "sfem",
        options: dict | None = None,
        linear: bool = False,
        near_nullspace: bool = False,
        form_compiler_params: dict | None = None,
        operator: Callable[[PETSc.Mat], None] | None = None,
        lagged_factorization: bool = False,
        max_lagged_iterations: int = 8,
        contact=None,
        volumetric=None,
    ):
        self.volumetric = volumetric
        #: The Jacobian form's own matrix when the volumetric tangent widens A's pattern, and
        #: the entries merged into A so far.
        self._A_form: PETSc.Mat | None = None
        self._merged = np.zeros(0, dtype=np.int64)
        self._modes: PETSc.NullSpace | None = None
        if volumetric is not None and (linear or operator is not None or lagged_factorization):
            raise ValueError("volumetric terms need a nonlinear solve with an assembled Jacobian")
        if contact is not None and (linear or operator is not None or lagged_factorization):
            raise ValueError("contact terms need a nonlinear solve with an assembled Jacobian")
        self.contact = contact
        self.u = u
        self._fill_operator = operator
        self._lagged = lagged_factorization
        self._max_lagged = max_lagged_iterations
        self._refactor = True
        self._reusing = False
        self.bcs = list(bcs or [])
        self.linear = linear
        comm = u.function_space.mesh.comm
        if jacobian is None:
            jacobian = ufl.derivative(residual, u, ufl.TrialFunction(u.function_space))
        fco = form_compiler_params or {}
        self._F = dolfinx.fem.form(residual, form_compiler_params=fco, jit_params=JIT_PARAMS)
        self._J = dolfinx.fem.form(jacobian, form_compiler_params=fco, jit_params=JIT_PARAMS)
        self._b = fem_petsc.create_vector(self._F)
        self._A = fem_petsc.create_matrix(self._J)
        self._x = self._b.duplicate()
        opts = default_snes_options()
        if linear:
            opts["snes_type"] = "ksponly"
        opts.update(options or {})
        if (
            contact is not None
            and any(pair.friction > 0 for pair in contact.pairs)
            and "snes_linesearch_type" not in (options or {})
        ):
            # the regularised friction law is stiff where the slip is small: full Newton steps
            # can cycle there (measured on a dragged block); backtracking settles it
            opts["snes_linesearch_type"] = "bt"
        if lagged_factorization and opts.get("ksp_type") in ("preonly", "cg"):
            # A stale factorization applied once (preonly) would silently give a wrong answer,
            # and the drifting operator need not be symmetric (cg): iterate with GMRES.
            opts["ksp_type"] = "gmres"
            opts.setdefault("ksp_rtol", 1e-12)
        if volumetric is not None and opts.get("ksp_type") == "cg":
            raise ValueError("volumetric terms: the Jacobian is not symmetric (Dirichlet rows)")
        self._near_nullspace = near_nullspace or opts.get("pc_type") == "gamg"
        self._operator_changed = True
        self.stats = SolveStats()
        self.prefix = unique_prefix(name)

        self.snes = PETSc.SNES().create(comm)
        self.snes.setOptionsPrefix(self.prefix)
        self.snes.setFunction(self._residual, self._b)
        self._P = fem_petsc.create_matrix(self._J) if lagged_factorization else self._A
        if self._near_nullspace:  # AMG reads the rigid-body modes from the preconditioner matrix
            modes = rigid_body_modes(u.function_space)
            self._A.setNearNullSpace(modes)
            self._P.setNearNullSpace(modes)
            self._modes = modes
        self.snes.setJacobian(self._jacobian, self._A, self._P)
        set_from_options(self.snes, opts)

    # -- PETSc callbacks -------------------------------------------------------------------
    def _copy_in(self, x: PETSc.Vec) -> None:
        x.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
        x.copy(self.u.vector)
        self.u.vector.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)

    def _residual(self, snes: PETSc.SNES, x: PETSc.Vec, b: PETSc.Vec) -> None:
        self._copy_in(x)
        if self.volumetric is not None:
            self.volumetric.update()
        with b.localForm() as b_local:
            b_local.set(0.0)
        fem_petsc.assemble_vector(b, self._F)
        if self.volumetric is None:
            fem_petsc.apply_lifting(b, [self._J], bcs=[self.bcs], x0=[x], scale=-1.0)
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        if self.contact is not None:
            self.contact.add_residual(b)
        fem_petsc.set_bc(b, self.bcs, x, -1.0)

    def _jacobian(self, snes: PETSc.SNES, x: PETSc.Vec, A: PETSc.Mat, P: PETSc.Mat) -> None:
        if self.linear and not self._operator_changed:
            return  # unchanged matrix state: PETSc keeps the factorization
        self._copy_in(x)
        if self._fill_operator is not None:
            if not A.assembled:  # give the matrix its full pattern once
                fem_petsc.assemble_matrix(A, self._J, bcs=self.bcs)
                A.assemble()
            self._fill_operator(A)
        else:
            self._assemble_form_jacobian(A)
        self._operator_changed = False
        refactor = self._refactor or not self._lagged
        # Lagged: the preconditioner matrix P is a separate copy, updated only to refactor;
        # PETSc re-factorizes only when P's state changes.
        if self._lagged and refactor:
            if not P.assembled:  # give P its full pattern once
                fem_petsc.assemble_matrix(P, self._J, bcs=self.bcs)
                P.assemble()
            A.copy(P, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
        self._reusing = not refactor
        if refactor:
            self.stats.factorizations += 1
            self._refactor = False

    def _assemble_form_jacobian(self, A: PETSc.Mat) -> None:
        """A = the Jacobian form at u, with the contact's and the volumetric terms' tangents."""
        vol = self.volumetric
        if vol is not None:
            vol.update()  # the form holds the pressure: at this x
        # a volumetric tangent that couples cells (P1) widens A's pattern: the form is then
        # assembled into a matrix of its own and merged into A with it
        widens = vol is not None and not vol.cell_local
        if widens and self._A_form is None:
            self._A_form = fem_petsc.create_matrix(self._J)
        target = self._A_form if widens else A
        target.zeroEntries()
        fem_petsc.assemble_matrix(target, self._J, bcs=self.bcs if vol is None else [])
        target.assemble()
        if self.contact is not None:
            self.contact.add_jacobian(target)
        if vol is None:
            return
        if widens:
            from shoulder_fem.engine.contact import add_to_pattern

            if not A.assembled:
                A.assemble()  # no entries yet: the first merges give it its pattern
            A.zeroEntries()
            comm = A.getComm().tompi4py()
            for term in (target, vol.tangent_matrix()):  # widened only by entries never merged
                self._merged = add_to_pattern(A, term, self._merged, comm)
            if self._modes is not None:  # a widened matrix has lost it
                A.setNearNullSpace(self._modes)
        else:
            vol.add_tangent(A)
        identity_rows(A, self.bcs, self.u.function_space)

    # -- public API ------------------------------------------------------------------------
    def operator_changed(self) -> None:
        """Tell a ``linear`` solver that its operator changed (next solve re-assembles)."""
        self._operator_changed = True

    def assemble_jacobian(self) -> PETSc.Mat:
        """A new matrix: the Jacobian form assembled now, with the Dirichlet rows (collective)."""
        if self.volumetric is not None:
            raise ValueError("assemble_jacobian: the volumetric terms' tangent is not in the form")
        A = fem_petsc.assemble_matrix(self._J, bcs=self.bcs)
        A.assemble()
        return A

    def solve(self, step: str = "") -> int:
        """Solve from the current ``u``; return the Newton iteration count.

        Raises:
            ConvergenceError: the SNES did not converge (``u`` then holds the last iterate;
                callers restore their own state).
        """
        self.u.vector.copy(self._x)
        self.snes.solve(None, self._x)
        ksp = self.snes.getKSP()
        if self._lagged and ksp.getConvergedReason() <= 0 and self._reusing:
            # The lagged factorization was not good enough: factorize this operator, retry.
            logger.info(
                "%s: lagged factorization failed (%s), re-factorizing",
                self.prefix,
                ksp.getConvergedReason(),
            )
            self._refactor, self._operator_changed = True, True
            self.u.vector.copy(self._x)
            self.snes.solve(None, self._x)
        krylov = ksp.getIterationNumber()
        self.stats.krylov_iterations += krylov
        if self._lagged and krylov > self._max_lagged:
            self._refactor = True  # next operator change gets a fresh factorization
        reason = self.snes.getConvergedReason()
        if self.linear and ksp.getConvergedReason() <= 0:
            reason = PETSc.SNES.ConvergedReason.DIVERGED_LINEAR_SOLVE
        its = self.snes.getIterationNumber()
        self.stats.solves += 1
        self.stats.newton_iterations += its
        self.stats.linear_solves += max(its, 1) if self.linear else its
        self.stats.history.append(its)
        if reason <= 0 or not np.isfinite(self.snes.getFunctionNorm()):
            raise ConvergenceError(step, failure_reason(reason, ksp), its, self.prefix)
        self._copy_in(self._x)
        return its

    def residual_norm(self) -> float:
        """The residual norm at the end of the last solve (N for force residuals)."""
        return float(self.snes.getFunctionNorm())

    def destroy(self) -> None:
        """Free the PETSc objects."""
        for obj in (self.snes, self._A, self._b, self._x, self._A_form):
            if obj is not None:
                obj.destroy()
        if self._P is not self._A:
            self._P.destroy()


def reason_name(reason: int, kind=PETSc.SNES) -> str:
    """The name and number of a SNES (or ``kind``) converged reason: ``DIVERGED_MAX_IT (-5)``."""
    names = [n for n, v in vars(kind.ConvergedReason).items() if v == reason]
    return f"{names[0] if names else 'UNKNOWN'} ({reason})"


def failure_reason(reason: int, ksp: PETSc.KSP) -> str:
    """A failed SNES's reason; for a failed linear solve, with the KSP's reason and iterations.

    E.g. ``DIVERGED_LINEAR_SOLVE (-3) (KSP DIVERGED_MAX_IT (-3) after 2 iterations)``.
    """
    why = reason_name(reason)
    if reason == PETSc.SNES.ConvergedReason.DIVERGED_LINEAR_SOLVE:
        ksp_reason = reason_name(ksp.getConvergedReason(), PETSc.KSP)
        why += f" (KSP {ksp_reason} after {ksp.getIterationNumber()} iterations)"
    return why


def time_grid(end_time: float, time_step: float, outputs: int) -> tuple[np.ndarray, np.ndarray]:
    """Step times and snapshot times of a run (s).

    Returns the uniform times 0 … ``end_time`` at about ``time_step``, and ``outputs`` + 1 of
    them (first and last included) for field snapshots.
    """
    n_steps = max(1, int(round(end_time / time_step)))
    times = np.linspace(0.0, end_time, n_steps + 1)
    chosen = np.unique(np.round(np.linspace(0, n_steps, min(outputs, n_steps) + 1)).astype(int))
    return times, times[chosen]


@dataclass
class StepperStats:
    """What a :func:`march` loop did."""

    steps: int = 0
    cutbacks: int = 0


def march(
    times: np.ndarray,
    advance: Callable[[float, float], None],
    save: Callable[[], object],
    restore: Callable[[object], None],
    on_step: Callable[[float], None] | None = None,
    max_cutbacks: int = 6,
    stats: StepperStats | None = None,
) -> StepperStats:
    """Step through ``times`` (increasing), cutting a failing interval back by halves.

    ``advance(t0, t1)`` takes the state from ``t0`` to ``t1`` and raises
    :class:`ConvergenceError` on failure; ``save()`` returns a snapshot of the state and
    ``restore(snapshot)`` puts it back. A failing interval is split in two, recursively, up to
    ``max_cutbacks`` levels; beyond that the last :class:`ConvergenceError` is re-raised (the
    states of the completed times stay as they were reported through ``on_step``).
    ``on_step(t)`` is called after each time of ``times`` is reached.
    """
    stats = stats or StepperStats()
    with Progress(times[0], times[-1], "step", "") as progress:
        for t0, t1 in zip(times[:-1], times[1:], strict=True):
            _advance_with_cutback(t0, t1, advance, save, restore, max_cutbacks, stats, depth=0)
            if on_step is not None:
                on_step(t1)
            progress.to(t1)
    return stats


def _advance_with_cutback(t0, t1, advance, save, restore, max_cutbacks, stats, depth):
    snapshot = save()
    try:
        advance(t0, t1)
        stats.steps += 1
        return
    except ConvergenceError as err:
        restore(snapshot)
        if depth >= max_cutbacks:
            raise ConvergenceError(
                f"{err.step} (after {depth} cut-back(s) to dt={t1 - t0:.3g})",
                err.reason,
                err.iterations,
                err.prefix,
            ) from err
        stats.cutbacks += 1
        logger.info("step %s cut back to dt=%.3g", err.step, (t1 - t0) / 2)
        logger.debug("step %s: %s", err.step, err.reason)
    tm = 0.5 * (t0 + t1)
    _advance_with_cutback(t0, tm, advance, save, restore, max_cutbacks, stats, depth + 1)
    _advance_with_cutback(tm, t1, advance, save, restore, max_cutbacks, stats, depth + 1)
