"""The coupled floating-frame solver (eq. 14) on the tumbling body, and the decoupled method.

Tolerances, derived from the integrator (Simo–Tarnow energy–momentum midpoint rule, see
``shoulder_fem/engine/floating.py``): energy, linear and angular momentum are conserved exactly
by the discrete equations, so what remains is the Newton residual left at each step. Newton stops at
|r| <= atol ≈ 1e-11 (2 m ℓ/Δt²) ≈ 4e-9 N (coarse box, Δt = 1.5 ms); per step that changes
L by at most Δt ℓ √N |r| ≈ 1.5e-3 · 0.027 · 8 · 4e-9 ≈ 1.3e-12 kg m²/s, about 2e-9 of
|L| = 7.2e-4 kg m²/s, so ≤ 5e-7 over 233 steps in the worst case (errors of random sign give
far less). The tests assert 1e-7 for energy and angular momentum; linear momentum starts at 0
and its per-step change Δt Σ r_i is at round-off, asserted below 1e-12 kg m/s (|P| scale
m ω ℓ ≈ 0.09 kg m/s).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI

import shoulder_fem.api as api
from shoulder_fem.families import tumbling
from shoulder_fem.scene import SceneError, load_scene


def scene(**values):
    return load_scene("tumbling-body").with_values(**values)


def run(method, out, comm=MPI.COMM_WORLD, **values):
    return api.run(scene(**values), method, level="coarse", out=out, comm=comm)


def convergence_orders(history: list[float]) -> list[float]:
    """p_k = log(e_{k+1}/e_k) / log(e_k/e_{k-1}) over the iterates above the round-off floor."""
    e = [x for x in history if x > 1e-11 * history[0]]
    return [math.log(e[k + 1] / e[k]) / math.log(e[k] / e[k - 1]) for k in range(1, len(e) - 1)]


def test_flip_period_measure():
    """Zero crossings of sin(2πt/T) are T/2 apart: the measure returns T."""
    t = np.linspace(0.0, 1.0, 2001)
    assert tumbling.flip_period(t, np.cos(2 * np.pi * t / 0.4)) == pytest.approx(0.4, rel=1e-5)
    assert math.isnan(tumbling.flip_period(t[:100], np.cos(2 * np.pi * t[:100] / 0.4)))


def test_rigid_reference_matches_the_analytic_flip_period():
    """Torque-free box, I1 < I2 < I3, started with L² < 2E·I2 (the orbit circles the minor
    axis): Euler's equations give ω_y ∝ cn(τ, k), period T = 4K(k)/s with
    k² = (I3 − I2)(L² − 2E·I1)/((I2 − I1)(2E·I3 − L²)), s² = (I2 − I1)(2E·I3 − L²)/(I1 I2 I3)
    (Landau–Lifshitz §37 with axes 1 and 3 swapped). The flip indicator crosses zero twice per
    T. NewtonEuler with Δt = 0.1 ms (the reference step of the default scene) is second order:
    relative error ~ (ΩΔt)² / 10 ~ 1e-5."""
    from scipy.special import ellipk

    m, sides = 1800 * 0.04 * 0.03 * 0.02, np.array([0.04, 0.03, 0.02])
    I1, I2, I3 = m / 12 * (np.sum(sides**2) - sides**2)
    omega = 100.0 * np.array([0.1, 1.0, 0.0])
    inertia = np.diag([I1, I2, I3])
    L2 = float(np.sum((inertia @ omega) ** 2))
    E2 = float(omega @ inertia @ omega)
    assert L2 < E2 * I2
    k2 = (I3 - I2) * (L2 - E2 * I1) / ((I2 - I1) * (E2 * I3 - L2))
    period = 4 * ellipk(k2) * math.sqrt(I1 * I2 * I3 / ((I2 - I1) * (E2 * I3 - L2)))
    measured = tumbling.rigid_flip_period(m, inertia, omega, 0.35, 1e-4)
    assert measured == pytest.approx(period, rel=1e-4)


def test_newton_failure_raises_convergence_error():
    """One Newton iteration cannot reach the tolerance: ConvergenceError names the step."""
    from shoulder_fem.engine.floating import FloatingBody
    from shoulder_fem.engine.solver import ConvergenceError
    from shoulder_fem.forms.materials import SaintVenantKirchhoff
    from shoulder_fem.meshes.box import build_box

    mesh = build_box(MPI.COMM_WORLD, (0.04, 0.03, 0.02), (2, 2, 1))
    body = FloatingBody(mesh, 1, 1800.0, SaintVenantKirchhoff(15e6, 0.3), max_iterations=1)
    body.set_initial_state(np.array([10.0, 100.0, 0.0]))
    snapshot = body.save()
    with pytest.raises(ConvergenceError, match="t = 0.001 s") as info:
        body.step(1e-3)
    assert info.value.iterations == 1
    body.restore(snapshot)
    body.max_iterations = 12
    assert len(body.step(1e-3)) >= 3
    body.destroy()


def test_scene_checks_the_principal_axes():
    with pytest.raises(SceneError, match="length_x > length_y > length_z"):
        tumbling.build(scene(length_y=0.05), "coarse", MPI.COMM_WORLD)


@pytest.fixture(scope="module")
def flips(tmp_path_factory):
    """Both methods over 0.83 flip periods at Δt = 1.5 ms (ΩΔt = 0.15), run once per module."""
    folder = Path(MPI.COMM_WORLD.bcast(str(tmp_path_factory.mktemp("flips")), root=0))
    return {m: run(m, folder / m, time_step=1.5e-3) for m in ("coupled", "decoupled")}


def test_coupled_conserves_and_flips_like_the_rigid_body(flips):
    """Coupled: energy, L and P conserved; the flip period within 1 % of the rigid integrator's.

    The period differs from the rigid one by the flexibility (ΔI/I ~ strain ~ 1e-4) and by the
    O((ΩΔt)²) phase error of the midpoint rule: measured +0.16 % at Δt = 1 ms, +0.53 % at 2 ms.
    """
    result = flips["coupled"]
    p = result.probes
    assert p["energy_drift"] < 1e-7
    assert p["angular_momentum_drift"] < 1e-7
    assert p["linear_momentum_drift"] < 1e-12
    assert p["flip_period"] == pytest.approx(p["flip_period_rigid"], rel=0.01)
    # It did flip: the indicator went from +1 through −1 (the body-frame L reversed).
    assert min(result.series["flip_indicator"]["y"]) < -0.9
    # Newton converges quadratically (every step takes 2–3 iterations).
    histories = [
        result.newton_history_first_step,
        result.newton_history_last_step,
        result.newton_history_slowest_step,
    ]
    orders = [p for history in histories for p in convergence_orders(history)]
    assert orders and min(orders) > 1.7, histories
    assert result.newton_iterations_max <= 4


def test_decoupled_rigid_motion_matches_the_rigid_integrator(flips):
    """Decoupled: the frame is NewtonEuler's, so the flip period is the rigid one at its Δt
    (measured −0.09 % at 1 ms, −0.35 % at 2 ms)."""
    p = flips["decoupled"].probes
    assert p["flip_period"] == pytest.approx(p["flip_period_rigid"], rel=0.01)
    assert min(flips["decoupled"].series["flip_indicator"]["y"]) < -0.9
    assert p["linear_momentum_drift"] < 1e-12


def test_coupled_and_decoupled_agree_on_the_straining(flips):
    """Spin far below the first elastic frequency (Ω/ω_el ~ 0.015) and strain ~1e-4: the
    decoupled linear straining matches the coupled finite-strain one; the peak von Mises stress
    (3.1 kPa, the static centrifugal value plus the flip's Euler load) agrees within 3 %."""
    coupled, decoupled = (flips[m].probes["peak_von_mises"] for m in ("coupled", "decoupled"))
    assert 1e3 < coupled < 1e4
    assert decoupled == pytest.approx(coupled, rel=0.03)


def test_time_step_refinement_shows_second_order(comm_tmp):
    """The body-frame angular velocity at t = 40 ms: differences between Δt, Δt/2, Δt/4 runs
    drop by ~4 (second order; Richardson: e(Δt)/e(Δt/2) = 2^p)."""
    finals = []
    for dt in (4e-3, 2e-3, 1e-3):
        result = run("coupled", comm_tmp / f"dt{dt:g}", end_time=0.04, time_step=dt)
        finals.append(np.array([result.series[f"omega_body_{c}"]["y"][-1] for c in "xyz"]))
    e1 = np.linalg.norm(finals[0] - finals[1])
    e2 = np.linalg.norm(finals[1] - finals[2])
    order = math.log2(e1 / e2)
    assert 1.8 < order < 2.3, (e1, e2, order)


@pytest.mark.mpi
def test_serial_and_parallel_agree(comm_tmp):
    """The same short coupled and decoupled runs on one rank and on all ranks: end-of-run
    values agree to 1e-8 relative (with one rank this compares two identical runs)."""
    world = MPI.COMM_WORLD
    values = {"end_time": 0.03, "time_step": 3e-3}
    for method in ("coupled", "decoupled"):
        par = run(method, comm_tmp / f"{method}-par", **values)
        ser = run(method, comm_tmp / f"{method}-ser-{world.rank}", comm=MPI.COMM_SELF, **values)
        for name in ("omega_body_x", "omega_body_y", "kinetic_energy", "strain_energy"):
            a, b = ser.series[name]["y"][-1], par.series[name]["y"][-1]
            assert a == pytest.approx(b, rel=1e-8), (method, name)
        assert ser.probes["peak_von_mises"] == pytest.approx(par.probes["peak_von_mises"], rel=1e-8)
