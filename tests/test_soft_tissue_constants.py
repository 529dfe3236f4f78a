"""The soft tissues' Table I constants are scene parameters, and enter the forms as constants.

A unit cube is stretched homogeneously and isochorically along x, F = diag(l, l^-1/2, l^-1/2)
(J = 1), interpolated exactly (P2 holds a linear field). The power of the shoulder's own
muscle and cartilage laws (``soft_tissue_laws`` + ``mixed_law``, as the shoulder's forms use
them) on the virtual velocity w = dF/dl X is then the generalised force dW/dl x volume:

* Veronda-Westmann: W = alpha (exp[beta (I1 - 3)] - 1) - alpha beta/2 (I2 - 3), so
  dW/dl = alpha beta exp[beta (I1 - 3)] dI1/dl - alpha beta/2 dI2/dl;
* neo-Hookean: dW/dl = C10 dI1/dl,

with I1 = l^2 + 2/l, I2 = 2 l + 1/l^2 (I1bar = I1 and I2bar = I2 at J = 1; the pointwise
stabilisation kappa_s/2 (ln J)^2 and its derivative vanish at J = 1). Quadrature is exact
(constant integrands): rounding only.
"""

from __future__ import annotations

import math

import dolfinx
import numpy as np
import pytest
import ufl
from mpi4py import MPI

from shoulder_fem.families.shoulder.interactions import mixed_law, soft_tissue_laws
from shoulder_fem.families.shoulder.model import ShoulderParameters
from shoulder_fem.forms import virtual_power as vp
from shoulder_fem.scene import SceneError, load_scene

pytestmark = pytest.mark.mpi  # serial and under mpirun -n 2 (seconds)

STRETCH = 1.15


def _params(**values) -> ShoulderParameters:
    scene = load_scene("shoulder-internal-rotation").with_values(**values)
    return ShoulderParameters.from_values(scene.values())


def _stretched_cube():
    """(u, w) on a unit cube: the stretch F - I and its rate dF/dl, both times X."""
    mesh = dolfinx.mesh.create_unit_cube(MPI.COMM_WORLD, 2, 2, 2)
    V = dolfinx.fem.VectorFunctionSpace(mesh, ("Lagrange", 2))
    l = STRETCH  # noqa: E741
    u, w = dolfinx.fem.Function(V), dolfinx.fem.Function(V)
    u.interpolate(lambda x: np.vstack([(l - 1) * x[0], (l**-0.5 - 1) * x[1], (l**-0.5 - 1) * x[2]]))
    rate = -0.5 * l**-1.5
    w.interpolate(lambda x: np.vstack([x[0], rate * x[1], rate * x[2]]))
    return mesh, u, w


def _forces(params: ShoulderParameters, mesh, u, w, cache) -> tuple[float, float]:
    """(cartilage, muscle) power on w (N m, = dW/dl x 1 m^3), compiled into ``cache``."""
    dx = ufl.Measure("dx", domain=mesh, metadata=params.quadrature())
    out = []
    for law in soft_tissue_laws(params, mesh):
        form = vp.internal_power_finite(mixed_law(law, params), u, w, dx)
        compiled = dolfinx.fem.form(
            form, form_compiler_params=params.quadrature(), jit_params={"cache_dir": str(cache)}
        )
        out.append(mesh.comm.allreduce(dolfinx.fem.assemble_scalar(compiled), op=MPI.SUM))
    return out[0], out[1]


def _hand(c10: float, alpha: float, beta: float) -> tuple[float, float]:
    """dW/dl of the neo-Hookean and the Veronda-Westmann laws at F = diag(l, l^-1/2, l^-1/2)."""
    l = STRETCH  # noqa: E741
    i1, di1 = l**2 + 2 / l, 2 * l - 2 / l**2
    di2 = 2 - 2 / l**3
    muscle = alpha * beta * math.exp(beta * (i1 - 3)) * di1 - alpha * beta / 2 * di2
    return c10 * di1, muscle


def test_the_constants_set_the_forces_as_a_hand_calculation_and_compile_nothing(comm_tmp):
    """Table I's values, then others through the scene (with units, as --set takes them):
    each time the stretched block's forces are the hand calculation's, and the second set of
    values compiles no new form (the cache holds as many modules as after the first)."""
    mesh, u, w = _stretched_cube()
    cache = comm_tmp / f"forms-rank{MPI.COMM_WORLD.rank}"
    # dolfinx 0.5 writes the coordinate element's variant into the mesh's UFL domain at its
    # first compiled form, which changes the signature of every later form on it (a run's
    # meshes have had theirs before the laws' forms): one form first, as in a run
    dolfinx.fem.form(ufl.inner(u, w) * ufl.dx(domain=mesh), jit_params={"cache_dir": str(cache)})
    table = _params()
    assert (table.cartilage_c10, table.muscle_alpha, table.muscle_beta) == (1.79e6, 0.12e6, 1.0)
    cart, musc = _forces(table, mesh, u, w, cache)
    # hand calculation (module docstring); rounding only, relative 1e-10
    assert (cart, musc) == pytest.approx(_hand(1.79e6, 0.12e6, 1.0), rel=1e-10)
    compiled = sorted(cache.rglob("*.so"))
    assert len(compiled) == 3, compiled  # the first form and the two laws' forms

    other = _params(cartilage_c10="2.5 MPa", muscle_alpha="0.06MPa", muscle_beta=1.6)
    cart2, musc2 = _forces(other, mesh, u, w, cache)
    assert (cart2, musc2) == pytest.approx(_hand(2.5e6, 0.06e6, 1.6), rel=1e-10)
    assert sorted(cache.rglob("*.so")) == compiled  # the same modules: nothing compiled
    # alpha halved at beta = 1: the muscle force halves (W is linear in alpha)
    half = _params(muscle_alpha="0.06 MPa")
    assert _forces(half, mesh, u, w, cache)[1] == pytest.approx(musc / 2, rel=1e-10)


@pytest.mark.parametrize(
    ("key", "value", "needs"),
    [
        ("muscle_alpha", "0", ">="),
        ("muscle_beta", "11", "<="),
        ("cartilage_c10", "-1 MPa", ">="),
        ("muscle_alpha", "0.1 mm", "does not convert to Pa"),
    ],
)
def test_a_constant_out_of_its_range_is_refused_in_one_line(key, value, needs):
    """A value outside the bounds, or in another dimension, is one line naming key and value."""
    scene = load_scene("shoulder-internal-rotation")
    with pytest.raises(SceneError) as err:
        scene.with_overrides([f"{key}={value}"])
    line = str(err.value)
    assert "\n" not in line and key in line and needs in line, line
