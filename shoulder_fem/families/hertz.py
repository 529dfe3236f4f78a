"""The ``hertz`` scene family: an elastic ball pressed on a flat or into a socket, against Hertz.

The verification scene of the contact code (:mod:`shoulder_fem.engine.contact`). Owns Hertz's
solution (:func:`hertz_solution`), :class:`HertzModel` (the typed scene parameters and the
quarter-ball mesh), :class:`HertzProblem` (the ball, and a deformable block if any, driven by
the approach of its top face until the contact force is the scene's) and the run that records
pressure and contact radius against theory.
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

from shoulder_fem.engine.contact import Contact, ContactPair, MeshSurface, Plane, Sphere
from shoulder_fem.engine.solver import ConvergenceError, NonlinearSolver, StepperStats
from shoulder_fem.families.base import Family, RunContext
from shoulder_fem.forms import materials
from shoulder_fem.forms import virtual_power as vp
from shoulder_fem.scene import Scene, SceneError

logger = logging.getLogger(__name__)

#: The quarter model carries a quarter of every force and area.
SYMMETRY_FACTOR = 4.0
#: Secant iterations allowed to match the contact force at one load step.
MAX_FORCE_ITERATIONS = 20
#: Uzawa iterations allowed per solve (augmented Lagrangian).
MAX_UZAWA = 30
#: Deformable flat, first solve from the unloaded state: a sub-step at this fraction of the
#: approach first. (The rigid predictor's initial penetration, the whole approach, sends Newton
#: astray against a mesh master with a stiff penalty: measured at the coarse level with the
#: factor 100, 30 iterations without converging at the approach of F/2, and 10 + 15 iterations
#: with the sub-step.)
COLD_START_FRACTION = 0.2


@dataclass(frozen=True)
class HertzSolution:
    """Hertz theory for a ball on a counterpart (SI units)."""

    contact_radius: float  # a, m
    max_pressure: float  # p0, Pa
    approach: float  # δ = a²/R*, m
    effective_radius: float  # R*, m
    effective_modulus: float  # E*, Pa


def hertz_solution(
    force: float,
    radius: float,
    youngs_modulus: float,
    poisson_ratio: float,
    socket_radius: float | None = None,
    counterpart_youngs_modulus: float | None = None,
    counterpart_poisson_ratio: float = 0.0,
) -> HertzSolution:
    """Hertz's contact radius, peak pressure and approach (flat, or socket of ``socket_radius``).

    The counterpart is rigid unless ``counterpart_youngs_modulus`` is given:
    1/E* = (1 − ν²)/E + (1 − ν₂²)/E₂.
    """
    compliance = (1.0 - poisson_ratio**2) / youngs_modulus
    if counterpart_youngs_modulus is not None:
        compliance += (1.0 - counterpart_poisson_ratio**2) / counterpart_youngs_modulus
    e_star = 1.0 / compliance
    r_eff = radius if socket_radius is None else radius * socket_radius / (socket_radius - radius)
    a = (3.0 * force * r_eff / (4.0 * e_star)) ** (1.0 / 3.0)
    return HertzSolution(a, 3.0 * force / (2.0 * math.pi * a * a), a * a / r_eff, r_eff, e_star)


@dataclass(frozen=True)
class HertzModel:
    """Everything a run needs (SI units)."""

    scene: Scene
    level: str
    geometry: str
    radius: float
    socket_radius: float | None
    youngs_modulus: float
    poisson_ratio: float
    counterpart_youngs_modulus: float | None  # None: rigid
    counterpart_poisson_ratio: float | None
    block_half_width: float | None  # deformable_flat only (m)
    block_depth: float | None
    force: float
    load_steps: int
    contact_method: str
    penalty: float
    gap_tolerance: float
    force_tolerance: float
    degree: int
    h_contact: float
    mesh: dolfinx.mesh.Mesh
    cell_tags: dolfinx.mesh.MeshTags
    facet_tags: dolfinx.mesh.MeshTags

    def theory(self, force: float | None = None) -> HertzSolution:
        """Hertz's solution at ``force`` (default: the scene's force)."""
        return hertz_solution(
            self.force if force is None else force,
            self.radius,
            self.youngs_modulus,
            self.poisson_ratio,
            self.socket_radius,
            self.counterpart_youngs_modulus,
            self.counterpart_poisson_ratio or 0.0,
        )

    @property
    def deformable(self) -> bool:
        """Whether the counterpart is an elastic block of the mesh."""
        return self.counterpart_youngs_modulus is not None

    def master(self) -> Plane | Sphere | MeshSurface:
        """The counterpart: an analytic rigid surface, or the block's top face."""
        from shoulder_fem.meshes.contact_bodies import BLOCK_TOP

        if self.deformable:
            return MeshSurface((BLOCK_TOP.id,))
        if self.socket_radius is None:
            return Plane((0.0, 0.0, 0.0), (0.0, 0.0, 1.0))
        return Sphere((0.0, 0.0, self.socket_radius), self.socket_radius, concave=True)


def build(scene: Scene, level: str | None, comm: MPI.Comm, method: str | None = None) -> HertzModel:
    """Check the parameters together and mesh the quarter ball (and block) of ``level``."""
    from shoulder_fem.meshes.contact_bodies import build_ball_on_block, build_hemisphere

    p = scene.values()
    level = level or scene.default_level
    lv = scene.level(level)
    for key in ("degree", "h_contact", "refine_radius", "h_far"):
        if key not in lv or not float(lv[key]) > 0:
            raise SceneError(f"{scene.source}: levels.{level}.{key} must be given and > 0")
    socket = p["socket_radius"] if p["geometry"] == "socket" else None
    if socket is not None and socket <= p["radius"]:
        raise SceneError(
            f"{scene.where('socket_radius', 'radius')}: socket_radius = {socket} m must exceed "
            f"radius = {p['radius']} m"
        )
    deformable = p["geometry"] == "deformable_flat"
    e2 = p["counterpart_youngs_modulus"] if deformable else None
    nu2 = p["counterpart_poisson_ratio"] if deformable else None
    sol = hertz_solution(
        p["force"], p["radius"], p["youngs_modulus"], p["poisson_ratio"], socket, e2, nu2 or 0.0
    )
    if sol.contact_radius > 0.3 * p["radius"]:
        raise SceneError(
            f"{scene.where('force')}: force = {p['force']} N gives a Hertz contact radius "
            f"{sol.contact_radius:.3g} m > 0.3 R: outside half-space theory; lower the force"
        )
    h_contact = float(lv["h_contact"]) * sol.contact_radius
    h_far = float(lv["h_far"]) * p["radius"]
    refine_radius = float(lv["refine_radius"]) * sol.contact_radius
    width = depth = None
    if deformable:
        width = p["block_half_width"] * sol.contact_radius
        depth = p["block_depth"] * sol.contact_radius
        if not refine_radius < min(width, depth):
            raise SceneError(
                f"{scene.where('block_half_width', 'block_depth')}: the block "
                f"({width:.3g} m wide, {depth:.3g} m deep) must extend beyond the refined "
                f"region (levels.{level}.refine_radius: {refine_radius:.3g} m)"
            )
        mesh, cell_tags, facet_tags = build_ball_on_block(
            comm, p["radius"], width, depth, h_contact, h_far, refine_radius, quarter=True
        )
    else:
        mesh, cell_tags, facet_tags = build_hemisphere(
            comm, p["radius"], h_contact, h_far, refine_radius, quarter=True
        )
    softer = p["youngs_modulus"] if e2 is None else min(p["youngs_modulus"], e2)
    return HertzModel(
        scene=scene,
        level=level,
        geometry=p["geometry"],
        radius=p["radius"],
        socket_radius=socket,
        youngs_modulus=p["youngs_modulus"],
        poisson_ratio=p["poisson_ratio"],
        counterpart_youngs_modulus=e2,
        counterpart_poisson_ratio=nu2,
        block_half_width=width,
        block_depth=depth,
        force=p["force"],
        load_steps=int(p["load_steps"]),
        contact_method=p["contact_method"],
        penalty=p["mesh_penalty_factor" if deformable else "penalty_factor"] * softer / h_contact,
        gap_tolerance=p["gap_tolerance"],
        force_tolerance=p["force_tolerance"],
        degree=int(lv["degree"]),
        h_contact=h_contact,
        mesh=mesh,
        cell_tags=cell_tags,
        facet_tags=facet_tags,
    )


def vector_space(model: HertzModel) -> dolfinx.fem.FunctionSpace:
    """Displacement space: continuous P_k vectors."""
    return dolfinx.fem.VectorFunctionSpace(model.mesh, ("Lagrange", model.degree))


def dofs(model: HertzModel) -> int:
    """Displacement DOFs (global)."""
    V = vector_space(model)
    return V.dofmap.index_map.size_global * V.dofmap.index_map_bs


def internal_power(model: HertzModel, u, w, dx: ufl.Measure) -> ufl.Form:
    """Linear elastic internal power of the ball, and of the block on a deformable flat."""
    from shoulder_fem.meshes.contact_bodies import BALL, BLOCK

    material = materials.LinearElastic(model.youngs_modulus, model.poisson_ratio)
    if model.deformable:
        block = materials.LinearElastic(
            model.counterpart_youngs_modulus, model.counterpart_poisson_ratio
        )
        return vp.internal_power_linear(material, u, w, dx(BALL.id)) + vp.internal_power_linear(
            block, u, w, dx(BLOCK.id)
        )
    return vp.internal_power_linear(material, u, w, dx)


class HertzProblem:
    """The quarter ball (and block) with its contact, driven by the approach δ (collective)."""

    def __init__(self, model: HertzModel, options: dict | None = None):
        from shoulder_fem.meshes.contact_bodies import CONTACT

        self.model = model
        V = self.V = vector_space(model)
        u = self.u = dolfinx.fem.Function(V, name="displacement")
        q = {"quadrature_degree": 2 * (model.degree - 1)}
        dx = ufl.Measure("dx", domain=model.mesh, subdomain_data=model.cell_tags, metadata=q)
        self.internal = internal_power(model, u, ufl.TestFunction(V), dx)
        self._internal_form = dolfinx.fem.form(self.internal, form_compiler_params=q)
        bcs = self.bcs = self._boundary_conditions()
        pair = ContactPair(
            "ball",
            (CONTACT.id,),
            model.master(),
            penalty=model.penalty,
            method=model.contact_method,
            gap_tolerance=model.gap_tolerance,
        )
        self.contact = Contact(V, u, model.facet_tags, [pair], bcs=bcs, quadrature_degree=0)
        force_scale = model.force / SYMMETRY_FACTOR
        self.solver = NonlinearSolver(
            self.internal,
            u,
            bcs,
            name="hertz",
            options={
                "snes_atol": 1e-9 * force_scale,
                "snes_rtol": 1e-9,
                "snes_divergence_tolerance": -1.0,
                # mesh master: the active set settles over more iterations (measured: up to 17)
                **({"snes_max_it": 50} if model.deformable else {}),
                **(options or {}),
            },
            form_compiler_params=q,
            contact=self.contact,
        )
        self.delta = 0.0
        #: the solution before the last one: (approach, displacement array)
        self._previous = (0.0, np.zeros_like(u.x.array))
        self.newton: list[int] = []
        self.uzawa: list[int] = []

    def _boundary_conditions(self) -> list:
        """Symmetry planes, the driven top face and, on a deformable flat, the block's bottom."""
        from shoulder_fem.meshes.contact_bodies import (
            BALL,
            BLOCK_BOTTOM,
            BLOCK_SYM_X,
            BLOCK_SYM_Y,
            SYM_X,
            SYM_Y,
            TOP,
        )

        model, V = self.model, self.V
        mesh = model.mesh
        fdim = mesh.topology.dim - 1
        ft = model.facet_tags
        bcs = []
        sym = ((0, SYM_X, BLOCK_SYM_X), (1, SYM_Y, BLOCK_SYM_Y))
        for comp, *markers in sym:
            facets = np.unique(np.concatenate([ft.find(m.id) for m in markers]))
            Vi, _ = V.sub(comp).collapse()
            dofs_i = dolfinx.fem.locate_dofs_topological((V.sub(comp), Vi), fdim, facets)
            zero = dolfinx.fem.Function(Vi)
            bcs.append(dolfinx.fem.dirichletbc(zero, dofs_i, V.sub(comp)))
        top = dolfinx.fem.locate_dofs_topological(V.sub(2), fdim, ft.find(TOP.id))
        self._top_dofs = top
        self.minus_approach = dolfinx.fem.Constant(mesh, PETSc.ScalarType(0.0))
        bcs.append(dolfinx.fem.dirichletbc(self.minus_approach, top, V.sub(2)))
        self._bottom_dofs = None
        if model.deformable:  # the block's bottom fixed in z
            bottom = dolfinx.fem.locate_dofs_topological(V.sub(2), fdim, ft.find(BLOCK_BOTTOM.id))
            self._bottom_dofs = bottom
            zero = PETSc.ScalarType(0.0)
            bcs.append(dolfinx.fem.dirichletbc(zero, bottom, V.sub(2)))
            # the ball's nodes (blocked indices): the rigid predictor moves them only
            self._ball_nodes = dolfinx.fem.locate_dofs_topological(
                V, mesh.topology.dim, model.cell_tags.find(BALL.id)
            )
        else:
            self._ball_nodes = slice(None)
        return bcs

    def solve(self, delta: float, step: str, cold_start: bool = True) -> float:
        """Drive the top face down by ``delta`` (m); return the total contact force (N).

        Predictor: the ball moved rigidly by the change of approach. With a deformable flat
        (where the rigid move would push the whole increment into the block), the displacement
        interpolated linearly in the approach between the last two solutions (the unloaded state
        counting as one), after, from the unloaded state, a sub-step at
        :data:`COLD_START_FRACTION` of the approach.
        """
        if cold_start and self.model.deformable and self.delta <= 0 < delta:
            self.solve(COLD_START_FRACTION * delta, f"{step} (cold-start sub-step)", False)
        current = (self.delta, self.u.x.array.copy())
        (d0, u0), d1 = self._previous, self.delta
        if self.model.deformable and delta > 0 and d1 > 0 and d1 != d0:
            self.u.x.array[:] += (delta - d1) / (d1 - d0) * (self.u.x.array - u0)
        else:
            self.u.x.array.reshape(-1, 3)[self._ball_nodes, 2] -= delta - d1  # rigid
        self.u.x.scatter_forward()
        self.minus_approach.value = -delta
        self.delta = delta
        for k in range(MAX_UZAWA):
            self.newton.append(self.solver.solve(step=f"{step}, approach {delta:.6g} m"))
            if not self.contact.augmented or self.contact.augment():
                self.uzawa.append(k + 1)
                break
        else:
            raise ConvergenceError(
                f"{step}: penetration above gap_tolerance after {MAX_UZAWA} Uzawa iterations",
                "DIVERGED_UZAWA",
                MAX_UZAWA,
                self.solver.prefix,
            )
        self._previous = current
        return self.contact_force()

    def contact_force(self) -> float:
        """Total (full-ball) contact force along z (N)."""
        return SYMMETRY_FACTOR * float(self.contact.resultants()["ball"]["force"][2])

    def contact_radius(self, res: dict) -> float:
        """Contact radius (m) of the full ball from the quarter's contact area in ``res``."""
        return math.sqrt(SYMMETRY_FACTOR * res["area"] / math.pi)

    def top_reaction(self) -> float:
        """Total force (N, along z) the driven face exerts on the ball, from the FE residual."""
        return self._reaction(self._top_dofs)

    def bottom_reaction(self) -> float | None:
        """Total force (N, along z) the support exerts on the block (None: rigid counterpart)."""
        return None if self._bottom_dofs is None else self._reaction(self._bottom_dofs)

    def _reaction(self, dofs: np.ndarray) -> float:
        vec = fem_petsc.assemble_vector(self._internal_form)
        vec.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        n_owned = self.V.dofmap.index_map.size_local * 3
        local = float(np.sum(vec.array_r[dofs[dofs < n_owned]]))
        vec.destroy()
        return SYMMETRY_FACTOR * self.u.function_space.mesh.comm.allreduce(local, op=MPI.SUM)

    def reach(self, force: float, step: str) -> float:
        """Find the approach giving a contact force ``force`` (secant); return it."""
        model = self.model
        tol = model.force_tolerance * force
        d0 = max(self.delta, 0.0)
        f0 = self.contact_force() if d0 > 0 else 0.0
        # predictor: Hertz's increment of approach from f0 to force
        d1 = d0 + model.theory(force).approach - (model.theory(f0).approach if f0 > 0 else 0.0)
        f1 = self.solve(d1, step)
        for _ in range(MAX_FORCE_ITERATIONS):
            if abs(f1 - force) <= tol:
                return d1
            if f1 != f0 and d1 != d0:
                d2 = d1 + (force - f1) * (d1 - d0) / (f1 - f0)
            else:
                d2 = d1 * 1.1
            if f1 <= 0 or d2 <= 0:  # no contact yet: move by Hertz's estimate
                d2 = d1 + model.theory(force).approach
            d0, f0, d1 = d1, f1, d2
            f1 = self.solve(d1, step)
        if abs(f1 - force) <= tol:
            return d1
        raise ConvergenceError(
            f"{step}: contact force {f1:.6g} N, target {force:.6g} N",
            "DIVERGED_FORCE_MATCH",
            MAX_FORCE_ITERATIONS,
            self.solver.prefix,
        )

    def pressure_profile(self) -> tuple[np.ndarray, np.ndarray]:
        """(r, p) of the active quadrature points, on rank 0 sorted by r (others: empty)."""
        st = self.contact.point_state(0)
        xq, p = st["xq"], st["p"]
        a = p > 0
        r = np.hypot(xq[a, 0], xq[a, 1])
        comm = self.u.function_space.mesh.comm
        parts = comm.gather((r, p[a]), root=0)
        if comm.rank != 0:
            return np.zeros(0), np.zeros(0)
        r = np.concatenate([x[0] for x in parts])
        p = np.concatenate([x[1] for x in parts])
        order = np.argsort(r)
        return r[order], p[order]


def run_coupled(model: HertzModel, run: RunContext) -> None:
    """Press the ball to the scene's force in ``load_steps`` increments; record against Hertz."""
    recorder = run.recorder
    monitor = run.monitor
    fields_dir = run.fields
    options = run.options
    problem = HertzProblem(model, options)
    recorder.set_parameter("socket_radius", model.socket_radius, "m")
    if model.deformable:
        recorder.set_parameter("counterpart_youngs_modulus", model.counterpart_youngs_modulus, "Pa")
        recorder.set_parameter("counterpart_poisson_ratio", model.counterpart_poisson_ratio, "1")
        recorder.set_parameter("block_half_width_m", model.block_half_width, "m")
        recorder.set_parameter("block_depth_m", model.block_depth, "m")
    else:
        recorder.set_parameter("counterpart_youngs_modulus", "rigid", "Pa")
        recorder.set_parameter("counterpart_poisson_ratio", "rigid", "1")
        recorder.set_parameter("block_half_width", None, "1")
        recorder.set_parameter("block_depth", None, "1")
    recorder.set_parameter("penalty", model.penalty, "Pa/m")
    recorder.set_parameter("h_contact", model.h_contact, "m")
    reached = 0.0
    try:
        for k in range(1, model.load_steps + 1):
            force = model.force * k / model.load_steps
            problem.reach(force, step=f"load step {k}/{model.load_steps}")
            reached = force
            res = problem.contact.resultants()["ball"]
            theory = model.theory(force)
            radius = problem.contact_radius(res)
            recorder.add_series_point("max_contact_pressure", force, res["max_pressure"], "N", "Pa")
            recorder.add_series_point("hertz_max_pressure", force, theory.max_pressure, "N", "Pa")
            recorder.add_series_point("contact_radius", force, radius, "N", "m")
            recorder.add_series_point(
                "hertz_contact_radius", force, theory.contact_radius, "N", "m"
            )
            recorder.add_series_point("approach", force, problem.delta, "N", "m")
            monitor.sample()
            logger.info(
                "hertz: F = %.6g N, p_max = %.6g Pa (Hertz %.6g), a = %.6g m (Hertz %.6g)",
                force,
                res["max_pressure"],
                theory.max_pressure,
                radius,
                theory.contact_radius,
            )
    finally:
        _record(model, problem, recorder, reached)
    _write_fields(problem, fields_dir)
    problem.solver.destroy()


def _record(model: HertzModel, problem: HertzProblem, recorder, reached: float) -> None:
    res = problem.contact.resultants()["ball"]
    theory = model.theory(reached) if reached > 0 else None
    radius = problem.contact_radius(res)
    recorder.set_probe("force_reached", reached, "N")
    recorder.set_probe("contact_force", SYMMETRY_FACTOR * float(res["force"][2]), "N")
    recorder.set_probe("top_reaction_force", problem.top_reaction(), "N")
    bottom = problem.bottom_reaction()
    if bottom is not None:
        recorder.set_probe("bottom_reaction_force", bottom, "N")
    recorder.set_probe("max_contact_pressure", res["max_pressure"], "Pa")
    recorder.set_probe("contact_radius", radius, "m")
    recorder.set_probe("contact_area", SYMMETRY_FACTOR * res["area"], "m^2")
    recorder.set_probe("approach", problem.delta, "m")
    recorder.set_probe("max_penetration", res["max_penetration"], "m")
    problem.contact.record(recorder, prefix="quarter_")  # the modelled quarter's resultants
    if theory is not None:
        recorder.set_probe("hertz_max_pressure", theory.max_pressure, "Pa")
        recorder.set_probe("hertz_contact_radius", theory.contact_radius, "m")
        recorder.set_probe("hertz_approach", theory.approach, "m")
        recorder.set_probe("hertz_effective_modulus", theory.effective_modulus, "Pa")
        recorder.set_probe(
            "max_pressure_rel_error", res["max_pressure"] / theory.max_pressure - 1.0, "1"
        )
        recorder.set_probe("contact_radius_rel_error", radius / theory.contact_radius - 1.0, "1")
    r, p = problem.pressure_profile()
    recorder.set_series("pressure_profile", r, p, "m", "Pa")
    if theory is not None and len(r):
        rr = np.linspace(0.0, theory.contact_radius, 50)
        pp = theory.max_pressure * np.sqrt(np.clip(1 - (rr / theory.contact_radius) ** 2, 0, 1))
        recorder.set_series("hertz_pressure_profile", rr, pp, "m", "Pa")
        if problem.u.function_space.mesh.comm.rank == 0:
            from shoulder_fem.io.plots import plot_pressure_profile

            plot_pressure_profile(
                r,
                p,
                (rr, pp),
                recorder.folder / "pressure_profile.png",
                title=f"hertz ({model.geometry}, {model.level}): F = {reached:.4g} N",
            )
    stats = problem.solver.stats
    recorder.add_solver_counts(stats, StepperStats(steps=model.load_steps))
    recorder.extra("newton_iterations_per_solve", list(problem.newton))
    recorder.extra("uzawa_iterations_per_solve", list(problem.uzawa))
    cs = problem.contact.stats
    recorder.extra(
        "contact",
        {
            "evaluations": cs.evaluations,
            "search_s": cs.search_s,
            "assembly_s": cs.assembly_s,
            "pattern_merges": cs.pattern_merges,
        },
    )


def _write_fields(problem: HertzProblem, fields_dir) -> None:
    from shoulder_fem.io.fields import FieldWriter

    mesh = problem.V.mesh
    V1 = dolfinx.fem.VectorFunctionSpace(mesh, ("Lagrange", 1))
    u1 = dolfinx.fem.Function(V1, name="displacement")
    u1.interpolate(problem.u)
    pressure, shear = problem.contact.pressure_fields()
    with FieldWriter(mesh.comm, mesh, fields_dir / "contact.xdmf") as writer:
        writer.write([u1, pressure, shear], 1.0)


# One method: there is no rigid motion to split, so "coupled" is the only pipeline.
FAMILY = Family(name="hertz", build=build, methods={"coupled": run_coupled}, dofs=dofs)
