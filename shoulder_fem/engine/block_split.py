"""A stiff field, a soft field and a small border: a block preconditioner (a PETSc python PC).

For a Newton system that holds bones and soft tissue in one matrix (the coupled shoulder), LU of
the whole is what a run costs (71-77 % of the coupled run at ``paper``). :class:`StiffSoftSplit`
splits the unknowns into

* field ``a``, the stiff one (the bones' free nodes and the plates tied to them): by default
  CG to a relative 1e-3 preconditioned by :class:`~shoulder_fem.engine.gamg.ScaledGAMG` on the
  field's block, with the matrix's near-nullspace restricted to the field;
* field ``b``, the soft one (the soft tissues' free nodes): by default MUMPS LU of its block;
* a border ``k`` of a few unknowns that neither field can hold, e.g. a travel control whose
  equation depends on the bones only (its row is zero in both fields' blocks).

The main unknowns m = a + b get one block Gauss-Seidel sweep M, by default the soft field
first: z_b = K_b⁻¹ r_b, z_a = K_a⁻¹ (r_a - A_ab z_b) (``split_order`` ``ba``; ``ab`` and
the symmetric ``aba`` too). The border is eliminated exactly about M: with W = M A_mk (k
columns, at set-up) and S = A_kk - A_km W (k x k, dense, on every rank),

    y = M r_m,   z_k = S⁻¹ (r_k - A_km y),   z_m = y - W z_k,

the exact inverse of [[M⁻¹, A_mk], [A_km, A_kk]]: a Krylov method outside (FGMRES, since the
stiff field's CG makes M vary) converges as on the main block preconditioned by M. The sweep
must carry the border's columns to its rows: the shoulder's actuator pulls on a muscle (soft)
and its control reads the humerus (stiff), so the soft field goes first (stiff first, S is
singular, and set-up says so). The nodes shared by a bone's and a soft tissue's cells belong
to field ``a``, whose block rows then carry the soft cells' stiffness too: that holds a bone
which only soft tissue holds (the humerus in the joint) in the stiff field's block.

The sub-solvers' options have the PC's options prefix + ``split_a_`` and ``split_b_``.
"""

from __future__ import annotations

import dolfinx
import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from shoulder_fem.engine.gamg import GAMG_DEFAULTS
from shoulder_fem.engine.gamg import PYTHON_TYPE as SCALED_GAMG

__all__ = ["PYTHON_TYPE", "StiffSoftSplit", "split_options"]

#: The ``pc_python_type`` that selects :class:`StiffSoftSplit`.
PYTHON_TYPE = "shoulder_fem.engine.block_split.StiffSoftSplit"


def split_options(rtol: float = 1e-9, max_it: int = 300) -> dict:
    """FGMRES with :class:`StiffSoftSplit`: CG + ScaledGAMG (to 1e-3) and LU in the fields.

    The stiff field's CG runs to a relative 1e-3, the soft field is factorized (MUMPS LU).
    Measured on the coupled shoulder's first Jacobian (a random right-hand side, to 1e-8):
    FGMRES 45 / 52 iterations at coarse / medium (48 / 56 / 55 at coarse / medium / paper with
    the stiff field first); with a single V-cycle for the stiff field (a fixed preconditioner,
    GMRES, stiff field first) 270 / 326 / 243. In whole runs (benchmarks/coupled_solvers.py)
    42.7 / 47.7 / 45.7 a solve. Modified Gram-Schmidt: with
    the classical one the Arnoldi basis lost its orthogonality and the true residual
    stalled at 2e-2 while GMRES's estimate went on falling. Give the split its fields with
    :meth:`StiffSoftSplit.set_fields` before the first solve.
    """
    gamg = {f"split_a_{k}": v for k, v in GAMG_DEFAULTS.items()}
    return {
        "ksp_type": "fgmres",
        "ksp_gmres_restart": max_it,
        "ksp_gmres_modifiedgramschmidt": "",
        "ksp_rtol": rtol,
        "ksp_atol": 0.0,
        "ksp_max_it": max_it,
        "pc_type": "python",
        "pc_python_type": PYTHON_TYPE,
        "split_a_ksp_type": "cg",
        "split_a_ksp_rtol": 1e-3,
        "split_a_ksp_max_it": 200,
        "split_a_pc_type": "python",
        "split_a_pc_python_type": SCALED_GAMG,
        **gamg,
        "split_b_ksp_type": "preonly",
        "split_b_pc_type": "lu",
        "split_b_pc_factor_mat_solver_type": "mumps",
    }


#: The sweeps ``split_order`` may name: soft then stiff (the default), stiff then soft, and the
#: symmetric stiff-soft-stiff.
ORDERS = ("ba", "ab", "aba")


def _index_set(indices: np.ndarray, comm: MPI.Comm) -> PETSc.IS:
    return PETSc.IS().createGeneral(np.asarray(indices, dtype=PETSc.IntType), comm=comm)


class StiffSoftSplit:
    """The block preconditioner of the module's docstring (collective methods)."""

    def __init__(self) -> None:
        #: The fields' index sets (a, b, m = a + b, k) and their owned rows' positions.
        self.fields: tuple[PETSc.IS, ...] | None = None
        self.ksp: dict[str, PETSc.KSP] = {}
        self._blocks: dict[str, PETSc.Mat] = {}
        self._work: dict[str, PETSc.Vec] = {}
        self.W: np.ndarray | None = None  # (k, owned rows of m): M A_mk's columns
        self.S: np.ndarray | None = None  # the border's Schur complement, on every rank
        #: The fields' order in the Gauss-Seidel sweep (option ``split_order``).
        self.order = "ba"

    def set_fields(self, stiff: np.ndarray, soft: np.ndarray, border: np.ndarray, A: PETSc.Mat):
        """The fields as this rank's owned global rows of ``A`` (the Jacobian's layout).

        Raises:
            ValueError: A row in no field or in two.
        """
        comm = A.getComm().tompi4py()
        lo, hi = A.getOwnershipRange()
        rows = [np.sort(np.asarray(i, dtype=np.int64)) for i in (stiff, soft, border)]
        every = np.concatenate(rows)
        if len(every) != hi - lo or not np.array_equal(np.sort(every), np.arange(lo, hi)):
            raise ValueError(
                f"StiffSoftSplit: the fields must hold every owned row once (rows {lo}-{hi}, "
                f"fields of {[len(r) for r in rows]})"
            )
        self._free_fields()
        main = np.sort(np.concatenate(rows[:2]))
        self.fields = tuple(_index_set(r, comm) for r in (*rows[:2], main, rows[2]))
        self._at = {  # positions in the owned part of A's vectors, and of a and b within m
            "a": rows[0] - lo,
            "b": rows[1] - lo,
            "m": main - lo,
            "k": rows[2] - lo,
            "a_in_m": np.searchsorted(main, rows[0]),
            "b_in_m": np.searchsorted(main, rows[1]),
        }
        self._k = comm.allreduce(len(rows[2]), op=MPI.SUM)
        self._k0 = comm.exscan(len(rows[2])) or 0

    def _sub_ksp(self, pc: PETSc.PC, name: str) -> PETSc.KSP:
        if name not in self.ksp:
            ksp = PETSc.KSP().create(pc.getComm())
            ksp.setOptionsPrefix((pc.getOptionsPrefix() or "") + f"split_{name}_")
            ksp.setType("preonly")
            self.ksp[name] = ksp
        return self.ksp[name]

    def setFromOptions(self, pc: PETSc.PC) -> None:  # noqa: N802 (petsc4py's hook name)
        """Read ``split_order``; let the sub-solvers read theirs (``split_a_``, ``split_b_``)."""
        order = PETSc.Options(pc.getOptionsPrefix() or "").getString("split_order", self.order)
        if order not in ORDERS:
            raise ValueError(f"StiffSoftSplit: split_order '{order}' is not one of {ORDERS}")
        self.order = order
        for name in ("a", "b"):
            self._sub_ksp(pc, name).setFromOptions()

    def setUp(self, pc: PETSc.PC) -> None:  # noqa: N802
        """Extract the blocks, set the sub-solvers up, eliminate the border about M."""
        if self.fields is None:
            raise RuntimeError("StiffSoftSplit: set_fields() was not called before the solve")
        _, A = pc.getOperators()
        a, b, m, k = self.fields
        self._free_blocks()
        blocks = self._blocks
        blocks["aa"] = A_aa = A.createSubMatrix(a, a)
        near = A.getNearNullSpace()
        if near.handle and near.getVecs():
            vecs = [v.getSubVector(a) for v in near.getVecs()]
            restricted = [v.copy() for v in vecs]
            for v, sub in zip(near.getVecs(), vecs, strict=True):
                v.restoreSubVector(a, sub)
            dolfinx.la.orthonormalize(restricted)
            A_aa.setNearNullSpace(PETSc.NullSpace().create(vectors=restricted, comm=A.comm))
        blocks["bb"] = A.createSubMatrix(b, b)
        blocks["ba"] = A.createSubMatrix(b, a)
        blocks["ab"] = A.createSubMatrix(a, b)
        for name in ("a", "b"):
            block = blocks[name + name]
            ksp = self._sub_ksp(pc, name)
            ksp.setOperators(block)
            ksp.setUp()
            self._work["r" + name], self._work["z" + name] = block.createVecs()
            self._work["t" + name] = block.createVecs()[0]
        self.S = self.W = None
        if self._k:
            self._eliminate_border(A, m, k)

    def _eliminate_border(self, A: PETSc.Mat, m: PETSc.IS, k: PETSc.IS) -> None:
        """W = M A_mk and S = A_kk - A_km W (S on every rank)."""
        comm = A.getComm().tompi4py()
        A_mk = self._blocks["mk"] = A.createSubMatrix(m, k)
        A_km = self._blocks["km"] = A.createSubMatrix(k, m)
        self._work["zm"], self._work["out"] = A_km.createVecs()  # (m, k)
        column = A_mk.createVecs()[1]
        self.W = np.zeros((self._k, len(self._at["m"])))
        S = np.zeros((self._k, self._k))
        zm, out = self._work["zm"], self._work["out"]
        for j in range(self._k):
            A_mk.getColumnVector(j, column)
            self.W[j] = self._main(column.array_r)
            zm.array[:] = self.W[j]
            A_km.mult(zm, out)
            S[:, j] = -self._gather(out.array_r, comm)
        column.destroy()
        A_kk = A.createSubMatrix(k, k)
        lo, hi = A_kk.getOwnershipRange()
        kk = np.zeros((self._k, self._k))
        if hi > lo:
            kk[lo:hi] = A_kk.getValues(range(lo, hi), range(self._k))
        A_kk.destroy()
        S += comm.allreduce(kk, op=MPI.SUM)
        if not np.isfinite(S).all() or np.linalg.cond(S) > 1e14:
            raise ValueError(
                f"StiffSoftSplit: the border's Schur complement is singular (condition number "
                f"{np.linalg.cond(S):.3g}): a border row that the sweep '{self.order}' does not "
                "reach (e.g. a control that reads the stiff field driven from the soft one needs "
                "the soft field first: split_order ba)"
            )
        self.S = S

    def _gather(self, owned: np.ndarray, comm: MPI.Comm) -> np.ndarray:
        """A border vector's entries on every rank from each rank's owned ones."""
        full = np.zeros(self._k)
        full[self._k0 : self._k0 + len(owned)] = owned
        return comm.allreduce(full, op=MPI.SUM)

    # ---- application ------------------------------------------------------------------------
    def _main(self, r_m: np.ndarray) -> np.ndarray:
        """M r on the main unknowns (owned entries of the m layout in, a new array out)."""
        at, work, blocks = self._at, self._work, self._blocks
        z = np.zeros_like(r_m)
        solved = set()
        for field in self.order:
            other = "b" if field == "a" else "a"
            rhs = work["r" + field]
            rhs.array[:] = r_m[at[f"{field}_in_m"]]
            if other in solved:  # less the coupling to the other field's last solution,
                coupling = blocks[field + other]  # still in work["z" + other]
                coupling.mult(work["z" + other], work["t" + field])
                rhs.axpy(-1.0, work["t" + field])
            self.ksp[field].solve(rhs, work["z" + field])
            z[at[f"{field}_in_m"]] = work["z" + field].array_r
            solved.add(field)
        return z

    def apply(self, pc: PETSc.PC, x: PETSc.Vec, y: PETSc.Vec) -> None:
        """Apply the preconditioner: ``y = P⁻¹ x``."""
        at = self._at
        r = x.array_r
        z_m = self._main(r[at["m"]])
        out = y.array
        if self._k:
            comm = x.getComm().tompi4py()
            zm, res = self._work["zm"], self._work["out"]
            zm.array[:] = z_m
            self._blocks["km"].mult(zm, res)
            r_k = self._gather(r[at["k"]] - res.array_r, comm)
            z_k = np.linalg.solve(self.S, r_k)
            z_m -= z_k @ self.W
            out[at["k"]] = z_k[self._k0 : self._k0 + len(at["k"])]
        out[at["m"]] = z_m

    def view(self, pc: PETSc.PC, viewer: PETSc.Viewer) -> None:
        """What ``-ksp_view`` prints: the fields' sizes and the sub-solvers."""
        sizes = [s.getSize() for s in self.fields] if self.fields else []
        viewer.printfASCII(f"  StiffSoftSplit: fields a, b, m, border of {sizes} rows\n")
        for ksp in self.ksp.values():
            ksp.view(viewer)

    # ---- clean-up ---------------------------------------------------------------------------
    def _free_blocks(self) -> None:
        for obj in (*self._blocks.values(), *self._work.values()):
            obj.destroy()
        self._blocks, self._work = {}, {}

    def _free_fields(self) -> None:
        for s in self.fields or ():
            s.destroy()
        self.fields = None

    def reset(self, pc: PETSc.PC) -> None:
        """Free the blocks (the fields stay): PCReset, e.g. after J's pattern changed."""
        self._free_blocks()
        for ksp in self.ksp.values():
            ksp.reset()

    def destroy(self, pc: PETSc.PC) -> None:
        """Free everything."""
        self._free_blocks()
        self._free_fields()
        for ksp in self.ksp.values():
            ksp.destroy()
        self.ksp = {}
