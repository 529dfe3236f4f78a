"""The driven body's parameters and mesh: a bar clamped to a hub whose rotation is prescribed.

Owns :class:`DrivenBody` (the typed scene parameters, checked together and built once per run),
the displacement space and the clamped face. Both methods (:mod:`.coupled`, :mod:`.decoupled`)
run this one model, so their results compare like for like.
"""

from __future__ import annotations

from dataclasses import dataclass

import dolfinx
import numpy as np
from mpi4py import MPI

from shoulder_fem.engine.rigid import SpinUp
from shoulder_fem.engine.solver import time_grid
from shoulder_fem.meshes.bar import ROOT, build_bar
from shoulder_fem.scene import Scene, SceneError

__all__ = [
    "SPIN_AXES",
    "VARIANTS",
    "DrivenBody",
    "build",
    "clamp_dofs",
    "dof_coordinates",
    "dofs",
    "quadrature",
    "vector_space",
]

#: Spin axes of the ``spin_axis`` parameter: across the bar (z: in-plane bending in x–y, the
#: spinning bar and the spin-up beam) or about the bar's own axis (x: a humerus in internal
#: rotation).
SPIN_AXES = {"transverse": (0.0, 0.0, 1.0), "axial": (1.0, 0.0, 0.0)}

#: Decoupled variants: the paper's eq. (13) as published; the rigid-frame inertia evaluated at the
#: strained position (spin softening); and that plus the geometric stiffness of the centrifugal
#: prestress (stress stiffening).
VARIANTS = ("paper", "spin-softening", "stress-stiffening")


@dataclass(frozen=True)
class DrivenBody:
    """Everything both methods need to run a driven-body scene (SI units)."""

    scene: Scene
    level: str
    mesh: dolfinx.mesh.Mesh
    facet_tags: dolfinx.mesh.MeshTags
    degree: int
    n_axial: int
    density: float
    youngs_modulus: float
    poisson_ratio: float
    inner_radius: float
    outer_radius: float
    side: float
    motion: SpinUp
    times: np.ndarray
    field_times: np.ndarray
    quasi_static: bool
    variant: str = "paper"
    numerical_damping: float = 0.0

    @property
    def spin_axis(self) -> str:
        """Spin axis name: transverse (z, across the bar) or axial (x, the bar's own axis)."""
        return "axial" if abs(self.axis[0]) > 0.5 else "transverse"

    @property
    def axis(self) -> np.ndarray:
        """Unit spin axis (body = inertial components at t = 0), through the origin."""
        return self.motion.axis

    @property
    def area(self) -> float:
        """Section area, m²."""
        return self.side**2

    def analytic_axial_stress(self, r: np.ndarray, omega: float) -> np.ndarray:
        """Steady axial stress σ(r) = ρΩ²(r_out² − r²)/2 (Pa) of a bar spinning at Ω."""
        return 0.5 * self.density * omega**2 * (self.outer_radius**2 - np.asarray(r) ** 2)


def build(scene: Scene, level: str | None, comm: MPI.Comm, method: str | None = None) -> DrivenBody:
    """Check the scene's parameters together and build the mesh of ``level``."""
    p = scene.values()
    lv = scene.level(level)
    if p["outer_radius"] <= p["inner_radius"]:
        raise SceneError(
            f"{scene.where('outer_radius', 'inner_radius')}: "
            f"outer_radius = {p['outer_radius']} m must exceed "
            f"inner_radius = {p['inner_radius']} m"
        )
    if p["time_step"] > p["end_time"]:
        raise SceneError(
            f"{scene.where('time_step', 'end_time')}: "
            f"time_step = {p['time_step']} s exceeds end_time = {p['end_time']} s"
        )
    for key in ("degree", "n_axial", "n_side"):
        if key not in lv or int(lv[key]) < 1:
            raise SceneError(f"{scene.source}: levels.{level}.{key} must be a positive integer")
    times, field_times = time_grid(p["end_time"], p["time_step"], int(p["field_outputs"]))
    mesh, tags = build_bar(
        comm,
        p["inner_radius"],
        p["outer_radius"],
        p["side"],
        int(lv["n_axial"]),
        int(lv["n_side"]),
    )
    return DrivenBody(
        scene=scene,
        level=level or scene.default_level,
        mesh=mesh,
        facet_tags=tags,
        degree=int(lv["degree"]),
        n_axial=int(lv["n_axial"]),
        density=p["density"],
        youngs_modulus=p["youngs_modulus"],
        poisson_ratio=p["poisson_ratio"],
        inner_radius=p["inner_radius"],
        outer_radius=p["outer_radius"],
        side=p["side"],
        motion=SpinUp(
            p["spin_rate"], p["spin_up_time"], axis=SPIN_AXES[p.get("spin_axis", "transverse")]
        ),
        times=times,
        field_times=field_times,
        quasi_static=bool(p["quasi_static"]),
        variant=p.get("decoupled_variant", "paper"),
        numerical_damping=p.get("numerical_damping", 0.0),
    )


def vector_space(model: DrivenBody) -> dolfinx.fem.FunctionSpace:
    """The displacement space: continuous Lagrange (Q_k on hexahedra) of the level's degree."""
    return dolfinx.fem.VectorFunctionSpace(model.mesh, ("Lagrange", model.degree))


def dofs(model: DrivenBody) -> int:
    """Displacement DOFs (global)."""
    V = vector_space(model)
    return V.dofmap.index_map.size_global * V.dofmap.index_map_bs


def clamp_dofs(model: DrivenBody, V: dolfinx.fem.FunctionSpace) -> np.ndarray:
    """Blocked DOFs of the root face (clamped to the hub)."""
    fdim = model.mesh.topology.dim - 1
    return dolfinx.fem.locate_dofs_topological(V, fdim, model.facet_tags.find(ROOT.id))


def quadrature(model: DrivenBody) -> dict:
    """Form-compiler parameters: a fixed quadrature degree (exact for the linear terms)."""
    return {"quadrature_degree": 2 * model.degree}


def dof_coordinates(V: dolfinx.fem.FunctionSpace) -> np.ndarray:
    """Reference coordinates of every (local + ghost) block DOF, shape (n, 3)."""
    return V.tabulate_dof_coordinates()
