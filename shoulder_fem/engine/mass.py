"""Mass properties of a body's mesh: mass, centre of mass, inertia tensor (the one place)."""

from __future__ import annotations

from dataclasses import dataclass

import dolfinx
import numpy as np
import ufl
from mpi4py import MPI

from shoulder_fem.forms import rigid_body

__all__ = ["MassProperties", "mass_properties"]


@dataclass(frozen=True)
class MassProperties:
    """A body's mass properties in its reference configuration.

    Attributes:
        mass: m (kg).
        centre: centre of mass X_G (m), shape (3,).
        inertia: inertia tensor about X_G, I_G (kg m²), shape (3, 3).
    """

    mass: float
    centre: np.ndarray
    inertia: np.ndarray


def mass_properties(mesh: dolfinx.mesh.Mesh, density, dx: ufl.Measure) -> MassProperties:
    """Mass, centre of mass and inertia tensor about it, from the UFL functionals (collective).

    Args:
        mesh: the body's reference mesh (m).
        density: ρ (kg/m³), a number or a UFL expression.
        dx: cell measure of the body (possibly restricted to its cells), with a quadrature
            degree exact for quadratic integrands.

    Raises:
        ValueError: if the body has no mass.
    """

    def integral(form: ufl.Form) -> float:
        value = dolfinx.fem.assemble_scalar(dolfinx.fem.form(form))
        return mesh.comm.allreduce(value, op=MPI.SUM)

    m = integral(rigid_body.mass(density, dx))
    if not m > 0:
        raise ValueError(f"mass_properties: the body has no mass ({m} kg)")
    x = ufl.SpatialCoordinate(mesh)
    centre = np.array([integral(f) for f in rigid_body.first_moment(density, x, dx)]) / m
    gm = x - dolfinx.fem.Constant(mesh, centre)  # a constant: another body compiles nothing
    rows = rigid_body.inertia_tensor(density, gm, dx)
    inertia = np.array([[integral(f) for f in row] for row in rows])
    return MassProperties(m, centre, 0.5 * (inertia + inertia.T))
