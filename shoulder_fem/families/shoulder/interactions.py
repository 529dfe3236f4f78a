"""How the shoulder's bodies act on each other: materials, contact, springs and plates.

The soft tissues' finite-strain forms (neo-Hookean cartilage, Veronda-Westmann muscle), the
bones' modulus field from the density image, the glenohumeral (and optional muscle-bone)
penalty contact, and the flexible elements that hang the scapula and the humerus: linear
springs from the centre of a bone patch to the ground, acting on a small rigid plate tied to
the patch (a spring on one node would be a point load), so the same spring model serves a
deformable bone (coupled; decoupled part 2) and a rigid one (decoupled part 1).
"""

from __future__ import annotations

import dolfinx
import numpy as np
import ufl
from petsc4py import PETSc

from shoulder_fem.engine.contact import Contact, ContactPair, MeshSurface
from shoulder_fem.engine.mean_dilatation import MeanDilatation
from shoulder_fem.engine.rigid_system import RigidBody, Tie
from shoulder_fem.engine.springs import GROUND, Spring
from shoulder_fem.families.shoulder.geometry import marker_names, surface_centroid, unit
from shoulder_fem.families.shoulder.model import ShoulderParameters
from shoulder_fem.forms import materials
from shoulder_fem.forms import virtual_power as vp
from shoulder_fem.forms.kinematics import deformation_gradient
from shoulder_fem.io import ct
from shoulder_fem.meshes import shoulder as S

__all__ = [
    "AP_DIRECTION",
    "DISTAL_DIRECTION",
    "DISTAL_SECTION",
    "HORIZONTAL_DIRECTIONS",
    "MESH_INTEGRATION",
    "MUSCLE_BONE_PAIRS",
    "ROW_DIRECTIONS",
    "bone_fields",
    "cauchy_stress",
    "joint_contact",
    "modulus_factors",
    "muscle_forms",
    "soft_tissue_laws",
    "soft_tissue_residual",
    "spring_layout",
    "spring_plates",
    "surfaces",
]

#: Directions (scapular frame: x lateral, y anterior, z superior; normalised) of the flexible
#: elements from their patch to the ground, per row of the 5 x 4 grid of patches on both faces
#: of the medial blade (rows at z = -45 ... 27 mm), after the fibres they stand for: lower
#: trapezius (to T12: inferior), rhomboid major (x 2 rows) and middle trapezius (to the spinous
#: processes: posterior, the rhomboids also superior), upper trapezius (to the occiput:
#: superior). The rows' different directions make the elements' lines of action non-coplanar:
#: with one direction for all of them, every rotation about an axis in their common plane
#: was held by the antero-posterior element alone (a 6 x 6 stiffness eigenvalue of 5e-3 N m/rad;
#: test_shoulder checks the springs' 6 x 6 stiffness).
ROW_DIRECTIONS = (
    (-1.0, -0.3, -0.9),
    (-1.0, -0.7, 0.5),
    (-1.0, -0.7, 0.35),
    (-1.0, -0.9, 0.0),
    (-0.5, -0.3, 1.0),
)
#: The antero-posterior element (the thorax behind the blade): anterior.
AP_DIRECTION = (0.0, 1.0, 0.0)
#: The humerus's distal elements: vertical, downwards (they prevent abduction).
DISTAL_DIRECTION = (0.0, 0.0, -1.0)
#: The horizontal distal elements (``humerus_horizontal_stiffness``, our addition): lateral and
#: anterior; together they hold the distal humerus against a horizontal swing. They act at the
#: centroid of the distal section, which lies on the shaft axis: a twist about the shaft does
#: not stretch them (on a spring patch, off the axis, they held the twist as well).
HORIZONTAL_DIRECTIONS = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0))
#: The distal section of the humerus (its cut face, with the vertical elements' patches): the
#: humerus's elements act on it, and the coupled method ties one rigid plate to all of it
#: (a potting fixture).
DISTAL_SECTION = "humerus_distal_section"
#: Contact integration against the mesh masters (:class:`shoulder_fem.contact.Contact`): the
#: segments rule; point-wise integration stalled at 6 deg at coarse (README).
MESH_INTEGRATION = "segments"


# ---- the flexible elements ------------------------------------------------------------------


def spring_layout(params: ShoulderParameters) -> list[dict]:
    """Every flexible element: name, patch, plate, bone, direction and stiffness (N/m).

    ``patch``: the surface (a marker or a set of :data:`meshes.shoulder.SURFACE_SETS`) at whose
    centroid the element acts; ``plate``: the surface that the coupled method ties to the
    element's rigid plate (the scapula's elements: their patch; the humerus's: the whole distal
    section, one plate for its 4 + 2 elements).
    """
    out = []
    for i in range(20):
        d = ROW_DIRECTIONS[i % 5]  # rows at z = -45, -27, -9, 9, 27 mm
        out.append(
            {
                "name": f"scapula_spring_{i + 1:02d}",
                "bone": "scapula",
                "direction": unit(d),
                "stiffness": params.scapula_spring_stiffness,
            }
        )
    out.append(
        {
            "name": "scapula_ap_spring",
            "bone": "scapula",
            "direction": unit(AP_DIRECTION),
            "stiffness": params.ap_spring_stiffness,
        }
    )
    for i in range(4):
        out.append(
            {
                "name": f"humerus_distal_spring_{i + 1}",
                "bone": "humerus",
                "direction": unit(DISTAL_DIRECTION),
                "stiffness": params.humerus_spring_stiffness,
            }
        )
    if params.humerus_horizontal_stiffness > 0:
        for i, d in enumerate(HORIZONTAL_DIRECTIONS):
            out.append(
                {
                    "name": f"humerus_horizontal_spring_{i + 1}",
                    "patch": DISTAL_SECTION,
                    "bone": "humerus",
                    "direction": unit(d),
                    "stiffness": params.humerus_horizontal_stiffness,
                }
            )
    for sp in out:
        sp.setdefault("patch", sp["name"])
        sp["plate"] = DISTAL_SECTION if sp["bone"] == "humerus" else sp["patch"]
    return out


def spring_plates(
    mesh, facet_tags, springs: list[dict], length: float
) -> tuple[list[RigidBody], list[Tie], list[Spring]]:
    """Rigid plates tied to the springs' plate surfaces (one per plate), and their springs.

    Each spring runs from its patch's centroid, on its plate, to the ground, ``length`` (m)
    along its direction. Returns (bodies, ties, springs).
    """
    bodies, ties, out, centres = [], [], [], {}

    def centre(surface: str) -> np.ndarray:  # a scapular patch is its own plate: once each
        if surface not in centres:
            centres[surface] = surface_centroid(mesh, facet_tags, surface)
        return centres[surface]

    for sp in springs:
        plate = sp["plate"]
        if plate not in (b.name for b in bodies):
            bodies.append(RigidBody(plate, centre(plate)))
            ties += [Tie(plate, m) for m in marker_names(plate)]
        c = centre(sp["patch"])
        out.append(
            Spring(sp["name"], plate, c, GROUND, c + length * sp["direction"], sp["stiffness"])
        )
    return bodies, ties, out


def surfaces(facet_tags, names) -> dict:
    """``{marker name: (facet_tags, marker id)}``: the tied surfaces of a rigid system."""
    return {n: (facet_tags, S.MARKERS[n].id) for n in names}


# ---- contact --------------------------------------------------------------------------------


#: The muscle-bone contact pairs, by bone: (pair name, the muscles' faces (slave: per muscle,
#: the tags of its faces), the bone's master surface). The scapula's pair looks at each
#: muscle's deep faces over the head as well as its faces over the scapula: the subscapularis's
#: face over the head also lies over the glenoid's anterior neck, which it crossed (0.86 mm at
#: 60 deg, coarse) while only the head's pair looked at it.
MUSCLE_BONE_PAIRS = {
    "humerus": (
        "muscle_humerus",
        tuple((h,) for h in S.MUSCLE_HEAD_FACES),
        S.HUMERUS_HEAD_SURFACE,
    ),
    "scapula": (
        "muscle_scapula",
        tuple(zip(S.MUSCLE_SCAPULA_FACES, S.MUSCLE_HEAD_FACES, strict=True)),
        S.SCAPULA_CONTACT_SURFACE,
    ),
}


def joint_contact(V, u, facet_tags, params: ShoulderParameters) -> Contact:
    """Glenohumeral contact; muscle-bone contact of the rotator cuff on the bones.

    The two articular surfaces are in large-sliding, frictionless penalty contact (the glenoid
    surface is the slave: its pressure is the paper's Fig. 2). With ``muscle_contact`` =
    ``humeral-head`` the muscles' deep faces slide on the humerus's free surface around the
    head (pair ``muscle_humerus``); with ``bones`` also on the scapula's free surface near them
    (``muscle_scapula``: their faces over the scapula and those over the head), with the same
    penalty, depth and smoothing. Each muscle's faces
    have their own tag (the forces per muscle: ``Contact.resultants(by_tag=True)``); a muscle that
    has no face over a bone on this mesh is left out of that pair.
    """
    pairs = [
        ContactPair(
            "glenohumeral",
            slave=(S.MARKERS["glenoid_articular"].id,),
            master=MeshSurface((S.MARKERS["humeral_articular"].id,)),
            penalty=params.contact_penalty,
            curved=params.contact_surfaces == "curved",
        )
    ]
    bones = {"humerus": params.humeral_head_contact, "scapula": params.scapula_contact}
    present = set().union(*V.mesh.comm.allgather(set(np.unique(facet_tags.values).tolist())))
    for bone, on in bones.items():
        name, faces, master = MUSCLE_BONE_PAIRS[bone]
        slave = tuple(f.id for muscle in faces for f in muscle if f.id in present)
        if on and slave:
            pairs.append(
                ContactPair(
                    name,
                    slave=slave,
                    master=MeshSurface((master.id,)),
                    penalty=params.muscle_contact_penalty,
                    search_depth=params.muscle_contact_depth,
                    smoothing=params.muscle_contact_smoothing,
                    curved=params.muscle_contact_surfaces == "curved",
                )
            )
    return Contact(
        V,
        u,
        facet_tags,
        pairs,
        quadrature_degree=params.contact_quadrature,
        slave_integration="element",
        mesh_integration=MESH_INTEGRATION,
    )


# ---- materials and forms --------------------------------------------------------------------


def soft_tissue_laws(params: ShoulderParameters, mesh: dolfinx.mesh.Mesh) -> tuple:
    """(cartilage law, muscle law) of ``soft_tissue_formulation``, nearly incompressible.

    The constants are the scene's (``cartilage_c10``, ``muscle_alpha``, ``muscle_beta``; Table
    I by default), each a :class:`dolfinx.fem.Constant` on ``mesh``, so that other values
    compile no form. An incompressible body's law (Table I) has kappa =
    ``soft_tissue_bulk_ratio`` x its shear modulus (the volumetric part goes to
    :class:`~shoulder_fem.engine.mean_dilatation.MeanDilatation`); a compressible one is the
    earlier model's: the cartilage's nu = 0.4, the muscle's 0.49. ``incompressible`` makes both
    incompressible, ``incompressible-cartilage`` the cartilages only, ``compressible`` neither.
    """
    c10, alpha, beta = params.cartilage_c10, params.muscle_alpha, params.muscle_beta
    ratio = params.soft_tissue_bulk_ratio
    if params.incompressible_cartilage:
        kappa_c = ratio * 2 * c10
    else:  # nu = 0.4 kept: E/(3 (1 - 2 nu)) at E = 10 MPa, scaled with C10
        nu = materials.CARTILAGE_NU
        kappa_c = materials.CARTILAGE_YOUNGS_MODULUS / (3 * (1 - 2 * nu))
        kappa_c *= c10 / materials.CARTILAGE_C10
    mu = alpha * beta
    if params.incompressible_muscles:
        kappa_m = ratio * mu
    else:
        nu = materials.MUSCLE_NU
        kappa_m = 2 * mu * (1 + nu) / (3 * (1 - 2 * nu))

    def constant(value: float) -> dolfinx.fem.Constant:
        return dolfinx.fem.Constant(mesh, PETSc.ScalarType(value))

    cart = materials.NeoHookean(constant(c10), constant(kappa_c))
    musc = materials.VerondaWestmann(constant(alpha), constant(beta), constant(kappa_m))
    return cart, musc


def value_of(x) -> float:
    """The number a law's constant holds (a :class:`dolfinx.fem.Constant` or a number)."""
    return float(x.value) if isinstance(x, dolfinx.fem.Constant) else float(x)


def mixed_law(law, params: ShoulderParameters) -> materials.Isochoric:
    """The pointwise part of an incompressible body's law (its volume kept elsewhere).

    Its isochoric energy and the stabilisation of ``soft_tissue_pointwise_bulk_ratio`` x its
    shear modulus (:class:`~forms.materials.Isochoric`).
    """
    ratio = params.soft_tissue_pointwise_bulk_ratio
    if not ratio:
        return materials.Isochoric(law)
    return materials.Isochoric(law, ratio * law.small_strain_moduli()[0])


def soft_tissue_residual(
    u, w, dx, cell_tags, params: ShoulderParameters
) -> tuple[ufl.Form, MeanDilatation | None]:
    """Internal virtual power of the cartilages and the muscles (finite strain).

    Returns:
        The form and, when a soft body is incompressible (``soft_tissue_formulation``), the
        mean-dilatation terms of those bodies (P2/P0: their residual is in the form; the solver
        adds their tangent), else ``None`` (pure P2 displacement).
    """
    cart, musc = soft_tissue_laws(params, u.function_space.mesh)
    cartilages = [(S.HUMERAL_CARTILAGE, cart), (S.GLENOID_CARTILAGE, cart)]
    muscles = [(m, musc) for m in (S.SUBSCAPULARIS, S.SUPRASPINATUS, S.INFRASPINATUS)]
    mixed = (cartilages if params.incompressible_cartilage else []) + (
        muscles if params.incompressible_muscles else []
    )
    plain = [b for b in cartilages + muscles if b not in mixed]
    F = sum(vp.internal_power_finite(law, u, w, dx(b.id)) for b, law in plain)
    if not mixed:
        return F, None
    volumetric = MeanDilatation(
        u,
        cell_tags,
        {b.id: value_of(law.bulk_modulus) for b, law in mixed},
        dx,
        form_compiler_params=params.quadrature(),
        pressure=params.soft_tissue_pressure,
    )
    F += sum(vp.internal_power_finite(mixed_law(law, params), u, w, dx(b.id)) for b, law in mixed)
    return F + volumetric.residual(w), volumetric


def uncondensed(params: ShoulderParameters, volumetric) -> bool:
    """Whether the Newton steps take the bordered LU (``soft_tissue_linear_solve``).

    Only for condensed P1 pressures (P0's terms lie within each cell's own couplings).
    """
    if volumetric is None or volumetric.cell_local:
        return False
    return params.soft_tissue_linear_solve == "uncondensed"


def muscle_forms(u, w, dx, params: ShoulderParameters, volumetric=None) -> dict:
    """Each muscle's internal virtual power, compiled, by muscle name.

    With incompressible muscles the muscle's mean-dilatation part is in ``volumetric``
    (:func:`soft_tissue_residual`'s): call ``volumetric.update()`` before assembling.
    """
    _, musc = soft_tissue_laws(params, u.function_space.mesh)
    out = {}
    for m in (S.SUBSCAPULARIS, S.SUPRASPINATUS, S.INFRASPINATUS):
        if not params.incompressible_muscles:
            form = vp.internal_power_finite(musc, u, w, dx(m.id))
        else:
            form = vp.internal_power_finite(mixed_law(musc, params), u, w, dx(m.id))
            form += volumetric.residual(w, (m.id,))
        out[m.name] = dolfinx.fem.form(form, form_compiler_params=params.quadrature())
    return out


def modulus_factors(params: ShoulderParameters) -> dict[str, float]:
    """The factor on each bone's E = E0 (rho/rho0)^2 (1 = the paper's Table I), by bone."""
    return {"scapula": params.scapula_modulus_factor, "humerus": params.humerus_modulus_factor}


def bone_fields(
    mesh, cell_tags, image, params: ShoulderParameters
) -> tuple[dolfinx.fem.Function, ufl.core.expr.Expr]:
    """(density kg/m^3 as a P1 field, E Pa as a UFL field) of the bones.

    Both sampled from the image at the mesh nodes (E = E0 (rho/rho0)^2); E times each bone's
    modulus factor (:func:`modulus_factors`). The factor is a cell-wise (DG0) field, 1 outside
    the bones, so that it is exact on each bone's cells whatever the partition (a node-wise
    factor would need the bone's cells on the node's owner).
    """
    rho, E = ct.nodal_modulus(mesh, image, params.calibration())
    factor = dolfinx.fem.Function(dolfinx.fem.FunctionSpace(mesh, ("DG", 0)), name="modulus_factor")
    factor.x.array[:] = 1.0
    for body, value in modulus_factors(params).items():
        factor.x.array[cell_tags.find(S.MARKERS[body].id)] = float(value)
    return rho, factor * E


def cauchy_stress(bone, u) -> ufl.core.expr.Expr:
    """Cauchy stress (Pa) of a finite-strain material law ``bone`` at displacement ``u``."""
    Fg = deformation_gradient(u)
    return bone.first_piola(Fg) * Fg.T / ufl.det(Fg)
