"""Hertz's solution for a ball on a flat or in a socket, and a Hertz profile fitted to pressures."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class HertzSolution:
    """Hertz theory for a ball on a counterpart (SI units)."""

    contact_radius: float  # a, m
    max_pressure: float  # p0, Pa
    approach: float  # δ = a²/R*, m
    effective_radius: float  # R*, m
    effective_modulus: float  # E*, Pa


def hertz_solution(
    force: float,
    radius: float,
    youngs_modulus: float,
    poisson_ratio: float,
    socket_radius: float | None = None,
    counterpart_youngs_modulus: float | None = None,
    counterpart_poisson_ratio: float = 0.0,
) -> HertzSolution:
    """Hertz's contact radius, peak pressure and approach (flat, or socket of ``socket_radius``).

    The counterpart is rigid unless ``counterpart_youngs_modulus`` is given:
    1/E* = (1 − ν²)/E + (1 − ν₂²)/E₂.
    """
    compliance = (1.0 - poisson_ratio**2) / youngs_modulus
    if counterpart_youngs_modulus is not None:
        compliance += (1.0 - counterpart_poisson_ratio**2) / counterpart_youngs_modulus
    e_star = 1.0 / compliance
    r_eff = radius if socket_radius is None else radius * socket_radius / (socket_radius - radius)
    a = (3.0 * force * r_eff / (4.0 * e_star)) ** (1.0 / 3.0)
    return HertzSolution(a, 3.0 * force / (2.0 * math.pi * a * a), a * a / r_eff, r_eff, e_star)


@dataclass(frozen=True)
class ProfileFit:
    """A Hertz profile p(r) = p0 √(1 − r²/a²) fitted to measured pressures (SI units).

    Attributes:
        max_pressure: the fitted p0 (Pa).
        contact_radius: the fitted a (m).
        rms: root mean square of the residuals p_i − p(r_i) (Pa): the scatter about the fit.
        points: how many pressures were fitted.
    """

    max_pressure: float
    contact_radius: float
    rms: float
    points: int


def hertz_profile(r: np.ndarray, p0: float, a: float) -> np.ndarray:
    """p0 √(1 − r²/a²) inside r < a, zero outside (Pa)."""
    return p0 * np.sqrt(np.clip(1.0 - (np.asarray(r) / a) ** 2, 0.0, None))


def fit_hertz_profile(r: np.ndarray, p: np.ndarray) -> ProfileFit:
    """Least squares of p(r) = p0 √(1 − r²/a²) over the points (r_i, p_i), p0 and a free.

    For a given a the best p0 is linear, p0(a) = Σ p_i f_i / Σ f_i² with f_i = √(1 − r_i²/a²)₊,
    so only a is searched: a grid over [0.5, 2] × the largest r_i, then a bounded scalar
    minimisation around the best grid value.

    Raises:
        ValueError: for fewer than 2 points or no positive pressure.
    """
    from scipy.optimize import minimize_scalar

    r, p = np.asarray(r, dtype=float), np.asarray(p, dtype=float)
    if len(r) < 2 or not np.any(p > 0):
        raise ValueError(f"fit_hertz_profile: need 2 or more points with pressure, got {len(r)}")

    def best(a: float) -> tuple[float, float]:
        f = hertz_profile(r, 1.0, a)
        p0 = float(p @ f / (f @ f)) if f @ f > 0 else 0.0
        return p0, float(np.sum((p - p0 * f) ** 2))

    r_max = float(r.max()) or float(np.abs(r).max()) or 1.0
    grid = np.linspace(0.5 * r_max, 2.0 * r_max, 301)
    k = int(np.argmin([best(a)[1] for a in grid]))
    lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
    found = minimize_scalar(
        lambda a: best(a)[1], bounds=(lo, hi), method="bounded", options={"xatol": 1e-9 * r_max}
    )
    a = float(found.x) if best(found.x)[1] <= best(grid[k])[1] else float(grid[k])
    p0, sse = best(a)
    return ProfileFit(p0, a, math.sqrt(sse / len(r)), len(r))
