"""A SNES convergence test that stops a Newton solve whose residual norm stalls or cycles."""

from __future__ import annotations

import math
from collections.abc import Mapping

from petsc4py import PETSc

from shoulder_fem.engine.solver import user_options

__all__ = ["StagnationTest"]


class StagnationTest:
    """PETSc's default SNES convergence test, and a stop where the residual norm stagnates.

    The default test's rules, in its order: a NaN norm diverges; |F| < atol converges; from
    the first iteration on |F| <= rtol |F_0| converges, a step |dx| < stol |x| converges and
    |F| > divtol |F_0| diverges (when divtol > 0; PETSc's loop itself stops at max_it). Added:
    when the last ``iterations`` + 1 norms lie within a relative ``band`` of each other the
    solve stops as ``DIVERGED_LOCAL_MIN`` (and :attr:`stagnated` holds the iteration). Newton
    converging, even linearly, changes |F| by far more per iteration; a line search stuck on a
    plateau of |F| does not: the shoulder's coupled solve at coarse, 5.5 -> 7.0 deg, kept |F|
    at 4 432 N within 0.002 % from its 4th to its 60th ``l2`` iteration, then cut back (at
    ``paper`` each such iteration is a 4.4 s LU). ``divtol`` is PETSc's
    ``snes_divergence_tolerance``, which petsc4py 3.18 cannot read back: :meth:`track` takes it
    from the options as they are set.

    A solve that cycles is stopped the same way (:attr:`cycled` holds the period): when each of
    the last ``iterations`` + 1 norms equals, within ``band``, the norm ``p`` iterations before
    it, for a period ``p`` of 2 to ``max_period``. Part 1 at ``medium`` with the anatomical
    cartilage cap, 54 -> 56 deg: its ``l2`` solve reached |F| = 0.04 N, then alternated between
    0.03846 and 0.05478 N (the same to 1e-8 from its 30th iteration on) up to its 60th
    iteration, 20 s, before the cut-back; at 56.8 -> 58.4 deg |F| fell from 0.82 to 0.033 N in
    10 iterations, jumped back to 0.82 N (the contact's active set) and did so again up to the
    60th.
    """

    def __init__(
        self, iterations: int = 5, band: float = 1e-3, divtol: float = 1e4, max_period: int = 12
    ) -> None:
        self.iterations = int(iterations)
        self.max_period = int(max_period)
        self.band = float(band)
        self.divtol = float(divtol)
        self.stagnated: int | None = None
        self.cycled = 0
        self._norms: list[float] = []

    def track(self, options: Mapping[str, object]) -> None:
        """Follow ``snes_divergence_tolerance`` in ``options`` (and in the user's options)."""
        for source in (options, user_options()):
            if "snes_divergence_tolerance" in source:
                self.divtol = float(source["snes_divergence_tolerance"])

    def __call__(self, snes: PETSc.SNES, it: int, norms: tuple[float, float, float]) -> int:
        """The SNES's reason after iteration ``it`` with (|x|, |dx|, |F|) = ``norms``."""
        xnorm, ynorm, fnorm = norms
        reason = PETSc.SNES.ConvergedReason
        rtol, atol, stol, _ = snes.getTolerances()
        if it == 0:
            self._norms = []
            self.stagnated = None
            self.cycled = 0
        if not math.isfinite(fnorm):
            return reason.DIVERGED_FNORM_NAN
        self._norms.append(float(fnorm))
        if fnorm < atol:
            return reason.CONVERGED_FNORM_ABS
        if it == 0:
            return reason.ITERATING
        f0 = self._norms[0]
        if fnorm <= rtol * f0:
            return reason.CONVERGED_FNORM_RELATIVE
        if ynorm < stol * xnorm:
            return reason.CONVERGED_SNORM_RELATIVE
        if self.divtol > 0 and fnorm > self.divtol * f0:
            return reason.DIVERGED_DTOL
        n = self.iterations + 1
        last = self._norms[-n:]
        if len(last) == n and max(last) <= (1.0 + self.band) * min(last):
            self.stagnated = it
            return reason.DIVERGED_LOCAL_MIN
        for period in range(2, self.max_period + 1):
            before = self._norms[-n - period : -period]
            if len(before) == n and all(
                abs(a - b) <= self.band * b for a, b in zip(last, before, strict=True)
            ):
                self.stagnated, self.cycled = it, period
                return reason.DIVERGED_LOCAL_MIN
        return reason.ITERATING

    def describe(self) -> str:
        """Why the last solve stopped as stagnated (empty if it did not)."""
        if self.stagnated is None:
            return ""
        if self.cycled:
            cycle = self._norms[-self.cycled :]
            return (
                f" (|F| cycled with period {self.cycled} between {min(cycle):.4g} and "
                f"{max(cycle):.4g}, the same within {100 * self.band:g} % over "
                f"{self.iterations + 1} iterations)"
            )
        return (
            f" (|F| stagnated within {100 * self.band:g} % over {self.iterations} iterations, "
            f"at {self._norms[-1]:.4g})"
        )
