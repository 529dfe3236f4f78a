"""Exact block elimination of a bordered linear system: a sparse FE block and a few dense rows.

The floating-frame solver and the decoupled tumbling body add a handful of dense rows and
columns (frame directions, mean-axes conditions) to a distributed FE matrix. The FE block is
factorized with MUMPS, one multi-right-hand-side solve gives the eliminated columns, and the small
Schur complement is solved with numpy on every rank: exact to round-off, while the FE block keeps
dolfinx's sparsity and parallel layout and the dense rows never enter a sparse matrix (no
preallocation or ownership of extra rows to manage in dolfinx 0.5.2).
"""

from __future__ import annotations

import dolfinx
import dolfinx.fem.petsc as fem_petsc
import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from shoulder_fem.engine.solver import (
    ConvergenceError,
    direct_solver_options,
    set_from_options,
    unique_prefix,
)

__all__ = ["BorderedSolver", "assemble_owned"]


def assemble_owned(form: dolfinx.fem.Form, vec: PETSc.Vec | None = None) -> np.ndarray:
    """Assemble a compiled 1-form and return its owned entries (a copy), ghosts summed in.

    Args:
        form: the compiled linear form.
        vec: a work vector of the form's layout, zeroed here; None: a new one, freed after.
    """
    if vec is None:
        vec = fem_petsc.create_vector(form)
        owned = True
    else:
        owned = False
        with vec.localForm() as local:
            local.set(0.0)
    fem_petsc.assemble_vector(vec, form)
    vec.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    values = vec.array.copy()
    if owned:
        vec.destroy()
    return values


class BorderedSolver:
    """Solve a bordered system ``[A U; Vᵀ Z]`` by exact block elimination (collective).

    A is a distributed PETSc matrix (factorized with MUMPS LU at the first solve after
    :meth:`set_operator`); U and V are a few dense columns and rows given as owned-entry arrays;
    Z is a small dense matrix known on every rank. The Schur complement Z − Vᵀ A⁻¹ U is
    reduced over ranks and solved with numpy, identically on every rank.

    Args:
        comm: the communicator.
        A: the matrix (its layout is reused for the work vectors).
        name: options-prefix stem.
    """

    def __init__(self, comm: MPI.Comm, A: PETSc.Mat, name: str = "bordered"):
        self.comm = comm
        self.ksp = PETSc.KSP().create(comm)
        self.prefix = unique_prefix(name)
        self.ksp.setOptionsPrefix(self.prefix)
        self.ksp.setOperators(A)
        set_from_options(self.ksp, direct_solver_options())
        self._b, self._y = A.createVecs()
        self.factorizations = 0
        self.back_substitutions = 0

    def set_operator(self, A: PETSc.Mat) -> None:
        """Use (and factorize at the next solve) the current values of ``A``."""
        self.ksp.setOperators(A)
        self.factorizations += 1

    def _solve(self, rhs: list[np.ndarray]) -> list[np.ndarray]:
        """A⁻¹ applied to several right-hand sides at once (one multi-RHS MUMPS solve)."""
        n_local = self._b.getLocalSize()
        n_global = self._b.getSize()
        sizes = ((n_local, n_global), (None, len(rhs)))
        B = PETSc.Mat().createDense(sizes, comm=self.comm)
        B.setUp()
        B.getDenseArray()[:, :] = np.column_stack(rhs)
        B.assemble()
        X = B.duplicate()
        pc = self.ksp.getPC()
        try:
            self.ksp.setUp()  # factorizes A if it changed (MUMPS LU)
            pc.getFactorMatrix().matSolve(B, X)
        except PETSc.Error as err:
            B.destroy()
            X.destroy()
            raise ConvergenceError(
                "linear solve", f"LU factorization or solve failed ({err})", 0, self.prefix
            ) from err
        self.back_substitutions += len(rhs)
        out = X.getDenseArray().copy()
        B.destroy()
        X.destroy()
        return [out[:, j].copy() for j in range(len(rhs))]

    def solve(
        self,
        r1: np.ndarray,
        cols: list[np.ndarray],
        rows: list[np.ndarray],
        Z: np.ndarray,
        r2: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Solve ``A y + U q = −r1``, ``Vᵀ y + Z q = −r2``; return (y owned entries, q).

        Args:
            r1: residual of the FE rows, owned entries.
            cols: the border columns U, owned entries each.
            rows: the border rows V, owned entries each (as many as columns).
            Z: the (k, k) corner block, the same on every rank.
            r2: residual of the border rows, shape (k,).
        """
        y0, *Y = self._solve([-r1, *cols])
        k = len(cols)
        local = np.array([[rows[i] @ Y[j] for j in range(k)] for i in range(k)])
        local_rhs = np.array([rows[i] @ y0 for i in range(k)])
        both = self.comm.allreduce(np.column_stack([local, local_rhs]), op=MPI.SUM)
        vy, vy0 = both[:, :k], both[:, k]
        q = np.linalg.solve(Z - vy, -r2 - vy0)
        y = y0 - sum((q[j] * Y[j] for j in range(k)), np.zeros_like(y0))
        return y, q

    def destroy(self) -> None:
        """Free the PETSc objects."""
        for obj in (self.ksp, self._b, self._y):
            obj.destroy()
