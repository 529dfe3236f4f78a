"""Where the contact is integrated: the contact points of a slave surface and their pairing.

Three kinds of points: a fixed rule on every slave facet (analytic masters, or
``mesh_integration="points"``); against a mesh master, the segments: each slave facet (or P2
sub-triangle) cut along the edges of the master triangles it overlaps, projected on its plane,
with a rule on each piece, so that both sides receive consistent loads and two non-matching
meshes transmit a uniform pressure exactly (patch test); or the closest-point projection of the
fixed points on the master's triangles. The pairing is searched again at every evaluation (a
k-d tree on the master triangle centroids), which is what large sliding needs.

A set of points is a dict: ``facet`` (slave facet of each point), ``N`` (the facet's shape
functions there), ``N1`` (its linear functions), ``W`` (weights, m² of reference area) and, for
segments, ``piece`` (the facet's flat piece), ``m_tri`` (master triangle) and ``bary``
(barycentric weights on it).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from shoulder_fem.engine.contact import kernel
from shoulder_fem.engine.contact.geometry import (
    FACING_MIN,
    NODE_MU,
    barycentric_2d,
    closest_points_on_triangles,
    facing_weight,
    fan_rule,
    overlap_polygons,
    p2_shape,
)
from shoulder_fem.engine.contact.pair import ContactPair
from shoulder_fem.engine.contact.surfaces import Facets, MasterMesh


def fixed_points(sl: Facets, N: np.ndarray, N1: np.ndarray, w: np.ndarray) -> dict:
    """The points of a fixed rule (``N``, ``N1``, ``w`` of unit area) on every slave facet."""
    nf, nq = len(sl.nodes), len(w)
    X = sl.X
    area = 0.5 * np.linalg.norm(np.cross(X[:, 1] - X[:, 0], X[:, 2] - X[:, 0]), axis=1)
    return dict(
        facet=np.repeat(np.arange(nf), nq),
        N=np.tile(N, (nf, 1)),
        N1=np.tile(N1, (nf, 1)),
        W=(area[:, None] * w[None, :]).ravel(),
    )


def _no_segments(nn: int) -> dict:
    """An empty set of segment points (slave facets of ``nn`` nodes)."""
    return dict(
        facet=np.zeros(0, dtype=np.int64),
        piece=np.zeros(0, dtype=np.int64),
        N=np.zeros((0, nn)),
        N1=np.zeros((0, 3)),
        W=np.zeros(0),
        m_tri=np.zeros(0, dtype=np.int64),
        bary=np.zeros((0, 3)),
    )


#: Candidate (slave piece, master triangle) pairs cut at once: bounds the cut's work arrays
#: (the pairs are independent, the points the same as in one pass). Measured at ``paper``, part
#: 1 at 60 deg: 200k candidate pairs in one pass took 76 MB of temporaries.
CUT_CHUNK = 20_000


def _facing_candidates(P: np.ndarray, tri: np.ndarray, candidates: int):
    """Pairs (slave piece j, master triangle t) near each other and facing each other.

    Returns:
        (j, t, ns, wf): the pairs' indices, the pieces' unit normals (all pieces) and each
        pair's :func:`~.geometry.facing_weight`.
    """
    ns = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    ns /= np.linalg.norm(ns, axis=1)[:, None]
    cs = P.mean(axis=1)
    rs = np.linalg.norm(P - cs[:, None], axis=2).max(axis=1)
    cm = tri.mean(axis=1)
    nm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    nm /= np.linalg.norm(nm, axis=1)[:, None]
    rm = np.linalg.norm(tri - cm[:, None], axis=2).max()
    k = min(max(candidates, 24), len(tri))
    dist, cand = cKDTree(cm).query(cs, k=k, distance_upper_bound=2.0 * rs.max() + rm)
    dist, cand = dist.reshape(len(cs), k), cand.reshape(len(cs), k)
    j, c = np.nonzero(np.isfinite(dist))
    t = cand[j, c]
    facing = -np.einsum("qi,qi->q", ns[j], nm[t])
    keep = facing > FACING_MIN  # facing each other
    return j[keep], t[keep], ns, facing_weight(facing[keep])


def segment_points(
    pair: ContactPair,
    sl: Facets,
    m: MasterMesh,
    x_nodes: np.ndarray,
    pieces: np.ndarray,
    seg_rule: tuple[np.ndarray, np.ndarray],
) -> dict:
    """Contact points of the slave facets cut along the master triangles they overlap.

    Args:
        pair: The contact pair (its ``candidates``).
        sl: The slave facets.
        m: The mesh master, at its current positions ``m.x``.
        x_nodes: Current positions of the local nodes (m, (n, 3)).
        pieces: The flat pieces of a slave facet (node triples: the facet, or its 4 P2
            sub-triangles).
        seg_rule: The rule on each piece of overlap (:func:`~.geometry.segment_rule`).
    """
    nf, npc = len(sl.nodes), len(pieces)
    empty = _no_segments(sl.nodes.shape[1])
    tri = m.x[m.index]
    if nf == 0 or len(tri) == 0:
        return empty
    P = x_nodes[sl.nodes][:, pieces].reshape(-1, 3, 3)  # current piece vertices
    PX = sl.X[:, pieces].reshape(-1, 3, 3)
    ref_area = 0.5 * np.linalg.norm(np.cross(PX[:, 1] - PX[:, 0], PX[:, 2] - PX[:, 0]), axis=1)
    piece_facet = np.repeat(np.arange(nf), npc)
    piece_id = np.tile(np.arange(npc), nf)
    j, t, ns, wf = _facing_candidates(P, tri, pair.candidates)
    nn = sl.nodes.shape[1]
    kern = kernel.load()
    parts = []
    for c in range(0, len(j), CUT_CHUNK):  # the cut's work arrays, a chunk of pairs at a time
        jc, tc, wc = j[c : c + CUT_CHUNK], t[c : c + CUT_CHUNK], wf[c : c + CUT_CHUNK]
        if kern is not None:
            rr, lam_s, beta, W = kern.cut(P[jc], ns[jc], tri[tc], seg_rule)
        else:
            s2, m2, poly, cnt = overlap_polygons(P[jc], ns[jc], tri[tc])
            # fan triangles of each polygon, the rule on each
            rr, pts, W = fan_rule(poly, cnt, s2, seg_rule)
            lam_s = barycentric_2d(pts, s2[rr])
            beta = barycentric_2d(pts, m2[rr])  # on the master's own vertex order
        if len(rr) == 0:
            continue
        W = W * ref_area[jc[rr]] * wc[rr]
        pj = jc[rr]
        cols = pieces[piece_id[pj]]  # (npts, 3)
        N1 = np.einsum("qk,qkj->qj", lam_s, NODE_MU[cols])
        if nn == 6:  # P2: the slave's own quadratic functions (consistent loads)
            N = p2_shape(N1)
        else:
            N = np.zeros((len(rr), nn))
            np.add.at(N, (np.arange(len(rr))[:, None], cols), lam_s)
        parts.append(
            dict(
                facet=piece_facet[pj], piece=piece_id[pj], N=N, N1=N1, W=W, m_tri=tc[rr], bary=beta
            )
        )
    if not parts:
        return empty
    return {key: np.concatenate([part[key] for part in parts]) for key in parts[0]}


def segment_gaps(m: MasterMesh, pts: dict, xq: np.ndarray):
    """Closest points, normals and gaps of segment points on the master triangles they cut.

    Returns:
        (xm, n, g, m_idx, bary, on) as :func:`project_on_mesh`; every point is ``on``.
    """
    t = pts["m_tri"]
    m_idx, bary = m.index[t], pts["bary"]
    tri = m.x[m_idx]
    if m.parent is not None:  # P2 master: its own quadratic functions
        bary = p2_shape(np.einsum("qk,qkj->qj", bary, m.tri_mu[t]))
        m_idx = m.parent[t]
    xm = np.einsum("qk,qki->qi", bary, m.x[m_idx])
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1), 1e-300)[:, None]
    g = np.einsum("qi,qi->q", xq - xm, n)
    on = np.ones(len(xq), dtype=bool)
    return xm, n, g, m_idx, bary, on


def project_on_mesh(pair: ContactPair, m: MasterMesh, xq: np.ndarray):
    """Closest points of ``xq`` (m, (q, 3)) on a mesh master's triangles.

    Returns:
        (xm, n, g, m_idx, bary, on): the closest points (m), the triangles' unit normals, the
        gaps (m), the master nodes of each point (q, 3) with their barycentric weights, and
        whether the point faces the master (False beyond its rim).
    """
    tri = m.x[m.index]  # (nt, 3, 3)
    if len(xq) == 0:
        z = np.zeros((0, 3))
        return z, z, np.zeros(0), np.zeros((0, 3), dtype=np.int64), z, np.zeros(0, bool)
    k = min(pair.candidates, len(tri))
    tree = cKDTree(tri.mean(axis=1))
    _, cand = tree.query(xq, k=k)
    cand = cand.reshape(len(xq), k)
    a, b, c = tri[cand, 0], tri[cand, 1], tri[cand, 2]
    q, bary, d2, feat = closest_points_on_triangles(xq[:, None, :], a, b, c)
    best = np.argmin(d2, axis=1)
    rows = np.arange(len(xq))
    t_id = cand[rows, best]
    q, bary, feat = q[rows, best], bary[rows, best], feat[rows, best]
    nrm = np.cross(tri[t_id, 1] - tri[t_id, 0], tri[t_id, 2] - tri[t_id, 0])
    n = nrm / np.linalg.norm(nrm, axis=1)[:, None]
    d = xq - q
    g = np.einsum("qi,qi->q", d, n)
    # a point beyond the master's rim (closest feature a rim edge, offset sideways) is
    # not in contact with it
    lateral = np.linalg.norm(d - g[:, None] * n, axis=1)
    size = np.sqrt(np.linalg.norm(nrm, axis=1))
    rim = np.zeros(len(xq), dtype=bool)
    fe = feat >= 0
    rim[fe] = m.boundary[t_id[fe], feat[fe]]
    on = ~(rim & (lateral > 1e-6 * size))
    return q, n, g, m.index[t_id], bary, on
