"""Parametric glenohumeral joint in gmsh (OpenCASCADE): bones, cartilages, rotator cuff.

The model is built from published anatomy (``ANATOMY.md`` of the project lists the sources) since
the project has no CT scan of the paper's shoulder. Every dimension is a named field of
:class:`ShoulderGeometry`, in SI units; :meth:`ShoulderGeometry.validate` rejects impossible
combinations before any geometry is made.

Frame (the scapular frame, right shoulder): origin at the centre of the humeral head, x lateral
(from the glenoid towards the humerus), y anterior, z superior. The scapular blade lies in the
x-z plane. The glenoid axis (pointing out of the glenoid, towards the head) is x turned by the
glenoid inclination (towards +z) and the version (negative: towards -y, retroversion). In the
neutral position the humeral articular axis is the opposite of the glenoid axis (the centre of
the humeral articular surface faces the centre of the glenoid) and the cartilages just touch.

Head shapes (``ShoulderGeometry.head_shape``): ``spherical`` (articular radius ``head_radius``);
``ellipsoidal`` (the head and its cartilage scaled antero-posteriorly by ``head_ratio``: the
transverse radius is ``head_ratio`` x the coronal one); ``prosthetic`` (the articular surface is a
sphere of radius ``prosthesis_radius`` whose centre lies ``prosthesis_offset_medial`` medial and
``prosthesis_offset_posterior`` posterior of the shaft axis, instead of the anatomical
``head_offset``; the tuberosities and shaft stay where the anatomy puts them relative to the shaft,
and a cartilage-thick layer is kept on the implant so that every shape has the same groups). In
every case the origin is the centre of the articular sphere and the glenoid faces it.

Simplifications (the stress question is the scapula near the glenoid): the humeral head is a
sphere with flat tuberosity facets; the metaphysis is a cone and the shaft a cylinder; the scapula
is a glenoid plate, a neck lofted to a blade, and a blade that tapers from the lateral to the
medial border (no spine, acromion or coracoid). Muscles are ruled lofts of rectangular sections: a
belly lying on its fossa (bonded over the origin footprint), routed clear of the head, ending
radially on the head (bonded over the insertion footprint); elsewhere they do not touch the bones
in the neutral position, so muscle-bone contact is a sliding interaction between the muscle's free
surface and the bone's free surface.

Interfaces: bonded interfaces (cartilage-bone, muscle footprints) are conforming (one OCC
fragment, shared nodes); the two articular surfaces are distinct surfaces that share no node.

gmsh works in millimetres (OCC tolerances are absolute); :func:`model_to_dolfinx` scales the
dolfinx mesh to metres.

Element choice (stated here, recorded in ``mesh.json``): straight-sided quadratic (P2)
tetrahedra for every body. The mesh is sized for P2 displacement with, in the nearly
incompressible cartilage and muscle, a continuous P1 pressure per body (Taylor-Hood P2/P1,
inf-sup stable: no volumetric locking); the solvers use P2 displacement alone in every body
today (Taylor-Hood is issue 20's item 2). Linear tetrahedra would lock in the soft tissue,
which is why the DOF counts of the levels are vector-P2 (+ P1 pressure) counts.

Levels (element sizes in the scene file, ``[levels.*]``, in m): ``h_joint`` in the cartilages and
the bone next to them, growing to ``h_bone`` in the bone away from the joint, ``h_muscle`` in the
muscles. Whatever the level, the blade's elements are at most 3 x its local thickness, the
humerus's at most 1.2 x the shaft radius, and the distal spring patches are meshed at 2 x their
radius (:data:`BLADE_SIZE_FACTOR` and the others): these caps bind at ``coarse`` only, where they
keep elements from spanning the thin blade or the whole shaft. The scene's levels aim at:
``coarse`` < 15k DOF (CI; min mean-ratio quality ~0.04, 1 % quantile ~0.08), ``paper`` ~84k DOF
with the paper's element split (~16.5k bone, ~2.9k cartilage, ~800 muscle elements), ``fine``
>= 500k DOF.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import asdict, dataclass, field, fields

import numpy as np
from mpi4py import MPI

from .markers import Marker

logger = logging.getLogger(__name__)


MUSCLES = ("subscapularis", "supraspinatus", "infraspinatus")

# Volumes (dolfinx cell tags).
HUMERUS = Marker("humerus", 1, 3)
SCAPULA = Marker("scapula", 2, 3)
HUMERAL_CARTILAGE = Marker("humeral_cartilage", 3, 3)
GLENOID_CARTILAGE = Marker("glenoid_cartilage", 4, 3)
SUBSCAPULARIS = Marker("subscapularis", 5, 3)
SUPRASPINATUS = Marker("supraspinatus", 6, 3)
INFRASPINATUS = Marker("infraspinatus", 7, 3)
VOLUMES = (
    HUMERUS,
    SCAPULA,
    HUMERAL_CARTILAGE,
    GLENOID_CARTILAGE,
    SUBSCAPULARIS,
    SUPRASPINATUS,
    INFRASPINATUS,
)
BONES = (HUMERUS, SCAPULA)
#: Muscle-bone contact: the humerus's free bone surface around the head (facet centroids within
#: ``HEAD_REGION_FACTOR`` x the articular radius of the articular centre) is the sliding master
#: of the muscles. ``rigid-bone`` keeps the humerus cells on it (this tag; not in
#: :data:`VOLUMES`), whose nodes the rigid humerus carries, so that the surface is made of
#: facets of the soft-tissue mesh in both variants, node for node the same.
HUMERUS_HEAD_LAYER = Marker("humerus_head_layer", 8, 3)
#: The facets of that master (a tag value given by :func:`head_surface_tags`, not by gmsh).
HUMERUS_HEAD_SURFACE = Marker("humerus_head_surface", 143, 2)
#: The deep faces of the muscles over the head (slave of the muscle-humerus contact), one tag
#: per muscle (so that the contact's force is reported per muscle), given by
#: :func:`head_surface_tags`: free muscle facets within the head region whose outward normal
#: is within acos(_DEEP_COSINE) of the direction to the articular centre. (One tag for the
#: three muscles until issue 20's muscle-scapula contact: the same facets.)
MUSCLE_HEAD_FACES = tuple(Marker(f"{m}_head_face", 144 + k, 2) for k, m in enumerate(MUSCLES))
#: The deep faces of the muscles over the scapula (slave of the muscle-scapula contact), one
#: tag per muscle, given by :func:`scapula_surface_tags`: free muscle facets, not over the
#: head, not touching the muscle's origin footprint (its rim: a facet with a node on the bonded
#: footprint is at zero gap from the bone by construction), whose midpoint lies within the
#: scapular reach of the scapula's contact surface and whose outward normal is within
#: acos(_DEEP_COSINE) of the direction to the closest point of that surface.
MUSCLE_SCAPULA_FACES = tuple(Marker(f"{m}_scapula_face", 147 + k, 2) for k, m in enumerate(MUSCLES))
#: The master of the muscle-scapula contact: the ``scapula_surface`` facets (the scapula's free
#: surface: without the origin footprints, the glenoid's bonded cartilage and the spring
#: patches, which have tags of their own) whose centroid lies within the scapular reach of the
#: muscles' free surfaces (a tag value given by :func:`scapula_surface_tags`).
SCAPULA_CONTACT_SURFACE = Marker("scapula_contact_surface", 150, 2)
#: ``rigid-bone`` with the muscle-scapula contact: the scapula cells with a node on that master
#: (reach x _LAYER_MARGIN, so that it holds every master facet), carried by the rigid scapula,
#: like :data:`HUMERUS_HEAD_LAYER` (not in :data:`VOLUMES`).
SCAPULA_LAYER = Marker("scapula_layer", 9, 3)
#: Reach of the muscle-scapula contact, in muscle thicknesses: the deep faces between the
#: origin and the glenoid neck lie 1.7-14.1 mm from the blade and the neck at coarse (8 mm
#: muscles; measured, 2026-11-27).
SCAPULA_REACH_FACTOR = 2.0
_LAYER_MARGIN = 1.25
_DEEP_COSINE = 0.3
#: Reach of the head region, in articular radii: the head, the tuberosities and the rotator
#: cuff over them (the muscles are 8 mm thick on a 24 mm head).
HEAD_REGION_FACTOR = 1.6
SOFT = tuple(v for v in VOLUMES if v not in BONES)


def _surface_markers() -> tuple[Marker, ...]:
    names = [
        "humeral_articular",  # humeral cartilage surface facing the glenoid (contact)
        "glenoid_articular",  # glenoid cartilage surface facing the head (contact)
        "humeral_cartilage_bone",  # bonded
        "glenoid_cartilage_bone",  # bonded
        "humeral_cartilage_edge",  # free border of the humeral cartilage
        "glenoid_cartilage_edge",  # free rim of the glenoid cartilage
    ]
    markers = [Marker(n, 101 + i, 2) for i, n in enumerate(names)]
    for k, muscle in enumerate(MUSCLES):
        base = 111 + 10 * k
        markers += [
            Marker(f"{muscle}_origin", base, 2),  # bonded to the scapula
            Marker(f"{muscle}_insertion", base + 1, 2),  # bonded to the humerus
            Marker(f"{muscle}_surface", base + 2, 2),  # free, slides on the bones
        ]
    markers += [
        Marker("humerus_surface", 141, 2),  # free bone surface (sliding master for muscles)
        Marker("scapula_surface", 142, 2),
        Marker("humerus_distal", 151, 2),  # distal section minus the 4 spring patches
    ]
    markers += [Marker(f"humerus_distal_spring_{i + 1}", 152 + i, 2) for i in range(4)]
    markers += [Marker(f"scapula_spring_{i + 1:02d}", 161 + i, 2) for i in range(20)]
    markers += [
        Marker("scapula_ap_spring", 181, 2),
        Marker("scapula_section", 190, 2),  # horizontal section at the contact level (interior)
    ]
    return tuple(markers)


SURFACES = _surface_markers()
MARKERS: dict[str, Marker] = {m.name: m for m in VOLUMES + SURFACES}

#: Unions of surface markers that scenes use as one set.
SURFACE_SETS: dict[str, tuple[str, ...]] = {
    "humerus_distal_section": ("humerus_distal",)
    + tuple(f"humerus_distal_spring_{i + 1}" for i in range(4)),
    "scapular_springs": tuple(f"scapula_spring_{i + 1:02d}" for i in range(20)),
}

#: Surfaces a rigid bone keeps (rigid-bone variant): tied or touched by other tissues, springs.
RIGID_BONE_SURFACES = tuple(
    m
    for m in SURFACES
    if m.name
    not in (
        "humeral_articular",
        "glenoid_articular",
        "humeral_cartilage_edge",
        "glenoid_cartilage_edge",
        "scapula_section",
    )
    and not m.name.endswith("_surface")
) + (MARKERS["humerus_surface"], MARKERS["scapula_surface"])

#: Surfaces that bound a soft tissue (the facet tags of the rigid-bone variant's volume mesh).
SOFT_SURFACES = tuple(
    m for m in SURFACES if m.name.startswith(("humeral_", "glenoid_")) or m.name.startswith(MUSCLES)
)

VARIANTS = ("deformable", "rigid-bone", "scapula", "humerus")
#: The variants of one bone alone (its volume and the surfaces on it).
BONE_VARIANTS = {"scapula": SCAPULA, "humerus": HUMERUS}
HEAD_SHAPES = ("spherical", "ellipsoidal", "prosthetic")

_MM = 1e3  # gmsh works in mm
_DEG = math.pi / 180.0
_CONTACT_CLEARANCE = 1e-6  # m, see ShoulderGeometry.contact_offset
_FACET_RAISE = 1.5  # mm: tuberosity facets stand this far outside the head sphere
_ARRIVAL_LIFT = 10.0  # mm: muscles arrive on their facet along a 45 deg oblique prism
_META_START = 10.0  # mm along the shaft axis from the head-centre level to the metaphysis
_META_RADIUS = 0.6  # metaphysis radius at its start, fraction of the humeral bone radius
_META_FRACTION = 0.45  # metaphysis length, fraction of the shaft length
_FACET_MARGIN = 2.0  # mm: facet border around the footprint
_BLOCK_TIP = 0.3  # tuberosity blocks taper to a point this fraction of the radius from the centre


@dataclass(frozen=True)
class ShoulderGeometry:
    """Named dimensions of the parametric shoulder, SI units (m, rad).

    Defaults and sources (see the project's ANATOMY.md):

    * humeral head articular radius 24 mm, transverse/coronal ratio 0.92, neck-shaft angle 135
      deg (Iannotti et al. 1992, JBJS 74:491; Robertson et al. 2000); retroversion 20 deg
      (Boileau 2008); head centre 7 mm medial to the shaft axis (Robertson 2000); shaft radius
      11 mm, 120 mm kept (model choice).
    * humeral cartilage 1.5 mm (cadaver series, max 2.2 +/- 0.5 mm; Zumstein 2013).
    * glenoid cartilage surface radius = head radius + 2.3 mm (Iannotti 1992; Soslowsky 1992);
      rim 39 x 29 mm (Iannotti 1992); version -2 deg, inclination 5 deg (Churchill et al. 2001);
      glenoid cartilage 2 mm (Fox et al. 1998, thinner centrally).
    * joint space (bone to bone at the contact point) = sum of the cartilage thicknesses: the
      cartilages just touch, as in the paper where cartilage filled the CT joint space.
    * scapular blade 120 x 90 mm, 10 mm thick laterally, 2 mm medially (osteometric series and
      Thai series of 97 scapulae, ANATOMY.md).
    * insertion footprints (length x width): subscapularis 40 x 20, supraspinatus 23 x 16,
      infraspinatus 29 x 19 mm (Curtis et al. 2006, Arthroscopy 22:609). Origin footprints on the
      blade are model choices (fossae of the simplified blade).
    * humeral cartilage to 70 deg from its axis (head height 15.8 mm). Iannotti 1992's head
      height, 19 +/- 2.4 mm, is a cap of about 78 deg (issue 20, item 4): the option
      :data:`ANATOMICAL_CAP`. There each insertion footprint is turned about its insertion
      direction by ``<muscle>_insertion_turn`` (positive from the muscle's arrival towards the
      footprint's length; 0 = the width along the arrival, the default): unturned, the
      subscapularis footprint's corners lie 77 deg from the articular axis, on the 78 deg cap,
      and no insertion direction clears both the cap and the humeral neck; turned by -15 deg
      they stand the required 5 deg clear of it. The supraspinatus's 20 and the
      infraspinatus's 15 deg keep 5 deg too and were chosen among the turns that do for the
      meshes' quality (the tuberosity blocks meet at oblique edges: the worst tetrahedron's
      mean ratio is 0.022, 0.022, 0.040 at coarse, medium and paper, and 1e-6 to 0.02 with
      other turns). Model choices.

    * prosthetic head (``head_shape = "prosthetic"``): a sphere of ``prosthesis_radius`` (default
      the anatomical 24 mm) with its centre ``prosthesis_offset_medial`` (default 7 mm, the
      anatomical offset) medial and ``prosthesis_offset_posterior`` (default 0) posterior of the
      shaft axis; model choice for later head-shape studies.

    Attributes:
        head_shape: ``"spherical"``, ``"ellipsoidal"`` (transverse radius = ``head_ratio`` x
            coronal) or ``"prosthetic"`` (sphere of ``prosthesis_radius`` at the prosthesis
            offsets).
    """

    head_shape: str = "spherical"
    head_radius: float = 24.0e-3
    head_ratio: float = 0.92
    prosthesis_radius: float = 24.0e-3
    prosthesis_offset_medial: float = 7.0e-3
    prosthesis_offset_posterior: float = 0.0
    humeral_cartilage_thickness: float = 1.5e-3
    humeral_cartilage_angle: float = 70.0 * _DEG
    neck_shaft_angle: float = 135.0 * _DEG
    retroversion: float = 20.0 * _DEG
    head_offset: float = 7.0e-3
    shaft_radius: float = 11.0e-3
    shaft_length: float = 120.0e-3
    glenoid_radius: float = 26.3e-3
    glenoid_height: float = 39.0e-3
    glenoid_width: float = 29.0e-3
    glenoid_version: float = -2.0 * _DEG
    glenoid_inclination: float = 5.0 * _DEG
    glenoid_cartilage_thickness: float = 2.0e-3
    joint_space: float = 3.5e-3
    glenoid_neck_depth: float = 15.0e-3
    blade_length: float = 120.0e-3
    blade_height: float = 90.0e-3
    blade_thickness_lateral: float = 10.0e-3
    blade_thickness_medial: float = 2.0e-3
    subscapularis_insertion_length: float = 40.0e-3
    subscapularis_insertion_width: float = 20.0e-3
    supraspinatus_insertion_length: float = 23.0e-3
    supraspinatus_insertion_width: float = 16.0e-3
    infraspinatus_insertion_length: float = 29.0e-3
    infraspinatus_insertion_width: float = 19.0e-3
    subscapularis_insertion_turn: float = 0.0
    supraspinatus_insertion_turn: float = 0.0
    infraspinatus_insertion_turn: float = 0.0
    subscapularis_origin_length: float = 50.0e-3
    subscapularis_origin_width: float = 36.0e-3
    supraspinatus_origin_length: float = 50.0e-3
    supraspinatus_origin_width: float = 14.0e-3
    infraspinatus_origin_length: float = 50.0e-3
    infraspinatus_origin_width: float = 34.0e-3
    muscle_thickness: float = 8.0e-3
    spring_patch_radius: float = 4.0e-3

    # ---------------------------------------------------------------- derived quantities
    @property
    def articular_radius(self) -> float:
        """Radius of the humeral articular (cartilage) surface (m): the implant's if prosthetic."""
        return self.prosthesis_radius if self.head_shape == "prosthetic" else self.head_radius

    @property
    def subchondral_radius(self) -> float:
        """Radius of the sphere under the humeral cartilage (bone or implant, m)."""
        return self.articular_radius - self.humeral_cartilage_thickness

    @property
    def humeral_bone_radius(self) -> float:
        """Anatomical subchondral radius (m): sets the tuberosities and the metaphysis."""
        return self.head_radius - self.humeral_cartilage_thickness

    @property
    def humeral_shift(self) -> np.ndarray:
        """Anatomical head centre relative to the articular centre (mm, glenoid frame).

        Zero unless prosthetic: then the shaft axis passes ``prosthesis_offset_medial`` lateral
        and ``prosthesis_offset_posterior`` anterior of the implant centre, and the anatomical
        parts (tuberosities, metaphysis, shaft) move with it.
        """
        if self.head_shape != "prosthetic":
            return np.zeros(3)
        s = _shaft_direction(self)
        lateral = _unit(np.array([1.0, 0.0, 0.0]) - s[0] * s)
        medial_change = (self.prosthesis_offset_medial - self.head_offset) * _MM
        return medial_change * lateral + self.prosthesis_offset_posterior * _MM * np.array(
            [0.0, 1.0, 0.0]
        )

    def neck_plane_cap_angle(self) -> float:
        """Half angle (rad) of an implant's cap whose margin lies on the anatomical neck plane.

        The anatomical cartilage ends on the plane ``head_radius cos(humeral_cartilage_angle)``
        from the anatomical centre along the articular axis (the anatomical neck, where a
        surgeon cuts); an implant of another radius or centre that covers the same cut ends on
        that plane too: cos(angle) = (head_radius cos(humeral_cartilage_angle) - shift_x) /
        prosthesis_radius, with shift_x the anatomical centre's offset along the articular axis
        (:attr:`humeral_shift`). Equal to ``humeral_cartilage_angle`` for the anatomical head.
        A study of implant shapes sets ``humeral_cartilage_angle`` to it
        (``benchmarks/head_shape.py``).
        """
        plane = self.head_radius * math.cos(self.humeral_cartilage_angle)
        c = (plane - self.humeral_shift[0] / _MM) / self.articular_radius
        return math.acos(min(1.0, max(-1.0, c)))

    @property
    def joint_gap(self) -> float:
        """Gap between the cartilages at the contact point in the neutral position (m)."""
        return (
            self.joint_space - self.humeral_cartilage_thickness - self.glenoid_cartilage_thickness
        )

    @property
    def contact_offset(self) -> float:
        """Distance between the articular surfaces along the axis as built (m).

        The joint gap plus 1 um: exactly tangent spheres would make OCC imprint the contact point
        on both surfaces, i.e. one node shared by the two cartilages. 1 um is far below any mesh
        size and contact tolerance ("just touching").
        """
        return self.joint_gap + _CONTACT_CLEARANCE

    def validate(self) -> None:
        """Check the parameters before any geometry is made.

        Raises:
            ValueError: naming the parameter, its value and the rule it breaks.
        """

        def mm(v: float) -> str:
            return f"{v * 1e3:g} mm"

        def deg(v: float) -> str:
            return f"{v / _DEG:g} deg"

        if self.head_shape not in HEAD_SHAPES:
            raise ValueError(f"head_shape = {self.head_shape!r}: expected one of {HEAD_SHAPES}")
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, float) and not math.isfinite(v):
                raise ValueError(f"{f.name} = {v}: must be finite")
        signed = ("retroversion", "glenoid_version", "glenoid_inclination")
        signed += ("prosthesis_offset_medial", "prosthesis_offset_posterior")
        turns = tuple(f"{m}_insertion_turn" for m in MUSCLES)
        signed += turns
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name not in signed and isinstance(v, float) and v <= 0:
                unit = "deg" if f.name.endswith("angle") else "mm"
                shown = deg(v) if unit == "deg" else mm(v)
                raise ValueError(f"{f.name} = {shown}: must be > 0")
        for name in turns:
            if abs(getattr(self, name)) > 90 * _DEG:
                raise ValueError(f"{name} = {deg(getattr(self, name))}: must lie in [-90, 90] deg")
        if not 0.7 <= self.head_ratio <= 1.0:
            raise ValueError(f"head_ratio = {self.head_ratio:g} (1): must lie in [0.7, 1]")
        if not 10e-3 <= self.head_radius <= 40e-3:
            raise ValueError(f"head_radius = {mm(self.head_radius)}: must lie in [10, 40] mm")
        if self.head_shape == "prosthetic":
            lo, hi = 0.75 * self.head_radius, 1.25 * self.head_radius
            if not lo <= self.prosthesis_radius <= hi:
                raise ValueError(
                    f"prosthesis_radius = {mm(self.prosthesis_radius)}: must lie within 25 % of "
                    f"head_radius, [{mm(lo)}, {mm(hi)}] (the tuberosities are anatomical)"
                )
            if self.prosthesis_radius > self.head_radius + _FACET_RAISE / _MM + 1e-12:
                raise ValueError(
                    f"prosthesis_radius = {mm(self.prosthesis_radius)}: must not exceed "
                    f"head_radius + {_FACET_RAISE:g} mm = "
                    f"{mm(self.head_radius + _FACET_RAISE / _MM)}: a larger implant buries the "
                    "anatomical tuberosity facets (at 26 mm against 24 mm gmsh aborts)"
                )
            shift = float(np.linalg.norm(self.humeral_shift)) * 1e-3
            if shift > 6e-3:
                raise ValueError(
                    f"prosthesis_offset_medial = {mm(self.prosthesis_offset_medial)}, "
                    f"prosthesis_offset_posterior = {mm(self.prosthesis_offset_posterior)}: move "
                    f"the implant centre {mm(shift)} from the anatomical centre (at most 6 mm)"
                )
        name_r = "prosthesis_radius" if self.head_shape == "prosthetic" else "head_radius"
        if self.humeral_cartilage_thickness >= 0.25 * self.articular_radius:
            raise ValueError(
                f"humeral_cartilage_thickness = {mm(self.humeral_cartilage_thickness)}: must be "
                f"< {name_r} / 4 = {mm(0.25 * self.articular_radius)}"
            )
        t_sum = self.humeral_cartilage_thickness + self.glenoid_cartilage_thickness
        if t_sum > self.joint_space + 1e-12:
            raise ValueError(
                f"humeral_cartilage_thickness + glenoid_cartilage_thickness = {mm(t_sum)} "
                f"exceeds joint_space = {mm(self.joint_space)}: the cartilages would overlap"
            )
        if self.joint_gap > 1e-3:
            raise ValueError(
                f"joint_space = {mm(self.joint_space)}: leaves a gap of {mm(self.joint_gap)} "
                "between the cartilages (at most 1 mm)"
            )
        if self.glenoid_radius <= self.articular_radius + self.joint_gap:
            raise ValueError(
                f"glenoid_radius = {mm(self.glenoid_radius)}: must exceed {name_r} "
                f"(articular, incl. humeral cartilage) = {mm(self.articular_radius)}, or the "
                "glenoid cuts into the head"
            )
        if self.glenoid_radius > self.articular_radius + 10e-3:
            raise ValueError(
                f"glenoid_radius = {mm(self.glenoid_radius)}: more than 10 mm above {name_r} "
                f"= {mm(self.articular_radius)}"
            )
        half = 0.5 * max(self.glenoid_height, self.glenoid_width)
        if half >= 0.9 * self.glenoid_radius:
            raise ValueError(
                f"glenoid_height = {mm(self.glenoid_height)}: the rim must stay within 0.9 "
                f"glenoid_radius = {mm(0.9 * self.glenoid_radius)} of the glenoid axis"
            )
        if self.glenoid_width > self.glenoid_height:
            raise ValueError(
                f"glenoid_width = {mm(self.glenoid_width)}: must not exceed glenoid_height "
                f"= {mm(self.glenoid_height)}"
            )
        for name in ("glenoid_version", "glenoid_inclination"):
            if abs(getattr(self, name)) > 20 * _DEG:
                raise ValueError(f"{name} = {deg(getattr(self, name))}: must lie in [-20, 20] deg")
        if not 110 * _DEG <= self.neck_shaft_angle <= 160 * _DEG:
            raise ValueError(
                f"neck_shaft_angle = {deg(self.neck_shaft_angle)}: must lie in [110, 160] deg"
            )
        if not 40 * _DEG <= self.humeral_cartilage_angle <= 80 * _DEG:
            raise ValueError(
                f"humeral_cartilage_angle = {deg(self.humeral_cartilage_angle)}: must lie in "
                "[40, 80] deg"
            )
        if self.shaft_radius >= 0.8 * self.humeral_bone_radius:
            raise ValueError(
                f"shaft_radius = {mm(self.shaft_radius)}: must be < 0.8 x humeral bone radius "
                f"= {mm(0.8 * self.humeral_bone_radius)}"
            )
        if self.shaft_length < 3 * self.head_radius:
            raise ValueError(
                f"shaft_length = {mm(self.shaft_length)}: must be >= 3 head_radius "
                f"= {mm(3 * self.head_radius)}"
            )
        if self.blade_thickness_medial > self.blade_thickness_lateral:
            raise ValueError(
                f"blade_thickness_medial = {mm(self.blade_thickness_medial)}: must not exceed "
                f"blade_thickness_lateral = {mm(self.blade_thickness_lateral)}"
            )
        if self.blade_thickness_medial < 1e-3:
            raise ValueError(
                f"blade_thickness_medial = {mm(self.blade_thickness_medial)}: must be >= 1 mm"
            )
        if self.blade_thickness_lateral >= self.glenoid_width:
            raise ValueError(
                f"blade_thickness_lateral = {mm(self.blade_thickness_lateral)}: must be < "
                f"glenoid_width = {mm(self.glenoid_width)}"
            )
        if self.muscle_thickness < 3e-3 or self.muscle_thickness > 20e-3:
            raise ValueError(
                f"muscle_thickness = {mm(self.muscle_thickness)}: must lie in [3, 20] mm"
            )
        layout(self)  # raises ValueError for footprints off the bone


# ---------------------------------------------------------------------------- layout (numpy)


@dataclass
class _Layout:
    """Derived positions in the scapular frame, in mm (gmsh units)."""

    rot: np.ndarray  # glenoid frame -> scapular frame
    x_lat: float  # blade lateral border (x, mm)
    x_med: float  # blade medial border
    z_top: float
    z_bot: float
    plate_x: tuple[float, float]  # glenoid plate x range in the glenoid frame
    muscles: dict = field(default_factory=dict)  # name -> list of sections
    insertions: dict = field(default_factory=dict)  # name -> (centre dir, e_w, e_n) glenoid frame
    origins: dict = field(default_factory=dict)  # name -> (x0, x1, z0, z1, side)
    spring_points: list = field(default_factory=list)  # (centre, normal) on the blade
    ap_point: tuple = ()
    distal: tuple = ()  # (centre, axis, [4 patch centres])


def _rot_y(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def blade_half_thickness(g: ShoulderGeometry, x_mm: float | np.ndarray) -> float | np.ndarray:
    """Half thickness of the blade (mm) at scapular-frame abscissa ``x_mm`` (mm)."""
    lay_x_lat, lay_x_med = _blade_x(g)
    s = (lay_x_lat - np.asarray(x_mm)) / (lay_x_lat - lay_x_med)
    t = g.blade_thickness_lateral + s * (g.blade_thickness_medial - g.blade_thickness_lateral)
    return 0.5 * t * _MM


def _blade_x(g: ShoulderGeometry) -> tuple[float, float]:
    pole = -(g.articular_radius + g.contact_offset + g.glenoid_cartilage_thickness) * _MM
    x_lat = pole - 3.0 - g.glenoid_neck_depth * _MM
    return x_lat, x_lat - g.blade_length * _MM


#: Insertion directions on the head (glenoid frame: x lateral, y anterior, z superior): lesser
#: tuberosity (anterior), superior and middle facets of the
#: greater tuberosity (Curtis 2006 footprint layout, model placement). The supraspinatus and
#: infraspinatus facets stand far enough apart that their blocks do not cut each other: with
#: (0.42, -0.10, 0.90) and (0.45, -0.87, 0.15) they did, leaving 1 mm edges and 0.6 mm^2 faces
#: (slivers at every level, and a supraspinatus footprint split in three).
_INSERTION_DIRS = {
    "subscapularis": (0.45, 0.87, 0.05),
    "supraspinatus": (0.42, 0.0, 0.90),
    "infraspinatus": (0.45, -0.87, 0.0),
}
#: The anatomical humeral cartilage (issue 20, item 4; not the default, see the README): the cap
#: to 78 deg (head height 19.0 mm) and the insertion footprints turned clear of it, as scene
#: overrides (``--set`` of ``run`` and ``bench``).
ANATOMICAL_CAP = (
    "humeral_cartilage_angle=78deg",
    "subscapularis_insertion_turn=-15deg",
    "supraspinatus_insertion_turn=20deg",
    "infraspinatus_insertion_turn=15deg",
)
#: Origin rectangles on the blade: (centre x from the lateral blade border as a fraction of the
#: blade length, centre z as a fraction of the height from the bottom, face side +1 anterior).
_ORIGIN_PLACES = {
    "subscapularis": (0.4, 0.38, +1),
    "supraspinatus": (0.4, 0.88, -1),
    "infraspinatus": (0.4, 0.32, -1),
}


def layout(g: ShoulderGeometry) -> _Layout:
    """Positions of every feature (mm), checking footprints lie on their bone."""
    rot = _rot_z(g.glenoid_version) @ _rot_y(-g.glenoid_inclination)
    x_lat, x_med = _blade_x(g)
    z_top = 0.4 * g.blade_height * _MM
    z_bot = z_top - g.blade_height * _MM
    rb = g.humeral_bone_radius * _MM  # anatomical: tuberosities, metaphysis
    rh = g.articular_radius * _MM  # articular sphere (cartilage surface), centred at the origin
    r_sub = g.subchondral_radius * _MM
    shift = g.humeral_shift  # anatomical centre, mm, glenoid frame
    pole_g = -(g.articular_radius + g.contact_offset)  # glenoid articular pole, glenoid frame (m)
    rim_x = (g.glenoid_radius - g.articular_radius - g.contact_offset) * _MM - math.sqrt(
        (g.glenoid_radius * _MM) ** 2 - (0.5 * g.glenoid_height * _MM) ** 2
    )
    plate_x = (
        (pole_g - g.glenoid_cartilage_thickness) * _MM - 3.0,
        rim_x + 3.0,
    )
    lay = _Layout(rot, x_lat, x_med, z_top, z_bot, plate_x)
    alpha = g.humeral_cartilage_angle
    length = x_lat - x_med
    spring_zone = x_med + 24.0  # medial strip kept for the stabiliser springs
    s_dir, s_base = shaft_axis(g)
    for muscle in MUSCLES:
        fx, fz, side = _ORIGIN_PLACES[muscle]
        ol = getattr(g, f"{muscle}_origin_length") * _MM
        ow = getattr(g, f"{muscle}_origin_width") * _MM
        xc = x_lat - fx * length
        zc = z_bot + fz * (z_top - z_bot)
        x0, x1, z0, z1 = xc - 0.5 * ol, xc + 0.5 * ol, zc - 0.5 * ow, zc + 0.5 * ow
        if x0 < spring_zone or x1 > x_lat - 2.0 or z0 < z_bot + 2.0 or z1 > z_top - 2.0:
            raise ValueError(
                f"{muscle}_origin_length x _width = {ol:g} x {ow:g} mm: the origin footprint "
                f"(x {x0:.0f}..{x1:.0f}, z {z0:.0f}..{z1:.0f} mm) runs off the scapular blade "
                f"(x {spring_zone:.0f}..{x_lat - 2:.0f}, z {z_bot + 2:.0f}..{z_top - 2:.0f} mm)"
            )
        lay.origins[muscle] = (x0, x1, z0, z1, side)
    for muscle in MUSCLES:
        big = getattr(g, f"{muscle}_insertion_length") * _MM
        small = getattr(g, f"{muscle}_insertion_width") * _MM
        d = _unit(_INSERTION_DIRS[muscle])
        # The muscle arrives along the facet (travel direction e_n, the footprint width) from
        # where it leaves the neck; the footprint length e_w runs across the line of action.
        travel = rot @ (rb * d + shift) - _neck_clear_centre(g, lay, muscle)
        travel = rot.T @ travel
        e_n = _unit(travel - np.dot(travel, d) * d)
        e_w = np.cross(e_n, d)
        # ... then the footprint turns about d (ShoulderGeometry.<muscle>_insertion_turn).
        turn = getattr(g, f"{muscle}_insertion_turn")
        e_n, e_w = (
            math.cos(turn) * e_n + math.sin(turn) * e_w,
            math.cos(turn) * e_w - math.sin(turn) * e_n,
        )
        # The footprint lies on a flat facet (a tuberosity block) whose corners must stay clear
        # of the articular cartilage and close to the head.
        half_diag = math.hypot(0.5 * big + _FACET_MARGIN, 0.5 * small + _FACET_MARGIN)
        if half_diag > 1.15 * rb:
            raise ValueError(
                f"{muscle}_insertion_length x _width = {big:g} x {small:g} mm: the insertion "
                f"footprint runs off the humeral head (half diagonal {half_diag:.1f} mm > "
                f"1.15 x bone radius {1.15 * rb:.1f} mm)"
            )
        for sw in (-1, 1):
            for sn in (-1, 1):
                lateral = sw * (0.5 * big + _FACET_MARGIN) * e_w
                lateral = lateral + sn * (0.5 * small + _FACET_MARGIN) * e_n
                outer = (rb + _FACET_RAISE) * d + lateral
                tip = _BLOCK_TIP * rb * d + 0.5 * lateral
                for frac in np.linspace(0.0, 1.0, 41):
                    corner = (1 - frac) * outer + frac * tip + shift
                    r = np.linalg.norm(corner)
                    angle = math.acos(np.clip(-corner[0] / r, -1, 1))
                    if r_sub - 1.0 < r < rh + 1.0 and angle < alpha + 5 * _DEG:
                        raise ValueError(
                            f"{muscle}_insertion_length x _width = {big:g} x {small:g} mm: the "
                            "insertion footprint runs off the tuberosity onto the articular "
                            f"cartilage ({angle / _DEG:.0f} deg from the articular axis, "
                            f"cartilage to {alpha / _DEG:.0f} deg)"
                        )
        # The metaphysis and shaft must stay below the facet plane, 0.5 mm clear of the
        # muscle's underside (else the muscle would overlap the neck). (1 mm until
        # 2026-11-27: the anatomical head cleared it by 0.01 mm, implants of 20-23 mm or
        # 9 mm medial offset missed it by 0.03-0.26 mm; 22 mm and the 9 mm offset mesh.)
        t = np.linspace(_META_START, g.shaft_length * _MM, 120)
        meta_end = _META_START + _META_FRACTION * g.shaft_length * _MM
        radius = np.interp(t, [_META_START, meta_end], [_META_RADIUS * rb, g.shaft_radius * _MM])
        u = _unit(np.cross(s_dir, (0.0, 1.0, 0.0)))
        v = np.cross(s_dir, u)
        phi = np.linspace(0.0, 2 * math.pi, 72, endpoint=False)
        ring = np.cos(phi)[:, None] * u[None, :] + np.sin(phi)[:, None] * v[None, :]
        pts = (s_base + t[:, None] * s_dir)[:, None, :] + radius[:, None, None] * ring[None]
        pts = pts.reshape(-1, 3)
        inside = (np.abs(pts @ e_w) <= 0.5 * big + 3.0) & (np.abs(pts @ e_n) <= 0.5 * small + 3.0)
        reach = np.concatenate([[0.0], (pts @ d)[inside]])
        if np.max(reach) > rb + _FACET_RAISE - 0.5:
            raise ValueError(
                f"{muscle}_insertion_length x _width = {big:g} x {small:g} mm: the insertion "
                "facet is too close to the humeral neck (the metaphysis reaches above it)"
            )
        lay.insertions[muscle] = (d, e_w, e_n, big, small)
    # Origins must not overlap each other (same face).
    sup, inf = lay.origins["supraspinatus"], lay.origins["infraspinatus"]
    if inf[3] > sup[2] - 2.0:
        raise ValueError(
            f"infraspinatus_origin_width = {inf[3] - inf[2]:g} mm: the infraspinatus origin "
            "overlaps the supraspinatus origin on the posterior face of the blade"
        )
    # Muscle sections (scapular frame, mm).
    for muscle in MUSCLES:
        lay.muscles[muscle] = _muscle_sections(g, lay, muscle)
    # Stabiliser springs: 2 columns x 5 rows on each face near the medial border.
    for side in (+1, -1):
        for x in (x_med + 6.0, x_med + 16.0):
            for z in np.linspace(z_bot + 9.0, z_top - 9.0, 5):
                lay.spring_points.append(_blade_point(g, lay, x, z, side))
    lay.ap_point = _blade_point(g, lay, x_med + 34.0, z_bot + 0.5 * (z_top - z_bot) - 14.0, +1)
    # Distal humerus: axis and 4 spring patches (anterior, lateral, posterior, medial).
    s, base = shaft_axis(g)
    centre = base + g.shaft_length * _MM * s
    e1 = _unit(np.cross(s, (0.0, 1.0, 0.0)))  # in the plane of the shaft and head axis
    e2 = np.cross(s, e1)
    c, sn = math.cos(g.retroversion), math.sin(g.retroversion)
    a1, a2 = c * e1 + sn * e2, -sn * e1 + c * e2  # epicondylar axis turned by the retroversion
    r = 0.6 * g.shaft_radius * _MM
    patches = [centre + r * v for v in (a1, a2, -a1, -a2)]
    lay.distal = (rot @ (centre + shift), rot @ s, [rot @ (p + shift) for p in patches])
    return lay


def shaft_axis(g: ShoulderGeometry) -> tuple[np.ndarray, np.ndarray]:
    """Distal shaft direction and the shaft-axis point level with the head centre (glenoid frame).

    The angle between the articular axis (-x) and the shaft is the neck-shaft angle; the point
    (mm) lies ``head_offset`` lateral of the head centre.
    """
    s = _shaft_direction(g)
    lateral = _unit(np.array([1.0, 0.0, 0.0]) - s[0] * s)
    return s, g.head_offset * _MM * lateral


def _shaft_direction(g: ShoulderGeometry) -> np.ndarray:
    """Distal shaft direction (glenoid frame): at the neck-shaft angle from the articular axis."""
    phi = g.neck_shaft_angle
    return math.cos(phi) * np.array([-1.0, 0.0, 0.0]) + math.sin(phi) * np.array([0.0, 0.0, -1.0])


def _blade_point(g: ShoulderGeometry, lay: _Layout, x: float, z: float, side: int):
    """Point on the anterior (side=+1) or posterior (-1) blade face and the outward normal."""
    h = blade_half_thickness(g, x)
    slope = (
        (g.blade_thickness_lateral - g.blade_thickness_medial) * _MM / 2 / (lay.x_lat - lay.x_med)
    )
    normal = _unit((-slope, side, 0.0))
    return np.array([x, side * h, z]), normal


def _rect_corners(centre, normal, w_dir, width, thick) -> np.ndarray:
    """Corners (4 x 3) of a rectangle in the plane normal to ``normal``."""
    t = _unit(normal)
    e_w = _unit(np.asarray(w_dir) - np.dot(w_dir, t) * t)
    e_n = np.cross(t, e_w)
    signs = ((1, 1), (-1, 1), (-1, -1), (1, -1))
    return np.array([centre + 0.5 * (a * width * e_w + b * thick * e_n) for a, b in signs])


def _rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit vector ``a`` to unit vector ``b``."""
    v = np.cross(a, b)
    c = float(np.dot(a, b))
    if np.linalg.norm(v) < 1e-12:
        return np.eye(3)
    k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + k + k @ k / (1.0 + c)


def _match_corners(prev: np.ndarray, corners: np.ndarray, rot: np.ndarray) -> np.ndarray:
    """Reorder ``corners`` (cyclically, either way round) to follow ``prev`` turned by ``rot``."""
    ref = (prev - prev.mean(axis=0)) @ rot.T
    offs = corners - corners.mean(axis=0)
    best, best_cost = corners, np.inf
    for order in (corners, corners[::-1]):
        o_offs = order - order.mean(axis=0)
        for k in range(4):
            cost = float(np.sum((np.roll(o_offs, k, axis=0) - ref) ** 2))
            if cost < best_cost:
                best, best_cost = np.roll(order, k, axis=0), cost
    del offs
    return best


def _neck_clear_centre(g: ShoulderGeometry, lay: _Layout, muscle: str) -> np.ndarray:
    """Centre (mm, scapular frame) of the muscle section standing clear of the glenoid neck."""
    x0, x1, z0, z1, side = lay.origins[muscle]
    t_m = g.muscle_thickness * _MM
    zc, width = 0.5 * (z0 + z1), z1 - z0
    if side < 0 and zc > 0:  # supraspinatus: pass above the glenoid rim
        zc = max(zc, 0.5 * g.glenoid_height * _MM + 3.0 + 0.5 * width)
    clear_y = side * (0.5 * g.glenoid_width * _MM + 2.0 + 0.5 * t_m)
    return np.array([lay.x_lat + 2.0, clear_y, zc])


def _muscle_sections(g: ShoulderGeometry, lay: _Layout, muscle: str) -> list:
    """Corner arrays (4 x 3, mm) of the rectangular sections along the muscle.

    Both ends lie flat on their bone, like a belly on its fossa: at the origin the underside is
    1 mm inside the blade from ``x0`` to ``x_a`` and rises from there in one straight ruled piece
    to the section clear of the neck, ``x_a`` chosen so that it leaves the blade exactly at ``x1``
    (no short edge at the footprint's border, which would mesh into slivers); at the insertion
    the muscle comes down onto its flat tuberosity facet over 4 mm at the near
    edge of the footprint and stays 1 mm inside it to the far edge. After the cut by the bones
    the bonded origin and insertion are exactly the footprint rectangles. In between, one
    section stands clear of the glenoid neck.
    """
    x0, x1, z0, z1, side = lay.origins[muscle]
    t_m = g.muscle_thickness * _MM
    n_out = np.array([0.0, side, 0.0])
    tangent = np.array([1.0, 0.0, 0.0])
    w_blade = np.cross(n_out, tangent)
    zc, width = 0.5 * (z0 + z1), z1 - z0

    def on_blade(x: float, lift: float) -> np.ndarray:
        h = blade_half_thickness(g, x)
        centre = np.array([x, side * (h + lift + 0.5 * t_m), zc])
        return _rect_corners(centre, tangent, w_blade, width, t_m)

    neck = _neck_clear_centre(g, lay, muscle)
    # The gap between the underside and the blade face is linear in x between two sections:
    # -1 mm at x_a, lift_n at the neck section, zero at x1.
    lift_n = abs(neck[1]) - 0.5 * t_m - blade_half_thickness(g, neck[0])
    x_a = (x1 * (1.0 + lift_n) - neck[0]) / lift_n
    if not (lift_n > 1.0 and x0 < x_a < x1):
        raise ValueError(
            f"{muscle}_origin_length = {x1 - x0:g} mm: the muscle cannot leave its origin "
            "footprint towards the glenoid neck (origin too close to the neck)"
        )
    sections = [on_blade(x0, -1.0), on_blade(x_a, -1.0)]
    sections.append(_rect_corners(neck, tangent, w_blade, width, t_m))
    d, e_w, e_n, big, small = lay.insertions[muscle]
    rot = lay.rot
    top = g.humeral_bone_radius * _MM + _FACET_RAISE
    n_f, w_f, travel = rot @ d, rot @ e_w, rot @ e_n
    centre = top * n_f + rot @ g.humeral_shift
    previous = sections[-1]
    arrival = ((-0.5 * small - 2.0, 1.0), (-0.5 * small + 2.0, -1.0), (0.5 * small, -1.0))
    for along, lift in arrival:
        c = centre + along * travel + (lift + 0.5 * t_m) * n_f
        corners = _rect_corners(c, travel, w_f, big, t_m)
        turn = _rotation_between(_unit(previous.mean(axis=0) - sections[-2].mean(axis=0)), travel)
        corners = _match_corners(previous, corners, turn)
        sections.append(corners)
        previous = corners
    return sections


# ---------------------------------------------------------------------------- gmsh model


def _rect_wire(occ, centre, tangent, w_dir, width, thick) -> int:
    return _quad_wire(occ, _rect_corners(centre, tangent, w_dir, width, thick))


def _quad_wire(occ, corners) -> int:
    pts = [occ.addPoint(*p) for p in corners]
    lines = [occ.addLine(pts[i], pts[(i + 1) % 4]) for i in range(4)]
    return occ.addWire(lines, checkClosed=True)


def _disk(occ, centre, normal, radius) -> int:
    n = _unit(normal)
    helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = _unit(np.cross(n, helper))
    v = np.cross(n, u)
    tag = occ.addDisk(0.0, 0.0, 0.0, radius, radius)
    a = [u[0], v[0], n[0], centre[0], u[1], v[1], n[1], centre[1], u[2], v[2], n[2], centre[2]]
    occ.affineTransform([(2, tag)], a)
    return tag


def _rotate_to_scapular(occ, dimtags, g: ShoulderGeometry) -> None:
    """Glenoid frame -> scapular frame (about the head centre)."""
    occ.rotate(dimtags, 0, 0, 0, 0, 1, 0, -g.glenoid_inclination)
    occ.rotate(dimtags, 0, 0, 0, 0, 0, 1, g.glenoid_version)


def build_model(g: ShoulderGeometry, sizes: dict) -> dict:
    """Build and mesh the shoulder in the current gmsh model (call on one rank only).

    Args:
        g: geometry parameters (validated here first).
        sizes: mesh sizes in m, the keys of :data:`SIZE_KEYS`.

    Returns:
        Information on the build: entity tags per marker, build time (s).

    Raises:
        ValueError: for invalid parameters (before any geometry) or a geometry that fails.
    """
    import gmsh

    g.validate()
    check_sizes(sizes)
    t0 = time.perf_counter()
    lay = layout(g)
    gmsh.model.add("shoulder")
    occ = gmsh.model.occ

    # --- humerus (glenoid frame, then rotated) -------------------------------------------
    rb, rh = g.humeral_bone_radius * _MM, g.articular_radius * _MM
    r_sub = g.subchondral_radius * _MM
    shift = g.humeral_shift  # anatomical centre (non-zero for a prosthetic head only)
    s, base = shaft_axis(g)
    base = base + shift
    head = occ.addSphere(0, 0, 0, r_sub)
    r_meta = _META_RADIUS * rb
    meta_len = _META_FRACTION * g.shaft_length * _MM
    cone_start = base + _META_START * s
    cone = occ.addCone(*cone_start, *(meta_len * s), r_meta, g.shaft_radius * _MM)
    shaft_start = cone_start + meta_len * s
    shaft = occ.addCylinder(
        *shaft_start, *((g.shaft_length * _MM - meta_len - _META_START) * s), g.shaft_radius * _MM
    )
    # Tuberosity facets: flat blocks carrying the insertion footprints.
    blocks = []
    for muscle in MUSCLES:
        d, e_w, e_n, big, small = lay.insertions[muscle]
        wide, thick = big + 2 * _FACET_MARGIN, small + 2 * _FACET_MARGIN
        top = _rect_wire(occ, (rb + _FACET_RAISE) * d + shift, d, e_w, wide, thick)
        tip = _rect_wire(occ, _BLOCK_TIP * rb * d + shift, d, e_w, 0.5 * wide, 0.5 * thick)
        blocks += occ.addThruSections([tip, top], makeSolid=True, makeRuled=True)
    # Humeral cartilage: shell between r_sub and rh, cap of half-angle alpha about -x.
    alpha = g.humeral_cartilage_angle
    # (A plane-cut shell, not a sphere segment about -x: a segment has a pole vertex exactly at
    # the contact point, which OCC would imprint on the glenoid and make a shared node.)
    outer = occ.addSphere(0, 0, 0, rh)
    inner = occ.addSphere(0, 0, 0, r_sub)
    shell, _ = occ.cut([(3, outer)], [(3, inner)])
    cut_x = -rh * math.cos(alpha)
    box = occ.addBox(-rh - 1.0, -rh - 1.0, -rh - 1.0, cut_x + rh + 1.0, 2 * rh + 2.0, 2 * rh + 2.0)
    hcart, _ = occ.intersect(shell, [(3, box)])
    if g.head_shape == "ellipsoidal":  # the head and its cartilage only, not the tuberosities
        occ.dilate([(3, head)] + hcart, 0, 0, 0, 1.0, g.head_ratio, 1.0)
    hum, _ = occ.fuse([(3, head)], [(3, cone), (3, shaft), *blocks])

    # --- glenoid (glenoid frame) ---------------------------------------------------------
    cg = (g.glenoid_radius - g.articular_radius - g.contact_offset) * _MM
    rg = g.glenoid_radius * _MM
    rgb = rg + g.glenoid_cartilage_thickness * _MM
    px0, px1 = lay.plate_x
    disk = occ.addDisk(0, 0, 0, 0.5 * g.glenoid_height * _MM, 0.5 * g.glenoid_width * _MM)
    occ.rotate([(2, disk)], 0, 0, 0, 0, 1, 0, math.pi / 2)  # normal z -> x, major axis -> z
    occ.translate([(2, disk)], px0, 0, 0)
    plate = occ.extrude([(2, disk)], px1 - px0, 0, 0)
    plate_vol = [dt for dt in plate if dt[0] == 3]
    gl_outer = occ.addSphere(cg, 0, 0, rgb)
    gl_inner = occ.addSphere(cg, 0, 0, rg)
    gshell, _ = occ.cut([(3, gl_outer)], [(3, gl_inner)])
    gcart, _ = occ.intersect(gshell, occ.copy(plate_vol))
    # Neck: loft from the glenoid oval at the plate's medial end to the blade junction.
    e1 = occ.addEllipse(0, 0, 0, 0.5 * g.glenoid_height * _MM, 0.5 * g.glenoid_width * _MM)
    occ.rotate([(1, e1)], 0, 0, 0, 0, 1, 0, math.pi / 2)
    occ.translate([(1, e1)], px0, 0, 0)  # the plate's medial face: no thin step
    glen = plate_vol + gcart
    _rotate_to_scapular(occ, glen + [(1, e1)], g)
    hum_all = hum + hcart
    _rotate_to_scapular(occ, hum_all, g)
    w1 = occ.addWire([e1])
    # Junction oval in the scapular frame (blade lateral border): 0.7 x glenoid height tall.
    e2 = occ.addEllipse(
        0, 0, 0, 0.35 * g.glenoid_height * _MM, 0.5 * g.blade_thickness_lateral * _MM
    )
    occ.rotate([(1, e2)], 0, 0, 0, 0, 1, 0, math.pi / 2)
    occ.translate([(1, e2)], lay.x_lat, 0, 0)
    w2 = occ.addWire([e2])
    neck = occ.addThruSections([w1, w2], makeSolid=True, makeRuled=False)
    # Blade: ruled loft from the lateral (thick) to the medial (thin) border.
    blade_x0 = lay.x_lat + 4.0
    z_mid = 0.5 * (lay.z_top + lay.z_bot)
    height = lay.z_top - lay.z_bot
    w_lat = _rect_wire(
        occ,
        np.array([blade_x0, 0.0, z_mid]),
        (1, 0, 0),
        (0, 0, 1),
        height,
        2 * blade_half_thickness(g, blade_x0),
    )
    w_med = _rect_wire(
        occ,
        np.array([lay.x_med, 0.0, z_mid]),
        (1, 0, 0),
        (0, 0, 1),
        height,
        g.blade_thickness_medial * _MM,
    )
    blade = occ.addThruSections([w_lat, w_med], makeSolid=True, makeRuled=True)
    scap, _ = occ.fuse(plate_vol, neck + blade)
    # Concave glenoid face: remove the sphere of the subchondral bone surface.
    cg_s = lay.rot @ np.array([cg, 0.0, 0.0])
    cutter = occ.addSphere(*cg_s, rgb)
    scap, _ = occ.cut(scap, [(3, cutter)])
    # Horizontal section at the contact level (z = 0): split the scapula only.
    big = 400.0
    rect = occ.addRectangle(-big, -big / 2, 0.0, 1.5 * big, big)
    pieces, _ = occ.fragment(scap, [(2, rect)])
    occ.synchronize()
    scap = [dt for dt in pieces if dt[0] == 3]
    stray = [(2, t) for d, t in pieces if d == 2 and not len(gmsh.model.getAdjacencies(2, t)[0])]
    if stray:
        occ.remove(stray, recursive=True)

    # --- muscles -------------------------------------------------------------------------
    muscles = {}
    for muscle in MUSCLES:
        wires = [_quad_wire(occ, corners) for corners in lay.muscles[muscle]]
        vol = occ.addThruSections(wires, makeSolid=True, makeRuled=True)
        muscles[muscle] = vol
    obstacles = hum_all + glen[len(plate_vol) :] + scap
    for muscle in MUSCLES:
        cut, _ = occ.cut(muscles[muscle], obstacles, removeObject=True, removeTool=False)
        muscles[muscle] = cut

    # --- spring patches ------------------------------------------------------------------
    r_patch = g.spring_patch_radius * _MM
    patches = [_disk(occ, c, n, r_patch) for c, n in lay.spring_points]
    ap_patch = _disk(occ, *lay.ap_point, r_patch)
    d_centre, d_axis, d_points = lay.distal
    distal_patches = [_disk(occ, p, d_axis, 0.8 * r_patch) for p in d_points]

    # --- one fragment: conforming bonded interfaces --------------------------------------
    groups = {
        "humerus": hum,
        "humeral_cartilage": hcart,
        "scapula": scap,
        "glenoid_cartilage": gcart,
        **muscles,
    }
    objects = [dt for v in groups.values() for dt in v]
    tools = [(2, t) for t in patches + [ap_patch] + distal_patches]
    out, out_map = occ.fragment(objects, tools)
    occ.synchronize()
    owner: dict[int, str] = {}
    k = 0
    for name, dts in groups.items():
        for _ in dts:
            for dim, tag in out_map[k]:
                if dim == 3:
                    owner[tag] = name
            k += 1
    patch_faces = []
    for j in range(len(tools)):
        patch_faces.append([t for d, t in out_map[len(objects) + j] if d == 2])
    info = _classify(gmsh, g, lay, owner, patch_faces, d_centre, d_axis)
    info["layout"] = lay
    info["geometry"] = g
    info["distal_patch_faces"] = [f for faces in patch_faces[-len(distal_patches) :] for f in faces]
    _set_physical_groups(gmsh, info, bones=True)
    info["geometry_s"] = time.perf_counter() - t0
    _mesh(gmsh, info, sizes)
    info["build_s"] = time.perf_counter() - t0
    info["meshing_s"] = info["build_s"] - info["geometry_s"]
    return info


def _classify(gmsh, g, lay, owner, patch_faces, d_centre, d_axis) -> dict:
    """Entity tags (gmsh) for every marker, from volume adjacency and geometry."""
    model = gmsh.model
    vols: dict[str, list[int]] = {m.name: [] for m in VOLUMES}
    for tag, name in owner.items():
        vols[name].append(tag)
    face_owners: dict[int, list[str]] = {}
    for name, tags in vols.items():
        for tag in tags:
            for _, f in model.getBoundary([(3, tag)], oriented=False):
                face_owners.setdefault(abs(f), []).append(name)
    surf: dict[str, list[int]] = {m.name: [] for m in SURFACES}
    n_springs = len(lay.spring_points)
    spring_of = {}
    for j, faces in enumerate(patch_faces):
        for f in faces:
            spring_of[f] = j
    free_cart: dict[str, list[int]] = {}
    for f, names in face_owners.items():
        key = tuple(sorted(names))
        if len(names) == 2:
            a, b = key
            if a == b == "scapula":
                surf["scapula_section"].append(f)
            elif a == b:
                continue  # interior face between two pieces of one body
            elif key == ("humeral_cartilage", "humerus"):
                surf["humeral_cartilage_bone"].append(f)
            elif key == ("glenoid_cartilage", "scapula"):
                surf["glenoid_cartilage_bone"].append(f)
            elif "humerus" in key and set(key) & set(MUSCLES):
                surf[f"{(set(key) & set(MUSCLES)).pop()}_insertion"].append(f)
            elif "scapula" in key and set(key) & set(MUSCLES):
                surf[f"{(set(key) & set(MUSCLES)).pop()}_origin"].append(f)
            elif key == ("humerus", "scapula"):
                raise ValueError("geometry: the humerus and the scapula overlap")
            else:
                raise ValueError(f"geometry: unexpected bonded interface between {a} and {b}")
            continue
        name = names[0]
        if name in MUSCLES:
            surf[f"{name}_surface"].append(f)
        elif name in ("humeral_cartilage", "glenoid_cartilage"):
            free_cart.setdefault(name, []).append(f)
        elif f in spring_of:
            j = spring_of[f]
            if j < n_springs:
                surf[f"scapula_spring_{j + 1:02d}"].append(f)
            elif j == n_springs:
                surf["scapula_ap_spring"].append(f)
            else:
                surf[f"humerus_distal_spring_{j - n_springs}"].append(f)
        elif name == "humerus":
            com = np.array(gmsh.model.occ.getCenterOfMass(2, f))
            if abs(np.dot(com - d_centre, d_axis)) < 1e-3 and np.linalg.norm(com - d_centre) < 5:
                surf["humerus_distal"].append(f)
            else:
                surf["humerus_surface"].append(f)
        else:
            surf["scapula_surface"].append(f)
    # The articular surface is the largest free face of a cartilage, the rest is its edge.
    for name, faces in free_cart.items():
        side = name.split("_")[0]
        areas = [gmsh.model.occ.getMass(2, f) for f in faces]
        big = faces[int(np.argmax(areas))]
        surf[f"{side}_articular"].append(big)
        surf[f"{side}_cartilage_edge"] += [f for f in faces if f != big]
    return {"volumes": vols, "surfaces": surf}


def _set_physical_groups(gmsh, info: dict, bones: bool) -> None:
    """Physical groups from the marker table; ``bones=False`` leaves the bone volumes out."""
    model = gmsh.model
    model.removePhysicalGroups()
    for m in VOLUMES:
        if not bones and m in BONES:
            continue
        model.addPhysicalGroup(3, info["volumes"][m.name], m.id)
        model.setPhysicalName(3, m.id, m.name)
    for m in SURFACES:
        if not bones and m not in SOFT_SURFACES:
            continue
        model.addPhysicalGroup(2, info["surfaces"][m.name], m.id)
        model.setPhysicalName(2, m.id, m.name)


#: Keys of a level's mesh sizes (m) and what they size.
SIZE_KEYS = {
    "h_joint": "cartilages, and bone within JOINT_ZONE of a cartilage-bone interface",
    "h_bone": "bone far from the joint (grows from h_joint over JOINT_GRADING)",
    "h_muscle": "muscles",
}
JOINT_ZONE = 4.0e-3  # m
JOINT_GRADING = 35.0e-3  # m
#: Thin-body caps (all levels; they bind at coarse sizes only): the blade's elements are at most
#: BLADE_SIZE_FACTOR x its local thickness, the humerus's at most SHAFT_SIZE_FACTOR x the shaft
#: radius, and the distal spring patches are meshed at PATCH_SIZE_FACTOR x their radius.
#: Without them a coarse element spans the 2 mm medial blade or the whole shaft (flat tets).
BLADE_SIZE_FACTOR = 3.0
SHAFT_SIZE_FACTOR = 1.2
PATCH_SIZE_FACTOR = 2.0


def check_sizes(sizes: dict) -> None:
    """Raise ValueError unless ``sizes`` has every :data:`SIZE_KEYS` entry > 0 (m)."""
    for key in SIZE_KEYS:
        value = sizes.get(key)
        if isinstance(value, bool) or not isinstance(value, int | float) or not value > 0:
            raise ValueError(f"mesh size {key} = {value!r}: must be given, in m, and > 0")
        if value > 0.1:
            raise ValueError(f"mesh size {key} = {value * 1e3:g} mm: must be <= 100 mm")


def _mesh(gmsh, info: dict, sizes: dict) -> None:
    """Size fields (one per kind of body) and the 3D mesh of every volume."""
    model = gmsh.model
    h_joint, h_bone, h_muscle = (sizes[k] * _MM for k in ("h_joint", "h_bone", "h_muscle"))
    vols = info["volumes"]
    fld = model.mesh.field

    def restricted(inner: int, names: tuple[str, ...]) -> int:
        """Field ``inner`` on the volumes ``names`` and on every entity of their boundaries."""
        tags = [t for n in names for t in vols[n]]
        faces = {abs(t) for _, t in model.getBoundary([(3, t) for t in tags], False, False)}
        curves = {abs(t) for _, t in model.getBoundary([(2, t) for t in faces], False, False)}
        points = {abs(t) for _, t in model.getBoundary([(1, t) for t in curves], False, False)}
        r = fld.add("Restrict")
        fld.setNumber(r, "InField", inner)
        fld.setNumbers(r, "RegionsList", tags)
        fld.setNumbers(r, "FacesList", sorted(faces))
        fld.setNumbers(r, "EdgesList", sorted(curves))
        fld.setNumbers(r, "VerticesList", sorted(points))
        return r

    def constant(h: float) -> int:
        c = fld.add("MathEval")
        fld.setString(c, "F", repr(float(h)))
        return c

    joint_faces = info["surfaces"]["humeral_cartilage_bone"]
    joint_faces = joint_faces + info["surfaces"]["glenoid_cartilage_bone"]
    dist = fld.add("Distance")
    fld.setNumbers(dist, "FacesList", joint_faces)
    graded = fld.add("Threshold")
    fld.setNumber(graded, "InField", dist)
    fld.setNumber(graded, "SizeMin", h_joint)
    fld.setNumber(graded, "SizeMax", max(h_bone, h_joint))
    fld.setNumber(graded, "DistMin", JOINT_ZONE * _MM)
    fld.setNumber(graded, "DistMax", JOINT_GRADING * _MM)
    parts = [
        restricted(constant(h_joint), ("humeral_cartilage", "glenoid_cartilage")),
        restricted(graded, ("humerus", "scapula")),
        restricted(constant(h_muscle), MUSCLES),
    ]
    g, lay = info["geometry"], info["layout"]
    # Blade: size <= factor x local thickness, linear in x (scapular frame, mm); larger than the
    # neck and glenoid need laterally of the blade, so applied to the whole scapula.
    t_lat, t_med = g.blade_thickness_lateral * _MM, g.blade_thickness_medial * _MM
    slope = BLADE_SIZE_FACTOR * (t_lat - t_med) / (lay.x_lat - lay.x_med)
    at_zero = BLADE_SIZE_FACTOR * t_lat - slope * lay.x_lat
    blade = fld.add("MathEval")
    fld.setString(blade, "F", f"{at_zero:.9g}{slope:+.9g}*x")  # no "- -": gmsh's parser aborts
    parts.append(restricted(blade, ("scapula",)))
    parts.append(restricted(constant(SHAFT_SIZE_FACTOR * g.shaft_radius * _MM), ("humerus",)))
    # Distal spring patches (small disks on the shaft section): graded from their border.
    r_patch = g.spring_patch_radius * _MM
    patch_curves = model.getBoundary([(2, f) for f in info["distal_patch_faces"]], False, False)
    near_patch = fld.add("Distance")
    fld.setNumbers(near_patch, "EdgesList", sorted({abs(t) for _, t in patch_curves}))
    patch = fld.add("Threshold")
    fld.setNumber(patch, "InField", near_patch)
    fld.setNumber(patch, "SizeMin", PATCH_SIZE_FACTOR * r_patch)
    fld.setNumber(patch, "SizeMax", 1e3)
    fld.setNumber(patch, "DistMin", r_patch)
    fld.setNumber(patch, "DistMax", 3 * r_patch)
    parts.append(patch)
    smallest = fld.add("Min")
    fld.setNumbers(smallest, "FieldsList", parts)
    fld.setAsBackgroundMesh(smallest)
    gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 0)
    gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
    gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 0)
    gmsh.option.setNumber("Mesh.MeshSizeMin", 0.25 * min(h_joint, h_bone, h_muscle))
    gmsh.option.setNumber("Mesh.MeshSizeMax", max(h_joint, h_bone, h_muscle))
    # MeshAdapt for the surfaces: the cartilage rims and the borders of the thin blade are
    # narrow curved bands about one element tall, where the Delaunay/frontal 2D algorithms make
    # flat triangles at some sizes (then slivers, or a failed boundary recovery in 3D).
    gmsh.option.setNumber("Mesh.Algorithm", 1)
    gmsh.option.setNumber("Mesh.Algorithm3D", 1)
    gmsh.option.setNumber("Mesh.Optimize", 1)
    gmsh.option.setNumber("Mesh.MinimumCirclePoints", 5)  # spring patches: pentagons at least
    gmsh.option.setNumber("Mesh.RandomSeed", 1)
    gmsh.option.setNumber("General.NumThreads", 1)
    gmsh.option.setNumber("Mesh.MaxNumThreads3D", 1)
    model.mesh.generate(2)
    # Tetrahedralise one volume at a time: the surface meshes (hence the shared nodes of the
    # bonded interfaces) are fixed by now, and bodies that only come close (the articular
    # surfaces 1 um apart, a muscle gliding over a bone) cannot make one boundary-recovery
    # problem fail where their triangulations cross.
    every = [(3, t) for tags in info["volumes"].values() for t in tags]
    gmsh.option.setNumber("Mesh.MeshOnlyVisible", 1)
    try:
        for one in every:
            model.setVisibility(every, 0, recursive=False)
            model.setVisibility([one], 1, recursive=False)
            model.mesh.generate(3)
    finally:
        model.setVisibility(every, 1, recursive=False)
        gmsh.option.setNumber("Mesh.MeshOnlyVisible", 0)


# ---------------------------------------------------------------------------- dolfinx


@dataclass
class ShoulderMesh:
    """A dolfinx mesh of the shoulder and its tags (coordinates in m).

    Attributes:
        mesh: the tetrahedral mesh (all bodies for ``deformable``, soft tissues only for
            ``rigid-bone``).
        cell_tags: volume markers (:data:`VOLUMES`).
        facet_tags: surface markers (:data:`SURFACES`).
        bone_surface: ``rigid-bone`` only: triangle mesh of the kept bone surfaces (tdim 2).
        bone_surface_tags: its cell tags (surface markers).
        info: build information (rank 0; broadcast scalars), e.g. ``build_s``.
    """

    mesh: object
    cell_tags: object
    facet_tags: object
    bone_surface: object = None
    bone_surface_tags: object = None
    info: dict = field(default_factory=dict)


def model_to_dolfinx(
    comm: MPI.Comm,
    info: dict | None,
    variant: str,
    rank: int = 0,
    detach: tuple = (),
    head_layer: bool = False,
    scapula_layer: bool = False,
):
    """Turn the meshed gmsh model (on ``rank``) into dolfinx meshes with tags, scaled to metres.

    Args:
        comm: communicator the meshes are distributed on (collective).
        info: the result of :func:`build_model` on ``rank`` (ignored elsewhere).
        variant: ``"deformable"``, ``"rigid-bone"``, ``"scapula"`` or ``"humerus"`` (that
            bone's volume and the surfaces on it).
        rank: the rank holding the gmsh model.
        detach: ``deformable`` only: names of bonded surfaces to cut open, as
            ``(surface, volume)`` pairs: the volume's cells get their own copy of the
            surface's nodes (the surface tag then marks the volume's side). E.g.
            ``(("subscapularis_origin", "subscapularis"),)`` frees a muscle's origin from the
            bone so that it can be displaced.
        head_layer: ``rigid-bone`` only: keep the humerus cells under the head's free surface
            (:data:`HUMERUS_HEAD_LAYER`), for muscle-bone contact on a rigid humerus.
        scapula_layer: ``rigid-bone`` only: keep the scapula cells under its free surface near
            the muscles (:data:`SCAPULA_LAYER`), for muscle-scapula contact on a rigid scapula;
            the ``detach`` pairs are then cut open as in ``deformable`` (the driven
            subscapularis origin is not tied to the layer).

    Returns:
        (mesh, cell_tags, facet_tags, bone_surface, bone_surface_tags); the last two are None for
        ``deformable``.
    """
    import gmsh
    from dolfinx.io import gmshio

    if variant not in VARIANTS:
        raise ValueError(f"variant = {variant!r}: expected one of {VARIANTS}")
    if variant in BONE_VARIANTS:
        # one bone alone (the scapula for part 2 of the decoupled method, the humerus for its
        # compliant correction): its volume and every surface whose nodes are all the bone's
        # (interfaces, springs, section), node for node those of the other variants
        bone = BONE_VARIANTS[variant]
        cells = {bone.id: info["volumes"][bone.name]} if comm.rank == rank else None
        facets = (
            {m.id: info["surfaces"][m.name] for m in SURFACES if m.name in info["surfaces"]}
            if comm.rank == rank
            else None
        )
        mesh, ct, ft = _tagged_mesh(comm, rank, 3, cells, facets)
        return mesh, ct, ft, None, None
    if variant == "deformable" and detach:
        cells = {m.id: info["volumes"][m.name] for m in VOLUMES} if comm.rank == rank else None
        facets = (
            {m.id: info["surfaces"][m.name] for m in SURFACES if m.name in info["surfaces"]}
            if comm.rank == rank
            else None
        )
        split = tuple((MARKERS[a].id, MARKERS[b].id) for a, b in detach)
        mesh, ct, ft = _tagged_mesh(comm, rank, 3, cells, facets, split)
        return mesh, ct, ft, None, None
    if variant == "deformable":
        if comm.rank == rank:
            _set_physical_groups(gmsh, info, bones=True)
        model = gmsh.model if comm.rank == rank else None
        mesh, ct, ft = gmshio.model_to_mesh(model, comm, rank, 3)
        mesh.geometry.x[:] /= _MM
        return mesh, ct, ft, None, None
    # rigid-bone: soft tissues as volumes; the kept bone surfaces as a triangle mesh. Both take
    # their nodes from the one gmsh mesh, so shared surfaces are node for node those of the
    # deformable variant. (gmshio.model_to_mesh passes every node of the model to dolfinx, which
    # fails when some are used by no cell; this keeps only the used ones.)
    soft_cells = {m.id: info["volumes"][m.name] for m in SOFT} if comm.rank == rank else None
    soft_facets = (
        {m.id: info["surfaces"][m.name] for m in SOFT_SURFACES} if comm.rank == rank else None
    )
    layers = []
    if head_layer and comm.rank == rank:
        # the humerus cells on the head's free surface (see HUMERUS_HEAD_LAYER) and that surface
        soft_facets[MARKERS["humerus_surface"].id] = info["surfaces"]["humerus_surface"]
        reach = head_region_radius(info["geometry"]) * _MM
        layers.append((HUMERUS_HEAD_LAYER.id, _head_layer_elements(info, reach)))
    split = ()
    if scapula_layer:
        split = tuple((MARKERS[a].id, MARKERS[b].id) for a, b in detach)
        if comm.rank == rank:  # the scapula cells under the muscles (see SCAPULA_LAYER)
            soft_facets[MARKERS["scapula_surface"].id] = info["surfaces"]["scapula_surface"]
            reach = _LAYER_MARGIN * scapula_reach(info["geometry"]) * _MM
            layers.append((SCAPULA_LAYER.id, _scapula_layer_elements(info, reach)))
    mesh, ct, ft = _tagged_mesh(comm, rank, 3, soft_cells, soft_facets, split, layers)
    bone_cells = (
        {m.id: info["surfaces"][m.name] for m in RIGID_BONE_SURFACES} if comm.rank == rank else None
    )
    surf, surf_tags, _ = _tagged_mesh(comm, rank, 2, bone_cells, None)
    return mesh, ct, ft, surf, surf_tags


def _tagged_mesh(
    comm: MPI.Comm,
    rank: int,
    tdim: int,
    cells: dict | None,
    facets: dict | None,
    split: tuple = (),
    extra_cells: list | None = None,
):
    """A dolfinx mesh (m) of the gmsh elements on the given entities, with cell and facet tags.

    Args:
        comm: communicator (collective).
        rank: rank holding the gmsh model.
        tdim: 3 (tetrahedra) or 2 (triangles in 3D).
        cells: on ``rank``: tag value -> gmsh entities of dimension ``tdim``.
        facets: on ``rank``: tag value -> gmsh entities of dimension ``tdim - 1`` (or None).
        split: ``(facet tag, cell tag)`` pairs: the nodes of those facets are duplicated for
            the cells of that tag (the interface is cut open; the facets keep the copy).
        extra_cells: on ``rank``: ``[(tag value, gmsh node tags (n, tdim + 1)), ...]``, cells
            given element by element (or None).
    """
    import dolfinx
    import gmsh
    from dolfinx.cpp.graph import AdjacencyList_int32
    from dolfinx.cpp.io import distribute_entity_data
    from dolfinx.io import gmshio

    gmsh_cell = {3: 4, 2: 2}[tdim]
    gmsh_facet = {3: 2, 2: 1}[tdim]
    nper, fper = tdim + 1, tdim
    if comm.rank == rank:
        node_tags, coords, _ = gmsh.model.mesh.getNodes()
        coords = coords.reshape(-1, 3)
        lookup = np.full(int(node_tags.max()) + 1, -1, dtype=np.int64)
        lookup[node_tags.astype(np.int64)] = np.arange(len(node_tags))

        def collect(groups: dict, dim: int, etype: int, nn: int):
            topo, vals = [np.empty((0, nn), dtype=np.int64)], [np.empty(0, dtype=np.int32)]
            for value, entities in groups.items():
                for ent in entities:
                    types, _, nodes = gmsh.model.mesh.getElements(dim, ent)
                    for t, n in zip(types, nodes, strict=True):
                        if t == etype:
                            conn = lookup[np.asarray(n, dtype=np.int64)].reshape(-1, nn)
                            topo.append(conn)
                            vals.append(np.full(len(conn), value, dtype=np.int32))
            return np.vstack(topo), np.concatenate(vals)

        cell_topo, cell_vals = collect(cells, tdim, gmsh_cell, nper)
        for value, elements in extra_cells or ():
            cell_topo = np.vstack([cell_topo, lookup[np.asarray(elements, dtype=np.int64)]])
            cell_vals = np.concatenate([cell_vals, np.full(len(elements), value, np.int32)])
        used, cell_topo = np.unique(cell_topo, return_inverse=True)
        cell_topo = cell_topo.reshape(-1, nper)
        x = coords[used] / _MM
        if facets:
            facet_topo, facet_vals = collect(facets, tdim - 1, gmsh_facet, fper)
            compact = np.full(len(node_tags), -1, dtype=np.int64)
            compact[used] = np.arange(len(used))
            facet_topo = compact[facet_topo]
            keep = np.all(facet_topo >= 0, axis=1)
            facet_topo, facet_vals = facet_topo[keep], facet_vals[keep]
            for facet_tag, cell_tag in split:
                on = facet_vals == facet_tag
                nodes = np.unique(facet_topo[on])
                copy = np.arange(len(x), len(x) + len(nodes))
                x = np.vstack([x, x[nodes]])
                remap = np.arange(len(x))
                remap[nodes] = copy
                mine = cell_vals == cell_tag
                cell_topo[mine] = remap[cell_topo[mine]]
                # every facet of the volume's cells that touches the cut takes the copy
                touching = mine & np.any(cell_topo >= copy[0], axis=1)
                faces = {
                    tuple(sorted(np.delete(c, i))) for c in cell_topo[touching] for i in range(nper)
                }
                for j in np.flatnonzero(np.any(np.isin(facet_topo, nodes), axis=1)):
                    moved = remap[facet_topo[j]]
                    if tuple(sorted(moved)) in faces:
                        facet_topo[j] = moved
            if split:  # the originals that no cell keeps (a partial layer: rigid-bone) go
                used = np.unique(cell_topo)
                compact = np.full(len(x), -1, dtype=np.int64)
                compact[used] = np.arange(len(used))
                x, cell_topo, facet_topo = x[used], compact[cell_topo], compact[facet_topo]
                keep = np.all(facet_topo >= 0, axis=1)
                facet_topo, facet_vals = facet_topo[keep], facet_vals[keep]
        else:
            facet_topo = np.empty((0, fper), dtype=np.int64)
            facet_vals = np.empty(0, dtype=np.int32)
    else:
        cell_topo = np.empty((0, nper), dtype=np.int64)
        cell_vals = np.empty(0, dtype=np.int32)
        facet_topo = np.empty((0, fper), dtype=np.int64)
        facet_vals = np.empty(0, dtype=np.int32)
        x = np.empty((0, 3))
    domain = gmshio.ufl_mesh(gmsh_cell, 3)
    mesh = dolfinx.mesh.create_mesh(comm, cell_topo, x, domain)
    entities, values = distribute_entity_data(mesh._mesh, tdim, cell_topo, cell_vals)
    mesh.topology.create_connectivity(tdim, 0)
    ct = dolfinx.mesh.meshtags_from_entities(
        mesh, tdim, AdjacencyList_int32(entities), values.astype(np.int32)
    )
    ct.name = "Cell tags"
    entities, values = distribute_entity_data(mesh._mesh, tdim - 1, facet_topo, facet_vals)
    mesh.topology.create_connectivity(tdim - 1, 0)
    mesh.topology.create_connectivity(tdim - 1, tdim)
    ft = dolfinx.mesh.meshtags_from_entities(
        mesh, tdim - 1, AdjacencyList_int32(entities), values.astype(np.int32)
    )
    ft.name = "Facet tags"
    return mesh, ct, ft


def head_region_radius(g: ShoulderGeometry) -> float:
    """Reach (m) of the muscle-bone contact region about the articular centre.

    The one value behind both the rigid-bone layer (:func:`_head_layer_elements`) and the
    facet tags (:func:`head_surface_tags`), so that the master facets lie on the layer.
    """
    return HEAD_REGION_FACTOR * g.articular_radius


def _head_layer_elements(info: dict, radius_mm: float) -> np.ndarray:
    """Node tags (gmsh, (n, 4)) of the humerus tetrahedra on its free surface near the head.

    The surface triangles are those of ``humerus_surface`` whose centroid lies within
    ``radius_mm`` of the articular centre (the origin); the cells, every humerus tetrahedron
    with a node on them (gmsh rank only).
    """
    xyz = _gmsh_node_coordinates()
    tri = _gmsh_triangles(info, ("humerus_surface",))
    near = np.linalg.norm(xyz[tri].mean(axis=1), axis=1) < radius_mm
    return _gmsh_tets_touching(info, HUMERUS.name, np.unique(tri[near]))


def scapula_reach(g: ShoulderGeometry) -> float:
    """Reach (m) of the muscle-scapula contact: :data:`SCAPULA_REACH_FACTOR` muscle thicknesses.

    The one value behind the rigid-bone layer (:func:`_scapula_layer_elements`, with a margin)
    and the facet tags (:func:`scapula_surface_tags`).
    """
    return SCAPULA_REACH_FACTOR * g.muscle_thickness


def _closest_on_triangles(p, a, b, c) -> np.ndarray:
    """Closest point of each triangle (a, b, c) to p, row by row ((n, 3) each; Ericson 2005)."""

    def dot(u, v):
        return np.einsum("ij,ij->i", u, v)

    ab, ac, ap, bp, cp = b - a, c - a, p - a, p - b, p - c
    d1, d2, d3, d4, d5, d6 = (
        dot(ab, ap),
        dot(ac, ap),
        dot(ab, bp),
        dot(ac, bp),
        dot(ab, cp),
        dot(ac, cp),
    )
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        den = va + vb + vc
        q = a + ab * (vb / den)[:, None] + ac * (vc / den)[:, None]  # the interior
        on_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        cases = [
            ((va <= 0) & (d4 >= d3) & (d5 >= d6), b + (c - b) * on_bc[:, None]),  # edge bc
            ((vb <= 0) & (d2 >= 0) & (d6 <= 0), a + ac * (d2 / (d2 - d6))[:, None]),  # edge ac
            ((vc <= 0) & (d1 >= 0) & (d3 <= 0), a + ab * (d1 / (d1 - d3))[:, None]),  # edge ab
            ((d6 >= 0) & (d5 <= d6), c),
            ((d3 >= 0) & (d4 <= d3), b),
            ((d1 <= 0) & (d2 <= 0), a),
        ]
    for where, at in cases:  # the vertices last: they win where their regions meet the edges'
        q = np.where(where[:, None], at, q)
    return q


def _closest_within(points: np.ndarray, tris: np.ndarray, reach: float):
    """Distance (inf beyond ``reach``) and closest point of each point on the triangles.

    ``points`` (n, 3), ``tris`` (m, 3, 3): only the triangles whose centroid lies within reach
    plus the largest centroid-vertex distance are tested exactly.
    """
    from scipy.spatial import cKDTree

    dist, q = np.full(len(points), np.inf), np.zeros((len(points), 3))
    if len(points) == 0 or len(tris) == 0:
        return dist, q
    cen = tris.mean(axis=1)
    rad = float(np.linalg.norm(tris - cen[:, None], axis=2).max())
    near = cKDTree(cen).query_ball_point(points, reach + rad)
    counts = np.array([len(k) for k in near])
    if counts.sum() == 0:
        return dist, q
    pi = np.repeat(np.arange(len(points)), counts)
    ti = np.concatenate([np.asarray(k, dtype=np.int64) for k in near if k])
    qq = _closest_on_triangles(points[pi], *(tris[ti, i] for i in range(3)))
    d2 = np.einsum("ij,ij->i", qq - points[pi], qq - points[pi])
    order = np.lexsort((d2, pi))
    first = order[np.unique(pi[order], return_index=True)[1]]
    dist[pi[first]], q[pi[first]] = np.sqrt(d2[first]), qq[first]
    dist[dist > reach] = np.inf
    return dist, q


def _gmsh_node_coordinates() -> np.ndarray:
    """Coordinates of every gmsh node, indexed by its tag (gmsh rank only)."""
    import gmsh

    node_tags, coords, _ = gmsh.model.mesh.getNodes()
    xyz = np.zeros((int(node_tags.max()) + 1, 3))
    xyz[node_tags.astype(np.int64)] = coords.reshape(-1, 3)
    return xyz


def _gmsh_tets_touching(info: dict, volume: str, on: np.ndarray) -> np.ndarray:
    """Node tags (gmsh, (n, 4)) of the tetrahedra of ``volume`` with a node in ``on``."""
    import gmsh

    cells = [np.zeros((0, 4), dtype=np.int64)]
    for ent in info["volumes"][volume]:
        types, _, nodes = gmsh.model.mesh.getElements(3, ent)
        for t, n in zip(types, nodes, strict=True):
            if t == 4:
                tet = np.asarray(n, dtype=np.int64).reshape(-1, 4)
                cells.append(tet[np.isin(tet, on).any(axis=1)])
    return np.vstack(cells)


def _gmsh_triangles(info: dict, names: tuple[str, ...]) -> np.ndarray:
    """Node tags (gmsh, (n, 3)) of the triangles of the named surfaces (gmsh rank only)."""
    import gmsh

    out = [np.zeros((0, 3), dtype=np.int64)]
    for name in names:
        for ent in info["surfaces"][name]:
            types, _, nodes = gmsh.model.mesh.getElements(2, ent)
            pairs = zip(types, nodes, strict=True)
            out += [np.asarray(n, np.int64).reshape(-1, 3) for t, n in pairs if t == 2]
    return np.vstack(out)


def _scapula_layer_elements(info: dict, reach_mm: float) -> np.ndarray:
    """Node tags (gmsh, (n, 4)) of the scapula tetrahedra under its free surface near the muscles.

    The surface triangles are those of ``scapula_surface`` whose centroid lies within
    ``reach_mm`` of the muscles' free surfaces; the cells, every scapula tetrahedron with a node
    on them (gmsh rank only).
    """
    xyz = _gmsh_node_coordinates()
    bone = _gmsh_triangles(info, ("scapula_surface",))
    muscle = _gmsh_triangles(info, tuple(f"{m}_surface" for m in MUSCLES))
    dist, _ = _closest_within(xyz[bone].mean(axis=1), xyz[muscle], reach_mm)
    return _gmsh_tets_touching(info, SCAPULA.name, np.unique(bone[np.isfinite(dist)]))


def _facet_triangles(mesh, facets: np.ndarray) -> np.ndarray:
    """Vertex coordinates (m, (n, 3, 3)) of straight facets, in their vertex order."""
    tdim = mesh.topology.dim
    mesh.topology.create_connectivity(tdim - 1, 0)
    mesh.topology.create_connectivity(tdim, 0)
    n_vert = mesh.topology.index_map(0).size_local + mesh.topology.index_map(0).num_ghosts
    v_to_x = np.zeros(n_vert, dtype=np.int64)
    v_to_x[mesh.topology.connectivity(tdim, 0).array] = mesh.geometry.dofmap.array
    f2v = mesh.topology.connectivity(tdim - 1, 0)
    if len(facets) == 0:
        return np.zeros((0, 3, 3))
    return mesh.geometry.x[v_to_x[np.vstack([f2v.links(f) for f in facets])]]


def _gathered(comm, a: np.ndarray) -> np.ndarray:
    """The rows of ``a`` of every rank, on every rank (collective)."""
    return np.concatenate(comm.allgather(a))


def _outward_normals(mesh, facets: np.ndarray) -> np.ndarray:
    """Unit outward normals of boundary facets (straight simplices, reference positions)."""
    tdim = mesh.topology.dim
    mesh.topology.create_connectivity(tdim - 1, tdim)
    f2c = mesh.topology.connectivity(tdim - 1, tdim)
    f2v = mesh.topology.connectivity(tdim - 1, 0)
    c2v = mesh.topology.connectivity(tdim, 0)
    geo = mesh.geometry.dofmap
    x = mesh.geometry.x
    out = np.zeros((len(facets), 3))
    for k, f in enumerate(facets):
        cell = f2c.links(f)[0]
        cv, fv = c2v.links(cell), f2v.links(f)
        pts = x[geo.links(cell)]  # straight P1 geometry: vertex order of the cell
        a, b, c = (pts[np.flatnonzero(cv == v)[0]] for v in fv)
        inner = pts[np.flatnonzero(~np.isin(cv, fv))[0]]
        n = np.cross(b - a, c - a)
        out[k] = -n if np.dot(n, inner - a) > 0 else n
    return out / np.linalg.norm(out, axis=1)[:, None]


def head_surface_tags(mesh, facet_tags, radius: float):
    """Facet tags with the surfaces of muscle-bone contact on the head re-tagged (collective).

    The ``humerus_surface`` facets whose centroid lies within ``radius`` (m) of the articular
    centre (the origin) take the value of :data:`HUMERUS_HEAD_SURFACE`; the free muscle facets
    within that reach whose outward normal points towards the centre (the muscles' deep
    faces, which wrap the head) take their muscle's :data:`MUSCLE_HEAD_FACES`; the rest is
    kept. The
    superficial faces of a muscle would otherwise see the head through the muscle.
    """
    import dolfinx

    fdim = mesh.topology.dim - 1
    mesh.topology.create_connectivity(fdim, 0)
    mesh.topology.create_connectivity(fdim + 1, 0)
    idx, vals = facet_tags.indices.copy(), facet_tags.values.copy()
    cand = np.flatnonzero(vals == MARKERS["humerus_surface"].id)
    if len(cand):
        x = dolfinx.mesh.compute_midpoints(mesh, fdim, idx[cand].astype(np.int32))
        vals[cand[np.linalg.norm(x, axis=1) < radius]] = HUMERUS_HEAD_SURFACE.id
    for muscle, face in zip(MUSCLES, MUSCLE_HEAD_FACES, strict=True):
        free = np.flatnonzero(vals == MARKERS[f"{muscle}_surface"].id)
        if len(free):
            x = dolfinx.mesh.compute_midpoints(mesh, fdim, idx[free].astype(np.int32))
            r = np.linalg.norm(x, axis=1)
            n = _outward_normals(mesh, idx[free])
            deep = (r < radius) & (np.einsum("fi,fi->f", n, -x) > _DEEP_COSINE * r)
            vals[free[deep]] = face.id
    tags = dolfinx.mesh.meshtags(mesh, fdim, idx, vals)
    tags.name = facet_tags.name
    return tags


def scapula_surface_tags(mesh, facet_tags, reach: float):
    """Facet tags with the surfaces of muscle-scapula contact re-tagged (collective).

    The ``scapula_surface`` facets whose centroid lies within ``reach`` (m) of the muscles'
    free surfaces take :data:`SCAPULA_CONTACT_SURFACE`; then each muscle's free facets that
    are not over the head (:func:`head_surface_tags` first, if at all), have no node on the
    muscle's origin footprint, lie within ``reach`` of that surface and face it (outward
    normal within acos(_DEEP_COSINE) of the direction to its closest point) take the
    muscle's :data:`MUSCLE_SCAPULA_FACES`. The rest is kept.
    """
    import dolfinx
    from scipy.spatial import cKDTree

    comm, fdim = mesh.comm, mesh.topology.dim - 1
    idx, vals = facet_tags.indices.copy(), facet_tags.values.copy()
    free_ids = [MARKERS[f"{m}_surface"].id for m in MUSCLES] + [f.id for f in MUSCLE_HEAD_FACES]
    muscle = _gathered(comm, _facet_triangles(mesh, idx[np.isin(vals, free_ids)]))
    bone = np.flatnonzero(vals == MARKERS["scapula_surface"].id)
    dist, _ = _closest_within(_facet_triangles(mesh, idx[bone]).mean(axis=1), muscle, reach)
    vals[bone[np.isfinite(dist)]] = SCAPULA_CONTACT_SURFACE.id
    master = _gathered(comm, _facet_triangles(mesh, idx[vals == SCAPULA_CONTACT_SURFACE.id]))
    for name, face in zip(MUSCLES, MUSCLE_SCAPULA_FACES, strict=True):
        foot = _gathered(comm, _facet_triangles(mesh, idx[vals == MARKERS[f"{name}_origin"].id]))
        free = np.flatnonzero(vals == MARKERS[f"{name}_surface"].id)
        tri = _facet_triangles(mesh, idx[free])
        rim = np.zeros(len(free), dtype=bool)
        if len(foot) and len(free):
            d, _ = cKDTree(foot.reshape(-1, 3)).query(tri.reshape(-1, 3))
            rim = (d.reshape(-1, 3) < 1e-9).any(axis=1)
        mid = tri.mean(axis=1)
        dist, q = _closest_within(mid, master, reach)
        n = _outward_normals(mesh, idx[free]) if len(free) else np.zeros((0, 3))
        ok = np.isfinite(dist) & ~rim
        facing = np.einsum("fi,fi->f", n[ok], q[ok] - mid[ok]) > _DEEP_COSINE * dist[ok]
        vals[free[np.flatnonzero(ok)[facing]]] = face.id
    tags = dolfinx.mesh.meshtags(mesh, fdim, idx, vals)
    tags.name = facet_tags.name
    return tags


def build_shoulder_mesh(
    comm: MPI.Comm,
    geometry: ShoulderGeometry,
    sizes: dict,
    variant: str | tuple[str, ...] = "deformable",
    rank: int = 0,
    detach: tuple = (),
    head_layer: bool = False,
    scapula_layer: bool = False,
) -> ShoulderMesh | dict[str, ShoulderMesh]:
    """Build the gmsh model on ``rank`` and return the dolfinx mesh with tags (collective).

    gmsh runs on one rank only, initialised and finalised here (gmsh 4.8 cannot tell whether it is
    initialised); an error there (bad parameters, failed geometry) is broadcast and raised as
    ValueError on every rank.

    Args:
        comm: communicator.
        geometry: parameters (SI).
        sizes: mesh sizes in m (see :func:`build_model`).
        variant: ``"deformable"`` (bone volumes meshed), ``"rigid-bone"``, ``"scapula"`` or
            ``"humerus"``; a tuple of them gives ``{variant: ShoulderMesh}`` from one gmsh mesh
            (node for node the same points on shared surfaces).
        rank: rank that runs gmsh.
        detach: bonded ``(surface, volume)`` pairs cut open in the ``deformable`` variant
            (:func:`model_to_dolfinx`).
        head_layer: ``rigid-bone``: keep the humerus cells under the head's free surface
            (:func:`model_to_dolfinx`).
        scapula_layer: ``rigid-bone``: keep the scapula cells under its free surface near the
            muscles (:func:`model_to_dolfinx`).
    """
    import gmsh

    variants = (variant,) if isinstance(variant, str) else tuple(variant)
    for v in variants:
        if v not in VARIANTS:
            raise ValueError(f"variant = {v!r}: expected one of {VARIANTS}")
    error, info = None, None
    if comm.rank == rank:
        try:
            geometry.validate()
            check_sizes(sizes)
        except ValueError as err:
            error = str(err)
    error = comm.bcast(error, root=rank)
    if error is not None:
        raise ValueError(error)
    initialised_here = False
    if comm.rank == rank:
        try:
            gmsh.initialize()
            initialised_here = True
            gmsh.option.setNumber("General.Terminal", 0)
            gmsh.clear()
            info = build_model(geometry, sizes)
        except ValueError as err:
            error = str(err)
        except Exception as err:  # noqa: BLE001 - any gmsh failure becomes a ValueError
            logger.debug("shoulder geometry failed", exc_info=True)
            error = f"shoulder geometry failed: {err}"
    error = comm.bcast(error, root=rank)
    if error is not None:
        if comm.rank == rank and initialised_here:
            gmsh.finalize()
        raise ValueError(error)
    try:
        built = {
            v: model_to_dolfinx(comm, info, v, rank, detach, head_layer, scapula_layer)
            for v in variants
        }
        summary = None
        if comm.rank == rank:
            summary = {
                "build_s": info["build_s"],
                "geometry_s": info["geometry_s"],
                "meshing_s": info["meshing_s"],
                "gmsh_entities": {
                    "volumes": {k: len(v) for k, v in info["volumes"].items()},
                    "surfaces": {k: len(v) for k, v in info["surfaces"].items()},
                },
            }
        summary = comm.bcast(summary, root=rank)
    finally:
        if comm.rank == rank:
            gmsh.clear()
            if initialised_here:
                gmsh.finalize()
    meshes = {v: ShoulderMesh(*parts, dict(summary)) for v, parts in built.items()}
    return meshes[variant] if isinstance(variant, str) else meshes


def geometry_from_values(values: dict) -> ShoulderGeometry:
    """A :class:`ShoulderGeometry` from scene values (SI; keys that are no field are ignored)."""
    known = {f.name for f in fields(ShoulderGeometry)}
    return ShoulderGeometry(**{k: v for k, v in values.items() if k in known})


def geometry_dict(g: ShoulderGeometry) -> dict:
    """The parameters as a plain dict (SI)."""
    return asdict(g)
