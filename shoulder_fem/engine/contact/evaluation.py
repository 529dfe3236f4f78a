"""The contact state of one pair at its contact points: gaps, pressures, friction tractions.

At every contact point q of the slave, in the current configuration x = X + u: the closest
point x_m on the master, its outward normal n (out of the master's solid, towards the slave)
and the signed gap g = (x_q - x_m) . n (negative = penetration); the normal pressure p (penalty
or augmented Lagrangian, :func:`~.pair.normal_pressure`); with friction coefficient mu > 0 the
tangential traction of a regularised Coulomb law, t = -mu p s / sqrt(|s|^2 + e_s^2), s the
relative slip over the load step projected on the tangent plane. The force (p n + t) dA acts
on the slave point and its opposite on the master, spread with the slave facet's shape
functions and the master's barycentric weights (:func:`couplings`). Pressures are nominal (per
unit reference area of the slave).

A pair's state is a dict of arrays over its points (:func:`evaluate_pair` lists the keys).
"""

from __future__ import annotations

import numpy as np

from shoulder_fem.engine.contact import kernel
from shoulder_fem.engine.contact.pair import ContactPair, normal_pressure
from shoulder_fem.engine.contact.points import project_on_mesh, segment_gaps
from shoulder_fem.engine.contact.surfaces import Facets, MasterMesh


def _friction(pair: ContactPair, N, nodes, x_nodes, x_prev, dxm, n, p):
    """Slip s (m) over the load step and friction traction t (Pa) at the points, (q, 3) each."""
    dxs = np.einsum("qa,qai->qi", N, (x_nodes - x_prev)[nodes])
    dx = dxs - dxm
    s = dx - np.einsum("qi,qi->q", dx, n)[:, None] * n
    root = np.sqrt(np.einsum("qi,qi->q", s, s) + pair.slip_regularization**2)
    t = -(pair.friction * p / root)[:, None] * s
    return s, t


def _master_gaps(pair: ContactPair, master: MasterMesh | None, pts: dict, sl: Facets, x_nodes):
    """Slave positions, normals, gaps, master nodes and weights and contact flags.

    Returns:
        (xq, n, g, dndx, m_idx, bary, on): dndx the analytic master's dn/dx (or None),
        m_idx/bary the mesh master's nodes and weights (or None), ``on`` False for points
        that cannot touch the master.
    """
    dndx, m_idx, bary = None, None, None
    kern = kernel.load() if master is not None and "m_tri" in pts else None
    if kern is not None:  # segment points, compiled: one pass over the points
        xq, n, g, m_idx, bary = kern.gaps(master, pts, sl.nodes, x_nodes)
        return xq, n, g, None, m_idx, bary, g >= -pair.search_depth
    xq = np.einsum("qa,qai->qi", pts["N"], x_nodes[sl.nodes[pts["facet"]]])
    if master is None:
        xm, n, g, dndx = pair.master.project(xq)
        on = np.ones(len(xq), dtype=bool)
    else:
        if "m_tri" in pts:
            xm, n, g, m_idx, bary, on = segment_gaps(master, pts, xq)
        else:
            xm, n, g, m_idx, bary, on = project_on_mesh(pair, master, xq)
        on &= g >= -pair.search_depth
    return xq, n, g, dndx, m_idx, bary, on


def _master_motion(master: MasterMesh | None, m_idx, bary, nq: int) -> np.ndarray:
    """The master point's motion over the load step (m, (q, 3); zero for a rigid master)."""
    if master is None:
        return np.zeros((nq, 3))
    return np.einsum("qk,qki->qi", bary, master.x[m_idx] - master.x_prev[m_idx])


def evaluate_pair(
    pair: ContactPair,
    sl: Facets,
    master: MasterMesh | None,
    pts: dict,
    x_nodes: np.ndarray,
    x_prev: np.ndarray,
    lam: np.ndarray,
) -> dict:
    """The state of one pair at its contact points ``pts`` (:mod:`~.points`).

    Args:
        pair: The pair.
        sl: Its slave facets.
        master: Its gathered mesh master (current positions set), or None for a rigid master.
        pts: The contact points.
        x_nodes: Current positions of the local nodes (m, (n, 3)).
        x_prev: Their positions at the last committed step (m).
        lam: Augmented Lagrangian multipliers, linear per slave facet (Pa, (nf, 3)).

    Returns:
        A dict over the points: ``facet``, ``N``, ``N1``, ``W`` (from ``pts``), ``xq``
        (positions, m), ``n`` (master normals), ``g`` (gaps, m), ``p`` (pressures, Pa), ``k``
        (-dp/dg, Pa/m), ``t`` (friction tractions, Pa), ``s`` (slips, m), ``active`` (p > 0),
        ``dndx`` (rigid master's dn/dx or None), ``m_idx``/``bary`` (mesh master nodes and
        weights, or None), ``on`` (points that can touch the master), ``piece``/``m_tri``
        (segments: the slave facet's piece and the master triangle of each point, or None).
    """
    f, N = pts["facet"], pts["N"]
    xq, n, g, dndx, m_idx, bary, on = _master_gaps(pair, master, pts, sl, x_nodes)
    lam = np.einsum("qa,qa->q", pts["N1"], lam[f]) if len(f) else np.zeros(0)
    p, k = normal_pressure(pair, g, lam)
    p = np.where(on, p, 0.0)
    k = np.where(on, k, 0.0)
    active = p > 0
    t = np.zeros_like(xq)
    s = np.zeros_like(xq)
    if pair.friction > 0:
        dxm = _master_motion(master, m_idx, bary, len(xq))
        s, t = _friction(pair, N, sl.nodes[f], x_nodes, x_prev, dxm, n, p)
    return dict(
        facet=f,
        N=N,
        N1=pts["N1"],
        W=pts["W"],
        xq=xq,
        n=n,
        g=g,
        p=p,
        k=k,
        t=t,
        s=s,
        active=active,
        dndx=dndx,
        m_idx=m_idx,
        bary=bary,
        on=on,
        piece=pts.get("piece"),
        m_tri=pts.get("m_tri"),
    )


def couplings(st: dict, sl: Facets, master: MasterMesh | None, node_rows: np.ndarray):
    """Active points, the global rows of their nodes (nqa, k, 3) and coefficients (nqa, k).

    The nodes of a point are its slave facet's, then (mesh master) its master nodes, whose
    coefficients are minus their barycentric weights.
    """
    act = np.flatnonzero(st["active"])
    rows = node_rows[sl.nodes[st["facet"][act]]]
    coef = st["N"][act]
    if st["m_idx"] is not None:
        rows = np.concatenate([rows, master.rows[st["m_idx"][act]]], axis=1)
        coef = np.hstack([coef, -st["bary"][act]])
    return act, rows, coef


def facet_projection(st: dict, nf: int, values: np.ndarray) -> np.ndarray:
    """Point values as linear fields per slave facet (lumped projection): (nf, 3)."""
    num = np.zeros((nf, 3))
    den = np.zeros((nf, 3))
    np.add.at(num, st["facet"], values[:, None] * st["N1"] * st["W"][:, None])
    np.add.at(den, st["facet"], st["N1"] * st["W"][:, None])
    return np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0)
