"""Contact: the numpy assembly against UFL, exact penalty solutions, the patch test, action and
reaction, friction, large sliding, robustness, Hertz, and serial = MPI."""

from __future__ import annotations

import math

import dolfinx
import dolfinx.fem.petsc as fem_petsc
import numpy as np
import pytest
import ufl
from mpi4py import MPI
from petsc4py import PETSc

from shoulder_fem.api import run
from shoulder_fem.engine.contact import (
    Contact,
    ContactError,
    ContactPair,
    MeshSurface,
    Plane,
    Sphere,
    penalty_law,
)
from shoulder_fem.engine.solver import ConvergenceError, NonlinearSolver, StepperStats, march
from shoulder_fem.families.hertz import hertz_solution
from shoulder_fem.families.hertz.theory import fit_hertz_profile, hertz_profile
from shoulder_fem.forms import contact as fc
from shoulder_fem.forms import materials
from shoulder_fem.forms import virtual_power as vp
from shoulder_fem.meshes import contact_bodies as cb
from shoulder_fem.scene import load_scene

E, NU = 1.0e9, 0.3
BOTTOM, TOP, XMIN, YMIN = 1, 2, 3, 4


def _column(n=(3, 3, 4), size=(1.0, 1.0, 2.0), degree=1):
    """A box on z in [0, H] with tagged bottom, top and the two symmetry faces."""
    mesh = dolfinx.mesh.create_box(
        MPI.COMM_WORLD, [[0, 0, 0], list(size)], list(n), dolfinx.mesh.CellType.tetrahedron
    )
    H = size[2]
    found = [
        (BOTTOM, lambda x: np.isclose(x[2], 0.0)),
        (TOP, lambda x: np.isclose(x[2], H)),
        (XMIN, lambda x: np.isclose(x[0], 0.0)),
        (YMIN, lambda x: np.isclose(x[1], 0.0)),
    ]
    idx, val = [], []
    for tag, where in found:
        f = dolfinx.mesh.locate_entities_boundary(mesh, 2, where)
        idx.append(f)
        val.append(np.full(len(f), tag, dtype=np.int32))
    idx, val = np.concatenate(idx), np.concatenate(val)
    order = np.argsort(idx)
    ft = dolfinx.mesh.meshtags(mesh, 2, idx[order], val[order])
    V = dolfinx.fem.VectorFunctionSpace(mesh, ("CG", degree))
    return mesh, ft, V


def _component_bc(V, ft, tag, comp, value):
    fdim = V.mesh.topology.dim - 1
    dofs = dolfinx.fem.locate_dofs_topological(V.sub(comp), fdim, ft.find(tag))
    const = dolfinx.fem.Constant(V.mesh, PETSc.ScalarType(value))
    return dolfinx.fem.dirichletbc(const, dofs, V.sub(comp)), const, dofs


def _reaction(residual_form, dofs) -> float:
    """Sum of the FE internal force over owned ``dofs`` (unrolled), all ranks."""
    vec = fem_petsc.assemble_vector(residual_form)
    vec.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    n_owned = len(vec.array_r)
    local = float(np.sum(vec.array_r[dofs[dofs < n_owned]]))
    vec.destroy()
    return MPI.COMM_WORLD.allreduce(local, op=MPI.SUM)


class Column:
    """A linear-elastic column pressed on a rigid plane through its top face."""

    def __init__(
        self,
        master,
        penalty,
        method="penalty",
        gap_tolerance=1e-9,
        friction=0.0,
        slip=1e-9,
        n=(3, 3, 4),
        options=None,
        poisson=NU,
    ):
        self.mesh, self.ft, self.V = _column(n)
        self.u = dolfinx.fem.Function(self.V)
        w = ufl.TestFunction(self.V)
        dx = ufl.Measure("dx", domain=self.mesh)
        self.F = vp.internal_power_linear(materials.LinearElastic(E, poisson), self.u, w, dx)
        self.form = dolfinx.fem.form(self.F)
        bx, _, _ = _component_bc(self.V, self.ft, XMIN, 0, 0.0)
        by, _, _ = _component_bc(self.V, self.ft, YMIN, 1, 0.0)
        bz, self.top_z, self.top_z_dofs = _component_bc(self.V, self.ft, TOP, 2, 0.0)
        self.bcs = [by, bz] if friction > 0 else [bx, by, bz]
        self.top_x = None
        if friction > 0:  # drag: the top face is moved along x too
            btx, self.top_x, self.top_x_dofs = _component_bc(self.V, self.ft, TOP, 0, 0.0)
            self.bcs.append(btx)
        pair = ContactPair(
            "base",
            (BOTTOM,),
            master,
            penalty,
            method=method,
            gap_tolerance=gap_tolerance,
            friction=friction,
            slip_regularization=slip,
        )
        self.contact = Contact(self.V, self.u, self.ft, [pair], bcs=self.bcs, quadrature_degree=0)
        self.solver = NonlinearSolver(
            self.F,
            self.u,
            self.bcs,
            name="column",
            options={"snes_atol": 1e-9, "snes_rtol": 1e-12, **(options or {})},
            contact=self.contact,
        )

    def solve(self, max_uzawa=40) -> int:
        for k in range(max_uzawa):
            self.solver.solve()
            if not self.contact.augmented or self.contact.augment():
                return k + 1
        raise AssertionError("Uzawa did not converge")

    def reaction(self, comp: int) -> float:
        dofs = self.top_z_dofs if comp == 2 else self.top_x_dofs
        return _reaction(self.form, np.asarray(dofs))


# ---- the assembly against UFL -----------------------------------------------------------------
@pytest.mark.mpi
@pytest.mark.parametrize("degree", [1, 2])
@pytest.mark.parametrize(
    "master",
    [
        Plane((0.0, 0.0, 0.01), (0.05, 0.02, 1.0)),
        Sphere((0.5, 0.4, -2.9), 3.0),
        Sphere((0.5, 0.4, 2.0), 2.03, concave=True),
    ],
    ids=["plane", "ball", "socket"],
)
def test_assembly_matches_ufl_penalty_form(degree, master):
    """Residual and tangent (curvature term included) of the numpy contact assembly equal the
    UFL penalty form and its automatic derivative when every point is in contact (so that
    both quadratures integrate a polynomial exactly): to round-off, serial and MPI."""
    mesh, ft, V = _column((3, 3, 2), (1.0, 1.0, 0.5), degree)
    u = dolfinx.fem.Function(V)
    u.interpolate(
        lambda x: np.vstack([0.01 * x[1] ** 2, -0.02 * x[0] * x[1], -0.05 - 0.01 * x[0] ** 2])
    )
    eps = 1e3
    c = Contact(
        V,
        u,
        ft,
        [ContactPair("p", (BOTTOM,), master, eps)],
        quadrature_degree=6,
        slave_integration="element",
    )
    w = ufl.TestFunction(V)
    ds = ufl.Measure("ds", domain=mesh, subdomain_data=ft, metadata={"quadrature_degree": 6})
    if isinstance(master, Plane):
        g, n = fc.plane_gap(u, ufl.as_vector(master.point), ufl.as_vector(master.normal))
    else:
        g, n = fc.sphere_gap(u, ufl.as_vector(master.centre), master.radius, master.concave)
    F = fc.penalty_contact_power(g, n, eps, w, ds(BOTTOM))
    J = ufl.derivative(F, u)
    b_ufl = fem_petsc.assemble_vector(dolfinx.fem.form(F))
    b_ufl.ghostUpdate(PETSc.InsertMode.ADD, PETSc.ScatterMode.REVERSE)
    b = b_ufl.duplicate()
    b.set(0.0)
    c.add_residual(b)
    A_ufl = fem_petsc.assemble_matrix(dolfinx.fem.form(J))
    A_ufl.assemble()
    A = fem_petsc.assemble_matrix(dolfinx.fem.form(J))
    A.assemble()
    A.zeroEntries()
    c.add_jacobian(A)
    assert c.resultants()["p"]["active_points"] == MPI.COMM_WORLD.allreduce(
        len(c._state[0]["p"]), op=MPI.SUM
    )
    b.axpy(-1.0, b_ufl)
    A.axpy(-1.0, A_ufl)
    assert b.norm() <= 1e-13 * b_ufl.norm()
    assert A.norm() <= 1e-13 * A_ufl.norm()


# ---- exact penalty / augmented solutions -------------------------------------------------------
@pytest.mark.mpi
def test_penalty_column_exact_and_penetration_falls_with_penalty():
    """Uniaxial stress in a column on a rigid plane: p = E δ/(H + E/ε) exactly, penetration p/ε,
    falling as the penalty ε rises. The penalty's stored energy 1/2 ∫ p (-g) dA is p²/(2ε) per
    unit area, and its share of the energy, with the column's strain energy p² H/(2E), is the
    penalty's share of the series compliance, (1/ε)/(1/ε + H/E) (what the shoulder's
    ``glenohumeral_penalty_energy_share`` measures)."""
    H, delta = 2.0, 1e-3
    pens = []
    for factor in (10.0, 100.0, 1000.0):
        eps = factor * E / H
        col = Column(Plane((0, 0, 0), (0, 0, 1)), eps)
        col.top_z.value = -delta
        col.solve()
        r = col.contact.resultants()["base"]
        p = E * delta / (H + E / eps)
        assert r["max_pressure"] == pytest.approx(p, rel=1e-8)
        assert r["normal_force"] == pytest.approx(p * 1.0, rel=1e-8)  # unit area
        assert r["area"] == pytest.approx(1.0, rel=1e-12)
        assert r["max_penetration"] == pytest.approx(p / eps, rel=1e-7)
        assert -col.reaction(2) == pytest.approx(r["force"][2], rel=1e-8)
        pens.append(r["max_penetration"])
        assert r["penalty_energy"] == pytest.approx(p**2 / (2 * eps), rel=1e-7)
        W = materials.LinearElastic(E, NU).strain_energy_density(ufl.sym(ufl.grad(col.u)))
        form = dolfinx.fem.form(W * ufl.dx(domain=col.mesh))
        column = MPI.COMM_WORLD.allreduce(dolfinx.fem.assemble_scalar(form))
        assert column == pytest.approx(p**2 * H / (2 * E), rel=1e-7)
        share = r["penalty_energy"] / (r["penalty_energy"] + column)
        assert share == pytest.approx((1 / eps) / (1 / eps + H / E), rel=1e-7)
    assert pens[0] > 9 * pens[1] > 81 * pens[2]


@pytest.mark.mpi
def test_augmented_lagrangian_gap_below_tolerance():
    """With a soft penalty (penetration 9 % of δ by penalty alone) the Uzawa iterations bring
    the gap below its tolerance and the pressure to E δ / H."""
    H, delta, tol = 2.0, 1e-3, 1e-8
    col = Column(Plane((0, 0, 0), (0, 0, 1)), 10.0 * E / H, method="augmented", gap_tolerance=tol)
    col.top_z.value = -delta
    uzawa = col.solve()
    r = col.contact.resultants()["base"]
    assert uzawa > 2
    assert r["max_penetration"] <= tol
    assert r["max_pressure"] == pytest.approx(E * delta / H, rel=1e-4)


@pytest.mark.mpi
def test_no_contact_gives_zero_force_not_nan():
    """A column lifted off the plane: zero force, zero pressure field, a finite residual."""
    col = Column(Plane((0, 0, -1.0), (0, 0, 1)), 100 * E)
    col.top_z.value = 1e-3
    col.solve()
    r = col.contact.resultants()["base"]
    assert np.all(r["force"] == 0.0) and r["area"] == 0.0 and r["max_pressure"] == 0.0
    assert r["centre_of_pressure"] is None and r["active_points"] == 0
    p, s = col.contact.pressure_fields()
    assert np.all(p.x.array == 0.0) and np.all(s.x.array == 0.0)
    assert np.isfinite(col.solver.residual_norm())


@pytest.mark.mpi
def test_initial_penetration_is_resolved():
    """The plane starts 1 mm inside the column (top held): Newton pushes the column out to the
    exact penalty solution p = E d/(H + E/ε)."""
    H, d, eps = 2.0, 1e-3, 100 * E / 2.0
    col = Column(Plane((0, 0, d), (0, 0, 1)), eps)
    col.solve()
    r = col.contact.resultants()["base"]
    assert r["max_pressure"] == pytest.approx(E * d / (H + E / eps), rel=1e-8)
    assert col.solver.stats.newton_iterations <= 3  # linear once the active set is known


# ---- two deformable blocks ---------------------------------------------------------------------
class TwoBlocks:
    """Upper block pressed on the lower one through non-matching meshes (frictionless)."""

    def __init__(
        self,
        upper=(1.0, 1.0, 0.5),
        offset=(0.0, 0.0),
        h_upper=0.13,
        drag=False,
        lower=(1.0, 1.0, 0.5),
        h_lower=0.2,
        penalty=None,
        degree=1,
        search_depth=math.inf,
    ):
        self.mesh, self.ct, self.ft = cb.build_two_blocks(
            MPI.COMM_WORLD, lower, upper, h_lower, h_upper, offset=offset
        )
        self.H = lower[2] + upper[2]
        V = self.V = dolfinx.fem.VectorFunctionSpace(self.mesh, ("CG", degree))
        self.u = dolfinx.fem.Function(V)
        w = ufl.TestFunction(V)
        dx = ufl.Measure("dx", domain=self.mesh)
        self.F = vp.internal_power_linear(materials.LinearElastic(E, NU), self.u, w, dx)
        self.form = dolfinx.fem.form(self.F)
        bcs = []
        self.eps = penalty or 1000 * E / self.H
        bcs.append(_component_bc(V, self.ft, cb.LOWER_BOTTOM.id, 2, 0.0))
        bcs.append(_component_bc(V, self.ft, cb.LOWER_XMIN.id, 0, 0.0))
        bcs.append(_component_bc(V, self.ft, cb.LOWER_YMIN.id, 1, 0.0))
        bcs.append(_component_bc(V, self.ft, cb.UPPER_TOP.id, 2, 0.0))
        if drag:
            bcs.append(_component_bc(V, self.ft, cb.UPPER_TOP.id, 0, 0.0))
            bcs.append(_component_bc(V, self.ft, cb.UPPER_TOP.id, 1, 0.0))
        else:
            bcs.append(_component_bc(V, self.ft, cb.UPPER_XMIN.id, 0, 0.0))
            bcs.append(_component_bc(V, self.ft, cb.UPPER_YMIN.id, 1, 0.0))
        self.base_dofs, self.top_dofs = np.asarray(bcs[0][2]), np.asarray(bcs[3][2])
        self.top_z = bcs[3][1]
        self.top_x = bcs[4][1] if drag else None
        self.bcs = [b[0] for b in bcs]
        pair = ContactPair(
            "interface",
            (cb.UPPER_BOTTOM.id,),
            MeshSurface((cb.LOWER_TOP.id,)),
            self.eps,
            search_depth=search_depth,
        )
        self.contact = Contact(V, self.u, self.ft, [pair], bcs=self.bcs, quadrature_degree=0)
        self.solver = NonlinearSolver(
            self.F,
            self.u,
            self.bcs,
            name="blocks",
            options={"snes_atol": 1e-6, "snes_rtol": 1e-12},
            contact=self.contact,
        )


def test_segments_cut_in_chunks_are_the_same_points(monkeypatch):
    """The segment cut works through its candidate pairs a chunk at a time (to bound its work
    arrays): cut 7 pairs at a time, the P2 patch test's solve gives the same pressures, gaps and
    force as in one pass, to the last bit (the pairs are independent)."""
    from shoulder_fem.engine.contact import points

    results = []
    for chunk in (points.CUT_CHUNK, 7):
        monkeypatch.setattr(points, "CUT_CHUNK", chunk)
        tb = TwoBlocks(degree=2)
        tb.top_z.value = -1e-3
        tb.solver.solve()
        st = tb.contact._state[0]
        pairs = np.unique(np.stack([st["facet"], st["piece"], st["m_tri"]], axis=1), axis=0)
        assert len(pairs) > 3 * 7  # cut pairs with points: several chunks of 7
        results.append((st["p"].copy(), st["g"].copy(), tb.u.x.array.copy()))
    for a, b in zip(results[0], results[1], strict=True):
        assert np.array_equal(a, b)


@pytest.mark.mpi
@pytest.mark.parametrize("degree", [1, 2])
def test_compiled_segment_kernel_equals_the_numpy_code(monkeypatch, degree):
    """The compiled segment kernel (segments.c) against the numpy code it replaces, on a block
    dragged 0.13 m over a non-matching mesh (P1 and P2; every cut shape: pieces inside a
    master triangle and crossed by its edges): the same points (pairing, weights and shape
    functions, positions, master weights, normals, gaps and pressures to 1e-11), and the
    same consistent tangent (both forward differences of step 1e-8 m, central near kinks:
    to 1e-9 of its largest entry, their round-off is 1.6e-12)."""
    from shoulder_fem.engine.contact import kernel

    monkeypatch.setenv("SHOULDER_FEM_CONTACT_KERNEL", "c")
    if kernel.load() is None:
        pytest.fail("the segment kernel did not compile (see the warning)")
    tb = TwoBlocks(
        upper=(0.3, 0.3, 0.2),
        lower=(1.6, 0.6, 0.3),
        offset=(0.1, 0.15),
        h_upper=0.06,
        h_lower=0.1,
        drag=True,
        degree=degree,
    )
    tb.top_z.value = -2e-4
    tb.solver.solve()
    tb.top_x.value = 0.13
    tb.solver.solve()
    A = fem_petsc.create_matrix(dolfinx.fem.form(ufl.derivative(tb.F, tb.u)))
    results = []
    for choice in ("c", "numpy"):
        monkeypatch.setenv("SHOULDER_FEM_CONTACT_KERNEL", choice)
        tb.contact.evaluate()
        st = tb.contact.point_state(0)
        K = tb.contact.jacobian_matrix(A)
        results.append((dict(st), [a.copy() for a in K.getValuesCSR()]))
        K.destroy()
    (st_c, K_c), (st_n, K_n) = results
    comm = MPI.COMM_WORLD
    assert comm.allreduce(int(np.count_nonzero(st_c["active"])), op=MPI.SUM) > 20
    for key in ("facet", "piece", "m_tri", "m_idx", "active"):
        assert np.array_equal(st_c[key], st_n[key]), key
    for key in ("W", "N", "N1", "bary", "xq", "n", "g", "p"):
        scale = comm.allreduce(float(np.abs(st_n[key]).max(initial=0.0)), op=MPI.MAX)
        assert np.abs(st_c[key] - st_n[key]).max(initial=0.0) <= 1e-11 * scale, key
    assert np.array_equal(K_c[0], K_n[0]) and np.array_equal(K_c[1], K_n[1])  # one pattern
    scale = comm.allreduce(float(np.abs(K_n[2]).max(initial=0.0)), op=MPI.MAX)
    assert scale > 0
    assert np.abs(K_c[2] - K_n[2]).max(initial=0.0) <= 1e-9 * scale  # measured 1.6e-12


@pytest.mark.parametrize("code", ["numpy", "c"])
def test_segment_points_move_continuously_when_the_cut_starts_elsewhere(monkeypatch, code):
    """The points of a cut are a continuous function of the geometry, so a kinked integrand
    (the penalty law across the zero-gap line) sums continuously too. The unit slave triangle
    under a master (0.6, delta), (-0.5, 0), (0.9, 1.5) whose first edge lies on the slave's
    edge y = 0: the overlap is the same pentagon for delta = -1e-9 and +1e-9, but the clipped
    polygon's vertex list starts at (0, 0) for one and at (0.6, 0) for the other (the cut's
    kink). The sum of max(0, x + y / 2 - 0.4) (a kink through the pentagon) moves by O(delta)
    with the fan about the polygon's centroid; with a fan about the polygon's first vertex (as
    before) it jumps by 3.5 % (on the shoulder's glenoid: 0.15 N on one piece, and a Newton
    solve cycled). The sum does not depend on where the vertex list starts either."""
    from shoulder_fem.engine.contact import kernel
    from shoulder_fem.engine.contact.geometry import fan_rule, overlap_polygons, segment_rule

    rule = segment_rule(4)
    mu, w = rule
    slave = np.array([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]])
    ns = np.array([[0.0, 0.0, 1.0]])

    def master(delta):
        return np.array([[[0.6, delta, 0.0], [-0.5, 0.0, 0.0], [0.9, 1.5, 0.0]]])

    def kinked(pts, W):
        return float(np.sum(W * np.maximum(0.0, pts[:, 0] + 0.5 * pts[:, 1] - 0.4)))

    def vertex_fan(poly):  # the fan about the first vertex, by hand
        total = 0.0
        for b, c in zip(poly[1:-1], poly[2:], strict=True):
            a = poly[0]
            area = 0.5 * abs((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]))
            total += 2.0 * area * kinked(mu @ np.array([a, b, c]), w)
        return total

    sums, polys = [], []
    for delta in (-1e-9, 1e-9):
        s2, _, poly, cnt = overlap_polygons(slave, ns, master(delta))
        polys.append(poly[0, : cnt[0]])
        if code == "c":
            monkeypatch.setenv("SHOULDER_FEM_CONTACT_KERNEL", "c")
            kern = kernel.load()
            if kern is None:
                pytest.fail("the segment kernel did not compile (see the warning)")
            _, lam, _, W = kern.cut(slave, ns, master(delta), rule)
            sums.append(kinked(lam[:, 1:], W))  # (x, y) on the unit slave = (l1, l2)
        else:
            sums.append(kinked(*fan_rule(poly, cnt, s2, rule)[1:]))
    assert np.abs(polys[0][0] - polys[1][0]).max() > 0.5  # the lists start at other vertices
    assert abs(sums[1] - sums[0]) <= 1e-8 * sums[0], sums  # measured 1.4e-9
    fans = [vertex_fan(poly) for poly in polys]
    assert abs(fans[1] - fans[0]) > 0.02 * fans[0], fans  # measured 3.5 %
    pent = polys[0]
    rolled = [
        kinked(
            *fan_rule(np.roll(pent, k, axis=0)[None], np.array([len(pent)]), slave[:, :, :2], rule)[
                1:
            ]
        )
        for k in range(len(pent))
    ]
    assert np.ptp(rolled) <= 1e-14 * rolled[0], rolled


def test_segment_tangent_is_central_near_kinks_forward_elsewhere(monkeypatch):
    """Where the segment tangent's difference quotient is one-sided and where central.

    The cut's kink distance by hand: a unit right triangle and its copy moved by (0.25, 0.4)
    are 0.35/sqrt(2) apart at the least (the master's vertex (0.25, 0.4) from the slave's
    hypotenuse x + y = 1; the legs' lines are 0.25 and more from the vertices); moved by
    (0.5, 0.5), a master vertex lies on the slave's hypotenuse: 0. The pressure law's: the
    penalty's |g|, the augmented law's |lam - eps g| / eps, the search depth's |g + depth|.
    A P1 pair through the compiled kernel: at a generic state its blocks are forward
    differences (within 2e-5 of the central ones: step 1e-8 m over a 1 mm piece); with a
    master edge on a slave edge's line, or all points at zero gap, the central ones."""
    from shoulder_fem.engine.contact import kernel
    from shoulder_fem.engine.contact.geometry import cut_kink, segment_rule
    from shoulder_fem.engine.contact.segment_tangent import FD_STEP, NEAR_KINK, kink_distance

    s2 = np.array([[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]])
    assert cut_kink(s2, s2 + [0.25, 0.4]) == pytest.approx([0.35 / math.sqrt(2)], abs=1e-15)
    assert cut_kink(s2, s2 + [0.5, 0.5]) == pytest.approx([0.0], abs=1e-15)
    pen = ContactPair("p", (1,), MeshSurface((2,)), 1e7, search_depth=5e-3)
    aug = ContactPair("a", (1,), MeshSurface((2,)), 1e7, method="augmented")
    g = np.array([-2e-3, 1e-3, -4.9e-3])
    assert np.allclose(kink_distance(pen, g, np.zeros(3)), [2e-3, 1e-3, 1e-4], atol=1e-15)
    assert np.allclose(kink_distance(aug, g, np.full(3, 1e4)), [3e-3, 0.0, 5.9e-3], atol=1e-15)

    monkeypatch.setenv("SHOULDER_FEM_CONTACT_KERNEL", "c")
    kern = kernel.load()
    if kern is None:
        pytest.fail("the segment kernel did not compile (see the warning)")
    rule = segment_rule(2)
    # the slave's normal -z faces the master's +z (a pair that faces away has no weight)
    slave = np.array([[0.0, 0.0, 0.0], [0.0, 1e-3, 0.0], [1e-3, 0.0, 0.0]])
    master = np.array([[-3e-4, -2e-4, 0.0], [1.7e-3, -1e-4, 0.0], [-1e-4, 1.6e-3, 0.0]])

    def blocks(master, lift, tilt, near):
        # the master (normal +z) raised by lift through the slave: gap -lift
        Y = np.concatenate([slave, master + [0.0, 0.0, lift]])[None]
        Y[0, 3:, 2] += tilt * Y[0, 3:, 0]  # a tilted master: its normal off the slave's
        one = np.arange(3)[None]
        args = (pen, Y, one, one, None, np.array([5e-7]), np.zeros((1, 3)), rule, 3, FD_STEP)
        return kern.tangent(*args, near)

    blk, central = blocks(master, 2e-5, 1e-4, NEAR_KINK)
    ref, _ = blocks(master, 2e-5, 1e-4, np.inf)
    assert not central[0] and np.abs(blk).max() > 0
    assert not np.array_equal(blk, ref)  # forward differences, ...
    # ... of the same tangent: a forward quotient is off by O(h / size) = 1e-5 (measured 5e-6)
    assert np.abs(blk - ref).max() <= 2e-5 * np.abs(ref).max()
    on_edge = master.copy()
    on_edge[:2, 1] = 0.0  # its first edge on the line of the slave's first: y = 0
    assert blocks(on_edge, 2e-5, 1e-4, NEAR_KINK)[1][0]
    assert blocks(master, 0.0, 0.0, NEAR_KINK)[1][0]  # parallel at zero gap
    assert not blocks(master, 2e-5, 0.0, NEAR_KINK)[1][0]  # parallel, pressed in


def test_a_piece_turning_through_the_facing_test_changes_its_forces_continuously(monkeypatch):
    """A (slave piece, master triangle) pair is cut only while they face each other, c = -n_s .
    n_m > FACING_MIN (0.05); up to FACING_FULL (0.2) its weights rise as a C1 cubic (by hand: 0,
    5/32, 1/2 and 1 at a quarter, half and all of the way, flat at both ends). Before, the test
    was a step at c = 0.2: on the shoulder's muscles a piece whose c crossed it dropped its
    0.02 N and Newton cycled. A P1 slave piece (normal -z) pressed by a master triangle tilted
    about x to c = cos(tilt): its forces (numpy) vanish at c = FACING_MIN from either side;
    half way up they are half the unweighted ones; and the compiled tangent there is the
    central difference of the numpy forces (the weight's derivative in)."""
    from shoulder_fem.engine.contact import geometry, kernel, segment_tangent
    from shoulder_fem.engine.contact.geometry import (
        FACING_FULL,
        FACING_MIN,
        facing_weight,
        segment_rule,
    )
    from shoulder_fem.engine.contact.segment_tangent import (
        FD_STEP,
        SegmentPairs,
        segment_geometry,
        segment_loads,
    )

    span = FACING_FULL - FACING_MIN
    c = FACING_MIN + span * np.array([-0.3, 0.0, 0.25, 0.5, 1.0, 2.0])
    assert facing_weight(c) == pytest.approx([0.0, 0.0, 0.15625, 0.5, 1.0, 1.0], abs=1e-15)
    ends = np.array([FACING_MIN, FACING_FULL])
    slope = (facing_weight(ends + [1e-7, 0.0]) - facing_weight(ends - [0.0, 1e-7])) / 1e-7
    assert np.abs(slope).max() < 1e-5 * 1.5 / span  # C1: flat at 0 and 1 (1.5 / span mid-way)

    pen = ContactPair("p", (1,), MeshSurface((2,)), 1e7)
    rule = segment_rule(2)
    slave = np.array([[0.0, 0.0, 0.0], [0.0, 1e-3, 0.0], [1e-3, 0.0, 0.0]])  # normal -z
    flat = np.array([[-3e-4, -2e-4, 0.0], [1.7e-3, -1e-4, 0.0], [-1e-4, 1.6e-3, 0.0]])
    pp = object.__new__(SegmentPairs)
    pp.facet, pp.cols, pp.m_vert = np.zeros(1, int), np.arange(3)[None], np.arange(3)[None]
    pp.m_nodes, pp.tri_mu, pp.ref_area = np.arange(3)[None], None, np.array([5e-7])

    def pair_at(cos):
        a = math.acos(cos)  # the master turned about x through the slave's centroid
        rot = np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
        centre = np.array([1e-3 / 3, 1e-3 / 3, 0.0])
        master = (flat - centre) @ rot.T + centre + [0.0, 0.0, 2e-5]
        return np.concatenate([slave, master])[None]

    def loads(Y):
        geo = segment_geometry(pp, Y, rule, 3)
        return segment_loads(pen, geo, Y, np.zeros((1, 3)), 3)

    full = np.abs(loads(pair_at(0.9))).max()
    assert full > 0
    # at c = FACING_MIN the weight is 0 and its slope too: no jump from either side
    for cos in (FACING_MIN - 1e-9, FACING_MIN + 1e-9):
        assert np.abs(loads(pair_at(cos))).max() <= 1e-6 * full
    Y = pair_at(FACING_MIN + 0.5 * span)
    R = loads(Y)
    monkeypatch.setattr(segment_tangent, "facing_weight", lambda c: np.ones_like(c))
    # half way up the cubic ramp the weight is 1/2 (by hand): the same cut, half the forces
    assert np.allclose(R, 0.5 * loads(Y), rtol=1e-12, atol=0.0) and np.abs(R).max() > 0
    monkeypatch.setattr(segment_tangent, "facing_weight", geometry.facing_weight)

    monkeypatch.setenv("SHOULDER_FEM_CONTACT_KERNEL", "c")
    kern = kernel.load()
    if kern is None:
        pytest.fail("the segment kernel did not compile (see the warning)")
    one = np.arange(3)[None]
    args = (pen, Y, one, one, None, pp.ref_area, np.zeros((1, 3)), rule, 3, FD_STEP, np.inf)
    blk, _ = kern.tangent(*args)  # central differences everywhere
    ref = np.empty((6, 3, 6, 3))
    h = 1e-9
    for node in range(6):
        for i in range(3):
            Yp, Ym = Y.copy(), Y.copy()
            Yp[0, node, i] += h
            Ym[0, node, i] -= h
            ref[:, :, node, i] = (loads(Yp)[0] - loads(Ym)[0]) / (2 * h)
    # two central difference quotients (steps 1e-8 and 1e-9 m over a 1 mm piece): measured
    # 2.8e-9 of the largest entry; a weight off by the ramp's factor would be off by O(1)
    assert np.abs(blk[0] - ref).max() <= 1e-4 * np.abs(ref).max()


def test_segment_kernel_without_a_compiler_falls_back_to_numpy(monkeypatch, tmp_path, caplog):
    """A kernel that does not compile (here the compiler is ``false``) leaves the numpy code
    running, after one warning that says why; a wrong selection is refused by name."""
    from shoulder_fem.engine.contact import kernel

    source = tmp_path / "segments.c"
    source.write_text(kernel._SOURCE.read_text() + "\n/* a new digest: not in the cache */\n")
    monkeypatch.setattr(kernel, "_SOURCE", source)
    monkeypatch.setattr(kernel, "_loaded", {})
    monkeypatch.setenv("CC", "false")
    monkeypatch.setenv("SHOULDER_FEM_CONTACT_KERNEL", "c")
    with caplog.at_level("WARNING", logger=kernel.__name__):
        assert kernel.load() is None
    assert "not available" in caplog.text and "false failed" in caplog.text
    monkeypatch.setenv("SHOULDER_FEM_CONTACT_KERNEL", "fortran")
    with pytest.raises(ValueError, match="SHOULDER_FEM_CONTACT_KERNEL = 'fortran'"):
        kernel.load()


@pytest.mark.mpi
@pytest.mark.parametrize("degree", [1, 2])
def test_patch_test_non_matching_meshes_and_action_reaction(degree):
    """Two blocks with non-matching interface meshes (P1 or P2) transmit a uniform pressure
    within 1 % (exact: p = E δ/(H + E/ε); the segment integration makes it exact to round-off);
    the contact force, the reaction at the lower block's base and the force on the upper
    block's top balance to the solver tolerance. The nodal pressure field (ParaView's) holds
    that pressure at every vertex of both faces, the slave's and the master's."""
    tb = TwoBlocks(degree=degree)
    delta = 1e-3
    tb.top_z.value = -delta
    tb.solver.solve()
    st = tb.contact._state[0]
    p_exact = E * delta / (tb.H + E / tb.eps)
    p_loc = st["p"][st["active"]]
    comm = MPI.COMM_WORLD
    p_min = comm.allreduce(float(p_loc.min(initial=np.inf)), op=MPI.MIN)
    p_max = comm.allreduce(float(p_loc.max(initial=0.0)), op=MPI.MAX)
    assert p_min == pytest.approx(p_exact, rel=1e-6)  # the issue asks 1 %
    assert p_max == pytest.approx(p_exact, rel=1e-6)
    r = tb.contact.resultants()["interface"]
    assert r["area"] == pytest.approx(1.0, rel=1e-12)
    assert r["force"][2] == pytest.approx(p_exact, rel=1e-6)
    base = _reaction(tb.form, tb.base_dofs)
    top = _reaction(tb.form, tb.top_dofs)
    tol = 1e-9 * p_exact  # the Newton residual is converged to 1e-6 N on forces ~1e6 N
    assert base + top == pytest.approx(0.0, abs=tol)
    assert -top == pytest.approx(r["force"][2], abs=tol)
    assert tb.contact.stats.pattern_merges >= 1
    pressure, shear = tb.contact.pressure_fields()
    n_owned = tb.contact.Q.dofmap.index_map.size_local
    z = tb.contact.Q.tabulate_dof_coordinates()[:n_owned, 2]
    face = pressure.x.array[:n_owned][np.isclose(z, 0.0, rtol=0, atol=1e-12)]  # the interface
    counts = comm.allreduce(np.array([len(face), np.count_nonzero(face > 0)]), op=MPI.SUM)
    # the two faces' vertices (non-matching meshes: (1/0.13 + 1)^2 + (1/0.2 + 1)^2 at least)
    assert counts[0] >= 100 and counts[1] == counts[0], counts
    assert np.allclose(face, p_exact, rtol=1e-6)
    assert np.all(shear.x.array == 0.0)  # frictionless


@pytest.mark.mpi
def test_large_sliding_is_path_independent():
    """Frictionless, elastic: an upper block dragged over 6 master elements ends in the state of
    a block placed there and pressed (same contact force within 0.5 %), and the pairing
    follows it: the master facets in contact are all different ones at the end."""
    up, lo = (0.3, 0.3, 0.2), (1.6, 0.6, 0.3)
    dragged = TwoBlocks(
        upper=up, lower=lo, offset=(0.1, 0.15), h_upper=0.06, h_lower=0.1, drag=True
    )
    dragged.top_z.value = -2e-4
    dragged.solver.solve()
    first = set(np.unique(dragged.contact._state[0]["m_idx"][dragged.contact._state[0]["active"]]))
    for s in np.linspace(0.1, 0.6, 6):
        dragged.top_x.value = s
        dragged.solver.solve()
    last = set(np.unique(dragged.contact._state[0]["m_idx"][dragged.contact._state[0]["active"]]))
    assert not (first & last) or MPI.COMM_WORLD.size > 1
    placed = TwoBlocks(upper=up, lower=lo, offset=(0.7, 0.15), h_upper=0.06, h_lower=0.1, drag=True)
    placed.top_z.value = -2e-4
    placed.solver.solve()
    f_drag = dragged.contact.resultants()["interface"]["force"]
    f_place = placed.contact.resultants()["interface"]["force"]
    assert f_drag[2] == pytest.approx(f_place[2], rel=5e-3)
    # frictionless: the force is normal to the master facets, which tilt only by the
    # deformation (strain ~1e-3)
    assert abs(f_drag[0]) <= 1e-4 * f_drag[2]


# ---- friction ----------------------------------------------------------------------------------
@pytest.mark.mpi
def test_friction_block_dragged_needs_mu_n():
    """A column (ν = 0: no lateral slip) pressed on a rigid flat, then dragged sideways a
    thousand times the regularisation slip: the tangential reaction is μ times the normal one.
    (The regularised law is stiff where the slip is small: Newton needs a backtracking line
    search there.)"""
    mu = 0.3
    col = Column(
        Plane((0, 0, 0), (0, 0, 1)),
        100 * E / 2.0,
        friction=mu,
        slip=1e-6,
        poisson=0.0,
        options={"snes_linesearch_type": "bt", "snes_max_it": 50},
    )
    col.top_z.value = -1e-3
    col.solve()
    col.contact.commit()
    col.top_x.value = 2e-3
    col.solve()
    r = col.contact.resultants()["base"]
    fx, fz = col.reaction(0), col.reaction(2)
    assert r["force"][0] < 0  # friction on the column opposes the drag (+x)
    assert abs(fx) == pytest.approx(mu * abs(fz), rel=1e-4)
    assert r["force"][0] == pytest.approx(-fx, rel=1e-6)
    assert r["force"][2] == pytest.approx(-fz, rel=1e-6)
    assert r["max_shear"] > 0


# ---- robustness --------------------------------------------------------------------------------
@pytest.mark.mpi
def test_search_depth_bounds_the_overlap_taken_as_contact():
    """The upper block moved rigidly 1 mm into the lower one: every contact point is 1 mm deep,
    so the pressure is ε x 1 mm on the whole unit interface (hand calculation) while the
    search depth exceeds 1 mm, and nothing once it is below (a far-side pairing)."""
    delta = 1e-3
    found = {}
    for depth in (2 * delta, 0.5 * delta):
        tb = TwoBlocks(search_depth=depth)
        upper = dolfinx.fem.locate_dofs_topological(tb.V, 3, tb.ct.find(cb.UPPER.id))
        tb.u.x.array.reshape(-1, 3)[upper, 2] = -delta
        found[depth] = tb.contact.resultants()["interface"]
    deep, shallow = found[2 * delta], found[0.5 * delta]
    assert deep["area"] == pytest.approx(1.0, rel=1e-12)
    assert deep["force"][2] == pytest.approx(tb.eps * delta, rel=1e-9)
    assert deep["max_penetration"] == pytest.approx(delta, rel=1e-9)
    assert shallow["active_points"] == 0
    assert np.all(shallow["force"] == 0.0)
    with pytest.raises(ContactError, match="search_depth"):
        ContactPair("p", (1,), MeshSurface((2,)), 1.0, search_depth=0.0)


@pytest.mark.mpi
def test_master_points_are_where_the_slave_presses_in_the_master_reference():
    """The upper block (offset 0.25 m in x) moved rigidly 1 mm into the lower one: every
    contact point lies on the overlap x in [0.25, 1], its master point is its own (x, y) on the
    lower block's undeformed top (1 mm above it: the blocks touched), and the forces p dA add
    up to eps x 1 mm over the 0.75 m^2 overlap (hand calculation)."""
    delta = 1e-3
    tb = TwoBlocks(offset=(0.25, 0.0))
    upper = dolfinx.fem.locate_dofs_topological(tb.V, 3, tb.ct.find(cb.UPPER.id))
    tb.u.x.array.reshape(-1, 3)[upper, 2] = -delta
    X, f = tb.contact.master_points("interface")
    st = tb.contact._state[0]
    xq = st["xq"][st["active"]]
    comm = MPI.COMM_WORLD
    assert comm.allreduce(len(X), op=MPI.SUM) > 0
    assert np.allclose(X[:, :2], xq[:, :2], atol=1e-12)
    assert np.allclose(X[:, 2], xq[:, 2] + delta, atol=1e-12)
    assert np.all(X[:, 0] >= 0.25 - 1e-12)
    total = comm.allreduce(float(f.sum()), op=MPI.SUM)
    assert total == pytest.approx(tb.eps * delta * 0.75, rel=1e-9)
    with pytest.raises(ContactError, match="no contact pair 'nope'"):
        tb.contact.master_points("nope")


@pytest.mark.mpi
def test_slave_facets_dealt_to_the_ranks_give_the_same_terms():
    """The slave facets dealt round-robin to the ranks (the default; issue 22: at paper the
    glenoid is all on rank 0): every rank holds its share of each pair (within one facet per
    rank), and the residual, tangent, pressure fields, resultants and multipliers equal those of
    the facets left with the ranks owning their cells, to round-off (serial and 2 ranks). Two
    pairs (a P2 mesh master in segments, with friction; a plane), the upper block pressed in and
    slid after the step's start."""
    tb = TwoBlocks(offset=(0.25, 0.0), degree=2)
    pairs = [
        ContactPair("interface", (cb.UPPER_BOTTOM.id,), MeshSurface((cb.LOWER_TOP.id,)),
                    tb.eps, friction=0.3, method="augmented"),
        ContactPair("floor", (cb.LOWER_BOTTOM.id,), Plane((0, 0, -0.499), (0, 0, 1)), tb.eps),
    ]  # fmt: skip
    dealt, kept = (Contact(tb.V, tb.u, tb.ft, pairs, share=s) for s in (True, False))
    comm = MPI.COMM_WORLD
    for sl in dealt._slaves:
        counts = comm.allgather(len(sl.nodes))
        assert max(counts) - min(counts) <= comm.size - 1, counts
    assert [comm.allreduce(len(sl.nodes)) for sl in dealt._slaves] == [
        comm.allreduce(len(sl.nodes)) for sl in kept._slaves
    ]
    x = tb.V.tabulate_dof_coordinates()
    upper = dolfinx.fem.locate_dofs_topological(tb.V, 3, tb.ct.find(cb.UPPER.id))
    tb.u.x.array.reshape(-1, 3)[upper, 2] = -1e-3 * (1.0 + 0.2 * x[upper, 0])
    for c in (dealt, kept):
        c.commit()  # the step starts here: the slide below is its slip
    tb.u.x.array.reshape(-1, 3)[upper, 0] += 2e-4
    for c in (dealt, kept):
        assert not c.augment()  # penetrations ~1 mm: one Uzawa update each
    A = fem_petsc.assemble_matrix(dolfinx.fem.form(ufl.derivative(tb.F, tb.u)))
    A.assemble()
    terms = []
    for c in (dealt, kept):
        b = A.createVecLeft()
        c.add_residual(b)
        K = A.duplicate()
        K.zeroEntries()
        c.add_jacobian(K)
        pressure, shear = c.pressure_fields()
        terms.append((b, K, pressure.x.array.copy(), shear.x.array.copy(), c.resultants()))
    (b1, K1, p1, s1, r1), (b2, K2, p2, s2, r2) = terms
    assert b2.norm() > 0 and K2.norm() > 0 and r2["interface"]["area"] > 0.5
    b1.axpy(-1.0, b2)
    K1.axpy(-1.0, K2)
    assert b1.norm() <= 1e-12 * b2.norm()
    assert K1.norm() <= 1e-12 * K2.norm()
    assert np.allclose(p1, p2, rtol=1e-12, atol=1e-12 * np.abs(p2).max())
    assert np.allclose(s1, s2, rtol=1e-12, atol=1e-12 * np.abs(s2).max()) and np.abs(s2).max() > 0
    for name in ("interface", "floor"):
        for key in ("force", "moment", "normal_force", "area", "max_pressure", "active_points"):
            assert np.allclose(r1[name][key], r2[name][key], rtol=1e-12), (name, key)


def test_resultants_per_slave_tag_add_up_to_the_pair():
    """The upper block (offset 0.25 m in x) moved rigidly 1 mm into the lower one, its bottom
    (the slave) split in two tags at x = 0.6 m: each tag's resultants are those of its own
    points; the forces and moments add up to the pair's, the areas to the 0.75 m^2 overlap,
    and the deepest penetration is the deeper tag's (the shoulder's forces per muscle)."""
    delta, other = 1e-3, 900
    tb = TwoBlocks(offset=(0.25, 0.0))
    ft = tb.ft
    mid = dolfinx.mesh.compute_midpoints(tb.mesh, 2, ft.indices)
    values = ft.values.copy()
    values[(values == cb.UPPER_BOTTOM.id) & (mid[:, 0] > 0.6)] = other
    split = dolfinx.mesh.meshtags(tb.mesh, 2, ft.indices, values)
    slave = (cb.UPPER_BOTTOM.id, other)
    pair = ContactPair("split", slave, MeshSurface((cb.LOWER_TOP.id,)), tb.eps)
    contact = Contact(tb.V, tb.u, split, [pair])
    upper = dolfinx.fem.locate_dofs_topological(tb.V, 3, tb.ct.find(cb.UPPER.id))
    tb.u.x.array.reshape(-1, 3)[upper, 2] = -delta
    whole = contact.resultants((0.5, 0.5, 0.0))["split"]
    parts = contact.resultants((0.5, 0.5, 0.0), by_tag=True)["split"]
    assert set(parts) == set(slave)
    assert all(parts[t]["normal_force"] > 0 for t in slave)  # both parts press
    force = parts[slave[0]]["force"] + parts[slave[1]]["force"]
    moment = parts[slave[0]]["moment"] + parts[slave[1]]["moment"]
    assert np.allclose(force, whole["force"], rtol=1e-12, atol=1e-9 * abs(whole["force"][2]))
    assert np.allclose(moment, whole["moment"], rtol=1e-12, atol=1e-9 * abs(whole["force"][2]))
    assert whole["force"][2] == pytest.approx(tb.eps * delta * 0.75, rel=1e-9)
    assert parts[slave[0]]["area"] + parts[slave[1]]["area"] == pytest.approx(0.75, rel=1e-12)
    deepest = max(parts[t]["max_penetration"] for t in slave)
    assert deepest == pytest.approx(whole["max_penetration"], rel=1e-12)


def test_smoothed_penalty_law_by_hand():
    """The C1 penalty law (ε = 2, s = 1): zero below -s, ε (d + s)²/(4 s) within, ε d above;
    values and slopes by hand, and the slope is the derivative (central differences)."""
    d = np.array([-2.0, -1.0, 0.0, 0.5, 1.0, 3.0])
    p, k = penalty_law(d, 2.0, 1.0)
    assert np.allclose(p, [0.0, 0.0, 0.5, 1.125, 2.0, 6.0], rtol=0, atol=1e-15)
    assert np.allclose(k, [0.0, 0.0, 1.0, 1.5, 2.0, 2.0], rtol=0, atol=1e-15)
    x = np.linspace(-1.5, 1.5, 61)
    h = 1e-6
    fd = (penalty_law(x + h, 2.0, 1.0)[0] - penalty_law(x - h, 2.0, 1.0)[0]) / (2 * h)
    assert np.allclose(fd, penalty_law(x, 2.0, 1.0)[1], atol=1e-6)
    plain = penalty_law(d, 2.0)
    assert np.array_equal(plain[0], 2.0 * np.maximum(d, 0)) and np.array_equal(
        plain[1], np.where(d > 0, 2.0, 0.0)
    )
    with pytest.raises(ContactError, match="smoothing"):
        ContactPair("p", (1,), MeshSurface((2,)), 1.0, method="augmented", smoothing=1e-3)


@pytest.mark.mpi
def test_bad_contact_input():
    """Unknown tags, interior facets, bad penalties, hexahedra: clear errors before any solve."""
    mesh, ft, V = _column((2, 2, 2))
    u = dolfinx.fem.Function(V)
    plane = Plane((0, 0, 0), (0, 0, 1))
    with pytest.raises(ContactError, match="facet tag 99"):
        Contact(V, u, ft, [ContactPair("p", (99,), plane, 1.0)])
    with pytest.raises(ContactError, match="penalty"):
        ContactPair("p", (BOTTOM,), plane, -1.0)
    with pytest.raises(ContactError, match="method"):
        ContactPair("p", (BOTTOM,), plane, 1.0, method="lagrange")
    with pytest.raises(ContactError, match="radius"):
        Sphere((0, 0, 0), 0.0)
    mesh.topology.create_entities(2)
    interior = dolfinx.mesh.locate_entities(mesh, 2, lambda x: np.isclose(x[2], 1.0))
    ft2 = dolfinx.mesh.meshtags(mesh, 2, np.sort(interior), np.full(len(interior), 5, np.int32))
    with pytest.raises(ContactError, match="inside a body"):
        Contact(V, u, ft2, [ContactPair("p", (5,), plane, 1.0)])
    hexes = dolfinx.mesh.create_unit_cube(MPI.COMM_WORLD, 1, 1, 1, dolfinx.mesh.CellType.hexahedron)
    Vh = dolfinx.fem.VectorFunctionSpace(hexes, ("CG", 1))
    fh = dolfinx.mesh.locate_entities_boundary(hexes, 2, lambda x: np.isclose(x[2], 0))
    fth = dolfinx.mesh.meshtags(hexes, 2, fh, np.full(len(fh), 1, np.int32))
    with pytest.raises(ContactError, match="tetrahedral"):
        Contact(Vh, dolfinx.fem.Function(Vh), fth, [ContactPair("p", (1,), plane, 1.0)])


@pytest.mark.mpi
def test_failing_contact_step_is_cut_back():
    """A ball driven to its full approach in one step with at most 3 Newton iterations does
    not converge (the active set keeps changing); march cuts the step back and reaches the
    same state as a run in small steps."""
    from shoulder_fem.families import hertz

    model = hertz.build(load_scene("hertz"), "coarse", MPI.COMM_WORLD)
    delta = model.theory().approach

    def press(options):
        problem = hertz.HertzProblem(model, options)

        def advance(t0, t1):
            problem.minus_approach.value = -t1 * delta
            problem.solver.solve(step=f"t={t1}")

        stats = march(
            np.array([0.0, 1.0]),
            advance,
            lambda: problem.u.x.array.copy(),
            lambda s: problem.u.x.array.__setitem__(slice(None), s),
            stats=StepperStats(),
        )
        return problem.contact_force(), stats

    with pytest.raises(ConvergenceError):
        problem = hertz.HertzProblem(model, {"snes_max_it": 3})
        problem.minus_approach.value = -delta
        problem.solver.solve(step="one step")
    force, stats = press({"snes_max_it": 3})
    assert stats.cutbacks >= 1
    ref, _ = press({"snes_max_it": 50})
    assert force == pytest.approx(ref, rel=1e-7)


# ---- Hertz -------------------------------------------------------------------------------------
def test_hertz_formulas_by_hand():
    """Hertz's formulas on a case computed by hand: F = 10 kN, R = 24 mm, E = 210 GPa, ν = 0.3
    on a rigid flat: E* = 230.77 GPa, a = 0.9205 mm, p0 = 5.635 GPa, δ = 35.31 µm."""
    s = hertz_solution(1e4, 0.024, 210e9, 0.3)
    assert s.effective_modulus == pytest.approx(210e9 / 0.91)
    assert s.contact_radius == pytest.approx((3 * 1e4 * 0.024 * 0.91 / (4 * 210e9)) ** (1 / 3))
    assert s.contact_radius == pytest.approx(0.9205e-3, rel=1e-4)
    assert s.max_pressure == pytest.approx(5.635e9, rel=1e-3)
    assert s.approach == pytest.approx(35.31e-6, rel=1e-3)
    sock = hertz_solution(1e4, 0.024, 210e9, 0.3, socket_radius=0.027)
    assert sock.effective_radius == pytest.approx(0.024 * 0.027 / 0.003)


def test_hertz_sphere_on_flat_converges(comm_tmp):
    """Peak pressure and contact radius within 5 % of Hertz at the medium mesh, and the peak
    pressure error smaller at medium than at coarse."""
    errors = {}
    for level in ("coarse", "medium"):
        res = run("hertz", "coupled", level=level, out=comm_tmp / level)
        p = res.probes
        assert p["contact_force"] == pytest.approx(1e4, rel=2e-4)
        assert p["top_reaction_force"] == pytest.approx(-p["contact_force"], rel=1e-7)
        errors[level] = (p["max_pressure_rel_error"], p["contact_radius_rel_error"])
        assert res.parameters["socket_radius"] is None
        assert res.parameters["counterpart_youngs_modulus"] == "rigid"
    assert abs(errors["medium"][0]) < 0.05 and abs(errors["medium"][1]) < 0.05
    assert abs(errors["medium"][0]) < abs(errors["coarse"][0])


def test_hertz_profile_fit_recovers_an_exact_profile():
    """The fit of p0 √(1 − r²/a²) to points of that very profile returns p0 and a (to the
    scalar search's 1e-9 relative tolerance on a) and no scatter; a uniform 1 % error on every
    point moves p0 by 1 % and leaves a."""
    r = np.linspace(0.0, 0.9e-3, 40)
    p = hertz_profile(r, 5.6e9, 0.92e-3)
    fit = fit_hertz_profile(r, p)
    assert fit.max_pressure == pytest.approx(5.6e9, rel=1e-7)
    assert fit.contact_radius == pytest.approx(0.92e-3, rel=1e-7)
    assert fit.rms < 1e-6 * 5.6e9 and fit.points == 40
    scaled = fit_hertz_profile(r, 1.01 * p)
    assert scaled.max_pressure == pytest.approx(1.01 * 5.6e9, rel=1e-7)
    assert scaled.contact_radius == pytest.approx(0.92e-3, rel=1e-7)
    with pytest.raises(ValueError, match="2 or more points"):
        fit_hertz_profile(r[:1], p[:1])


def test_hertz_counters_are_the_solvers_own_on_a_cut_back_run(comm_tmp):
    """The whole force in one load step with at most 5 Newton iterations per solve: the step
    fails (DIVERGED_MAX_IT after exactly 5 iterations) and is halved until it goes (measured:
    9 cut-backs). Counted by hand, independently of the summary's counters: the SNES ran
    every completed solve's iterations (``newton_iterations_per_solve``) plus 5 per failed
    solve, one failed solve per cut-back; halving one interval adds one step per cut-back; one
    MUMPS factorization and one solve per Newton iteration. The run still reaches F."""
    scene = load_scene("hertz").with_values(load_steps=1)
    res = run(
        scene, "coupled", level="coarse", out=comm_tmp / "cut", solver_options={"snes_max_it": 5}
    )
    counts, per_solve = res.solver, res.data["newton_iterations_per_solve"]
    assert counts["cutbacks"] >= 1
    assert counts["steps"] == 1 + counts["cutbacks"]
    assert counts["newton_iterations"] == sum(per_solve) + 5 * counts["cutbacks"]
    assert counts["factorizations"] == counts["newton_iterations"]
    assert counts["linear_solves"] == counts["newton_iterations"]
    assert res.probes["contact_force"] == pytest.approx(1e4, rel=2e-4)


@pytest.mark.slow
def test_hertz_fitted_peak_pressure_converges(comm_tmp):
    """The Hertz profile fitted to the nodal pressures (p0 and a free) against Hertz's p0 at
    h = 0.17 a, 0.12 a, 0.08 a (coarse, medium, paper). Measured: +0.97 %, +0.33 %, +0.41 %
    (and +0.20 % at fine, h = 0.05 a, not run here): over coarse → paper the error falls at
    order log(0.97/0.41)/log(0.17/0.08) = 1.1, not monotonically (medium and paper both near
    +0.4 %), hence a bound on the order over the whole range and 0.5 % from medium on.
    The largest nodal value, by contrast, is +6.0 %, +4.6 %, +2.8 %: one node's scatter
    (the fit's RMS residual: 3.9 %, 2.9 %, 2.1 % of p0)."""
    errors, scatter = [], []
    for level in ("coarse", "medium", "paper"):
        p = run("hertz", "coupled", level=level, out=comm_tmp / level).probes
        errors.append(abs(p["fitted_max_pressure_rel_error"]))
        scatter.append(p["pressure_scatter_rel"])
        assert abs(p["fitted_max_pressure_rel_error"]) < abs(p["max_pressure_rel_error"])
        assert p["fitted_points"] >= 100
    h = np.array([0.17, 0.12, 0.08])  # levels.*.h_contact of the scene file, in units of a
    order = math.log(errors[0] / errors[2]) / math.log(h[0] / h[2])
    assert order >= 1.0, (errors, order)
    assert max(errors[1:]) < 0.005
    assert scatter[0] > scatter[1] > scatter[2]


def test_ball_in_socket_against_conforming_hertz(comm_tmp):
    """Ball (R = 24 mm) in a rigid socket (27 mm): peak pressure and contact radius against the
    conforming Hertz estimate R* = R Rs/(Rs − R) = 216 mm within 7.5 % (a/R = 0.1 here, where
    the half-space estimate itself is only approximate)."""
    scene = load_scene("hertz").with_values(geometry="socket")
    res = run(scene, "coupled", level="coarse", out=comm_tmp / "socket")
    p = res.probes
    assert res.parameters["socket_radius"] == pytest.approx(0.027)
    theory = hertz_solution(1e4, 0.024, 210e9, 0.3, 0.027)
    assert p["hertz_contact_radius"] == pytest.approx(theory.contact_radius)
    assert abs(p["max_pressure_rel_error"]) < 0.075
    assert abs(p["contact_radius_rel_error"]) < 0.075


def test_hertz_formulas_deformable_counterpart():
    """1/E* = (1 − ν1²)/E1 + (1 − ν2²)/E2: two equal steel bodies halve E*, so a grows by 2^(1/3)
    and p0 falls by 2^(2/3) against the rigid flat (a = 1.1598 mm, p0 = 3.5497 GPa)."""
    rigid = hertz_solution(1e4, 0.024, 210e9, 0.3)
    s = hertz_solution(1e4, 0.024, 210e9, 0.3, None, 210e9, 0.3)
    assert s.effective_modulus == pytest.approx(210e9 / (2 * 0.91))
    assert s.contact_radius == pytest.approx(rigid.contact_radius * 2 ** (1 / 3))
    assert s.max_pressure == pytest.approx(rigid.max_pressure / 2 ** (2 / 3))
    assert s.contact_radius == pytest.approx(1.1598e-3, rel=1e-4)
    soft = hertz_solution(1e4, 0.024, 210e9, 0.3, None, 70e9, 0.25)
    assert 1 / soft.effective_modulus == pytest.approx(0.91 / 210e9 + (1 - 0.25**2) / 70e9)


def test_hertz_ball_on_deformable_flat(comm_tmp):
    """Mesh-to-mesh Hertz: the ball (slave) on an elastic block of the same steel (master,
    segment integration), E* = E/(2(1 − ν²)), block 20 a. Measured (mesh_penalty_factor 2):
    peak pressure +0.4 % at coarse, +3.2 % at medium; contact radius −0.1 % at coarse, +0.3 %
    at medium. The peak is a quadrature-point maximum over non-matching faceted surfaces, whose
    misfit the penalty turns into pressure oscillations: it does not converge monotonically
    (more points, larger extremes), hence a tolerance set by the medium level, the issue's 5 %;
    the radius (from the area) within 2 %, six times the larger measured error. The contact
    force is F; the driven face's and the support's reactions balance it."""
    scene = load_scene("hertz").with_values(geometry="deformable_flat")
    res = run(scene, "coupled", level="coarse", out=comm_tmp / "deformable")
    p, par = res.probes, res.parameters
    assert par["counterpart_youngs_modulus"] == pytest.approx(210e9)
    assert par["counterpart_poisson_ratio"] == pytest.approx(0.3)
    assert par["socket_radius"] is None
    theory = hertz_solution(1e4, 0.024, 210e9, 0.3, None, 210e9, 0.3)
    assert p["hertz_effective_modulus"] == pytest.approx(210e9 / (2 * (1 - 0.3**2)))
    assert p["hertz_contact_radius"] == pytest.approx(theory.contact_radius)
    assert p["hertz_max_pressure"] == pytest.approx(theory.max_pressure)
    assert p["contact_force"] == pytest.approx(1e4, rel=2e-4)
    assert p["top_reaction_force"] == pytest.approx(-p["contact_force"], rel=1e-7)
    assert p["bottom_reaction_force"] == pytest.approx(p["contact_force"], rel=1e-7)
    assert abs(p["max_pressure_rel_error"]) < 0.05
    assert abs(p["contact_radius_rel_error"]) < 0.02


@pytest.mark.mpi
def test_hertz_serial_and_mpi_agree(comm_tmp):
    """The Hertz run on all ranks and on each rank alone: the same probes (1e-6 relative: the
    secant on the approach stops at a force tolerance, so the iterates may differ slightly)."""
    world = run("hertz", "coupled", level="coarse", out=comm_tmp / "world")
    alone = run(
        "hertz",
        "coupled",
        level="coarse",
        out=comm_tmp / f"self{MPI.COMM_WORLD.rank}",
        comm=MPI.COMM_SELF,
    )
    assert world.ranks == MPI.COMM_WORLD.size
    names = ("contact_force", "max_contact_pressure", "contact_radius", "approach")
    names += ("fitted_max_pressure", "pole_pressure", "pressure_scatter")
    for name in names:
        assert world.probes[name] == pytest.approx(alone.probes[name], rel=1e-6), name
    assert math.isfinite(world.probes["max_penetration"])


# ---- a rigid body's surface as a contact master (rigid_bodies + contact) ----------------------
@pytest.mark.mpi
def test_rigid_plate_presses_column_through_contact():
    """A plate whose whole boundary is tied to a rigid body (6 DOFs, held sideways by
    springs) is pushed by a force F onto a column (ν = 0, base fixed) through contact, the plate's
    bottom being the (rigid) master: the plate moves by F H/(E A) + F/(ε A), the contact force
    is F, and the plate's balance (tie + springs + load) closes to the solver tolerance."""
    from shoulder_fem.engine.rigid_system import RigidBody, RigidSystem, Tie
    from shoulder_fem.engine.springs import GROUND, Spring

    a, H, t = 0.5, 1.0, 0.2
    mesh, _, ft = cb.build_two_blocks(
        MPI.COMM_WORLD, (a, a, H), (1.0, 1.0, t), 0.2, 0.25, offset=(-0.25, -0.25)
    )
    # the column sits on z in [-H, 0], the plate on [0, t]
    V = dolfinx.fem.VectorFunctionSpace(mesh, ("CG", 1))
    u = dolfinx.fem.Function(V)
    w = ufl.TestFunction(V)
    F_int = vp.internal_power_linear(materials.LinearElastic(E, 0.0), u, w, ufl.dx(domain=mesh))
    plate_faces = [
        "upper_bottom",
        "upper_top",
        "upper_xmin",
        "upper_xmax",
        "upper_ymin",
        "upper_ymax",
    ]
    surfaces = {n: (ft, cb.TWO_BLOCKS_MARKERS[n].id) for n in [*plate_faces, "lower_bottom"]}
    force = 2e5
    c0 = np.array([0.25, 0.25, t / 2])
    plate = RigidBody("plate", c0, force=[0.0, 0.0, -force])
    # lateral springs: no force at equilibrium; stiff enough to dominate the follower-force
    # terms of a tilting master that the mesh-master tangent leaves out (F/a = 4e5 N/m)
    k = 1e8
    springs = [
        Spring("sx", "plate", c0 + [0.5, 0.0, 0.0], GROUND, c0 + [1.5, 0.0, 0.0], k),
        Spring("sy", "plate", c0 + [0.0, 0.5, 0.0], GROUND, c0 + [0.0, 1.5, 0.0], k),
        Spring("sy2", "plate", c0 + [0.5, 0.5, 0.0], GROUND, c0 + [0.5, 1.5, 0.0], k),
    ]
    eps = 1e3 * E / H
    pair = ContactPair("plate", (cb.LOWER_TOP.id,), MeshSurface((cb.UPPER_BOTTOM.id,)), eps)
    contact = Contact(V, u, ft, [pair], quadrature_degree=0)
    system = RigidSystem(
        [plate],
        springs,
        u=u,
        residual=F_int,
        surfaces=surfaces,
        ties=[Tie("plate", f) for f in plate_faces],
        fixed=["lower_bottom"],
        contact=contact,
        options={"snes_atol": 1e-6, "snes_rtol": 1e-12},
    )
    # start in contact (frictionless contact is all that holds the plate vertically)
    system.move("plate", [0.0, 0.0, -1e-4], np.eye(3))
    its = system.solve("press")
    A = a * a
    expected = -(force * H / (E * A) + force / (eps * A))
    assert plate.translation[2] == pytest.approx(expected, rel=1e-6)
    # sideways only by the springs' second-order stretch δ²/(2 L) as the plate sinks
    assert np.allclose(plate.translation[:2], 0.0, atol=1e-3 * abs(expected))
    assert np.allclose(plate.rotation, np.eye(3), atol=1e-7)
    r = contact.resultants()["plate"]
    assert r["force"][2] == pytest.approx(-force, rel=1e-6)  # on the column top, downwards
    bal = system.balance("plate")
    np.testing.assert_allclose(bal.force_sum, 0.0, atol=1e-6 * force)
    np.testing.assert_allclose(bal.moment_sum, 0.0, atol=1e-6 * force * a)
    assert its <= 6


@pytest.mark.mpi
def test_taylor_hood_column_contact_exact():
    """Contact on the displacement block of a mixed Taylor–Hood (P2/P1) space, nearly
    incompressible (ν = 0.499): a column pressed on a rigid plane, uniaxial stress, p = E δ/(H +
    E/ε) exactly (the mixed form reproduces the linear fields), with the pressure unknown."""
    mesh, ft, _ = _column((2, 2, 3), (1.0, 1.0, 2.0), 1)
    cell = mesh.ufl_cell()
    el = ufl.MixedElement([ufl.VectorElement("CG", cell, 2), ufl.FiniteElement("CG", cell, 1)])
    W = dolfinx.fem.FunctionSpace(mesh, el)
    w = dolfinx.fem.Function(W)
    u, p = ufl.split(w)
    v, q = ufl.TestFunctions(W)
    nu = 0.499
    mu, lam = E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))
    eps_u, eps_v = ufl.sym(ufl.grad(u)), ufl.sym(ufl.grad(v))
    F = (2 * mu * ufl.inner(eps_u, eps_v) - p * ufl.div(v) + (ufl.div(u) + p / lam) * q) * ufl.dx
    fdim = 2
    bcs = []
    for tag, comp, value in ((XMIN, 0, 0.0), (YMIN, 1, 0.0), (TOP, 2, -1e-3)):
        Wc = W.sub(0).sub(comp)
        dofs = dolfinx.fem.locate_dofs_topological(Wc, fdim, ft.find(tag))
        bcs.append(dolfinx.fem.dirichletbc(PETSc.ScalarType(value), dofs, Wc))
    H, eps = 2.0, 100 * E / 2.0
    contact = Contact(
        W.sub(0),
        w,
        ft,
        [ContactPair("base", (BOTTOM,), Plane((0, 0, 0), (0, 0, 1)), eps)],
        bcs=bcs,
        quadrature_degree=2,
        slave_integration="element",  # P2's own functions: consistent loads
    )
    solver = NonlinearSolver(F, w, bcs, name="th", options={"snes_atol": 1e-8}, contact=contact)
    solver.solve()
    r = contact.resultants()["base"]
    p_exact = E * 1e-3 / (H + E / eps)
    assert r["max_pressure"] == pytest.approx(p_exact, rel=1e-7)
    assert r["force"][2] == pytest.approx(p_exact, rel=1e-7)
    # the pressure unknown p = -λ div u = λ (1 - 2ν) P / E = ν P / (1 + ν) in uniaxial stress P
    p_h = w.sub(1).collapse().x.array
    assert np.allclose(p_h, nu / (1 + nu) * p_exact, rtol=1e-6)
