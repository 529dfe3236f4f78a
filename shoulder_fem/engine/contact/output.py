"""What a run reports of the contact: resultants per pair, master points, pressure fields."""

from __future__ import annotations

from collections.abc import Sequence

import dolfinx
import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from shoulder_fem.engine.contact.pair import ContactPair
from shoulder_fem.engine.contact.surfaces import Facets, MasterMesh

#: The resultants of a pair (:func:`resultants`) and their units, as recorded in probes.
RESULTANT_UNITS = {
    "force": "N",
    "moment": "N*m",
    "normal_force": "N",
    "area": "m^2",
    "max_pressure": "Pa",
    "max_shear": "Pa",
    "centre_of_pressure": "m",
    "max_penetration": "m",
    "active_points": "1",
    "penalty_energy": "J",
}


def pair_resultants(
    st: dict, comm: MPI.Comm, point: np.ndarray, select: np.ndarray | None = None
) -> dict:
    """Resultants of one pair's state ``st`` on its slave (collective; :func:`resultants`).

    ``select``: a mask of the state's points to sum over (None: all of them).
    """
    if select is not None:
        keys = ("active", "W", "p", "n", "t", "xq", "g")
        st = {k: st[k][select] for k in keys}
    a = st["active"]
    W = st["W"][a]
    f = (st["p"][a, None] * st["n"][a] + st["t"][a]) * W[:, None]
    x = st["xq"][a]
    local = np.zeros(13)
    local[0:3] = f.sum(axis=0)
    local[3:6] = np.cross(x - point, f).sum(axis=0)
    local[6] = (st["p"][a] * W).sum()
    local[7] = W.sum()
    local[8:11] = (st["p"][a, None] * W[:, None] * x).sum(axis=0)
    local[11] = np.count_nonzero(a)
    local[12] = 0.5 * (st["p"][a] * -st["g"][a] * W).sum()
    total = comm.allreduce(local, op=MPI.SUM)
    pmax = comm.allreduce(float(st["p"].max(initial=0.0)), op=MPI.MAX)
    shear = np.linalg.norm(st["t"], axis=1) if len(st["t"]) else np.zeros(0)
    tmax = comm.allreduce(float(shear.max(initial=0.0)), op=MPI.MAX)
    pen = comm.allreduce(float((-st["g"][a]).max(initial=0.0)), op=MPI.MAX)
    return dict(
        force=total[0:3],
        moment=total[3:6],
        normal_force=float(total[6]),
        area=float(total[7]),
        max_pressure=pmax,
        max_shear=tmax,
        centre_of_pressure=(total[8:11] / total[6]) if total[6] > 0 else None,
        max_penetration=pen,
        active_points=int(total[11]),
        penalty_energy=float(total[12]),
    )


def resultants(
    pairs: Sequence[ContactPair],
    states: Sequence[dict],
    comm: MPI.Comm,
    point: Sequence[float] = (0.0, 0.0, 0.0),
    slaves: Sequence[Facets] | None = None,
) -> dict[str, dict]:
    """Resultants of every pair on its slave (collective).

    Returns:
        Per pair: force on the slave (N), moment about ``point`` (N m), normal force (N),
        area in contact (m², reference), maximum pressure (Pa), maximum shear (Pa), centre
        of pressure (m; None without contact), largest penetration (m), active points, and
        the energy the penalty stores in the overlap, 1/2 sum p (-g) dA (J; exact for the linear
        law p = eps (-g), the elastic energy of the penalty's own compliance 1/eps). With
        the pairs' ``slaves`` given: per pair, those of each tag value of its slave
        (:func:`tag_resultants`).
    """
    point = np.asarray(point, dtype=float)
    if slaves is not None:
        parts = zip(pairs, states, slaves, strict=True)
        return {p.name: tag_resultants(p, st, sl, comm, point) for p, st, sl in parts}
    return {
        pair.name: pair_resultants(st, comm, point) for pair, st in zip(pairs, states, strict=True)
    }


def tag_resultants(
    pair: ContactPair, st: dict, slave: Facets, comm: MPI.Comm, point: Sequence[float]
) -> dict[int, dict]:
    """Resultants of one pair on each tag value of its slave (collective).

    The slave's points summed by the tag of the facet they lie on (:func:`pair_resultants`):
    e.g. the muscles of one slave surface, each its own tag. Their forces add up to the
    pair's.
    """
    point = np.asarray(point, dtype=float)
    of_point = slave.tags[st["facet"]] if len(st["facet"]) else np.zeros(0, dtype=np.int64)
    return {t: pair_resultants(st, comm, point, of_point == t) for t in pair.slave}


def master_points(st: dict, m: MasterMesh) -> tuple[np.ndarray, np.ndarray]:
    """Active points of a pair on its mesh master ``m``, in the master's reference geometry.

    Returns:
        The points (m, (n, 3): the master nodes' reference positions weighted as the current
        closest points) and their normal forces p dA (N, (n,)).
    """
    a = st["active"]
    X = np.einsum("qk,qki->qi", st["bary"][a], m.X[st["m_idx"][a]])
    return X, st["p"][a] * st["W"][a]


def pressure_fields(
    Q: dolfinx.fem.FunctionSpace,
    slaves: Sequence[Facets],
    states: Sequence[dict],
    masters: Sequence[MasterMesh | None] = (),
) -> tuple[dolfinx.fem.Function, dolfinx.fem.Function]:
    """Nodal contact pressure and shear (Pa) on the slave and mesh-master surfaces (CG1 on Q).

    Lumped projections of the contact points' values with the linear functions of the facets
    they lie on. On the slave, whose facets all carry points, over each node's points. On the
    master (for a P2 master, its parent facets' linear functions: the P2 ones at the point,
    each edge's value shared by its two vertices), over the node's whole lumped area, the part
    no slave covers counting as zero pressure: normalised by the covered part alone, a node
    barely reached at the contact's rim took one point's pressure (measured at ``coarse``,
    60 deg: 1.10 MPa against the glenoid's 0.52). Collective.
    """
    fields = []
    comm = Q.mesh.comm
    for name, key in (("contact_pressure", "p"), ("contact_shear", "t")):
        num = dolfinx.fem.Function(Q, name=name)
        den = dolfinx.fem.Function(Q)
        for sl, st in zip(slaves, states, strict=True):  # the slaves' p1: global dofs
            val = _point_values(st, key)
            f, N1, W = st["facet"], st["N1"], st["W"]
            rows = sl.p1[f].ravel().astype(PETSc.IntType)
            add = PETSc.InsertMode.ADD_VALUES
            num.vector.setValues(rows, (val[:, None] * N1 * W[:, None]).ravel(), addv=add)
            den.vector.setValues(rows, (N1 * W[:, None]).ravel(), addv=add)
        for fn in (num, den):
            fn.vector.assemblyBegin()
            fn.vector.assemblyEnd()
            fn.x.scatter_forward()
        for m, st in zip(masters, states, strict=False):
            if m is not None:  # the master's sums are global: added to owned and ghost dofs
                m_num, m_den = _master_sums(m, st, key, comm)
                for fn, sums in ((num, m_num), (den, m_den)):
                    values = np.zeros_like(fn.x.array)
                    values[m.vertex_q] = sums[m.vertex_gathered]
                    fn.x.array[:] += values
        with np.errstate(invalid="ignore", divide="ignore"):
            num.x.array[:] = np.where(den.x.array > 0, num.x.array / den.x.array, 0.0)
        fields.append(num)
    return fields[0], fields[1]


def _point_values(st: dict, key: str) -> np.ndarray:
    return st[key] if key == "p" else np.linalg.norm(st[key], axis=1)


def _master_sums(m: MasterMesh, st: dict, key: str, comm: MPI.Comm):
    """Lumped-projection sums (value x weight, lumped area) on the gathered master vertices."""
    val, W, bary, nodes = _point_values(st, key), st["W"], st["bary"], st["m_idx"]
    if bary.shape[1] == 6:  # P2: the parent facet's linear functions from its P2 ones
        bary = bary[:, :3] + 0.5 * bary[:, [3, 3, 4]] + 0.5 * bary[:, [5, 4, 5]]
        nodes = nodes[:, :3]
    num = np.zeros(len(m.X))
    np.add.at(num, nodes, val[:, None] * bary * W[:, None])
    return comm.allreduce(num, op=MPI.SUM), m.lumped_area
