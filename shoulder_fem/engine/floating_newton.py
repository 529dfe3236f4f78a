"""The bordered Newton system of the floating-frame solver: residual and correction at an iterate.

:class:`FloatingNewtonSystem` assembles, at one iterate of
:class:`~shoulder_fem.engine.floating.FloatingBody`'s Newton loop, the residual of the straining
rows, the frame rows and the mean-axes conditions, and solves the bordered linear system for the
correction. The loop itself (tolerances, updates) stays in the body.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import dolfinx.fem.petsc as fem_petsc
import numpy as np
from mpi4py import MPI

from shoulder_fem.engine.bordered import BorderedSolver, assemble_owned
from shoulder_fem.engine.floating_forms import FloatingForms, frame_directions

__all__ = ["FloatingNewtonSystem", "NewtonResidual"]


@dataclass
class NewtonResidual:
    """The bordered residual at one Newton iterate.

    Attributes:
        dirs: the six frame directions d_k, local + ghost nodal arrays (n, 3) (m or m/rad).
        d_owned: their owned blocked entries.
        r1: Rᵀ r + Cᵀ λ, the straining rows (N), owned entries.
        r_frame: d_k · r, the frame rows (N, N·m).
        g: C ũ, the mean-axes conditions (kg m, kg m²).
        norm: the scaled residual norm the convergence test uses (N).
    """

    dirs: list[np.ndarray]
    d_owned: list[np.ndarray]
    r1: np.ndarray
    r_frame: np.ndarray
    g: np.ndarray
    norm: float


class FloatingNewtonSystem:
    """Newton's method for the floating body in one bordered linear system (collective).

    The test space is split as in the paper, ``w = w_G + Ω_w × R(Y + ũ) + R w̃``. With
    K = ∂r/∂x_{n+1} (not symmetric: S_alg depends on C_{n+1} through F_{n+1}, and is tested with
    F_{n+½}) and the six frame directions d_k (k < 3: translation e_k; k ≥ 3: rotation
    e_k × R(Y + ũ), the multiplicative update R ← exp(hat δθ) R), each iteration solves::

        [ A    B    Cᵀ ] [δũ]     [ Rᵀr + Cᵀλ ]
        [ Bʳ   D    0  ] [δf ] = −[ d_k · r    ]
        [ C    0    0  ] [δλ]     [ C ũ        ]

    A = Rᵀ K R, columns B_k = Rᵀ K d_k, rows Bʳ_k = d_kᵀ K R and D_kl = d_k·K d_l (the forms of
    :class:`FloatingForms`); C holds the six mean-axes rows. Terms from the test functions' own
    dependence on (R, ũ) multiply the residual and vanish at the solution; leaving them out keeps
    the convergence quadratic (checked in the tests). At a solution λ = 0 and the full nodal
    residual r vanishes: the test map (w_G, Ω_w, w̃) → w has rank 3N and its 6-dimensional kernel
    is fixed by the constraints.

    The system is solved by :class:`BorderedSolver`: A is factorized once per iteration, one
    multi-right-hand-side solve gives A⁻¹ r and A⁻¹ [B Cᵀ] (13 columns), and the 12 × 12 Schur
    complement is solved on every rank. Extra cost per iteration: 13 back-substitutions in one
    MUMPS call and 12 vector assemblies.

    Args:
        forms: the body's forms (their Functions carry ũ and the frame).
        n_owned: the number of owned blocked entries of ũ.
        length: the body's size ℓ (m), the scale of the rotation rows in the norm.
        name: options-prefix stem of the linear solver.
    """

    def __init__(self, forms: FloatingForms, n_owned: int, length: float, name: str):
        self.forms = forms
        self.comm = forms.u.function_space.mesh.comm
        self.n_owned = n_owned
        self.length = length
        #: The six mean-axes rows c_k (owned entries).
        self.C = [assemble_owned(f) for f in forms.mean_axes]
        self._r = fem_petsc.create_vector(forms.r)
        self.A = fem_petsc.create_matrix(forms.a)
        fem_petsc.assemble_matrix(self.A, forms.a)
        self.A.assemble()
        self.linear = BorderedSolver(self.comm, self.A, name)

    def dots(self, pairs: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
        """Global dot products of owned-entry arrays, one reduction for all of them."""
        local = np.array([float(a @ b) for a, b in pairs])
        return self.comm.allreduce(local, op=MPI.SUM)

    @staticmethod
    def rotate_to_body(owned: np.ndarray, R: np.ndarray) -> np.ndarray:
        """Node-wise Rᵀ r for owned blocked entries."""
        return (owned.reshape(-1, 3) @ R).ravel()

    def residual(self, x_g: np.ndarray, R: np.ndarray, lam: np.ndarray, h: float) -> NewtonResidual:
        """The bordered residual at the iterate (x_G m, R, ũ) with multipliers ``lam``.

        Args:
            x_g: centre of mass (m).
            R: rotation body → inertial frame.
            lam: the six multipliers λ (N, N·m).
            h: the time step (s).
        """
        forms = self.forms
        forms.x_g.value[:] = x_g
        forms.R.value[:] = R
        dirs = frame_directions(forms.positions(x_g, R) - x_g)
        d_owned = [d.ravel()[: self.n_owned].copy() for d in dirs]
        r = assemble_owned(forms.r, self._r)
        r1 = self.rotate_to_body(r, R) + sum(lam[k] * self.C[k] for k in range(6))
        u_owned = forms.u.x.array[: self.n_owned]
        dots = self.dots([(d, r) for d in d_owned] + [(c, u_owned) for c in self.C] + [(r1, r1)])
        r_frame, g = dots[:6], dots[6:12]
        norm = math.sqrt(
            dots[12]
            + float(r_frame[:3] @ r_frame[:3])
            + float(r_frame[3:] @ r_frame[3:]) / self.length**2
            + float(g @ g) * (2.0 / h**2) ** 2 * (1.0 + 1.0 / self.length**2)
        )
        return NewtonResidual(dirs, d_owned, r1, r_frame, g, norm)

    def solve(self, res: NewtonResidual, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Solve the bordered system at the iterate of ``res`` (rotation ``R``).

        Returns:
            δũ (m, owned entries) and q = (δx_G m, δθ rad, δλ N and N·m).
        """
        forms = self.forms
        self.A.zeroEntries()
        fem_petsc.assemble_matrix(self.A, forms.a)
        self.A.assemble()
        self.linear.set_operator(self.A)
        Kd, rows = [], []
        for d in res.dirs:
            forms.d.x.array[:] = d.ravel()
            Kd.append(assemble_owned(forms.kd, self._r))
            rows.append(assemble_owned(forms.kt, self._r))
        cols = [self.rotate_to_body(kd, R) for kd in Kd]
        Z = np.zeros((12, 12))
        Z[:6, :6] = self.dots([(d, kd) for d in res.d_owned for kd in Kd]).reshape(6, 6)
        return self.linear.solve(
            res.r1, cols + self.C, rows + self.C, Z, np.concatenate([res.r_frame, res.g])
        )

    def destroy(self) -> None:
        """Free the PETSc objects."""
        self.linear.destroy()
        self.A.destroy()
        self._r.destroy()
