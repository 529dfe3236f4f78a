"""Constitutive laws under homogeneous deformations, against hand calculations.

A homogeneous deformation x = F X is interpolated exactly (P1) on a unit cube; the energy density
is the assembled energy divided by the assembled volume, and a stress component S_ij is the
assembled inner(S, K) with K = e_i (x) e_j, divided by the volume. Every assembled scalar is
summed over ranks, so the tests give the same numbers on 1 and 2 ranks.

Tolerances: the integrands are constant per cell, so quadrature is exact and the only error is
rounding: a few ulp per operation, summed over the 48 cells of the mesh, and amplified by the
cancellations inside the laws (I1bar - 3, ln J) that act on terms of the size of the modulus.
Hence an absolute tolerance ``ROUNDING * scale`` with ``ROUNDING = 100 * eps`` (about 2e-14) and
``scale`` the modulus or the expected value, whichever is larger (observed: below 8 eps).
"""

from __future__ import annotations

import dolfinx
import numpy as np
import pytest
import ufl
from mpi4py import MPI
from petsc4py import PETSc

from shoulder_fem.forms import (
    BONE_E0,
    BONE_NU,
    BONE_RHO0,
    LinearElastic,
    NeoHookean,
    SaintVenantKirchhoff,
    VerondaWestmann,
    bone_modulus,
    deformation_gradient,
    linear_strain,
    right_cauchy_green,
)

EPS = np.finfo(PETSc.ScalarType).eps
ROUNDING = 100 * EPS
I3 = np.eye(3)


def rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation matrix about ``axis`` by ``angle`` (rad), Rodrigues' formula."""
    n = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    K = np.array([[0, -n[2], n[1]], [n[2], 0, -n[0]], [-n[1], n[0], 0]])
    return I3 + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def uniaxial_isochoric(s: float) -> np.ndarray:
    """F = diag(s, s^-1/2, s^-1/2), det F = 1."""
    return np.diag([s, s**-0.5, s**-0.5])


def simple_shear(gamma: float) -> np.ndarray:
    """F = I + gamma e1 (x) e2."""
    F = I3.copy()
    F[0, 1] = gamma
    return F


class HomogeneousProbe:
    """Energy density and stress of one material under a homogeneous deformation F (assembled)."""

    def __init__(self, material, mesh: dolfinx.mesh.Mesh, V: dolfinx.fem.FunctionSpace):
        self.comm = mesh.comm
        self.u = dolfinx.fem.Function(V)
        self.K = dolfinx.fem.Constant(mesh, PETSc.ScalarType(np.zeros((3, 3))))
        dx = ufl.dx(domain=mesh)
        if isinstance(material, LinearElastic):
            eps = linear_strain(self.u)
            energy, stress = material.strain_energy_density(eps), material.stress(eps)
        else:
            C = right_cauchy_green(deformation_gradient(self.u))
            energy, stress = material.strain_energy(C), material.second_piola(C)
        self.energy_form = dolfinx.fem.form(energy * dx)
        self.stress_form = dolfinx.fem.form(ufl.inner(stress, self.K) * dx)
        one = dolfinx.fem.Constant(mesh, PETSc.ScalarType(1.0))
        self.volume = self._assemble(dolfinx.fem.form(one * dx))

    def _assemble(self, form) -> float:
        return self.comm.allreduce(dolfinx.fem.assemble_scalar(form), op=MPI.SUM)

    def deform(self, F: np.ndarray) -> None:
        """Set u = (F - I) X, exact in P1."""
        self.u.interpolate(lambda x: (F - I3) @ x)

    def energy(self, F: np.ndarray) -> float:
        """Energy density, J/m^3."""
        self.deform(F)
        return self._assemble(self.energy_form) / self.volume

    def stress(self, F: np.ndarray) -> np.ndarray:
        """Stress tensor (S for hyperelastic laws, sigma for LinearElastic), Pa."""
        self.deform(F)
        out = np.zeros((3, 3))
        for i in range(3):
            for j in range(3):
                self.K.value[:] = np.outer(I3[i], I3[j])
                out[i, j] = self._assemble(self.stress_form) / self.volume
        return out


@pytest.fixture(scope="module")
def cube():
    """Unit cube, 2x2x2x6 tetrahedra, P1 vector space."""
    mesh = dolfinx.mesh.create_unit_cube(MPI.COMM_WORLD, 2, 2, 2)
    return mesh, dolfinx.fem.VectorFunctionSpace(mesh, ("CG", 1))


def assert_close(actual, expected, scale: float) -> None:
    """Equal up to rounding, relative to ``scale`` (a modulus) or to the expected value."""
    scale = max(scale, float(np.max(np.abs(expected))))
    np.testing.assert_allclose(actual, expected, rtol=0, atol=ROUNDING * scale)


# --- Hand calculations ------------------------------------------------------------------------

# Simple numbers: E = 2.6 Pa, nu = 0.3 give lmbda = 2.6*0.3/(1.3*0.4) = 1.5 Pa and mu = 1 Pa.
LMBDA, MU = 1.5, 1.0


def nearly_incompressible_S(F, W1, W2, dU):
    """Textbook S of W = What(I1bar, I2bar) + U(J) (Holzapfel, Nonlinear Solid Mechanics, 6.5).

    S = J^(-2/3) DEV[Sbar] + J U'(J) C^-1, Sbar = 2 (W1 + I1bar W2) I - 2 W2 Cbar,
    DEV[A] = A - (A:C)/3 C^-1; W1, W2 = dWhat/dI1bar, dWhat/dI2bar; dU = U'(J).
    """
    C = F.T @ F
    J = np.linalg.det(F)
    Cbar = J ** (-2 / 3) * C
    Cinv = np.linalg.inv(C)
    Sbar = 2 * (W1 + np.trace(Cbar) * W2) * I3 - 2 * W2 * Cbar
    dev = Sbar - np.sum(Sbar * C) / 3 * Cinv
    return J ** (-2 / 3) * dev + J * dU * Cinv


def isochoric_invariants_np(F):
    """(I1bar, I2bar, J) of C = F^T F."""
    C = F.T @ F
    J = np.linalg.det(F)
    i1, i2 = np.trace(C), (np.trace(C) ** 2 - np.trace(C @ C)) / 2
    return J ** (-2 / 3) * i1, J ** (-4 / 3) * i2, J


def case_linear_elastic():
    """Linear elasticity under a small uniaxial strain plus shear."""
    # eps = [[a, g, 0], [g, 0, 0], [0, 0, 0]] (u = eps X, grad u symmetric):
    # W = mu (a^2 + 2 g^2) + lmbda/2 a^2; sigma_11 = (lmbda + 2 mu) a, sigma_22 = sigma_33 =
    # lmbda a, sigma_12 = sigma_21 = 2 mu g.
    a, g = 1e-3, 2e-3
    F = I3 + np.array([[a, g, 0], [g, 0, 0], [0, 0, 0]])
    W = MU * (a**2 + 2 * g**2) + LMBDA / 2 * a**2
    sigma = np.array(
        [[(LMBDA + 2 * MU) * a, 2 * MU * g, 0], [2 * MU * g, LMBDA * a, 0], [0, 0, LMBDA * a]]
    )
    return LinearElastic(2.6, 0.3), F, W, sigma


def case_svk_uniaxial():
    """Saint Venant-Kirchhoff under a uniaxial stretch of 1.5."""
    # F = diag(s, 1, 1): E = diag(e, 0, 0) with e = (s^2 - 1)/2 = 0.625 for s = 1.5.
    # W = lmbda/2 e^2 + mu e^2 = 1.75 * 0.390625 = 0.68359375;
    # S = diag((lmbda + 2 mu) e, lmbda e, lmbda e) = diag(2.1875, 0.9375, 0.9375).
    s = 1.5
    e = (s**2 - 1) / 2
    return (
        SaintVenantKirchhoff(2.6, 0.3),
        np.diag([s, 1, 1]),
        (LMBDA / 2 + MU) * e**2,
        np.diag([(LMBDA + 2 * MU) * e, LMBDA * e, LMBDA * e]),
    )


def case_svk_shear():
    """Saint Venant-Kirchhoff under a simple shear of 0.5."""
    # F = I + g e1 (x) e2: C = [[1, g, 0], [g, 1 + g^2, 0], [0, 0, 1]],
    # E = [[0, g/2, 0], [g/2, g^2/2, 0], [0, 0, 0]], tr E = g^2/2, E:E = g^2/2 + g^4/4.
    # W = lmbda/2 (g^2/2)^2 + mu (g^2/2 + g^4/4); S = lmbda g^2/2 I + 2 mu E.
    g = 0.5
    E = np.array([[0, g / 2, 0], [g / 2, g**2 / 2, 0], [0, 0, 0]])
    W = LMBDA / 2 * (g**2 / 2) ** 2 + MU * (g**2 / 2 + g**4 / 4)
    return SaintVenantKirchhoff(2.6, 0.3), simple_shear(g), W, LMBDA * g**2 / 2 * I3 + 2 * MU * E


def case_nh_dilatation():
    """Neo-Hookean under a pure dilatation of 1.1."""
    # F = d I: J = d^3, I1bar = 3, so W = kappa/2 (3 ln d)^2;
    # S = kappa ln J C^-1 = kappa 3 ln d / d^2 I (isochoric part vanishes).
    c10, kappa, d = 1.79e6, 16.7e6, 1.1
    return (
        NeoHookean(c10, kappa),
        d * I3,
        kappa / 2 * (3 * np.log(d)) ** 2,
        kappa * 3 * np.log(d) / d**2 * I3,
    )


def case_nh_uniaxial():
    """Neo-Hookean under an isochoric uniaxial stretch of 1.2."""
    # F = diag(s, s^-1/2, s^-1/2), J = 1: I1bar = s^2 + 2/s, W = C10 (s^2 + 2/s - 3);
    # S = 2 C10 (I - I1/3 C^-1), C^-1 = diag(s^-2, s, s):
    # S_11 = 2 C10 (1 - I1/(3 s^2)), S_22 = S_33 = 2 C10 (1 - I1 s/3).
    c10, kappa, s = 1.79e6, 16.7e6, 1.2
    i1 = s**2 + 2 / s
    S = 2 * c10 * np.diag([1 - i1 / (3 * s**2), 1 - i1 * s / 3, 1 - i1 * s / 3])
    return NeoHookean(c10, kappa), uniaxial_isochoric(s), c10 * (i1 - 3), S


def case_nh_general():
    """Neo-Hookean under a simple shear combined with a dilatation."""
    # F = d R_shear: isochoric simple shear (I1bar = 3 + g^2) times a dilatation d.
    # W = C10 g^2 + kappa/2 (3 ln d)^2; S from the textbook split with W1 = C10, W2 = 0,
    # U'(J) = kappa ln J / J.
    c10, kappa, d, g = 1.79e6, 16.7e6, 0.95, 0.4
    F = d * simple_shear(g)
    J = d**3
    S = nearly_incompressible_S(F, c10, 0.0, kappa * np.log(J) / J)
    return NeoHookean(c10, kappa), F, c10 * g**2 + kappa / 2 * np.log(J) ** 2, S


def case_vw_uniaxial():
    """Veronda-Westmann under an isochoric uniaxial stretch of 1.3."""
    # F = diag(s, s^-1/2, s^-1/2), J = 1: b = diag(s^2, 1/s, 1/s), I1 = s^2 + 2/s,
    # I2 = 2 s + s^-2. W = alpha (exp(beta (I1 - 3)) - 1) - alpha beta/2 (I2 - 3).
    # W1 = alpha beta exp(beta (I1 - 3)), W2 = -alpha beta/2; the Cauchy stress is
    # sigma = 2 dev[(W1 + I1 W2) b - W2 b^2] (ln J = 0: no volumetric stress), S = F^-1 sigma F^-T.
    alpha, beta, kappa, s = 0.12e6, 1.0, 5.96e6, 1.3
    i1, i2 = s**2 + 2 / s, 2 * s + s**-2
    W1, W2 = alpha * beta * np.exp(beta * (i1 - 3)), -alpha * beta / 2
    b = np.diag([s**2, 1 / s, 1 / s])
    A = (W1 + i1 * W2) * b - W2 * b @ b
    sigma = 2 * (A - np.trace(A) / 3 * I3)
    Finv = np.linalg.inv(uniaxial_isochoric(s))
    W = alpha * (np.exp(beta * (i1 - 3)) - 1) - alpha * beta / 2 * (i2 - 3)
    return VerondaWestmann(alpha, beta, kappa), uniaxial_isochoric(s), W, Finv @ sigma @ Finv.T


def case_vw_general():
    """Veronda-Westmann under stretch, shear and dilatation combined."""
    # F = d F_iso with F_iso = shear(g) diag(s, s^-1/2, s^-1/2) (det F_iso = 1), J = d^3.
    # W = alpha (exp(beta (I1bar - 3)) - 1) - alpha beta/2 (I2bar - 3) + kappa/2 (ln J)^2, with
    # the invariants of F_iso; S from the textbook split with W1 = alpha beta exp(beta (I1bar-3)),
    # W2 = -alpha beta/2, U'(J) = kappa ln J / J.
    alpha, beta, kappa, d, g, s = 0.12e6, 1.5, 5.96e6, 1.05, 0.3, 0.9
    F = d * simple_shear(g) @ uniaxial_isochoric(s)
    i1, i2, J = isochoric_invariants_np(F)
    W1, W2 = alpha * beta * np.exp(beta * (i1 - 3)), -alpha * beta / 2
    W = (
        alpha * (np.exp(beta * (i1 - 3)) - 1)
        - alpha * beta / 2 * (i2 - 3)
        + kappa / 2 * np.log(J) ** 2
    )
    S = nearly_incompressible_S(F, W1, W2, kappa * np.log(J) / J)
    return VerondaWestmann(alpha, beta, kappa), F, W, S


CASES = {
    "linear-elastic": case_linear_elastic,
    "svk-uniaxial": case_svk_uniaxial,
    "svk-shear": case_svk_shear,
    "neo-hookean-dilatation": case_nh_dilatation,
    "neo-hookean-uniaxial": case_nh_uniaxial,
    "neo-hookean-shear-dilatation": case_nh_general,
    "veronda-westmann-uniaxial": case_vw_uniaxial,
    "veronda-westmann-general": case_vw_general,
}


def modulus(material) -> float:
    """Largest small-strain modulus of a law, Pa (the scale of its rounding errors)."""
    return float(max(material.small_strain_moduli()))


@pytest.mark.mpi
@pytest.mark.parametrize("name", CASES)
def test_homogeneous_energy_and_stress(cube, name):
    """Assembled energy density and stress match the hand calculation."""
    material, F, W, S = CASES[name]()
    probe = HomogeneousProbe(material, *cube)
    assert_close(probe.energy(F), W, modulus(material))
    assert_close(probe.stress(F), S, modulus(material))


HYPERELASTIC = {
    "svk": SaintVenantKirchhoff(2.6, 0.3),
    "neo-hookean": NeoHookean.cartilage(),
    "veronda-westmann": VerondaWestmann.muscle(),
}
# A general deformation (stretch, shear and a 3 % volume change) and a large rotation.
F_GENERAL = np.array([[1.10, 0.20, 0.05], [-0.10, 0.95, 0.15], [0.02, 0.10, 1.02]])
R_LARGE = rotation([1.0, 2.0, 3.0], np.deg2rad(100.0))


@pytest.mark.mpi
@pytest.mark.parametrize("name", HYPERELASTIC)
def test_objectivity(cube, name):
    """A superposed rigid rotation changes neither W nor S."""
    # W(R F) = W(F) and S(R F) = S(F): C = F^T R^T R F = F^T F.
    material = HYPERELASTIC[name]
    probe = HomogeneousProbe(material, *cube)
    assert_close(probe.energy(R_LARGE @ F_GENERAL), probe.energy(F_GENERAL), modulus(material))
    assert_close(probe.stress(R_LARGE @ F_GENERAL), probe.stress(F_GENERAL), modulus(material))


@pytest.mark.mpi
def test_linear_elastic_is_not_objective(cube):
    """Small-strain energy of a large rigid rotation is not zero."""
    # A 90 degree rotation about z, F = R: eps = sym(R - I) = diag(-1, -1, 0), so
    # W = mu (1 + 1) + lmbda/2 (-2)^2 = 2 + 3 = 5 Pa, although the body is not strained.
    probe = HomogeneousProbe(LinearElastic(2.6, 0.3), *cube)
    assert_close(probe.energy(rotation([0, 0, 1], np.pi / 2)), 2 * MU + 2 * LMBDA, MU)


@pytest.mark.mpi
@pytest.mark.parametrize("name", HYPERELASTIC)
def test_small_strain_limit(cube, name):
    """At 1e-6 strain S equals the linear stress of small_strain_moduli()."""
    # F = I + h G with h = 1e-6: S = 2 mu eps + (kappa - 2 mu/3) tr(eps) I + O(h^2 modulus),
    # eps = h sym(G). The O(h^2) remainder is a relative error of about h times the law's
    # nonlinearity constants (<= 10 here); rounding acting on terms of the size of the modulus
    # is amplified by 1/h relative to the signal. Hence rtol = 10 h + ROUNDING / h.
    h = 1e-6
    G = np.array([[0.3, -0.8, 0.5], [0.4, -0.2, 0.7], [-0.6, 0.1, 0.5]])
    material = HYPERELASTIC[name]
    mu, kappa = material.small_strain_moduli()
    eps = h * (G + G.T) / 2
    sigma = 2 * mu * eps + (kappa - 2 * mu / 3) * np.trace(eps) * I3
    S = HomogeneousProbe(material, *cube).stress(I3 + h * G)
    scale = np.max(np.abs(sigma))
    np.testing.assert_allclose(S, sigma, rtol=0, atol=(10 * h + ROUNDING / h) * scale)


def test_moduli_from_young():
    """NeoHookean.from_young recovers the small-strain E and nu."""
    # C10 = E/(4(1+nu)) = mu/2 and kappa = E/(3(1-2nu)): the linear moduli come back.
    E, nu = 10e6, 0.4
    mu, kappa = NeoHookean.from_young(E, nu).small_strain_moduli()
    assert mu == pytest.approx(E / (2 * (1 + nu)), rel=4 * EPS)
    assert kappa == pytest.approx(E / (3 * (1 - 2 * nu)), rel=4 * EPS)


def test_tissue_parameters():
    """Cartilage and muscle parameters are the paper's."""
    # Cartilage (paper, Table I): C10 = 1.79 MPa, kappa = 10 MPa / (3 * 0.2) = 16.67 MPa.
    cartilage = NeoHookean.cartilage()
    assert cartilage.c10 == 1.79e6
    assert cartilage.bulk_modulus == pytest.approx(10e6 / 0.6, rel=4 * EPS)
    # Muscle: alpha = 0.12 MPa, beta = 1, mu = alpha beta; kappa chosen for nu = 0.49,
    # nu = (3 kappa - 2 mu) / (2 (3 kappa + mu)).
    muscle = VerondaWestmann.muscle()
    mu, kappa = muscle.small_strain_moduli()
    assert (muscle.alpha, muscle.beta, mu) == (0.12e6, 1.0, 0.12e6)
    assert (3 * kappa - 2 * mu) / (2 * (3 * kappa + mu)) == pytest.approx(0.49, rel=16 * EPS)


def test_bone_modulus_numbers_and_arrays():
    """bone_modulus on floats and numpy arrays."""
    # E = E0 (rho/rho0)^2: rho0 gives E0, rho0/2 gives E0/4.
    assert bone_modulus(BONE_RHO0) == BONE_E0
    np.testing.assert_allclose(
        bone_modulus(np.array([0.0, BONE_RHO0 / 2, BONE_RHO0])),
        [0.0, BONE_E0 / 4, BONE_E0],
        rtol=4 * EPS,
    )
    assert BONE_NU == 0.3


@pytest.mark.mpi
def test_bone_modulus_ufl_field(cube):
    """bone_modulus on a UFL density, used as a LinearElastic modulus."""
    # A UFL density gives a UFL modulus, accepted unchecked by LinearElastic; its mean over the
    # unit cube for rho = 1200 kg/m^3 is 15 GPa * (1200/1800)^2 = 6.667 GPa.
    mesh, _ = cube
    rho = dolfinx.fem.Constant(mesh, PETSc.ScalarType(1200.0))
    E = bone_modulus(rho)
    LinearElastic(E, BONE_NU)
    dx = ufl.dx(domain=mesh)
    value = mesh.comm.allreduce(dolfinx.fem.assemble_scalar(dolfinx.fem.form(E * dx)), MPI.SUM)
    # The unit cube has volume 1 m^3 (exactly, up to rounding).
    assert value == pytest.approx(BONE_E0 * (1200 / 1800) ** 2, rel=ROUNDING)


@pytest.mark.parametrize(
    ("make", "name", "unit"),
    [
        (lambda: LinearElastic(-1.0, 0.3), "youngs_modulus", "Pa"),
        (lambda: LinearElastic(1e9, 0.5), "poisson_ratio", "dimensionless"),
        (lambda: LinearElastic(1e9, -1.2), "poisson_ratio", "dimensionless"),
        (lambda: SaintVenantKirchhoff(0.0, 0.3), "youngs_modulus", "Pa"),
        (lambda: SaintVenantKirchhoff(1e9, 0.7), "poisson_ratio", "dimensionless"),
        (lambda: NeoHookean(-1.0, 1e6), "c10", "Pa"),
        (lambda: NeoHookean(1e6, float("nan")), "bulk_modulus", "Pa"),
        (lambda: NeoHookean.from_young(10e6, 0.5), "poisson_ratio", "dimensionless"),
        (lambda: NeoHookean.from_young(-10e6, 0.4), "youngs_modulus", "Pa"),
        (lambda: VerondaWestmann(-0.12e6, 1.0, 6e6), "alpha", "Pa"),
        (lambda: VerondaWestmann(0.12e6, 0.0, 6e6), "beta", "dimensionless"),
        (lambda: VerondaWestmann(0.12e6, 1.0, -6e6), "bulk_modulus", "Pa"),
        (lambda: bone_modulus(-5.0), "density", "kg/m^3"),
        (lambda: bone_modulus(np.array([1.0, -5.0])), "density", "kg/m^3"),
        (lambda: bone_modulus(1000.0, e0=0.0), "e0", "Pa"),
        (lambda: bone_modulus(1000.0, rho0=-1.0), "rho0", "kg/m^3"),
    ],
)
def test_parameter_validation(make, name, unit):
    """Invalid numeric parameters raise ValueError naming parameter and unit."""
    with pytest.raises(ValueError, match=name) as info:
        make()
    assert unit in str(info.value)


def test_von_mises_by_hand():
    """Uniaxial σ = diag(100, 0, 0) Pa: von Mises = 100 Pa; pure shear τ = 10 Pa: √3 τ."""
    import dolfinx
    from mpi4py import MPI

    from shoulder_fem.forms.materials import von_mises

    mesh = dolfinx.mesh.create_unit_cube(MPI.COMM_SELF, 1, 1, 1)
    dx = ufl.dx(domain=mesh)
    for sigma, expected in (
        (ufl.as_matrix([[100.0, 0, 0], [0, 0, 0], [0, 0, 0]]), 100.0),
        (ufl.as_matrix([[0, 10.0, 0], [10.0, 0, 0], [0, 0, 0]]), 10.0 * 3**0.5),
    ):
        value = dolfinx.fem.assemble_scalar(dolfinx.fem.form(von_mises(sigma) * dx))
        assert value == pytest.approx(expected, rel=1e-12)
