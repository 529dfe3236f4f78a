"""Nearly incompressible bodies without volumetric locking: condensed mixed formulations.

The volumetric energy U(θ) is taken on a volume ratio θ projected onto a pressure space Q, with
P2 displacements:

* ``P0`` -- mean dilatation (Simo, Taylor and Pister 1985; P2/P0): one θ per cell,
  θ_K = (1/|K|) ∫_K J dx. The pressure is inf-sup stable, but the volume may vary inside a cell
  as long as its mean is kept (measured on the shoulder's muscles at ``coarse``, 30 deg: J from
  0.04 to 2.5 at the cells' points, with cell means within 0.3 %).
* ``P1`` -- the Taylor-Hood pair P2/P1 with the pressure's mass lumped, condensed (a perturbed
  Lagrangian, U'(θ) = p, eliminated vertex by vertex): θ_a = ∫ φ_a J dx / ∫ φ_a dx for each
  vertex a of the tagged cells, so that the volume is kept around every vertex. Its tangent
  couples the cells around a vertex: a wider pattern than the body's own.

With p_a = U'(θ_a) and b_a(v) = ∫ φ_a J F⁻ᵀ : ∇v dx (φ_a the pressure basis function):

* residual: Σ_a p_a b_a(w), the UFL form ∫ p J F⁻ᵀ : ∇w dx with p the Q function of the p_a
  (:meth:`MeanDilatation.residual`, added to the body's residual form);
* tangent: the derivative of that form at fixed p (UFL) plus Σ_a U''(θ_a)/|a| b_a(w) b_a(du),
  the matrix Bᵀ D B with B the (pressure DOFs × displacement DOFs) matrix of the b_a and D
  diagonal (:meth:`MeanDilatation.tangent_matrix`), |a| = ∫ φ_a dx.

U(θ) = κ/2 (ln θ)² as the compressible laws of :mod:`shoulder_fem.forms.materials`, so
U'(θ) = κ ln θ / θ and U''(θ) = κ (1 − ln θ)/θ²; both pairs tend to the incompressible solution
as O(μ/κ) (tested on a homogeneous stretch) and do not lock (a cantilever, tested). With
multipliers λ (an augmented Lagrangian, :meth:`MeanDilatation.augment`), p = λ + U'(θ):
updated until θ = 1 to a tolerance, they give the incompressible solution with a moderate κ
(tested). p must be current before any assembly of a form that holds it:
:meth:`MeanDilatation.update` (the solvers that take these terms call it before each residual
and tangent).
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

__all__ = ["MeanDilatation", "VolumeChange"]


class MeanDilatation:
    """The condensed volumetric terms of the cells tagged in ``bulk`` (collective).

    Args:
        u: Displacement (m), a 3D vector Lagrange function.
        cell_tags: Cell markers of u's mesh.
        bulk: Bulk modulus κ (Pa) per cell tag.
        dx: Volume measure with ``cell_tags`` as subdomain data (its metadata, e.g. the
            quadrature degree, is kept).
        form_compiler_params: Passed to ``dolfinx.fem.form``.
        pressure: The pressure space, ``P0`` (one per cell) or ``P1`` (continuous, lumped).
    """

    def __init__(
        self,
        u: dolfinx.fem.Function,
        cell_tags: dolfinx.mesh.MeshTags,
        bulk: Mapping[int, float],
        dx: ufl.Measure,
        form_compiler_params: dict | None = None,
        pressure: str = "P0",
    ) -> None:
        if not bulk:
            raise ValueError("MeanDilatation: no cell tag given")
        for tag, kappa in bulk.items():
            if not float(kappa) > 0:
                raise ValueError(f"MeanDilatation: bulk modulus of cell tag {tag} must be > 0 Pa")
        if pressure not in ("P0", "P1"):
            raise ValueError(f"MeanDilatation: pressure must be 'P0' or 'P1', got {pressure!r}")
        self.u = u
        self.ids = tuple(int(t) for t in bulk)
        #: Whether every volumetric coupling lies within one cell (P0: the tangent fits the
        #: body's pattern; P1 couples the cells around a vertex).
        self.cell_local = pressure == "P0"
        mesh = u.function_space.mesh
        self.comm = mesh.comm
        Q = dolfinx.fem.FunctionSpace(mesh, ("DG", 0) if self.cell_local else ("CG", 1))
        self.n_owned = Q.dofmap.index_map.size_local
        self._dx_all = dx
        self.dx = dx(self.ids)
        fco, jit = form_compiler_params or {}, JIT_PARAMS
        q = ufl.TestFunction(Q)
        Fg = ufl.Identity(3) + ufl.grad(u)
        self._J, self._Finv_T = ufl.det(Fg), ufl.inv(Fg).T
        volume = dolfinx.fem.form(q * self.dx, jit_params=jit)
        self._vec = fem_petsc.create_vector(volume)
        #: The (lumped) reference volume of each owned pressure DOF, ∫ q dx (m^3; 0 outside).
        self.volume = self._assemble(volume)
        cell_kappa = dolfinx.fem.Function(dolfinx.fem.FunctionSpace(mesh, ("DG", 0)))
        cells = cell_kappa.function_space.dofmap.list.array  # one DOF per cell
        for tag, kappa in bulk.items():
            cell_kappa.x.array[cells[cell_tags.find(int(tag))]] = float(kappa)
        soft = self.volume > 0
        #: The bulk modulus of each owned pressure DOF (Pa; the volume-weighted mean over
        #: the cells around a P1 vertex).
        self.kappa = np.zeros(self.n_owned)
        weighted = self._assemble(dolfinx.fem.form(cell_kappa * q * self.dx, jit_params=jit))
        self.kappa[soft] = weighted[soft] / self.volume[soft]
        #: The factor on every bulk modulus (1: their own; < 1 in a continuation).
        self.bulk_factor = 1.0
        self._mean = dolfinx.fem.form(
            self._J * q * self.dx, form_compiler_params=fco, jit_params=jit
        )
        du = ufl.TrialFunction(u.function_space)
        b = q * self._J * ufl.inner(self._Finv_T, ufl.grad(du)) * self.dx
        self._b_form = dolfinx.fem.form(b, form_compiler_params=fco, jit_params=jit)
        #: Volume ratio θ of each pressure DOF (1 outside the tagged cells).
        self.theta = dolfinx.fem.Function(Q, name="volume_ratio")
        #: Pressure p = U'(θ) of each pressure DOF (Pa); the coefficient of :meth:`residual`.
        self.pressure = dolfinx.fem.Function(Q, name="pressure")
        self._B = fem_petsc.create_matrix(self._b_form)
        self._BtDB: PETSc.Mat | None = None
        #: B P (:meth:`reduced_product`) and Pᵀ Bᵀ D B P (:meth:`reduced_tangent`).
        self._BP: PETSc.Mat | None = None
        self._PtBtDBP: PETSc.Mat | None = None
        self._d = np.zeros(self.n_owned)
        #: Augmented-Lagrangian multiplier of each pressure DOF (Pa): p = λ + U'(θ).
        self.multiplier = np.zeros(self.n_owned)
        self.update()

    def _assemble(self, form) -> np.ndarray:
        """The owned values of a vector form on the pressure space (collective)."""
        vec = self._vec
        with vec.localForm() as loc:
            loc.set(0.0)
        fem_petsc.assemble_vector(vec, form)
        vec.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        return vec.array_r[: self.n_owned].copy()

    def residual(self, w: ufl.Argument, ids: tuple[int, ...] | None = None) -> ufl.Form:
        """The volumetric virtual power ∫ p J F⁻ᵀ : ∇w dx (N) over the cells of ``ids`` (all)."""
        dx = self.dx if ids is None else self._dx_all(tuple(int(i) for i in ids))
        return self.pressure * self._J * ufl.inner(self._Finv_T, ufl.grad(w)) * dx

    def update(self) -> None:
        """θ, p and U''/|a| of every pressure DOF at the current ``u`` (collective)."""
        mean = self._assemble(self._mean)
        soft = self.volume > 0
        theta = np.ones(self.n_owned)
        theta[soft] = mean[soft] / self.volume[soft]
        kappa = self.bulk_factor * self.kappa
        with np.errstate(invalid="ignore", divide="ignore"):
            log = np.log(theta)  # NaN for an inverted cell: the residual says so
            p = self.multiplier + kappa * log / theta
            self._d = np.where(soft, kappa * (1 - log) / theta**2, 0.0)
        self._d[soft] /= self.volume[soft]
        for f, values in ((self.theta, theta), (self.pressure, p)):
            f.x.array[: self.n_owned] = values
            f.x.scatter_forward()

    def violation(self) -> float:
        """The largest |ln θ| over the pressure DOFs, now: the volume error (collective)."""
        self.update()
        log = np.abs(np.log(self.theta.x.array[: self.n_owned]))
        return self.comm.allreduce(float(log.max()) if len(log) else 0.0, op=MPI.MAX)

    def augment(self) -> None:
        """λ ← p: each multiplier takes its current pressure (an augmented-Lagrangian update).

        With p = λ + U'(θ), a state solved again after the update keeps the volume better by
        about the ratio of the tissue's stiffness to κ (Uzawa); at θ = 1 (ln θ = 0), p = λ is
        the incompressible pressure, whatever κ.
        """
        self.update()
        self.multiplier[:] = self.pressure.x.array[: self.n_owned]
        self.update()

    def scale_bulk(self, factor: float) -> None:
        """Every bulk modulus at ``factor`` x its own (a continuation; 1 gives them back)."""
        if not factor > 0:
            raise ValueError(f"MeanDilatation: bulk factor must be > 0, got {factor!r}")
        self.bulk_factor = float(factor)
        self.update()

    def tangent_matrix(self) -> PETSc.Mat:
        """Σ_a U''(θ_a)/|a| b_a ⊗ b_a (N/m) at the state of the last :meth:`update`.

        The same matrix object from call to call (refilled; its pattern is fixed); owned here.
        """
        B = self._assemble_b()
        self._BtDB = self._btdb(B, self._BtDB)
        return self._BtDB

    def reduced_tangent(self, P: PETSc.Mat) -> PETSc.Mat:
        """Pᵀ (Bᵀ D B) P as (B P)ᵀ D (B P), for a prolongation ``P`` (u's DOFs x reduced DOFs).

        The same as ``tangent_matrix().PtAP(P)`` to round-off, without forming Bᵀ D B on u's
        DOFs (the cells around each vertex coupled: measured at ``medium``, part 1's first
        Jacobian, 138 MB for Bᵀ D B and 617 MB more for its product with P). ``P``'s pattern
        must be the same from call to call (its values may change). The same matrix object
        from call to call; owned here.
        """
        self._PtBtDBP = self._btdb(self.reduced_product(P), self._PtBtDBP)
        return self._PtBtDBP

    def reduced_product(self, P: PETSc.Mat) -> PETSc.Mat:
        """B P at the state of the last :meth:`update` (B's rows: the pressure DOFs).

        ``P``'s pattern must be the same from call to call (its values may change). The same
        matrix object from call to call; owned here.
        """
        B = self._assemble_b()
        if self._BP is None:
            self._BP = B.matMult(P)
        else:
            B.matMult(P, result=self._BP)
        return self._BP

    def stiffness_diagonal(self) -> np.ndarray:
        """D's diagonal: U''(θ_a)/|a| of each owned pressure DOF at the last update (0 outside)."""
        return self._d

    def _assemble_b(self) -> PETSc.Mat:
        B = self._B
        B.zeroEntries()
        fem_petsc.assemble_matrix(B, self._b_form)
        B.assemble()
        return B

    def _btdb(self, B: PETSc.Mat, result: PETSc.Mat | None) -> PETSc.Mat:
        """Bᵀ D B into ``result`` (or a new matrix), D the diagonal of U''(θ_a)/|a|."""
        DB = B.duplicate(copy=True)
        d = B.createVecLeft()
        d.array[:] = self._d
        DB.diagonalScale(L=d)
        if result is None:
            result = B.transposeMatMult(DB)
        else:
            B.transposeMatMult(DB, result=result)
        DB.destroy()
        d.destroy()
        return result

    def add_tangent(self, K: PETSc.Mat) -> None:
        """Add :meth:`tangent_matrix` to ``K``.

        P0: ``K`` must hold the cells' couplings (the body's tangent does); P1: K's pattern is
        widened (PETSc rebuilds K, without its local numbering: assemble forms elsewhere).
        """
        kind = PETSc.Mat.Structure
        if self.cell_local:
            K.axpy(1.0, self.tangent_matrix(), structure=kind.SUBSET_NONZERO_PATTERN)
            return
        K.axpy(1.0, self.tangent_matrix(), structure=kind.DIFFERENT_NONZERO_PATTERN)

    def destroy(self) -> None:
        """Free the PETSc objects."""
        for obj in (self._B, self._BtDB, self._BP, self._PtBtDBP, self._vec):
            if obj is not None:
                obj.destroy()


class VolumeChange:
    """Relative volume change ∫J dx / |Ω| − 1 of the cells of each tag, at ``u`` (collective).

    Args:
        u: Displacement (m), a 3D vector Lagrange function.
        dx: Volume measure with the cell tags as subdomain data.
        tags: The cell tags measured.
        form_compiler_params: Passed to ``dolfinx.fem.form``.
    """

    def __init__(self, u, dx: ufl.Measure, tags, form_compiler_params: dict | None = None):
        self.comm = u.function_space.mesh.comm
        J = ufl.det(ufl.Identity(3) + ufl.grad(u))
        fco = form_compiler_params or {}
        #: Per tag, the current volume's form and the reference volume (m^3).
        self._forms = {}
        for tag in tags:
            ref = dolfinx.fem.assemble_scalar(dolfinx.fem.form(1.0 * dx(int(tag))))
            self._forms[int(tag)] = (
                dolfinx.fem.form(J * dx(int(tag)), form_compiler_params=fco),
                self.comm.allreduce(ref, op=MPI.SUM),
            )

    def __call__(self) -> dict[int, float]:
        """The relative volume change of each tag's cells now, by tag."""
        out = {}
        for tag, (form, ref) in self._forms.items():
            now = self.comm.allreduce(dolfinx.fem.assemble_scalar(form), op=MPI.SUM)
            out[tag] = now / ref - 1.0
        return out
