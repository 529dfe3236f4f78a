"""The contact tangent: its triplets, its own AIJ matrix, and merging it into the FE Jacobian.

The tangent includes the normal penalty term (eps n n), the rotation of an analytic master's
normal (the curvature term p dn/dx, exact for planes and spheres), the friction terms, and for
mesh masters the rotation of the master facet's normal and the sliding of the contact point
over it. A frictionless pair integrated in segments gets the consistent tangent of its
segments instead (:mod:`~.segment_tangent`: the change of the segments as the surfaces slide
is half of the contact's tangent in a joint's sliding mode; without it Newton converged
linearly). Left out: the change of the segments with friction, and the normal of a point
projected on an edge (points mode).

The couplings lie outside dolfinx's sparsity pattern. They are routed to the owning rank of each
row, assembled into their own exactly preallocated AIJ matrix, and added to the FE Jacobian;
the FE matrix is widened (one explicit merge) only when a pair appears that it has not held
before, never by PETSc reallocating entry by entry.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import scipy.sparse
from mpi4py import MPI
from petsc4py import PETSc

from shoulder_fem.engine.contact.evaluation import couplings
from shoulder_fem.engine.contact.pair import ContactPair
from shoulder_fem.engine.contact.segment_tangent import segment_tangent_blocks
from shoulder_fem.engine.contact.surfaces import Facets, MasterMesh
from shoulder_fem.engine.so3 import hats


def master_geometric_terms(st: dict, m: MasterMesh, act, coef, p) -> np.ndarray:
    """Tangent terms of a mesh master's geometry, per unit weight.

    The rotation of the master facet's normal, p dn/dx_k, felt by every node of the point;
    and the sliding of the contact point over the facet, which moves the master's share
    f beta_k, with d(beta_k) = a_k . d(x_s - x_m) (a_k: the in-plane gradients of the
    barycentric coordinates).
    """
    tri = m.x[st["m_idx"][act]]  # (q, 3, 3)
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    nt = np.cross(e1, e2)
    norm = np.linalg.norm(nt, axis=1)
    n = nt / norm[:, None]
    proj = (np.eye(3)[None] - np.einsum("qi,qj->qij", n, n)) / norm[:, None, None]
    h1, h2 = hats(e1), hats(e2)
    B = np.stack([h2 - h1, -h2, h1], axis=1)  # (q, 3 vertices, 3, 3): d(e1 x e2)/dx_k
    dn = np.einsum("qij,qkjl->qkil", proj, B)  # (q, k, 3, 3)
    ns = coef.shape[1] - 3  # slave nodes per point
    q = len(act)
    blk = np.zeros((q, coef.shape[1], 3, coef.shape[1], 3))
    # normal rotation: d(-c_a p n)/dx_k
    blk[:, :, :, ns:, :] -= np.einsum("q,qa,qkij->qaikj", p, coef, dn)
    # sliding: d(beta_k f)/dx_b = c_b f a_k^T
    g11 = np.einsum("qi,qi->q", e1, e1)
    g12 = np.einsum("qi,qi->q", e1, e2)
    g22 = np.einsum("qi,qi->q", e2, e2)
    det = g11 * g22 - g12 * g12
    a1 = (g22 / det)[:, None] * e1 - (g12 / det)[:, None] * e2
    a2 = (g11 / det)[:, None] * e2 - (g12 / det)[:, None] * e1
    a = np.stack([-(a1 + a2), a1, a2], axis=1)  # (q, 3, 3)
    f = p[:, None] * st["n"][act] + st["t"][act]
    blk[:, ns:, :, :, :] += np.einsum("qb,qi,qkj->qkibj", coef, f, a)
    return blk


def _pair_blocks(pair: ContactPair, st: dict, m: MasterMesh | None, act, coef) -> np.ndarray:
    """The tangent blocks (nqa, k, 3, k, 3) of a pair's active points, weights included."""
    eye = np.eye(3)
    n, p, W, kn = st["n"][act], st["p"][act], st["W"][act], st["k"][act]
    nn = np.einsum("qi,qj->qij", n, n)
    D = kn[:, None, None] * nn
    if pair.friction > 0:
        s = st["s"][act]
        root = np.sqrt(np.einsum("qi,qi->q", s, s) + pair.slip_regularization**2)
        mu = pair.friction
        tang = eye[None] - nn
        dts = -(mu * p / root)[:, None, None] * (
            eye[None] - np.einsum("qi,qj->qij", s, s) / (root**2)[:, None, None]
        )
        D = D - mu * np.einsum("q,qi,qj->qij", kn, s / root[:, None], n)
        D = D - np.einsum("qij,qjk->qik", dts, tang)
    blk = np.einsum("qa,qb,qij->qaibj", coef, coef, D)
    if st["dndx"] is not None:  # analytic master: rotation of the normal (slave only)
        dn = st["dndx"][act]
        blk = blk - np.einsum("q,qa,qb,qij->qaibj", p, coef, coef, dn)
    if st["m_idx"] is not None and st["m_idx"].shape[1] == 3:  # flat master facets
        blk = blk + master_geometric_terms(st, m, act, coef, p)
    return blk * W[:, None, None, None, None]


def _expand(blk: np.ndarray, node_rows: np.ndarray, k: int, bc_global: np.ndarray):
    """Sum the blocks of points that couple the same nodes; triplets off the bc rows/columns."""
    # points that couple the same nodes (one slave facet, one master facet) share
    # their block: sum them before expanding to triplets
    _, first, inv = np.unique(node_rows[:, :, 0], axis=0, return_index=True, return_inverse=True)
    inv = inv.ravel()
    order = np.argsort(inv, kind="stable")
    starts = np.r_[0, np.flatnonzero(np.diff(inv[order])) + 1]
    blk = np.add.reduceat(blk[order].reshape(len(node_rows), -1), starts, axis=0)
    blk = blk.reshape(len(first), k, 3, k, 3)
    r = node_rows[first]  # (ng, k, 3)
    bc = np.isin(r, bc_global)
    keep = ~(bc[:, :, :, None, None] | bc[:, None, None, :, :])
    shape = (len(first), k, 3, k, 3)
    rows = np.broadcast_to(r[:, :, :, None, None], shape)[keep]
    cols = np.broadcast_to(r[:, None, None, :, :], shape)[keep]
    return rows, cols, blk[keep]


def jacobian_triplets(
    pairs: Sequence[ContactPair],
    states: Sequence[dict],
    slaves: Sequence[Facets],
    masters: Sequence[MasterMesh | None],
    node_rows: np.ndarray,
    bc_global: np.ndarray,
    segments: dict | None = None,
):
    """(rows, cols, vals) of the contact tangent on this rank, in global rows and columns.

    ``segments``: ``x_nodes`` (current node positions), ``pieces``, ``rule`` and ``lam`` (per
    pair) of segment integration; with it a frictionless pair integrated in segments gets the
    consistent tangent of its segments (:mod:`~.segment_tangent`).
    """
    rows, cols, vals = [], [], []
    for i, (pair, st, sl, m) in enumerate(zip(pairs, states, slaves, masters, strict=True)):
        act, pair_rows, coef = couplings(st, sl, m, node_rows)
        if len(act) == 0:
            continue
        if segments is not None and st.get("m_tri") is not None and pair.friction == 0:
            blk, pair_rows = segment_tangent_blocks(
                pair,
                st,
                sl,
                m,
                segments["x_nodes"],
                segments["pieces"],
                segments["rule"],
                segments["lam"][i],
                node_rows,
            )
        else:
            blk = _pair_blocks(pair, st, m, act, coef)
        r, c, v = _expand(blk, pair_rows, blk.shape[1], bc_global)
        rows.append(r)
        cols.append(c)
        vals.append(v)
    if not rows:
        return (np.zeros(0, dtype=np.int64),) * 2 + (np.zeros(0),)
    return np.concatenate(rows), np.concatenate(cols), np.concatenate(vals)


def _route_to_owners(A: PETSc.Mat, rows, cols, vals, comm: MPI.Comm):
    """Send every triplet to the rank owning its row of ``A`` (collective)."""
    ranges = np.asarray(A.getOwnershipRanges())
    dest = np.searchsorted(ranges, rows, side="right") - 1
    order = np.argsort(dest, kind="stable")
    bounds = np.searchsorted(dest[order], np.arange(comm.size + 1))
    rows, cols, vals = rows[order], cols[order], vals[order]
    send = [(rows[a:b], cols[a:b], vals[a:b]) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]
    recv = comm.alltoall(send)
    rows = np.concatenate([r[0] for r in recv]).astype(np.int64)
    cols = np.concatenate([r[1] for r in recv]).astype(np.int64)
    vals = np.concatenate([r[2] for r in recv])
    return rows, cols, vals


def triplet_matrix(A: PETSc.Mat, rows, cols, vals, comm: MPI.Comm, reuse=None):
    """Triplets (any rank) as an exactly preallocated AIJ matrix with A's layout (collective).

    Args:
        A: The matrix whose layout K takes.
        rows: Global rows of the triplets.
        cols: Global columns of the triplets.
        vals: Values of the triplets (duplicates are summed).
        comm: A's communicator.
        reuse: ``(K, keys)`` of an earlier call, or ``None``: when the triplets' pattern is
            ``keys`` on every rank, K is refilled in place and returned (no new matrix).

    Returns:
        (K, keys): the matrix and the global (row * ncols + col) keys of its local nonzeros.
    """
    if comm.size > 1:  # route every triplet to the rank owning its row
        rows, cols, vals = _route_to_owners(A, rows, cols, vals, comm)
    r0, r1 = A.getOwnershipRange()
    c0, c1 = A.getOwnershipRangeColumn()
    ncol = A.getSize()[1]
    nloc = r1 - r0
    csr = scipy.sparse.coo_matrix((vals, (rows - r0, cols)), shape=(nloc, ncol)).tocsr()
    csr.sum_duplicates()
    csr.sort_indices()
    indptr = csr.indptr.astype(PETSc.IntType)
    uc = csr.indices.astype(np.int64)
    ur = r0 + np.repeat(np.arange(nloc), np.diff(csr.indptr))
    keys = ur.astype(np.int64) * ncol + uc
    if reuse is not None and comm.allreduce(np.array_equal(keys, reuse[1]), op=MPI.LAND):
        K = reuse[0]  # the same pattern: every entry is overwritten
        if len(uc):
            K.setValuesCSR(indptr, uc.astype(PETSc.IntType), csr.data)
        K.assemble()
        return K, reuse[1]
    diag = (uc >= c0) & (uc < c1)
    d_nnz = np.bincount(ur[diag] - r0, minlength=nloc).astype(PETSc.IntType)
    o_nnz = np.bincount(ur[~diag] - r0, minlength=nloc).astype(PETSc.IntType)
    K = PETSc.Mat().createAIJ(A.getSizes(), nnz=(d_nnz, o_nnz), comm=comm)
    K.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, True)
    if len(uc):
        K.setValuesCSR(indptr, uc.astype(PETSc.IntType), csr.data)
    K.assemble()
    return K, keys


def local_keys(K: PETSc.Mat) -> np.ndarray:
    """Global (row * ncols + col) keys of the locally owned nonzeros of an AIJ matrix."""
    indptr, cols, _ = K.getValuesCSR()
    r0, _ = K.getOwnershipRange()
    rows = r0 + np.repeat(np.arange(len(indptr) - 1), np.diff(indptr))
    return rows.astype(np.int64) * K.getSize()[1] + cols.astype(np.int64)


def widen(A: PETSc.Mat, K: PETSc.Mat) -> None:
    """A += K, A's pattern widened to hold K's: one explicit merge (collective).

    A keeps its near-nullspace (the merge replaces A's data and header).
    """
    near = A.getNearNullSpace()
    A.axpy(1.0, K, structure=PETSc.Mat.Structure.DIFFERENT_NONZERO_PATTERN)
    if near.handle:  # petsc4py: 0 when there is none
        A.setNearNullSpace(near)


def add_to_pattern(
    A: PETSc.Mat,
    K: PETSc.Mat,
    merged: np.ndarray,
    comm: MPI.Comm,
    keys: np.ndarray | None = None,
    add=None,
) -> np.ndarray:
    """A += K, widening A's pattern only when K has entries never merged before (collective).

    The widening is one explicit merge (never PETSc reallocating entry by entry); A keeps its
    near-nullspace (the merge replaces A's data and header). Otherwise ``add(A, K)`` (e.g. a
    :class:`~shoulder_fem.engine.subset_add.SubsetAdd`; default ``MatAXPY``). Returns the keys
    merged so far.
    """
    keys = local_keys(K) if keys is None else keys
    new = np.setdiff1d(keys, merged)
    if comm.allreduce(len(new), op=MPI.SUM) > 0:
        widen(A, K)
        return np.union1d(merged, keys)
    if add is None:
        A.axpy(1.0, K, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
    else:
        add(A, K)
    return merged
