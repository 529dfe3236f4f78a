"""Travel control (an unknown travel and its equation in the Newton system) and the trial-state
guard (Newton steps shortened inside the line search): hand solutions and a 1-D SNES.

Cheap; serial and under ``mpirun -n 2`` (the rigid DOFs live on rank 0).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from _util import six_springs
from mpi4py import MPI
from petsc4py import PETSc

from shoulder_fem.engine.rigid_system import RigidBody, RigidSystem
from shoulder_fem.engine.rigid_system.control import MeasureGradient
from shoulder_fem.engine.rigid_system.guard import TrialGuard
from shoulder_fem.engine.solver import ConvergenceError, SolveStats, set_from_options
from shoulder_fem.engine.springs import Spring
from shoulder_fem.engine.stagnation import StagnationTest

pytestmark = pytest.mark.mpi

K_LINK = 400.0  # N/m, the spring from the plate to the body
SCALE = 1e3  # N per m of the measure


def _plate_and_body(admissible=None):
    """Body "b" on the six springs, pulled along x by a link spring from a prescribed plate "a"
    (rest length 0.3 m, unstressed at rest); the measure is b's x translation. ``admissible``:
    None, or Callable(b) -> bool, the model's test of trial states."""
    springs, K = six_springs()
    b = RigidBody("b", np.zeros(3))
    a = RigidBody("a", np.array([0.3, 0.0, 0.0]), prescribed=True)
    link = Spring("link", "b", (0.0, 0, 0), "a", (0.3, 0, 0), K_LINK, rest_length=0.3)
    test = None if admissible is None else (lambda: admissible(b))
    system = RigidSystem([b, a], [*springs, link], comm=MPI.COMM_WORLD, admissible=test)

    def measure(with_gradient: bool) -> MeasureGradient:
        out = MeasureGradient(float(b.translation[0]))
        if with_gradient:
            out.bodies[0] = np.array([1.0, 0, 0, 0, 0, 0])
        return out

    return system, a, b, measure, K


def test_the_travel_that_gives_a_target_by_hand():
    """Linear regime: b's x translation x_b = C k (d - x_b) with C = (K⁻¹)_xx, so the plate's
    travel is d = x_b (1 + 1/(k C)) and d(travel)/d(target) is the same factor. The target is
    hit to snes_atol / scale, the plate stays on its line, and the tangent predictor of the next
    target is exact to second order: the next solve needs at most one Newton iteration."""
    system, a, b, measure, K = _plate_and_body()
    system.solve("rest")
    control = system.set_control("a", [1.0, 0, 0], measure, SCALE)
    assert control.target == pytest.approx(0.0, abs=1e-15)
    factor = 1.0 + 1.0 / (K_LINK * np.linalg.inv(K)[0, 0])
    control.target = 1e-5
    system.solve("1e-5 m")
    assert abs(b.translation[0] - 1e-5) <= 1e-12 / SCALE
    assert control.travel(a.translation) == pytest.approx(factor * 1e-5, rel=1e-4)
    assert np.abs(a.translation[1:]).max() < 1e-15  # on its line
    tangent = system.control_tangent()
    k = system._problem.layout.rigid_cols(1)[0]  # the plate's x row (rank 0 owns it)
    lo, hi = tangent.getOwnershipRange()
    dd = tangent.array_r[k - lo] if lo <= k < hi else None
    dd = MPI.COMM_WORLD.bcast(dd, root=0)
    assert dd == pytest.approx(factor, rel=1e-4)
    system.predict(tangent, 1e-5)
    control.target = 2e-5
    its = system.solve("2e-5 m")
    assert its <= 1 and abs(b.translation[0] - 2e-5) <= 1e-12 / SCALE
    tangent.destroy()
    system.destroy()


def test_a_predictor_into_an_inadmissible_state_is_shortened():
    """The tangent predictor of the next target is checked as a Newton trial state is: here the
    model admits b's x translation below 1.4e-5 m only. From 1e-5 m, the predictor of a 1e-5
    step (to 2e-5, exact in this linear regime) is refused, then its half (1.5e-5), and its
    quarter (1.25e-5) is taken; Newton then reaches the target 1.3e-5 from there. A model that
    admits nothing keeps the converged state (no predictor)."""
    limit = {"x": 1.4e-5}

    def below(b) -> bool:
        return bool(MPI.COMM_WORLD.allreduce(b.translation[0] < limit["x"], op=MPI.LAND))

    system, a, b, measure, _ = _plate_and_body(below)
    system.solve("rest")
    control = system.set_control("a", [1.0, 0, 0], measure, SCALE)
    control.target = 1e-5
    system.solve("1e-5 m")
    tangent = system.control_tangent()
    assert system.predict(tangent, 1e-5) == 0.25
    assert b.translation[0] == pytest.approx(1.25e-5, rel=1e-6)
    control.target = 1.3e-5
    system.solve("1.3e-5 m")
    assert abs(b.translation[0] - 1.3e-5) <= 1e-12 / SCALE
    before = b.translation.copy()
    limit["x"] = -1.0  # nothing admissible
    assert system.predict(tangent, 1e-5) == 0.0
    assert np.array_equal(b.translation, before)
    tangent.destroy()
    system.destroy()


def test_control_needs_a_prescribed_body():
    system, _, _, measure, _ = _plate_and_body()
    with pytest.raises(ValueError, match="needs a prescribed body, 'b' is not"):
        system.set_control("b", [1.0, 0, 0], measure, SCALE)
    system.destroy()


# ---- the trial-state guard -------------------------------------------------------------------


def _log_snes(guard: bool):
    """Solve ln(x) = ln(2) from x = 10 with full Newton steps (one entry per rank).

    Newton's first step lands at 10 - 10 ln(5) = -6.09, where ln is NaN. With ``guard`` the
    trial-state guard (admissible: x > 0) is the line search's pre-check, wired as in
    :class:`RigidSystem`. Returns (converged reason, x, the guard's counters, iterations).
    """
    comm = MPI.COMM_WORLD
    x = PETSc.Vec().createMPI((1, comm.size), comm=comm)
    r = x.duplicate()
    state = {"x": None}

    def update(v):
        state["x"] = v.array_r.copy()

    def residual(snes, v, out):
        with np.errstate(invalid="ignore"):
            out.array[:] = np.log(v.array_r) - math.log(2.0)

    def jacobian(snes, v, A, P):
        P.zeroEntries()
        lo, _ = P.getOwnershipRange()
        P.setValue(lo, lo, 1.0 / v.array_r[0])
        P.assemble()

    A = PETSc.Mat().createAIJ(((1, comm.size), (1, comm.size)), nnz=(1, 0), comm=comm)
    snes = PETSc.SNES().create(comm)
    stats = SolveStats()
    stats.shortened_steps = stats.step_halvings = 0

    def admissible() -> bool:
        return bool(comm.allreduce(bool(np.all(state["x"] > 0)), op=MPI.LAND))

    g = TrialGuard(update, residual, admissible, stats, comm) if guard else None
    snes.setFunction(g.residual if guard else residual, r)
    snes.setJacobian(jacobian, A, A)
    if guard:
        snes.setLineSearchPreCheck(g)
    snes.setOptionsPrefix(f"logtest{int(guard)}_")
    set_from_options(
        snes,
        {"snes_linesearch_type": "basic", "snes_atol": 1e-12, "snes_rtol": 0, "snes_max_it": 30}
        | {"ksp_type": "preonly", "pc_type": "lu"},
    )
    x.set(10.0)
    snes.solve(None, x)
    out = (snes.getConvergedReason(), x.array_r.copy(), stats, snes.getIterationNumber())
    for obj in (snes, A, x, r):
        obj.destroy()
    if g is not None:
        g.destroy()
    return out


def test_a_step_into_nan_is_shortened_inside_the_solve():
    """Without the guard the first full Newton step of ln(x) = ln(2) from 10 gives a NaN
    residual and the solve ends (DIVERGED_FNORM_NAN); with it the step is halved once (to
    x = 10 - 16.09/2 = 1.95 > 0) and Newton converges to 2 in the same SNES."""
    reason, _, _, _ = _log_snes(guard=False)
    assert reason == PETSc.SNES.ConvergedReason.DIVERGED_FNORM_NAN
    reason, x, stats, its = _log_snes(guard=True)
    assert reason > 0 and np.allclose(x, 2.0, rtol=1e-12), (reason, x)
    assert stats.shortened_steps == 1 and stats.step_halvings == 1, vars(stats)
    # Newton from 1.95 on ln x: 4 iterations measured (the guarded step counted); 8 is a bound
    assert its <= 8


def test_a_rigid_system_names_a_solve_that_cannot_be_rescued():
    """A guard that admits nothing: every step is halved 20 times, the solve still ends with a
    ConvergenceError naming the step (nothing hangs)."""
    springs, _ = six_springs()
    body = RigidBody("b", np.zeros(3), force=[1.0, 0, 0])
    system = RigidSystem(
        [body],
        springs,
        comm=MPI.COMM_WORLD,
        admissible=lambda: False,
        options={"snes_max_it": 3},
    )
    with pytest.raises(ConvergenceError, match="at never"):
        system.solve("never")
    assert system.stats.shortened_steps >= 1
    # TrialGuard's max_halvings = 20 per shortened step: nothing admissible, all of them used
    assert system.stats.step_halvings == 20 * system.stats.shortened_steps
    system.destroy()


def test_the_retries_give_back_the_line_searchs_own_largest_step():
    """:func:`solve_with_fallback`'s ``l2`` retries cap the line search's step at 1 (the full
    Newton step the guard checked) and then give back the step the solver had before, read
    from PETSc (7.5 here, set by the solver's options), not PETSc's default 1e8 (as it did)."""
    from shoulder_fem.engine.petsc_lib import line_search_maxstep
    from shoulder_fem.families.shoulder.newton import solve_with_fallback

    springs, _ = six_springs()
    body = RigidBody("b", np.zeros(3), force=[1.0, 0, 0])
    seen = []
    system = RigidSystem(
        [body],
        springs,
        comm=MPI.COMM_WORLD,
        admissible=lambda: seen.append(line_search_maxstep(system.snes)) and False,
        options={"snes_max_it": 3, "snes_linesearch_maxstep": 7.5},
    )
    assert line_search_maxstep(system.snes) == 7.5
    with pytest.raises(ConvergenceError, match="l2 line search"):
        solve_with_fallback(system, "never", system.snapshot(), None, None)
    assert 7.5 in seen and 1.0 in seen  # the first solve's, then the retries'
    assert seen.index(1.0) > seen.index(7.5) and seen[-1] == 1.0
    assert line_search_maxstep(system.snes) == 7.5
    system.destroy()


def test_mumps_options_reach_the_factorization_and_leave_with_the_solver():
    """A solver's own MUMPS option (part 1's QAMD ordering, ICNTL(7) = 6) is read at the
    factorization, after the solver's set-up: it stays in PETSc's database under the solver's
    prefix until :func:`release_options`, while its other options leave at once (they used to
    leave together, and MUMPS never saw its options)."""
    from shoulder_fem.engine.solver import release_options

    A = PETSc.Mat().createAIJ([4, 4], comm=PETSc.COMM_SELF)
    A.setUp()
    for i in range(4):
        A[i, i] = 2.0 + i
    A.assemble()
    ksp = PETSc.KSP().create(PETSc.COMM_SELF)
    ksp.setOptionsPrefix("mumps_late_")
    ksp.setOperators(A)
    options = {"ksp_type": "preonly", "pc_type": "lu", "pc_factor_mat_solver_type": "mumps"}
    set_from_options(ksp, options | {"mat_mumps_icntl_7": 6})
    left = PETSc.Options().getAll()
    assert "mumps_late_mat_mumps_icntl_7" in left and "mumps_late_ksp_type" not in left
    b = A.createVecLeft()
    b.set(1.0)
    x = b.duplicate()
    ksp.solve(b, x)
    factor = ksp.getPC().getFactorMatrix()
    assert factor.getMumpsIcntl(7) == 6 and factor.getMumpsInfog(7) == 6  # asked, and used
    assert np.allclose(x.array, 1.0 / (2.0 + np.arange(4)))
    release_options("mumps_late_")
    assert not [k for k in PETSc.Options().getAll() if k.startswith("mumps_late_")]
    for obj in (ksp, A, b, x):
        obj.destroy()


def _scalar_snes(f, df, x0: float, custom: bool, max_it: int = 40):
    """A 1-unknown SNES (full Newton steps, LU) on each rank: (reason, iterations, x, test)."""
    snes = PETSc.SNES().create(PETSc.COMM_SELF)
    x = PETSc.Vec().createSeq(1)
    r = x.duplicate()
    J = PETSc.Mat().createDense([1, 1], comm=PETSc.COMM_SELF)
    J.setUp()

    def residual(_, xv, rv):
        rv[0] = f(xv[0])
        rv.assemble()

    def jacobian(_, xv, A, P):
        P[0, 0] = df(xv[0])
        P.assemble()

    snes.setFunction(residual, r)
    snes.setJacobian(jacobian, J)
    snes.setOptionsPrefix("stagnation_test_")
    opts = {"snes_linesearch_type": "basic", "snes_max_it": max_it, "ksp_type": "preonly"}
    set_from_options(snes, opts | {"pc_type": "lu", "snes_rtol": 1e-12, "snes_atol": 1e-14})
    test = StagnationTest() if custom else None
    if custom:
        snes.setConvergenceTest(test)
    x[0] = x0
    snes.solve(None, x)
    out = snes.getConvergedReason(), snes.getIterationNumber(), float(x[0]), test
    for obj in (snes, x, r, J):
        obj.destroy()
    return out


def test_the_stagnation_test_is_petscs_default_and_stops_a_plateau():
    """:class:`StagnationTest` gives PETSc's default test's reason, iterations and solution where
    Newton converges: x^3 = 2 from 1 (quadratically), from the root (|F| < atol at once), and
    with a tangent twice too stiff (linearly, |F| halving per iteration). With a tangent 1e6
    too stiff (|F| falls by 1e-6 per iteration: a plateau) PETSc's test runs to max_it, the
    stagnation test stops after 5 iterations within 0.1 %, as DIVERGED_LOCAL_MIN, and says so;
    |F| > divtol |F_0| diverges as PETSc's does."""
    cube = (lambda v: v**3 - 2.0, lambda v: 3.0 * v**2)
    half = (cube[0], lambda v: 6.0 * v**2)
    for problem, x0 in ((cube, 1.0), (cube, 2.0 ** (1.0 / 3.0)), (half, 1.0)):
        default = _scalar_snes(*problem, x0, custom=False)
        ours = _scalar_snes(*problem, x0, custom=True)
        assert default[0] > 0 and ours[:2] == default[:2], (default, ours)
        assert ours[2] == pytest.approx(2.0 ** (1.0 / 3.0), rel=1e-6) and ours[2] == default[2]
    plateau = (lambda v: v + 5.0, lambda v: 1e6)
    reason, its, _, _ = _scalar_snes(*plateau, 0.0, custom=False)
    assert reason == PETSc.SNES.ConvergedReason.DIVERGED_MAX_IT and its == 40
    reason, its, _, test = _scalar_snes(*plateau, 0.0, custom=True)
    assert reason == PETSc.SNES.ConvergedReason.DIVERGED_LOCAL_MIN and its == 5, its
    assert test.stagnated == its and "stagnated within 0.1 % over 5 iterations" in test.describe()
    # Newton on x^3 - 2x + 2 from 0 cycles 0, 1, 0, 1, ... (|F| = 2, 1, 2, 1, ...): the
    # default test runs to max_it, the stagnation test stops once 6 norms have repeated those
    # two iterations before them (the 8th norm, iteration 7)
    cycle = (lambda v: v**3 - 2.0 * v + 2.0, lambda v: 3.0 * v**2 - 2.0)
    reason, its, _, _ = _scalar_snes(*cycle, 0.0, custom=False)
    assert reason == PETSc.SNES.ConvergedReason.DIVERGED_MAX_IT and its == 40
    reason, its, x, test = _scalar_snes(*cycle, 0.0, custom=True)
    assert reason == PETSc.SNES.ConvergedReason.DIVERGED_LOCAL_MIN and its == 7, its
    assert test.cycled == 2 and x in (0.0, 1.0)
    assert "cycled with period 2 between 1 and 2" in test.describe(), test.describe()
    # a longer cycle (the shoulder's part 1: |F| falling linearly, then reset by the contact):
    # norms 8, 4, 2, 1 repeated stop once 6 norms equal those 4 before them
    test = StagnationTest()
    snes = PETSc.SNES().create(PETSc.COMM_SELF)
    norms = [16.0] + [8.0, 4.0, 2.0, 1.0] * 3
    reasons = [test(snes, k, (1.0, 1.0, f)) for k, f in enumerate(norms)]
    stop = PETSc.SNES.ConvergedReason.DIVERGED_LOCAL_MIN
    assert reasons.index(stop) == 10 and test.cycled == 4, reasons
    snes.destroy()
    test = StagnationTest(divtol=10.0)
    snes = PETSc.SNES().create(PETSc.COMM_SELF)
    assert test(snes, 0, (1.0, 0.0, 2.0)) == PETSc.SNES.ConvergedReason.ITERATING
    assert test(snes, 1, (1.0, 1.0, 20.5)) == PETSc.SNES.ConvergedReason.DIVERGED_DTOL
    snes.destroy()
