"""Constitutive laws: one small frozen dataclass per law, stresses derived with UFL.

Units are SI: moduli and stresses in Pa, strain energies per unit reference volume in J/m^3 (= Pa),
densities in kg/m^3; strains, stretches and Poisson's ratios are dimensionless.

Laws and where they are used (paper, Table I):

* :class:`LinearElastic` -- bone, small strain, with the density-dependent modulus
  :func:`bone_modulus` (E = E0 (rho/rho0)^2, nu = 0.3).
* :class:`SaintVenantKirchhoff` -- the same law at finite strain (Green-Lagrange strain), for the
  coupled method's deformable bones.
* :class:`NeoHookean` -- cartilage, nearly incompressible.
* :class:`VerondaWestmann` -- passive muscle, nearly incompressible, exponential.

The nearly incompressible laws split the energy into an isochoric part, a function of the
isochoric invariants (I1bar, I2bar), and the volumetric part U(J) = kappa/2 (ln J)^2. The
logarithmic form was chosen over kappa/2 (J - 1)^2 because it grows without bound as J -> 0, so a
strongly compressed element cannot invert at finite energy. Both give the same small-strain
bulk modulus kappa.

Every hyperelastic law exposes ``strain_energy(C)``, ``second_piola(C)`` = 2 dW/dC (by
``ufl.variable`` + ``ufl.diff``), ``first_piola(F)`` = F S and ``small_strain_moduli()``.
Parameters that are plain numbers are checked on construction; a UFL expression (e.g. a
spatially varying modulus) is accepted as it is.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass

import numpy as np
import ufl

from .kinematics import isochoric_invariants, right_cauchy_green

__all__ = [
    "BONE_E0",
    "BONE_NU",
    "BONE_RHO0",
    "CARTILAGE_C10",
    "CARTILAGE_NU",
    "CARTILAGE_YOUNGS_MODULUS",
    "MUSCLE_ALPHA",
    "MUSCLE_BETA",
    "MUSCLE_NU",
    "Hyperelastic",
    "Isochoric",
    "LinearElastic",
    "NeoHookean",
    "SaintVenantKirchhoff",
    "Scalar",
    "VerondaWestmann",
    "bone_modulus",
    "von_mises",
]

Scalar = float | ufl.core.expr.Expr
"""A material parameter: a plain number or a UFL scalar expression (Constant, Function, ...)."""

BONE_E0 = 15e9
"""Reference Young's modulus of bone at density BONE_RHO0, Pa (paper: 15 000 MPa)."""
BONE_RHO0 = 1800.0
"""Reference apparent density of bone, kg/m^3 (paper: 1.8 g/cm^3)."""
BONE_NU = 0.3
"""Poisson's ratio of bone, dimensionless."""

CARTILAGE_C10 = 1.79e6
"""Neo-Hookean C10 of cartilage, Pa (paper: 1.79 MPa, from E = 10 MPa and nu = 0.4)."""
CARTILAGE_YOUNGS_MODULUS = 10e6
"""Small-strain Young's modulus of cartilage, Pa."""
CARTILAGE_NU = 0.4
"""Small-strain Poisson's ratio of cartilage, dimensionless."""

MUSCLE_ALPHA = 0.12e6
"""Veronda-Westmann alpha of passive muscle, Pa (paper: 0.12 MPa)."""
MUSCLE_BETA = 1.0
"""Veronda-Westmann beta of passive muscle, dimensionless (paper: 1.0)."""
MUSCLE_NU = 0.49
"""Small-strain Poisson's ratio used to choose the muscle bulk modulus (our choice; the paper
treats muscle as incompressible)."""


def _is_number(value: object) -> bool:
    """Whether a parameter is a plain real number (and so can be checked)."""
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def _check_positive(name: str, value: object, unit: str) -> None:
    """Raise ValueError if a plain-number parameter is not > 0 (NaN included)."""
    if _is_number(value) and not value > 0:
        raise ValueError(f"{name} must be > 0 {unit}, got {value!r} {unit}")


def _check_poisson(name: str, value: object) -> None:
    """Raise ValueError if a plain-number Poisson's ratio is outside (-1, 0.5)."""
    if _is_number(value) and not -1.0 < value < 0.5:
        raise ValueError(f"{name} must lie in (-1, 0.5) (dimensionless), got {value!r}")


def _lame(youngs_modulus: Scalar, poisson_ratio: Scalar) -> tuple[Scalar, Scalar]:
    """Lame constants (lmbda, mu) in Pa from Young's modulus (Pa) and Poisson's ratio."""
    E, nu = youngs_modulus, poisson_ratio
    lmbda = E * nu / ((1 + nu) * (1 - 2 * nu))
    mu = E / (2 * (1 + nu))
    return lmbda, mu


def _volumetric_energy(bulk_modulus: Scalar, J: ufl.core.expr.Expr) -> ufl.core.expr.Expr:
    """Volumetric strain energy U(J) = kappa/2 (ln J)^2, J/m^3."""
    return bulk_modulus / 2 * ufl.ln(J) ** 2


def bone_modulus(
    density: float | np.ndarray | ufl.core.expr.Expr,
    e0: float = BONE_E0,
    rho0: float = BONE_RHO0,
) -> float | np.ndarray | ufl.core.expr.Expr:
    """Young's modulus of bone from its apparent density, E = E0 (rho/rho0)^2 (paper, Table I).

    Args:
        density: Apparent density rho in kg/m^3: a number, a numpy array, or a UFL expression
            (e.g. a DG0 Function read from CT data).
        e0: Modulus E0 at the reference density, Pa.
        rho0: Reference density rho0, kg/m^3.

    Returns:
        E in Pa, of the same kind as ``density``.

    Raises:
        ValueError: If a numeric density is negative or e0, rho0 are not positive.
    """
    _check_positive("e0", e0, "Pa")
    _check_positive("rho0", rho0, "kg/m^3")
    if _is_number(density) or isinstance(density, np.ndarray):
        if np.any(np.asarray(density) < 0) or np.any(np.isnan(density)):
            raise ValueError(f"density must be >= 0 kg/m^3, got {density!r} kg/m^3")
    return e0 * (density / rho0) ** 2


class Hyperelastic:
    """Stresses shared by every hyperelastic law, derived from ``strain_energy(C)``.

    Subclasses define ``strain_energy(C)`` (J/m^3, per unit reference volume) and
    ``small_strain_moduli()``.
    """

    def strain_energy(self, C: ufl.core.expr.Expr) -> ufl.core.expr.Expr:
        """Strain energy density W(C), J/m^3 per unit reference volume."""
        raise NotImplementedError

    def small_strain_moduli(self) -> tuple[Scalar, Scalar]:
        """(shear modulus, bulk modulus) of the law linearised at C = I, Pa."""
        raise NotImplementedError

    def second_piola(self, C: ufl.core.expr.Expr) -> ufl.core.expr.Expr:
        """Second Piola-Kirchhoff stress S = 2 dW/dC, Pa.

        Args:
            C: Right Cauchy-Green tensor, dimensionless.
        """
        C = ufl.variable(C)
        return 2 * ufl.diff(self.strain_energy(C), C)

    def first_piola(self, F: ufl.core.expr.Expr) -> ufl.core.expr.Expr:
        """First Piola-Kirchhoff stress P = F S, Pa (force per unit reference area).

        Args:
            F: Deformation gradient, dimensionless.
        """
        return F * self.second_piola(right_cauchy_green(F))


@dataclass(frozen=True)
class _YoungPoisson:
    """Isotropic moduli given as Young's modulus and Poisson's ratio (checked on creation).

    Attributes:
        youngs_modulus: E in Pa; a number or a UFL field such as ``bone_modulus(rho)``.
        poisson_ratio: nu, dimensionless, in (-1, 0.5).
    """

    youngs_modulus: Scalar
    poisson_ratio: Scalar

    def __post_init__(self) -> None:
        _check_positive("youngs_modulus", self.youngs_modulus, "Pa")
        _check_poisson("poisson_ratio", self.poisson_ratio)

    def lame(self) -> tuple[Scalar, Scalar]:
        """Lame constants (lmbda, mu), Pa."""
        return _lame(self.youngs_modulus, self.poisson_ratio)

    def small_strain_moduli(self) -> tuple[Scalar, Scalar]:
        """(shear modulus mu, bulk modulus lmbda + 2 mu/3), Pa."""
        lmbda, mu = self.lame()
        return mu, lmbda + 2 * mu / 3


@dataclass(frozen=True)
class LinearElastic(_YoungPoisson):
    """Isotropic linear elasticity (small strain): sigma = lmbda tr(eps) I + 2 mu eps.

    Attributes:
        youngs_modulus: E in Pa; a number or a UFL field such as ``bone_modulus(rho)``.
        poisson_ratio: nu, dimensionless, in (-1, 0.5).
    """

    def stress(self, eps: ufl.core.expr.Expr) -> ufl.core.expr.Expr:
        """Cauchy stress sigma(eps), Pa.

        Args:
            eps: Infinitesimal strain tensor, dimensionless.
        """
        lmbda, mu = self.lame()
        return lmbda * ufl.tr(eps) * ufl.Identity(ufl.shape(eps)[0]) + 2 * mu * eps

    def strain_energy_density(self, eps: ufl.core.expr.Expr) -> ufl.core.expr.Expr:
        """Strain energy density mu eps:eps + lmbda/2 (tr eps)^2, J/m^3.

        Args:
            eps: Infinitesimal strain tensor, dimensionless.
        """
        lmbda, mu = self.lame()
        return mu * ufl.inner(eps, eps) + lmbda / 2 * ufl.tr(eps) ** 2


@dataclass(frozen=True)
class SaintVenantKirchhoff(_YoungPoisson, Hyperelastic):
    """Saint Venant-Kirchhoff: the linear law written in the Green-Lagrange strain E.

    W = lmbda/2 (tr E)^2 + mu E:E. Valid for large rotations with small strains.

    Attributes:
        youngs_modulus: E in Pa; a number or a UFL field.
        poisson_ratio: nu, dimensionless, in (-1, 0.5).
    """

    def strain_energy(self, C: ufl.core.expr.Expr) -> ufl.core.expr.Expr:
        """W(C) = lmbda/2 (tr E)^2 + mu E:E with E = (C - I)/2, J/m^3."""
        lmbda, mu = self.lame()
        E = (C - ufl.Identity(ufl.shape(C)[0])) / 2
        return lmbda / 2 * ufl.tr(E) ** 2 + mu * ufl.inner(E, E)


@dataclass(frozen=True)
class NeoHookean(Hyperelastic):
    """Nearly incompressible neo-Hookean law (cartilage).

    W = C10 (I1bar - 3) + kappa/2 (ln J)^2. Small-strain shear modulus 2 C10, bulk modulus kappa.

    Attributes:
        c10: C10 in Pa.
        bulk_modulus: kappa in Pa.
    """

    c10: Scalar
    bulk_modulus: Scalar

    def __post_init__(self) -> None:
        _check_positive("c10", self.c10, "Pa")
        _check_positive("bulk_modulus", self.bulk_modulus, "Pa")

    @classmethod
    def from_young(cls, youngs_modulus: float, poisson_ratio: float) -> NeoHookean:
        """Law matching a small-strain (E, nu): C10 = E/(4(1+nu)), kappa = E/(3(1-2nu)).

        Args:
            youngs_modulus: E in Pa.
            poisson_ratio: nu, dimensionless, in (-1, 0.5).
        """
        _check_positive("youngs_modulus", youngs_modulus, "Pa")
        _check_poisson("poisson_ratio", poisson_ratio)
        E, nu = youngs_modulus, poisson_ratio
        return cls(c10=E / (4 * (1 + nu)), bulk_modulus=E / (3 * (1 - 2 * nu)))

    @classmethod
    def cartilage(cls) -> NeoHookean:
        """Cartilage of the paper: C10 = 1.79 MPa, kappa = E/(3(1-2nu)) = 16.7 MPa.

        kappa comes from E = 10 MPa, nu = 0.4; C10 is the paper's rounded 1.79 MPa
        (E/(4(1+nu)) = 1.786 MPa).
        """
        E, nu = CARTILAGE_YOUNGS_MODULUS, CARTILAGE_NU
        return cls(c10=CARTILAGE_C10, bulk_modulus=E / (3 * (1 - 2 * nu)))

    def small_strain_moduli(self) -> tuple[Scalar, Scalar]:
        """(shear modulus 2 C10, bulk modulus kappa), Pa."""
        return 2 * self.c10, self.bulk_modulus

    def isochoric_energy(self, C: ufl.core.expr.Expr) -> ufl.core.expr.Expr:
        """The isochoric part C10 (I1bar - 3), J/m^3."""
        i1bar, _, _ = isochoric_invariants(C)
        return self.c10 * (i1bar - 3)

    def strain_energy(self, C: ufl.core.expr.Expr) -> ufl.core.expr.Expr:
        """W(C) = C10 (I1bar - 3) + kappa/2 (ln J)^2, J/m^3."""
        _, _, J = isochoric_invariants(C)
        return self.isochoric_energy(C) + _volumetric_energy(self.bulk_modulus, J)


@dataclass(frozen=True)
class VerondaWestmann(Hyperelastic):
    """Nearly incompressible Veronda-Westmann law (passive muscle).

    W = alpha (exp[beta (I1bar - 3)] - 1) - alpha beta/2 (I2bar - 3) + kappa/2 (ln J)^2.
    Small-strain shear modulus alpha beta (2 (dW/dI1bar + dW/dI2bar) at C = I), bulk modulus
    kappa. The paper's form has no "- 1", which only shifts W by a constant.

    Attributes:
        alpha: alpha in Pa.
        beta: beta, dimensionless.
        bulk_modulus: kappa in Pa.
    """

    alpha: Scalar
    beta: Scalar
    bulk_modulus: Scalar

    def __post_init__(self) -> None:
        _check_positive("alpha", self.alpha, "Pa")
        _check_positive("beta", self.beta, "(dimensionless)")
        _check_positive("bulk_modulus", self.bulk_modulus, "Pa")

    @classmethod
    def muscle(cls) -> VerondaWestmann:
        """Passive muscle of the paper: alpha = 0.12 MPa, beta = 1.0, kappa = 5.96 MPa.

        kappa is our choice: the bulk modulus that gives a small-strain Poisson's ratio
        nu = 0.49 with mu = alpha beta = 0.12 MPa, kappa = 2 mu (1 + nu)/(3 (1 - 2 nu)).
        """
        mu, nu = MUSCLE_ALPHA * MUSCLE_BETA, MUSCLE_NU
        kappa = 2 * mu * (1 + nu) / (3 * (1 - 2 * nu))
        return cls(alpha=MUSCLE_ALPHA, beta=MUSCLE_BETA, bulk_modulus=kappa)

    def small_strain_moduli(self) -> tuple[Scalar, Scalar]:
        """(shear modulus alpha beta, bulk modulus kappa), Pa."""
        return self.alpha * self.beta, self.bulk_modulus

    def isochoric_energy(self, C: ufl.core.expr.Expr) -> ufl.core.expr.Expr:
        """The isochoric part alpha (exp[beta (I1bar - 3)] - 1) - alpha beta/2 (I2bar - 3)."""
        i1bar, i2bar, _ = isochoric_invariants(C)
        a, b = self.alpha, self.beta
        return a * (ufl.exp(b * (i1bar - 3)) - 1) - a * b / 2 * (i2bar - 3)

    def strain_energy(self, C: ufl.core.expr.Expr) -> ufl.core.expr.Expr:
        """W(C) as in the class docstring, J/m^3."""
        _, _, J = isochoric_invariants(C)
        return self.isochoric_energy(C) + _volumetric_energy(self.bulk_modulus, J)


@dataclass(frozen=True)
class Isochoric(Hyperelastic):
    """The isochoric part of a nearly incompressible law (its volumetric part taken elsewhere).

    For a mixed or mean-dilatation formulation (:mod:`shoulder_fem.engine.mean_dilatation`),
    which carries the volumetric energy kappa/2 (ln theta)^2 on a pressure space of its own.

    With ``pointwise_bulk`` kappa_s > 0 it adds kappa_s/2 (ln J)^2 on the pointwise J: a
    stabilisation that bounds the volume change at each point, which the projected constraint
    leaves free inside a pressure patch. It and its derivative vanish at J = 1, so the
    incompressible solution is unchanged by it; a small kappa_s/mu adds little stiffness
    (P2 locks only for kappa/mu in the hundreds).

    Attributes:
        law: A :class:`NeoHookean` or :class:`VerondaWestmann` law.
        pointwise_bulk: kappa_s in Pa (0: the isochoric energy alone).
    """

    law: NeoHookean | VerondaWestmann
    pointwise_bulk: Scalar = 0.0

    def strain_energy(self, C: ufl.core.expr.Expr) -> ufl.core.expr.Expr:
        """The law's isochoric energy (and the pointwise stabilisation), J/m^3."""
        if not self.pointwise_bulk:
            return self.law.isochoric_energy(C)
        _, _, J = isochoric_invariants(C)
        return self.law.isochoric_energy(C) + _volumetric_energy(self.pointwise_bulk, J)

    def small_strain_moduli(self) -> tuple[Scalar, Scalar]:
        """(the law's shear modulus, ``pointwise_bulk``), Pa."""
        return self.law.small_strain_moduli()[0], self.pointwise_bulk


def von_mises(stress: ufl.core.expr.Expr) -> ufl.core.expr.Expr:
    """The von Mises equivalent stress √(3/2 s:s) of a 3×3 stress, s its deviator (its unit)."""
    dev = stress - ufl.tr(stress) / 3 * ufl.Identity(3)
    return ufl.sqrt(1.5 * ufl.inner(dev, dev))
