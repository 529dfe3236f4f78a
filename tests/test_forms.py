"""Rigid-body functionals and virtual-power terms on a box, against closed-form values.

The box [0, a] x [0, b] x [0, c] has uniform density rho. Every term is tested as the paper
uses it: its virtual power for a rigid virtual velocity w = W (a translation) or
w = Omega_w x GM (a rotation about G), which turns the field integrals into the rigid-body
quantities of eqs. (6), (7) and (9). The virtual velocities are UFL expressions built from
``Constant``s, so each term is compiled once and evaluated for every unit vector by updating the
constants. Every assembled scalar is summed over ranks.

Tolerances: the integrands are polynomials of degree <= 3 in x on affine cells and UFL picks a
quadrature exact for them, so the only error is rounding: a few ulp per quadrature point,
accumulated over the 384 cells. ``ROUNDING = 1e3 * eps`` (about 2e-13) times the natural scale of
each quantity (e.g. rho Omega^2 |GM| V for the centrifugal term).
"""

from __future__ import annotations

import dolfinx
import numpy as np
import pytest
import ufl
from mpi4py import MPI
from petsc4py import PETSc

from shoulder_fem.forms import (
    LinearElastic,
    NeoHookean,
    body_force_power,
    centrifugal_inertia,
    coriolis_inertia,
    deformation_gradient,
    euler_inertia,
    first_moment,
    inertia_power,
    inertia_tensor,
    internal_power_finite,
    internal_power_linear,
    mass,
    relative_inertia,
    resultant_force,
    resultant_moment,
    right_cauchy_green,
    rigid_frame_inertia,
    traction_power,
    translational_inertia,
)

EPS = np.finfo(PETSc.ScalarType).eps
ROUNDING = 1e3 * EPS
A, B, C = 2.0, 1.0, 0.5  # box edges, m (distinct, so the principal moments are distinct)
RHO = 1000.0  # kg/m^3
LOADED = 1  # facet tag of the face x = A
E = np.eye(3)

# Rigid-frame state (body-frame components), deliberately not aligned with the axes.
OMEGA = np.array([0.7, -1.1, 2.3])  # rad/s
D_OMEGA = np.array([-0.4, 0.9, 1.7])  # rad/s^2
A_G = np.array([0.3, -2.0, 9.81])  # m/s^2
V_REL = np.array([0.02, 0.05, -0.03])  # m/s, uniform straining velocity
TRACTION = np.array([0.3, -1.2, 2.0])  # Pa, on the face x = A


class Box:
    """The box, its measures, rho, the centre of mass constant X_G and GM = x - X_G."""

    def __init__(self, comm: MPI.Comm):
        self.comm = comm
        self.mesh = dolfinx.mesh.create_box(
            comm, [np.zeros(3), np.array([A, B, C])], [8, 4, 2], dolfinx.mesh.CellType.tetrahedron
        )
        fdim = self.mesh.topology.dim - 1
        facets = dolfinx.mesh.locate_entities_boundary(
            self.mesh, fdim, lambda x: np.isclose(x[0], A)
        )
        tags = dolfinx.mesh.meshtags(
            self.mesh, fdim, facets, np.full(len(facets), LOADED, dtype=np.int32)
        )
        self.dx = ufl.Measure("dx", domain=self.mesh)
        self.ds = ufl.Measure("ds", domain=self.mesh, subdomain_data=tags)
        self.rho = self.constant(RHO)
        self.x = ufl.SpatialCoordinate(self.mesh)
        self.x_g = self.constant(np.zeros(3))
        self.gm = self.x - self.x_g

    def constant(self, value) -> dolfinx.fem.Constant:
        """A Constant on the box mesh."""
        return dolfinx.fem.Constant(self.mesh, PETSc.ScalarType(value))

    def integrate(self, form: ufl.Form) -> float:
        """Assemble a scalar form and sum over ranks."""
        local = dolfinx.fem.assemble_scalar(dolfinx.fem.form(form))
        return self.comm.allreduce(local, op=MPI.SUM)

    def rigid_powers(self, term) -> tuple[np.ndarray, np.ndarray]:
        """Virtual powers of ``term(w)`` for w = e_k and for w = e_k x GM, k = 0, 1, 2.

        Returns the 'force' vector (coefficients of a virtual translation) and the 'moment'
        vector (coefficients of a virtual rotation about G).
        """
        unit = self.constant(np.zeros(3))
        translation = dolfinx.fem.form(term(unit))
        rotation = dolfinx.fem.form(term(ufl.cross(unit, self.gm)))
        force, moment = np.zeros(3), np.zeros(3)
        for k in range(3):
            unit.value[:] = E[k]
            force[k] = self.comm.allreduce(dolfinx.fem.assemble_scalar(translation), MPI.SUM)
            moment[k] = self.comm.allreduce(dolfinx.fem.assemble_scalar(rotation), MPI.SUM)
        return force, moment


@pytest.fixture(scope="module")
def box():
    """The box with X_G set to its centre (computed in test_mass_properties too)."""
    body = Box(MPI.COMM_WORLD)
    body.x_g.value[:] = [A / 2, B / 2, C / 2]
    return body


# Closed forms for the uniform box about its centre.
MASS = RHO * A * B * C
I_G = MASS / 12 * np.diag([B**2 + C**2, A**2 + C**2, A**2 + B**2])
R_MAX = np.linalg.norm([A, B, C]) / 2  # largest |GM|, m


def assert_close(actual, expected, scale: float, err_msg: str = "") -> None:
    """Equal up to rounding, relative to the natural scale of the quantity."""
    np.testing.assert_allclose(actual, expected, rtol=0, atol=ROUNDING * scale, err_msg=err_msg)


@pytest.mark.mpi
def test_mass_properties():
    """Mass, centre of mass and I_G of the box match the textbook formulas."""
    # m = rho a b c; X_G = (a/2, b/2, c/2); I_G = m/12 diag(b^2 + c^2, a^2 + c^2, a^2 + b^2).
    body = Box(MPI.COMM_WORLD)
    m = body.integrate(mass(body.rho, body.dx))
    centre = np.array([body.integrate(f) for f in first_moment(body.rho, body.x, body.dx)]) / m
    body.x_g.value[:] = centre
    inertia = np.array(
        [[body.integrate(f) for f in row] for row in inertia_tensor(body.rho, body.gm, body.dx)]
    )
    assert_close(m, MASS, MASS)
    assert_close(centre, [A / 2, B / 2, C / 2], R_MAX)
    assert_close(inertia, I_G, MASS * R_MAX**2)


@pytest.mark.mpi
def test_euler_inertia_gives_eq6(box):
    """Euler term against paper eq. (6)."""
    # Eq. (6): int rho (dOmega x GM).(Omega_w x GM) = (I_G dOmega).Omega_w; for Omega_w = e_z and
    # dOmega = dOmega_z e_z this is I_zz dOmega_z. A translation sees int rho GM = 0.
    d_omega = box.constant(D_OMEGA)
    force, moment = box.rigid_powers(lambda w: euler_inertia(box.rho, d_omega, box.gm, w, box.dx))
    scale = MASS * R_MAX * np.linalg.norm(D_OMEGA)
    assert_close(force, 0.0, scale)
    assert_close(moment, I_G @ D_OMEGA, scale * R_MAX)
    d_omega.value[:] = [0.0, 0.0, 1.7]
    _, moment = box.rigid_powers(lambda w: euler_inertia(box.rho, d_omega, box.gm, w, box.dx))
    assert_close(moment[2], I_G[2, 2] * 1.7, scale * R_MAX)


@pytest.mark.mpi
def test_centrifugal_inertia_gives_eq7(box):
    """Centrifugal term against paper eq. (7)."""
    # Spinning about z: int rho Omega x (Omega x GM) . e_i = Omega x (Omega x int rho GM) = 0,
    # G being the centre of mass. Eq. (7) for a general Omega:
    # int rho [Omega x (Omega x GM)].(Omega_w x GM) = (Omega x I_G Omega).Omega_w.
    omega = box.constant([0.0, 0.0, 2.3])
    force, moment = box.rigid_powers(
        lambda w: centrifugal_inertia(box.rho, omega, box.gm, w, box.dx)
    )
    scale = MASS * R_MAX * 2.3**2
    assert_close(force, 0.0, scale)
    assert_close(moment, 0.0, scale * R_MAX)  # z is a principal axis: Omega x I_G Omega = 0
    omega.value[:] = OMEGA
    force, moment = box.rigid_powers(
        lambda w: centrifugal_inertia(box.rho, omega, box.gm, w, box.dx)
    )
    scale = MASS * R_MAX * np.dot(OMEGA, OMEGA)
    assert_close(force, 0.0, scale)
    assert_close(moment, np.cross(OMEGA, I_G @ OMEGA), scale * R_MAX)


@pytest.mark.mpi
def test_translational_coriolis_relative_inertia(box):
    """Terms with uniform fields give m times the field."""
    # Uniform fields: int rho a.e_i = m a_i, and int rho a.(e_k x GM) = e_k.(int rho GM x a) = 0.
    # Coriolis with a uniform v: int rho 2 (Omega x v).e_i = 2 m (Omega x v)_i.
    a_g, omega, v_rel = box.constant(A_G), box.constant(OMEGA), box.constant(V_REL)
    expected = {
        "translational": (lambda w: translational_inertia(box.rho, a_g, w, box.dx), A_G),
        "relative": (lambda w: relative_inertia(box.rho, a_g, w, box.dx), A_G),
        "inertial-frame": (lambda w: inertia_power(box.rho, a_g, w, box.dx), A_G),
        "body-force": (lambda w: body_force_power(box.rho, a_g, w, box.dx), A_G),
        "coriolis": (
            lambda w: coriolis_inertia(box.rho, omega, v_rel, w, box.dx),
            2 * np.cross(OMEGA, V_REL),
        ),
    }
    for name, (term, acceleration) in expected.items():
        force, moment = box.rigid_powers(term)
        scale = MASS * np.linalg.norm(acceleration)
        assert_close(force, MASS * acceleration, scale, err_msg=name)
        assert_close(moment, 0.0, scale * R_MAX, err_msg=name)


@pytest.mark.mpi
def test_rigid_frame_inertia_gives_eq9(box):
    """The rigid-frame inertia sum against paper eq. (9)."""
    # The sum of the three rigid-frame terms gives the right-hand side of eq. (9):
    # m a_G . W + (I_G dOmega + Omega x I_G Omega) . Omega_w.
    a_g, omega, d_omega = box.constant(A_G), box.constant(OMEGA), box.constant(D_OMEGA)
    force, moment = box.rigid_powers(
        lambda w: rigid_frame_inertia(box.rho, a_g, omega, d_omega, box.gm, w, box.dx)
    )
    scale = MASS * (np.linalg.norm(A_G) + R_MAX * (np.linalg.norm(D_OMEGA) + OMEGA @ OMEGA))
    assert_close(force, MASS * A_G, scale)
    assert_close(moment, I_G @ D_OMEGA + np.cross(OMEGA, I_G @ OMEGA), scale * R_MAX)


@pytest.mark.mpi
def test_tractions_resultants(box):
    """Resultant force and moment of a face traction, and their power."""
    # Uniform t on the face x = a (area b c, centroid at GM = (a/2, 0, 0) from the centre):
    # F = b c t, M_G = int GM x t = (a/2) b c e_x x t. Its virtual power for a rigid velocity
    # W + Omega_w x GM is F.W + M_G.Omega_w.
    t = box.constant(TRACTION)
    ds = box.ds(LOADED)
    force = np.array([box.integrate(f) for f in resultant_force(t, ds)])
    moment = np.array([box.integrate(f) for f in resultant_moment(t, box.gm, ds)])
    scale = B * C * np.linalg.norm(TRACTION)
    assert_close(force, B * C * TRACTION, scale)
    assert_close(moment, A / 2 * B * C * np.cross(E[0], TRACTION), scale * R_MAX)
    power_force, power_moment = box.rigid_powers(lambda w: traction_power(t, w, ds))
    assert_close(power_force, force, scale)
    assert_close(power_moment, moment, scale * R_MAX)


@pytest.mark.mpi
def test_internal_power_vanishes_for_rigid_virtual_velocity(box):
    """Paper eq. (8) at finite strain."""
    # Eq. (8) at finite strain: for w = Omega_w x (x + u - X_G), rigid in the deformed
    # configuration, Grad w = [Omega_w]x F and P : Grad w = [Omega_w]x : F S F^T = 0 because
    # F S F^T is symmetric, for any (non-homogeneous) u.
    V = dolfinx.fem.VectorFunctionSpace(box.mesh, ("CG", 1))
    u = dolfinx.fem.Function(V)
    u.interpolate(lambda x: 0.05 * np.stack([np.sin(x[1]), x[0] * x[2], np.cos(x[0] * x[1])]))
    material = NeoHookean.cartilage()
    unit = box.constant(np.zeros(3))
    form = dolfinx.fem.form(internal_power_finite(material, u, ufl.cross(unit, box.gm + u), box.dx))
    P = material.first_piola(deformation_gradient(u))
    magnitude = box.integrate(ufl.sqrt(ufl.inner(P, P)) * R_MAX * box.dx)
    for k in range(3):
        unit.value[:] = E[k]
        power = box.comm.allreduce(dolfinx.fem.assemble_scalar(form), MPI.SUM)
        assert abs(power) <= ROUNDING * magnitude


@pytest.mark.mpi
def test_internal_power_is_energy_derivative(box):
    """internal_power_finite is the derivative of the energy."""
    # int P(F(u)) : grad w = d/ds int W(C(u + s w)) at s = 0 (Gateaux derivative by UFL).
    V = dolfinx.fem.VectorFunctionSpace(box.mesh, ("CG", 1))
    u, w = dolfinx.fem.Function(V), dolfinx.fem.Function(V)
    u.interpolate(lambda x: 0.05 * np.stack([np.sin(x[1]), x[0] * x[2], np.cos(x[0] * x[1])]))
    w.interpolate(lambda x: np.stack([x[1] * x[2], -x[0], x[0] ** 2]))
    material = NeoHookean.cartilage()
    energy = material.strain_energy(right_cauchy_green(deformation_gradient(u))) * box.dx
    power = box.integrate(internal_power_finite(material, u, w, box.dx))
    derivative = box.integrate(ufl.derivative(energy, u, w))
    P = material.first_piola(deformation_gradient(u))
    magnitude = box.integrate(
        ufl.sqrt(ufl.inner(P, P) * ufl.inner(ufl.grad(w), ufl.grad(w))) * box.dx
    )
    assert abs(power - derivative) <= ROUNDING * magnitude


@pytest.mark.mpi
def test_internal_power_linear_homogeneous(box):
    """internal_power_linear for homogeneous u and w."""
    # u = eps0 X, w = G X: int sigma(eps0) : sym(G) = V sigma(eps0) : G, with
    # sigma = lmbda tr(eps0) I + 2 mu eps0 (E = 2.6 Pa, nu = 0.3: lmbda = 1.5 Pa, mu = 1 Pa).
    eps0 = np.array([[1e-3, 2e-4, 0.0], [2e-4, -5e-4, 3e-4], [0.0, 3e-4, 2e-4]])
    G = np.array([[0.3, -0.8, 0.5], [0.4, -0.2, 0.7], [-0.6, 0.1, 0.5]])
    V = dolfinx.fem.VectorFunctionSpace(box.mesh, ("CG", 1))
    u = dolfinx.fem.Function(V)
    u.interpolate(lambda x: eps0 @ x)
    w = ufl.dot(box.constant(G), box.x)
    power = box.integrate(internal_power_linear(LinearElastic(2.6, 0.3), u, w, box.dx))
    sigma = 1.5 * np.trace(eps0) * E + 2 * 1.0 * eps0
    volume = A * B * C
    expected = volume * np.sum(sigma * G)
    assert_close(power, expected, volume * np.linalg.norm(sigma) * np.linalg.norm(G))
