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


def _random_aij(pattern: np.ndarray, values: np.ndarray) -> PETSc.Mat:
    """An assembled AIJ matrix on COMM with ``values`` at ``pattern``'s True entries."""
    n = pattern.shape[0]
    M = PETSc.Mat().createAIJ([n, n], nnz=(n, n), comm=COMM)
    r0, r1 = M.getOwnershipRange()
    for i in range(r0, r1):
        cols = np.nonzero(pattern[i])[0].astype(PETSc.IntType)
        M.setValues([i], cols, values[i, cols])
    M.assemble()
    return M


@pytest.mark.mpi
def test_subset_add_gives_mataxpy_to_the_last_bit():
    """``SubsetAdd`` (C's entries added by a compiled walk along the rows of J's and C's own
    arrays) against PETSc's own ``MatAXPY(SUBSET_NONZERO_PATTERN)``: a 200 x 200 J with about 5 % of
    its entries stored and a C with half of them, serial and on 2 ranks (the off-diagonal
    block's entries too). Three sums, then J widened (a new entry: its pattern, so its
    pattern is checked again) and three more: every value equal to the last bit, the patterns
    checked twice, not at every sum. Serial, a C with an entry J has not is refused as
    ``MatAXPY`` refuses it."""
    from shoulder_fem.engine.subset_add import SubsetAdd

    n = 200
    rng = np.random.default_rng(7)  # the same on every rank
    pj = (rng.random((n, n)) < 0.05) | np.eye(n, dtype=bool)
    pc = pj & (rng.random((n, n)) < 0.5)
    vj, vc = rng.standard_normal((n, n)), rng.standard_normal((n, n))
    mine, theirs, C = _random_aij(pj, vj), _random_aij(pj, vj), _random_aij(pc, vc)
    add = SubsetAdd()
    subset = PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN
    for widen in (False, True):
        if widen:  # one entry more (0, n - 1) in both, by PETSc's merge of the two patterns
            extra = np.zeros((n, n), dtype=bool)
            extra[0, n - 1] = True
            assert not pj[0, n - 1]
            E = _random_aij(extra, vc)
            for J in (mine, theirs):
                J.axpy(1.0, E, structure=PETSc.Mat.Structure.DIFFERENT_NONZERO_PATTERN)
        for _ in range(3):
            add(mine, C)
            theirs.axpy(1.0, C, structure=subset)
        a, b = mine.getValuesCSR(), theirs.getValuesCSR()
        assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
        assert np.array_equal(a[2], b[2])  # bitwise: the same one addition per entry
        assert len(a[2]) > 0 or COMM.size > 1
    assert (add.walked, add.checks, add.fallbacks) == (6, 2, 0)
    assert mine.getType() == ("mpiaij" if COMM.size > 1 else "seqaij")
    if COMM.size > 1:
        return  # MatAXPY's refusal is raised on the rank of the entry alone: serial only
    outside = pc.copy()
    outside[n - 1, 0] = True
    assert not pj[n - 1, 0]
    D = _random_aij(outside, vc)
    mine.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, True)
    with pytest.raises(PETSc.Error):
        add(mine, D)
    assert add.fallbacks == 1


def test_the_shoulder_with_subset_add_repeats_mataxpy_to_the_last_bit(comm_tmp, monkeypatch):
    """Part 1 of the shoulder (coarse, 0-4 deg: contact, P1 pressures, the Jacobian's pattern
    widened on the way) with the Jacobian's sums through :class:`SubsetAdd` and again through
    PETSc's ``MatAXPY``: every series and counter the same to the last bit, and the patterns
    checked for a few of the sums only. Serial only: on 2 ranks two identical runs with
    ``MatAXPY`` in one process already differ (85 against 86 Newton iterations, the
    penalty's energy share by 9e-4 relative at 0-4 deg; measured), as much as the two ways
    do; the 2-rank layout of the sums is the test above's."""
    from shoulder_fem import api
    from shoulder_fem.engine import subset_add
    from shoulder_fem.scene import load_scene

    scene = load_scene("shoulder-internal-rotation").with_overrides(
        ["final_angle=4deg", "angle_step=2deg", "output_angle=2deg"]
    )
    counts = {}  # each SubsetAdd's counters after its last sum
    real = subset_add.SubsetAdd.__call__

    def counted(self, J, C):
        real(self, J, C)
        counts[id(self)] = (self.walked, self.checks, self.fallbacks)

    monkeypatch.setattr(subset_add.SubsetAdd, "__call__", counted)
    walked = api.run(scene, "decoupled", "coarse", comm_tmp / "walked")

    def mataxpy(self, J, C):
        J.axpy(1.0, C, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)

    monkeypatch.setattr(subset_add.SubsetAdd, "__call__", mataxpy)
    plain = api.run(scene, "decoupled", "coarse", comm_tmp / "plain")
    assert walked.status == plain.status == "ok"
    for name, series in plain.data["series"].items():
        assert walked.data["series"][name]["y"] == series["y"], name
    timings = {k for k in plain.probes if k.endswith("_s")}
    assert {k: v for k, v in walked.probes.items() if k not in timings} == {
        k: v for k, v in plain.probes.items() if k not in timings
    }
    sums, checks, fallbacks = np.sum(list(counts.values()), axis=0)
    assert sums > 50 and checks < sums / 4 and fallbacks == 0, counts
