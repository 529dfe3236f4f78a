"""The scapula's mesh kept in a decoupled run's folder, for the part 2s that reuse its part 1.

A sweep over the bone (:func:`shoulder_fem.api.sweep`) needs the scapula as part 1 saw it, node
for node (part 1's loads sit on its nodes). Meshing the whole joint again took 4.7-6.6 of the
first variant's 6.5-9 CPU s at ``paper``; reading the scapula back from the run's
``scapula_mesh.xdmf`` (:func:`save`) takes a fraction of a second. A run written before the
file existed is meshed again.
"""

from __future__ import annotations

from pathlib import Path

import dolfinx
from mpi4py import MPI

from shoulder_fem.meshes import shoulder as S

__all__ = ["FILE", "load", "save"]

#: The file in a decoupled run's folder (with its ``.h5``).
FILE = "scapula_mesh.xdmf"
_CELLS, _FACETS = "cell_tags", "facet_tags"


def save(sm: S.ShoulderMesh, folder: Path) -> None:
    """Write the scapula mesh ``sm`` and its cell and facet tags to ``folder/FILE`` (collective).

    ``folder`` is a run's staging folder (committed whole when the run ends).
    """
    mesh = sm.mesh
    mesh.topology.create_connectivity(mesh.topology.dim - 1, mesh.topology.dim)
    names = sm.cell_tags.name, sm.facet_tags.name
    sm.cell_tags.name, sm.facet_tags.name = _CELLS, _FACETS
    try:
        with dolfinx.io.XDMFFile(mesh.comm, str(Path(folder) / FILE), "w") as f:
            f.write_mesh(mesh)
            f.write_meshtags(sm.cell_tags)
            f.write_meshtags(sm.facet_tags)
    finally:
        sm.cell_tags.name, sm.facet_tags.name = names


def load(comm: MPI.Comm, folder: Path) -> S.ShoulderMesh | None:
    """The scapula mesh of the run in ``folder`` (collective), or None if it has none."""
    path = Path(folder) / FILE
    if not comm.allreduce(path.is_file() and path.with_suffix(".h5").is_file(), op=MPI.LAND):
        return None
    with dolfinx.io.XDMFFile(comm, str(path), "r") as f:
        mesh = f.read_mesh(name="mesh")
        mesh.topology.create_connectivity(mesh.topology.dim - 1, mesh.topology.dim)
        cell_tags = f.read_meshtags(mesh, name=_CELLS)
        facet_tags = f.read_meshtags(mesh, name=_FACETS)
    return S.ShoulderMesh(mesh, cell_tags, facet_tags)
