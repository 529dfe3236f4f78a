"""Slave facets dealt evenly to the ranks: the contact's work balanced under MPI.

A slave facet is found by the rank owning its cell (:func:`~.surfaces.surface_facets`), and
the partitioner keeps a small surface whole: at ``paper`` on 2 ranks every one of the
glenoid's 291 facets is on rank 0, so rank 0 cut, evaluated and differentiated all the
glenohumeral contact while rank 1 waited. :func:`share_slaves` deals each rank's facets of
every pair round-robin to all the ranks (facet i of rank r to rank (i + r) mod size), once, at
the start. A rank then holds facets whose nodes it may not have: those nodes are *imported*,
appended after its own nodes, and :meth:`NodeImport.extend` brings their values (current
positions at every evaluation, global rows once; reference positions come with the facets)
from the rank that dealt the facet. The contact's rows and columns are global, so its forces
and tangent reach their owners as before (PETSc's stash, the triplets' all-to-all).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from mpi4py import MPI

from shoulder_fem.engine.contact.surfaces import Facets

__all__ = ["NodeImport", "global_dofs", "share_slaves"]


def global_dofs(Q) -> np.ndarray:
    """The global index of every local (owned and ghost) dof of a scalar space ``Q``."""
    imap = Q.dofmap.index_map
    return imap.local_to_global(np.arange(imap.size_local + imap.num_ghosts, dtype=np.int32))


@dataclass
class NodeImport:
    """Which of this rank's nodes every other rank imports, in the order it appends them."""

    comm: MPI.Comm
    #: Per rank: the local node indices whose values that rank imports (empty for this rank).
    send: list[np.ndarray]

    def extend(self, local: np.ndarray) -> np.ndarray:
        """``local`` (a row per local node), the imported nodes' rows appended (collective)."""
        if self.comm.size == 1:
            return local
        parts = self.comm.alltoall([local[idx] for idx in self.send])
        return np.concatenate([local, *parts])


def share_slaves(
    slaves: list[Facets], n_nodes: int, q_global: np.ndarray, comm: MPI.Comm
) -> tuple[list[Facets], NodeImport]:
    """Deal every pair's slave facets round-robin to the ranks (collective).

    Args:
        slaves: Every pair's facets as found on this rank (local nodes, local CG1 dofs).
        n_nodes: This rank's local nodes (owned and ghost): imported nodes are numbered from it.
        q_global: Global index of every local CG1 dof.
        comm: The mesh's communicator.

    Returns:
        The facets this rank holds for every pair (its own kept ones first, then those dealt
        by each other rank in rank order), their ``p1`` as *global* CG1 dofs, and the import
        that completes their nodes.
    """
    size, rank = comm.size, comm.rank
    p1_global = [q_global[sl.p1] for sl in slaves]
    if size == 1:
        shared = [
            _facets(sl.nodes, sl.X, p1, sl.tags) for sl, p1 in zip(slaves, p1_global, strict=True)
        ]
        return shared, NodeImport(comm, [np.zeros(0, dtype=np.int64)])
    dest = [(np.arange(len(sl.nodes)) + rank) % size for sl in slaves]
    send, payload = [], []
    for d in range(size):
        picks = [to == d for to in dest]
        if d == rank:
            send.append(np.zeros(0, dtype=np.int64))
            payload.append(None)
            continue
        nodes = [sl.nodes[pick].ravel() for sl, pick in zip(slaves, picks, strict=True)]
        send.append(np.concatenate(nodes).astype(np.int64) if nodes else np.zeros(0, np.int64))
        payload.append(
            [
                (sl.X[pick], p1[pick], sl.tags[pick])
                for sl, p1, pick in zip(slaves, p1_global, picks, strict=True)
            ]
        )
    received = comm.alltoall(payload)
    start, first = n_nodes, {}  # where each other rank's imported nodes begin
    for s in range(size):
        if s != rank:
            first[s] = start
            start += sum(len(X) * X.shape[1] for X, _, _ in received[s])
    shared = []
    for p, sl in enumerate(slaves):
        keep = dest[p] == rank
        nodes, X, p1, tags = [sl.nodes[keep]], [sl.X[keep]], [p1_global[p][keep]], [sl.tags[keep]]
        for s in sorted(first):
            Xs, p1s, tags_s = received[s][p]
            nf, nn = Xs.shape[0], Xs.shape[1]
            nodes.append(first[s] + np.arange(nf * nn, dtype=np.int64).reshape(nf, nn))
            first[s] += nf * nn
            X.append(Xs)
            p1.append(p1s)
            tags.append(tags_s)
        shared.append(
            _facets(
                np.concatenate(nodes), np.concatenate(X), np.concatenate(p1), np.concatenate(tags)
            )
        )
    return shared, NodeImport(comm, send)


def _facets(nodes, X, p1, tags) -> Facets:
    return Facets(
        nodes=np.asarray(nodes, dtype=np.int64),
        X=np.asarray(X, dtype=float),
        p1=np.asarray(p1, dtype=np.int64),
        tags=np.asarray(tags, dtype=np.int64),
    )
