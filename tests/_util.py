"""Helpers shared by several test files (not tests themselves)."""

from __future__ import annotations

import numpy as np


def quadratic_orders(history: list[float], floor: float) -> list[float]:
    """Order estimates log ρ_{k+1} / log ρ_k (ρ = r / max r) where ρ_k < 0.2, r_{k+1} > floor."""
    r = np.asarray(history)
    rho = r / r.max()
    return [
        float(np.log(rho[k + 1]) / np.log(rho[k]))
        for k in range(len(r) - 1)
        if rho[k] < 0.2 and r[k + 1] > floor
    ]


def assert_same_probes(world, alone, rel: float = 1e-8) -> None:
    """Two runs' probes agree to ``rel``; a probe that is physically ~0 (a moment component
    about an axis of symmetry, a deflection at rest) is compared against the largest probe of
    the same unit, times ``rel``, rather than against its own round-off."""
    units = alone.data.get("probe_units", {})
    scale: dict = {}
    for name, value in alone.probes.items():
        if value is None:
            continue
        mag = float(np.max(np.abs(np.asarray(value, dtype=float))))
        scale[units.get(name)] = max(scale.get(units.get(name), 0.0), mag)
    for name, value in alone.probes.items():
        if value is None:
            assert world.probes[name] is None, name
            continue
        floor = rel * scale[units.get(name)]
        np.testing.assert_allclose(
            np.asarray(world.probes[name], dtype=float),
            np.asarray(value, dtype=float),
            rtol=rel,
            atol=floor,
            err_msg=name,
        )
