"""The consistent tangent of segment integration against a mesh master.

The segments' points and weights are cut anew at every evaluation: when the surfaces slide, a
master edge moves over the slave facet and its segments change their areas, their points'
places on the slave (the slave's shape functions there) and on the master. Where a master edge
crosses the loaded zone, the force direction p n jumps across it (flat master triangles), and
the rate of that change is a tangent stiffness of its own: the one that holds the sliding of
one faceted surface on the other. The point-wise tangent (the penalty term, the rotation of
the master's normal and the sliding over the master facet) leaves it out, and it is not small
where it matters: in the soft sliding mode of a joint (the humerus turning in its socket) it
was half of the contact's tangent along the Newton step, which made Newton converge linearly
(rate 0.5-0.6 per iteration, measured on the shoulder's part 1).

Here the tangent of each contributing (slave piece, master triangle) pair is the difference
quotient of the pair's exact nodal forces (the same cutting and rule as the residual,
:mod:`~.points`, :mod:`~.evaluation`) in the coordinates of its nodes: the slave facet's and
the master facet's (3 or 6 each). The pairs are independent and small, so the differences are
taken for all of them and all their node coordinates in one evaluation. Forward differences
(3 x 12 perturbed copies of a P2 pair) except for a pair within :data:`NEAR_KINK` of a kink:
of the pressure law at one of its points (g = 0 for the penalty, lam = eps g for the augmented
law, g = -depth) or of its cut (a vertex of the slave piece or the master triangle on the line
of an edge of the other, :func:`~.geometry.cut_kink`). Central ones there (2 x 3 x 12 copies),
since a one-sided difference takes a kink as all or nothing. Measured: forward differences
everywhere broke the muscle-bone contact's seating solve (``muscle_contact = humeral-head``:
the muscle's surface lies on the bone's, vertices on edges at zero gap; no convergence in 15
iterations, where central ones take 8); with the rule, 38 % of that pair's pieces go
central and the solve takes the same 8 iterations. The glenohumeral pair (non-matching
meshes): none at ``coarse``, 6 of 56 112 at ``paper`` (0-60 deg, decoupled). With central
differences everywhere the tangent's error along the Newton step was 2e-6 of the residual
(5e-1 without the segment terms, coarse), and the residual fell 3.4e-3, 3.4e-5, 3.1e-11 N at
the end of a step; forward ones end the same histories at 9e-11 and 4.6e-11 N instead of
5.2e-11 and 9.4e-11, with the same iterations, for half the cuts.
"""

from __future__ import annotations

import numpy as np

from shoulder_fem.engine.contact import kernel
from shoulder_fem.engine.contact.geometry import (
    NODE_MU,
    barycentric_2d,
    cut_kink,
    facing_weight,
    fan_rule,
    overlap_polygons,
    p2_shape,
)
from shoulder_fem.engine.contact.pair import ContactPair, normal_pressure
from shoulder_fem.engine.contact.surfaces import Facets, MasterMesh

__all__ = [
    "FD_STEP",
    "NEAR_KINK",
    "SegmentGeometry",
    "SegmentPairs",
    "segment_geometry",
    "segment_loads",
    "segment_tangent_blocks",
]

#: Difference step (m) of the node coordinates.
FD_STEP = 1e-8
#: Kink distance (m) under which a pair's differences are central: a point on a kink, to 1 %
#: of the step (the conforming surfaces' vertices on edges and points at zero gap are there
#: to round-off). Measured at ``paper``, decoupled 0-10 deg: 41 Newton iterations with this
#: bound, with 1e-12 m and with forward differences everywhere; 51-52 with FD_STEP and 10
#: FD_STEP (2.8 % of the pairs central), the first step's overshoot (a retry with the ``l2``
#: line search in every case) taking 12 iterations to be detected instead of 7.
NEAR_KINK = FD_STEP / 100
#: Perturbed pair copies evaluated at once (memory bound; every pair is independent).
CHUNK_ROWS = 2000


class SegmentPairs:
    """The (slave piece, master triangle) pairs that carry pressure, and their nodes.

    Attributes:
        facet: Slave facet of each pair (M,).
        cols: The piece's vertices among the slave facet's nodes (M, 3).
        m_nodes: The master nodes of each pair (gathered list; (M, 3) flat, (M, 6) P2).
        m_vert: The master triangle's vertices among ``m_nodes`` (M, 3).
        tri_mu: P2: the triangle's vertices in its parent's barycentric coordinates, or None.
        ref_area: Reference area of each slave piece (m²).
    """

    def __init__(self, st: dict, sl: Facets, m: MasterMesh, pieces: np.ndarray):
        act = np.flatnonzero(st["active"])
        key = np.stack([st["facet"][act], st["piece"][act], st["m_tri"][act]], axis=1)
        key = np.unique(key, axis=0) if len(key) else np.zeros((0, 3), dtype=np.int64)
        self.facet, piece, t = key[:, 0], key[:, 1], key[:, 2]
        self.cols = pieces[piece]
        if m.parent is None:
            self.m_nodes = m.index[t]
            self.m_vert = np.broadcast_to(np.arange(3), (len(t), 3))
            self.tri_mu = None
        else:
            self.m_nodes = m.parent[t]
            verts = m.index[t]
            self.m_vert = np.argmax(self.m_nodes[:, None, :] == verts[:, :, None], axis=2)
            self.tri_mu = m.tri_mu[t]
        PX = sl.X[self.facet[:, None], self.cols]
        self.ref_area = 0.5 * np.linalg.norm(
            np.cross(PX[:, 1] - PX[:, 0], PX[:, 2] - PX[:, 0]), axis=1
        )

    def __len__(self) -> int:
        return len(self.facet)

    def select(self, rows: slice) -> SegmentPairs:
        """The pairs ``rows`` only."""
        out = object.__new__(SegmentPairs)
        out.facet, out.cols = self.facet[rows], self.cols[rows]
        out.m_nodes, out.m_vert = self.m_nodes[rows], self.m_vert[rows]
        out.tri_mu = None if self.tri_mu is None else self.tri_mu[rows]
        out.ref_area = self.ref_area[rows]
        return out

    def tiled(self, copies: int) -> SegmentPairs:
        """The same pairs ``copies`` times over (one evaluation of many perturbed states)."""
        out = object.__new__(SegmentPairs)
        out.facet = np.tile(self.facet, copies)
        out.cols = np.tile(self.cols, (copies, 1))
        out.m_nodes = np.tile(self.m_nodes, (copies, 1))
        out.m_vert = np.tile(self.m_vert, (copies, 1))
        out.tri_mu = None if self.tri_mu is None else np.tile(self.tri_mu, (copies, 1, 1))
        out.ref_area = np.tile(self.ref_area, copies)
        return out


class SegmentGeometry:
    """The points of the pairs' segments: what the residual takes from the cut, not from g.

    Attributes:
        rr: The pair of every point (Q,), sorted.
        N1: The slave facet's linear functions at the points (Q, 3).
        N: The slave facet's shape functions there (Q, ns_nodes).
        Nm: The master nodes' functions there (Q, k - ns_nodes).
        W: Weights (m², reference area of the slave) (Q,).
        n: The master triangle's unit normal at every point (Q, 3).
    """

    def __init__(self, rr, N1, N, Nm, W, n):
        self.rr, self.N1, self.N, self.Nm, self.W, self.n = rr, N1, N, Nm, W, n

    def take(self, src: np.ndarray) -> SegmentGeometry:
        """The points of the pairs ``src`` (pair i of the result is pair ``src[i]`` here)."""
        counts = np.bincount(self.rr, minlength=len(src) and int(src.max()) + 1)[src]
        first = np.r_[0, np.cumsum(np.bincount(self.rr))][src]
        rr = np.repeat(np.arange(len(src)), counts)
        idx = np.repeat(first - (np.cumsum(counts) - counts), counts) + np.arange(len(rr))
        return SegmentGeometry(
            rr, self.N1[idx], self.N[idx], self.Nm[idx], self.W[idx], self.n[idx]
        )


def _planar(pp: SegmentPairs, Y: np.ndarray, ns_nodes: int):
    """The pairs' slave pieces (M, 3, 3), their unit normals and their master triangles."""
    rows = np.arange(len(Y))[:, None]
    P = Y[rows, pp.cols]
    tri = Y[rows, ns_nodes + pp.m_vert]
    nsv = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    nsv /= np.linalg.norm(nsv, axis=1)[:, None]
    return P, nsv, tri


def segment_geometry(
    pp: SegmentPairs, Y: np.ndarray, rule: tuple[np.ndarray, np.ndarray], ns_nodes: int
) -> SegmentGeometry | None:
    """The segments' points of the pairs at their nodes' positions ``Y`` (M, k, 3), or None.

    Only the slave piece's vertices (``pp.cols``) and the master triangle's (``pp.m_vert``)
    move them: the other nodes enter the residual through the gap alone.
    """
    P, nsv, tri = _planar(pp, Y, ns_nodes)
    s2, m2, poly, cnt = overlap_polygons(P, nsv, tri)
    rr, pts, W = fan_rule(poly, cnt, s2, rule)
    if len(rr) == 0:
        return None
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1), 1e-300)[:, None]
    W = W * (pp.ref_area * facing_weight(-np.einsum("qi,qi->q", nsv, n)))[rr]
    lam_s = barycentric_2d(pts, s2[rr])
    beta = barycentric_2d(pts, m2[rr])
    N1 = np.einsum("qk,qkj->qj", lam_s, NODE_MU[pp.cols[rr]])
    N = N1 if ns_nodes == 3 else p2_shape(N1)
    if pp.tri_mu is None:
        Nm = beta
    else:
        Nm = p2_shape(np.einsum("qk,qkj->qj", beta, pp.tri_mu[rr]))
    return SegmentGeometry(rr, N1, N, Nm, W, n[rr])


def segment_loads(
    pair: ContactPair,
    geo: SegmentGeometry | None,
    Y: np.ndarray,
    lam_f: np.ndarray,
    ns_nodes: int,
) -> np.ndarray:
    """Residual contributions (N) of the pairs, (M, k, 3), at ``Y`` with the points ``geo``.

    ``Y`` (M, k, 3): the slave facet's ``ns_nodes`` nodes, then the master nodes. With ``geo``
    from :func:`segment_geometry` at ``Y``: the same cutting, rule, gaps and pressures as
    :func:`~.points.segment_points` and :func:`~.evaluation.evaluate_pair` (frictionless),
    restricted to each pair.
    """
    R = np.zeros_like(Y)
    if geo is None:
        return R
    rr, N, Nm, n = geo.rr, geo.N, geo.Nm, geo.n
    Yr = Y[rr]
    g, lam = _gaps(geo, Yr, lam_f, ns_nodes)
    p, _ = normal_pressure(pair, g, lam)
    p = np.where(g >= -pair.search_depth, p, 0.0)
    f = (p * geo.W)[:, None] * n
    C = np.empty(Yr.shape)  # -(N, -Nm) x f, without the temporaries
    np.multiply(N[:, :, None], -f[:, None, :], out=C[:, :ns_nodes])
    np.multiply(Nm[:, :, None], f[:, None, :], out=C[:, ns_nodes:])
    starts = np.r_[0, np.flatnonzero(np.diff(rr)) + 1]  # rr is sorted (fan_rule)
    R[rr[starts]] = np.add.reduceat(C, starts, axis=0)  # np.add.at is ten times slower
    return R


def _gaps(geo: SegmentGeometry, Yr: np.ndarray, lam_f: np.ndarray, ns_nodes: int):
    """Gaps (m) and multipliers (Pa) at the points of ``geo``; ``Yr`` the nodes per point."""
    xq = np.einsum("qa,qai->qi", geo.N, Yr[:, :ns_nodes])
    xm = np.einsum("qa,qai->qi", geo.Nm, Yr[:, ns_nodes:])
    g = np.einsum("qi,qi->q", xq - xm, geo.n)
    return g, np.einsum("qa,qa->q", geo.N1, lam_f[geo.rr])


def kink_distance(pair: ContactPair, g: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """How far (m of gap) the pressure law's argument is from a kink or jump of the law.

    g = 0 (penalty), lam - eps g = 0 (augmented), g = -depth (the search depth); the
    smoothed penalty is C1 and has none but the depth.
    """
    d = np.abs(g + pair.search_depth)
    if pair.method == "augmented":
        return np.minimum(np.abs(lam - pair.penalty * g) / pair.penalty, d)
    return np.minimum(np.abs(g), d) if pair.smoothing == 0.0 else d


def near_kink(pair: ContactPair, pp: SegmentPairs, geo: SegmentGeometry | None, Y, lam_f):
    """Per pair (M,), whether it lies within :data:`NEAR_KINK` of a kink.

    Of its cut (:func:`~.geometry.cut_kink`) or of the pressure law at one of its points.
    """
    ns_nodes = Y.shape[1] - pp.m_nodes.shape[1]
    s2, m2 = overlap_polygons(*_planar(pp, Y, ns_nodes))[:2]
    out = cut_kink(s2, m2) < NEAR_KINK
    if geo is not None:
        g, lam = _gaps(geo, Y[geo.rr], lam_f, ns_nodes)
        out[geo.rr[kink_distance(pair, g, lam) < NEAR_KINK]] = True
    return out


def _perturbed(Ys: np.ndarray, nodes: np.ndarray) -> np.ndarray:
    """Copies of the pairs' positions ``Ys`` (m, k, 3), one node coordinate moved by +-h each.

    ``nodes`` (m, q): the nodes moved, per pair. Returns (2, q, 3, m, k, 3): [0] +h, [1] -h.
    """
    m, q = nodes.shape
    Yall = np.broadcast_to(Ys, (2, q, 3) + Ys.shape).copy()
    j, i, r = np.ix_(np.arange(q), np.arange(3), np.arange(m))
    Yall[0, j, i, r, nodes.T[:, None, :], i] += FD_STEP
    Yall[1, j, i, r, nodes.T[:, None, :], i] -= FD_STEP
    return Yall


def _moved_nodes(pp: SegmentPairs, k: int, ns_nodes: int) -> tuple[np.ndarray, np.ndarray]:
    """Per pair, the nodes that move its segments' points (M, 6) and the others (M, k - 6)."""
    cut = np.hstack([pp.cols, ns_nodes + pp.m_vert])
    mask = np.zeros((len(pp), k), dtype=bool)
    mask[np.arange(len(pp))[:, None], cut] = True
    others = np.nonzero(~mask)[1].reshape(len(pp), k - cut.shape[1])
    return cut, others


def segment_tangent_blocks(
    pair: ContactPair,
    st: dict,
    sl: Facets,
    m: MasterMesh,
    x_nodes: np.ndarray,
    pieces: np.ndarray,
    rule: tuple[np.ndarray, np.ndarray],
    lam: np.ndarray,
    node_rows: np.ndarray,
):
    """The consistent tangent blocks of a segment-integrated, frictionless pair.

    Forward differences, central for the pairs :func:`near_kink`. The differences in the
    coordinates of the nodes that do not move the segments' points (P2: the slave facet's
    nodes off the piece, the master facet's off its triangle) reuse the unperturbed pair's
    points: the same values as cutting every copy anew. The numpy code takes both sides for
    every pair and keeps the forward quotient where the compiled kernel does.

    Returns:
        (blk (M, k, 3, k, 3), rows (M, k, 3)): d(residual)/d(node positions) of every pair
        that carries pressure, and the global rows of its nodes.
    """
    pp = SegmentPairs(st, sl, m, pieces)
    ns_nodes = sl.nodes.shape[1]
    Y = np.concatenate([x_nodes[sl.nodes[pp.facet]], m.x[pp.m_nodes]], axis=1)  # (M, k, 3)
    M, k = Y.shape[:2]
    rows = np.concatenate([node_rows[sl.nodes[pp.facet]], m.rows[pp.m_nodes]], axis=1)
    kern = kernel.load()
    if kern is not None:
        lam_f = lam[pp.facet]
        blk, _ = kern.tangent(
            pair,
            Y,
            pp.cols,
            pp.m_vert,
            pp.tri_mu,
            pp.ref_area,
            lam_f,
            rule,
            ns_nodes,
            FD_STEP,
            NEAR_KINK,
        )
        return blk, rows
    cut, others = _moved_nodes(pp, k, ns_nodes)
    blk = np.empty((M, k, 3, k, 3))
    chunk = max(1, CHUNK_ROWS // (6 * cut.shape[1]))  # pairs per evaluation: bounds the memory
    for s in range(0, M, chunk):
        sub = pp.select(slice(s, s + chunk))
        Ys, lam_s = Y[s : s + chunk], lam[sub.facet]
        mc = len(Ys)
        D = np.empty((mc, k, 3, k, 3))  # D[pair, moved node, coordinate] = d(R of the pair)
        r = np.arange(mc)[None, None, :]
        base_geo = segment_geometry(sub, Ys, rule, ns_nodes)
        R0 = segment_loads(pair, base_geo, Ys, lam_s, ns_nodes)  # (mc, k, 3)
        central = near_kink(pair, sub, base_geo, Ys, lam_s)[:, None, None]
        for nodes, same_cut in ((cut[s : s + chunk], False), (others[s : s + chunk], True)):
            q = nodes.shape[1]
            if q == 0:
                continue
            Yall = _perturbed(Ys, nodes).reshape(-1, k, 3)  # (2*3q*mc, k, 3)
            src = np.tile(np.arange(mc), 6 * q)
            if same_cut:
                geo = None if base_geo is None else base_geo.take(src)
            else:
                geo = segment_geometry(sub.tiled(6 * q), Yall, rule, ns_nodes)
            R = segment_loads(pair, geo, Yall, lam_s[src], ns_nodes).reshape(2, q, 3, mc, k, 3)
            Dq = np.where(central, (R[0] - R[1]) / (2 * FD_STEP), (R[0] - R0) / FD_STEP)
            D[r, nodes.T[:, None, :], np.arange(3)[None, :, None]] = Dq
        blk[s : s + chunk] = np.moveaxis(D, (1, 2), (3, 4))
    return blk, rows
