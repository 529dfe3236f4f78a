"""Helpers shared by several test files (not tests themselves)."""

from __future__ import annotations

import numpy as np

from shoulder_fem.engine.springs import GROUND, Spring


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


def taylor_rates(system, rng, size: float) -> tuple[list[float], np.ndarray]:
    """Taylor test of a RigidSystem's tangent at a perturbed state.

    Remainders |F(x + e d) - F(x) - e J d| for e = 1, 1/2, 1/4, 1/8 along a random direction d
    of infinity-norm ``size``, and their convergence rates (2 for an exact tangent).
    """
    from petsc4py import PETSc

    x = system.reduced_vector()
    x.array[:] += 1e-4 * rng.standard_normal(x.getLocalSize())
    d = x.duplicate()
    d.array[:] = rng.standard_normal(x.getLocalSize())
    d.scale(size / d.norm(PETSc.NormType.NORM_INFINITY))
    r0, r1, Jd = x.duplicate(), x.duplicate(), x.duplicate()
    system.snes.computeFunction(x, r0)
    J = system.snes.getJacobian()[0]
    system.snes.computeJacobian(x, J)
    J.mult(d, Jd)
    remainders = []
    for eps in (1.0, 0.5, 0.25, 0.125):
        xe = x.copy()
        xe.axpy(eps, d)
        system.snes.computeFunction(xe, r1)
        r1.axpy(-1.0, r0)
        r1.axpy(-eps, Jd)
        remainders.append(r1.norm())
    e = np.array(remainders)
    return remainders, np.log(e[:-1] / e[1:]) / np.log(2.0)


def six_springs(k: float = 1000.0, arm: float = 0.05, length: float = 0.1):
    """Six springs to the ground, at ±arm along each axis, each pointing along the next axis.

    Returns the springs and the small-rotation stiffness of the arrangement (hand solution):
    K = Σ k_s b_s b_sᵀ, b_s = (n_s, p_s × n_s), n_s the spring's direction, p_s its body point
    (relative to the reference point, the origin): a small motion (t, θ) stretches spring s by
    b_s · (t, θ), and the arrangement's virtual work gives K.
    """
    springs, K = [], np.zeros((6, 6))
    for i in range(3):
        for sign in (1.0, -1.0):
            p = sign * arm * np.eye(3)[i]
            n = np.eye(3)[(i + 1) % 3]
            ks = k * (1 + i)
            springs.append(
                Spring(f"s{i}{'+' if sign > 0 else '-'}", "b", p, GROUND, p + length * n, ks)
            )
            b = np.r_[n, np.cross(p, n)]
            K += ks * np.outer(b, b)
    return springs, K
