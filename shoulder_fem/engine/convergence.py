"""A SNES convergence test whose divergence test looks at the best residual so far.

PETSc's default test (``SNESConvergedDefault``) calls a solve diverged when the residual
exceeds ``divtol`` times the *first* one. A Newton solve that first improves a lot and then
overshoots into another contact state climbs for many iterations before it passes that bound:
measured on the shoulder's part 1 at ``paper`` (the first step from the seated state, 283 N):
283, 241, 34, 850, 730, 681, 631, 6 316 N, i.e. 7 iterations before the retry with a line
search, 12 in another run. Against the best residual (34 N) the third iterate already fails.
:class:`BestResidualTest` is PETSc 3.18's default test with that one change.
"""

from __future__ import annotations

import math

from petsc4py import PETSc

__all__ = ["BestResidualTest"]


class BestResidualTest:
    """PETSc's default SNES convergence test, diverged at ``divtol`` x the best residual so far.

    Install with ``snes.setConvergenceTest(test)``. The same tests as ``SNESConvergedDefault``
    (PETSc 3.18), in its order: a non-finite residual; ``|F| < atol`` (at iteration 0 too);
    from iteration 1 ``|F| <= rtol |F_0|``, a step ``< stol |x|``, then the divergence test
    ``|F| > divtol min_{k<i} |F_k|`` (PETSc's: ``divtol |F_0|``). ``divtol`` None or <= 0: no
    divergence test. The iteration limit is the solver's own (DIVERGED_MAX_IT).
    """

    def __init__(self, divtol: float | None):
        self.divtol = divtol
        self._best = math.inf
        self._ttol = 0.0

    def __call__(self, snes: PETSc.SNES, it: int, norms: tuple[float, float, float]) -> int:
        """The reason at iteration ``it``; ``norms`` = (|x|, |step|, |F|) as PETSc passes them."""
        xnorm, snorm, fnorm = norms
        rtol, atol, stol, _ = snes.getTolerances()
        reason = PETSc.SNES.ConvergedReason
        if it == 0:
            self._ttol, self._best = fnorm * rtol, fnorm
        if not math.isfinite(fnorm):
            return reason.DIVERGED_FNORM_NAN
        if fnorm < atol:
            return reason.CONVERGED_FNORM_ABS
        if it > 0:
            if fnorm <= self._ttol:
                return reason.CONVERGED_FNORM_RELATIVE
            if snorm < stol * xnorm:
                return reason.CONVERGED_SNORM_RELATIVE
            if self.divtol is not None and self.divtol > 0 and fnorm > self.divtol * self._best:
                return reason.DIVERGED_DTOL
        self._best = min(self._best, fnorm)
        return reason.CONVERGED_ITERATING
