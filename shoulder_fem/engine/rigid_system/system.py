"""A system of a deformable body, rigid bodies, ties, springs and loads, solved by one SNES.

:class:`RigidSystem` is the public face of the package: it builds the layout, the FE part and the
reduced problem, runs the SNES for static solves and dynamic steps, and reports the state
(balances, spring forces, reactions, snapshots).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Mapping, Sequence

import dolfinx
import numpy as np
import ufl
from mpi4py import MPI
from petsc4py import PETSc

from shoulder_fem.engine.rigid_system.bodies import RigidBody, Tie
from shoulder_fem.engine.rigid_system.control import ControlledSystem
from shoulder_fem.engine.rigid_system.corotation import RigidRegions
from shoulder_fem.engine.rigid_system.deformable import DeformablePart
from shoulder_fem.engine.rigid_system.dynamics import StepState
from shoulder_fem.engine.rigid_system.fields import SplitFields
from shoulder_fem.engine.rigid_system.guard import TrialGuard
from shoulder_fem.engine.rigid_system.layout import ReducedLayout, check_topology
from shoulder_fem.engine.rigid_system.offsets import OffsetTies
from shoulder_fem.engine.rigid_system.problem import (
    ReducedProblem,
    RigidSolveStats,
    jacobian_is_stale,
    rebuild_jacobian,
    timed,
)
from shoulder_fem.engine.rigid_system.reports import SystemReports
from shoulder_fem.engine.rigid_system.uncondensed import UncondensedLU, UncondensedPC, operator
from shoulder_fem.engine.solver import (
    ConvergenceError,
    default_snes_options,
    failure_reason,
    release_options,
    set_from_options,
    unique_prefix,
)
from shoulder_fem.engine.springs import Spring
from shoulder_fem.engine.stagnation import StagnationTest

logger = logging.getLogger(__name__)

__all__ = ["RigidSystem", "create_snes", "run_snes"]


def create_snes(
    problem: ReducedProblem,
    guard: TrialGuard,
    prefix: str,
    options: dict | None,
    uncondensed: bool = False,
) -> tuple[PETSc.SNES, str]:
    """A SNES on ``problem``'s residual and Jacobian, options under ``prefix``; its line search.

    ``options`` (PETSc options) go over :func:`shoulder_fem.engine.solver.default_snes_options`.
    Every Newton step passes ``guard`` (the line search's pre-check), which hands the residual
    it evaluated at the accepted trial to the line search (it is the SNES function).
    ``uncondensed``: the preconditioner is :func:`use_uncondensed`'s.
    """
    # Rotating a tied face by a finite angle makes the first Newton iterate of a nearly
    # incompressible body (linearised rotation of the free nodes) far worse than the start:
    # no divergence test on the residual growth (max_it still bounds the solve).
    opts = default_snes_options() | {"snes_divergence_tolerance": -1.0} | dict(options or {})
    snes = PETSc.SNES().create(problem.comm)
    snes.setOptionsPrefix(prefix)
    snes.setFunction(guard.residual, problem.r)
    snes.setJacobian(problem.jacobian, problem.J, problem.J)
    set_from_options(snes, opts)
    stagnation = StagnationTest()
    stagnation.track(opts)
    snes.setConvergenceTest(stagnation)
    snes.setAttr("stagnation_test", stagnation)
    snes.setLineSearchPreCheck(guard)
    snes.setConvergenceHistory(length=200, reset=True)
    if uncondensed:
        use_uncondensed(snes, problem, prefix)
    return snes, str(opts["snes_linesearch_type"])


def use_uncondensed(snes: PETSc.SNES, problem: ReducedProblem, prefix: str) -> None:
    """Make ``snes``'s preconditioner the bordered LU of :mod:`~.uncondensed`.

    Its operator becomes J₀ with the pressures' product applied (J is not assembled).

    Raises:
        ValueError: No P1 volumetric terms, or a linear solver other than ``preonly`` + LU.
    """
    vol = problem.fe.volumetric if problem.fe is not None else None
    if vol is None or vol.cell_local:
        raise ValueError(f"{prefix}: uncondensed needs condensed P1 volumetric terms")
    ksp = snes.getKSP()
    if ksp.getType() != PETSc.KSP.Type.PREONLY or ksp.getPC().getType() != PETSc.PC.Type.LU:
        raise ValueError(
            f"{prefix}: uncondensed replaces the LU of preonly + lu, not "
            f"{ksp.getType()} + {ksp.getPC().getType()}"
        )
    problem.uncondensed = lu = UncondensedLU(problem, prefix)
    pc = ksp.getPC()
    pc.setType(PETSc.PC.Type.PYTHON)
    pc.setPythonContext(UncondensedPC(lu))
    snes.setJacobian(problem.jacobian, operator(problem), problem.J)


def run_snes(snes: PETSc.SNES, x: PETSc.Vec, stats: RigidSolveStats, step: str, prefix: str) -> int:
    """Run ``snes`` from ``x`` (left at the last iterate), count it in ``stats``; its iterations.

    Raises:
        ConvergenceError: The SNES did not converge (names the step, reason, iterations).
    """
    snes.setConvergenceHistory(length=200, reset=True)
    petsc_error = None
    with timed(stats, "snes_s"):
        try:
            snes.solve(None, x)
        except PETSc.Error as err:  # e.g. MUMPS on a matrix with NaN entries
            petsc_error = f"PETSc error {err.ierr} in the solve (a failed factorization)"
        except ArithmeticError as err:  # a diverged iterate, e.g. a rotation vector of 1e80
            petsc_error = f"{type(err).__name__} in the residual or Jacobian ({err})"
    reason = snes.getConvergedReason()
    its = snes.getIterationNumber()
    history = [float(v) for v in snes.getConvergenceHistory()[0]]
    stats.solves += 1
    stats.newton_iterations += its
    stats.linear_solves += its
    stats.krylov_iterations += snes.getLinearSolveIterations()
    stats.history.append(its)
    stats.residual_histories.append(history)
    if petsc_error or reason <= 0 or not math.isfinite(snes.getFunctionNorm()):
        # A failed factorization must not be reused by the next solve (MUMPS then stops
        # with INFOG(1) = -3): the next solve factorizes afresh.
        snes.getKSP().getPC().reset()
        why = petsc_error or failure_reason(reason, snes.getKSP())
        logger.debug("%s %s: failed after %d Newton iterations %s", prefix, step, its, history)
        stagnation = snes.getAttr("stagnation_test")
        if not petsc_error and stagnation is not None:
            why += stagnation.describe()
        raise ConvergenceError(step, why, its, prefix)
    logger.debug("%s %s: %d Newton iterations %s", prefix, step, its, history)
    return its


class RigidSystem(SystemReports, ControlledSystem, OffsetTies, SplitFields):
    """A system of a deformable body, rigid bodies, ties, springs and applied loads.

    Static by default (:meth:`solve`); with ``dynamic=True`` :meth:`step` also integrates the
    bodies that have a mass in time (the scheme: :class:`dynamics.StepState`).

    Args:
        bodies: The rigid bodies (their states are updated in place by :meth:`solve` and
            :meth:`step`).
        springs: Springs between bodies and the ground (:mod:`shoulder_fem.engine.springs`).
        u: Displacement of the deformable body (m), a 3D vector Lagrange function; ``None`` for
            a system of rigid bodies and springs only.
        residual: UFL residual F(u; w) of the deformable body (N), required with ``u``.
        surfaces: Named surfaces: ``{name: (facet MeshTags, tag id)}``; cell tags name a
            region whose every node is tied (a block of cells carried by a body).
        ties: Which surface follows which body.
        fixed: Names of surfaces whose nodes are fixed (zero displacement).
        jacobian: UFL tangent of ``residual``; ``ufl.derivative`` if omitted.
        comm: Communicator (taken from ``u``'s mesh when given).
        deformable: Name of the deformable body in :attr:`Spring.body_a` / ``body_b``: such an
            end is attached to the FE node at its point (which must be a node); on a tied node
            it moves with that rigid body, on a fixed node it is a ground point.
        name: Short name; the SNES options prefix is ``<name><n>_``.
        options: PETSc options over :func:`shoulder_fem.engine.solver.default_snes_options`.
        form_compiler_params: Passed to ``dolfinx.fem.form``.
        dynamic: Enable :meth:`step`: bodies with a mass (not prescribed) carry inertia; such
            a body needs nothing to hold it. ``False`` (default): static, masses are ignored.
        time: Initial time (s) of a dynamic system (:attr:`time`).
        contact: Contact terms on ``u`` (built with no Dirichlet conditions): a contact
            surface whose nodes are tied to a rigid body moves with it and loads it.
        linear_ties: Small-rotation kinematics of the tied nodes, ``u = t + φ × (X - X_ref)``
            with φ the body's total rotation vector (``rotation = exp(hat φ)``), and no
            geometric (tie-load) terms: with a linear residual the reduced problem is then
            linear in the tied nodes (the springs keep their exact response). For a linear
            elastic body in its floating frame (decoupled part 2): finite rotations of plates
            tied to stiff bone make the residual quadratic in rotations of a mode that only
            soft springs hold, which ruins the convergence of a chord (one-factorization)
            iteration. Static only.
        admissible: Callable() -> bool: whether the current state may be a Newton trial state
            (e.g. no inverted element). Newton steps to inadmissible states, or to states with a
            non-finite residual, are halved inside the line search (:class:`~.guard.TrialGuard`).
        near_nullspace: Give the Jacobian the system's six rigid motions as its near-nullspace
            (for GAMG, e.g. :func:`shoulder_fem.engine.gamg.scaled_gamg_options`).
        rigid_regions: Stiff regions of the deformable body (per region, local node indices,
            e.g. a bone's cells' nodes) whose share of every Newton step is made
            a finite rotation (:mod:`~.corotation`); the converged states are unchanged.
        volumetric: Condensed volumetric terms of ``u`` whose residual is in ``residual``
            (:class:`~shoulder_fem.engine.mean_dilatation.MeanDilatation`).
        uncondensed: The Newton steps of a P1 ``volumetric`` by the LU of the uncondensed
            system (:mod:`~.uncondensed`); needs ``preonly`` + ``lu``.

    Raises:
        ValueError: Duplicate body names, a tie to an unknown body or surface, an empty
            surface, a spring on an unknown body, a node both tied and fixed or tied twice,
            or a free rigid body that nothing holds (static scene, or massless in a dynamic
            one) -- all before any solve.
    """

    def __init__(
        self,
        bodies: Sequence[RigidBody],
        springs: Sequence[Spring] = (),
        *,
        u: dolfinx.fem.Function | None = None,
        residual: ufl.Form | None = None,
        surfaces: Mapping[str, tuple[dolfinx.mesh.MeshTags, int]] | None = None,
        ties: Sequence[Tie] = (),
        fixed: Sequence[str] = (),
        jacobian: ufl.Form | None = None,
        comm: MPI.Comm | None = None,
        deformable: str = "deformable",
        name: str = "rigid",
        options: dict | None = None,
        form_compiler_params: dict | None = None,
        dynamic: bool = False,
        time: float = 0.0,
        contact=None,
        linear_ties: bool = False,
        admissible: Callable[[], bool] | None = None,
        near_nullspace: bool = False,
        rigid_regions: Sequence[np.ndarray] = (),
        volumetric=None,
        uncondensed: bool = False,
    ) -> None:
        self.bodies = list(bodies)
        self.linear_ties = bool(linear_ties)
        if self.linear_ties and dynamic:
            raise ValueError("RigidSystem: linear_ties is for static systems")
        if self.linear_ties and any(not np.allclose(b.rotation, np.eye(3)) for b in self.bodies):
            raise ValueError("RigidSystem: linear_ties needs bodies that start unrotated")
        #: Contact terms (:class:`shoulder_fem.engine.contact.Contact` on ``u``, built without bcs):
        #: added to the FE residual and tangent before the reduction, so that a master surface
        #: whose nodes are tied to a rigid body is a rigid contact surface.
        self.contact = contact
        self._step = StepState(dynamic=bool(dynamic))
        #: Time (s) of the current state; advanced by :meth:`step`.
        self.time = float(time)
        self.springs = list(springs)
        self.ties = list(ties)
        self.u = u
        surfaces = dict(surfaces or {})
        self.deformable = deformable if u is not None else None
        self.comm = u.function_space.mesh.comm if u is not None else (comm or MPI.COMM_WORLD)
        parts = self.bodies, self.springs, self.ties
        check_topology(*parts, surfaces, fixed, self.deformable, self.dynamic, self.comm)
        self._index = {b.name: i for i, b in enumerate(self.bodies)}
        if u is not None and residual is None:
            raise ValueError("RigidSystem: a deformable body (u) needs its residual form")
        V = u.function_space if u is not None else None
        layout = ReducedLayout(self.comm, self.bodies, self.ties, V, surfaces, fixed)
        fe_args = (u, residual, jacobian, form_compiler_params, contact, layout, volumetric)
        self._fe = DeformablePart(*fe_args) if u is not None else None
        where = self._index, self.deformable
        ends = [layout.spring_end(s, i, *where) for s in self.springs for i in (0, 1)]
        self.stats = RigidSolveStats()
        fe_parts = (self._fe, self._step, self.stats, self.linear_ties)
        self._problem = problem = ReducedProblem(
            *parts, layout, ends, *fe_parts, near_nullspace=near_nullspace
        )
        self.prefix = unique_prefix(name)
        #: The stiff regions whose Newton steps turn by finite rotations, or None.
        self.rigid_regions = (
            RigidRegions(layout, self.bodies, rigid_regions) if len(rigid_regions) else None
        )
        # every Newton step is corrected (rigid_regions), then shortened until its trial state
        # is admissible with a finite residual (guard.py)
        fix = self.rigid_regions.precheck if self.rigid_regions else None
        checks = (admissible, self.stats, self.comm)
        self._guard = TrialGuard(problem.update_state, problem.residual, *checks, correct=fix)
        snes_args = self._guard, self.prefix, options, uncondensed
        self.snes, self._linesearch = create_snes(problem, *snes_args)
        #: Whether every Newton iteration evaluates J (not a lagged, chord Jacobian): only then
        #: may J be rebuilt between solves (:func:`~.problem.rebuild_jacobian`), since a lagged
        #: factorization would meet the new matrix unfilled.
        self._fresh_jacobians = int((options or {}).get("snes_lag_jacobian", 1)) == 1

    @property
    def dynamic(self) -> bool:
        """Whether :meth:`step` integrates the bodies that have a mass (``dynamic=True``)."""
        return self._step.dynamic

    @property
    def linesearch(self) -> str:
        """The SNES line search type (``basic``, ``l2``, ``bt``, ``cp``)."""
        return self._linesearch

    @linesearch.setter
    def linesearch(self, kind: str) -> None:
        self.set_options({"snes_linesearch_type": kind})

    def set_options(self, options: Mapping[str, object]) -> None:
        """Change SNES options between solves (e.g. ``snes_max_it``, the line search type)."""
        set_from_options(self.snes, options, ksp=False)
        self.snes.getAttr("stagnation_test").track(options)
        self.snes.setLineSearchPreCheck(self._guard)  # the line search keeps its pre-check
        if "snes_linesearch_type" in options:
            self._linesearch = str(options["snes_linesearch_type"])
        if "snes_lag_jacobian" in options:
            self._fresh_jacobians = int(options["snes_lag_jacobian"]) == 1

    # ---- solves ------------------------------------------------------------------------------
    def solve(self, step: str = "") -> int:
        """Solve for the current loads and prescribed motions; return the Newton iterations.

        Static: no inertia, even in a dynamic system (whose bodies keep their velocities; the
        loads that the next :meth:`step` starts from are re-evaluated at the new state). On
        success the bodies' rotations are committed (``R₀ ← exp(hat φ) R₀``). On failure the
        state is left at the last iterate (use :meth:`snapshot` / :meth:`restore`).

        Raises:
            ConvergenceError: The SNES did not converge (names the step, reason, iterations).
        """
        self._step.dt = None
        self._step.loads = None
        self._step.last_inertia = None
        its = self._run_snes(step)
        self._problem.commit()
        return its

    def _run_snes(self, step: str) -> int:
        """Run the SNES from the current state (or predictor); leave the state at the solution."""
        if self._fresh_jacobians and jacobian_is_stale(self._problem):
            self.snes.getKSP().reset()  # frees the factorization and its hold on the old J
            rebuild_jacobian(self._problem)
            problem = self._problem
            self.snes.setJacobian(problem.jacobian, operator(problem), problem.J)
        x = self._problem.x_from_state()
        its = run_snes(self.snes, x, self.stats, step, self.prefix)
        self._problem.update_state(x)
        if self._fe is not None:
            self._fe.assemble_residual()
        return its

    def start_dynamics(self, time: float | None = None) -> None:
        """Take the current state as the initial state of the time integration (collective).

        Records the loads of the current state (ties, springs, applied ``force``/``moment``)
        that the first :meth:`step` averages with those of its end. Called by :meth:`step`
        when needed; call it explicitly to restart at ``time`` (s) after changing the state
        (velocities, :meth:`move`). The FE part should be in equilibrium with the bodies.
        """
        if not self.dynamic:
            raise ValueError(f"{self.prefix}: start_dynamics needs RigidSystem(dynamic=True)")
        if time is not None:
            self.time = float(time)
        self._problem.commit()
        if self._fe is not None:
            # Tied nodes at the bodies' current motions (a move() is applied now).
            self._problem.update_state(self._problem.x_from_state(targets=False))
        self._step.loads = self._problem.external_loads()
        self._step.last_inertia = None

    def _begin_step(self, dt: float) -> None:
        """Arm the residual and tangent of a step of ``dt`` (s) from the current state."""
        h = float(dt)
        if not self.dynamic:
            raise ValueError(
                f"{self.prefix}: step() needs RigidSystem(dynamic=True); use solve() for statics"
            )
        if not (math.isfinite(h) and h > 0.0):
            raise ValueError(f"{self.prefix}: time step must be finite and > 0 s, got {dt}")
        if self._step.loads is None:
            self.start_dynamics()
        self._problem.commit()
        self._step.begin(self.bodies, h)

    def step(self, dt: float, step: str = "") -> int:
        """Advance the system by one implicit step of ``dt`` (s); return the Newton iterations.

        Set the applied loads (``body.force``, ``body.moment``) and the prescribed motions
        (:meth:`RigidBody.prescribe`) of the step's end, t + dt, before calling. On success the
        bodies' motions, velocities (``velocity``, ``omega``) and the FE displacement are those
        of t + dt and :attr:`time` is advanced. Prescribed and massless bodies get the
        trapezoidal-rule velocities of their motion. On failure the state is left at the last
        iterate and the time is not advanced (use :meth:`snapshot` / :meth:`restore`).

        Raises:
            ValueError: Not a dynamic system, or a bad ``dt``.
            ConvergenceError: The SNES did not converge (names the step, reason, iterations).
        """
        self._begin_step(dt)
        h = self._step.dt
        try:
            its = self._run_snes(step or f"t={self.time + h:.9g} s")
            inertia = self._step.inertia_rows(self.bodies, self._problem.phi)
        finally:
            self._step.dt = None
        self._step.set_velocities(self.bodies, self._problem.phi, h)
        self._problem.commit()
        self._step.loads = self._problem.external_loads()
        self._step.last_inertia = inertia
        self.time += h
        return its

    # ---- state -------------------------------------------------------------------------------
    def reduced_vector(self) -> PETSc.Vec:
        """A new vector of the reduced layout holding the current state (φ = 0)."""
        return self._problem.x_from_state().copy()

    def move(self, name: str, translation: np.ndarray, rotation: np.ndarray) -> None:
        """Set body ``name``'s motion now (m, rotation matrix): a predictor for the next solve.

        The tied nodes follow at the next solve; the free nodes keep ``u`` (set them too for a
        good start). In a dynamic system, call :meth:`start_dynamics` after moving bodies to
        take the new state as an initial state.
        """
        b = self._index[name]
        body = self.bodies[b]
        body.translation = np.asarray(translation, dtype=float).copy()
        body.rotation = np.asarray(rotation, dtype=float).copy()
        self._problem.set_rotation(b, body.rotation)
        self._step.last_inertia = None

    def snapshot(self) -> tuple:
        """The state (FE displacement, body motions, dynamic state) for :meth:`restore`."""
        u = self.u.x.array.copy() if self._fe is not None else None
        motions = [(b.translation.copy(), b.rotation.copy()) for b in self.bodies]
        return u, motions, self._step.snapshot(self.bodies, self.time)

    def restore(self, snapshot: tuple) -> None:
        """Put back a :meth:`snapshot`."""
        u, motions, *rest = snapshot
        if self._fe is not None:
            self.u.x.array[:] = u
        for b, (body, (t, R)) in enumerate(zip(self.bodies, motions, strict=True)):
            body.translation, body.rotation = t.copy(), R.copy()
            self._problem.set_rotation(b, R)
        if rest:
            self.time = self._step.restore(self.bodies, rest[0])
        self._step.dt = None

    # ---- outputs -----------------------------------------------------------------------------
    def destroy(self) -> None:
        """Free the PETSc objects (and the options kept for their factorizations)."""
        release_options(self.snes.getOptionsPrefix() or "")
        self.snes.destroy()
        self._guard.destroy()
        self._problem.destroy()
        if self._fe is not None:
            self._fe.destroy()
