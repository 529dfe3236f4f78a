"""Rigid bodies and springs: hand solutions, exact tangent, Newton's rate, equilibrium, bad input.

Every test here is cheap and runs serially and under ``mpirun -n 2`` (the rigid DOFs live on
rank 0; the deformable block of the Taylor test is distributed).
"""

from __future__ import annotations

import numpy as np
import pytest
import ufl
from _util import quadratic_orders, six_springs, taylor_rates
from mpi4py import MPI

from shoulder_fem.engine.rigid_system import RigidBody, RigidSystem, Tie
from shoulder_fem.engine.so3 import log_so3, rotation_about
from shoulder_fem.engine.springs import GROUND, Spring, spring_response

pytestmark = pytest.mark.mpi


def test_body_on_springs_matches_small_rotation_stiffness():
    """Small force and moment: (t, θ) = K⁻¹ (F, M) to the linearisation error, about |θ| ~ 1e-6
    relative (second-order terms), so 1e-5 relative. Spring tensions match k b_s·(t, θ)."""
    springs, K = six_springs()
    F, M = np.array([1e-4, 2e-4, -1e-4]), np.array([1e-5, -2e-5, 3e-5])
    body = RigidBody("b", np.zeros(3), force=F, moment=M)
    system = RigidSystem([body], springs, comm=MPI.COMM_WORLD)
    system.solve("springs")
    q = np.linalg.solve(K, np.r_[F, M])
    got = np.r_[body.translation, log_so3(body.rotation)]
    np.testing.assert_allclose(got, q, rtol=0, atol=1e-5 * np.abs(q).max())
    tensions = system.spring_forces()
    for s in springs:
        p = np.asarray(s.point_a)
        n = (np.asarray(s.point_a) - np.asarray(s.point_b)) / 0.1
        hand = s.stiffness * np.r_[n, np.cross(p, n)] @ q
        assert tensions[s.name]["tension"] == pytest.approx(hand, abs=1e-5 * np.abs(F).max())
    # Equilibrium to the solver tolerance: snes_atol = 1e-12 (N and N·m rows together).
    bal = system.balance("b")
    assert np.linalg.norm(np.r_[bal.force_sum, bal.moment_sum]) < 1e-12
    system.destroy()


def test_tension_only_spring_goes_slack():
    """A tension-only spring along x from the body's reference point to the ground at +x, no
    preload: pushed towards its anchor it is slack (the six linear springs alone carry the load);
    pulled away it adds k to the x stiffness."""
    springs, K = six_springs()
    k = 500.0
    cable = Spring("cable", "b", (0, 0, 0), GROUND, (0.1, 0, 0), k, tension_only=True)
    for fx in (+1e-4, -1e-4):
        body = RigidBody("b", np.zeros(3), force=[fx, 0, 0])
        system = RigidSystem([body], [*springs, cable], comm=MPI.COMM_WORLD)
        system.solve("cable")
        Kc = K.copy()
        if fx < 0:
            Kc[0, 0] += k
        q = np.linalg.solve(Kc, np.r_[fx, 0, 0, 0, 0, 0])
        assert body.translation[0] == pytest.approx(q[0], rel=1e-6)
        tension = system.spring_forces()["cable"]["tension"]
        assert tension == (0.0 if fx > 0 else pytest.approx(-k * q[0], rel=1e-6))
        system.destroy()


def test_newton_converges_quadratically_at_large_rotation():
    """Loads turning the body by ~0.08 rad and moving it by a spring's rest length fraction: the
    exact tangent (spring geometric stiffness, rotation terms) gives Newton's quadratic rate."""
    springs, _ = six_springs()
    body = RigidBody("b", np.zeros(3), force=[1.0, 2.0, -1.0], moment=[0.5, -0.2, 0.3])
    system = RigidSystem([body], springs, comm=MPI.COMM_WORLD, options={"snes_atol": 1e-13})
    its = system.solve("large")
    history = system.stats.residual_histories[-1]
    orders = quadratic_orders(history, floor=1e-12)
    print(f"springs, large rotation: {its} Newton iterations, residuals {history}, orders {orders}")
    assert np.linalg.norm(log_so3(body.rotation)) > 0.05
    assert its <= 6 and len(orders) >= 2 and min(orders) > 1.8, (history, orders)
    system.destroy()


def test_rigid_to_rigid_spring_and_prescribed_body():
    """Body "b" on a spring to a prescribed body "a" turned by 120°: the spring follows "a"'s
    rotated attachment point and "b" settles where the hand solution puts it; "a" is held by
    its prescription (no reaction needed for a static scene)."""
    springs, K = six_springs(k=1.0)  # soft: the link spring dominates along x
    a = RigidBody("a", np.array([1.0, 0, 0]), prescribed=True)
    b = RigidBody("b", np.zeros(3))
    link = Spring("link", "b", (0.0, 0, 0), "a", (0.5, 0, 0), 1e4, rest_length=0.5)
    system = RigidSystem([a, b], [*springs, link], comm=MPI.COMM_WORLD)
    R = rotation_about([0, 0, 1], 2 * np.pi / 3)
    a.prescribe(np.zeros(3), R)
    system.solve("link")
    assert np.allclose(a.rotation, R, atol=1e-14) and np.allclose(a.translation, 0.0)
    anchor = a.position((0.5, 0, 0))
    resp = spring_response(link, b.position((0, 0, 0)), anchor)
    bal = system.balance("b")
    assert np.abs(bal.force_sum).max() < 1e-9 * abs(resp.tension)
    assert np.abs(bal.moment_sum).max() < 1e-9 * abs(resp.tension)
    assert resp.length == pytest.approx(0.5 + resp.tension / 1e4, rel=1e-12)
    system.destroy()


# ---- a small deformable block for the FE-coupled checks ----------------------------------


def small_block(comm: MPI.Comm = MPI.COMM_WORLD):
    """A 2×2×4 Q1 neo-Hookean block (10 mm × 10 mm × 40 mm), base and top surfaces."""
    import dolfinx

    from shoulder_fem.forms import materials
    from shoulder_fem.forms import virtual_power as vp
    from shoulder_fem.meshes.block import BASE, TOP, build_block

    mesh, _, tags = build_block(comm, 0.01, 0.04, 2, 4)
    V = dolfinx.fem.VectorFunctionSpace(mesh, ("Lagrange", 1))
    u = dolfinx.fem.Function(V)
    law = materials.NeoHookean(c10=0.5e6, bulk_modulus=20e6)
    dx = ufl.dx(domain=mesh, metadata={"quadrature_degree": 2})
    residual = vp.internal_power_finite(law, u, ufl.TestFunction(V), dx)
    surfaces = {"base": (tags, BASE.id), "top": (tags, TOP.id)}
    return u, residual, surfaces


def plate_system(
    plate: RigidBody,
    springs,
    options: dict | None = None,
    comm: MPI.Comm = MPI.COMM_WORLD,
    dynamic: bool = False,
) -> RigidSystem:
    """:func:`small_block` with its base fixed and its top tied to ``plate``."""
    u, residual, surfaces = small_block(comm)
    return RigidSystem(
        [plate],
        list(springs),
        u=u,
        residual=residual,
        surfaces=surfaces,
        ties=[Tie("plate", "top")],
        fixed=["base"],
        dynamic=dynamic,
        options=options,
    )


def test_reaction_on_surfaces_that_share_nodes_counts_them_once():
    """The base fixed as two halves that share a line of nodes: the reaction over both names is
    the reaction of the same block with the base fixed whole (solved apart), while the plain sum
    of the halves' reactions counts the shared line twice."""
    import dolfinx

    def solved(split: bool):
        u, residual, surfaces = small_block()
        tags, base = surfaces["base"]
        mesh = u.function_space.mesh
        facets = tags.find(base)
        fixed = ["base"]
        if split:  # two halves of the base, by their facets' midpoints
            x = dolfinx.mesh.compute_midpoints(mesh, 2, facets)[:, 0]
            order = np.argsort(facets)
            values = np.where(x[order] < 0.0, 1, 2).astype(np.int32)
            halves = dolfinx.mesh.meshtags(mesh, 2, facets[order], values)
            surfaces = {"top": surfaces["top"], "left": (halves, 1), "right": (halves, 2)}
            fixed = ["left", "right"]
        plate = RigidBody("plate", (0, 0, 0.04), force=[0.3, -0.2, 0.5], moment=[1e-4, 0, 2e-4])
        options = {"snes_rtol": 1e-12, "snes_atol": 1e-12, "snes_max_it": 30}
        system = RigidSystem(
            [plate],
            u=u,
            residual=residual,
            surfaces=surfaces,
            ties=[Tie("plate", "top")],
            fixed=fixed,
            options=options,
        )
        system.solve()
        return system, fixed

    whole, _ = solved(split=False)
    halves, names = solved(split=True)
    F, M = whole.reaction("base")
    F2, M2 = halves.reaction(names)
    assert np.allclose(F2, F, atol=1e-9 * np.abs(F).max()), (F2, F)
    assert np.allclose(M2, M, atol=1e-9 * np.abs(M).max()), (M2, M)
    # the plate's applied force comes back at the base
    assert np.allclose(F, [-0.3, 0.2, -0.5], atol=1e-9), F
    summed = sum(halves.reaction(n)[0] for n in names)
    assert np.linalg.norm(summed - F) > 1e-3 * np.linalg.norm(F), (summed, F)
    whole.destroy()
    halves.destroy()


def test_tangent_is_exact_taylor_test():
    """Taylor test of the reduced residual at a random, far-from-equilibrium state (plate turned
    by ~0.6 rad, random free displacements, springs plate-ground, node-ground and plate-node,
    an applied moment): the remainder
    |r(x + εd) - r(x) - ε J d| falls as ε² (rate 2), i.e. the tangent (PtAP, tie geometric
    term, rotation-parametrisation term, springs) is the exact derivative."""
    plate = RigidBody("plate", (0, 0, 0.04), moment=[1e-3, 0, 2e-3])
    springs = [
        Spring("s", "plate", (0.005, 0, 0.04), GROUND, (0.05, 0, 0.06), 100.0),
        # deformable ends: a free node on a side face, to the ground and to the plate
        Spring("side", "deformable", (0.005, 0, 0.02), GROUND, (0.03, 0.01, 0.02), 300.0),
        Spring("brace", "plate", (-0.005, 0.0, 0.04), "deformable", (-0.005, 0, 0.01), 200.0),
    ]
    system = plate_system(plate, springs)
    rng = np.random.default_rng(7 + MPI.COMM_WORLD.rank)
    system.move("plate", [1e-4, -2e-4, 3e-4], rotation_about([0.2, 0.1, 1.0], 0.6))
    remainders, rates = taylor_rates(system, rng, 1e-4)
    assert np.all(rates > 1.9), (remainders, rates)  # second order: an exact tangent
    system.destroy()


def _plate_on_block(offset: np.ndarray | None):
    """The small block under a plate held by two springs and a moment; the tied nodes and the
    springs' plate ends offset by ``offset`` (m, plate frame) when given: (system, plate)."""
    plate = RigidBody("plate", (0, 0, 0.04), moment=[2e-3, -1e-3, 3e-3])
    springs = [
        Spring("a", "plate", (0.005, 0, 0.04), GROUND, (0.05, 0.01, 0.06), 400.0),
        Spring("b", "plate", (-0.005, 0.002, 0.04), GROUND, (-0.04, 0.0, 0.07), 300.0),
    ]
    options = {"snes_rtol": 1e-12, "snes_atol": 1e-13, "snes_max_it": 30}
    system = plate_system(plate, springs, options)
    if offset is not None:
        o = np.asarray(offset, dtype=float)
        system.set_tie_offsets("plate", lambda X: np.tile(o, (len(X), 1)), {"a": o, "b": o})
    return system, plate


def test_tie_offsets_move_the_surface_in_the_body_frame():
    """A body whose tied nodes and spring ends are all offset by the same o (its frame) is the
    same body moved by o: the offset system's solution (t, R) and the plain one's (t', R')
    satisfy R = R', t' = t + R o, with the same displacement field (the applied load is a
    couple, which does not care where the body's reference point is)."""
    o = np.array([3e-4, -2e-4, 1e-4])
    system, plate = _plate_on_block(o)
    system.move("plate", [0, 0, 0], rotation_about([0.0, 0.3, 1.0], 0.05))
    system.solve("offset")
    t, R, u = plate.translation.copy(), plate.rotation.copy(), system.u.x.array.copy()
    system.destroy()
    system, plate = _plate_on_block(None)
    system.move("plate", [0, 0, 0], rotation_about([0.0, 0.3, 1.0], 0.05))
    system.solve("plain")
    assert np.linalg.norm(log_so3(plate.rotation @ R.T)) < 1e-9
    assert np.allclose(plate.translation, t + R @ o, rtol=0, atol=1e-11)
    assert np.abs(system.u.x.array - u).max() < 1e-10
    assert np.linalg.norm(R @ o) > 1e-4  # the two motions differ by much more than that
    system.destroy()


def test_tangent_is_exact_with_tie_offsets():
    """Taylor test with different random offsets per tied node (and per spring end) at a turned
    plate: the prolongation and the tie's geometric term use the offset points (rate 2)."""
    system, plate = _plate_on_block(None)
    rng = np.random.default_rng(3 + MPI.COMM_WORLD.rank)
    system.set_tie_offsets(
        "plate",
        lambda X: 1e-3 * np.sin(400 * X + 1.0),  # the same at a node shared by two ranks
        {"a": [1e-3, 0, -5e-4]},
    )
    system.move("plate", [1e-4, -2e-4, 3e-4], rotation_about([0.2, 0.1, 1.0], 0.6))
    remainders, rates = taylor_rates(system, rng, 1e-4)
    assert np.all(rates > 1.9), (remainders, rates)
    with pytest.raises(ValueError, match="bad spring offset 'c'"):
        system.set_tie_offsets("plate", None, {"c": [0, 0, 0]})
    with pytest.raises(ValueError, match="one 3-vector"):
        system.set_tie_offsets("plate", lambda X: np.zeros((len(X), 2)))
    system.destroy()


def _linear_block_with_plate(load: float, linear_ties: bool):
    """Linear elastic block, base fixed, a plate tied to the top under a force and a moment
    (scaled by ``load``): (system, plate)."""
    import dolfinx

    from shoulder_fem.forms import materials
    from shoulder_fem.forms import virtual_power as vp
    from shoulder_fem.meshes.block import BASE, TOP, build_block

    mesh, _, tags = build_block(MPI.COMM_WORLD, 0.01, 0.04, 2, 4)
    V = dolfinx.fem.VectorFunctionSpace(mesh, ("Lagrange", 1))
    u = dolfinx.fem.Function(V)
    law = materials.LinearElastic(1e9, 0.3)
    residual = vp.internal_power_linear(law, u, ufl.TestFunction(V), ufl.dx(domain=mesh))
    plate = RigidBody(
        "plate",
        (0, 0, 0.04),
        force=load * np.array([0.2, -0.1, 0.5]),
        moment=load * np.array([3e-3, 2e-3, -4e-3]),
    )
    system = RigidSystem(
        [plate],
        [],
        u=u,
        residual=residual,
        surfaces={"base": (tags, BASE.id), "top": (tags, TOP.id)},
        ties=[Tie("plate", "top")],
        fixed=["base"],
        linear_ties=linear_ties,
        options={"snes_rtol": 1e-12, "snes_atol": 1e-14, "snes_max_it": 5 if linear_ties else 40},
    )
    return system, plate


def test_linear_ties_make_a_linear_problem():
    """With ``linear_ties`` a linear elastic body with a tied plate is a linear problem: one
    Newton iteration, a response proportional to the load, and the finite-rotation ties'
    response at a small load (where the two agree to the order of the rotation)."""
    system, plate = _linear_block_with_plate(1.0, linear_ties=True)
    its = system.solve("load 1")
    hist = system.stats.residual_histories[-1]
    assert its <= 2 and hist[1] < 1e-9 * hist[0], hist
    t1, u1 = plate.translation.copy(), system.u.x.array.copy()
    phi1 = log_so3(plate.rotation)
    system.destroy()
    system, plate = _linear_block_with_plate(2.0, linear_ties=True)
    system.solve("load 2")
    assert np.allclose(plate.translation, 2 * t1, rtol=1e-8, atol=1e-15)
    assert np.allclose(log_so3(plate.rotation), 2 * phi1, rtol=1e-8, atol=1e-15)
    assert np.allclose(system.u.x.array, 2 * u1, rtol=1e-8, atol=1e-15)
    system.destroy()
    # finite-rotation ties: the rotation is ~1e-4 rad, the difference of that order
    assert 1e-6 < np.linalg.norm(phi1) < 1e-3
    system, plate = _linear_block_with_plate(1.0, linear_ties=False)
    system.solve("finite")
    scale = np.abs(u1).max()
    assert np.abs(system.u.x.array - u1).max() < 1e-2 * scale
    assert np.linalg.norm(log_so3(plate.rotation) - phi1) < 1e-2 * np.linalg.norm(phi1)
    system.destroy()


def test_mass_properties_of_a_bar():
    """A 10 × 10 × 40 mm bar of density 1800 kg/m³ on [-5, 5]² × [0, 40] mm:
    m = ρ a² L, G = (0, 0, L/2), I_xx = I_yy = m (a² + L²)/12, I_zz = m a²/6."""
    from shoulder_fem.engine.mass import mass_properties
    from shoulder_fem.meshes.block import build_block

    mesh, _, _ = build_block(MPI.COMM_WORLD, 0.01, 0.04, 2, 4)
    props = mass_properties(mesh, 1800.0, ufl.dx(domain=mesh, metadata={"quadrature_degree": 2}))
    m = 1800.0 * 0.01**2 * 0.04
    assert props.mass == pytest.approx(m, rel=1e-12)
    np.testing.assert_allclose(props.centre, [0, 0, 0.02], atol=1e-14)
    Ixx = m * (0.01**2 + 0.04**2) / 12
    np.testing.assert_allclose(
        props.inertia, np.diag([Ixx, Ixx, m * 0.01**2 / 6]), rtol=0, atol=1e-12 * Ixx
    )


def test_bad_input_is_named_before_any_solve():
    """A tie to a missing surface, a tie to an unknown body, a spring on an unknown body and a
    free body held by nothing all raise ValueError naming the culprit, while building."""
    u, residual, surfaces = small_block()
    plate = RigidBody("plate", (0, 0, 0.04))
    common = {"u": u, "residual": residual, "surfaces": surfaces, "fixed": ["base"]}
    with pytest.raises(ValueError, match="surface 'lid' does not exist"):
        RigidSystem([plate], ties=[Tie("plate", "lid")], **common)
    with pytest.raises(ValueError, match="unknown rigid body 'bone'"):
        RigidSystem([plate], ties=[Tie("bone", "top")], **common)
    spring = Spring("ligament", "scapula", (0, 0, 0), GROUND, (0, 0, 1), 10.0)
    with pytest.raises(ValueError, match="spring 'ligament': unknown body 'scapula'"):
        RigidSystem([plate], [spring], ties=[Tie("plate", "top")], **common)
    loose = RigidBody("humerus", (0, 0, 0.1), force=[0, 0, -1.0])
    with pytest.raises(ValueError, match="rigid body 'humerus' is held by nothing"):
        RigidSystem([plate, loose], ties=[Tie("plate", "top")], **common)
    with pytest.raises(ValueError, match="rigid body 'humerus' is held by nothing"):
        RigidSystem([loose], comm=MPI.COMM_WORLD)
    off = Spring("off", "deformable", (0.001, 0.002, 0.003), GROUND, (0, 0, 1), 10.0)
    with pytest.raises(ValueError, match="spring 'off': point .* is not a node"):
        RigidSystem([plate], [off], ties=[Tie("plate", "top")], **common)
    with pytest.raises(ValueError, match="spring 'bad': stiffness"):
        Spring("bad", "plate", (0, 0, 0), GROUND, (1, 0, 0), -1.0)


def test_cell_region_tie_carries_every_node_of_its_cells():
    """A tie named by cell tags ties every node of those cells (vertices, P2 mid-edge nodes,
    nodes inside the block): the upper half of a P2 block follows a prescribed plate turned
    by 0.3 rad exactly, u = t + (R - I)(X - X_ref) (the tie kinematics), while the lower half
    deforms between it and the fixed base."""
    import dolfinx

    from shoulder_fem.forms import materials
    from shoulder_fem.forms import virtual_power as vp
    from shoulder_fem.meshes.block import BASE, build_block

    mesh, _, tags = build_block(MPI.COMM_WORLD, 0.01, 0.04, 2, 4)
    V = dolfinx.fem.VectorFunctionSpace(mesh, ("Lagrange", 2))
    u = dolfinx.fem.Function(V)
    tdim = mesh.topology.dim
    n_cells = mesh.topology.index_map(tdim).size_local + mesh.topology.index_map(tdim).num_ghosts
    cells = np.arange(n_cells, dtype=np.int32)
    upper = cells[dolfinx.mesh.compute_midpoints(mesh, tdim, cells)[:, 2] > 0.02]
    region = dolfinx.mesh.meshtags(mesh, tdim, upper, np.full(len(upper), 9, dtype=np.int32))
    law = materials.SaintVenantKirchhoff(1e6, 0.3)
    dx = ufl.dx(domain=mesh, metadata={"quadrature_degree": 4})
    residual = vp.internal_power_finite(law, u, ufl.TestFunction(V), dx)
    ref = np.array([0.0, 0.0, 0.04])
    plate = RigidBody("plate", ref, prescribed=True)
    system = RigidSystem(
        [plate],
        [],
        u=u,
        residual=residual,
        surfaces={"base": (tags, BASE.id), "upper": (region, 9)},
        ties=[Tie("plate", "upper")],
        fixed=["base"],
        options={"snes_atol": 1e-10, "snes_rtol": 1e-10},
    )
    t, R = np.array([1e-3, -5e-4, 2e-3]), rotation_about([0.0, 0.0, 1.0], 0.3)
    plate.prescribe(t, R)
    system.solve("turned")
    tied = dolfinx.fem.locate_dofs_topological(V, tdim, upper)
    X = V.tabulate_dof_coordinates()[tied]
    expected = t + (X - ref) @ (R - np.eye(3)).T
    assert np.abs(u.x.array.reshape(-1, 3)[tied] - expected).max() < 1e-12
    # more than the region's boundary: nodes inside the region are tied too
    inside = X[(X[:, 2] > 0.021) & (X[:, 2] < 0.039)]
    assert MPI.COMM_WORLD.allreduce(len(inside), op=MPI.SUM) > 0
    # and no further: the nodes below the region are strained between it and the fixed base,
    # millimetres from the plate's rigid motion (its translation alone is 2.3 mm)
    X_all = V.tabulate_dof_coordinates()
    lower = np.flatnonzero(X_all[:, 2] < 0.019)
    rigid = t + (X_all[lower] - ref) @ (R - np.eye(3)).T
    gap = np.abs(u.x.array.reshape(-1, 3)[lower] - rigid).max(initial=0.0)
    assert MPI.COMM_WORLD.allreduce(gap, op=MPI.MAX) > 1e-3
    system.destroy()


@pytest.mark.mpi
def test_rigid_regions_turn_a_newton_step_by_a_finite_rotation():
    """:class:`~shoulder_fem.engine.rigid_system.corotation.RigidRegions` on a block with a
    plate tied to its top: a linear rigid step t + ω × (p - c0) (|ω| = 0.3 rad) moves the free
    nodes off a rigid motion by about |ω|² r / 2, so their distances change (measured: by up to
    3.4 % of the largest); corrected, the free nodes and the plate's reference point keep every
    distance to 1e-12 of the largest, i.e. they turn by the finite rotation exp(hat ω) (the
    same on any partition: the fit sums over every rank). The fit recovers ω exactly from the
    linear step."""
    from scipy.spatial.distance import pdist

    from shoulder_fem.engine.rigid_system.corotation import rigid_fit

    comm = MPI.COMM_WORLD
    u, residual, surfaces = small_block(comm)
    plate = RigidBody("plate", (0.001, -0.002, 0.04))
    plate.translation = np.array([1e-4, 2e-4, -3e-4])
    foot = RigidBody("foot", (0.0, 0.0, 0.0))  # a second body: the region's ties, gathered
    V = u.function_space
    n_all = V.dofmap.index_map.size_local + V.dofmap.index_map.num_ghosts
    system = RigidSystem(
        [plate, foot],
        [Spring("hold", "foot", (0.0, 0.0, 0.0), GROUND, (0.0, 0.0, -0.1), 1e3)],
        u=u,
        residual=residual,
        surfaces=surfaces,
        ties=[Tie("plate", "top"), Tie("foot", "base")],
        rigid_regions=[np.arange(n_all)],
    )
    regions = system.rigid_regions
    lay = regions.layout
    assert list(regions.tied[0]) == [0, 1]  # both plates are tied to the region
    rng = np.random.default_rng(3 + comm.rank)
    n = lay.n_free_local
    x = np.zeros(lay.n_local)
    x[:n] = 1e-4 * rng.standard_normal(n)  # a current state: free displacements
    if comm.rank == 0:
        x[n : n + 3] = plate.translation
    omega, t, c0 = np.array([0.1, -0.2, 0.2]), np.array([1e-3, 0.0, 2e-3]), np.array([0, 0, 0.02])
    p = lay.X[lay.free_nodes] + x[:n].reshape(-1, 3)
    d = np.zeros(lay.n_local)
    d[:n] = (t + np.cross(omega, p - c0)).ravel()
    ref = plate.reference_point + plate.translation
    if comm.rank == 0:
        d[n : n + 3] = t + np.cross(omega, ref - c0)
        d[n + 3 : n + 6] = omega
    _, fitted = rigid_fit(p, d[:n].reshape(-1, 3), comm)
    assert np.allclose(fitted, omega, rtol=0, atol=1e-12), fitted

    def moved(step):  # every free node and the plate's reference point after the step
        pts = np.vstack(comm.allgather(p + step[:n].reshape(-1, 3)))
        end = comm.bcast(ref + step[n : n + 3] if comm.rank == 0 else None, root=0)
        return np.vstack([pts, end])

    before = pdist(np.vstack([np.vstack(comm.allgather(p)), ref]))
    linear = pdist(moved(d))
    assert np.abs(linear - before).max() > 0.01 * before.max()  # a linear rotation deforms
    theta = regions.correct(x, d)
    assert theta == pytest.approx(np.linalg.norm(omega), rel=1e-12)
    after = pdist(moved(d))
    assert np.abs(after - before).max() <= 1e-12 * before.max()
    system.destroy()
