"""The Newton steps of the condensed P1 pressures by the LU of the uncondensed (bordered) system.

On the shoulder's part 1 (coarse, 0-4 deg: contact, the travel control's rows, a prescribed
body's rows, the Jacobian's pattern widened on the way), every step the preconditioner gives
solves the SNES's own condensed Jacobian J: ‖J x - b‖ ≤ 1e-9 ‖b‖, with an LU of far fewer
entries than J's own; and the run gives the outputs of the LU of J (``condensed``) to the
solver's tolerance. Serial and on 2 ranks.
"""

from __future__ import annotations

import numpy as np
import pytest
from petsc4py import PETSc

pytestmark = pytest.mark.mpi

SERIES = ("max_pressure", "contact_force", "subscapularis_force", "infraspinatus_force")


def _factor_entries(ksp: PETSc.KSP) -> int:
    """The LU's entries (MUMPS INFOG(20)) of ``ksp``'s set-up factorization."""
    return int(ksp.getPC().getFactorMatrix().getMumpsInfog(20))


def _assembled(lu) -> PETSc.Mat:
    """J = J₀ + G_Tᵀ D G_B as one matrix (the condensed LU's), from ``lu``'s blocks."""
    G = lu._G
    DG = G["B"].copy()
    DG.diagonalScale(L=lu._d)
    J = lu.J0.copy()
    product = G["Tt"].matMult(DG)
    J.axpy(1.0, product, structure=PETSc.Mat.Structure.DIFFERENT_NONZERO_PATTERN)
    product.destroy()
    DG.destroy()
    return J


def test_the_bordered_lu_solves_the_condensed_jacobian(comm_tmp, monkeypatch):
    from shoulder_fem import api
    from shoulder_fem.engine.rigid_system import uncondensed
    from shoulder_fem.scene import load_scene

    scene = load_scene("shoulder-internal-rotation").with_overrides(
        ["final_angle=4deg", "angle_step=2deg", "output_angle=2deg"]
    )
    seen = {"solves": 0, "worst": 0.0, "entries": None}
    real = uncondensed.UncondensedLU.solve

    def checked(self, b, x):
        real(self, b, x)
        r = b.duplicate()
        self.operator.mult(x, r)  # J x, J applied (the SNES's operator)
        r.axpy(-1.0, b)
        seen["solves"] += 1
        seen["worst"] = max(seen["worst"], r.norm() / b.norm())
        if seen["entries"] is None and seen["solves"] > 20:  # past the seating: J as widened
            J = _assembled(self)
            lu = PETSc.KSP().create(self.comm)
            lu.setType("preonly")
            lu.getPC().setType("lu")
            lu.getPC().setFactorSolverType("mumps")
            lu.setOperators(J)
            lu.setUp()
            seen["entries"] = (_factor_entries(self.ksp), _factor_entries(lu))
            lu.destroy()
            J.destroy()

    monkeypatch.setattr(uncondensed.UncondensedLU, "solve", checked)
    bordered = api.run(scene, "decoupled", "coarse", comm_tmp / "bordered")
    monkeypatch.setattr(uncondensed.UncondensedLU, "solve", real)
    assert seen["solves"] > 40
    # J x = b is the equation the condensed LU solves exactly: its residual, not a stored
    # number (measured 1.9e-11 before the refinement; the LU of J itself leaves about 1e-13)
    assert seen["worst"] <= 1e-9, seen
    # the other factorization of the same state: MUMPS's own count for the LU of J
    # (measured 0.60M against 1.43M entries, 0.42)
    ours, condensed_lu = seen["entries"]
    assert ours < 0.6 * condensed_lu, seen

    plain = scene.with_overrides(["soft_tissue_linear_solve=condensed"])
    condensed = api.run(plain, "decoupled", "coarse", comm_tmp / "condensed")
    assert bordered.status == condensed.status == "ok"
    # the other method of the same Newton steps: the LU of the condensed J
    for name in SERIES:
        a = np.array(bordered.data["series"][name]["y"])
        b = np.array(condensed.data["series"][name]["y"])
        assert np.allclose(a, b, rtol=1e-5, atol=1e-6 * np.abs(b).max()), name


def _tied_block(prescribed: bool, uncondensed: bool):
    """A P2 block with condensed P1 pressures, its base fixed, its top tied to a plate (free,
    loaded and on a spring; or prescribed, its travel controlled): its RigidSystem and
    MeanDilatation."""
    import dolfinx
    import ufl
    from mpi4py import MPI

    from shoulder_fem.engine.mean_dilatation import MeanDilatation
    from shoulder_fem.engine.rigid_system import RigidBody, RigidSystem, Tie
    from shoulder_fem.engine.rigid_system.control import MeasureGradient
    from shoulder_fem.engine.springs import GROUND, Spring
    from shoulder_fem.forms import Isochoric, NeoHookean, internal_power_finite
    from shoulder_fem.meshes.block import BASE, TOP, build_block

    mesh, ct, tags = build_block(MPI.COMM_WORLD, 0.01, 0.04, 2, 4)
    V = dolfinx.fem.VectorFunctionSpace(mesh, ("Lagrange", 2))
    u, w = dolfinx.fem.Function(V), ufl.TestFunction(V)
    dx = ufl.Measure("dx", domain=mesh, subdomain_data=ct, metadata={"quadrature_degree": 4})
    law = NeoHookean(c10=0.5e6, bulk_modulus=500e6)
    kappa = {int(t): law.bulk_modulus for t in np.unique(ct.values)}
    md = MeanDilatation(u, ct, kappa, dx, pressure="P1")
    residual = internal_power_finite(Isochoric(law), u, w, dx) + md.residual(w)
    ref = np.array([0.005, 0.005, 0.04])
    plate = RigidBody("plate", ref, force=[0.2, 0.0, 1.0], prescribed=prescribed)
    springs = [] if prescribed else [Spring("s", "plate", ref, GROUND, ref + [0.1, 0, 0], 500.0)]
    system = RigidSystem(
        [plate],
        springs,
        u=u,
        residual=residual,
        surfaces={"base": (tags, BASE.id), "top": (tags, TOP.id)},
        ties=[Tie("plate", "top")],
        fixed=["base"],
        volumetric=md,
        uncondensed=uncondensed,
    )
    if prescribed:  # its vertical travel the unknown of a controlled row, as part 1's humerus

        def measure(with_gradient: bool) -> MeasureGradient:
            out = MeasureGradient(float(plate.translation[2]))
            if with_gradient:
                out.bodies[0] = np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0])
            return out

        system.set_control("plate", [0.0, 0.0, 1.0], measure, 1e3)
    return system, md


@pytest.mark.parametrize("prescribed", [False, True])
def test_the_operator_is_the_condensed_jacobian(prescribed):
    """The SNES's operator, J applied as J₀ x + G_Tᵀ D G_B x, is the Jacobian the condensed
    system assembles (J₀ + Pᵀ Bᵀ D B P in one matrix, its prescribed and controlled rows made
    after the sum), at a deformed state, to round-off; and, for the free plate, the derivative
    of the residual (Taylor remainders of order 2). Serial and on 2 ranks."""
    from _util import taylor_rates

    rng = np.random.default_rng(7)
    systems = [_tied_block(prescribed, uncondensed) for uncondensed in (True, False)]
    (bordered, _), (condensed, _) = systems
    x = bordered.reduced_vector()
    x.array[:] += 2e-4 * rng.uniform(-1.0, 1.0, x.getLocalSize())
    outputs = []
    for system, _ in systems:
        r = x.duplicate()
        system.snes.computeFunction(x, r)
        A, P = system.snes.getJacobian()[:2]
        system.snes.computeJacobian(x, A, P)
        d, y, yt = x.duplicate(), x.duplicate(), x.duplicate()
        d.array[:] = np.random.default_rng(11 + x.comm.rank).uniform(-1.0, 1.0, d.getLocalSize())
        A.mult(d, y)
        A.multTranspose(d, yt)
        outputs.append((y, yt))
    assert bordered.snes.getJacobian()[0].getType() == "python"  # J not assembled
    assert condensed.snes.getJacobian()[0].getType() != "python"
    for ours, theirs in zip(*outputs, strict=True):  # J d, then Jᵀ d
        diff = ours.copy()
        diff.axpy(-1.0, theirs)
        assert theirs.norm() > 0
        # the other method: the condensed system's assembled J; equal up to round-off
        assert diff.norm() <= 1e-12 * theirs.norm(), diff.norm() / theirs.norm()
    if not prescribed:
        # a convergence rate: the remainders of an exact tangent fall as eps², rate 2
        remainders, rates = taylor_rates(bordered, rng, 1e-5)
        assert min(rates) > 1.8, (remainders, rates)
    for system, md in systems:
        system.destroy()
        md.destroy()
