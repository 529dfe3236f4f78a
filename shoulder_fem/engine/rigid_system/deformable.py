"""The deformable body of a :class:`RigidSystem`: its displacement, FE residual and tangent.

Assembled without boundary conditions (ties and fixed nodes enter through the prolongation of
:mod:`~shoulder_fem.engine.rigid_system.layout`), with the contact terms added; also what is
measured at its nodes (reactions of fixed surfaces, positions of tied nodes).
"""

from __future__ import annotations

from collections.abc import Sequence

import dolfinx
import dolfinx.fem.petsc as fem_petsc
import numpy as np
import ufl
from mpi4py import MPI
from petsc4py import PETSc

from shoulder_fem.engine.fem import JIT_PARAMS
from shoulder_fem.engine.rigid_system.bodies import RigidBody
from shoulder_fem.engine.rigid_system.layout import ReducedLayout

__all__ = ["DeformablePart"]


class DeformablePart:
    """The FE part of a system: displacement ``u`` (m), residual F (N) and tangent K (N/m).

    Args:
        u: Displacement (m), a 3D vector Lagrange function.
        residual: UFL residual F(u; w) (N).
        jacobian: UFL tangent of ``residual``; ``ufl.derivative`` if ``None``.
        form_compiler_params: Passed to ``dolfinx.fem.form``.
        contact: Contact terms on ``u`` (built with no Dirichlet conditions), or ``None``:
            added to F and, by :meth:`contact_tangent`, to K.
        layout: The system's layout (which nodes are free, tied, fixed).
        volumetric: A :class:`~shoulder_fem.engine.mean_dilatation.MeanDilatation` on ``u``
            whose residual is part of ``residual``, or ``None``: updated before every residual
            and tangent, its cell-mean tangent added to K.
    """

    def __init__(
        self,
        u: dolfinx.fem.Function,
        residual: ufl.Form,
        jacobian: ufl.Form | None,
        form_compiler_params: dict | None,
        contact,
        layout: ReducedLayout,
        volumetric=None,
    ) -> None:
        self.u = u
        self.volumetric = volumetric
        self.contact = contact
        self.layout = layout
        fco = form_compiler_params or {}
        if jacobian is None:
            jacobian = ufl.derivative(residual, u, ufl.TrialFunction(u.function_space))
        self.F_form = dolfinx.fem.form(residual, form_compiler_params=fco, jit_params=JIT_PARAMS)
        self.J_form = dolfinx.fem.form(jacobian, form_compiler_params=fco, jit_params=JIT_PARAMS)
        #: The assembled residual (N) and tangent (N/m, AIJ; from the first
        #: :meth:`assemble_tangent` on), without conditions.
        self.F = fem_petsc.create_vector(self.F_form)
        self.K: PETSc.Mat | None = None
        #: K assembled block-wise (BAIJ, 3x3 blocks), then converted into ``K`` (see
        #: :meth:`assemble_tangent`); ``None`` between assemblies until it is kept.
        self._K_blocks: PETSc.Mat | None = None
        #: The packed constants and coefficients K was last assembled from.
        self._tangent_inputs: tuple | None = None
        #: How many times K has been assembled.
        self.tangent_assemblies = 0
        #: How many times F has been assembled (tells a caller whether F is still its own).
        self.residual_assemblies = 0

    def assemble_residual(self) -> None:
        """Assemble F at the current ``u`` (contact added; ghosts updated)."""
        self.residual_assemblies += 1
        if self.volumetric is not None:
            self.volumetric.update()
        with self.F.localForm() as loc:
            loc.set(0.0)
        fem_petsc.assemble_vector(self.F, self.F_form)
        self.F.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        if self.contact is not None:
            self.contact.add_residual(self.F)
            self.F.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)

    def assemble_tangent(self) -> None:
        """Assemble K at the current ``u`` (without contact: see :meth:`contact_tangent`).

        Nothing is done when the form's coefficients and constants are those of the last
        assembly (K is current: a system assembles K for its Jacobian's pattern, then again
        for its first Jacobian at the same state).

        Assembled block-wise (BAIJ, 3x3 blocks), then converted into the AIJ ``K`` that the
        products take: measured on the shoulder's soft tissue at ``paper``, 0.109 s per AIJ
        assembly against 0.074 s + 0.016 s of conversion (PETSc's AIJ insertion searches
        every entry's column, BAIJ's a block's). K is the first conversion's own matrix: a
        reused conversion into a matrix made otherwise misplaced off-process columns under
        MPI (measured, 2 ranks). The block matrix is kept from the second assembly on: a
        linear problem assembles once and does not hold a second copy of its tangent through
        its factorization.
        """
        if self.volumetric is not None:
            self.volumetric.update()
        constants = dolfinx.cpp.fem.pack_constants(self.J_form)
        coefficients = dolfinx.cpp.fem.pack_coefficients(self.J_form)
        if self.K is not None and self._same_inputs(constants, coefficients):
            return
        self._tangent_inputs = (constants, coefficients, self._bulk_factor())
        self.tangent_assemblies += 1
        if self._K_blocks is None:
            self._K_blocks = fem_petsc.create_matrix(self.J_form, "baij")
        Kb = self._K_blocks
        Kb.zeroEntries()
        fem_petsc.assemble_matrix(Kb, self.J_form, constants=constants, coeffs=coefficients)
        Kb.assemble()
        if self.K is None:
            self.K = Kb.convert(PETSc.Mat.Type.AIJ, PETSc.Mat())
        else:
            Kb.convert(PETSc.Mat.Type.AIJ, self.K)
        if self.volumetric is not None and self.volumetric.cell_local:
            self.volumetric.add_tangent(self.K)  # else the system adds it (couples cells)
        if self.tangent_assemblies < 2:
            Kb.destroy()
            self._K_blocks = None

    def _bulk_factor(self) -> float:
        """The volumetric terms' bulk-modulus factor (1 without them)."""
        return self.volumetric.bulk_factor if self.volumetric is not None else 1.0

    def _same_inputs(self, constants: np.ndarray, coefficients: dict) -> bool:
        """Whether K was assembled from these packed constants and coefficients (collective)."""
        last = self._tangent_inputs
        same = (
            last is not None
            and last[2] == self._bulk_factor()  # K holds the volumetric tangent at it
            and np.array_equal(last[0], constants)
            and last[1].keys() == coefficients.keys()
            and all(np.array_equal(last[1][k], c) for k, c in coefficients.items())
        )
        return bool(self.layout.comm.allreduce(same, op=MPI.LAND))

    def contact_tangent(self, reuse: PETSc.Mat | None = None) -> PETSc.Mat:
        """The contact tangent (N/m) at the current state: ``reuse`` refilled, or a new matrix.

        ``reuse``: the matrix returned last; it comes back (refilled) while the pattern is the
        same, else a new matrix is returned (the caller destroys what it no longer uses).
        """
        return self.contact.jacobian_matrix(self.K, reuse)

    def free_values(self) -> np.ndarray:
        """The displacement DOFs of the free owned nodes, in the layout's order (m)."""
        return self.u.x.array.reshape(-1, 3)[self.layout.free_nodes].ravel()

    def set_displacement(
        self,
        free: np.ndarray,
        bodies: Sequence[RigidBody],
        phi: np.ndarray,
        linear_ties: bool,
    ) -> None:
        """Set ``u``: ``free`` on the free nodes, zero on fixed ones, tied ones from their body.

        A tied node follows ``t + R (X + o - X_ref) - (X - X_ref)`` (o its offset in the body's
        frame, :meth:`RigidSystem.set_tie_offsets`, zero by default); with ``linear_ties``
        ``t + φ × (X - X_ref)`` (φ the body's total rotation vector, rad). Ghosts updated.
        """
        lay = self.layout
        u = self.u.x.array.reshape(-1, 3)
        u[lay.free_nodes] = free.reshape(-1, 3)
        u[lay.fixed_all] = 0.0
        for b, nodes in enumerate(lay.tied_nodes):
            body = bodies[b]
            d = lay.X[nodes] - body.reference_point
            if linear_ties:
                u[nodes] = body.translation + np.cross(phi[b], d)
            else:  # at the body point X + offset (layout.X_tied)
                r = lay.X_tied[nodes] - body.reference_point
                u[nodes] = body.translation + r @ body.rotation.T - d
        self.u.x.scatter_forward()

    def reaction(
        self, surface: str | Sequence[str], point: np.ndarray | None = None
    ) -> tuple[np.ndarray, ...]:
        """Force (N) and moment about ``point`` (m, default origin, N·m) on fixed ``surface``.

        ``surface``: a name, or several (their nodes counted once: surfaces that share an edge).
        """
        point = np.zeros(3) if point is None else np.asarray(point, dtype=float)
        self.assemble_residual()
        names = (surface,) if isinstance(surface, str) else tuple(surface)
        owned = np.unique(np.concatenate([self.layout.fixed_owned[n] for n in names]))
        f = self.F.array_r.reshape(-1, 3)[owned]
        x = self.layout.X[owned] + self.u.x.array.reshape(-1, 3)[owned]
        local = np.r_[f.sum(axis=0), np.cross(x - point, f).sum(axis=0)]
        total = self.layout.comm.allreduce(local, op=MPI.SUM)
        return total[:3], total[3:]

    def tied_positions(self, b: int) -> tuple[np.ndarray, np.ndarray]:
        """Reference and current positions (m) of the nodes tied to body b, on every rank."""
        owned = self.layout.tied_owned[b]
        X = self.layout.X[owned]
        x = X + self.u.x.array.reshape(-1, 3)[owned]
        Xs = self.layout.comm.allgather(X)
        xs = self.layout.comm.allgather(x)
        return np.vstack(Xs), np.vstack(xs)

    def destroy(self) -> None:
        """Free the PETSc objects."""
        for obj in (self.K, self._K_blocks, self.F):
            if obj is not None:
                obj.destroy()
