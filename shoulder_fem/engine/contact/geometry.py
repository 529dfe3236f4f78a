"""Geometry of triangles: shape functions, quadrature rules, closest points and clipping.

Pure functions on arrays (no mesh, no MPI): the slave facets' rules (a P2 facet possibly as its
4 flat sub-triangles), the closest point of a triangle, convex polygon clipping and the fan rule
that integrates the overlap of a slave piece and a master triangle.
"""

from __future__ import annotations

import basix
import numpy as np

#: The 4 flat sub-triangles of a P2 facet in canonical node order (v0 v1 v2 e01 e12 e20).
P2_SUBTRIANGLES = ((0, 3, 5), (3, 1, 4), (5, 4, 2), (3, 4, 5))
#: Barycentric coordinates of the 6 canonical nodes of a P2 triangle.
NODE_MU = np.array(
    [[1, 0, 0], [0, 1, 0], [0, 0, 1], [0.5, 0.5, 0], [0, 0.5, 0.5], [0.5, 0, 0.5]], dtype=float
)


#: The facing test of a slave piece and a master triangle, on c = -n_s . n_m (1: face to face,
#: 0: at right angles). A pair with c <= FACING_MIN is not cut (the far side of a curved
#: master, a slave face looking away from it); from FACING_MIN to FACING_FULL the weights of
#: its points rise as a C1 cubic (:func:`facing_weight`), so that a piece turning through the
#: test changes its forces continuously; from FACING_FULL on a pair counts whole, as every
#: cut pair did before. Before 2026-11-28 the test was a step at c = 0.2: a muscle piece whose
#: c crossed it dropped its 0.02 N at once, Newton's residual jumped by that much along its
#: step (the tangent exact to 1e-5), and the incompressible part 1 at ``coarse`` with 8 mm
#: muscles cycled at |F| = 0.023 N at 54 deg. A ramp above 0.2 instead (0.2 to 0.5, the
#: pairs between weighed less than before) moved the default coarse run's path: the coupled
#: run 0-20 deg failed 4 steps at 7.3 deg where it had failed none.
FACING_MIN = 0.05
FACING_FULL = 0.2


def p2_shape(mu: np.ndarray) -> np.ndarray:
    """P2 triangle shape functions (canonical order) at barycentric points mu (q, 3)."""
    return np.column_stack(
        [
            mu[:, 0] * (2 * mu[:, 0] - 1),
            mu[:, 1] * (2 * mu[:, 1] - 1),
            mu[:, 2] * (2 * mu[:, 2] - 1),
            4 * mu[:, 0] * mu[:, 1],
            4 * mu[:, 1] * mu[:, 2],
            4 * mu[:, 2] * mu[:, 0],
        ]
    )


def facing_weight(c: np.ndarray) -> np.ndarray:
    """The factor of a pair's weights at c = -n_s . n_m: 0 up to FACING_MIN, 1 from FACING_FULL."""
    t = np.clip((np.asarray(c, dtype=float) - FACING_MIN) / (FACING_FULL - FACING_MIN), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def triangle_shape(degree: int, points: np.ndarray) -> np.ndarray:
    """Shape functions of the canonical P1/P2 triangle (nodes v0 v1 v2 [e01 e12 e20])."""
    m = np.column_stack([1.0 - points[:, 0] - points[:, 1], points[:, 0], points[:, 1]])
    return m if degree == 1 else p2_shape(m)


def subtriangle_rule(points: np.ndarray, weights: np.ndarray):
    """A P2 facet integrated as its 4 flat sub-triangles with linear shape functions.

    The penalty pressure of a P2 surface integrated with its own (quadratic) shape functions
    oscillates from one quadrature point to the next (its vertex functions integrate to zero);
    piecewise-linear interpolation between the 6 nodes keeps every nodal weight positive.

    Returns:
        (N, N1, w): the 6 nodes' piecewise-linear functions at the sub-triangles' points, the
        parent facet's linear functions there (for the pressure field), and weights of unit area.
    """
    beta = triangle_shape(1, points)  # (nq, 3) on each sub-triangle
    N, N1, w = [], [], []
    for sub in P2_SUBTRIANGLES:
        Ns = np.zeros((len(points), 6))
        Ns[:, list(sub)] = beta
        N.append(Ns)
        N1.append(beta @ NODE_MU[list(sub)])
        w.append(weights / 4.0)
    return np.vstack(N), np.vstack(N1), np.concatenate(w)


def closest_points_on_triangles(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray):
    """Closest point of each triangle (a, b, c) to p, vectorised over leading axes.

    Returns:
        (q, bary, dist2, feature): the closest points, their barycentric weights on (a, b, c),
        the squared distances, and the feature reached: -1 the interior, 0/1/2 the edges
        ab/bc/ca (their end vertices included).
    """
    ab, ac, ap = b - a, c - a, p - a
    d00 = np.einsum("...i,...i", ab, ab)
    d01 = np.einsum("...i,...i", ab, ac)
    d11 = np.einsum("...i,...i", ac, ac)
    d20 = np.einsum("...i,...i", ap, ab)
    d21 = np.einsum("...i,...i", ap, ac)
    den = d00 * d11 - d01 * d01
    v = (d11 * d20 - d01 * d21) / den
    w = (d00 * d21 - d01 * d20) / den
    u = 1.0 - v - w
    bary = np.stack([u, v, w], axis=-1)
    inside = (u >= 0) & (v >= 0) & (w >= 0)
    feature = np.full(u.shape, -1)
    best = np.full(u.shape, np.inf)
    bary_edge = np.zeros_like(bary)
    for k, (s, e, i, j) in enumerate(((a, b, 0, 1), (b, c, 1, 2), (c, a, 2, 0))):
        se = e - s
        t = np.clip(np.einsum("...i,...i", p - s, se) / np.einsum("...i,...i", se, se), 0.0, 1.0)
        q = s + t[..., None] * se
        d2 = np.einsum("...i,...i", p - q, p - q)
        better = ~inside & (d2 < best)
        best = np.where(better, d2, best)
        feature = np.where(better, k, feature)
        bk = np.zeros_like(bary)
        bk[..., i] = 1.0 - t
        bk[..., j] = t
        bary_edge = np.where(better[..., None], bk, bary_edge)
    bary = np.where(inside[..., None], bary, bary_edge)
    q = bary[..., 0:1] * a + bary[..., 1:2] * b + bary[..., 2:3] * c
    dist2 = np.einsum("...i,...i", p - q, p - q)
    return q, bary, dist2, feature


def clip_polygons(poly: np.ndarray, cnt: np.ndarray, a: np.ndarray, b: np.ndarray):
    """Clip convex 2D polygons to the left of the lines a -> b (Sutherland-Hodgman).

    Vectorised over M: ``poly`` (M, K, 2) with ``cnt`` valid vertices each; ``a``, ``b`` (M, 2).

    Returns:
        (poly, cnt): the clipped polygons (M, K', 2), their valid vertices first (zeros after
        them), and their numbers of valid vertices (M,).
    """
    M, K, _ = poly.shape
    idx = np.arange(K)
    nxt = (idx[None, :] + 1) % np.maximum(cnt[:, None], 1)
    cur = poly
    nx = poly[np.arange(M)[:, None], nxt]
    valid = idx[None, :] < cnt[:, None]
    e = b - a

    def side(p):
        return e[:, None, 0] * (p[..., 1] - a[:, None, 1]) - e[:, None, 1] * (
            p[..., 0] - a[:, None, 0]
        )

    dc, dn = side(cur), side(nx)
    inc, inn = dc >= 0, dn >= 0
    den = np.where(dc != dn, dc - dn, 1.0)
    t = np.clip(dc / den, 0.0, 1.0)
    out = np.empty((M, 2 * K, 2))
    keep = np.zeros((M, 2 * K), dtype=bool)
    out[:, 0::2] = cur
    out[:, 1::2] = cur + t[..., None] * (nx - cur)
    keep[:, 0::2] = valid & inc
    keep[:, 1::2] = valid & (inc != inn)
    cnt = keep.sum(axis=1)
    kmax = max(int(cnt.max(initial=0)), 1)
    clipped = np.zeros((M, kmax, 2))  # the kept vertices moved to the front, in order
    rank = np.cumsum(keep, axis=1) - 1
    clipped[np.nonzero(keep)[0], rank[keep]] = out[keep]
    return clipped, cnt


def barycentric_2d(p: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Barycentric coordinates of 2D points p (..., 2) in triangles tri (..., 3, 2)."""
    v0, v1 = tri[..., 1, :] - tri[..., 0, :], tri[..., 2, :] - tri[..., 0, :]
    d = p - tri[..., 0, :]
    det = v0[..., 0] * v1[..., 1] - v0[..., 1] * v1[..., 0]
    l1 = (d[..., 0] * v1[..., 1] - d[..., 1] * v1[..., 0]) / det
    l2 = (v0[..., 0] * d[..., 1] - v0[..., 1] * d[..., 0]) / det
    return np.stack([1.0 - l1 - l2, l1, l2], axis=-1)


def segment_rule(degree: int) -> tuple[np.ndarray, np.ndarray]:
    """A rule on a triangle: barycentric points and weights summing to 1."""
    pts, wts = basix.make_quadrature(basix.QuadratureType.Default, basix.CellType.triangle, degree)
    mu = np.column_stack([1.0 - pts[:, 0] - pts[:, 1], pts[:, 0], pts[:, 1]])
    return mu, 2.0 * wts


def slave_rule(degree: int, quadrature_degree: int, subtriangles: bool):
    """The fixed rule of a slave facet of a P1/P2 surface, on the reference triangle.

    Args:
        degree: Degree of the displacement (1 or 2).
        quadrature_degree: Degree of the rule (0: the three vertices).
        subtriangles: A P2 facet integrated as its 4 flat sub-triangles
            (:func:`subtriangle_rule`) instead of with its own shape functions.

    Returns:
        (N, N1, w): the facet's shape functions at the points (nq, nn), its linear functions
        there (nq, 3) and weights of unit area (nq,).
    """
    if quadrature_degree == 0:  # nodal (vertex) rule: contact points at the nodes
        points = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
        weights = np.full(3, 1.0 / 6.0)
    else:
        points, weights = basix.make_quadrature(
            basix.QuadratureType.Default, basix.CellType.triangle, quadrature_degree
        )
    N = triangle_shape(degree, points)  # (nq, nn)
    N1 = triangle_shape(1, points)  # (nq, 3)
    w = 2.0 * weights  # reference triangle area 1/2 -> weights of unit area
    if degree == 2 and subtriangles:
        N, N1, w = subtriangle_rule(points, w)
    return N, N1, w


def overlap_polygons(P: np.ndarray, ns: np.ndarray, tri: np.ndarray):
    """Overlaps of slave triangles and master triangles, in the slave triangles' planes.

    Args:
        P: Slave triangles (M, 3, 3), counter-clockwise seen from their normal.
        ns: Their unit normals (M, 3).
        tri: One master triangle each (M, 3, 3), in any orientation.

    Returns:
        (s2, m2, poly, cnt): both triangles in 2D coordinates of the slave's plane (origin at
        its first vertex; (M, 3, 2) each, the master in its own vertex order), and the
        overlap polygons (M, K, 2) with their numbers of valid vertices (M,).
    """
    e1 = P[:, 1] - P[:, 0]
    e1 /= np.linalg.norm(e1, axis=1)[:, None]
    e2 = np.cross(ns, e1)

    def to2d(x):
        d = x - P[:, 0][:, None, :]
        return np.stack([np.einsum("mki,mi->mk", d, e1), np.einsum("mki,mi->mk", d, e2)], -1)

    s2 = to2d(P)  # (M, 3, 2), counter-clockwise
    m2 = to2d(tri)
    det = (m2[:, 1, 0] - m2[:, 0, 0]) * (m2[:, 2, 1] - m2[:, 0, 1]) - (
        m2[:, 1, 1] - m2[:, 0, 1]
    ) * (m2[:, 2, 0] - m2[:, 0, 0])
    flip = det < 0
    m2c = m2.copy()
    m2c[flip, 1], m2c[flip, 2] = m2[flip, 2], m2[flip, 1]
    poly, cnt = s2.copy(), np.full(len(P), 3)
    for a, b in ((0, 1), (1, 2), (2, 0)):
        poly, cnt = clip_polygons(poly, cnt, m2c[:, a], m2c[:, b])
    return s2, m2, poly, cnt


def cut_kink(s2: np.ndarray, m2: np.ndarray) -> np.ndarray:
    """The distance of a vertex of either 2D triangle from the line of an edge of the other.

    ``s2``, ``m2`` (M, 3, 2) as :func:`overlap_polygons` returns them. Where it is zero the
    overlap polygon changes shape (a vertex crosses an edge's line): the cut's kinks.
    Returns (M,).
    """
    d = np.full(len(s2), np.inf)
    for E, V in ((s2, m2), (m2, s2)):
        for e in range(3):
            a, b = E[:, e], E[:, (e + 1) % 3]
            ex, ey = (b - a).T
            side = ex[:, None] * (V[..., 1] - a[:, None, 1]) - ey[:, None] * (
                V[..., 0] - a[:, None, 0]
            )
            dist = np.abs(side).min(axis=1) / np.hypot(ex, ey)
            d = np.minimum(d, dist)
    return d


def fan_rule(poly: np.ndarray, cnt: np.ndarray, s2: np.ndarray, rule):
    """A rule on every convex polygon, applied on the triangles of its fan about its centroid.

    Each polygon is cut into the triangles (centroid, v_i, v_i+1) about its area centroid, which
    moves continuously with the polygon: a fan about one of its vertices changes its triangles
    at once when the clipping starts the polygon at another vertex (a slave vertex crossing a
    master edge's line), and where the pressure law has a kink inside the polygon (the zero-gap
    line) the rule's sum then jumps (measured at ``coarse``, part 1 at 16 deg: 0.15 N on one
    piece for a state change of 1e-12, and Newton cycled at a residual of 0.1 N).

    Args:
        poly: Convex polygons (M, K, 2) with ``cnt`` (M,) valid vertices each.
        cnt: Numbers of valid vertices.
        s2: The triangle each polygon lies in (M, 3, 2); the weights are fractions of its area.
        rule: (mu, w) of :func:`segment_rule`.

    Returns:
        (rr, pts, w): the polygon of every point (S,), the points (S, 2) and their weights as
        fractions of the area of the polygon's triangle ``s2`` (S,). Polygons and fan triangles
        of no area (below 1e-12 of it) are left out.
    """
    M, kmax = poly.shape[:2]
    if kmax < 3 or M == 0:
        return np.zeros(0, dtype=np.int64), np.zeros((0, 2)), np.zeros(0)
    s_area = 0.5 * np.abs(
        (s2[:, 1, 0] - s2[:, 0, 0]) * (s2[:, 2, 1] - s2[:, 0, 1])
        - (s2[:, 1, 1] - s2[:, 0, 1]) * (s2[:, 2, 0] - s2[:, 0, 0])
    )
    idx = np.arange(kmax)
    valid = idx[None, :] < cnt[:, None]
    nxt = np.where(idx[None, :] + 1 < cnt[:, None], idx[None, :] + 1, 0)
    rows = np.arange(M)[:, None]
    rel = poly - poly[:, :1]  # about the first vertex (round-off)
    B, C = rel, rel[rows, nxt]
    cross = np.where(valid, B[..., 0] * C[..., 1] - B[..., 1] * C[..., 0], 0.0)
    area2 = cross.sum(axis=1)  # twice the signed area
    big = np.abs(area2) > 2e-12 * s_area
    den = np.where(big, 3.0 * area2, 1.0)
    cen = np.einsum("mk,mkd->md", cross, B + C) / den[:, None]  # the area centroid, relative
    A = np.broadcast_to(cen[:, None, :], B.shape)
    tri2 = 0.5 * (
        (B[..., 0] - A[..., 0]) * (C[..., 1] - A[..., 1])
        - (B[..., 1] - A[..., 1]) * (C[..., 0] - A[..., 0])
    )
    ok = valid & big[:, None] & (np.abs(tri2) > 1e-12 * s_area[:, None])
    r, f = np.nonzero(ok)
    if len(r) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros((0, 2)), np.zeros(0)
    origin = poly[r, 0]
    corners = np.stack([A[r, f], B[r, f], C[r, f]], axis=1) + origin[:, None, :]  # (S, 3, 2)
    seg_mu, seg_w = rule
    pts = np.einsum("qk,skd->sqd", seg_mu, corners).reshape(-1, 2)
    rr = np.repeat(r, len(seg_w))
    W = (np.abs(tri2[r, f])[:, None] * seg_w[None, :]).ravel()
    return rr, pts, W / s_area[rr]
