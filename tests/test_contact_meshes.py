"""Mesh builders of the contact verifications measure what their parameters say.

Hemisphere tolerances (no fudge factor): every node of the curved surface lies on the sphere, so
each triangle of the faceted sphere is a plane section of it, at distance sqrt(R² - ρ²) from the
centre (ρ: the triangle's circumradius). With g = max over the triangles of R - sqrt(R² - ρ²) (the
largest sagitta, ~ h²/(2R) for triangles of size h), the faceted surface lies in the shell
R - g <= |x - c| <= R. Hence, for the body (convex, flat faces exact):

* volume: V_exact (1 - g/R)³ <= V <= V_exact (the ball of radius R - g is inside the mesh, the
  mesh is inside the ball);
* flat faces (discs or quarter discs bounded by great-circle arcs): the chords are edges of the
  curved triangles, so A_exact (1 - g/R)² <= A <= A_exact;
* curved surface: the radial projection from the centre maps it onto the exact spherical surface,
  with area ratio dA_flat / dA_sphere = r³ / (R² d) in [(d/R)², R/d] (r = |x - c|, d the
  triangle's distance), so A_exact (1 - g/R)² <= A <= A_exact / (1 - g/R).

g is measured on the mesh and checked against its a priori size h_far²/(2R) (1 % of R here), so
these brackets are tight. Block faces
are planar and meshed exactly: their areas and volumes are exact to round-off (1e-12). The ball on
a block: the ball's brackets as above, the block's measures exact.
"""

from __future__ import annotations

import math

import dolfinx
import numpy as np
import pytest
from mpi4py import MPI

from shoulder_fem.meshes import contact_bodies as cb

pytestmark = pytest.mark.mpi

MM = 1e-3
R = 24 * MM
HEMI = dict(radius=R, h_contact=0.5 * MM, h_far=5.0 * MM, refine_radius=4.0 * MM)
LOWER, UPPER = (30 * MM, 20 * MM, 10 * MM), (12 * MM, 8 * MM, 6 * MM)
BLOCKS = dict(lower=LOWER, upper=UPPER, h_lower=4 * MM, h_upper=2.5 * MM)
BOB = dict(radius=R, block_half_width=12 * MM, block_depth=10 * MM, **{
    k: HEMI[k] for k in ("h_contact", "h_far", "refine_radius")
})  # fmt: skip


# --- helpers: global measures from the local owned entities ---------------------------------


def _owned(mesh, dim: int, entities: np.ndarray) -> np.ndarray:
    return entities[entities < mesh.topology.index_map(dim).size_local]


def _points(mesh, dim: int, entities: np.ndarray) -> np.ndarray:
    """Coordinates of the vertices of the entities, shape (n, dim + 1, 3)."""
    mesh.topology.create_connectivity(dim, 0)
    nodes = dolfinx.cpp.mesh.entities_to_geometry(mesh._mesh, dim, entities.astype(np.int32), False)
    return mesh.geometry.x[nodes].reshape(len(entities), dim + 1, 3)


def _tagged(mesh, tags, marker, owned: bool = True) -> np.ndarray:
    entities = tags.indices[tags.values == marker.id]
    return _owned(mesh, marker.dim, entities) if owned else entities


def _measure(mesh, tags, marker) -> float:
    """Global volume (dim 3) or area (dim 2) of the entities tagged ``marker``."""
    p = _points(mesh, marker.dim, _tagged(mesh, tags, marker))
    if marker.dim == 3:
        local = (
            np.abs(
                np.einsum(
                    "ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), p[:, 3] - p[:, 0]
                )
            ).sum()
            / 6
        )
    else:
        local = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1).sum()
    return mesh.comm.allreduce(float(local), op=MPI.SUM)


def _count(mesh, tags, marker) -> int:
    return mesh.comm.allreduce(len(_tagged(mesh, tags, marker)), op=MPI.SUM)


def _max_sagitta(mesh, ft, radius: float) -> float:
    """g = max over the curved triangles of R - sqrt(R² - ρ²), ρ the circumradius."""
    p = _points(mesh, 2, _tagged(mesh, ft, cb.CONTACT, owned=False))
    a = np.linalg.norm(p[:, 1] - p[:, 2], axis=1)
    b = np.linalg.norm(p[:, 0] - p[:, 2], axis=1)
    c = np.linalg.norm(p[:, 0] - p[:, 1], axis=1)
    area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    rho = a * b * c / (4 * area)
    local = float(np.max(radius - np.sqrt(radius**2 - rho**2), initial=0.0))
    return mesh.comm.allreduce(local, op=MPI.MAX)


def _edges(p: np.ndarray) -> np.ndarray:
    n = p.shape[1]
    pairs = [(i, j) for i in range(n) for j in range(i + 1, n)]
    return np.stack([np.linalg.norm(p[:, i] - p[:, j], axis=1) for i, j in pairs], axis=1)


def _assert_boundary_tagged(mesh, ft) -> None:
    """The owned tagged facets are exactly the owned exterior facets (each tagged once)."""
    tagged = _owned(mesh, 2, ft.indices)
    boundary = _owned(mesh, 2, dolfinx.mesh.exterior_facet_indices(mesh.topology))
    assert len(np.unique(ft.indices)) == len(ft.indices)
    assert np.array_equal(np.sort(tagged), np.sort(boundary))


def _gather(comm, a: np.ndarray) -> np.ndarray:
    return np.concatenate(comm.allgather(a))


# --- fixtures -------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def quarter():
    return cb.build_hemisphere(MPI.COMM_WORLD, **HEMI)


@pytest.fixture(scope="module")
def full():
    return cb.build_hemisphere(MPI.COMM_WORLD, **HEMI, quarter=False)


@pytest.fixture(scope="module")
def ball_on_block():
    return cb.build_ball_on_block(MPI.COMM_WORLD, **BOB)


@pytest.fixture(scope="module")
def blocks():
    return cb.build_two_blocks(MPI.COMM_WORLD, **BLOCKS, gap=0.0, offset=(9 * MM, 6 * MM))


# --- hemisphere -----------------------------------------------------------------------------


@pytest.mark.parametrize("which", ["quarter", "full"])
def test_hemisphere_volume_and_areas(which, request):
    mesh, ct, ft = request.getfixturevalue(which)
    g = _max_sagitta(mesh, ft, R)
    # a priori: g ~ ρ²/(2R), ρ = h/sqrt(3) for an equilateral triangle of edge h = h_far; allow
    # edges up to sqrt(3) h_far (gmsh sizes are targets, not bounds)
    assert 0 < g <= HEMI["h_far"] ** 2 / (2 * R), g
    s = 1 - g / R
    k = 4 if which == "quarter" else 1  # the quarter is a fourth of the half ball
    exact = {
        cb.BALL: 2 / 3 * math.pi * R**3 / k,
        cb.CONTACT: 2 * math.pi * R**2 / k,
        cb.TOP: math.pi * R**2 / k,
    }
    if which == "quarter":
        exact[cb.SYM_X] = exact[cb.SYM_Y] = math.pi * R**2 / 4
    measured = {m: _measure(mesh, ct if m.dim == 3 else ft, m) for m in exact}
    print(
        f"\n{which}: g/R = {g / R:.2e}; "
        + ", ".join(f"{m.name} {measured[m] / exact[m] - 1:+.2e}" for m in exact)
    )
    rel = 1e-12
    v = measured[cb.BALL] / exact[cb.BALL]
    assert s**3 * (1 - rel) <= v <= 1 + rel
    c = measured[cb.CONTACT] / exact[cb.CONTACT]
    assert s**2 * (1 - rel) <= c <= (1 + rel) / s
    for m in exact:
        if m.dim == 2 and m is not cb.CONTACT:
            assert s**2 * (1 - rel) <= measured[m] / exact[m] <= 1 + rel, m.name
    # the total area of the facet tags: every boundary facet is tagged exactly once
    _assert_boundary_tagged(mesh, ft)
    assert _count(mesh, ct, cb.BALL) == mesh.topology.index_map(3).size_global


def test_hemisphere_markers_and_exact_surfaces(quarter, full):
    for (mesh, ct, ft), sym in ((quarter, True), (full, False)):
        assert _count(mesh, ct, cb.BALL) > 0
        assert _count(mesh, ft, cb.CONTACT) > 0 and _count(mesh, ft, cb.TOP) > 0
        assert (_count(mesh, ft, cb.SYM_X) > 0) == sym and (_count(mesh, ft, cb.SYM_Y) > 0) == sym
        c = np.array([0.0, 0.0, R])
        p = _points(mesh, 2, _tagged(mesh, ft, cb.CONTACT, owned=False)).reshape(-1, 3)
        assert np.allclose(np.linalg.norm(p - c, axis=1), R, rtol=0, atol=1e-12 * R)
        assert np.all(p[:, 2] <= R)
        for marker, axis, value in ((cb.TOP, 2, R), (cb.SYM_X, 0, 0.0), (cb.SYM_Y, 1, 0.0)):
            q = _points(mesh, 2, _tagged(mesh, ft, marker, owned=False)).reshape(-1, 3)
            assert np.all(q[:, axis] == value), marker.name  # snapped: exactly on the plane
        x = mesh.geometry.x
        assert np.all(x[:, 2] >= -1e-12 * R) and np.all(x[:, 2] <= R)
        if sym:
            assert np.all(x[:, :2] >= 0)
    # the quarter has a node exactly at the pole (a vertex of its geometry)
    mesh = quarter[0]
    local = float(np.min(np.linalg.norm(mesh.geometry.x, axis=1), initial=np.inf))
    assert mesh.comm.allreduce(local, op=MPI.MIN) < 1e-12 * R


@pytest.mark.parametrize("which", ["quarter", "full"])
def test_hemisphere_size_near_pole(which, request):
    """Within refine_radius of the pole: the surface triangles' edges <= 1.5 h_contact; the
    tetrahedra's median edge is h_contact within 15 %, 95 % of their edges <= 1.45 h_contact and
    all <= 1.75 h_contact (gmsh's 3D Delaunay spreads interior edges more than surface ones)."""
    mesh, ct, ft = request.getfixturevalue(which)
    hc, rr = HEMI["h_contact"], HEMI["refine_radius"]
    cells = np.arange(mesh.topology.index_map(3).size_local, dtype=np.int32)
    p = _points(mesh, 3, cells)
    near = np.linalg.norm(p, axis=2).max(axis=1) <= rr
    edges = _gather(mesh.comm, _edges(p[near]).ravel()) / hc
    t = _points(mesh, 2, _tagged(mesh, ft, cb.CONTACT))
    tri = _gather(mesh.comm, _edges(t[np.linalg.norm(t, axis=2).max(axis=1) <= rr]).ravel()) / hc
    print(
        f"\n{which}: {len(edges) // 6} cells near the pole, edge / h_contact percentiles "
        f"50/95/100: {np.percentile(edges, [50, 95, 100]).round(3)}; surface triangles "
        f"{len(tri) // 3}, max edge {tri.max():.3f}"
    )
    assert len(edges) >= 6 * 50 and len(tri) >= 3 * 20
    assert tri.max() <= 1.5
    assert 0.85 <= np.median(edges) <= 1.15
    assert np.percentile(edges, 95) <= 1.45 and edges.max() <= 1.75
    # far away the size is h_far: the top face's edges are all longer than refine-zone ones
    top = _gather(mesh.comm, _edges(_points(mesh, 2, _tagged(mesh, ft, cb.TOP))).ravel())
    assert np.median(top) > 0.6 * HEMI["h_far"]


def test_hemisphere_bad_input():
    with pytest.raises(ValueError, match="h_contact"):
        cb.build_hemisphere(MPI.COMM_WORLD, R, 2 * MM, 1 * MM, 4 * MM)
    with pytest.raises(ValueError, match="radius"):
        cb.build_hemisphere(MPI.COMM_WORLD, -R, 1 * MM, 2 * MM, 4 * MM)


# --- two blocks -----------------------------------------------------------------------------


def _block_exact(gap: float, offset: tuple[float, float]) -> dict:
    (lx, ly, lz), (ux, uy, uz) = LOWER, UPPER
    return {
        cb.LOWER: lx * ly * lz,
        cb.UPPER: ux * uy * uz,
        **{m: lx * ly for m in (cb.LOWER_BOTTOM, cb.LOWER_TOP)},
        **{m: ly * lz for m in (cb.LOWER_XMIN, cb.LOWER_XMAX)},
        **{m: lx * lz for m in (cb.LOWER_YMIN, cb.LOWER_YMAX)},
        **{m: ux * uy for m in (cb.UPPER_BOTTOM, cb.UPPER_TOP)},
        **{m: uy * uz for m in (cb.UPPER_XMIN, cb.UPPER_XMAX)},
        **{m: ux * uz for m in (cb.UPPER_YMIN, cb.UPPER_YMAX)},
    }


def _planes(gap: float, offset: tuple[float, float]) -> dict:
    (lx, ly, lz), (ux, uy, uz), (ox, oy) = LOWER, UPPER, offset
    return {
        cb.LOWER_BOTTOM: (2, -lz), cb.LOWER_TOP: (2, 0.0),
        cb.LOWER_XMIN: (0, 0.0), cb.LOWER_XMAX: (0, lx),
        cb.LOWER_YMIN: (1, 0.0), cb.LOWER_YMAX: (1, ly),
        cb.UPPER_BOTTOM: (2, gap), cb.UPPER_TOP: (2, gap + uz),
        cb.UPPER_XMIN: (0, ox), cb.UPPER_XMAX: (0, ox + ux),
        cb.UPPER_YMIN: (1, oy), cb.UPPER_YMAX: (1, oy + uy),
    }  # fmt: skip


@pytest.mark.parametrize("gap, offset", [(0.0, (9 * MM, 6 * MM)), (0.5 * MM, (0.0, 0.0))])
def test_two_blocks_exact_measures(gap, offset, blocks):
    if gap == 0.0:
        mesh, ct, ft = blocks
    else:
        mesh, ct, ft = cb.build_two_blocks(MPI.COMM_WORLD, **BLOCKS, gap=gap, offset=offset)
    assert set(cb.TWO_BLOCKS_MARKERS.values()) == set(_block_exact(gap, offset))
    for marker, exact in _block_exact(gap, offset).items():
        tags = ct if marker.dim == 3 else ft
        assert _count(mesh, tags, marker) > 0, marker.name
        assert _measure(mesh, tags, marker) == pytest.approx(exact, rel=1e-12), marker.name
    for marker, (axis, value) in _planes(gap, offset).items():
        q = _points(mesh, 2, _tagged(mesh, ft, marker, owned=False)).reshape(-1, 3)
        assert np.all(q[:, axis] == value), marker.name  # exactly on its plane
    _assert_boundary_tagged(mesh, ft)  # every face tagged once


def test_two_blocks_share_no_node_and_interfaces_do_not_match(blocks):
    mesh, ct, ft = blocks
    imap = mesh.topology.index_map(0)
    mesh.topology.create_connectivity(3, 0)
    c2v = mesh.topology.connectivity(3, 0)

    def global_vertices(marker):
        cells = _tagged(mesh, ct, marker, owned=False)
        local = np.unique(c2v.array.reshape(-1, 4)[cells])  # (may be empty on a rank)
        return np.unique(_gather(mesh.comm, imap.local_to_global(local.astype(np.int32))))

    lower, upper = global_vertices(cb.LOWER), global_vertices(cb.UPPER)
    assert len(lower) + len(upper) == imap.size_global
    assert len(np.intersect1d(lower, upper)) == 0
    # no facet is shared: the contact faces z = 0 of both bodies are boundary facets (checked in
    # the exact-measure test); the two interface meshes differ: most upper_bottom nodes are not
    # at the position of any lower_top node
    a = np.unique(
        _gather(mesh.comm, _points(mesh, 2, _tagged(mesh, ft, cb.LOWER_TOP)).reshape(-1, 3)), axis=0
    )
    b = np.unique(
        _gather(mesh.comm, _points(mesh, 2, _tagged(mesh, ft, cb.UPPER_BOTTOM)).reshape(-1, 3)),
        axis=0,
    )
    assert np.all(a[:, 2] == 0.0) and np.all(b[:, 2] == 0.0)
    dist = np.min(np.linalg.norm(b[:, None, :2] - a[None, :, :2], axis=2), axis=1)
    assert np.mean(dist > 1e-9) > 0.5
    print(f"\n{len(b)} upper_bottom nodes, {np.sum(dist <= 1e-9)} at a lower_top node's position")


def test_two_blocks_sizes(blocks):
    mesh, ct, _ = blocks
    for marker, h in ((cb.LOWER, BLOCKS["h_lower"]), (cb.UPPER, BLOCKS["h_upper"])):
        e = _gather(mesh.comm, _edges(_points(mesh, 3, _tagged(mesh, ct, marker))).ravel()) / h
        assert 0.8 <= np.median(e) <= 1.2 and e.max() <= 2.0, (marker.name, np.median(e), e.max())


def test_two_blocks_bad_input():
    with pytest.raises(ValueError, match="two blocks"):
        cb.build_two_blocks(MPI.COMM_WORLD, LOWER, (1 * MM, 0.0, 1 * MM), 1 * MM, 1 * MM)


# --- ball on block --------------------------------------------------------------------------


def _cell_nodes(mesh, ct, marker) -> np.ndarray:
    """Global indices of the vertices of the cells tagged ``marker`` (every rank)."""
    imap = mesh.topology.index_map(0)
    mesh.topology.create_connectivity(3, 0)
    c2v = mesh.topology.connectivity(3, 0)
    local = np.unique(c2v.array.reshape(-1, 4)[_tagged(mesh, ct, marker, owned=False)])
    return np.unique(_gather(mesh.comm, imap.local_to_global(local.astype(np.int32))))


def test_ball_on_block_measures_markers_and_planes(ball_on_block):
    mesh, ct, ft = ball_on_block
    w, d = BOB["block_half_width"], BOB["block_depth"]
    g = _max_sagitta(mesh, ft, R)
    assert 0 < g <= HEMI["h_far"] ** 2 / (2 * R), g
    s = 1 - g / R
    ball = {
        cb.BALL: 2 / 3 * math.pi * R**3 / 4,
        cb.CONTACT: 2 * math.pi * R**2 / 4,
        cb.TOP: math.pi * R**2 / 4,
        cb.SYM_X: math.pi * R**2 / 4,
        cb.SYM_Y: math.pi * R**2 / 4,
    }
    block = {
        cb.BLOCK: w * w * d,
        cb.BLOCK_TOP: w * w,
        cb.BLOCK_BOTTOM: w * w,
        **{m: w * d for m in (cb.BLOCK_SYM_X, cb.BLOCK_SYM_Y, cb.BLOCK_XMAX, cb.BLOCK_YMAX)},
    }
    assert set(cb.BALL_ON_BLOCK_MARKERS.values()) == set(ball) | set(block) | {
        cb.BLOCK_XMIN,
        cb.BLOCK_YMIN,
    }
    rel = 1e-12
    for marker, exact in {**ball, **block}.items():
        tags = ct if marker.dim == 3 else ft
        assert _count(mesh, tags, marker) > 0, marker.name
        ratio = _measure(mesh, tags, marker) / exact
        if marker is cb.BALL:
            assert s**3 * (1 - rel) <= ratio <= 1 + rel
        elif marker is cb.CONTACT:
            assert s**2 * (1 - rel) <= ratio <= (1 + rel) / s
        elif marker in ball:
            assert s**2 * (1 - rel) <= ratio <= 1 + rel, marker.name
        else:
            assert ratio == pytest.approx(1.0, rel=rel), marker.name
    for marker in (cb.BLOCK_XMIN, cb.BLOCK_YMIN):  # quarter: no face at -w
        assert _count(mesh, ft, marker) == 0
    planes = {
        cb.TOP: (2, R), cb.SYM_X: (0, 0.0), cb.SYM_Y: (1, 0.0),
        cb.BLOCK_TOP: (2, 0.0), cb.BLOCK_BOTTOM: (2, -d),
        cb.BLOCK_SYM_X: (0, 0.0), cb.BLOCK_SYM_Y: (1, 0.0),
        cb.BLOCK_XMAX: (0, w), cb.BLOCK_YMAX: (1, w),
    }  # fmt: skip
    for marker, (axis, value) in planes.items():
        q = _points(mesh, 2, _tagged(mesh, ft, marker, owned=False)).reshape(-1, 3)
        assert np.all(q[:, axis] == value), marker.name  # exactly on its plane
    _assert_boundary_tagged(mesh, ft)  # every face of both bodies tagged once
    assert (
        _count(mesh, ct, cb.BALL) + _count(mesh, ct, cb.BLOCK)
        == mesh.topology.index_map(3).size_global
    )


def test_ball_on_block_share_no_node_and_refined_at_pole(ball_on_block):
    """Two independent meshes (the ball's pole and the block's corner are distinct nodes at the
    origin), both refined near the pole: edges of the cells within refine_radius have a median
    of h_contact within 15 % in each body; the block's bottom, far away, is coarser."""
    mesh, ct, ft = ball_on_block
    ball, block = _cell_nodes(mesh, ct, cb.BALL), _cell_nodes(mesh, ct, cb.BLOCK)
    assert len(ball) + len(block) == mesh.topology.index_map(0).size_global
    assert len(np.intersect1d(ball, block)) == 0
    x = mesh.geometry.x
    at_origin = mesh.comm.allreduce(
        int(np.count_nonzero(np.all(np.abs(x[: mesh.topology.index_map(0).size_local]) == 0.0,
                                    axis=1))),
        op=MPI.SUM,
    )  # fmt: skip
    assert at_origin == 2  # the ball's pole and the block's corner
    hc, rr = BOB["h_contact"], BOB["refine_radius"]
    for marker in (cb.BALL, cb.BLOCK):
        p = _points(mesh, 3, _tagged(mesh, ct, marker))
        near = np.linalg.norm(p, axis=2).max(axis=1) <= rr
        e = _gather(mesh.comm, _edges(p[near]).ravel()) / hc
        assert len(e) >= 6 * 50, marker.name
        assert 0.85 <= np.median(e) <= 1.15, (marker.name, np.median(e))
    bottom = _gather(
        mesh.comm, _edges(_points(mesh, 2, _tagged(mesh, ft, cb.BLOCK_BOTTOM))).ravel()
    )
    # the size requested at the bottom's distance (>= depth) from the pole: h_contact + grading
    # (d - refine_radius), below h_far here
    h_bottom = min(HEMI["h_far"], hc + cb.DEFAULT_GRADING * (BOB["block_depth"] - rr))
    assert np.median(bottom) > 0.8 * h_bottom > 2 * hc


def test_ball_on_block_full_and_bad_input():
    mesh, ct, ft = cb.build_ball_on_block(
        MPI.COMM_WORLD, R, 12 * MM, 10 * MM, 2 * MM, 6 * MM, 4 * MM, quarter=False
    )
    w, d = 12 * MM, 10 * MM
    assert _measure(mesh, ct, cb.BLOCK) == pytest.approx(4 * w * w * d, rel=1e-12)
    assert _measure(mesh, ft, cb.BLOCK_TOP) == pytest.approx(4 * w * w, rel=1e-12)
    for marker in (cb.BLOCK_XMIN, cb.BLOCK_XMAX, cb.BLOCK_YMIN, cb.BLOCK_YMAX):
        assert _measure(mesh, ft, marker) == pytest.approx(2 * w * d, rel=1e-12), marker.name
    for marker in (cb.SYM_X, cb.SYM_Y, cb.BLOCK_SYM_X, cb.BLOCK_SYM_Y):
        assert _count(mesh, ft, marker) == 0, marker.name
    _assert_boundary_tagged(mesh, ft)
    with pytest.raises(ValueError, match="ball on block"):
        cb.build_ball_on_block(MPI.COMM_WORLD, R, 0.0, 10 * MM, 1 * MM, 2 * MM, 4 * MM)
    with pytest.raises(ValueError, match="h_contact"):
        cb.build_ball_on_block(MPI.COMM_WORLD, R, 12 * MM, 10 * MM, 2 * MM, 1 * MM, 4 * MM)


# --- determinism, MPI, gmsh session ---------------------------------------------------------


def _signature(mesh, ct, ft) -> tuple:
    return (
        mesh.geometry.x.copy(),
        mesh.geometry.dofmap.array.copy(),
        ct.indices.copy(), ct.values.copy(), ft.indices.copy(), ft.values.copy(),
    )  # fmt: skip


@pytest.mark.parametrize("builder", ["hemisphere", "two_blocks", "ball_on_block"])
def test_same_parameters_same_mesh(builder):
    def build():
        if builder == "hemisphere":
            return cb.build_hemisphere(MPI.COMM_SELF, **HEMI)
        if builder == "ball_on_block":
            return cb.build_ball_on_block(MPI.COMM_SELF, **BOB)
        return cb.build_two_blocks(MPI.COMM_SELF, **BLOCKS, gap=0.0, offset=(9 * MM, 6 * MM))

    first, second = _signature(*build()), _signature(*build())
    for a, b in zip(first, second, strict=True):
        assert a.shape == b.shape and np.array_equal(a, b)


@pytest.mark.parametrize("which", ["quarter", "blocks", "ball_on_block"])
def test_distributed_equals_serial(which, request):
    """On COMM_WORLD (distributed under mpirun) the global counts and measures equal those of
    the same mesh built on one rank (COMM_SELF)."""
    world = request.getfixturevalue(which)
    if which == "quarter":
        alone = cb.build_hemisphere(MPI.COMM_SELF, **HEMI)
        markers = list(cb.HEMISPHERE_MARKERS.values())
    elif which == "ball_on_block":
        alone = cb.build_ball_on_block(MPI.COMM_SELF, **BOB)
        markers = list(cb.BALL_ON_BLOCK_MARKERS.values())
    else:
        alone = cb.build_two_blocks(MPI.COMM_SELF, **BLOCKS, gap=0.0, offset=(9 * MM, 6 * MM))
        markers = list(cb.TWO_BLOCKS_MARKERS.values())
    for index in (0, 3):
        assert (
            world[0].topology.index_map(index).size_global
            == alone[0].topology.index_map(index).size_global
        )
    for m in markers:
        w_mesh, w_ct, w_ft = world
        a_mesh, a_ct, a_ft = alone
        wt, at = (w_ct, a_ct) if m.dim == 3 else (w_ft, a_ft)
        assert _count(w_mesh, wt, m) == _count(a_mesh, at, m), m.name
        assert _measure(w_mesh, wt, m) == pytest.approx(_measure(a_mesh, at, m), rel=1e-12)


def test_caller_gmsh_session_left_alone():
    """With gmsh already initialised, a build keeps the caller's model and options."""
    import gmsh

    gmsh.initialize(readConfigFiles=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("caller")
        gmsh.model.occ.addBox(0, 0, 0, 1, 1, 1)
        gmsh.model.occ.synchronize()
        gmsh.option.setNumber("Mesh.Algorithm", 5)
        mesh, _, _ = cb.build_two_blocks(MPI.COMM_SELF, **BLOCKS)
        assert mesh.topology.index_map(3).size_global > 0
        assert gmsh.model.getCurrent() == "caller"
        assert "contact_bodies_two_blocks" not in gmsh.model.list()
        assert gmsh.model.getEntities(3) == [(3, 1)]
        assert gmsh.option.getNumber("Mesh.Algorithm") == 5
    finally:
        gmsh.finalize()
