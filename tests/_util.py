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
