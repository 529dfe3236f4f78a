"""Grid convergence of an output over three meshes: Roache's grid convergence index (GCI).

The procedure of Celik et al. (2008), "Procedure for estimation and reporting of uncertainty due
to discretization in CFD applications", J. Fluids Eng. 130, 078001: with representative sizes
h1 < h2 < h3 (1 the finest) and the output phi1, phi2, phi3 on them, r21 = h2/h1, r32 = h3/h2,
e21 = phi2 - phi1, e32 = phi3 - phi2 and s = sign(e32/e21), the apparent order p solves

    p = |ln|e32/e21| + ln((r21^p - s)/(r32^p - s))| / ln r21

(fixed-point iteration from p = |ln|e32/e21|| / ln r21), the extrapolated value is
(r21^p phi1 - phi2)/(r21^p - 1), and GCI_fine = 1.25 |e21/phi1| / (r21^p - 1), the relative
band that holds the mesh-converged value with 95 % confidence when the grids are in the
asymptotic range. The ratio R = e21/e32 says the kind of convergence: monotone (0 < R < 1),
oscillatory (R < 0) or none (R >= 1: the differences grow as the mesh is refined, e.g. a
quantity that is singular, such as a peak at an edge).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

__all__ = ["CONVERGED_GCI", "SETTLED_CHANGE", "GridConvergence", "gci"]

#: A monotone output whose GCI_fine is at most this is reported as converged.
CONVERGED_GCI = 0.05
#: A non-monotone output whose last refinement changed it by at most this (relative) is
#: reported as settled: its differences are round-off or solver tolerance, not a trend.
SETTLED_CHANGE = 0.01


@dataclass(frozen=True)
class GridConvergence:
    """One output's convergence over three meshes (see the module docstring).

    Attributes:
        kind: ``monotone``, ``oscillatory``, ``diverging`` or ``unchanged`` (e21 = e32 = 0).
        order: the apparent order p (None unless it could be computed).
        extrapolated: the extrapolated value (None unless monotone).
        gci_fine: GCI on the finest mesh, relative (None unless monotone).
        relative_change: |e21/phi1|, the last refinement's relative change.
        ratio: R = e21/e32 (None if e32 = 0).
        verdict: ``converged`` (monotone, GCI_fine <= :data:`CONVERGED_GCI`), ``converging``
            (monotone, larger GCI), ``settled`` (not monotone, but the last refinement changed
            it by at most :data:`SETTLED_CHANGE`), or ``kind`` otherwise.
    """

    kind: str
    order: float | None
    extrapolated: float | None
    gci_fine: float | None
    relative_change: float
    ratio: float | None
    verdict: str

    def as_dict(self) -> dict:
        """The fields as a plain dict (JSON)."""
        return asdict(self)


def gci(h: tuple[float, float, float], phi: tuple[float, float, float]) -> GridConvergence:
    """The convergence of ``phi`` (finest first) on meshes of sizes ``h`` (finest first).

    Raises:
        ValueError: Sizes not strictly increasing, or a non-finite value.
    """
    h1, h2, h3 = (float(v) for v in h)
    f1, f2, f3 = (float(v) for v in phi)
    if not 0 < h1 < h2 < h3:
        raise ValueError(f"gci: mesh sizes must increase from the finest, got {h}")
    if not all(math.isfinite(v) for v in (f1, f2, f3)):
        raise ValueError(f"gci: values must be finite, got {phi}")
    r21, r32 = h2 / h1, h3 / h2
    e21, e32 = f2 - f1, f3 - f2
    change = abs(e21 / f1) if f1 else math.inf
    if e21 == 0 and e32 == 0:
        return GridConvergence("unchanged", None, f1, 0.0, 0.0, None, "converged")
    ratio = e21 / e32 if e32 else None
    if e21 == 0:  # converged on the last two meshes: no order to compute
        return GridConvergence("monotone", None, f1, 0.0, 0.0, 0.0, "converged")
    if e32 == 0 or ratio >= 1:
        verdict = "settled" if change <= SETTLED_CHANGE else "diverging"
        return GridConvergence("diverging", None, None, None, change, ratio, verdict)
    s = math.copysign(1.0, e32 / e21)
    order = _apparent_order(r21, r32, e21, e32, s)
    if ratio < 0:
        verdict = "settled" if change <= SETTLED_CHANGE else "oscillatory"
        return GridConvergence("oscillatory", order, None, None, change, ratio, verdict)
    factor = r21**order - 1
    extrapolated = (r21**order * f1 - f2) / factor
    band = 1.25 * change / factor
    verdict = "converged" if band <= CONVERGED_GCI else "converging"
    return GridConvergence("monotone", order, extrapolated, band, change, ratio, verdict)


def _apparent_order(r21: float, r32: float, e21: float, e32: float, s: float) -> float | None:
    """The fixed-point solution for p (None if it does not settle in 100 iterations)."""
    log_ratio = math.log(abs(e32 / e21))
    p = abs(log_ratio) / math.log(r21)
    for _ in range(100):
        inner = (r21**p - s) / (r32**p - s)
        if inner <= 0:
            return None
        new = abs(log_ratio + math.log(inner)) / math.log(r21)
        if abs(new - p) < 1e-12 * max(1.0, new):
            return new
        p = new
    return None
