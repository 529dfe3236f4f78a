"""The compiled forms of the floating-frame solver: the residual of eq. (14) and its derivatives.

UFL and dolfinx only: what :class:`~shoulder_fem.engine.floating.FloatingBody` assembles in its
Newton iterations, the mean-axes frame conditions (shared with the decoupled tumbling body), the
frame directions and the body-frame stress measures. SI units: m, s, kg, N, Pa.
"""

from __future__ import annotations

import dolfinx
import numpy as np
import ufl

from shoulder_fem.engine.fem import constant
from shoulder_fem.engine.so3 import I3
from shoulder_fem.forms import kinematics, materials
from shoulder_fem.forms.materials import Hyperelastic

__all__ = ["FloatingForms", "frame_directions", "mean_axes_forms"]


def mean_axes_forms(rho: float, Y, w, dx: ufl.Measure) -> list[ufl.Form]:
    """The six linear mean-axes (Buckens) conditions on ``w``: ∫ρ w_k (k < 3), ∫ρ (Y × w)_k.

    Args:
        rho: density (kg/m³).
        Y: the position relative to the reference centre of mass, a UFL vector (m).
        w: the test function the conditions act on.
        dx: the cell measure.

    Returns:
        The six UFL forms, translations first (not compiled).
    """
    forms = [rho * w[k] * dx for k in range(3)]
    forms += [rho * ufl.cross(Y, w)[k] * dx for k in range(3)]
    return forms


def frame_directions(arm: np.ndarray) -> list[np.ndarray]:
    """The six frame directions d_k at nodes of arm ``x − x_G`` (m), each shaped like ``arm``.

    k < 3: the translation e_k; k ≥ 3: the rotation e_k × (x − x_G) of the multiplicative update
    R ← exp(hat δθ) R.
    """
    dirs = [np.broadcast_to(I3[k], arm.shape) for k in range(3)]
    dirs += [np.cross(I3[k], arm) for k in range(3)]
    return dirs


class FloatingForms:
    """The forms of the Simo–Tarnow energy–momentum midpoint rule for a floating body.

    **Kinematics.** A material point with reference position X is at
    ``x = x_G + R (Y + ũ)``, ``Y = X − X_G``, with ũ the straining displacement (body-frame
    components, m) and X_G the reference centre of mass.

    **Residual** (J.C. Simo, N. Tarnow, ZAMP 43, 1992), on the inertial nodal positions with the
    consistent mass matrix M, ``F_{n+½} = (F_n + F_{n+1})/2`` and the algorithmic stress
    ``S_alg = S((C_n + C_{n+1})/2)``::

        x_{n+1} − x_n = Δt (v_n + v_{n+1})/2,      M (v_{n+1} − v_n)/Δt + f_alg = 0,
        r(w) = ∫ ρ a·w + ∫ F_{n+½} S_alg : ∇w,      a = 2 (x_{n+1} − x_n − Δt v_n)/Δt².

    Conservation for a free body with no loads, proved for the discrete equations (so on any
    mesh, to the Newton tolerance):

    * **linear momentum** ∫ρ v: Σ_i f_alg,i = 0 (the form vanishes for a uniform w);
    * **angular momentum** ∫ρ x × v: with d = x_{n+1} − x_n = Δt s, s = (v_n + v_{n+1})/2,
      ΔL = Σ_ij M_ij (x_{n+½,i} × Δv_j + d_i × s_j)
      = −Δt Σ_i x_{n+½,i} × f_alg,i + Δt Σ_ij M_ij s_i × s_j.
      The second sum vanishes by the symmetry of M; the first is ∫ F_{n+½} S_alg : hat(e) F_{n+½}
      = hat(e) : F_{n+½} S_alg F_{n+½}ᵀ = 0 because S_alg is symmetric;
    * **energy** ½ vᵀMv + ∫W: ΔE_kin = −f_alg · d, and ∫ F_{n+½} S_alg : ∇d = ∫ S_alg : ΔE
      because ΔE = sym(F_{n+½}ᵀ ΔF) exactly; for Saint Venant–Kirchhoff W is quadratic in E, so
      S((E_n + E_{n+1})/2) : ΔE = ΔW exactly and the energy is conserved (for other laws to
      O(Δt²)).

    The plain midpoint rule (P evaluated at F_{n+½}) conserves both momenta too, but not energy:
    a rotating body is shrunk at the mid-step by cos(ΩΔt/2), a spurious strain of (ΩΔt)²/8 that
    for a soft body swamps the physical one. Accuracy is second order in Δt (a symmetric one-step
    scheme).

    **Derivatives.** With K = ∂r/∂x_{n+1} and the frame directions d_k (:func:`frame_directions`):
    ``a`` is A = Rᵀ K R (``ufl.derivative`` of the w̃ = Rᵀw rows in ũ), ``kd`` the columns K d_k
    and ``kt`` the rows d_kᵀ K (the direction in :attr:`d`). UFL cannot differentiate with respect
    to a Constant, so the frame enters x through the zero Function :attr:`z` and
    ∂/∂(frame) = ∂/∂z along d_k.

    Args:
        mesh: reference mesh (m).
        V: the vector Lagrange space of ũ.
        rho: density ρ (kg/m³), uniform.
        material: the hyperelastic law.
        centre: the reference centre of mass X_G (m).
        dx: the cell measure (with the quadrature degree ``qd``).
        qd: the quadrature degree of every form.
    """

    def __init__(
        self,
        mesh: dolfinx.mesh.Mesh,
        V: dolfinx.fem.FunctionSpace,
        rho: float,
        material: Hyperelastic,
        centre: np.ndarray,
        dx: ufl.Measure,
        qd: int,
    ):
        self.u = dolfinx.fem.Function(V, name="strain_displacement")
        self.z = dolfinx.fem.Function(V)  # stays zero: carries the frame derivatives
        self.d = dolfinx.fem.Function(V)  # a frame direction
        self.x_n = dolfinx.fem.Function(V)  # inertial nodal positions at t_n
        self.v_n = dolfinx.fem.Function(V)  # inertial nodal velocities at t_n
        self.x_g = constant(mesh, np.zeros(3))
        self.R = constant(mesh, np.eye(3))
        self.dt = constant(mesh, 1.0)
        #: Y = X − X_G at the local + ghost nodes, (n, 3) (m).
        self.Y_nodes = V.tabulate_dof_coordinates() - centre
        X = ufl.SpatialCoordinate(mesh)
        #: Y = X − X_G as a UFL vector (m); X_G a constant, so that another body's centre
        #: compiles no new form.
        self.Y = X - constant(mesh, centre)
        x1 = self.x_g + self.R * (self.Y + self.u) + self.z
        acc = 2 * (x1 - self.x_n - self.dt * self.v_n) / self.dt**2
        F_n, F_1 = ufl.grad(self.x_n), ufl.grad(x1)
        F_mid = (F_n + F_1) / 2
        # Simo–Tarnow: S at the mean of the end-point C's (exact energy balance for SVK).
        P_mid = F_mid * material.second_piola((F_n.T * F_n + F_1.T * F_1) / 2)

        def residual(w):
            return rho * ufl.dot(acc, w) * dx + ufl.inner(P_mid, ufl.grad(w)) * dx

        w = ufl.TestFunction(V)
        du = ufl.TrialFunction(V)
        fcp = {"quadrature_degree": qd}
        self.r = dolfinx.fem.form(residual(w), form_compiler_params=fcp)
        self.kd = dolfinx.fem.form(
            ufl.derivative(residual(w), self.z, self.d), form_compiler_params=fcp
        )
        self.kt = dolfinx.fem.form(
            ufl.derivative(residual(self.d), self.u, w), form_compiler_params=fcp
        )
        self.a = dolfinx.fem.form(
            ufl.derivative(residual(self.R * w), self.u, du), form_compiler_params=fcp
        )
        #: Frame conditions: c_k · ũ = ∫ρ ũ_k (k < 3), ∫ρ (Y × ũ)_k (k ≥ 3), compiled.
        self.mean_axes = [dolfinx.fem.form(f) for f in mean_axes_forms(rho, self.Y, w, dx)]
        self._stress_measures(mesh, material, dx)

    def positions(self, x_g: np.ndarray, R: np.ndarray) -> np.ndarray:
        """Inertial nodal positions x = x_G + R(Y + ũ) (m), local + ghost nodes, (n, 3).

        Args:
            x_g: centre of mass (m).
            R: rotation body → inertial frame.
        """
        return x_g + (self.Y_nodes + self.u.x.array.reshape(-1, 3)) @ R.T

    def _stress_measures(self, mesh: dolfinx.mesh.Mesh, material: Hyperelastic, dx) -> None:
        """Strain energy and von Mises stress of ũ in the body frame (frame invariant)."""
        F_body = kinematics.deformation_gradient(self.u)
        C_body = kinematics.right_cauchy_green(F_body)
        #: ∫W(E(ũ)) (J), compiled.
        self.strain_energy = dolfinx.fem.form(material.strain_energy(C_body) * dx)
        S = material.second_piola(C_body)
        Q0 = dolfinx.fem.FunctionSpace(mesh, ("DG", 0))
        self.von_mises = dolfinx.fem.Function(Q0, name="von_mises")
        #: The von Mises stress of S (Pa), to interpolate into :attr:`von_mises`.
        self.von_mises_expr = dolfinx.fem.Expression(
            materials.von_mises(S), Q0.element.interpolation_points()
        )
