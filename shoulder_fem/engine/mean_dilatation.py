"""Nearly incompressible bodies without volumetric locking: the mean-dilatation (P2/P0) method.

The three-field (u, θ, p) formulation of Simo, Taylor and Pister (1985) with the volume ratio θ
and the pressure p constant in each cell (P2 displacement, P0 pressure), condensed cell by cell:
the volumetric energy U(θ) of a cell K is taken on its mean volume ratio

    θ_K = (1/|K|) ∫_K J dx,

so that a cell carries one volumetric constraint instead of one per quadrature point (a pure
P2 displacement with a large bulk modulus locks). The pair P2/P0 is inf-sup stable on
tetrahedra (its discrete inf-sup constant measured on refined meshes in
``tests/test_materials.py``). The isochoric energy is integrated as usual.

With p_K = U'(θ_K) and b_K(v) = ∫_K J F⁻ᵀ : ∇v dx (the variation of the cell's volume):

* residual: Σ_K p_K b_K(w), i.e. the UFL form ∫ p̄ J F⁻ᵀ : ∇w dx with p̄ the P0 function of
  the p_K (:meth:`MeanDilatation.residual`, added to the body's residual form);
* tangent: the derivative of that form at fixed p̄ (UFL) plus Σ_K U''(θ_K)/|K| b_K(w) b_K(du),
  the matrix Bᵀ D B with B the (cells × displacement DOFs) matrix of the b_K and D diagonal
  (:meth:`MeanDilatation.add_tangent`).

U(θ) = κ/2 (ln θ)² as the compressible laws of :mod:`shoulder_fem.forms.materials`, so
U'(θ) = κ ln θ / θ and U''(θ) = κ (1 − ln θ)/θ². p̄ must be current before any assembly of a
form that holds it: :meth:`MeanDilatation.update` (the deformable part of a
:class:`~shoulder_fem.engine.rigid_system.RigidSystem` calls it before each residual and tangent).
"""

from __future__ import annotations

from collections.abc import Mapping

import dolfinx
import dolfinx.fem.petsc as fem_petsc
import numpy as np
import ufl
from mpi4py import MPI
from petsc4py import PETSc

from shoulder_fem.engine.fem import JIT_PARAMS

__all__ = ["MeanDilatation"]


class MeanDilatation:
    """The mean-dilatation volumetric terms of the cells tagged in ``bulk`` (collective).

    Args:
        u: Displacement (m), a 3D vector Lagrange function.
        cell_tags: Cell markers of u's mesh.
        bulk: Bulk modulus κ (Pa) per cell tag.
        dx: Volume measure with ``cell_tags`` as subdomain data (its metadata, e.g. the
            quadrature degree, is kept).
        form_compiler_params: Passed to ``dolfinx.fem.form``.
    """

    def __init__(
        self,
        u: dolfinx.fem.Function,
        cell_tags: dolfinx.mesh.MeshTags,
        bulk: Mapping[int, float],
        dx: ufl.Measure,
        form_compiler_params: dict | None = None,
    ) -> None:
        if not bulk:
            raise ValueError("MeanDilatation: no cell tag given")
        for tag, kappa in bulk.items():
            if not float(kappa) > 0:
                raise ValueError(f"MeanDilatation: bulk modulus of cell tag {tag} must be > 0 Pa")
        self.u = u
        self.ids = tuple(int(t) for t in bulk)
        mesh = u.function_space.mesh
        self.comm = mesh.comm
        Q = dolfinx.fem.FunctionSpace(mesh, ("DG", 0))
        self.n_owned = Q.dofmap.index_map.size_local
        cell_dof = Q.dofmap.list.array  # one DOF per cell
        self.kappa = np.zeros(self.n_owned)
        #: Owned P0 DOFs of each tag's cells.
        self.cells: dict[int, np.ndarray] = {}
        for tag, kappa in bulk.items():
            dofs = cell_dof[cell_tags.find(int(tag))]
            dofs = dofs[dofs < self.n_owned]
            self.kappa[dofs] = float(kappa)
            self.cells[int(tag)] = dofs
        self._dx_all = dx
        self.dx = dx(self.ids)
        fco, jit = form_compiler_params or {}, JIT_PARAMS
        q = ufl.TestFunction(Q)
        Fg = ufl.Identity(3) + ufl.grad(u)
        self._J, self._Finv_T = ufl.det(Fg), ufl.inv(Fg).T
        self._mean = dolfinx.fem.form(
            self._J * q * self.dx, form_compiler_params=fco, jit_params=jit
        )
        du = ufl.TrialFunction(u.function_space)
        b = q * self._J * ufl.inner(self._Finv_T, ufl.grad(du)) * self.dx
        self._b_form = dolfinx.fem.form(b, form_compiler_params=fco, jit_params=jit)
        self._vec = fem_petsc.create_vector(self._mean)
        volume = dolfinx.fem.form(q * self.dx, form_compiler_params=fco, jit_params=jit)
        #: Reference volume of each owned cell (m^3; 0 outside the tagged cells).
        self.volume = self._assemble(volume)
        #: Mean volume ratio θ of each cell (1 outside the tagged cells), P0.
        self.theta = dolfinx.fem.Function(Q, name="mean_volume_ratio")
        #: Pressure p̄ = U'(θ) of each cell (Pa), P0; the coefficient of :meth:`residual`.
        self.pressure = dolfinx.fem.Function(Q, name="mean_pressure")
        self._B = fem_petsc.create_matrix(self._b_form)
        self._d = np.zeros(self.n_owned)
        self.update()

    def _assemble(self, form) -> np.ndarray:
        """The owned values of a P0 vector form (collective)."""
        vec = self._vec
        with vec.localForm() as loc:
            loc.set(0.0)
        fem_petsc.assemble_vector(vec, form)
        vec.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        return vec.array_r[: self.n_owned].copy()

    def residual(self, w: ufl.Argument, ids: tuple[int, ...] | None = None) -> ufl.Form:
        """The volumetric virtual power ∫ p̄ J F⁻ᵀ : ∇w dx (N) over the cells of ``ids`` (all)."""
        dx = self.dx if ids is None else self._dx_all(tuple(int(i) for i in ids))
        return self.pressure * self._J * ufl.inner(self._Finv_T, ufl.grad(w)) * dx

    def update(self) -> None:
        """θ, p̄ and U''/|K| of every cell at the current ``u`` (collective)."""
        mean = self._assemble(self._mean)
        soft = self.volume > 0
        theta = np.ones(self.n_owned)
        theta[soft] = mean[soft] / self.volume[soft]
        with np.errstate(invalid="ignore", divide="ignore"):
            log = np.log(theta)  # NaN for an inverted cell: the residual says so
            p = self.kappa * log / theta
            self._d = np.where(soft, self.kappa * (1 - log) / theta**2, 0.0)
        self._d[soft] /= self.volume[soft]
        for f, values in ((self.theta, theta), (self.pressure, p)):
            f.x.array[: self.n_owned] = values
            f.x.scatter_forward()

    def add_tangent(self, K: PETSc.Mat) -> None:
        """Add Σ_K U''(θ_K)/|K| b_K ⊗ b_K (N/m) to ``K`` at the state of the last :meth:`update`.

        ``K`` must hold the cells' couplings in its pattern (the body's tangent does).
        """
        B = self._B
        B.zeroEntries()
        fem_petsc.assemble_matrix(B, self._b_form)
        B.assemble()
        DB = B.duplicate(copy=True)
        d = B.createVecLeft()
        d.array[:] = self._d
        DB.diagonalScale(L=d)
        BtDB = B.transposeMatMult(DB)
        K.axpy(1.0, BtDB, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
        for obj in (DB, d, BtDB):
            obj.destroy()

    def volume_change(self, tag: int) -> float:
        """Relative volume change ∫J dx / |Ω| − 1 of the cells of ``tag``, now (collective)."""
        self.update()
        cells = self.cells[int(tag)]
        th = self.theta.x.array[cells]
        local = np.array([float(np.dot(th, self.volume[cells])), float(self.volume[cells].sum())])
        total = self.comm.allreduce(local, op=MPI.SUM)
        return float(total[0] / total[1] - 1.0)

    def destroy(self) -> None:
        """Free the PETSc objects."""
        self._B.destroy()
        self._vec.destroy()
