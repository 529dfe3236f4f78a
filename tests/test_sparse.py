"""The rigid system's matrices: the FE tangent assembled block-wise, the Jacobian's pattern
widened in one merge (issue 19's speed-ups), against plain PETSc and dolfinx."""

from __future__ import annotations

import dolfinx
import dolfinx.fem.petsc as fem_petsc
import numpy as np
import pytest
import ufl
from mpi4py import MPI
from petsc4py import PETSc

from shoulder_fem.engine.rigid_system.deformable import DeformablePart
from shoulder_fem.engine.rigid_system.layout import ReducedLayout
from shoulder_fem.engine.sparse import with_entries

COMM = MPI.COMM_WORLD


def _owned_csr(M: PETSc.Mat) -> dict:
    """{(row, col): value} of this rank's rows."""
    indptr, cols, vals = M.getValuesCSR()
    r0 = M.getOwnershipRange()[0]
    rows = r0 + np.repeat(np.arange(len(indptr) - 1), np.diff(indptr))
    return dict(zip(zip(rows.tolist(), cols.tolist(), strict=True), vals.tolist(), strict=True))


@pytest.mark.mpi
def test_with_entries_widens_the_pattern_exactly():
    """A 40 x 40 matrix with 3 entries per row, one a stored zero; a 3 x 4 block added on rank
    0's rows: 120 + 12 - 2 (two of the block's entries were already there) = 130 nonzeros
    (counted by hand), every old value and the stored zero kept, the block's entries new
    zeros that take values without a new allocation."""
    n = 40
    C = PETSc.Mat().createAIJ(((None, n), (None, n)), nnz=(3, 3), comm=COMM)
    r0, r1 = C.getOwnershipRange()
    for i in range(r0, r1):
        C.setValue(i, i, 2.0 + i)
        C.setValue(i, (i + 1) % n, 0.0)
        C.setValue(i, (i + 5) % n, -1.0)
    C.assemble()
    rows = np.array([37, 38, 39]) if r0 <= 37 < r1 else np.zeros(0, dtype=int)
    cols = np.array([0, 10, 20, 37])
    J = with_entries(C, rows, cols)
    info = PETSc.Mat.InfoType.GLOBAL_SUM
    assert C.getInfo(info)["nz_used"] == 120
    assert J.getInfo(info)["nz_used"] == 130
    old, new = _owned_csr(C), _owned_csr(J)
    assert all(new[key] == value for key, value in old.items())  # the stored zeros too
    added = {(int(r), int(c)) for r in rows for c in cols} - set(old)
    assert COMM.allreduce(len(added), op=MPI.SUM) == 10
    assert all(new[key] == 0.0 for key in added)
    J.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, True)
    if len(rows):
        J.setValues(rows.astype(PETSc.IntType), cols.astype(PETSc.IntType), np.ones((3, 4)))
    J.assemble()  # no "new nonzero caused a malloc"


@pytest.mark.mpi
def test_block_wise_tangent_equals_dolfinx_aij_and_is_not_assembled_twice():
    """DeformablePart's tangent (BAIJ assembly, converted to AIJ) equals dolfinx's AIJ assembly
    of the same form entry for entry (to round-off under MPI: off-process sums), at two states;
    an unchanged state is not assembled again, a changed one is."""
    mesh = dolfinx.mesh.create_unit_cube(COMM, 3, 3, 3)
    V = dolfinx.fem.VectorFunctionSpace(mesh, ("CG", 2))
    u = dolfinx.fem.Function(V)
    w = ufl.TestFunction(V)
    F = ufl.Identity(3) + ufl.grad(u)
    E = 0.5 * (F.T * F - ufl.Identity(3))
    residual = ufl.derivative((ufl.tr(E) ** 2 + ufl.inner(E, E)) * ufl.dx, u, w)
    part = DeformablePart(u, residual, None, None, None, ReducedLayout(COMM, [], [], V))
    reference = fem_petsc.create_matrix(part.J_form)
    for scale in (0.1, 0.3):
        u.interpolate(lambda x, s=scale: np.vstack([s * x[0] ** 2, s * x[1] * x[2], 0 * x[0]]))
        before = part.tangent_assemblies
        part.assemble_tangent()
        part.assemble_tangent()  # the same state: nothing to do
        assert part.tangent_assemblies == before + 1
        reference.zeroEntries()
        fem_petsc.assemble_matrix(reference, part.J_form)
        reference.assemble()
        got, want = _owned_csr(part.K), _owned_csr(reference)
        assert got.keys() == want.keys()
        scale_k = COMM.allreduce(max(abs(v) for v in want.values()), op=MPI.MAX)
        diff = max(abs(got[k] - want[k]) for k in want)
        assert diff <= 1e-14 * scale_k, diff
    part.destroy()
    reference.destroy()
