"""The ``tied-block`` scene family: a neo-Hookean block twisted through a plate on its top.

Owns :class:`TiedBlock` (the typed scene parameters and both meshes), the measures both methods
report (:class:`FaceMeasures`), and the two methods: ``decoupled`` ties the block's top face to
a rigid plate (six DOFs), ``coupled`` meshes the plate as a stiff deformable layer. The plate is
loaded by a torque about the block's axis or, with ``rotation_driven``, turned by a prescribed
angle; Saint-Venant's linear twist is the reference.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import dolfinx
import dolfinx.fem.petsc as fem_petsc
import numpy as np
import ufl
from mpi4py import MPI
from petsc4py import PETSc

from shoulder_fem.engine.fem import constant, owned_flags
from shoulder_fem.engine.rigid_system import RigidBody, RigidSystem, Tie
from shoulder_fem.engine.so3 import rotation_about
from shoulder_fem.engine.solver import NonlinearSolver, StepperStats, march
from shoulder_fem.families.base import Family, RunContext, SolverOptions
from shoulder_fem.forms import materials
from shoulder_fem.forms import virtual_power as vp
from shoulder_fem.meshes.block import BASE, BLOCK, PLATE, PLATE_TOP, TOP, build_block
from shoulder_fem.scene import Scene, SceneError

logger = logging.getLogger(__name__)

#: Saint-Venant torsion constant of a square section, J = β a⁴ (Timoshenko & Goodier).
SQUARE_TORSION_BETA = 0.1406
#: Poisson's ratio of the coupled method's stiff plate.
PLATE_POISSON = 0.3


@dataclass(frozen=True)
class TiedBlock:
    """Everything both methods need to run a tied-block scene (SI units)."""

    scene: Scene
    level: str
    side: float
    length: float
    shear_modulus: float
    bulk_modulus: float
    torque: float
    plate_thickness: float
    plate_stiffness_ratio: float
    rotation_driven: bool
    prescribed_rotation: float
    load_steps: int
    degree: int
    mesh: dolfinx.mesh.Mesh
    facet_tags: dolfinx.mesh.MeshTags
    plated_mesh: dolfinx.mesh.Mesh
    plated_cell_tags: dolfinx.mesh.MeshTags
    plated_facet_tags: dolfinx.mesh.MeshTags

    @property
    def saint_venant_rotation(self) -> float:
        """Linear Saint-Venant twist of the top, T L / (μ β a⁴) (rad)."""
        return self.torque * self.length / (self.shear_modulus * SQUARE_TORSION_BETA * self.side**4)

    def load_factors(self) -> np.ndarray:
        """Load factors 0 … 1 of the load steps."""
        return np.linspace(0.0, 1.0, self.load_steps + 1)

    def quadrature(self) -> dict:
        """Form-compiler parameters: Gauss degree 2k (3×3×3 points for Q2)."""
        return {"quadrature_degree": 2 * self.degree}

    def block_material(self, mesh: dolfinx.mesh.Mesh | None = None) -> materials.NeoHookean:
        """Neo-Hookean block: C10 = μ/2 (Pa), κ (Pa).

        With ``mesh`` the moduli are ``Constant``s, so that one compiled form serves every
        parameter value.
        """
        c10, kappa = self.shear_modulus / 2, self.bulk_modulus
        if mesh is not None:
            c10, kappa = constant(mesh, c10), constant(mesh, kappa)
        return materials.NeoHookean(c10=c10, bulk_modulus=kappa)

    def plate_material(self, mesh: dolfinx.mesh.Mesh | None = None) -> materials.NeoHookean:
        """The stiff plate of the coupled method (compressible, ν = 0.3).

        Young's modulus ``plate_stiffness_ratio`` times the block's small-strain
        E = 9κμ/(3κ + μ) (Pa). Compressible so that its bulk modulus, and with it the residual's
        round-off floor, grows only with the ratio.
        """
        mu, kappa = self.shear_modulus, self.bulk_modulus
        e_block = 9 * kappa * mu / (3 * kappa + mu)
        law = materials.NeoHookean.from_young(self.plate_stiffness_ratio * e_block, PLATE_POISSON)
        if mesh is None:
            return law
        return materials.NeoHookean(constant(mesh, law.c10), constant(mesh, law.bulk_modulus))

    def force_tolerance(self, coupled: bool = False) -> float:
        """Absolute Newton tolerance on the residual (N): 1e-13 κ a², κ the largest bulk modulus.

        The residual's round-off floor is set by the stiffest (volumetric) forces: about
        1e-15 κ a² on the coarse mesh, growing with the number of nodes; 1e-13 stays above it.
        """
        kappa = self.bulk_modulus
        if coupled:
            kappa = max(kappa, float(self.plate_material().bulk_modulus))
        return 1e-13 * kappa * self.side**2


def build(scene: Scene, level: str | None, comm: MPI.Comm, method: str | None = None) -> TiedBlock:
    """Check the scene's parameters together and build both meshes of ``level``."""
    p = scene.values()
    lv = scene.level(level)
    for key in ("degree", "n_side", "n_axial", "n_plate"):
        if key not in lv or int(lv[key]) < 1:
            raise SceneError(f"{scene.source}: levels.{level}.{key} must be a positive integer")
    if p["plate_thickness"] >= p["length"]:
        raise SceneError(
            f"{scene.where('plate_thickness', 'length')}: plate_thickness = "
            f"{p['plate_thickness']} m must be smaller than length = {p['length']} m"
        )
    args = (comm, p["side"], p["length"], int(lv["n_side"]), int(lv["n_axial"]))
    mesh, _, facet_tags = build_block(*args)
    plated, plated_cells, plated_facets = build_block(
        *args, plate_thickness=p["plate_thickness"], n_plate=int(lv["n_plate"])
    )
    return TiedBlock(
        scene=scene,
        level=level or scene.default_level,
        side=p["side"],
        length=p["length"],
        shear_modulus=p["shear_modulus"],
        bulk_modulus=p["bulk_modulus"],
        torque=p["torque"],
        plate_thickness=p["plate_thickness"],
        plate_stiffness_ratio=p["plate_stiffness_ratio"],
        rotation_driven=bool(p["rotation_driven"]),
        prescribed_rotation=p["prescribed_rotation"],
        load_steps=int(p["load_steps"]),
        degree=int(lv["degree"]),
        mesh=mesh,
        facet_tags=facet_tags,
        plated_mesh=plated,
        plated_cell_tags=plated_cells,
        plated_facet_tags=plated_facets,
    )


def vector_space(mesh: dolfinx.mesh.Mesh, degree: int) -> dolfinx.fem.FunctionSpace:
    """Displacement space: continuous Q_k vectors."""
    return dolfinx.fem.VectorFunctionSpace(mesh, ("Lagrange", degree))


def dofs(model: TiedBlock) -> int:
    """Displacement DOFs of the block (global): the size both methods share."""
    V = vector_space(model.mesh, model.degree)
    return V.dofmap.index_map.size_global * V.dofmap.index_map_bs


# ---- measures shared by both methods ------------------------------------------------------


class FaceMeasures:
    """Rotation and reactions measured on node sets of ``u``'s space (collective calls).

    Args:
        u: Displacement (m).
        top_nodes: Owned block-DOF indices of the block's top face (z = L).
        base_nodes: Owned block-DOF indices of the base (z = 0).
    """

    def __init__(self, u: dolfinx.fem.Function, top_nodes: np.ndarray, base_nodes: np.ndarray):
        self.u = u
        self.comm = u.function_space.mesh.comm
        n = len(u.x.array) // 3
        self.X = u.function_space.tabulate_dof_coordinates()[:n]
        self.top, self.base = top_nodes, base_nodes

    def plate_rotation(self) -> float:
        """Rotation about z (rad) fitted to the top-face nodes: exact for a rigid rotation.

        θ = atan2(Σ (X̃ × x̃)_z, Σ X̃·x̃) over in-plane positions relative to their centroids.
        """
        X = self.X[self.top, :2]
        x = X + self.u.x.array.reshape(-1, 3)[self.top, :2]
        n = self.comm.allreduce(len(X), op=MPI.SUM)
        Xc = self.comm.allreduce(X.sum(axis=0), op=MPI.SUM) / n
        xc = self.comm.allreduce(x.sum(axis=0), op=MPI.SUM) / n
        X, x = X - Xc, x - xc
        s = self.comm.allreduce(
            np.array([np.sum(X[:, 0] * x[:, 1] - X[:, 1] * x[:, 0]), np.sum(X * x)]), op=MPI.SUM
        )
        return math.atan2(s[0], s[1])

    def axial_displacement(self) -> float:
        """Mean z-displacement of the top-face nodes (m)."""
        uz = self.u.x.array.reshape(-1, 3)[self.top, 2]
        total = self.comm.allreduce(np.array([uz.sum(), len(uz)]), op=MPI.SUM)
        return float(total[0] / total[1])

    def base_axial_force(self, residual: PETSc.Vec) -> float:
        """Axial (z) force (N) the base exerts on the block, from the assembled FE residual."""
        local = float(residual.array_r.reshape(-1, 3)[self.base, 2].sum())
        return self.comm.allreduce(local, op=MPI.SUM)

    def base_torque(self, residual: PETSc.Vec) -> float:
        """Torque about z (N·m) the base exerts on the block, from the assembled FE residual."""
        f = residual.array_r.reshape(-1, 3)[self.base]
        X = self.X[self.base]
        local = float(np.sum(X[:, 0] * f[:, 1] - X[:, 1] * f[:, 0]))
        return self.comm.allreduce(local, op=MPI.SUM)


def _owned_nodes_on(V, tags, tag: int) -> np.ndarray:
    """Owned block DOFs of the facets tagged ``tag`` (marked from every rank's facets)."""
    fdim = V.mesh.topology.dim - 1
    dofs_ = dolfinx.fem.locate_dofs_topological(V, fdim, tags.find(tag))
    imap = V.dofmap.index_map
    return np.flatnonzero(owned_flags(imap, dofs_, V.mesh.comm)[: imap.size_local])


def _record(model, recorder, measures, lam, base_torque) -> None:
    x = lam * (model.prescribed_rotation if model.rotation_driven else model.torque)
    x_unit = "rad" if model.rotation_driven else "N*m"
    recorder.add_series_point("plate_rotation", x, measures.plate_rotation(), x_unit, "rad")
    recorder.add_series_point("base_reaction_torque", x, base_torque, x_unit, "N*m")


def _probes(model, recorder, measures, residual, lam) -> None:
    recorder.set_probe("plate_rotation", measures.plate_rotation(), "rad")
    recorder.set_probe("base_reaction_torque", measures.base_torque(residual), "N*m")
    recorder.set_probe("base_reaction_axial_force", measures.base_axial_force(residual), "N")
    recorder.set_probe("plate_axial_displacement", measures.axial_displacement(), "m")
    recorder.set_probe("load_factor", lam, "1")
    if not model.rotation_driven:
        recorder.set_probe("plate_rotation_saint_venant", lam * model.saint_venant_rotation, "rad")


def twist_predictor(u: dolfinx.fem.Function, length: float, angle: float) -> None:
    """Turn every node's current position about the z axis by ``angle`` z/L (rad).

    The start of a load step: the increment of a twist is mostly a rotation growing along the
    block, and applying it as exact rotations (not linearised) keeps the nearly incompressible
    block free of spurious volume change, so Newton starts close to the solution.
    """
    n = len(u.x.array) // 3
    X = u.function_space.tabulate_dof_coordinates()[:n]
    x = X + u.x.array.reshape(-1, 3)
    a = angle * np.clip(X[:, 2] / length, 0.0, 1.0)
    c, s = np.cos(a), np.sin(a)
    turned = np.column_stack([c * x[:, 0] - s * x[:, 1], s * x[:, 0] + c * x[:, 1], x[:, 2]])
    u.x.array[:] = (turned - X).ravel()
    u.x.scatter_forward()


def _twist_increment(model: TiedBlock, measures: FaceMeasures, l0: float, l1: float) -> float:
    """Predicted increment of the plate rotation from load factor l0 to l1 (rad)."""
    if model.rotation_driven:
        return (l1 - l0) * model.prescribed_rotation
    if l0 > 0:
        return (l1 - l0) / l0 * measures.plate_rotation()
    return (l1 - l0) * model.saint_venant_rotation


def _write_fields(model, mesh, u, fields_dir) -> None:
    from shoulder_fem.io.fields import FieldWriter

    V1 = dolfinx.fem.VectorFunctionSpace(mesh, ("Lagrange", 1))
    u1 = dolfinx.fem.Function(V1, name="displacement")
    u1.interpolate(u)
    with FieldWriter(mesh.comm, mesh, fields_dir / "displacement.xdmf") as writer:
        writer.write([u1], 1.0)


# ---- decoupled: rigid plate ---------------------------------------------------------------


def make_rigid_system(model: TiedBlock, options: dict | None = None):
    """The block, its rigid plate (tied to the top face) and the fixed base.

    Returns:
        ``(system, plate, u)``.
    """
    mesh = model.mesh
    V = vector_space(mesh, model.degree)
    u = dolfinx.fem.Function(V, name="displacement")
    w = ufl.TestFunction(V)
    dx = ufl.Measure("dx", domain=mesh, metadata=model.quadrature())
    residual = vp.internal_power_finite(model.block_material(mesh), u, w, dx)
    plate = RigidBody(
        "plate", reference_point=(0.0, 0.0, model.length), prescribed=model.rotation_driven
    )
    system = RigidSystem(
        [plate],
        u=u,
        residual=residual,
        surfaces={"base": (model.facet_tags, BASE.id), "top": (model.facet_tags, TOP.id)},
        ties=[Tie("plate", "top")],
        fixed=["base"],
        name="tiedblock_rigid",
        options={"snes_atol": model.force_tolerance(), **(options or {})},
        form_compiler_params=model.quadrature(),
    )
    return system, plate, u


def run_decoupled(model: TiedBlock, run: RunContext) -> None:
    """The plate as a rigid body (six DOFs): reduced system, torque or prescribed rotation."""
    recorder = run.recorder
    monitor = run.monitor
    fields_dir = run.fields
    options = run.options
    system, plate, u = make_rigid_system(model, options)
    V = u.function_space
    measures = FaceMeasures(
        u,
        _owned_nodes_on(V, model.facet_tags, TOP.id),
        _owned_nodes_on(V, model.facet_tags, BASE.id),
    )
    ez = np.array([0.0, 0.0, 1.0])
    state = {"lam": 0.0}

    def advance(l0: float, l1: float) -> None:
        turn = _twist_increment(model, measures, l0, l1)
        twist_predictor(u, model.length, turn)
        system.move("plate", plate.translation, rotation_about(ez, turn) @ plate.rotation)
        if model.rotation_driven:
            plate.prescribe(np.zeros(3), rotation_about(ez, l1 * model.prescribed_rotation))
        else:
            plate.moment = l1 * model.torque * ez
        its = system.solve(step=f"load factor {l1:.4g}")
        state["lam"] = l1
        logger.info("tied-block decoupled: load factor %.4g, %d Newton iterations", l1, its)

    def on_step(lam: float) -> None:
        _record(model, recorder, measures, lam, measures.base_torque(system.assembled_residual()))
        monitor.sample()

    stats = StepperStats()
    try:
        march(model.load_factors(), advance, system.snapshot, system.restore, on_step, stats=stats)
    finally:
        _probes(model, recorder, measures, system.assembled_residual(), state["lam"])
        bal = system.balance("plate")
        recorder.set_probe("plate_tie_torque", float(bal.tie_moment[2]), "N*m")
        recorder.set_probe("plate_tie_axial_force", float(bal.tie_force[2]), "N")
        recorder.set_probe("tied_distance_error", tied_distance_error(system, "plate"), "1")
        recorder.extra(
            "plate_balance",
            {
                "tie_force": bal.tie_force,
                "tie_moment": bal.tie_moment,
                "applied_moment": bal.applied_moment,
                "force_sum": bal.force_sum,
                "moment_sum": bal.moment_sum,
            },
        )
        recorder.extra("newton_residual_histories", system.stats.residual_histories)
        recorder.add_solver_counts(system.stats, stats)
        recorder.extra("newton_iterations_per_step", list(system.stats.history))
    _write_fields(model, model.mesh, u, fields_dir)
    system.destroy()


def tied_distance_error(system: RigidSystem, body: str) -> float:
    """Largest relative change of the mutual distances of the nodes tied to ``body``."""
    X, x = system.tied_positions(body)
    D0 = np.linalg.norm(X[:, None, :] - X[None, :, :], axis=-1)
    D = np.linalg.norm(x[:, None, :] - x[None, :, :], axis=-1)
    off = D0 > 0
    return float(np.max(np.abs(D[off] - D0[off]) / D0[off]))


# ---- coupled: stiff deformable plate ------------------------------------------------------


@dataclass(frozen=True)
class PlatedBlock:
    """The coupled method's problem: the block and its stiff plate, one finite-strain solve.

    Attributes:
        u: the displacement (m) on the plated mesh.
        solver: Newton on the whole residual.
        residual_form: the compiled residual (for the base reactions).
        torque: the torque T (N·m) the top traction applies about the axis.
        u_top: the prescribed displacement of the plate's top face (rotation-driven scenes).
        top_dofs: the blocked DOFs of the plate's top face.
    """

    u: dolfinx.fem.Function
    solver: NonlinearSolver
    residual_form: dolfinx.fem.FormMetaClass
    torque: dolfinx.fem.Constant
    u_top: dolfinx.fem.Function
    top_dofs: np.ndarray

    def assembled_residual(self) -> PETSc.Vec:
        """The FE residual (N) at the current ``u``, without boundary conditions (destroy it)."""
        vec = fem_petsc.assemble_vector(self.residual_form)
        vec.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        return vec


def make_plated_block(model: TiedBlock, options: SolverOptions | None = None) -> PlatedBlock:
    """The block with its plate as a layer of elements, base fixed, torque traction on top.

    The traction is t = (T/J_p) e_z × (x − c), J_p = a⁴/6 the polar moment of the top face, x
    the current position, so the moment stays T e_z as the plate turns. Rotation-driven scenes
    prescribe the top face's displacement instead.
    """
    mesh = model.plated_mesh
    V = vector_space(mesh, model.degree)
    u = dolfinx.fem.Function(V, name="displacement")
    w = ufl.TestFunction(V)
    q = model.quadrature()
    dx = ufl.Measure("dx", domain=mesh, subdomain_data=model.plated_cell_tags, metadata=q)
    ds = ufl.Measure("ds", domain=mesh, subdomain_data=model.plated_facet_tags, metadata=q)
    torque = dolfinx.fem.Constant(mesh, PETSc.ScalarType(0.0))
    polar = model.side**4 / 6.0
    x = ufl.SpatialCoordinate(mesh) + u
    ez = ufl.as_vector((0.0, 0.0, 1.0))
    traction = torque / polar * ufl.cross(ez, x)
    residual = (
        vp.internal_power_finite(model.block_material(mesh), u, w, dx(BLOCK.id))
        + vp.internal_power_finite(model.plate_material(mesh), u, w, dx(PLATE.id))
        - vp.traction_power(traction, w, ds(PLATE_TOP.id))
    )
    fdim = mesh.topology.dim - 1
    base_dofs = dolfinx.fem.locate_dofs_topological(V, fdim, model.plated_facet_tags.find(BASE.id))
    bcs = [dolfinx.fem.dirichletbc(np.zeros(3, dtype=PETSc.ScalarType), base_dofs, V)]
    u_top = dolfinx.fem.Function(V)
    top_dofs = dolfinx.fem.locate_dofs_topological(
        V, fdim, model.plated_facet_tags.find(PLATE_TOP.id)
    )
    if model.rotation_driven:
        bcs.append(dolfinx.fem.dirichletbc(u_top, top_dofs))
    solver = NonlinearSolver(
        residual,
        u,
        bcs,
        name="tiedblock_coupled",
        options={
            "snes_atol": model.force_tolerance(coupled=True),
            "snes_divergence_tolerance": -1.0,
            **(options or {}),
        },
        form_compiler_params=q,
    )
    residual_form = dolfinx.fem.form(residual, form_compiler_params=q)
    return PlatedBlock(u, solver, residual_form, torque, u_top, top_dofs)


def run_coupled(model: TiedBlock, run: RunContext) -> None:
    """The plate as a stiff deformable layer, everything one finite-strain solve."""
    recorder = run.recorder
    monitor = run.monitor
    block = make_plated_block(model, run.options)
    u, solver = block.u, block.solver
    V = u.function_space
    measures = FaceMeasures(
        u,
        _owned_nodes_on(V, model.plated_facet_tags, TOP.id),
        _owned_nodes_on(V, model.plated_facet_tags, BASE.id),
    )
    Xd = V.tabulate_dof_coordinates()
    top_dofs = block.top_dofs
    state = {"lam": 0.0}
    ezv = np.array([0.0, 0.0, 1.0])

    def advance(l0: float, l1: float) -> None:
        twist_predictor(u, model.length, _twist_increment(model, measures, l0, l1))
        if model.rotation_driven:
            R = rotation_about(ezv, l1 * model.prescribed_rotation)
            block.u_top.x.array[:] = (Xd @ R.T - Xd).ravel()
            u.x.array.reshape(-1, 3)[top_dofs] = Xd[top_dofs] @ R.T - Xd[top_dofs]
        else:
            block.torque.value = l1 * model.torque
        its = solver.solve(step=f"load factor {l1:.4g}")
        state["lam"] = l1
        logger.info("tied-block coupled: load factor %.4g, %d Newton iterations", l1, its)

    def on_step(lam: float) -> None:
        vec = block.assembled_residual()
        _record(model, recorder, measures, lam, measures.base_torque(vec))
        vec.destroy()
        monitor.sample()

    stats = StepperStats()
    try:
        march(
            model.load_factors(),
            advance,
            lambda: u.x.array.copy(),
            lambda s: u.x.array.__setitem__(slice(None), s),
            on_step,
            stats=stats,
        )
    finally:
        vec = block.assembled_residual()
        _probes(model, recorder, measures, vec, state["lam"])
        vec.destroy()
        recorder.add_solver_counts(solver.stats, stats)
        recorder.extra("newton_iterations_per_step", list(solver.stats.history))
    _write_fields(model, model.plated_mesh, u, run.fields)
    solver.destroy()


FAMILY = Family(
    name="tied-block",
    build=build,
    methods={"coupled": run_coupled, "decoupled": run_decoupled},
    dofs=dofs,
)
