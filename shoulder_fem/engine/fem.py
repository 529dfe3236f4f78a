"""Small dolfinx helpers shared by the engine and the scene families."""

from __future__ import annotations

import dolfinx
import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

__all__ = ["constant", "owned_flags"]


def constant(mesh: dolfinx.mesh.Mesh, value) -> dolfinx.fem.Constant:
    """A float64 ``Constant`` (scalar, vector or matrix) on ``mesh``."""
    return dolfinx.fem.Constant(mesh, PETSc.ScalarType(np.asarray(value, dtype=float)))


def owned_flags(imap, local_nodes: np.ndarray, comm: MPI.Comm) -> np.ndarray:
    """Flags (owned + ghost nodes) of ``local_nodes`` marked on any rank (collective)."""
    vec = dolfinx.la.create_petsc_vector(imap, 1)
    with vec.localForm() as loc:
        loc.set(0.0)
        loc.array[local_nodes] = 1.0
    vec.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    vec.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
    with vec.localForm() as loc:
        flags = loc.array > 0.5
    vec.destroy()
    return flags
