"""What a run reports of the contact: resultants per pair, master points, pressure fields."""

from __future__ import annotations

from collections.abc import Sequence

import dolfinx
import numpy as np
from mpi4py import MPI

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
}


def pair_resultants(st: dict, comm: MPI.Comm, point: np.ndarray) -> dict:
    """Resultants of one pair's state ``st`` on its slave (collective; :func:`resultants`)."""
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
    )


def resultants(
    pairs: Sequence[ContactPair],
    states: Sequence[dict],
    comm: MPI.Comm,
    point: Sequence[float] = (0.0, 0.0, 0.0),
) -> dict[str, dict]:
    """Resultants of every pair on its slave (collective).

    Returns:
        Per pair: force on the slave (N), moment about ``point`` (N m), normal force (N),
        area in contact (m², reference), maximum pressure (Pa), maximum shear (Pa), centre
        of pressure (m; None without contact), largest penetration (m), active points.
    """
    point = np.asarray(point, dtype=float)
    return {
        pair.name: pair_resultants(st, comm, point) for pair, st in zip(pairs, states, strict=True)
    }


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
    Q: dolfinx.fem.FunctionSpace, slaves: Sequence[Facets], states: Sequence[dict]
) -> tuple[dolfinx.fem.Function, dolfinx.fem.Function]:
    """Nodal contact pressure and shear (Pa) on the slave surfaces, as CG1 fields on ``Q``.

    A lumped projection of the contact points' values with the facets' linear functions
    (collective).
    """
    fields = []
    for name, key in (("contact_pressure", "p"), ("contact_shear", "t")):
        num = dolfinx.fem.Function(Q, name=name)
        den = dolfinx.fem.Function(Q)
        for sl, st in zip(slaves, states, strict=True):
            val = st[key] if key == "p" else np.linalg.norm(st[key], axis=1)
            f, N1, W = st["facet"], st["N1"], st["W"]
            np.add.at(num.x.array, sl.p1[f], val[:, None] * N1 * W[:, None])
            np.add.at(den.x.array, sl.p1[f], N1 * W[:, None])
        for fn in (num, den):
            fn.x.scatter_reverse(dolfinx.la.ScatterMode.add)
            fn.x.scatter_forward()
        with np.errstate(invalid="ignore", divide="ignore"):
            num.x.array[:] = np.where(den.x.array > 0, num.x.array / den.x.array, 0.0)
        fields.append(num)
    return fields[0], fields[1]
