"""The SNES convergence test with the divergence test against the best residual so far."""

from __future__ import annotations

import math

import pytest
from mpi4py import MPI
from petsc4py import PETSc

from shoulder_fem.engine.convergence import BestResidualTest

R = PETSc.SNES.ConvergedReason


def _snes(rtol=1e-8, atol=1e-3, stol=0.0, max_it=15) -> PETSc.SNES:
    snes = PETSc.SNES().create(MPI.COMM_SELF)
    snes.setTolerances(rtol=rtol, atol=atol, stol=stol, max_it=max_it)
    return snes


def _reasons(test, snes, fnorms, xnorm=1.0, snorm=1.0):
    return [test(snes, it, (xnorm, snorm, f)) for it, f in enumerate(fnorms)]


def test_divergence_against_the_best_residual_by_hand():
    """The part-1 history that PETSc's test let climb for 4 more iterations (283, 241, 34,
    850 N, ...; PETSc's bound is 10 x 283 = 2 830 N): diverged at the fourth residual,
    850 > 10 x 34. The same history without a divergence test iterates on; a residual that
    rises less than 10 x its best (11.6, 36, 80, 37 N: a step that then converged) is not
    stopped; the other reasons as PETSc's default test gives them."""
    snes = _snes()
    seen = _reasons(BestResidualTest(10.0), snes, [283.0, 241.0, 34.0, 850.0])
    assert seen == [R.ITERATING] * 3 + [R.DIVERGED_DTOL]
    assert _reasons(BestResidualTest(None), snes, [283.0, 241.0, 34.0, 850.0]) == [R.ITERATING] * 4
    assert _reasons(BestResidualTest(10.0), snes, [11.6, 36.0, 80.0, 37.0]) == [R.ITERATING] * 4
    test = BestResidualTest(10.0)
    assert _reasons(test, snes, [100.0, 50.0, 5e-4]) == [R.ITERATING] * 2 + [R.CONVERGED_FNORM_ABS]
    assert _reasons(test, snes, [5e-4]) == [R.CONVERGED_FNORM_ABS]  # at iteration 0, as PETSc
    tight = _snes(rtol=1e-3, atol=0.0)
    assert _reasons(test, tight, [2.0, 1e-2, 1.9e-3]) == [R.ITERATING] * 2 + [
        R.CONVERGED_FNORM_RELATIVE
    ]
    assert _reasons(test, snes, [2.0, math.nan]) == [R.ITERATING, R.DIVERGED_FNORM_NAN]
    small = _snes(stol=1e-6, atol=0.0)
    assert test(small, 0, (1.0, 1.0, 2.0)) == R.ITERATING
    assert test(small, 1, (1.0, 1e-7, 1.0)) == R.CONVERGED_SNORM_RELATIVE
    for s in (snes, tight, small):
        s.destroy()


@pytest.mark.mpi
def test_a_solve_with_it_is_petscs_default_where_nothing_diverges():
    """x³ = 2 by Newton from x = 1 (one unknown per rank): the same iterates, iteration count
    and reason (CONVERGED_FNORM_RELATIVE) with the test as with PETSc's own."""
    comm = MPI.COMM_WORLD

    def solve(test):
        x = PETSc.Vec().createMPI((1, comm.size), comm=comm)
        f = x.duplicate()
        J = PETSc.Mat().createAIJ(((1, comm.size), (1, comm.size)), nnz=1, comm=comm)
        J.setUp()

        def residual(snes, x, f):
            f.array[:] = x.array_r**3 - 2.0

        def jacobian(snes, x, J, P):
            r = x.getOwnershipRange()[0]
            J.setValue(r, r, 3.0 * x.array_r[0] ** 2)
            J.assemble()

        snes = PETSc.SNES().create(comm)
        snes.setFunction(residual, f)
        snes.setJacobian(jacobian, J)
        snes.setTolerances(rtol=1e-12, atol=0.0, stol=0.0, max_it=30)
        snes.getKSP().setType("preonly")
        snes.getKSP().getPC().setType("lu")
        if test is not None:
            snes.setConvergenceTest(test)
        snes.setConvergenceHistory()
        x.set(1.0)
        snes.solve(None, x)
        out = (snes.getIterationNumber(), snes.getConvergedReason(), x.array_r[0])
        history = list(snes.getConvergenceHistory()[0])
        for obj in (snes, J, f, x):
            obj.destroy()
        return out, history

    (its, reason, root), history = solve(BestResidualTest(10.0))
    (its0, reason0, root0), history0 = solve(None)
    assert (its, reason) == (its0, reason0) and reason == R.CONVERGED_FNORM_RELATIVE
    assert history == history0 and root == pytest.approx(2.0 ** (1 / 3), rel=1e-12)
