"""Dynamic rigid bodies in the reduced system: analytic motions, conservation, convergence order,
exact tangent, Newton's rate, FE coupling, serial vs ``mpirun -n 2``, bad input.

The scheme (:mod:`shoulder_fem.engine.rigid_system.dynamics`) is Simo–Wong's energy–momentum
algorithm with trapezoidal loads. Every reference number here is independent of it: closed-form
motions (2π√(m/k), M t²/(2I)), conserved quantities of the exact dynamics, a high-accuracy ODE
solution (scipy DOP853), the statically measured stiffness of the FE block, and rigid.py's own
Simo–Wong integrator (a separate implementation).

MPI: the tests marked ``mpi`` also run under ``mpirun -n 2``, among them the FE-coupled ones
(the block is distributed, the rigid DOFs live on rank 0) and a run on all ranks against the
same run on each rank alone. The four analytic tests of a lone body with hundreds of steps are
serial only: their system has only rank-0 DOFs, so under mpirun they would exercise no other
code path and mostly time parallel MUMPS on a 6×6 matrix (~0.1 s per step).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import ufl
from _util import quadratic_orders, taylor_rates
from mpi4py import MPI
from test_rigid_bodies import plate_system, six_springs

from shoulder_fem.engine.mass import mass_properties
from shoulder_fem.engine.rigid import NewtonEuler
from shoulder_fem.engine.rigid_system import RigidBody, RigidSystem
from shoulder_fem.engine.so3 import hat, log_so3, rotation_about
from shoulder_fem.engine.springs import GROUND, Spring


def discrete_period(x: np.ndarray, h: float) -> float:
    """Period (s) of a sampled linear oscillation x_n = A cos(ω_h n h + φ₀): from the
    recurrence x_{n+1} + x_{n-1} = 2 cos(ω_h h) x_n (least squares over the samples)."""
    c = np.sum((x[2:] + x[:-2]) * x[1:-1]) / (2.0 * np.sum(x[1:-1] ** 2))
    return 2.0 * math.pi * h / math.acos(c)


def test_spring_oscillator_period_converges_at_second_order():
    """Mass m on a linear spring k (along the spring's axis, so exactly linear), released from
    x = A at rest, 2.25 periods with n = 20, 40, 80 steps per period. The numerical period tends
    to 2π√(m/k) at order 2 (the trapezoidal rule's error (ωh)²/12: 5.1e-4 at n = 80, required
    < 6e-4), the end position's error (at a zero of x, so ~ A × phase error) also at order 2,
    and the energy ½kx² + ½mv² is conserved to 1e-12 relative (the rule conserves quadratic
    energies exactly)."""
    m, k, A = 2.0, 800.0, 1e-3
    omega = math.sqrt(k / m)
    T = 2.0 * math.pi / omega
    period_errors, end_errors = [], []
    for n in (20, 40, 80):
        h = T / n
        body = RigidBody("b", np.zeros(3), mass=m, inertia=[1e-3, 2e-3, 3e-3])
        spring = Spring("s", "b", (0, 0, 0), GROUND, (0.1, 0, 0), k)
        system = RigidSystem([body], [spring], comm=MPI.COMM_WORLD, dynamic=True)
        system.move("b", [A, 0, 0], np.eye(3))
        x, energy = [A], []
        for _ in range(9 * n // 4):
            system.step(h)
            x.append(body.translation[0])
            e = system.energy()
            energy.append(e["kinetic"] + e["springs"])
        period = discrete_period(np.array(x), h)
        period_errors.append(abs(period / T - 1.0))
        end_errors.append(abs(x[-1] - A * math.cos(omega * 2.25 * T)))
        np.testing.assert_allclose(energy, 0.5 * k * A * A, rtol=1e-12)
        assert np.abs(body.translation[1:]).max() == 0.0 and np.allclose(body.rotation, np.eye(3))
        system.destroy()
    p_orders = np.log2(np.array(period_errors[:-1]) / period_errors[1:])
    x_orders = np.log2(np.array(end_errors[:-1]) / end_errors[1:])
    print(f"spring oscillator: period errors {period_errors} (orders {p_orders}),")
    print(f"  end-position errors {end_errors} m (orders {x_orders})")
    assert period_errors[-1] < 6e-4
    assert np.all(np.abs(p_orders - 2.0) < 0.05) and np.all(np.abs(x_orders - 2.0) < 0.1)


def test_constant_moment_about_a_principal_axis():
    """A free body (principal axes turned by a rotation Q; centre of mass off the reference
    point) under a constant moment M about its principal axis n = Q e_z, from rest: the body
    turns about n by θ(t) = M t²/(2 I_n) (here to ~4.5 rad, past π) and ω = M t/I_n, while its
    centre of mass stays put (no force). The scheme is exact for this motion: 1e-12."""
    Q = rotation_about([1.0, -2.0, 0.5], 0.7)
    principal = np.array([0.02, 0.03, 0.05])
    inertia = Q @ np.diag(principal) @ Q.T
    n_axis, M = Q[:, 2], 0.4
    centre = np.array([0.1, -0.05, 0.02])
    body = RigidBody("b", np.zeros(3), moment=M * n_axis, mass=1.3, inertia=inertia, centre=centre)
    system = RigidSystem([body], comm=MPI.COMM_WORLD, dynamic=True)
    h, n = 0.025, 60
    for i in range(1, n + 1):
        system.step(h)
        t = i * h
        theta = M * t * t / (2.0 * principal[2])
        np.testing.assert_allclose(body.rotation, rotation_about(n_axis, theta), atol=1e-12)
        np.testing.assert_allclose(
            body.rotation @ body.omega,
            M * t / principal[2] * n_axis,
            rtol=0,
            atol=1e-12 * M * t / principal[2],
        )
        np.testing.assert_allclose(body.centre_position(), centre, atol=1e-13)
    assert theta > math.pi
    print(f"constant moment: θ(end) = {theta:.6f} rad, Newton iterations {system.stats.history}")
    system.destroy()


def asymmetric_body(**kwargs) -> RigidBody:
    """A body with a full (non-diagonal) inertia tensor, offset centre, spinning near its
    intermediate axis (the unstable one) and drifting."""
    inertia = np.array([[0.02, 0.001, 0.0], [0.001, 0.03, 0.002], [0.0, 0.002, 0.05]])
    return RigidBody(
        "b",
        np.zeros(3),
        mass=1.5,
        inertia=inertia,
        centre=[0.05, -0.02, 0.03],
        omega=[0.3, 6.0, 0.2],
        velocity=[0.1, 0.0, 0.2],
        **kwargs,
    )


def test_torque_free_body_conserves_energy_and_momentum():
    """Torque- and force-free asymmetric body, 250 steps through a flip about its unstable
    intermediate axis: kinetic energy and angular momentum about a fixed point are conserved to
    the solver tolerance (scheme: exactly), the centre of mass moves uniformly, and the motion
    equals rigid.py's Simo–Wong integrator (independent code, same scheme) to 1e-8."""
    body = asymmetric_body()
    system = RigidSystem(
        [body],
        comm=MPI.COMM_WORLD,
        dynamic=True,
        options={"snes_rtol": 1e-12, "snes_atol": 1e-12, "snes_stol": 1e-14},
    )
    reference = NewtonEuler(body.mass, body.inertia)
    state = body.state()
    E0, L0, x0, v0 = (
        body.kinetic_energy(),
        body.angular_momentum(np.zeros(3)),
        body.centre_position(),
        body.velocity.copy(),
    )
    h, n = 0.01, 250
    energy_drift, momentum_drift = 0.0, 0.0
    for i in range(1, n + 1):
        system.step(h)
        state = reference.step(state, h)
        energy_drift = max(energy_drift, abs(body.kinetic_energy() / E0 - 1.0))
        dL = np.linalg.norm(body.angular_momentum(np.zeros(3)) - L0) / np.linalg.norm(L0)
        momentum_drift = max(momentum_drift, dL)
        np.testing.assert_allclose(body.centre_position(), x0 + v0 * i * h, rtol=0, atol=1e-12)
    print(
        f"torque-free: max energy drift {energy_drift:.2e}, max momentum drift "
        f"{momentum_drift:.2e}, iterations per step {set(system.stats.history)}"
    )
    # the body has flipped (the intermediate axis is unstable): a real test of the rotation
    assert np.linalg.norm(log_so3(body.rotation)) > 1.0
    assert energy_drift < 1e-12 and momentum_drift < 1e-12
    np.testing.assert_allclose(body.rotation, state.R, atol=1e-8)
    np.testing.assert_allclose(body.omega, state.omega, atol=1e-8 * np.linalg.norm(state.omega))
    system.destroy()


def test_torque_free_rotation_converges_at_second_order():
    """The same body over 0.5 s with 25, 50, 100 steps against a DOP853 solution of
    Ṙ = R hat(Ω), I Ω̇ = I Ω × Ω (rtol 1e-12): the rotation's error falls at order 2."""
    from scipy.integrate import solve_ivp

    body0 = asymmetric_body()
    inertia, inv = body0.inertia, np.linalg.inv(body0.inertia)

    def rhs(_, y):
        R, w = y[:9].reshape(3, 3), y[9:]
        return np.r_[(R @ hat(w)).ravel(), inv @ np.cross(inertia @ w, w)]

    t_end = 0.5
    sol = solve_ivp(
        rhs,
        (0, t_end),
        np.r_[np.eye(3).ravel(), body0.omega],
        method="DOP853",
        rtol=1e-12,
        atol=1e-14,
    )
    R_ref = sol.y[:9, -1].reshape(3, 3)
    errors = []
    for n in (25, 50, 100):
        body = asymmetric_body()
        system = RigidSystem([body], comm=MPI.COMM_WORLD, dynamic=True)
        for _ in range(n):
            system.step(t_end / n)
        errors.append(float(np.linalg.norm(log_so3(R_ref.T @ body.rotation))))
        system.destroy()
    orders = np.log2(np.array(errors[:-1]) / errors[1:])
    print(f"torque-free rotation errors {errors} rad, orders {orders}")
    assert np.all(np.abs(orders - 2.0) < 0.1)


@pytest.mark.mpi
def test_newton_converges_quadratically_in_a_dynamic_step():
    """A body on six nonlinear springs (geometric stiffness), offset centre, spinning at 20 rad/s
    about a tilted axis, steps turning it by ~0.4 rad: Newton's rate is quadratic (the inertia
    tangent is consistent) in every step."""
    springs, _ = six_springs()
    body = RigidBody(
        "b",
        np.zeros(3),
        force=[1.0, 2.0, -1.0],
        moment=[0.5, -0.2, 0.3],
        mass=0.5,
        inertia=[2e-3, 3e-3, 4e-3],
        centre=[0.01, 0.02, -0.01],
        omega=20.0 * np.array([0.3, 0.5, 0.8]),
        velocity=[0.2, -0.1, 0.3],
    )
    system = RigidSystem(
        [body],
        springs,
        comm=MPI.COMM_WORLD,
        dynamic=True,
        options={"snes_rtol": 1e-14, "snes_atol": 1e-11},
    )
    for i in range(5):
        its = system.step(0.02)
        history = system.stats.residual_histories[-1]
        orders = quadratic_orders(history, floor=1e-11)
        print(f"dynamic step {i}: {its} Newton iterations, residuals {history}, orders {orders}")
        assert its <= 6 and len(orders) >= 1 and min(orders) > 1.8, (history, orders)
    bal = system.balance("b")
    assert np.linalg.norm(np.r_[bal.force_sum, bal.moment_sum]) < 1e-11
    system.destroy()


# ---- FE coupling: a rigid plate with mass tied to a quasi-static deformable block ------------


def plate_mass_properties(comm: MPI.Comm):
    """Mass properties of a 10 × 10 × 5 mm steel plate (7800 kg/m³) on top of the block
    (z in [40, 45] mm), from its mesh region (the geometry)."""
    from shoulder_fem.meshes.block import PLATE, build_block

    mesh, cells, _ = build_block(comm, 0.01, 0.04, 2, 4, plate_thickness=0.005, n_plate=1)
    dx = ufl.Measure("dx", domain=mesh, subdomain_data=cells, metadata={"quadrature_degree": 2})
    return mass_properties(mesh, 7800.0, dx(PLATE.id))


def plate_on_block(comm: MPI.Comm, dynamic: bool, springs=(), options=None, **body_kwargs):
    """The plate (reference point at the centre of the top face) tied to the block's top face,
    the block's base fixed."""
    plate = RigidBody("plate", (0, 0, 0.04), **body_kwargs)
    return plate, plate_system(plate, springs, options, comm, dynamic)


@pytest.mark.mpi
def test_plate_on_block_torsional_period():
    """Plate (mass and inertia from its mesh region) tied to the block's top, spun at a small
    rate about the axis: it oscillates with the trapezoidal rule's period for the torsional
    stiffness k_θ that a static solve of the same block measures, T_h = πh/atan(ωh/2) with
    ω = √(k_θ/I_zz) (→ 2π√(I_zz/k_θ) as h → 0), to 1e-4 (amplitude 1e-3 rad: nonlinear terms
    ~1e-6); the plate's dynamic balance (ties + d'Alembert) closes to the solver tolerance
    (snes_atol = 1e-11, above the FE residual's round-off floor of ~1e-12 N)."""
    props = plate_mass_properties(MPI.COMM_WORLD)
    a, m = 0.01, 7800.0 * 0.01 * 0.01 * 0.005
    assert props.mass == pytest.approx(m, rel=1e-12)
    assert props.inertia[2, 2] == pytest.approx(m * a * a / 6, rel=1e-12)
    # static torsional stiffness at the amplitude of the oscillation
    options = {"snes_atol": 1e-11}
    M = 4e-5
    plate, static = plate_on_block(MPI.COMM_WORLD, False, options=options, moment=[0, 0, M])
    static.solve("k_theta")
    k_theta = M / log_so3(plate.rotation)[2]
    static.destroy()
    omega = math.sqrt(k_theta / props.inertia[2, 2])
    plate, system = plate_on_block(
        MPI.COMM_WORLD, True, options=options, omega=[0, 0, 1e-3 * omega]
    )
    plate.set_mass_properties(props)  # after the system is built: taken into account too
    T = 2.0 * math.pi / omega
    n = 32
    h = T / n
    angle = [0.0]
    for _ in range(12):  # 3/8 of a period: enough samples for the recurrence
        system.step(h)
        angle.append(log_so3(plate.rotation)[2])
    period = discrete_period(np.array(angle), h)
    expected = math.pi * h / math.atan(omega * h / 2)
    print(
        f"plate on block: k_θ = {k_theta:.6e} N m/rad, I_zz = {props.inertia[2, 2]:.4e} kg m², "
        f"T = {T:.6e} s, T_h = {period:.6e} s (expected {expected:.6e} s), Newton iterations "
        f"{system.stats.history}"
    )
    assert period == pytest.approx(expected, rel=1e-4)
    assert abs(period / T - 1.0) < (omega * h) ** 2 / 12 * 1.1
    bal = system.balance("plate")
    print(
        f"  balance: tie moment {bal.tie_moment}, d'Alembert {bal.inertia_moment}, "
        f"sums {bal.force_sum}, {bal.moment_sum}"
    )
    assert np.abs(bal.tie_moment[2]) > 1e-5  # a real dynamic balance (amplitude 4e-5 N m)
    assert np.linalg.norm(np.r_[bal.force_sum, bal.moment_sum]) < 1e-11
    system.destroy()


def fe_dynamic_run(comm: MPI.Comm, n_steps: int = 6) -> tuple[np.ndarray, list]:
    """A large 3D motion of a massive plate on the block, with a spring from the plate to the
    ground and one from a free block node to the plate: trajectory (t, φ, ω per step) and the
    residual histories."""
    springs = [
        Spring("s", "plate", (0.005, 0, 0.04), GROUND, (0.05, 0, 0.06), 100.0),
        Spring("brace", "plate", (-0.005, 0.0, 0.04), "deformable", (-0.005, 0, 0.01), 200.0),
    ]
    plate, system = plate_on_block(
        comm,
        True,
        springs,
        mass=0.004,
        inertia=[1e-7, 1.5e-7, 2e-7],
        centre=[0.001, 0, 0.0425],
        omega=[30.0, -20.0, 60.0],
        velocity=[0.05, 0.02, 0.0],
        force=[0, 0, -0.04],
    )
    rows = []
    for _ in range(n_steps):
        system.step(2e-3)
        rows.append(np.r_[plate.translation, log_so3(plate.rotation), plate.omega])
    histories = system.stats.residual_histories
    system.destroy()
    return np.array(rows), histories


@pytest.mark.mpi
def test_fe_coupled_step_newton_rate():
    """Plate with mass tied to the deformable block, springs plate–ground and plate–block
    node, spinning and translating (rotation steps of ~0.1 rad): Newton converges in <= 6
    iterations per step, superlinearly with orders rising to 2 (measured, e.g. residuals
    13.4, 3.9e-2, 4.8e-5, 1.1e-9, 3.9e-13: the nearly incompressible top layer is strongly
    nonlinear, so the pre-asymptotic orders are ~1.6-2.6; the tangent itself is exact: see the
    Taylor test, and a central finite-difference check agreed to 1e-9)."""
    rows, histories = fe_dynamic_run(MPI.COMM_WORLD)
    for i, history in enumerate(histories):
        # the rate from the largest residual on (the first iterates may grow: the tied nodes
        # turn exactly, the free ones by the linearised increment)
        orders = quadratic_orders(history[int(np.argmax(history)) :], floor=1e-11)
        print(
            f"FE step {i}: {len(history) - 1} Newton iterations, residuals {history}, "
            f"orders {orders}"
        )
        assert len(history) - 1 <= 6 and len(orders) >= 1 and min(orders) > 1.5, (history, orders)
    assert np.abs(rows[-1, 3:6]).max() > 0.1  # it did turn


@pytest.mark.mpi
def test_serial_and_parallel_agree():
    """The FE-coupled dynamic run on all ranks (COMM_WORLD) and on each rank alone (COMM_SELF)
    gives the same trajectory to 1e-9 relative (serial under plain pytest)."""
    world, _ = fe_dynamic_run(MPI.COMM_WORLD)
    alone, _ = fe_dynamic_run(MPI.COMM_SELF)
    scale = np.abs(alone).max(axis=0)
    np.testing.assert_allclose(world, alone, rtol=0, atol=1e-9 * scale.max())
    for col in range(9):
        np.testing.assert_allclose(world[:, col], alone[:, col], rtol=0, atol=1e-9 * scale[col])


@pytest.mark.mpi
def test_dynamic_tangent_is_exact_taylor_test():
    """Taylor test of the reduced residual of a dynamic step at a random state far from the
    solution (plate with mass, offset centre and velocities, turned by ~0.6 rad, springs to the
    ground and to a free node): the remainder falls as ε² (rate 2)."""
    springs = [
        Spring("s", "plate", (0.005, 0, 0.04), GROUND, (0.05, 0, 0.06), 100.0),
        Spring("brace", "plate", (-0.005, 0.0, 0.04), "deformable", (-0.005, 0, 0.01), 200.0),
    ]
    plate, system = plate_on_block(
        MPI.COMM_WORLD,
        True,
        springs,
        mass=0.004,
        inertia=[[1e-7, 1e-8, 0], [1e-8, 1.5e-7, 0], [0, 0, 2e-7]],
        centre=[0.002, -0.001, 0.045],
        omega=[30.0, -20.0, 60.0],
        velocity=[0.05, 0.02, 0.0],
        moment=[1e-3, 0, 2e-3],
    )
    system.move("plate", [1e-4, -2e-4, 3e-4], rotation_about([0.2, 0.1, 1.0], 0.6))
    system.start_dynamics()
    system._begin_step(1e-3)  # arm the step's residual without solving
    rng = np.random.default_rng(11 + MPI.COMM_WORLD.rank)
    remainders, rates = taylor_rates(system, rng, 1e-3)
    assert np.all(rates > 1.9), (remainders, rates)  # second order: an exact tangent
    system.destroy()


@pytest.mark.mpi
def test_mass_is_ignored_by_static_solves():
    """The default (static) behaviour is unchanged: a body with a mass in a static system, or a
    static solve in a dynamic one, lands where the massless body does."""
    springs, _ = six_springs()
    loads = {"force": [1.0, 2.0, -1.0], "moment": [0.5, -0.2, 0.3]}
    ref = RigidBody("b", np.zeros(3), **loads)
    RigidSystem([ref], springs, comm=MPI.COMM_WORLD).solve()
    for dynamic in (False, True):
        body = RigidBody("b", np.zeros(3), mass=2.0, inertia=[1, 2, 3], omega=[1, 0, 0], **loads)
        RigidSystem([body], springs, comm=MPI.COMM_WORLD, dynamic=dynamic).solve()
        np.testing.assert_allclose(body.translation, ref.translation, rtol=1e-13, atol=1e-15)
        np.testing.assert_allclose(body.rotation, ref.rotation, rtol=0, atol=1e-13)


@pytest.mark.mpi
def test_bad_dynamic_input_is_named_before_any_solve():
    """Negative, zero or non-finite mass, an inertia that is not symmetric positive-definite, a
    mass without inertia, a massless free body in a dynamic scene, a step of a static system and
    a non-positive step: ValueError naming the body and the value."""
    with pytest.raises(
        ValueError,
        match=r"rigid body 'humerus': mass must be finite and > 0 kg, "
        r"got -2.0",
    ):
        RigidBody("humerus", np.zeros(3), mass=-2.0, inertia=[1, 1, 1])
    with pytest.raises(ValueError, match="rigid body 'humerus': mass must be .* got 0.0"):
        RigidBody("humerus", np.zeros(3), mass=0.0, inertia=[1, 1, 1])
    with pytest.raises(ValueError, match="rigid body 'humerus': mass must be .* got nan"):
        RigidBody("humerus", np.zeros(3), mass=float("nan"), inertia=[1, 1, 1])
    bad = np.array([[1.0, 2.0, 0.0], [2.0, 1.0, 0.0], [0.0, 0.0, 1.0]])  # eigenvalues -1, 1, 3
    with pytest.raises(
        ValueError,
        match=r"rigid body 'scapula': inertia must be positive-"
        r"definite, got eigenvalues \[-1\.0",
    ):
        RigidBody("scapula", np.zeros(3), mass=1.0, inertia=bad)
    with pytest.raises(ValueError, match=r"'scapula': inertia must be positive-definite.*\[-0\.5"):
        RigidBody("scapula", np.zeros(3), mass=1.0, inertia=[1.0, -0.5, 2.0])
    with pytest.raises(ValueError, match="rigid body 'scapula': inertia must be symmetric"):
        RigidBody("scapula", np.zeros(3), mass=1.0, inertia=[[1, 0.1, 0], [0, 1, 0], [0, 0, 1]])
    with pytest.raises(ValueError, match="rigid body 'scapula': a mass of 1.0 kg needs an inertia"):
        RigidBody("scapula", np.zeros(3), mass=1.0)
    body = RigidBody("clavicle", np.zeros(3))
    with pytest.raises(ValueError, match="rigid body 'clavicle': mass must be .* got -1"):
        body.set_mass_properties(-1, [1, 1, 1])
    with pytest.raises(ValueError, match="rigid body 'clavicle' is held by nothing .* no mass"):
        RigidSystem([body], comm=MPI.COMM_WORLD, dynamic=True)
    springs, _ = six_springs()
    static = RigidSystem([RigidBody("b", np.zeros(3))], springs, comm=MPI.COMM_WORLD)
    with pytest.raises(ValueError, match=r"step\(\) needs RigidSystem\(dynamic=True\)"):
        static.step(0.01)
    dynamic = RigidSystem(
        [RigidBody("b", np.zeros(3), mass=1.0, inertia=[1, 1, 1])],
        comm=MPI.COMM_WORLD,
        dynamic=True,
    )
    with pytest.raises(ValueError, match="time step must be finite and > 0 s, got -0.01"):
        dynamic.step(-0.01)
    assert dynamic.stats.solves == 0 and static.stats.solves == 0
