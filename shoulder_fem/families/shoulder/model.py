"""The ``shoulder`` family's model: its typed parameters and the meshes each method needs.

The paper's glenohumeral internal rotation: humerus and scapula (bone), the two cartilages and
three rotator-cuff muscles (:mod:`shoulder_fem.meshes.shoulder`), the humerus turned by the
subscapularis. :func:`build` reads the scene once into :class:`ShoulderParameters` and meshes the
joint for one method; the bodies' interactions are in :mod:`.interactions`, the stepping in
:mod:`.stepping`, the two methods in :mod:`.coupled` and :mod:`.decoupled`.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, field, fields
from pathlib import Path

import dolfinx
import numpy as np
import ufl
from mpi4py import MPI

from shoulder_fem.families.shoulder import mesh_store
from shoulder_fem.families.shoulder.geometry import glenoid_frame, humeral_cap
from shoulder_fem.io import ct
from shoulder_fem.meshes import shoulder as S
from shoulder_fem.scene import Scene, SceneError

__all__ = [
    "DETACHED",
    "Displacement",
    "ShoulderModel",
    "ShoulderParameters",
    "build",
    "check_bench",
    "resolve",
    "displacement",
    "dofs",
    "head_tags",
    "scapula_at",
]

#: The bonded interface cut open in the coupled mesh: the driven origin plate is not bone.
DETACHED = (("subscapularis_origin", "subscapularis"),)

_TYPES = {"float": float, "int": int, "str": str}


@dataclass(frozen=True)
class ShoulderParameters:
    """The study's scene parameters (the geometry's are :class:`meshes.shoulder.ShoulderGeometry`).

    Fields are named as the scene keys; SI values (angles in rad, lengths in m, stiffnesses in
    N/m, penalties in Pa/m, time in s).
    """

    final_angle: float
    angle_step: float
    max_angle_step: float
    output_angle: float
    max_cutbacks: int
    contact_penalty: float
    muscle_contact: str
    contact_surfaces: str
    muscle_contact_surfaces: str
    muscle_contact_penalty: float
    muscle_contact_depth: float
    muscle_contact_smoothing: float
    contact_quadrature: int
    cartilage_c10: float
    muscle_alpha: float
    muscle_beta: float
    soft_tissue_formulation: str
    soft_tissue_bulk_ratio: float
    soft_tissue_pressure: str
    soft_tissue_linear_solve: str
    soft_tissue_pointwise_bulk_ratio: float
    soft_tissue_volume_tolerance: float
    soft_tissue_penalty_raise: float
    soft_tissue_multiplier_prediction: str
    quadrature_degree: int
    trial_check: str
    spring_length: float
    scapula_spring_stiffness: float
    ap_spring_stiffness: float
    humerus_spring_stiffness: float
    humerus_horizontal_stiffness: float
    scapula_modulus_factor: float
    humerus_modulus_factor: float
    rotation_duration: float
    nodal_stress: str
    coupled_solver: str
    part2_solver: str
    part2_level: str
    part1_bones: str
    ct_image: str
    ct_density_intercept: float
    ct_density_slope: float

    @classmethod
    def from_values(cls, values: dict) -> ShoulderParameters:
        """The parameters from scene values (SI); keys that are no field are ignored.

        Raises:
            KeyError: A parameter of the study is missing from ``values``.
        """
        missing = [f.name for f in fields(cls) if f.name not in values]
        if missing:
            raise KeyError(f"shoulder scene: missing parameter(s) {', '.join(missing)}")
        return cls(**{f.name: _TYPES[f.type](values[f.name]) for f in fields(cls)})

    @property
    def humeral_head_contact(self) -> bool:
        """Whether the rotator cuff slides on the humeral head (``muscle_contact``)."""
        return self.muscle_contact in ("humeral-head", "bones")

    @property
    def incompressible_cartilage(self) -> bool:
        """Whether the cartilages are incompressible (``soft_tissue_formulation``, Table I)."""
        return self.soft_tissue_formulation in ("incompressible", "incompressible-cartilage")

    @property
    def incompressible_muscles(self) -> bool:
        """Whether the muscles are incompressible too (``soft_tissue_formulation``)."""
        return self.soft_tissue_formulation == "incompressible"

    @property
    def compliant_part1(self) -> bool:
        """Whether part 1 sees the bones' compliance (``part1_bones``, :mod:`.correction`)."""
        return self.part1_bones != "rigid"

    @property
    def part1_humerus(self) -> bool:
        """Whether the compliant part 1 sees the humerus's compliance too (:mod:`.humerus`)."""
        return self.part1_bones == "compliant"

    @property
    def scapula_contact(self) -> bool:
        """Whether the rotator cuff slides on the scapula too (``muscle_contact = bones``)."""
        return self.muscle_contact == "bones"

    def calibration(self) -> ct.Calibration:
        """The HU calibration of the bones' density (``ct_density_*``)."""
        return ct.Calibration(self.ct_density_intercept, self.ct_density_slope)

    def quadrature(self) -> dict:
        """Form-compiler parameters of the volume forms (``quadrature_degree``)."""
        return {"quadrature_degree": self.quadrature_degree}


@dataclass
class ShoulderModel:
    """What :func:`build` makes for one method: the parameters and the meshes it needs."""

    scene: Scene
    level: str
    comm: MPI.Comm
    method: str
    params: ShoulderParameters
    geometry: S.ShoulderGeometry
    meshes: dict
    shaft_axis: np.ndarray  # unit, pointing proximally: internal rotation is positive about it
    image: object = None
    info: dict = field(default_factory=dict)


#: Meshes kept from one run to the next while :func:`reuse_meshes` is on (a sweep's variants
#: share the geometry and the level: meshing the joint at ``paper`` took 4.7-4.9 of a
#: variant's 6.3-6.6 CPU s, part 2 1.5 s), keyed on everything the mesh depends on.
_MESHES: dict | None = None
#: The decoupled run whose part 1 the builds within :func:`reuse_meshes` reuse, or None.
_SOURCE: Path | None = None


@contextlib.contextmanager
def reuse_meshes(source: Path | None = None):
    """Keep the meshes between builds within the block (:func:`shoulder_fem.api.sweep`).

    A build with the same geometry, level and layers takes the last one's meshes instead of
    meshing again. With ``source`` (a decoupled run whose part 1 every build's run reuses) a
    decoupled build reads that run's scapula (:mod:`.mesh_store`) instead of meshing the
    joint, when the run kept it.
    """
    global _MESHES, _SOURCE
    _MESHES, _SOURCE = {}, source
    try:
        yield
    finally:
        _MESHES, _SOURCE = None, None


#: Keys that act only with one head shape: set with another, they would be silently ignored.
_HEAD_SHAPE_KEYS = {
    "prosthesis_radius": "prosthetic",
    "prosthesis_offset_medial": "prosthetic",
    "prosthesis_offset_posterior": "prosthetic",
    "head_ratio": "ellipsoidal",
}


def resolve(scene: Scene) -> Scene:
    """The scene as run: an implant's cap ends on the anatomical neck plane unless given.

    With ``head_shape = prosthetic`` and no ``humeral_cartilage_angle`` set, the implant's
    articular cap takes :meth:`~meshes.shoulder.ShoulderGeometry.neck_plane_cap_angle` (the
    surgeon's cut of the anatomical head, 70 deg, on the implant's own sphere), which keeps the
    insertion footprints off the cartilage for the documented implant radii; the value used is
    the one recorded.
    """
    if scene["head_shape"] != "prosthetic" or "humeral_cartilage_angle" in scene.overridden:
        return scene
    angle = S.geometry_from_values(scene.values()).neck_plane_cap_angle()
    where = f"{scene.where('prosthesis_radius')} (the implant's cap on the neck plane)"
    return scene.with_values(where, humeral_cartilage_angle=angle)


def check_effective(scene: Scene) -> None:
    """Refuse a key given (``--set``, ``with_values``) that has no effect here.

    Each key of :data:`_HEAD_SHAPE_KEYS` acts with one ``head_shape`` only; the line names it.
    """
    shape = scene["head_shape"]
    for key, needs in _HEAD_SHAPE_KEYS.items():
        if key in scene.overridden and shape != needs:
            raise SceneError(
                f"{scene.where(key)}: {key} acts only with head_shape = {needs}, and "
                f"head_shape is {shape!r}: add --set head_shape={needs}"
            )


def build(scene: Scene, level: str, comm: MPI.Comm, method: str) -> ShoulderModel:
    """Mesh the joint for ``method`` (collective): all bodies, or soft tissues + the scapula."""
    check_effective(scene)
    values = scene.values()
    params = ShoulderParameters.from_values(values)
    elsewhere = params.part2_level not in ("", level)
    if method == "decoupled" and params.compliant_part1 and elsewhere:
        raise SceneError(
            f"{scene.where('part1_bones')}: part1_bones = {params.part1_bones} needs part 2 on "
            f"part 1's mesh (it moves part 1's scapula nodes by part 2's displacement there), but "
            f"part2_level = {params.part2_level!r} differs from the level {level!r}"
        )
    geometry = S.geometry_from_values(values)
    sizes = scene.level(level)
    variants = ("deformable",) if method == "coupled" else ("rigid-bone", "scapula")
    if method == "decoupled" and params.part1_humerus:
        variants += ("humerus",)  # the humerus's deformation for part 1 (.humerus)
    layers = (params.humeral_head_contact, params.scapula_contact)
    key = (comm.py2f(), repr(geometry), repr(sorted(sizes.items())), variants, layers)
    if _MESHES is not None and key in _MESHES:
        meshes = dict(_MESHES[key])  # a run may drop a mesh from its own dict
    else:
        stored = mesh_store.load(comm, _SOURCE) if method == "decoupled" and _SOURCE else None
        if stored is not None:  # part 2 alone, on the source run's scapula
            meshes = {"scapula": stored}
        else:
            meshes = _mesh(scene, comm, geometry, sizes, variants, layers)
        if _MESHES is not None:
            _MESHES.clear()
            _MESHES[key] = dict(meshes)
    lay = S.layout(geometry)
    s_dir = lay.rot @ S.shaft_axis(geometry)[0]
    axis = -s_dir / np.linalg.norm(s_dir)
    image = _image(scene, params, geometry)
    model = ShoulderModel(
        scene=scene,
        level=level,
        comm=comm,
        method=method,
        params=params,
        geometry=geometry,
        meshes=meshes,
        shaft_axis=axis,
        image=image,
    )
    if params.ct_image:
        _check_image(scene, params, image, meshes)
    if method == "decoupled" and "rigid-bone" not in meshes:  # the source run's scapula
        with np.load(Path(_SOURCE) / "shoulder.npz") as res:
            model.info["glenoid_frame"] = (res["glenoid_centre"], res["glenoid_axis"])
        return model
    first = meshes["deformable" if method == "coupled" else "rigid-bone"]
    model.info["glenoid_frame"] = glenoid_frame(first.mesh, first.facet_tags)
    model.info["humeral_cap"] = humeral_cap(first.mesh, first.facet_tags)
    return model


def _mesh(scene: Scene, comm, geometry, sizes, variants, layers) -> dict:
    # the subscapularis origin is the actuator: cut it free of the scapula
    try:
        return S.build_shoulder_mesh(
            comm,
            geometry,
            sizes,
            variants,
            detach=DETACHED,
            head_layer=layers[0],
            scapula_layer=layers[1],
        )
    except ValueError as err:  # a geometry the builder refuses: say which scene and why
        raise SceneError(f"{scene.source}: {err}") from None


def check_bench(scene: Scene, level: str) -> None:
    """``bench`` compares part 2 with the coupled scapula node by node: one level for both.

    (And the keys of :func:`check_effective`, before either method runs.)
    """
    check_effective(scene)
    part2 = scene.values().get("part2_level", "")
    if part2 not in ("", level):
        raise SceneError(
            f"{scene.where('part2_level')}: part2_level = {part2!r} differs from the bench's "
            f"level {level!r}; bench compares part 2 with the coupled run node by node on "
            "one mesh (use run --method decoupled for part 2 on another level)"
        )


def scapula_at(model: ShoulderModel, level: str) -> S.ShoulderMesh:
    """The scapula alone meshed at ``level`` (collective): part 2 on another mesh than part 1."""
    sizes = model.scene.level(level)
    try:
        sm = S.build_shoulder_mesh(
            model.comm,
            model.geometry,
            sizes,
            "scapula",
            detach=DETACHED,
            head_layer=model.params.humeral_head_contact,
            scapula_layer=model.params.scapula_contact,
        )
    except ValueError as err:
        raise SceneError(f"{model.scene.source}: {err}") from None
    if model.params.ct_image:
        _check_image(model.scene, model.params, model.image, {"scapula": sm})
    return sm


def _image(scene: Scene, params: ShoulderParameters, geometry) -> ct.CTImage:
    """The CT image of the bones: the scene's ``ct_image``, or the phantom of the geometry."""
    if not params.ct_image:
        return ct.shoulder_phantom(geometry, calibration=params.calibration())
    try:
        return ct.read_ct(params.ct_image)
    except (OSError, ValueError) as err:
        raise SceneError(f"{scene.where('ct_image')}: {err}") from None


def _check_image(scene: Scene, params, image: ct.CTImage, meshes: dict) -> None:
    """Refuse a scan that misses the bones; warn when part of them, or a uniform density."""
    for sm in meshes.values():
        bone = np.concatenate([sm.cell_tags.find(S.MARKERS[b].id) for b in ("humerus", "scapula")])
        n_owned = sm.mesh.geometry.index_map().size_local
        cells = sm.mesh.geometry.dofmap.array.reshape(-1, 4)  # straight tetrahedra
        nodes = np.unique(cells[bone].ravel())
        points = sm.mesh.geometry.x[nodes[nodes < n_owned]]
        where = f"{scene.where('ct_image')}: {params.ct_image}"
        try:
            ct.check_scan(image, points, sm.mesh.comm, where, params.calibration())
        except ValueError as err:
            raise SceneError(str(err)) from None


def _vector_dofs(mesh) -> int:
    V = dolfinx.fem.VectorFunctionSpace(mesh, ("Lagrange", 2))
    return V.dofmap.index_map.size_global * 3


def dofs(model: ShoulderModel) -> int:
    """Displacement DOFs: the whole joint (coupled), or part 1 + part 2 (decoupled).

    With ``part1_bones = compliant``, the humerus's own problem too.
    """
    return sum(_vector_dofs(m.mesh) for m in model.meshes.values())


def head_tags(model: ShoulderModel, mesh, facet_tags) -> dolfinx.mesh.MeshTags:
    """The facet tags, with the surfaces of muscle-bone contact if it is on (collective).

    The muscles' faces over the humeral head and the head's master (``humeral-head`` and
    ``bones``), then those over the scapula and its master (``bones``).
    """
    if model.params.humeral_head_contact:
        radius = S.head_region_radius(model.geometry)
        facet_tags = S.head_surface_tags(mesh, facet_tags, radius)
    if model.params.scapula_contact:
        facet_tags = S.scapula_surface_tags(mesh, facet_tags, S.scapula_reach(model.geometry))
    return facet_tags


@dataclass(frozen=True)
class Displacement:
    """A mesh variant's P2 displacement, its test function and cell measure (collective)."""

    mesh: dolfinx.mesh.Mesh
    cell_tags: dolfinx.mesh.MeshTags
    facet_tags: dolfinx.mesh.MeshTags  # with the muscle-bone contact surfaces if it is on
    V: dolfinx.fem.FunctionSpace
    u: dolfinx.fem.Function
    w: ufl.Argument
    dx: ufl.Measure


def displacement(model: ShoulderModel, variant: str) -> Displacement:
    """The displacement field on mesh variant ``variant`` ("deformable", "rigid-bone")."""
    sm = model.meshes[variant]
    mesh, ct_ = sm.mesh, sm.cell_tags
    ft = head_tags(model, mesh, sm.facet_tags)
    V = dolfinx.fem.VectorFunctionSpace(mesh, ("Lagrange", 2))
    u = dolfinx.fem.Function(V, name="displacement")
    w = ufl.TestFunction(V)
    dx = ufl.Measure("dx", domain=mesh, subdomain_data=ct_, metadata=model.params.quadrature())
    return Displacement(mesh, ct_, ft, V, u, w, dx)
