"""Small dolfinx helpers shared by the engine and the scene families."""

from __future__ import annotations

import dolfinx
import dolfinx.jit
import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

__all__ = ["JIT_PARAMS", "JIT_TIMEOUT", "constant", "identity_rows", "owned_flags"]

#: C compiler flags of the hot forms' kernels (``jit_params`` of ``dolfinx.fem.form``).
#: ``-fno-math-errno`` lets the compiler inline and vectorise ``sqrt``, ``exp`` and ``log``
#: (they no longer set ``errno``; their IEEE results, NaN and inf included, are unchanged):
#: measured on the shoulder's soft-tissue tangent at ``paper``, 0.18 -> 0.126 s per matrix
#: and 0.011 -> 0.005 s per residual, with the same assembled values as dolfinx's default
#: ``-O2 -g0``. ``-march=native`` (0.096 s) is left out: it changes round-off (contraction
#: into FMA) and a form cache shared by the nodes of a cluster must run on all of them.
JIT_PARAMS = {"cffi_extra_compile_args": ["-O2", "-g0", "-fno-math-errno"]}

#: How long (s) a process waits for another process's compilation of the same form in the
#: shared cache. dolfinx's default, 10 s, can be shorter than a soft-tissue tangent takes to
#: compile on a busy machine; a second process on the same empty cache (simultaneous runs of
#: a cluster's jobs) then stops with a TimeoutError (FFCx's ``get_cached_module`` polls once a
#: second; read from its source, not observed here). Set as dolfinx's default at import: a
#: ``timeout`` in the user's ``dolfinx_jit_parameters.json`` still wins.
JIT_TIMEOUT = 300
_doc = dolfinx.jit.DOLFINX_DEFAULT_JIT_PARAMETERS["timeout"][1]
dolfinx.jit.DOLFINX_DEFAULT_JIT_PARAMETERS["timeout"] = (JIT_TIMEOUT, _doc)


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


def identity_rows(A: PETSc.Mat, bcs: list, V: dolfinx.fem.FunctionSpace) -> None:
    """The rows of the Dirichlet DOFs of ``bcs`` in ``A`` made identity rows, columns kept.

    By global number (a matrix whose pattern PETSc widened has lost its local numbering); the
    pattern is kept for the next fills (collective).
    """
    rows = [bc.dof_indices()[0] for bc in bcs]
    if not rows:
        return
    imap, bs = V.dofmap.index_map, V.dofmap.index_map_bs
    local = np.unique(np.concatenate(rows))
    local = local[local < imap.size_local * bs]
    nodes = imap.local_to_global(local // bs)
    A.setOption(PETSc.Mat.Option.KEEP_NONZERO_PATTERN, True)
    A.zeroRows((nodes * bs + local % bs).astype(PETSc.IntType), 1.0)
