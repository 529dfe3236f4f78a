"""The reduced nonlinear problem of a :class:`RigidSystem`: its residual and Jacobian.

Maps a reduced vector to the state (bodies' motions, FE displacement) and back, and evaluates
``r = Pᵀ F + r_rigid`` and ``J = Pᵀ K P + (rigid tangent)`` there: the SNES callbacks, apart
from the driver that runs the SNES and from the layout and terms they combine.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from shoulder_fem.engine.rigid_system.bodies import RigidBody, Tie
from shoulder_fem.engine.rigid_system.control import TravelControl, set_control_rows
from shoulder_fem.engine.rigid_system.deformable import DeformablePart
from shoulder_fem.engine.rigid_system.dynamics import StepState
from shoulder_fem.engine.rigid_system.layout import ReducedLayout
from shoulder_fem.engine.rigid_system.terms import (
    RigidTerms,
    SpringEnd,
    end_states,
    external_loads,
    rigid_terms,
    spring_terms,
    tie_loads,
)
from shoulder_fem.engine.so3 import exp_so3, log_so3
from shoulder_fem.engine.solver import SolveStats
from shoulder_fem.engine.sparse import with_entries
from shoulder_fem.engine.springs import Spring
from shoulder_fem.engine.subset_add import SubsetAdd

__all__ = [
    "STALE_FRACTION",
    "ContactProduct",
    "ReducedProblem",
    "RigidSolveStats",
    "jacobian_is_stale",
    "rebuild_jacobian",
    "timed",
]


@contextlib.contextmanager
def timed(stats: SolveStats, name: str) -> Iterator[None]:
    """Add the wall time of the enclosed block to ``stats.<name>`` (s), even if it raises."""
    t0 = time.perf_counter()
    try:
        yield
    finally:
        setattr(stats, name, getattr(stats, name) + time.perf_counter() - t0)


#: J is rebuilt between solves when this fraction of it is stale (:func:`rebuild_jacobian`).
STALE_FRACTION = 0.05


@contextlib.contextmanager
def ptap_algorithm(comm: MPI.Comm) -> Iterator[None]:
    """Products ``K.PtAP(P)`` created inside use the fastest numeric algorithm measured.

    Serial (SeqAIJ), PETSc's ``rap`` (Pᵀ formed once, then R A P): the numeric product of
    the shoulder's part 1 at ``paper`` (K 25k rows, 1.6M nonzeros, P 15.9k columns) takes
    0.009-0.012 s against 0.12-0.13 s with the default ``scalable``, equal to the last bit;
    it is chosen when the product is created and kept by every refill. MPIAIJ keeps PETSc's
    default (``rap`` does not exist there).
    """
    if comm.size > 1:
        yield
        return
    opts = PETSc.Options()
    opts["matptap_via"] = "rap"
    try:
        yield
    finally:
        opts.delValue("matptap_via")


@dataclass
class RigidSolveStats(SolveStats):
    """:class:`SolveStats` plus the residual-norm history of every solve and where the time went.

    Wall seconds of this rank: ``snes_s`` in the Newton solves in all, ``residual_s`` and
    ``jacobian_s`` in their residual and Jacobian evaluations (contact included); the rest of
    ``snes_s`` is the linear solves (factorizations). Within ``jacobian_s``: ``fe_assembly_s``
    (the FE residual and matrix) and ``reduction_s`` (the products Pᵀ K P of the FE and contact
    matrices, a P1 pressure's (B P)ᵀ D (B P) with B's assembly, and their sums into J).
    """

    residual_histories: list[list[float]] = field(default_factory=list)
    snes_s: float = 0.0
    #: Newton steps shortened because their trial state was not admissible, and the halvings
    #: (:class:`~.guard.TrialGuard`).
    shortened_steps: int = 0
    step_halvings: int = 0
    #: Times J was rebuilt without its stale contact entries (:func:`rebuild_jacobian`).
    pattern_rebuilds: int = 0
    residual_s: float = 0.0
    jacobian_s: float = 0.0
    fe_assembly_s: float = 0.0
    reduction_s: float = 0.0


class ContactProduct:
    """The contact tangent's Pᵀ K_c P added to a Jacobian.

    K_c and the product are reused (refilled; numeric product only) while K_c's pattern holds.
    """

    def __init__(self, comm) -> None:
        self.comm = comm
        self.K: PETSc.Mat | None = None
        self.C: PETSc.Mat | None = None
        #: The entries merged into the Jacobian's pattern so far (:func:`add_to_pattern`).
        self.keys = np.zeros(0, dtype=np.int64)
        self.sum = SubsetAdd()  # J += C while both patterns hold

    def add(
        self, J: PETSc.Mat, fe: DeformablePart, P: PETSc.Mat, stats: SolveStats, tangent=None
    ) -> None:
        """J += Pᵀ K_c P at the current state (collective).

        K_c: ``tangent(last)`` -- the last matrix refilled, or a new one -- or, by default,
        ``fe``'s contact tangent.
        """
        from shoulder_fem.engine.contact import add_to_pattern

        K = (tangent or fe.contact_tangent)(self.K)
        with timed(stats, "reduction_s"):
            if K is self.K:  # the last one's pattern: so is the product's
                K.PtAP(P, self.C)
                self.sum(J, self.C)
                return
            self.destroy()
            with ptap_algorithm(self.comm):
                self.K, self.C = K, K.PtAP(P)
            self.keys = add_to_pattern(J, self.C, self.keys, self.comm, add=self.sum)

    def destroy(self) -> None:
        """Free the matrices."""
        for obj in (self.K, self.C):
            if obj is not None:
                obj.destroy()
        self.K = self.C = None


class VolumetricProduct:
    """The condensed P1 pressure's tangent Pᵀ Bᵀ D B P added to a Jacobian.

    Formed by the :class:`~shoulder_fem.engine.mean_dilatation.MeanDilatation` as
    (B P)ᵀ D (B P) (:meth:`~.MeanDilatation.reduced_tangent`, which owns it): the same matrix
    from call to call, merged into J's pattern once, then summed by the compiled walk.
    """

    def __init__(self, comm) -> None:
        self.comm = comm
        self.C: PETSc.Mat | None = None
        #: The entries of C beyond the FE product's (:func:`jacobian_is_stale`), once counted.
        self.extra: int | None = None
        self.sum = SubsetAdd()

    def add(self, J: PETSc.Mat, vol, P: PETSc.Mat, stats: SolveStats) -> None:
        """J += Pᵀ Bᵀ D B P at the state of ``vol``'s last update (collective).

        C's pattern is fixed: J is widened to hold it the first time only (and by
        :meth:`merge` after J is rebuilt), with no list of the entries merged (at ``medium``
        such lists of C's 7.8M entries and their union held 390 MB).
        """
        with timed(stats, "reduction_s"):  # B's assembly included
            C = vol.reduced_tangent(P)
            if C is self.C:
                self.sum(J, C)
                return
            self.C = C
            self.merge(J)

    def merge(self, J: PETSc.Mat) -> None:
        """J += C, J's pattern widened to hold C's (one merge; J keeps its near-nullspace)."""
        from shoulder_fem.engine.contact.jacobian import widen

        widen(J, self.C)

    def destroy(self) -> None:
        """Let go of C (the MeanDilatation frees it)."""
        self.C = None


class ReducedProblem:
    """Residual and Jacobian of the reduced unknowns (see :class:`ReducedLayout`).

    Owns each body's rotation as ``R = exp(hat φ) R₀``: at the end of every converged solve
    (:meth:`commit`) ``R₀ ← R`` and ``φ ← 0``, so rotations are composed on SO(3) and angles
    are never added across solves (with ``linear_ties`` φ is the total rotation vector and R₀
    stays the identity). Prescribed bodies take their six DOFs from
    :meth:`RigidBody.prescribe`; their rows and columns of the Jacobian become the identity and
    their residual rows zero (Dirichlet-like).

    Args:
        bodies: The rigid bodies (updated in place from the reduced vector).
        springs: The springs; ``ends`` their ends resolved to ``layout`` (2 per spring).
        ties: Which surface follows which body.
        layout: The reduced layout.
        ends: The springs' ends (:meth:`ReducedLayout.spring_end`).
        fe: The deformable body, or ``None``.
        step_state: The dynamic step being solved (shared with the driver).
        stats: Where the callbacks' wall times and factorizations are counted.
        linear_ties: Small-rotation kinematics of the tied nodes (static only).
        near_nullspace: Attach the system's six rigid motions to J as its near-nullspace
            (:meth:`ReducedLayout.rigid_modes`), for an algebraic multigrid preconditioner.
    """

    def __init__(
        self,
        bodies: Sequence[RigidBody],
        springs: Sequence[Spring],
        ties: Sequence[Tie],
        layout: ReducedLayout,
        ends: Sequence[SpringEnd],
        fe: DeformablePart | None,
        step_state: StepState,
        stats: RigidSolveStats,
        linear_ties: bool,
        near_nullspace: bool = False,
    ) -> None:
        self.bodies, self.springs, self.ties = bodies, springs, ties
        self.layout, self.ends, self.fe = layout, list(ends), fe
        self.step_state, self.stats, self.linear_ties = step_state, stats, linear_ties
        self.comm = layout.comm
        # the products of the contact's tangent and of a P1 pressure's volumetric tangent
        self.contact, self.volumetric = ContactProduct(self.comm), VolumetricProduct(self.comm)
        #: The bordered LU of the Newton steps and J's operator (:mod:`~.uncondensed`), or None.
        self.uncondensed = None
        self.R0 = [b.rotation.copy() for b in bodies]
        self.phi = np.zeros((len(bodies), 3))
        self.x = PETSc.Vec().createMPI((layout.n_local, layout.n_global), comm=self.comm)
        self.r = self.x.duplicate()
        #: The reduced vector at which the last residual assembled F (see :meth:`_f_current`),
        #: with the number of F assemblies then; ``None`` when unknown.
        self._f_at: tuple[np.ndarray, int] | None = None
        #: The prolongation P and the product Pᵀ K P (FE only).
        self.P: PETSc.Mat | None = None
        self.C: PETSc.Mat | None = None
        self._fe_sum = SubsetAdd()  # J += C while both patterns hold
        if fe is not None:
            self.P = layout.create_prolongation(bodies, self.phi, linear_ties)
        #: J's near-nullspace (attached to every J built), or None.
        self.near_nullspace: PETSc.NullSpace | None = None
        if near_nullspace:
            self.near_nullspace = PETSc.NullSpace().create(
                vectors=layout.rigid_modes(bodies, self.x), comm=self.comm
            )
        self.J = self._create_jacobian()
        self._nonzeros = None  # J's nonzeros at the last factorization's analysis
        #: The travel control (:meth:`set_control`), or None.
        self.control: TravelControl | None = None
        self._control_work: tuple[PETSc.Vec, PETSc.Vec] | None = None

    def set_control(self, control: TravelControl) -> None:
        """Solve for ``control``'s travel: its body's translation rows become the control's."""
        self.control = control
        if self.P is not None and self._control_work is None:
            self._control_work = self.P.createVecs()  # (reduced, FE)

    def _controlled(self, b: int) -> bool:
        return self.control is not None and self.control.body == b

    def dirichlet_rows(self) -> np.ndarray:
        """The prescribed DOFs whose rows and columns are the identity.

        The controlled body's translation is not one of them (its rows are the control's).
        """
        rows = self.layout.prescribed_rows(self.bodies)
        if self.control is None or len(rows) == 0:
            return rows
        free = self.layout.rigid_cols(self.control.body)[:3]
        return rows[~np.isin(rows, free)]

    # ---- state <-> reduced vector -----------------------------------------------------------
    def x_from_state(self, targets: bool = True) -> PETSc.Vec:
        """Reduced vector of the current state (φ = 0, or the prescribed increment).

        During a dynamic step the inertial bodies that carry no tied surface start from the
        predictor θ = h Ω_n, x_G = x_n + h v_n + h² F_n/(2m); a body with tied nodes starts
        from the state at t_n (moving its tied nodes alone would distort the elements next to
        them). ``targets=False``: the current state only.
        """
        tied = {t.body for t in self.ties}
        lay, steps = self.layout, self.step_state
        x = self.x
        arr = x.array
        if self.fe is not None:
            arr[: lay.n_free_local] = self.fe.free_values()
        if self.comm.rank == 0:
            for b, body in enumerate(self.bodies):
                t, phi = body.translation, np.zeros(3)
                if self.linear_ties:
                    phi = self.phi[b].copy()  # the total rotation vector (R0 = I)
                if targets and body.prescribed and body.target is not None:
                    if not self._controlled(b):  # a controlled body's travel is an unknown
                        t = body.target[0]
                    phi = log_so3(body.target[1] @ self.R0[b].T)
                elif (
                    targets
                    and steps.dt is not None
                    and b in steps.inertial(self.bodies)
                    and body.name not in tied
                ):
                    t, phi = steps.predictor(b, body)
                k = lay.n_free_local + 6 * b
                arr[k : k + 3], arr[k + 3 : k + 6] = t, phi
        return x

    def update_state(self, x: PETSc.Vec) -> None:
        """Bodies and the FE displacement from the reduced vector ``x`` (collective)."""
        arr = x.array_r
        nb = len(self.bodies)
        n_free = self.layout.n_free_local
        rigid = arr[n_free:].copy() if self.comm.rank == 0 else None
        rigid = self.comm.bcast(rigid, root=0).reshape(nb, 6) if nb else np.zeros((0, 6))
        for b, body in enumerate(self.bodies):
            body.translation = rigid[b, :3].copy()
            self.phi[b] = rigid[b, 3:]
            body.rotation = exp_so3(self.phi[b]) @ self.R0[b]
        if self.fe is not None:
            self.fe.set_displacement(arr[:n_free], self.bodies, self.phi, self.linear_ties)

    def commit(self) -> None:
        """Take the current rotations as the new R₀ (φ ← 0), unless ``linear_ties``."""
        self._f_at = None
        if self.linear_ties:
            return  # φ is the total rotation vector, R0 stays the identity
        for b, body in enumerate(self.bodies):
            self.R0[b] = body.rotation.copy()
            self.phi[b] = 0.0

    def set_rotation(self, b: int, R: np.ndarray) -> None:
        """Body b's rotation is ``R`` now: R₀ ← R, φ ← 0."""
        self.R0[b], self.phi[b] = R.copy(), 0.0
        self._f_at = None

    # ---- loads at the current state ----------------------------------------------------------
    def end_states(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """(current position m, lever m) of every spring end (collective)."""
        u = None if self.fe is None else self.fe.u
        return end_states(self.ends, self.bodies, u, self.comm)

    def tie_loads(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per body Σ f_i (N), Σ r_i × f_i (N·m), Σ hat(f_i) hat(r_i) of the assembled F."""
        F = None if self.fe is None else self.fe.F
        return tie_loads(self.bodies, self.layout.X_tied, self.layout.tied_owned, F, self.comm)

    def external_loads(self) -> np.ndarray:
        """Per body, the total external force F (N) and moment about G (N·m) (collective).

        External: ties (minus the FE residual at the tied nodes), springs and applied loads,
        at the current state (the FE residual is assembled here).
        """
        nb = len(self.bodies)
        if self.fe is not None:
            self.fe.assemble_residual()
        tie_f, tie_m, _ = self.tie_loads()
        res, _, _, _ = spring_terms(self.springs, self.ends, self.end_states(), nb)
        return external_loads(self.bodies, tie_f, tie_m, res)

    def rigid_terms(self, with_tangent: bool) -> RigidTerms:
        """The rigid rows at the current state (:func:`terms.rigid_terms`; F assembled)."""
        nb = len(self.bodies)
        springs = spring_terms(self.springs, self.ends, self.end_states(), nb)
        zeros = np.zeros((nb, 3))
        if with_tangent and not self.linear_ties:
            _, tie_m, G = self.tie_loads()
        else:
            tie_m, G = zeros, np.zeros((nb, 3, 3))
        steps, inertia = self.step_state, {}
        if steps.dt is not None:
            for b in steps.inertial(self.bodies):
                inertia[b] = steps.rows(b, self.bodies[b], self.phi[b])
        return rigid_terms(self.bodies, springs, tie_m, G, inertia, self.phi, self.linear_ties)

    # ---- SNES callbacks -------------------------------------------------------------------
    def residual(self, snes: PETSc.SNES, x: PETSc.Vec, r: PETSc.Vec) -> None:
        """SNES residual: r = Pᵀ F + r_rigid at ``x`` (N; N·m); zero rows of prescribed bodies."""
        with timed(self.stats, "residual_s"):
            self._residual(x, r)

    def _residual(self, x: PETSc.Vec, r: PETSc.Vec) -> None:
        self.update_state(x)
        lay = self.layout
        if self.fe is not None:
            self.fe.assemble_residual()
            self._f_at = (x.array_r.copy(), self.fe.residual_assemblies)
            lay.fill_prolongation(self.P, self.bodies, self.phi, self.linear_ties)
            self.P.multTranspose(self.fe.F, r)
        else:
            r.set(0.0)
        terms = self.rigid_terms(with_tangent=False)
        control = None
        if self.control is not None:
            value = self.control.measure(False).value
            control = self.control.residual(value, self.bodies[self.control.body].translation)
        # Every rank touches the array (PETSc bumps the vector's state, which must stay the same
        # on all ranks or cached norms differ and the ranks fall out of step).
        arr = r.array
        for i, vec in terms.node_residual:
            _, _, _, owner, _, col0 = self.ends[i]
            if self.comm.rank == owner:
                arr[col0 - lay.start : col0 - lay.start + 3] += vec
        if self.comm.rank == 0:
            arr[lay.n_free_local :] += terms.residual
            for b, body in enumerate(self.bodies):
                if body.prescribed:
                    k = lay.n_free_local + 6 * b
                    arr[k : k + 6] = 0.0
                    if self._controlled(b):
                        arr[k : k + 3] = control

    def jacobian(self, snes: PETSc.SNES, x: PETSc.Vec, J: PETSc.Mat, P: PETSc.Mat) -> None:
        """SNES Jacobian: Pᵀ K P + rigid tangent at ``x`` into :attr:`J` (see ``operator``)."""
        with timed(self.stats, "jacobian_s"):
            self._jacobian(x, self.J)
        nonzeros = self.J.getInfo(PETSc.Mat.InfoType.GLOBAL_SUM)["nz_used"]
        if snes is not None and nonzeros != self._nonzeros:
            # A widened pattern (new contact entries, the control row) must be analysed
            # afresh: measured under mpirun -n 2, MUMPS reused the old analysis and corrupted
            # memory. Growth is rare; each one costs one symbolic analysis.
            snes.getKSP().getPC().reset()
        self._nonzeros = nonzeros

    def _jacobian(self, x: PETSc.Vec, J: PETSc.Mat) -> None:
        f_current = self.fe is not None and self._f_current(x)
        self.update_state(x)
        J.zeroEntries()
        if self.fe is not None:
            self._add_fe_tangent(J, f_current)
        terms = self.rigid_terms(with_tangent=True)
        finish_jacobian(self, J, terms)
        if self.uncondensed is not None:
            self.uncondensed.refresh()
        self.stats.factorizations += 1

    def _f_current(self, x: PETSc.Vec) -> bool:
        """Whether the residual callback's F at this same ``x`` and R₀ is F's last (collective)."""
        at = self._f_at
        same = at is not None and at[1] == self.fe.residual_assemblies
        return bool(self.comm.allreduce(same and np.array_equal(at[0], x.array_r), op=MPI.LAND))

    def _add_fe_tangent(self, J: PETSc.Mat, f_current: bool) -> None:
        """Assemble F (unless ``f_current``) and K, add Pᵀ K P and the contact's Pᵀ K_c P."""
        with timed(self.stats, "fe_assembly_s"):
            if not f_current:
                self.fe.assemble_residual()
            self.fe.assemble_tangent()
        with timed(self.stats, "reduction_s"):
            self.layout.fill_prolongation(self.P, self.bodies, self.phi, self.linear_ties)
            self.fe.K.PtAP(self.P, self.C)
            self._fe_sum(J, self.C)
        if self.fe.contact is not None:
            self.contact.add(J, self.fe, self.P, self.stats)
        if self.uncondensed is None:  # else applied by the operator, never assembled
            add_volumetric_tangent(self, J)

    # ---- the Jacobian's pattern ---------------------------------------------------------------
    def _create_jacobian(self) -> PETSc.Mat:
        if self.fe is not None:
            self.update_state(self.x_from_state())
            self.fe.assemble_tangent()
            with ptap_algorithm(self.comm):
                self.C = self.fe.K.PtAP(self.P)
        J = jacobian_pattern(self)
        J.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, True)
        return J

    def reset_analysis(self) -> None:
        """Let the next Jacobian's factorization be analysed afresh (J was replaced)."""
        self._nonzeros = None

    def destroy(self) -> None:
        """Free the PETSc objects."""
        objs = [self.J, self.x, self.r]
        if self.near_nullspace is not None:
            objs.append(self.near_nullspace)
        if self.fe is not None:
            objs += [self.P, self.C]
        for obj in (*objs, self.contact, self.volumetric, self.uncondensed):
            if obj is not None:
                obj.destroy()


def finish_jacobian(problem: ReducedProblem, J: PETSc.Mat, terms: RigidTerms) -> None:
    """J += the rigid bodies' and springs' tangents; then the special rows (collective).

    The prescribed DOFs' rows and columns become the identity, the controlled rows the
    control's.
    """
    if problem.comm.rank == 0 and len(problem.bodies):
        rigid = problem.layout.rigid_range(len(problem.bodies))
        J.setValues(rigid, rigid, terms.tangent.ravel(), addv=PETSc.InsertMode.ADD_VALUES)
    problem.layout.add_node_blocks(J, problem.ends, terms.node_tangent, terms.T)
    J.assemble()
    J.zeroRowsColumns(problem.dirichlet_rows(), 1.0)
    if problem.control is not None:
        work = problem._control_work
        set_control_rows(J, problem.control, problem.layout, problem.P, work, problem.phi)


def add_volumetric_tangent(problem: ReducedProblem, J: PETSc.Mat) -> None:
    """J += Pᵀ K_v P for condensed volumetric terms that couple cells (P1 pressure; collective).

    Merged into J's pattern as the contact's is (P0 terms are in the FE tangent already).
    """
    vol = problem.fe.volumetric
    if vol is not None and not vol.cell_local:
        problem.volumetric.add(J, vol, problem.P, problem.stats)


def jacobian_is_stale(problem: ReducedProblem) -> bool:
    """Whether more than :data:`STALE_FRACTION` of ``problem.J``'s entries are of contacts gone."""
    if problem.fe is None or problem.contact.C is None:
        return False
    info = PETSc.Mat.InfoType.GLOBAL_SUM
    needed = problem.C.getInfo(info)["nz_used"] + problem.contact.C.getInfo(info)["nz_used"]
    vol = problem.volumetric
    if vol.C is not None:  # a P1 pressure's couplings beyond the FE product's (fixed)
        if vol.extra is None:
            union = problem.C.duplicate(copy=True)
            union.axpy(1.0, vol.C, structure=PETSc.Mat.Structure.DIFFERENT_NONZERO_PATTERN)
            vol.extra = union.getInfo(info)["nz_used"] - problem.C.getInfo(info)["nz_used"]
            union.destroy()
        needed += vol.extra
    return problem.J.getInfo(info)["nz_used"] > (1.0 + STALE_FRACTION) * needed


def rebuild_jacobian(problem: ReducedProblem) -> None:
    """Rebuild ``problem.J`` without the entries of contacts gone (collective; between solves).

    J's pattern only grows within a solve (every new contact entry is merged); over a long
    run its stale entries cost the LU fill and memory (measured at ``paper``, part 1: J from
    0.99M nonzeros at 0 deg to 1.33M at 50 deg, MUMPS from 50 to 98 MB; rebuilt, 1.09M and
    64 MB at 50 deg). When more than :data:`STALE_FRACTION` of J's entries are neither the FE
    product's nor the current contact product's (:func:`jacobian_is_stale`), J is rebuilt on
    those two patterns (the control row and new contact entries are merged again by the next
    Jacobian, whose factorization is then analysed afresh).

    The caller frees the old factorization first and gives the SNES the new J
    (:meth:`RigidSystem._run_snes`): the old J and its factors are not held beside the new.
    """
    from shoulder_fem.engine.contact import add_to_pattern

    problem.J.destroy()
    problem.J = jacobian_pattern(problem)
    problem.stats.pattern_rebuilds += 1
    empty = np.zeros(0, np.int64)
    problem.contact.keys = add_to_pattern(problem.J, problem.contact.C, empty, problem.comm)
    if problem.volumetric.C is not None:
        problem.volumetric.merge(problem.J)
    problem.J.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, True)
    problem.reset_analysis()


def jacobian_pattern(problem: ReducedProblem) -> PETSc.Mat:
    """A new J of ``problem``: the FE product's pattern (if any), the rigid and spring blocks."""
    comm, nb, lay = problem.comm, len(problem.bodies), problem.layout
    rigid = lay.rigid_range(nb)
    if problem.fe is not None:
        # the bodies' block (absent from C between bodies no element joins) preallocated
        J = with_entries(problem.C, *((rigid, rigid) if comm.rank == 0 else (rigid[:0],) * 2))
        J.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, False)
    else:
        J = PETSc.Mat().createAIJ(((lay.n_local, lay.n_global),) * 2, comm=comm)
        J.setPreallocationNNZ((6 * nb, 0))
        if comm.rank == 0 and nb:
            J.setValues(rigid, rigid, np.zeros((6 * nb, 6 * nb)), addv=PETSc.InsertMode.ADD)
    if any(e.kind == "node" for e in problem.ends):
        terms = problem.rigid_terms(with_tangent=True)  # the blocks' positions
        zero = [(i, k, 0.0 * block) for i, k, block in terms.node_tangent]
        problem.layout.add_node_blocks(J, problem.ends, zero, terms.T)
    J.assemble()
    if problem.near_nullspace is not None:
        J.setNearNullSpace(problem.near_nullspace)
    return J
