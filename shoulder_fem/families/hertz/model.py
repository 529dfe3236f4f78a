"""The hertz scene's typed parameters and mesh (:class:`HertzModel`, :func:`build`)."""

from __future__ import annotations

from dataclasses import dataclass

import dolfinx
import ufl
from mpi4py import MPI

from shoulder_fem.engine.contact import MeshSurface, Plane, Sphere
from shoulder_fem.families.hertz.theory import HertzSolution, hertz_solution
from shoulder_fem.forms import materials
from shoulder_fem.forms import virtual_power as vp
from shoulder_fem.scene import Scene, SceneError

#: The quarter model carries a quarter of every force and area.
SYMMETRY_FACTOR = 4.0


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
