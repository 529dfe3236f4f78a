"""Newton steps of a condensed P1 pressure by an LU of the uncondensed system (a PETSc PC).

With a P1 pressure condensed vertex by vertex (:class:`~shoulder_fem.engine.mean_dilatation.
MeanDilatation`), the reduced Jacobian is J = J₀ + Gᵀ D G: J₀ everything else (the soft
tissues' deviatoric tangent, the contact, the rigid bodies, the prescribed and controlled
rows), G = B P the pressure DOFs' rows of the volume ratios' gradient in the reduced unknowns
and D = diag(U''(θ_a)/|a|). Gᵀ D G couples every pair of nodes that share a pressure vertex's
cells: at ``medium`` it widens part 1's J from 1.6M to 7.8M nonzeros, and its LU has 24M
entries. The bordered matrix

    A = [[J₀, G_Tᵀ], [G_B, −D⁻¹]]

has J as its Schur complement (y = D G_B x from the second row), so A [x; y] = [b; 0] gives
J x = b exactly; A has 2.0M nonzeros and an LU of 7.6M entries, factorized 4-5 times faster
(measured on part 1's 30th Jacobian at ``medium``, 0.19-0.27 s against 1.0-1.2 s). G_B is G
with the prescribed DOFs' columns zeroed, G_T also with the controlled rows' (J's rows and
columns that :func:`~.problem.finish_jacobian` replaces). A pressure DOF outside the soft
tissue (d = 0, an empty row of G) gets -1 on the diagonal.

J itself is never assembled: the problem's matrix is J₀ (its Jacobian leaves the volumetric
product out), and the SNES's operator is :class:`UncondensedOperator`, which applies
J = J₀ + G_Tᵀ D G_B to a vector (for line searches, tests and monitors; ``preonly`` applies
only the PC). :class:`UncondensedLU` keeps the blocks and A; :class:`UncondensedPC` is the
SNES's preconditioner (a ``python`` PC): with ``preonly`` it is the Newton step, as the LU of
J was.
"""

from __future__ import annotations

import numpy as np
from petsc4py import PETSc

from shoulder_fem.engine.petsc_lib import nonzero_key
from shoulder_fem.engine.solver import direct_solver_options, release_options, set_from_options

__all__ = ["REFINEMENT", "UncondensedLU", "UncondensedOperator", "UncondensedPC", "operator"]

#: Two steps of MUMPS's iterative refinement on every solve with A (ICNTL(10) < 0: that many,
#: without a test). Without them a step left ‖J x - b‖ up to 2e-11 ‖b‖ (against about 1e-13
#: by the LU of J), enough to change the Newton paths: part 1 at ``coarse``, 0-60 deg, took
#: 429 Newton iterations (a second ``l2`` retry) against the condensed LU's 409; with them
#: the same 409, each step and retry as the LU of J's, the outputs within 1e-9.
REFINEMENT = {"mat_mumps_icntl_10": -2}


def operator(problem) -> PETSc.Mat:
    """A :class:`~.problem.ReducedProblem`'s SNES operator: its J, or J₀ + G_Tᵀ D G_B applied."""
    return problem.J if problem.uncondensed is None else problem.uncondensed.operator


class UncondensedLU:
    """J₀, the bordered matrix A of a :class:`~.problem.ReducedProblem` and A's LU (collective).

    Args:
        problem: The reduced problem (its FE part has a P1 MeanDilatation).
        prefix: The SNES's options prefix; A's LU takes ``<prefix>uncondensed_``.
    """

    def __init__(self, problem, prefix: str) -> None:
        self.problem = problem
        self.comm = problem.comm
        self._G: dict[str, PETSc.Mat] = {}
        self._D: PETSc.Mat | None = None  # A's block, -D⁻¹
        self._d: PETSc.Vec | None = None  # D's diagonal, the operator's
        self._nest: PETSc.Mat | None = None
        self.A: PETSc.Mat | None = None
        self._A_key = None  # J₀'s (id, nonzero state) when A was made
        self._factored = None  # J₀'s (handle, object state) after the last factorization
        self._vecs: tuple[PETSc.Vec, PETSc.Vec] | None = None
        self.ksp = PETSc.KSP().create(self.comm)
        self.ksp_prefix = f"{prefix}uncondensed_"
        self.ksp.setOptionsPrefix(self.ksp_prefix)
        set_from_options(self.ksp, direct_solver_options() | REFINEMENT)
        #: J as the SNES's operator (a ``python`` Mat of J₀'s sizes).
        self.operator = PETSc.Mat().createPython(
            problem.J.getSizes(), UncondensedOperator(self), comm=self.comm
        )
        self.operator.setUp()

    @property
    def J0(self) -> PETSc.Mat:
        """J₀: the problem's Jacobian matrix, without the condensed pressure's product."""
        return self.problem.J

    # ---- the blocks, at each Jacobian ----------------------------------------------------------
    def refresh(self) -> None:
        """G_T, G_B and D at the state of the Jacobian just formed (collective).

        Called by the Jacobian once J₀ is complete (its prolongation filled at this state).
        """
        self._blocks()

    def _blocks(self) -> None:
        p = self.problem
        vol = p.fe.volumetric
        G = vol.reduced_product(p.P)  # B P at this state
        prescribed = p.dirichlet_rows()
        controlled = p.layout.rigid_cols(p.control.body)[:3] if p.control is not None else []
        mask_b, mask_t = G.createVecRight(), G.createVecRight()
        for mask, rows in ((mask_b, prescribed), (mask_t, np.union1d(prescribed, controlled))):
            mask.set(1.0)
            rows = np.asarray(rows, dtype=PETSc.IntType)
            mask.setValues(rows, np.zeros(len(rows)), addv=PETSc.InsertMode.INSERT_VALUES)
            mask.assemble()
        for name, mask in (("B", mask_b), ("T", mask_t)):
            if name not in self._G:
                self._G[name] = G.duplicate(copy=True)
            else:
                G.copy(self._G[name], structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
            self._G[name].diagonalScale(R=mask)
            mask.destroy()
        if "Tt" not in self._G:
            self._G["Tt"] = self._G["T"].transpose(PETSc.Mat())  # no argument: in place
        else:
            self._G["T"].transpose(self._G["Tt"])
        diagonal = vol.stiffness_diagonal()
        if self._d is None:
            self._d = G.createVecLeft()
        self._d.array[:] = diagonal
        d = G.createVecLeft()
        # d < 0 (θ > e) is still exact: only d = 0 (no tissue, an empty row of G) has no inverse
        held = diagonal != 0
        d.array[:] = -1.0
        d.array[held] = -1.0 / diagonal[held]
        if self._D is None:
            self._D = PETSc.Mat().createAIJ(
                (G.getSizes()[0], G.getSizes()[0]), nnz=(1, 0), comm=self.comm
            )
            self._D.setDiagonal(d)
            self._D.assemble()
        else:
            self._D.setDiagonal(d)
        d.destroy()

    def apply_condensed(self, x: PETSc.Vec, y: PETSc.Vec, transpose: bool = False) -> None:
        """J x = J₀ x + G_Tᵀ D G_B x (or Jᵀ x) into ``y`` at the last :meth:`refresh`."""
        G = self._G
        first, second = (G["T"], G["B"]) if transpose else (G["B"], G["T"])
        g = self._d.duplicate()
        first.mult(x, g)
        g.pointwiseMult(g, self._d)
        if transpose:
            self.J0.multTranspose(x, y)
        else:
            self.J0.mult(x, y)
        second.multTransposeAdd(g, y, y)
        g.destroy()

    # ---- A and its LU -------------------------------------------------------------------------
    def factorize(self) -> None:
        """A at the last :meth:`refresh`, and its LU (a new analysis when J₀'s pattern grew)."""
        key = nonzero_key(self.J0)
        if self.A is None or key is None or key != self._A_key:
            self._new_bordered()
            self._A_key = key
        else:
            self._nest.convert(PETSc.Mat.Type.AIJ, self.A)
        self.ksp.setOperators(self.A, self.A)
        self.ksp.setUp()
        # reading J₀ into A raises J₀'s object state, so PETSc would set the PC up again for
        # the same J₀: measured, every Newton step factorized A twice
        self._factored = (self.J0.handle, self.J0.stateGet())

    def current(self) -> bool:
        """Whether A's LU is of J₀ as it is now (nothing changed J₀ since :meth:`factorize`)."""
        return self._factored == (self.J0.handle, self.J0.stateGet())

    def _new_bordered(self) -> None:
        for obj in (self._nest, self.A, *(self._vecs or ())):
            if obj is not None:
                obj.destroy()
        G = self._G
        self._nest = PETSc.Mat().createNest([[self.J0, G["Tt"]], [G["B"], self._D]], comm=self.comm)
        self.A = self._nest.convert(PETSc.Mat.Type.AIJ, PETSc.Mat())
        self._vecs = self.A.createVecs()
        self.ksp.reset()  # a new pattern: analysed afresh

    def solve(self, b: PETSc.Vec, x: PETSc.Vec) -> None:
        """X = J⁻¹ b through A's LU: A [x; y] = [b; 0] (each rank: its rows of J, then of G)."""
        xa, ba = self._vecs
        n = b.getLocalSize()
        arr = ba.getArray()
        arr[:n] = b.getArray(readonly=True)
        arr[n:] = 0.0
        self.ksp.solve(ba, xa)
        x.getArray()[:] = xa.getArray(readonly=True)[:n]

    def forget(self) -> None:
        """Drop the factorization (the next one is analysed afresh)."""
        self.ksp.reset()
        self._A_key = self._factored = None

    def destroy(self) -> None:
        """Free the PETSc objects (J₀ is the problem's)."""
        for obj in (self._D, self._d, self._nest, self.A, self.operator, *(self._vecs or ())):
            if obj is not None:
                obj.destroy()
        for mat in self._G.values():
            mat.destroy()
        self._G.clear()
        self.ksp.destroy()
        release_options(self.ksp_prefix)


class UncondensedOperator:
    """The context of a ``python`` Mat that applies J = J₀ + G_Tᵀ D G_B (the SNES's operator)."""

    def __init__(self, lu: UncondensedLU) -> None:
        self.lu = lu

    def mult(self, mat, x: PETSc.Vec, y: PETSc.Vec) -> None:
        """J x into ``y``."""
        self.lu.apply_condensed(x, y)

    def multTranspose(self, mat, x: PETSc.Vec, y: PETSc.Vec) -> None:  # noqa: N802 (petsc4py)
        """Jᵀ x into ``y``."""
        self.lu.apply_condensed(x, y, transpose=True)


class UncondensedPC:
    """The context of a ``python`` PC whose set-up factorizes A and whose apply solves with it."""

    def __init__(self, lu: UncondensedLU) -> None:
        self.lu = lu

    def setUp(self, pc) -> None:  # noqa: N802 (petsc4py's name)
        """Factorize A (PETSc calls it when J₀ changed, and once more after A read it)."""
        if not self.lu.current():
            self.lu.factorize()

    def apply(self, pc, x: PETSc.Vec, y: PETSc.Vec) -> None:
        """Solve J y = x."""
        self.lu.solve(x, y)

    def reset(self, pc) -> None:
        """Drop the factorization."""
        self.lu.forget()
