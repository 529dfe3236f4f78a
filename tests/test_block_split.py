"""The stiff / soft block preconditioner with an eliminated border (engine/block_split.py)
against MUMPS LU, on a block whose lower half is 1000 x stiffer than its upper half."""

from __future__ import annotations

import dolfinx
import numpy as np
import pytest
import ufl
from mpi4py import MPI
from petsc4py import PETSc

from shoulder_fem.engine.block_split import StiffSoftSplit, split_options
from shoulder_fem.engine.fem import owned_flags
from shoulder_fem.engine.gamg import ScaledGAMG
from shoulder_fem.engine.rigid_system import RigidBody, RigidSystem, Tie
from shoulder_fem.engine.rigid_system.control import MeasureGradient
from shoulder_fem.engine.solver import clear_user_options, set_user_options, unused_user_options
from shoulder_fem.engine.springs import GROUND, Spring
from shoulder_fem.forms import materials
from shoulder_fem.forms import virtual_power as vp
from shoulder_fem.meshes.block import BASE, TOP, build_block

pytestmark = pytest.mark.mpi

LENGTH = 0.04  # m; the lower half (z < LENGTH / 2) is the stiff field
TIGHT = {"snes_rtol": 1e-11, "snes_atol": 1e-9, "snes_max_it": 8}  # forces ~ 1 N
TARGET = 2e-6  # m, the stiff half's mean x displacement that the top plate's travel must give


def controlled_block(options: dict, split: bool):
    """A P2 block, E = 1 GPa below mid-height and 1 MPa above, on a base plate held by six
    springs; the top plate is prescribed and slides along x until the stiff half's mean x
    displacement is TARGET (a travel control: its row has entries on stiff nodes only, zero in
    both fields' blocks, as the shoulder's actuator)."""
    comm = MPI.COMM_WORLD
    mesh, _, tags = build_block(comm, 0.01, LENGTH, 3, 6)
    V = dolfinx.fem.VectorFunctionSpace(mesh, ("Lagrange", 2))
    u = dolfinx.fem.Function(V)
    x = ufl.SpatialCoordinate(mesh)
    E = ufl.conditional(ufl.lt(x[2], LENGTH / 2), 1e9, 1e6)
    residual = vp.internal_power_linear(
        materials.LinearElastic(E, 0.3), u, ufl.TestFunction(V), ufl.dx(domain=mesh)
    )
    base = RigidBody("base", (0, 0, 0.0))
    top = RigidBody("top", (0, 0, LENGTH), prescribed=True)
    springs = []
    for k, d in enumerate(np.vstack([np.eye(3), -np.eye(3)])):
        a = np.array([0.004 * d[1], 0.004 * d[0], 0.0])  # off-centre: they hold turns
        springs.append(Spring(f"s{k}", "base", a, GROUND, a + 0.05 * d, 4e4))
    system = RigidSystem(
        [base, top],
        springs,
        u=u,
        residual=residual,
        surfaces={"base": (tags, BASE.id), "top": (tags, TOP.id)},
        ties=[Tie("base", "base"), Tie("top", "top")],
        options=TIGHT | options,
        linear_ties=True,
        near_nullspace=split,
    )
    cells = dolfinx.mesh.locate_entities(mesh, 3, lambda p: p[2] < LENGTH / 2 + 1e-12)
    stiff = dolfinx.fem.locate_dofs_topological(V, 3, cells)  # the interface's nodes too
    n_owned = V.dofmap.index_map.size_local
    owned = np.flatnonzero(owned_flags(V.dofmap.index_map, stiff, comm)[:n_owned])
    count = comm.allreduce(len(owned), op=MPI.SUM)

    def measure(with_gradient: bool) -> MeasureGradient:
        mean = comm.allreduce(u.x.array.reshape(-1, 3)[owned, 0].sum(), op=MPI.SUM) / count
        out = MeasureGradient(float(mean))
        if with_gradient:
            out.fe = np.zeros(3 * n_owned)
            out.fe[3 * owned] = 1.0 / count
        return out

    if split:
        system.split_fields(stiff, ["base"])
    control = system.set_control("top", [1.0, 0, 0], measure, 1e6)
    control.target = TARGET
    return system, control, measure


def _solve(options: dict, split: bool):
    system, control, measure = controlled_block(options, split)
    system.solve("travel")
    assert abs(measure(False).value - TARGET) < 1e-9 * TARGET
    return system, system.u.x.array.copy(), control.travel(system.bodies[1].translation)


def test_the_split_gives_lus_solution_and_its_choice_reaches_petsc():
    """FGMRES with the split (CG + ScaledGAMG on the stiff half, LU on the soft one, the top
    plate's control row eliminated) gives LU's displacements and travel to 1e-8 (serial and 2
    ranks); the KSP and sub-solvers are the ones asked for, and a user option under the stiff
    field's prefix is read (PETSc's options database)."""
    lu, u_lu, travel_lu = _solve({}, False)
    assert lu.snes.getKSP().getPC().getType() == "lu"
    lu.destroy()
    set_user_options({"split_a_scaled_pc_gamg_threshold": "0.07"})
    try:
        it, u_it, travel_it = _solve(split_options(rtol=1e-12), True)
        ksp = it.snes.getKSP()
        assert ksp.getType() == "fgmres"
        split = ksp.getPC().getPythonContext()
        assert isinstance(split, StiffSoftSplit)
        assert split.ksp["a"].getType() == "cg"
        assert isinstance(split.ksp["a"].getPC().getPythonContext(), ScaledGAMG)
        assert split.ksp["b"].getPC().getType() == "lu"
        assert split.ksp["b"].getPC().getFactorSolverType() == "mumps"
        assert "split_a_scaled_pc_gamg_threshold" not in (unused_user_options() or [])
        assert it.stats.krylov_iterations > 2  # really iterative (measured 30 in 2 solves)
    finally:
        clear_user_options()
    comm = MPI.COMM_WORLD
    diff = comm.allreduce(float(np.abs(u_it - u_lu).max(initial=0.0)), op=MPI.MAX)
    size = comm.allreduce(float(np.abs(u_lu).max(initial=0.0)), op=MPI.MAX)
    assert diff < 1e-8 * size, (diff, size)
    assert travel_it == pytest.approx(travel_lu, rel=1e-8)
    assert travel_lu > 2 * TARGET  # the soft half shears: the plate travels 3.2x as far
    it.destroy()


def test_exact_blocks_make_the_split_exact_on_the_whole_main_block():
    """With LU on both fields the split is one block Gauss-Seidel sweep, and the border is
    eliminated exactly about it: the preconditioner is linear (P(a + b) = P a + P b to
    round-off), and FGMRES needs only the iterations the sweep leaves (a handful)."""
    exact = {"split_a_ksp_type": "preonly", "split_a_pc_type": "lu"}
    exact["split_a_pc_factor_mat_solver_type"] = "mumps"
    system, _, _ = controlled_block(split_options(rtol=1e-12) | exact, True)
    system.solve("travel")
    split = system.snes.getKSP().getPC().getPythonContext()
    assert split.ksp["a"].getPC().getType() == "lu"
    pc = system.snes.getKSP().getPC()
    a, b = system._problem.J.createVecs()
    rng = np.random.default_rng(MPI.COMM_WORLD.rank)
    a.array[:] = rng.standard_normal(a.getLocalSize())
    b.array[:] = rng.standard_normal(b.getLocalSize())
    pa, pb, pab = a.duplicate(), a.duplicate(), a.duplicate()
    pc.apply(a, pa)
    pc.apply(b, pb)
    a.axpy(1.0, b)
    pc.apply(a, pab)
    pab.axpy(-1.0, pa)
    pab.axpy(-1.0, pb)
    assert pab.norm() < 1e-10 * pa.norm()  # linear: only round-off (two MUMPS solves)
    per_solve = system.stats.krylov_iterations / system.stats.linear_solves
    # measured 6.5 (13 iterations in 2 Newton steps), serial and 2 ranks; the CG + GAMG stiff
    # field of the first test takes 15 a solve
    assert per_solve <= 12, per_solve
    for v in (a, b, pa, pb, pab):
        v.destroy()
    system.destroy()


def test_fields_that_miss_a_row_are_refused():
    """Every owned row in exactly one field, else a ValueError that gives the counts."""
    system, _, _ = controlled_block(split_options(), True)
    split = system.snes.getKSP().getPC().getPythonContext()
    lo, hi = system._problem.x.getOwnershipRange()
    rows = np.arange(lo, hi)
    with pytest.raises(ValueError, match="every owned row once"):
        split.set_fields(rows[1:], np.zeros(0, np.int64), np.zeros(0, np.int64), system._problem.J)
    system.destroy()
    lu, _, _ = controlled_block({}, False)
    with pytest.raises(ValueError, match="StiffSoftSplit"):
        lu.split_fields(np.zeros(0, np.int64), ["base"])
    lu.destroy()


def test_a_border_that_the_sweep_does_not_reach_is_named():
    """Stiff field first: the top plate (on the soft half) moves no stiff node within one sweep,
    so the control row (stiff nodes only) is zero in the border's Schur complement; the solve
    stops with an error that says so, instead of a singular dense solve (serial and 2 ranks)."""
    system, _, _ = controlled_block(split_options() | {"split_order": "ab"}, True)
    with pytest.raises(ValueError, match="Schur complement is singular"):
        system.solve("travel")
    system.destroy()


def test_a_widened_pattern_keeps_the_near_nullspace():
    """Merging a contact tangent with new entries replaces the matrix's header (MatAXPY with a
    different pattern): the near-nullspace that GAMG reads must survive it (it did not, and
    the split's stiff field then had none)."""
    from shoulder_fem.engine.contact import add_to_pattern

    comm = MPI.COMM_WORLD
    n = 6
    A = PETSc.Mat().createAIJ((n * comm.size,) * 2, nnz=1, comm=comm)
    lo, hi = A.getOwnershipRange()
    for i in range(lo, hi):
        A.setValue(i, i, 2.0)
    A.assemble()
    v = A.createVecLeft()
    v.set(1.0)
    A.setNearNullSpace(PETSc.NullSpace().create(vectors=[v], comm=comm))
    K = PETSc.Mat().createAIJ((n * comm.size,) * 2, nnz=2, comm=comm)
    for i in range(lo, hi):
        K.setValue(i, (i + 1) % (n * comm.size), 1.0)
    K.assemble()
    merged = add_to_pattern(A, K, np.zeros(0, np.int64), comm)
    assert len(merged) == hi - lo  # widened
    assert A.getValue(lo, lo + 1) == 1.0
    near = A.getNearNullSpace()
    assert near.handle and len(near.getVecs()) == 1
    for obj in (A, K, v):
        obj.destroy()
