"""Tetrahedral meshes of the bodies of the contact verifications (gmsh OpenCASCADE).

Three builders:

* :func:`build_hemisphere`: the lower half of a ball of radius R centred at (0, 0, R), whose pole
  touches the plane z = 0 at the origin (Hertz sphere on a rigid flat; ball in a rigid concave
  socket), optionally cut to the quarter x >= 0, y >= 0 with its two symmetry planes, refined
  around the pole.
* :func:`build_ball_on_block`: the same (quarter) half ball resting on a separate block below
  z = 0, the two meshed independently (no shared node) with one size field refined around the
  pole (Hertz sphere on a deformable flat).
* :func:`build_two_blocks`: two boxes stacked along z, meshed independently (no shared node even
  when they touch) with different sizes, so that their interface meshes do not match (contact
  patch test, block dragged over a flat, contact benchmark).

gmsh runs on rank 0 of the communicator only; the mesh is then distributed by
``dolfinx.io.gmshio.model_to_mesh``. The elements are first-order (affine) tetrahedra. Every length
in the interface is in metres; internally the gmsh model is built in units of a reference length
(the radius, or the largest block dimension) so that the absolute tolerances of OpenCASCADE are
relative ones, and the dolfinx coordinates are scaled back to metres. Nodes that lie on a flat face
are then snapped onto its plane exactly (OpenCASCADE leaves them within ~1e-16 of it), so that
symmetry planes and block faces are exact.

Meshing is deterministic: one gmsh thread, fixed random seed, no configuration files read, every
option that matters set explicitly. When gmsh is already initialised by the caller, the builders
work in their own temporary model, leave the caller's current model current and restore the
options they changed; otherwise they initialise and finalise gmsh themselves.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import dolfinx
import numpy as np
from mpi4py import MPI

from .markers import Marker

# --- hemisphere -----------------------------------------------------------------------------
BALL = Marker("ball", 1, 3)
CONTACT = Marker("contact", 1, 2)  # the whole curved (spherical) surface
TOP = Marker("top", 2, 2)  # flat face z = R
SYM_X = Marker("sym_x", 3, 2)  # symmetry plane x = 0 (quarter only)
SYM_Y = Marker("sym_y", 4, 2)  # symmetry plane y = 0 (quarter only)
HEMISPHERE_MARKERS: dict[str, Marker] = {m.name: m for m in (BALL, CONTACT, TOP, SYM_X, SYM_Y)}

# --- ball on block (the hemisphere's markers, and the block's) ----------------------------------
BLOCK = Marker("block", 2, 3)
BLOCK_TOP = Marker("block_top", 11, 2)  # z = 0, the face the ball rests on
BLOCK_BOTTOM = Marker("block_bottom", 12, 2)  # z = -depth
BLOCK_SYM_X = Marker("block_sym_x", 13, 2)  # x = 0 (symmetry plane with quarter)
BLOCK_SYM_Y = Marker("block_sym_y", 14, 2)  # y = 0 (symmetry plane with quarter)
BLOCK_XMAX = Marker("block_xmax", 15, 2)  # x = w (far lateral face)
BLOCK_YMAX = Marker("block_ymax", 16, 2)  # y = w (far lateral face)
BLOCK_XMIN = Marker("block_xmin", 17, 2)  # x = -w (full model only)
BLOCK_YMIN = Marker("block_ymin", 18, 2)  # y = -w (full model only)
BALL_ON_BLOCK_MARKERS: dict[str, Marker] = {
    **HEMISPHERE_MARKERS,
    **{
        m.name: m
        for m in (
            BLOCK,
            BLOCK_TOP,
            BLOCK_BOTTOM,
            BLOCK_SYM_X,
            BLOCK_SYM_Y,
            BLOCK_XMAX,
            BLOCK_YMAX,
            BLOCK_XMIN,
            BLOCK_YMIN,
        )
    },
}

# --- two blocks -----------------------------------------------------------------------------
LOWER = Marker("lower", 1, 3)
UPPER = Marker("upper", 2, 3)
LOWER_BOTTOM = Marker("lower_bottom", 11, 2)  # z = -lz
LOWER_TOP = Marker("lower_top", 12, 2)  # z = 0
LOWER_XMIN = Marker("lower_xmin", 13, 2)
LOWER_XMAX = Marker("lower_xmax", 14, 2)
LOWER_YMIN = Marker("lower_ymin", 15, 2)
LOWER_YMAX = Marker("lower_ymax", 16, 2)
UPPER_BOTTOM = Marker("upper_bottom", 21, 2)  # z = gap
UPPER_TOP = Marker("upper_top", 22, 2)  # z = gap + uz
UPPER_XMIN = Marker("upper_xmin", 23, 2)
UPPER_XMAX = Marker("upper_xmax", 24, 2)
UPPER_YMIN = Marker("upper_ymin", 25, 2)
UPPER_YMAX = Marker("upper_ymax", 26, 2)
TWO_BLOCKS_MARKERS: dict[str, Marker] = {
    m.name: m
    for m in (
        LOWER,
        UPPER,
        LOWER_BOTTOM,
        LOWER_TOP,
        LOWER_XMIN,
        LOWER_XMAX,
        LOWER_YMIN,
        LOWER_YMAX,
        UPPER_BOTTOM,
        UPPER_TOP,
        UPPER_XMIN,
        UPPER_XMAX,
        UPPER_YMIN,
        UPPER_YMAX,
    )
}

#: Ratio of the size requested inside the volume to the size requested on the surfaces.
VOLUME_SIZE_FACTOR = 0.75

#: Default growth rate of the mesh size away from the refined pole region (size per distance).
DEFAULT_GRADING = 0.3

_SNAP = 1e-9  # snapping tolerance, relative to the reference length


def build_hemisphere(
    comm: MPI.Comm,
    radius: float,
    h_contact: float,
    h_far: float,
    refine_radius: float,
    quarter: bool = True,
    *,
    grading: float = DEFAULT_GRADING,
) -> tuple[dolfinx.mesh.Mesh, dolfinx.mesh.MeshTags, dolfinx.mesh.MeshTags]:
    """Lower half of a ball resting on its pole, refined around the pole (collective).

    The body is {|x - (0, 0, R)| <= R, z <= R} (with ``quarter``: also x >= 0, y >= 0). The mesh
    size is ``h_contact`` within ``refine_radius`` of the pole (0, 0, 0) and grows linearly with
    the distance d to the pole, at ``grading`` metres of size per metre of distance, up to
    ``h_far`` (a gmsh Threshold field on the exact distance to the pole), reached at
    d = refine_radius + (h_far - h_contact) / grading.

    Args:
        comm: Communicator the mesh is distributed on.
        radius: Radius R of the ball (m).
        h_contact: Mesh size near the pole (m).
        h_far: Mesh size far from the pole (m), >= ``h_contact``.
        refine_radius: Radius of the region around the pole meshed at ``h_contact`` (m).
        quarter: Keep only the quarter x >= 0, y >= 0 (symmetry planes x = 0 and y = 0).
        grading: Growth rate of the size away from the refined region (dimensionless, > 0).

    Returns:
        ``(mesh, cell_tags, facet_tags)``: cells :data:`BALL`; facets :data:`CONTACT` (the whole
        spherical surface), :data:`TOP` (z = R), and with ``quarter`` :data:`SYM_X` (x = 0) and
        :data:`SYM_Y` (y = 0).

    Raises:
        ValueError: on every rank, for invalid parameters or a gmsh failure.
    """
    if not (radius > 0 and 0 < h_contact <= h_far and refine_radius >= 0 and grading > 0):
        raise ValueError(
            f"hemisphere: radius = {radius} m, h_contact = {h_contact} m, h_far = {h_far} m, "
            f"refine_radius = {refine_radius} m, grading = {grading} invalid "
            "(need radius > 0, 0 < h_contact <= h_far, refine_radius >= 0, grading > 0)"
        )
    scale = float(radius)

    def build(gmsh) -> None:
        volume = _half_ball(gmsh, quarter)
        _pole_size_field(gmsh, [volume], scale, h_contact, h_far, refine_radius, grading)
        _mesh_options(gmsh, h_max=h_far / scale)
        gmsh.model.mesh.generate(3)

    planes = [(2, radius)]
    if quarter:
        planes += [(0, 0.0), (1, 0.0)]
    return _gmsh_to_dolfinx(comm, "contact_bodies_hemisphere", build, scale, planes)


def build_ball_on_block(
    comm: MPI.Comm,
    radius: float,
    block_half_width: float,
    block_depth: float,
    h_contact: float,
    h_far: float,
    refine_radius: float,
    quarter: bool = True,
    *,
    grading: float = DEFAULT_GRADING,
) -> tuple[dolfinx.mesh.Mesh, dolfinx.mesh.MeshTags, dolfinx.mesh.MeshTags]:
    """The half ball of :func:`build_hemisphere` resting on a block, meshed independently.

    The ball is that of :func:`build_hemisphere` (its pole touches z = 0 at the origin); the
    block is [0, w] x [0, w] x [-depth, 0] with ``quarter`` ([-w, w] x [-w, w] x [-depth, 0]
    without), w = ``block_half_width``. The two are separate OpenCASCADE volumes (not
    fragmented): they share no node (the ball's pole and the block's corner or top face are
    distinct nodes at the same place) and their meshes of the contact region do not match. One
    size field, that of :func:`build_hemisphere` (the distance to the pole), sizes both bodies:
    ``h_contact`` within ``refine_radius`` of the origin, growing at ``grading`` up to
    ``h_far``.

    Args:
        comm: Communicator the mesh is distributed on.
        radius: Radius R of the ball (m).
        block_half_width: Half-width w of the block (m): its extent in x and y from the axis.
        block_depth: Depth of the block below z = 0 (m).
        h_contact: Mesh size near the pole (m).
        h_far: Mesh size far from the pole (m), >= ``h_contact``.
        refine_radius: Radius of the region around the pole meshed at ``h_contact`` (m).
        quarter: Keep only the quarter x >= 0, y >= 0 of both bodies.
        grading: Growth rate of the size away from the refined region (dimensionless, > 0).

    Returns:
        ``(mesh, cell_tags, facet_tags)``: cells :data:`BALL` and :data:`BLOCK`; the ball's
        facets as in :func:`build_hemisphere` (:data:`CONTACT`, :data:`TOP`, :data:`SYM_X`,
        :data:`SYM_Y`); the block's :data:`BLOCK_TOP` (z = 0), :data:`BLOCK_BOTTOM`
        (z = -depth), :data:`BLOCK_XMAX` (x = w), :data:`BLOCK_YMAX` (y = w), and with
        ``quarter`` :data:`BLOCK_SYM_X` (x = 0) and :data:`BLOCK_SYM_Y` (y = 0), without
        :data:`BLOCK_XMIN` (x = -w) and :data:`BLOCK_YMIN` (y = -w).

    Raises:
        ValueError: on every rank, for invalid parameters or a gmsh failure.
    """
    if not (
        radius > 0
        and block_half_width > 0
        and block_depth > 0
        and 0 < h_contact <= h_far
        and refine_radius >= 0
        and grading > 0
    ):
        raise ValueError(
            f"ball on block: radius = {radius} m, block_half_width = {block_half_width} m, "
            f"block_depth = {block_depth} m, h_contact = {h_contact} m, h_far = {h_far} m, "
            f"refine_radius = {refine_radius} m, grading = {grading} invalid (need radius, "
            "block_half_width, block_depth > 0, 0 < h_contact <= h_far, refine_radius >= 0, "
            "grading > 0)"
        )
    w, depth = float(block_half_width), float(block_depth)
    scale = float(radius)  # model units: lengths / radius (the ball's geometry is unchanged)
    x0 = 0.0 if quarter else -w
    # per axis: the marker of the face at the low and at the high end of the block
    sides = (
        (BLOCK_SYM_X if quarter else BLOCK_XMIN, BLOCK_XMAX),
        (BLOCK_SYM_Y if quarter else BLOCK_YMIN, BLOCK_YMAX),
        (BLOCK_BOTTOM, BLOCK_TOP),
    )

    def build(gmsh) -> None:
        ball = _half_ball(gmsh, quarter)
        lo = np.array([x0, x0, -depth]) / scale
        hi = np.array([w, w, 0.0]) / scale
        block = gmsh.model.occ.addBox(*lo, *(hi - lo))
        gmsh.model.occ.synchronize()  # no fragment: the two volumes stay independent
        _physical(gmsh, 3, [block], BLOCK)
        _, surfaces = gmsh.model.getAdjacencies(3, block)
        tol = 1e-6 * min(w, depth) / scale
        groups: dict[Marker, list[int]] = {}
        for face in surfaces:
            box = np.asarray(gmsh.model.getBoundingBox(2, face))  # enlarged by OCC
            axis = int(np.argmin(box[3:] - box[:3]))  # the face's normal
            centre = gmsh.model.occ.getCenterOfMass(2, face)[axis]
            side = int(abs(centre - hi[axis]) < tol)
            if abs(centre - (hi if side else lo)[axis]) > tol:
                raise RuntimeError(f"face {face} of the block is on no box plane")
            groups.setdefault(sides[axis][side], []).append(int(face))
        if sorted(len(v) for v in groups.values()) != [1] * 6:
            raise RuntimeError(f"block faces per marker {groups}, expected one each")
        for marker in (m for pair in sides for m in pair):
            _physical(gmsh, 2, groups[marker], marker)
        _pole_size_field(gmsh, [ball, block], scale, h_contact, h_far, refine_radius, grading)
        _mesh_options(gmsh, h_max=h_far / scale)
        gmsh.model.mesh.generate(3)

    # with quarter, x0 = 0: the block's and the ball's symmetry planes
    planes = [(2, radius), (0, x0), (0, w), (1, x0), (1, w), (2, -depth), (2, 0.0)]
    return _gmsh_to_dolfinx(comm, "contact_bodies_ball_on_block", build, scale, planes)


def _half_ball(gmsh, quarter: bool) -> int:
    """Make the (quarter) lower half ball of radius 1 in the current model; return its volume.

    With its physical groups :data:`BALL`, :data:`CONTACT`, :data:`TOP`, :data:`SYM_X`,
    :data:`SYM_Y`.
    """
    occ = gmsh.model.occ
    r = 1.0  # model units: lengths / radius
    ball = occ.addSphere(0.0, 0.0, r, r)
    if quarter:
        # the sphere's parametric pole is the contact pole, a vertex of the quarter's face
        box = occ.addBox(0.0, 0.0, 0.0, 2 * r, 2 * r, r)
    else:
        # turn the sphere about its centre so that its parametric poles (singular points of
        # the surface mesher) and its seam lie far from the contact pole: the lower one at
        # (sin 60°, 0, -cos 60°) R from the centre, at distance R from the contact pole
        occ.rotate([(3, ball)], 0.0, 0.0, r, 0.0, 1.0, 0.0, -math.pi / 3)
        box = occ.addBox(-2 * r, -2 * r, 0.0, 4 * r, 4 * r, r)
    volumes, _ = occ.intersect([(3, ball)], [(3, box)])
    occ.synchronize()
    if len(volumes) != 1:
        raise RuntimeError(f"expected one volume after the intersection, got {volumes}")
    volume = volumes[0][1]
    own = set(gmsh.model.getAdjacencies(3, volume)[1].tolist())
    tol = 1e-6
    groups: dict[int, list[int]] = {m.id: [] for m in (CONTACT, TOP, SYM_X, SYM_Y)}
    for _, face in gmsh.model.getEntities(2):
        if face not in own:
            continue
        kind = gmsh.model.getType(2, face)
        cx, cy, cz = occ.getCenterOfMass(2, face)
        if kind == "Sphere":
            groups[CONTACT.id].append(face)
        elif kind == "Plane" and abs(cz - r) < tol:
            groups[TOP.id].append(face)
        elif kind == "Plane" and abs(cx) < tol:
            groups[SYM_X.id].append(face)
        elif kind == "Plane" and abs(cy) < tol:
            groups[SYM_Y.id].append(face)
        else:
            raise RuntimeError(f"unexpected {kind} face {face}, centre {(cx, cy, cz)}")
    expected = {CONTACT.id: 1, TOP.id: 1, SYM_X.id: int(quarter), SYM_Y.id: int(quarter)}
    found = {k: len(v) for k, v in groups.items()}
    if found != expected:
        raise RuntimeError(f"faces per marker {found}, expected {expected}")
    _physical(gmsh, 3, [volume], BALL)
    for marker in (CONTACT, TOP, SYM_X, SYM_Y):
        if groups[marker.id]:
            _physical(gmsh, 2, groups[marker.id], marker)
    return volume


def _pole_size_field(
    gmsh,
    volumes: list[int],
    scale: float,
    h_contact: float,
    h_far: float,
    refine_radius: float,
    grading: float,
) -> None:
    """Set the background size field refined around the origin (the pole).

    ``h_contact`` within ``refine_radius`` of the origin, growing linearly with the distance at
    ``grading`` up to ``h_far`` (lengths in m, ``scale`` m per model unit); VOLUME_SIZE_FACTOR
    times that inside ``volumes``.
    """
    field = gmsh.model.mesh.field
    distance = field.add("MathEval")  # exact distance to the pole, model units
    field.setString(distance, "F", "Sqrt(x*x + y*y + z*z)")
    d_min = refine_radius / scale
    d_max = (refine_radius + (h_far - h_contact) / grading) / scale

    def threshold(factor: float) -> int:
        tag = field.add("Threshold")
        field.setNumber(tag, "InField", distance)
        field.setNumber(tag, "SizeMin", factor * h_contact / scale)
        field.setNumber(tag, "SizeMax", factor * h_far / scale)
        field.setNumber(tag, "DistMin", d_min)
        field.setNumber(tag, "DistMax", max(d_max, d_min * (1 + 1e-9) + 1e-12))
        return tag

    # gmsh's 3D Delaunay makes interior edges ~1.3 times the requested size; asking the
    # volume for VOLUME_SIZE_FACTOR times the size (curves and surfaces get the size itself)
    # brings the median interior edge back to about the requested size.
    in_volume = field.add("Restrict")
    field.setNumber(in_volume, "InField", threshold(VOLUME_SIZE_FACTOR))
    field.setNumbers(in_volume, "RegionsList", list(volumes))
    both = field.add("Min")
    field.setNumbers(both, "FieldsList", [threshold(1.0), in_volume])
    field.setAsBackgroundMesh(both)


def build_two_blocks(
    comm: MPI.Comm,
    lower: tuple[float, float, float],
    upper: tuple[float, float, float],
    h_lower: float,
    h_upper: float,
    gap: float = 0.0,
    offset: tuple[float, float] = (0.0, 0.0),
) -> tuple[dolfinx.mesh.Mesh, dolfinx.mesh.MeshTags, dolfinx.mesh.MeshTags]:
    """Two boxes meshed independently, the upper one above the lower one (collective).

    The lower box spans [0, lx] x [0, ly] x [-lz, 0], the upper one
    [ox, ox + ux] x [oy, oy + uy] x [gap, gap + uz]. They are two separate OpenCASCADE volumes
    (not fragmented): even when ``gap`` = 0 they share no node, and with ``h_lower`` !=
    ``h_upper`` the two meshes of the interface plane do not match. (With equal sizes and the
    same footprint gmsh may produce coincident, though still distinct, nodes on the interface.)

    Args:
        comm: Communicator the mesh is distributed on.
        lower: Dimensions (lx, ly, lz) of the lower box (m).
        upper: Dimensions (ux, uy, uz) of the upper box (m).
        h_lower: Mesh size of the lower box (m).
        h_upper: Mesh size of the upper box (m).
        gap: Height of the upper box's bottom face above the lower box's top face z = 0 (m);
            may be negative (initial interpenetration).
        offset: In-plane position (ox, oy) of the upper box's corner (m).

    Returns:
        ``(mesh, cell_tags, facet_tags)``: cells :data:`LOWER` / :data:`UPPER`; facets
        :data:`LOWER_BOTTOM`, :data:`LOWER_TOP`, :data:`LOWER_XMIN`, :data:`LOWER_XMAX`,
        :data:`LOWER_YMIN`, :data:`LOWER_YMAX` and their ``UPPER_*`` counterparts
        (every face of both boxes).

    Raises:
        ValueError: on every rank, for invalid parameters or a gmsh failure.
    """
    lx, ly, lz = (float(v) for v in lower)
    ux, uy, uz = (float(v) for v in upper)
    ox, oy = (float(v) for v in offset)
    gap = float(gap)
    if min(lx, ly, lz, ux, uy, uz) <= 0 or h_lower <= 0 or h_upper <= 0:
        raise ValueError(
            f"two blocks: lower = {lower} m, upper = {upper} m, h_lower = {h_lower} m, "
            f"h_upper = {h_upper} m invalid (every dimension and size must be > 0)"
        )
    scale = max(lx, ly, lz, ux, uy, uz)
    boxes = (
        (LOWER, (0.0, 0.0, -lz), (lx, ly, lz), h_lower),
        (UPPER, (ox, oy, gap), (ux, uy, uz), h_upper),
    )
    faces = {
        LOWER.id: (LOWER_XMIN, LOWER_XMAX, LOWER_YMIN, LOWER_YMAX, LOWER_BOTTOM, LOWER_TOP),
        UPPER.id: (UPPER_XMIN, UPPER_XMAX, UPPER_YMIN, UPPER_YMAX, UPPER_BOTTOM, UPPER_TOP),
    }

    def build(gmsh) -> None:
        occ = gmsh.model.occ
        tags = []
        for _, corner, dims, _ in boxes:
            tags.append(occ.addBox(*(c / scale for c in corner), *(d / scale for d in dims)))
        occ.synchronize()  # no fragment: the two volumes stay independent
        sizes = []
        for (marker, corner, dims, h), volume in zip(boxes, tags, strict=True):
            _physical(gmsh, 3, [volume], marker)
            _, surfaces = gmsh.model.getAdjacencies(3, volume)
            lo = np.asarray(corner) / scale
            hi = lo + np.asarray(dims) / scale
            tol = 1e-6 * min(dims) / scale
            for face in surfaces:
                box = np.asarray(gmsh.model.getBoundingBox(2, face))  # enlarged by OCC
                axis = int(np.argmin(box[3:] - box[:3]))  # the face's normal
                centre = gmsh.model.occ.getCenterOfMass(2, face)[axis]
                side = int(abs(centre - hi[axis]) < tol)
                if abs(centre - (hi if side else lo)[axis]) > tol:
                    raise RuntimeError(f"face {face} of {marker.name} is on no box plane")
                _physical(gmsh, 2, [int(face)], faces[marker.id][2 * axis + side])
            # size h on the box's curves and faces, VOLUME_SIZE_FACTOR * h inside (see
            # build_hemisphere); each field is restricted to one box's entities
            curves = gmsh.model.getBoundary([(2, f) for f in surfaces], combined=False)
            on_boundary = _restricted_constant(gmsh, h / scale, "FacesList", list(surfaces))
            gmsh.model.mesh.field.setNumbers(
                on_boundary, "EdgesList", sorted({abs(c) for _, c in curves})
            )
            inside = _restricted_constant(
                gmsh, VOLUME_SIZE_FACTOR * h / scale, "RegionsList", [volume]
            )
            sizes += [on_boundary, inside]
        both = gmsh.model.mesh.field.add("Min")
        gmsh.model.mesh.field.setNumbers(both, "FieldsList", sizes)
        gmsh.model.mesh.field.setAsBackgroundMesh(both)
        _mesh_options(gmsh, h_max=max(h_lower, h_upper) / scale)
        gmsh.model.mesh.generate(3)

    planes = [(0, 0.0), (0, lx), (1, 0.0), (1, ly), (2, -lz), (2, 0.0)]
    planes += [(0, ox), (0, ox + ux), (1, oy), (1, oy + uy), (2, gap), (2, gap + uz)]
    return _gmsh_to_dolfinx(comm, "contact_bodies_two_blocks", build, scale, planes)


# --- gmsh plumbing --------------------------------------------------------------------------


def _physical(gmsh, dim: int, entities: list[int], marker: Marker) -> None:
    gmsh.model.addPhysicalGroup(dim, entities, marker.id)
    gmsh.model.setPhysicalName(dim, marker.id, marker.name)


def _restricted_constant(gmsh, size: float, entity_list: str, entities: list[int]) -> int:
    """A gmsh field equal to ``size`` on the given entities (and 1e22 elsewhere)."""
    field = gmsh.model.mesh.field
    constant = field.add("MathEval")
    field.setString(constant, "F", repr(float(size)))
    tag = field.add("Restrict")
    field.setNumber(tag, "InField", constant)
    field.setNumbers(tag, entity_list, entities)
    return tag


def _mesh_options(gmsh, h_max: float) -> None:
    """Options that make the mesh first-order, sized by the background field only, deterministic."""
    gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 0)
    gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
    gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 0)
    gmsh.option.setNumber("Mesh.MeshSizeMin", 0.0)
    gmsh.option.setNumber("Mesh.MeshSizeMax", h_max)
    gmsh.option.setNumber("Mesh.MeshSizeFactor", 1.0)
    gmsh.option.setNumber("Mesh.Algorithm", 6)  # Frontal-Delaunay
    gmsh.option.setNumber("Mesh.Algorithm3D", 1)  # Delaunay (serial, deterministic)
    gmsh.option.setNumber("Mesh.ElementOrder", 1)
    gmsh.option.setNumber("Mesh.Optimize", 1)
    gmsh.option.setNumber("Mesh.OptimizeNetgen", 0)
    gmsh.option.setNumber("Mesh.RandomSeed", 1)
    gmsh.option.setNumber("Mesh.RandomFactor", 1e-9)
    gmsh.option.setNumber("General.NumThreads", 1)
    gmsh.option.setNumber("Mesh.MaxNumThreads1D", 1)
    gmsh.option.setNumber("Mesh.MaxNumThreads2D", 1)
    gmsh.option.setNumber("Mesh.MaxNumThreads3D", 1)


#: Every option the builders set (saved and restored when the caller owns the gmsh session).
_OPTIONS = (
    "General.Terminal",
    "General.NumThreads",
    "Mesh.MeshSizeFromPoints",
    "Mesh.MeshSizeFromCurvature",
    "Mesh.MeshSizeExtendFromBoundary",
    "Mesh.MeshSizeMin",
    "Mesh.MeshSizeMax",
    "Mesh.MeshSizeFactor",
    "Mesh.Algorithm",
    "Mesh.Algorithm3D",
    "Mesh.ElementOrder",
    "Mesh.Optimize",
    "Mesh.OptimizeNetgen",
    "Mesh.RandomSeed",
    "Mesh.RandomFactor",
    "Mesh.MaxNumThreads1D",
    "Mesh.MaxNumThreads2D",
    "Mesh.MaxNumThreads3D",
)


def _gmsh_initialized(gmsh) -> bool:
    """Whether the gmsh API is initialised (gmsh 4.8 has no ``isInitialized``)."""
    if hasattr(gmsh, "isInitialized"):
        return bool(gmsh.isInitialized())
    try:  # an initialised gmsh always has a current model (the default one is named "")
        return len(gmsh.model.list()) > 0
    except Exception:  # noqa: BLE001 - "not initialised" after a finalize
        return False


def _gmsh_to_dolfinx(
    comm: MPI.Comm,
    name: str,
    build: Callable,
    scale: float,
    planes: list[tuple[int, float]],
) -> tuple[dolfinx.mesh.Mesh, dolfinx.mesh.MeshTags, dolfinx.mesh.MeshTags]:
    """Run ``build(gmsh)`` on rank 0 and return the distributed mesh in metres (collective).

    Args:
        comm: Communicator.
        name: gmsh model name.
        build: Makes the geometry, physical groups and the 3D mesh in the current gmsh model.
        scale: Length of one model unit (m).
        planes: ``(axis, value)`` of the flat faces (m), onto which nearby nodes are snapped.
    """
    import gmsh
    from dolfinx.io import gmshio

    error = None
    owned = False
    previous_model = None
    saved: dict[str, float] = {}
    if comm.rank == 0:
        try:
            if _gmsh_initialized(gmsh):
                previous_model = gmsh.model.getCurrent()
                saved = {opt: gmsh.option.getNumber(opt) for opt in _OPTIONS}
            else:
                gmsh.initialize(readConfigFiles=False)
                owned = True
            gmsh.option.setNumber("General.Terminal", 0)
            gmsh.model.add(name)
            build(gmsh)
        except Exception as err:  # noqa: BLE001 - any gmsh failure becomes a ValueError
            error = f"{name}: gmsh failed: {err}"
    error = comm.bcast(error, root=0)
    try:
        if error is not None:
            raise ValueError(error)
        model = gmsh.model if comm.rank == 0 else None
        mesh, cell_tags, facet_tags = gmshio.model_to_mesh(model, comm, 0, gdim=3)
    finally:
        if comm.rank == 0:
            if owned:
                gmsh.finalize()
            elif _gmsh_initialized(gmsh):
                if name in gmsh.model.list():
                    gmsh.model.setCurrent(name)
                    gmsh.model.remove()
                if previous_model is not None and previous_model in gmsh.model.list():
                    gmsh.model.setCurrent(previous_model)
                for opt, value in saved.items():
                    gmsh.option.setNumber(opt, value)
    x = mesh.geometry.x
    x[:] *= scale
    tol = _SNAP * scale
    for axis, value in planes:
        on_plane = np.abs(x[:, axis] - value) < tol
        x[on_plane, axis] = value
    cell_tags.name = "cell_tags"
    facet_tags.name = "facet_tags"
    mesh.name = name
    mesh.topology.create_connectivity(mesh.topology.dim - 1, mesh.topology.dim)
    return mesh, cell_tags, facet_tags


__all__ = [
    "BALL",
    "BALL_ON_BLOCK_MARKERS",
    "BLOCK",
    "BLOCK_BOTTOM",
    "BLOCK_SYM_X",
    "BLOCK_SYM_Y",
    "BLOCK_TOP",
    "BLOCK_XMAX",
    "BLOCK_XMIN",
    "BLOCK_YMAX",
    "BLOCK_YMIN",
    "CONTACT",
    "DEFAULT_GRADING",
    "HEMISPHERE_MARKERS",
    "LOWER",
    "LOWER_BOTTOM",
    "LOWER_TOP",
    "LOWER_XMAX",
    "LOWER_XMIN",
    "LOWER_YMAX",
    "LOWER_YMIN",
    "SYM_X",
    "SYM_Y",
    "TOP",
    "TWO_BLOCKS_MARKERS",
    "UPPER",
    "UPPER_BOTTOM",
    "UPPER_TOP",
    "UPPER_XMAX",
    "UPPER_XMIN",
    "UPPER_YMAX",
    "UPPER_YMIN",
    "build_ball_on_block",
    "build_hemisphere",
    "build_two_blocks",
]
