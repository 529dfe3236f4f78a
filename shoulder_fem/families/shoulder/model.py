"""The ``shoulder`` scene family: internal rotation of the glenohumeral joint (paper's study).

Bodies (mesh of :mod:`shoulder_fem.meshes.shoulder`): humerus and scapula (bone, linear elastic,
E = E0 (rho/rho0)^2 from a CT(-like) density image, nu = 0.3: Saint Venant-Kirchhoff at finite
strain), humeral and glenoid cartilage (neo-Hookean, nearly incompressible), subscapularis,
supraspinatus and infraspinatus (Veronda-Westmann, nearly incompressible). Every body is P2
(10-node tetrahedra, pure displacement; nu = 0.4 cartilage, 0.49 muscle).

Interactions: the two articular surfaces are in large-sliding, frictionless penalty contact
(the glenoid surface is the slave: its pressure is the paper's Fig. 2); cartilages are bonded to
their bone and muscles to their footprints (shared nodes). The scapula hangs on 20 flexible
elements (trapezius, rhomboids) and one antero-posterior element, the humerus's distal section
on 4 vertical ones: linear springs (:mod:`shoulder_fem.springs`) between the centre of a
bone patch and the ground. The patch is a small rigid plate tied to the bone's patch nodes
(a spring on a single node would be a point load, with an infinite stress under it), so the
spring model is the same whether the bone is deformable (coupled; decoupled part 2) or rigid
(decoupled part 1: the plate is then part of the bone).

Actuation (paper): the scapular origin of the subscapularis is a rigid plate displaced along
``actuation_direction`` (medially); the humerus turns internally about its shaft axis. The
humeral rotation angle (the twist about the shaft axis of the humerus's best-fit rigid
rotation) is the progress variable: the displacement d of the origin is found by secant
iterations for each target angle (every ``angle_step``), outputs are written every
``output_angle``. A step whose Newton solve fails is cut back (halved) up to ``max_cutbacks``
times in a row (at most 2 x ``max_cutbacks`` failures per target angle); then the run stops
with status ``incomplete``, keeping the angles reached.

Methods:
* ``coupled``: one finite-strain problem with every body deformable, one Newton solve per
  step (:class:`shoulder_fem.rigid_bodies.RigidSystem` holds the spring plates and the
  actuator plate as rigid bodies tied to the mesh).
* ``decoupled``: part 1, the bones rigid (6 DOFs each), cartilages and muscles deformable,
  the same contact and springs; at each output angle it records the nodal forces that the
  glenoid cartilage and the supraspinatus and infraspinatus apply to the scapula and the
  scapula's rigid motion. Part 2: the scapula alone, linear elastic in its floating frame
  (paper eq. 13): K u = R^T f (transferred loads) + springs + rigid-frame inertia and Coriolis
  loads of the recorded motion (the rotation takes ``rotation_duration``), one factorization
  for every angle (chord iterations, only the springs' geometric terms are nonlinear).

Reported against the angle: glenoid pressure map (nodal) and its maximum, contact force, muscle
forces at the scapular footprints, the scapula's nodal von Mises stress (volume-weighted
average at the vertices of the cell values, the same operator for both methods), and for
the decoupled method the equilibrium residual of the transferred loads and the inertia loads.
``shoulder.npz`` in the run folder holds the arrays of :mod:`shoulder_fem.shoulder_report`.

Muscle-bone contact (``muscle_contact``): ``none`` (default) lets the muscles pass through
bone (at coarse, the infraspinatus's nodes reach 14.7 mm from the head centre at 50 deg, the
head's bone radius being 22.5 mm); ``humeral-head`` makes the muscles' deep faces slide on
the humerus's free surface around the head (penalty, :func:`_contact`): deformable in the
coupled method, a layer of humerus cells carried by the rigid humerus in part 1. The
muscles' contact with the scapula is not modelled.

Not modelled (stated in the README): cartilage friction, muscle-scapula contact, and the
Taylor-Hood pressure of the mesh module (pure-displacement P2 instead, same for both
methods).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path

import dolfinx
import dolfinx.fem.petsc as fem_petsc
import numpy as np
import ufl
from mpi4py import MPI
from petsc4py import PETSc
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from shoulder_fem.engine.contact import Contact, ContactPair, MeshSurface
from shoulder_fem.engine.rigid_system import RigidBody, RigidSystem, Tie
from shoulder_fem.engine.so3 import hat
from shoulder_fem.engine.solver import ConvergenceError, StepperStats
from shoulder_fem.engine.springs import GROUND, Spring, spring_response
from shoulder_fem.families.base import RunContext
from shoulder_fem.forms import materials
from shoulder_fem.forms import virtual_power as vp
from shoulder_fem.io import ct
from shoulder_fem.io.output import atomic_savez
from shoulder_fem.meshes import shoulder as S
from shoulder_fem.scene import Scene

logger = logging.getLogger(__name__)

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

#: Displacement direction of the subscapularis origin plate: medial, along the blade.
ACTUATION_DIRECTION = (-1.0, 0.0, 0.0)
#: The bonded interface cut open in the coupled mesh: the driven origin plate is not bone.
DETACHED = (("subscapularis_origin", "subscapularis"),)
#: Contact integration against the mesh masters (:class:`shoulder_fem.contact.Contact`): the
#: segments rule; point-wise integration stalled at 6 deg at coarse (README).
MESH_INTEGRATION = "segments"
SCAPULA_LOAD_SURFACES = ("glenoid_cartilage_bone", "supraspinatus_origin", "infraspinatus_origin")
REPORTED_MUSCLES = ("subscapularis", "supraspinatus", "infraspinatus")

#: Newton settings of the nonlinear solves. Joint forces are ~10-100 N: atol 1e-3 N is 1e-5 of
#: them. The penalty contact between the faceted surfaces converges linearly at the end (rate
#: ~0.5-0.85 per iteration: the change of the segments' areas is not in the tangent). Full
#: Newton steps (``basic``) are the fastest almost everywhere, but cycled between two contact
#: states (period-2 residual) on the way to 55 deg at the coarse level; there a step that fails
#: is retried with ``FALLBACK_LINESEARCH`` (a secant minimisation of |F|^2 along the Newton
#: direction) before it is cut back. ``l2`` everywhere is 3-5 times slower in the coupled
#: solve (residual decrease ~0.9 per iteration from the first step on; ``bt`` and ``cp`` too).
SNES_OPTIONS = {
    "snes_rtol": 1e-8,
    "snes_atol": 1e-3,
    "snes_max_it": 60,
    "snes_linesearch_type": "basic",
}
FALLBACK_LINESEARCH = "l2"


# ---- model ----------------------------------------------------------------------------------


@dataclass
class ShoulderModel:
    """What :func:`build` makes for one method: the scene values and the meshes it needs."""

    scene: Scene
    level: str
    comm: MPI.Comm
    method: str
    values: dict
    geometry: S.ShoulderGeometry
    meshes: dict
    shaft_axis: np.ndarray  # unit, pointing proximally: internal rotation is positive about it
    image: object = None
    info: dict = field(default_factory=dict)


def build(scene: Scene, level: str, comm: MPI.Comm, method: str) -> ShoulderModel:
    """Mesh the joint for ``method`` (collective): all bodies, or soft tissues + the scapula."""
    values = scene.values()
    geometry = S.geometry_from_values(values)
    sizes = scene.level(level)
    variants = ("deformable",) if method == "coupled" else ("rigid-bone", "scapula")
    # the subscapularis origin is the actuator: cut it free of the scapula
    wrap = _muscle_contact(values)
    meshes = S.build_shoulder_mesh(
        comm, geometry, sizes, variants, detach=DETACHED, head_layer=wrap
    )
    lay = S.layout(geometry)
    s_dir = lay.rot @ S.shaft_axis(geometry)[0]
    axis = -s_dir / np.linalg.norm(s_dir)
    image = ct.shoulder_phantom(geometry)
    model = ShoulderModel(scene, level, comm, method, values, geometry, meshes, axis, image)
    first = meshes["deformable" if method == "coupled" else "rigid-bone"]
    model.info["glenoid_frame"] = _glenoid_frame(first.mesh, first.facet_tags)
    model.info["humeral_cap"] = humeral_cap(first.mesh, first.facet_tags)
    return model


def _vector_dofs(mesh) -> int:
    V = dolfinx.fem.VectorFunctionSpace(mesh, ("Lagrange", 2))
    return V.dofmap.index_map.size_global * 3


def dofs(model: ShoulderModel) -> int:
    """Displacement DOFs: the whole joint (coupled), or part 1 + part 2 (decoupled)."""
    return sum(_vector_dofs(m.mesh) for m in model.meshes.values())


# ---- geometry helpers -----------------------------------------------------------------------


def _entity_centroids(mesh, dim: int, entities: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centroids (m) and areas (m^2) of straight triangles (facets or 2D cells)."""
    tdim = mesh.topology.dim
    mesh.topology.create_connectivity(dim, 0)
    mesh.topology.create_connectivity(tdim, 0)
    conn = mesh.topology.connectivity(dim, 0)
    c_to_v = mesh.topology.connectivity(tdim, 0)
    n_vert = mesh.topology.index_map(0).size_local + mesh.topology.index_map(0).num_ghosts
    # vertex -> geometry node (straight P1 geometry: the cells' vertex and node lists agree)
    v_to_x = np.zeros(n_vert, dtype=np.int64)
    v_to_x[c_to_v.array] = mesh.geometry.dofmap.array
    tri = np.vstack([conn.links(e) for e in entities]).astype(np.int64)
    p = mesh.geometry.x[v_to_x[tri]]
    area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    return p.mean(axis=1), area


def patch_centroid(mesh, tags, tag) -> np.ndarray:
    """Area-weighted centroid (m) of the entities of ``tags`` with value(s) ``tag`` (collective).

    ``tag``: one value or a list of them (a surface made of several markers).
    """
    dim = tags.dim
    n_owned = mesh.topology.index_map(dim).size_local
    chosen = np.isin(tags.values, np.atleast_1d(tag)) & (tags.indices < n_owned)
    ents = tags.indices[chosen]
    local = np.zeros(4)
    if len(ents):
        c, a = _entity_centroids(mesh, dim, ents)
        local[:3] = (c * a[:, None]).sum(axis=0)
        local[3] = a.sum()
    total = mesh.comm.allreduce(local, op=MPI.SUM)
    if total[3] <= 0:
        raise ValueError(f"shoulder mesh: surface tag {tag} is empty")
    return total[:3] / total[3]


def twist_angle(R: np.ndarray, axis: np.ndarray) -> float:
    """Twist (rad) of rotation ``R`` about the unit ``axis`` (swing-twist decomposition)."""
    x, y, z, w = Rotation.from_matrix(R).as_quat()
    return 2.0 * math.atan2(float(np.dot([x, y, z], axis)), w)


def swing_angle(R: np.ndarray, axis: np.ndarray) -> float:
    """Swing (rad) of rotation ``R``: the angle by which it turns the unit ``axis`` itself."""
    return math.acos(float(np.clip(np.dot(axis, R @ axis), -1.0, 1.0)))


def cap_angles(X: np.ndarray, centre: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Angles (rad) of points ``X`` (n, 3) from the unit ``axis`` of a cap, seen from ``centre``."""
    d = np.asarray(X, dtype=float).reshape(-1, 3) - centre
    r = np.linalg.norm(d, axis=1)
    return np.arccos(np.clip(d @ axis / np.where(r > 0, r, 1.0), -1.0, 1.0))


def best_fit_rotation(X: np.ndarray, x: np.ndarray, comm: MPI.Comm) -> np.ndarray:
    """Rotation of the least-squares rigid fit x ~ c + R (X - C) over the owned points (Kabsch)."""
    n = comm.allreduce(len(X), op=MPI.SUM)
    C = comm.allreduce(X.sum(axis=0), op=MPI.SUM) / n
    c = comm.allreduce(x.sum(axis=0), op=MPI.SUM) / n
    H = comm.allreduce((X - C).T @ (x - c), op=MPI.SUM)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    return Vt.T @ np.diag([1.0, 1.0, d]) @ U.T


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def spring_layout(values: dict) -> list[dict]:
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
                "direction": _unit(d),
                "stiffness": values["scapula_spring_stiffness"],
            }
        )
    out.append(
        {
            "name": "scapula_ap_spring",
            "bone": "scapula",
            "direction": _unit(AP_DIRECTION),
            "stiffness": values["ap_spring_stiffness"],
        }
    )
    for i in range(4):
        out.append(
            {
                "name": f"humerus_distal_spring_{i + 1}",
                "bone": "humerus",
                "direction": _unit(DISTAL_DIRECTION),
                "stiffness": values["humerus_spring_stiffness"],
            }
        )
    if values["humerus_horizontal_stiffness"] > 0:
        for i, d in enumerate(HORIZONTAL_DIRECTIONS):
            out.append(
                {
                    "name": f"humerus_horizontal_spring_{i + 1}",
                    "patch": DISTAL_SECTION,
                    "bone": "humerus",
                    "direction": _unit(d),
                    "stiffness": values["humerus_horizontal_stiffness"],
                }
            )
    for sp in out:
        sp.setdefault("patch", sp["name"])
        sp["plate"] = DISTAL_SECTION if sp["bone"] == "humerus" else sp["patch"]
    return out


def _marker_names(surface: str) -> tuple[str, ...]:
    """The markers of a surface: a set of :data:`meshes.shoulder.SURFACE_SETS` or one marker."""
    return S.SURFACE_SETS.get(surface, (surface,))


def surface_centroid(mesh, tags, surface: str) -> np.ndarray:
    """Area-weighted centroid (m) of a marker or a marker set (collective)."""
    return patch_centroid(mesh, tags, [S.MARKERS[n].id for n in _marker_names(surface)])


# ---- materials and forms --------------------------------------------------------------------


def _soft_residual(u, w, dx) -> ufl.Form:
    cart, musc = materials.NeoHookean.cartilage(), materials.VerondaWestmann.muscle()
    F = vp.internal_power_finite(cart, u, w, dx(S.HUMERAL_CARTILAGE.id))
    F += vp.internal_power_finite(cart, u, w, dx(S.GLENOID_CARTILAGE.id))
    for m in (S.SUBSCAPULARIS, S.SUPRASPINATUS, S.INFRASPINATUS):
        F += vp.internal_power_finite(musc, u, w, dx(m.id))
    return F


def _muscle_forms(u, w, dx) -> dict:
    musc = materials.VerondaWestmann.muscle()
    out = {}
    for m in (S.SUBSCAPULARIS, S.SUPRASPINATUS, S.INFRASPINATUS):
        out[m.name] = dolfinx.fem.form(vp.internal_power_finite(musc, u, w, dx(m.id)))
    return out


# scene keys that multiply each bone's E = E0 (rho/rho0)^2 (1 = the paper's Table I)
MODULUS_FACTORS = {"scapula": "scapula_modulus_factor", "humerus": "humerus_modulus_factor"}


def bone_fields(mesh, cell_tags, image, values: dict):
    """(density kg/m^3 as a P1 field, E Pa as a UFL field) of the bones.

    Both sampled from the image at the mesh nodes (E = E0 (rho/rho0)^2); E times each bone's
    modulus factor (``MODULUS_FACTORS``). The factor is a cell-wise (DG0) field, 1 outside the
    bones, so that it is exact on each bone's cells whatever the partition (a node-wise factor
    would need the bone's cells on the node's owner).
    """
    rho, E = ct.nodal_modulus(mesh, image)
    factor = dolfinx.fem.Function(dolfinx.fem.FunctionSpace(mesh, ("DG", 0)), name="modulus_factor")
    factor.x.array[:] = 1.0
    for body, key in MODULUS_FACTORS.items():
        factor.x.array[cell_tags.find(S.MARKERS[body].id)] = float(values[key])
    return rho, factor * E


def _quadrature(values: dict) -> dict:
    return {"quadrature_degree": int(values["quadrature_degree"])}


# ---- measurements ---------------------------------------------------------------------------


class Probe:
    """Per-output measurements shared by both methods (collective)."""

    def __init__(self, u, cell_tags, facet_tags, contact: Contact, values: dict):
        V = u.function_space
        mesh = V.mesh
        self.u, self.V, self.mesh, self.contact = u, V, mesh, contact
        self.comm = mesh.comm
        dx = ufl.Measure("dx", domain=mesh, subdomain_data=cell_tags, metadata=_quadrature(values))
        self._muscle = _muscle_forms(u, ufl.TestFunction(V), dx)
        self._vec = fem_petsc.create_vector(next(iter(self._muscle.values())))
        n_owned = V.dofmap.index_map.size_local
        self._origin = {}
        for m in REPORTED_MUSCLES:
            tag = S.MARKERS[f"{m}_origin"].id
            d = dolfinx.fem.locate_dofs_topological(V, 2, facet_tags.find(tag))
            self._origin[m] = d[d < n_owned]
        # glenoid nodes (P1 dofs of the contact pressure field on the slave surface)
        Q = contact.Q
        qd = dolfinx.fem.locate_dofs_topological(
            Q, 2, facet_tags.find(S.MARKERS["glenoid_articular"].id)
        )
        self._glenoid = qd[qd < Q.dofmap.index_map.size_local]
        self.glenoid_points = _gather_rows(Q.tabulate_dof_coordinates()[self._glenoid], self.comm)

    def muscle_forces(self) -> dict[str, np.ndarray]:
        """Force (N, vector) each muscle applies to its origin plate or bone footprint."""
        out = {}
        for name, form in self._muscle.items():
            with self._vec.localForm() as loc:
                loc.set(0.0)
            fem_petsc.assemble_vector(self._vec, form)
            self._vec.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
            f = self._vec.array_r.reshape(-1, 3)[self._origin[name]].sum(axis=0)
            out[name] = -self.comm.allreduce(f, op=MPI.SUM)
        return out

    def glenoid(self) -> tuple[np.ndarray, np.ndarray]:
        """Nodal contact pressure and shear (Pa) at the glenoid points (gathered on every rank)."""
        p, t = self.contact.pressure_fields()
        return (
            _gather_rows(p.x.array[self._glenoid], self.comm),
            _gather_rows(t.x.array[self._glenoid], self.comm),
        )

    def destroy(self) -> None:
        """Free the PETSc vector."""
        self._vec.destroy()


def _gather_rows(a: np.ndarray, comm: MPI.Comm) -> np.ndarray:
    parts = comm.allgather(np.asarray(a))
    return np.concatenate(parts, axis=0) if parts else np.asarray(a)


class VonMises:
    """Nodal von Mises stress (Pa) of the scapula (collective).

    Cell values at the vertices (DG1), volume-weighted average over the scapula cells around
    each vertex.
    """

    def __init__(self, mesh, cell_tags, stress: ufl.core.expr.Expr):
        dev = stress - ufl.tr(stress) / 3 * ufl.Identity(3)
        vm = ufl.sqrt(1.5 * ufl.inner(dev, dev))
        self.D = dolfinx.fem.FunctionSpace(mesh, ("DG", 1))
        self.P = dolfinx.fem.FunctionSpace(mesh, ("Lagrange", 1))
        self._expr = dolfinx.fem.Expression(vm, self.D.element.interpolation_points())
        self._dg = dolfinx.fem.Function(self.D)
        self.field = dolfinx.fem.Function(self.P, name="von_mises")
        n_owned = mesh.topology.index_map(3).size_local
        cells = cell_tags.find(S.SCAPULA.id)
        self._cells = cells[cells < n_owned]
        mesh.topology.create_connectivity(3, 3)
        vol_form = dolfinx.fem.form(
            ufl.TestFunction(dolfinx.fem.FunctionSpace(mesh, ("DG", 0))) * ufl.dx
        )
        self._vol = fem_petsc.assemble_vector(vol_form).array_r.copy()
        self._num = dolfinx.fem.Function(self.P)
        self._den = dolfinx.fem.Function(self.P)
        p_dofs = np.array([self.P.dofmap.cell_dofs(c) for c in self._cells], dtype=np.int64)
        d_dofs = np.array([self.D.dofmap.cell_dofs(c) for c in self._cells], dtype=np.int64)
        self._p_dofs, self._d_dofs = p_dofs.reshape(-1, 4), d_dofs.reshape(-1, 4)
        vol = np.repeat(self._vol[self._cells], 4).reshape(-1, 4)
        np.add.at(self._den.x.array, self._p_dofs, vol)
        self._den.x.scatter_reverse(dolfinx.la.ScatterMode.add)
        self._den.x.scatter_forward()
        owned = self.P.dofmap.index_map.size_local
        self._nodes = np.unique(self._p_dofs)
        self._nodes = self._nodes[self._nodes < owned]

    def update(self) -> dolfinx.fem.Function:
        """Evaluate at the current state; returns the P1 field (0 off the scapula)."""
        self._dg.interpolate(self._expr)
        self._num.x.array[:] = 0.0
        vals = self._dg.x.array[self._d_dofs] * self._vol[self._cells][:, None]
        np.add.at(self._num.x.array, self._p_dofs, vals)
        self._num.x.scatter_reverse(dolfinx.la.ScatterMode.add)
        self._num.x.scatter_forward()
        den = self._den.x.array
        self.field.x.array[:] = np.where(den > 0, self._num.x.array / np.where(den > 0, den, 1), 0)
        return self.field

    def nodal(self, comm: MPI.Comm) -> tuple[np.ndarray, np.ndarray]:
        """(points m, von Mises Pa) of the scapula vertices, gathered on every rank."""
        X = self.P.tabulate_dof_coordinates()[self._nodes]
        return _gather_rows(X, comm), _gather_rows(self.field.x.array[self._nodes], comm)

    def cells(self, comm: MPI.Comm) -> tuple[np.ndarray, np.ndarray]:
        """(vertex points, tetrahedra) of the scapula, gathered on every rank.

        Vertices are deduplicated by their global P1 index.
        """
        imap = self.P.dofmap.index_map
        glob = imap.local_to_global(self._p_dofs.ravel().astype(np.int32)).reshape(-1, 4)
        X = self.P.tabulate_dof_coordinates()
        gl = _gather_rows(glob, comm)
        xs = _gather_rows(X[self._p_dofs.ravel()], comm)
        uniq, inverse = np.unique(gl.ravel(), return_inverse=True)
        points = np.zeros((len(uniq), 3))
        points[inverse] = xs
        return points, inverse.reshape(-1, 4)


# ---- the angle-driven stepping --------------------------------------------------------------


@dataclass
class StepLog:
    """Counters of the stepping."""

    steps: int = 0
    failed_steps: int = 0
    fallbacks: int = 0
    newton_iterations: int = 0
    history: list = field(default_factory=list)


def drive_rotation(
    system: RigidSystem,
    contact: Contact,
    actuator: RigidBody,
    direction: np.ndarray,
    angle,
    values: dict,
    on_output,
    label: str,
) -> tuple[float, StepLog, str | None]:
    """Move the actuator plate until the humerus reaches each target angle (collective).

    Args:
        system: The system to solve (its actuator body is prescribed).
        contact: Its contact terms (committed after each accepted step).
        actuator: The prescribed plate of the subscapularis origin.
        direction: Unit direction of its displacement.
        angle: Callable -> current humeral rotation angle (rad).
        values: Scene values (angles in rad, lengths in m).
        on_output: Callable(angle_rad) at 0 and every output angle reached.
        label: For the progress messages.

    Returns:
        (final angle in rad, counters, None or the reason the run stopped early).
    """
    final = values["final_angle"]
    step = values["angle_step"]
    every = values["output_angle"]
    tol = values["angle_tolerance"]
    d_max = values["max_actuation_step"]
    max_cut = int(values["max_cutbacks"])
    log = StepLog()
    system.solve(step=f"{label} 0 deg")
    contact.commit()
    theta, d = angle(), 0.0
    on_output(0.0)
    n_targets = int(round(final / step))
    slope = None
    previous = None  # (d, snapshot) of the step before the current state
    for k in range(1, n_targets + 1):
        target = k * step
        limit = d_max
        # cutbacks in a row; failures on the way to this target (a short secant step that
        # converges resets the cutbacks, not the failures: at a wall the run ends all the same)
        cuts = fails = 0
        for _ in range(30):
            if abs(theta - target) <= tol:
                break
            if slope is None or slope <= 0:
                dd = 0.25 * d_max
            else:
                dd = (target - theta) / slope
            dd = float(np.clip(dd, -limit, limit))
            snap = system.snapshot()

            def predict(snap=snap, dd=dd, d=d, previous=previous):
                if previous is not None and abs(previous[0] - d) > 0:
                    _extrapolate(system, snap, previous, dd / (d - previous[0]))
                actuator.prescribe((d + dd) * direction, np.eye(3))

            predict()
            try:
                its = _solve_with_fallback(
                    system, f"{label} {math.degrees(target):.1f} deg", snap, predict, log
                )
            except ConvergenceError as err:
                system.restore(snap)
                log.failed_steps += 1
                cuts += 1
                limit = 0.5 * abs(dd)
                logger.warning(
                    "%s: step d = %.3f -> %.3f mm failed (%s); cutback %d/%d",
                    label,
                    d * 1e3,
                    (d + dd) * 1e3,
                    err.reason,
                    cuts,
                    max_cut,
                )
                fails += 1
                if cuts > max_cut or fails > 2 * max_cut:
                    why = (
                        f"after {max_cut} cutbacks"
                        if cuts > max_cut
                        else f"in {fails} tries (more than 2 x max_cutbacks)"
                    )
                    msg = (
                        f"{label}: stopped at {math.degrees(theta):.2f} deg of "
                        f"{math.degrees(final):.0f} deg: the step towards "
                        f"{math.degrees(target):.1f} deg did not converge {why} ({err.reason})"
                    )
                    return theta, log, msg
                continue
            contact.commit()
            cuts = 0
            limit = min(d_max, 2.0 * limit)  # a cut-back step size grows back on success
            previous = (d, snap)
            new = angle()
            if abs(dd) > 0 and abs(new - theta) > 1e-12:
                slope = (new - theta) / dd
            d, theta = d + dd, new
            log.steps += 1
            log.newton_iterations += its
            log.history.append((d, theta, its))
            logger.info(
                "%s: d = %.3f mm, angle %.3f deg (target %.1f), %d Newton iterations",
                label,
                d * 1e3,
                math.degrees(theta),
                math.degrees(target),
                its,
            )
        if abs(theta - target) > tol:
            msg = (
                f"{label}: stopped at {math.degrees(theta):.2f} deg of {math.degrees(final):.0f} "
                f"deg: the angle {math.degrees(target):.1f} deg was not reached within "
                f"{math.degrees(tol):.3g} deg in 30 secant steps"
            )
            return theta, log, msg
        if abs(target / every - round(target / every)) < 1e-9:
            on_output(target)
    return theta, log, None


def _solve_with_fallback(system: RigidSystem, step: str, snap, predict, log: StepLog) -> int:
    """Solve; if Newton ran out of iterations, solve again with the ``FALLBACK_LINESEARCH``.

    The second solve starts from ``snap`` (re-predicted by ``predict()``). Returns the Newton
    iterations of the solve that converged.

    Raises:
        ConvergenceError: Both solves failed (the reason of the second).
    """
    try:
        return system.solve(step=step)
    except ConvergenceError as err:
        original = system.linesearch
        if original == FALLBACK_LINESEARCH or "MAX_IT" not in err.reason:
            raise  # a NaN residual or a failed factorization: the step is too long
        logger.info(
            "%s: %s; retried with the %s line search", step, err.reason, FALLBACK_LINESEARCH
        )
        log.fallbacks += 1
        system.restore(snap)
        predict()
        system.linesearch = FALLBACK_LINESEARCH
        try:
            return system.solve(step=f"{step} ({FALLBACK_LINESEARCH} line search)")
        finally:
            system.linesearch = original


def _extrapolate(system: RigidSystem, current: tuple, previous: tuple, ratio: float) -> None:
    """Linear predictor: state + ratio x (state - previous state) for u and the free bodies."""
    u_now, motions_now, _ = current
    u_old, motions_old, _ = previous[1]
    ratio = float(np.clip(ratio, -1.0, 1.0))
    system.u.x.array[:] = u_now + ratio * (u_now - u_old)
    for body, (t1, R1), (t0, R0) in zip(system.bodies, motions_now, motions_old, strict=True):
        if body.prescribed:
            continue
        step = Rotation.from_matrix(R0.T @ R1).as_rotvec()
        system.move(
            body.name, t1 + ratio * (t1 - t0), R1 @ Rotation.from_rotvec(ratio * step).as_matrix()
        )


# ---- coupled --------------------------------------------------------------------------------


def _surfaces(facet_tags, names) -> dict:
    return {n: (facet_tags, S.MARKERS[n].id) for n in names}


def _head_tags(model: ShoulderModel, mesh, facet_tags):
    """The facet tags, with the surfaces of muscle-bone contact if it is on (collective)."""
    if not _muscle_contact(model.values):
        return facet_tags
    return S.head_surface_tags(mesh, facet_tags, S.head_region_radius(model.geometry))


def _muscle_contact(values: dict) -> bool:
    """Whether the rotator cuff slides on the humeral head (``muscle_contact``)."""
    return values["muscle_contact"] == "humeral-head"


def _contact(V, u, facet_tags, values: dict) -> Contact:
    """Glenohumeral contact; muscle-bone contact of the rotator cuff on the humeral head."""
    pairs = [
        ContactPair(
            "glenohumeral",
            slave=(S.MARKERS["glenoid_articular"].id,),
            master=MeshSurface((S.MARKERS["humeral_articular"].id,)),
            penalty=values["contact_penalty"],
        )
    ]
    if _muscle_contact(values):
        pairs.append(
            ContactPair(
                "muscle_humerus",
                slave=(S.MUSCLE_DEEP_SURFACE.id,),
                master=MeshSurface((S.HUMERUS_HEAD_SURFACE.id,)),
                penalty=values["muscle_contact_penalty"],
                search_depth=values["muscle_contact_depth"],
                smoothing=values["muscle_contact_smoothing"],
            )
        )
    return Contact(
        V,
        u,
        facet_tags,
        pairs,
        quadrature_degree=int(values["contact_quadrature"]),
        slave_integration="element",
        mesh_integration=MESH_INTEGRATION,
    )


def _spring_plates(mesh, facet_tags, springs: list[dict], length: float):
    """Rigid plates tied to the springs' plate surfaces (one per plate), and their springs.

    Each spring runs from its patch's centroid, on its plate, to the ground.
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
            ties += [Tie(plate, m) for m in _marker_names(plate)]
        c = centre(sp["patch"])
        out.append(
            Spring(sp["name"], plate, c, GROUND, c + length * sp["direction"], sp["stiffness"])
        )
    return bodies, ties, out


def run_coupled(model: ShoulderModel, run: RunContext) -> None:
    """Method #1: every body deformable, finite strain (collective)."""
    recorder = run.recorder
    monitor = run.monitor
    fields_dir = run.fields
    options = run.options
    v = model.values
    sm = model.meshes["deformable"]
    mesh, ct_ = sm.mesh, sm.cell_tags
    ft = _head_tags(model, mesh, sm.facet_tags)
    comm = mesh.comm
    V = dolfinx.fem.VectorFunctionSpace(mesh, ("Lagrange", 2))
    u = dolfinx.fem.Function(V, name="displacement")
    w = ufl.TestFunction(V)
    dx = ufl.Measure("dx", domain=mesh, subdomain_data=ct_, metadata=_quadrature(v))
    rho, E = bone_fields(mesh, ct_, model.image, v)
    bone = materials.SaintVenantKirchhoff(E, materials.BONE_NU)
    F = _soft_residual(u, w, dx)
    F += vp.internal_power_finite(bone, u, w, dx(S.HUMERUS.id))
    F += vp.internal_power_finite(bone, u, w, dx(S.SCAPULA.id))
    contact = _contact(V, u, ft, v)
    bodies, ties, springs = _spring_plates(mesh, ft, spring_layout(v), v["spring_length"])
    origin = patch_centroid(mesh, ft, S.MARKERS["subscapularis_origin"].id)
    actuator = RigidBody("actuator", origin, prescribed=True)
    bodies.append(actuator)
    ties.append(Tie("actuator", "subscapularis_origin"))
    system = RigidSystem(
        bodies,
        springs,
        u=u,
        residual=F,
        surfaces=_surfaces(ft, [t.surface for t in ties]),
        ties=ties,
        name="shoulder_coupled",
        options=SNES_OPTIONS | dict(options or {}),
        form_compiler_params=_quadrature(v),
        contact=contact,
    )
    humerus_dofs = dolfinx.fem.locate_dofs_topological(V, 3, ct_.find(S.HUMERUS.id))
    humerus_dofs = humerus_dofs[humerus_dofs < V.dofmap.index_map.size_local]
    X_h = V.tabulate_dof_coordinates()[humerus_dofs]

    def rotation() -> np.ndarray:
        x = X_h + u.x.array.reshape(-1, 3)[humerus_dofs]
        return best_fit_rotation(X_h, x, comm)

    stress_vm = VonMises(mesh, ct_, _cauchy(bone, u))
    probe = Probe(u, ct_, ft, contact, v)
    data = _run_steps(
        model,
        recorder,
        monitor,
        fields_dir,
        system,
        contact,
        actuator,
        rotation,
        probe,
        stress_vm,
        u,
        "coupled",
        "rotation",
    )
    recorder.extra("dofs_coupled", _unknowns(system))
    _save_results(model, data, stress_vm, mesh, ft, fields_dir.parent / "shoulder.npz")
    probe.destroy()
    system.destroy()


def _unknowns(system: RigidSystem) -> int:
    """Unknowns of a system's Newton solves: free FE DOFs and six per rigid body (collective).

    Tied and fixed nodes are not unknowns (the rigid-bone mesh carries tied bone nodes).
    """
    x = system.reduced_vector()
    n = x.getSize()
    x.destroy()
    return int(n)


def humeral_cap(mesh, ft) -> tuple[np.ndarray, np.ndarray, float]:
    """The humeral cartilage as meshed: centre (m), unit axis, half-angle (rad) (collective).

    The centre is the articular sphere's (the frame origin of :mod:`meshes.shoulder`, for every
    head shape); the axis points from it to the centroid of the articular surface; the
    half-angle is that of the articular surface's farthest node from the axis.
    """
    centre = np.zeros(3)
    axis = _unit(patch_centroid(mesh, ft, S.MARKERS["humeral_articular"].id) - centre)
    Q = dolfinx.fem.FunctionSpace(mesh, ("Lagrange", 1))
    nodes = dolfinx.fem.locate_dofs_topological(Q, 2, ft.find(S.MARKERS["humeral_articular"].id))
    X = Q.tabulate_dof_coordinates()[nodes]
    half = float(cap_angles(X, centre, axis).max(initial=0.0))
    return centre, axis, mesh.comm.allreduce(half, op=MPI.MAX)


def _glenoid_frame(mesh, ft) -> tuple[np.ndarray, np.ndarray]:
    """Centre (m) and outward unit axis of the glenoid articular surface (collective)."""
    centre = patch_centroid(mesh, ft, S.MARKERS["glenoid_articular"].id)
    bone = patch_centroid(mesh, ft, S.MARKERS["glenoid_cartilage_bone"].id)
    return centre, _unit(centre - bone)


def _save_results(model, data, stress_vm, mesh, ft, path: Path) -> None:
    """shoulder.npz of one run (see :mod:`shoulder_fem.shoulder_report`)."""
    comm = mesh.comm
    points, vm = data.get("von_mises", (np.zeros((0, 3)), np.zeros(0)))
    cell_points, cells = stress_vm.cells(comm)
    # the nodal values in the order of the cell points
    tree = cKDTree(points) if len(points) else None
    order = tree.query(cell_points)[1] if tree is not None else np.zeros(0, dtype=int)
    section = patch_centroid(mesh, ft, S.MARKERS["scapula_section"].id)[2]
    centre, axis = model.info["glenoid_frame"]
    n_out = len(data["angles_deg"])
    arrays = {
        "angles_deg": np.asarray(data["angles_deg"], dtype=float),
        "glenoid_points": np.asarray(data["glenoid_points"]),
        "glenoid_pressure": np.asarray(data["glenoid_pressure"]).reshape(n_out, -1),
        "glenoid_shear": np.asarray(data["glenoid_shear"]).reshape(n_out, -1),
        "glenoid_centre": centre,
        "glenoid_axis": axis,
        "scapula_points": cell_points,
        "scapula_cells": cells,
        "scapula_von_mises": np.asarray(vm)[order] if len(vm) else np.zeros(len(cell_points)),
        "von_mises_angle_deg": float(data.get("von_mises_angle_deg", math.nan)),
        "section_z": float(section),
        "final_angle_deg": float(data["final_angle_deg"]),
    }
    for key, value in data.get("arrays", {}).items():
        arrays[key] = value
    _save_npz(path, arrays, comm)


def _cauchy(bone, u) -> ufl.core.expr.Expr:
    from shoulder_fem.forms.kinematics import deformation_gradient

    Fg = deformation_gradient(u)
    return bone.first_piola(Fg) * Fg.T / ufl.det(Fg)


def _record_von_mises(recorder, stress_vm: VonMises, x: float, data: dict, comm) -> None:
    """Record the scapula's von Mises stress at output angle ``x`` (deg) (collective).

    Its maximum as a series point, its nodal values in ``data`` (the last output's are saved).
    """
    field_vm = stress_vm.update()
    local = float(field_vm.x.array.max()) if len(field_vm.x.array) else 0.0
    recorder.add_series_point(
        "scapula_max_von_mises", x, comm.allreduce(local, op=MPI.MAX), "deg", "Pa"
    )
    data["von_mises"] = stress_vm.nodal(comm)
    data["von_mises_angle_deg"] = x


def _time_split(recorder, label: str, system: RigidSystem, contact: Contact) -> None:
    """Where a stepping's Newton time went (probes ``<label>_time_*_s``, wall s, slowest rank).

    ``newton``: in the Newton solves in all; ``residual`` and ``jacobian``: their evaluations
    (FE assembly, contact, the reduction to the rigid bodies; within ``jacobian``:
    ``jacobian_fe_assembly`` and ``jacobian_reduction``, the products Pᵀ K P); ``linear``: the
    rest of ``newton`` (the LU factorizations and solves); ``contact``: the contact search and
    assembly, part of ``residual`` and ``jacobian``.
    """
    st, cs = system.stats, contact.stats
    times = {
        "newton": st.snes_s,
        "residual": st.residual_s,
        "jacobian": st.jacobian_s,
        "jacobian_fe_assembly": st.fe_assembly_s,
        "jacobian_reduction": st.reduction_s,
        "linear": max(st.snes_s - st.residual_s - st.jacobian_s, 0.0),
        "contact": cs.search_s + cs.assembly_s,
    }
    for key, value in times.items():
        worst = system.comm.allreduce(float(value), op=MPI.MAX)
        recorder.set_probe(f"{label}_time_{key}_s", worst, "s")


def _run_steps(
    model,
    recorder,
    monitor,
    fields_dir,
    system,
    contact,
    actuator,
    rotation,
    probe,
    stress_vm,
    u,
    label,
    stage,
    on_output_extra=None,
):
    """Drive the rotation, recording every output angle; write shoulder.npz (collective).

    ``rotation()`` is the humerus's current rotation: its twist about the shaft axis is the
    progress angle, its swing (how far the shaft axis itself turns) is recorded with it.
    """
    v = model.values
    comm = system.comm
    cap_centre, cap_axis, cap_half = model.info["humeral_cap"]
    recorder.set_probe("humeral_cap_half_angle_deg", math.degrees(cap_half), "deg")

    def angle() -> float:
        return twist_angle(rotation(), model.shaft_axis)

    def cap_position() -> tuple[float, float]:
        """Where the glenoid presses on the humeral cartilage, in deg from the cartilage's axis.

        Force-weighted mean and largest angle, in the humerus's reference geometry.
        """
        X, f = contact.master_points("glenohumeral")
        a = cap_angles(X, cap_centre, cap_axis)
        fa, fs = (
            comm.allreduce(float((f * a).sum()), op=MPI.SUM),
            comm.allreduce(float(f.sum()), op=MPI.SUM),
        )
        top = comm.allreduce(float(a.max(initial=0.0)), op=MPI.MAX)
        return (math.degrees(fa / fs) if fs > 0 else 0.0), math.degrees(top)

    direction = _unit(ACTUATION_DIRECTION)
    data = {"angles_deg": [], "glenoid_pressure": [], "glenoid_shear": []}
    writer = dolfinx.io.XDMFFile(comm, str(fields_dir / f"{label}.xdmf"), "w")
    writer.write_mesh(u.function_space.mesh)
    P1 = dolfinx.fem.VectorFunctionSpace(u.function_space.mesh, ("Lagrange", 1))
    u1 = dolfinx.fem.Function(P1, name="displacement")

    def on_output(target: float) -> None:
        deg = math.degrees(angle())
        p, t = probe.glenoid()
        data["angles_deg"].append(round(math.degrees(target), 6))
        data["glenoid_pressure"].append(p)
        data["glenoid_shear"].append(t)
        both = contact.resultants()
        res, wrap = both["glenohumeral"], both.get("muscle_humerus")
        x = math.degrees(target)
        recorder.add_series_point("humeral_angle", x, deg, "deg", "deg")
        recorder.add_series_point(
            "humeral_swing",
            x,
            math.degrees(swing_angle(rotation(), model.shaft_axis)),
            "deg",
            "deg",
        )
        mean, top = cap_position()
        recorder.add_series_point("humeral_cap_contact_angle", x, mean, "deg", "deg")
        recorder.add_series_point("humeral_cap_contact_angle_max", x, top, "deg", "deg")
        recorder.add_series_point("max_pressure", x, float(p.max()) if len(p) else 0.0, "deg", "Pa")
        recorder.add_series_point("max_shear", x, float(t.max()) if len(t) else 0.0, "deg", "Pa")
        recorder.add_series_point(
            "contact_force", x, float(np.linalg.norm(res["force"])), "deg", "N"
        )
        recorder.add_series_point("contact_area", x, float(res["area"]), "deg", "m^2")
        if wrap is not None:  # the rotator cuff on the humeral head: force, deepest overlap
            recorder.add_series_point(
                "muscle_bone_contact_force", x, float(np.linalg.norm(wrap["force"])), "deg", "N"
            )
            recorder.add_series_point(
                "muscle_bone_penetration", x, float(wrap["max_penetration"]), "deg", "m"
            )
        forces = probe.muscle_forces()
        for m, f in forces.items():
            recorder.add_series_point(f"{m}_force", x, float(np.linalg.norm(f)), "deg", "N")
        recorder.add_series_point(
            "actuation",
            x,
            float(np.linalg.norm(actuator._target[0]) if actuator._target else 0.0),
            "deg",
            "m",
        )
        if on_output_extra is not None:
            on_output_extra(target)
        if stress_vm is not None:
            _record_von_mises(recorder, stress_vm, x, data, comm)
        u1.interpolate(u)
        writer.write_function(u1, x)
        logger.info(
            "%s: output at %.0f deg (measured %.3f deg), max pressure %.3f MPa",
            label,
            x,
            deg,
            (float(p.max()) if len(p) else 0.0) / 1e6,
        )

    with monitor.stage(stage):
        final, log, stop = drive_rotation(
            system, contact, actuator, direction, angle, v, on_output, label
        )
    writer.close()
    recorder.set_probe("final_angle_deg", math.degrees(final), "deg")
    recorder.set_probe("steps", log.steps, "1")
    recorder.set_probe("failed_steps", log.failed_steps, "1")
    recorder.set_probe("linesearch_fallbacks", log.fallbacks, "1")
    recorder.set_probe("newton_iterations", log.newton_iterations, "1")
    recorder.add_solver_counts(system.stats, StepperStats(log.steps, log.failed_steps))
    _time_split(recorder, label, system, contact)
    if stop is not None:
        mean, top = cap_position()  # at the last converged state: where the contact had got to
        stop += (
            f"; at {math.degrees(final):.2f} deg the glenoid pressed on the humeral cartilage up "
            f"to {top:.1f} deg from its axis (force-weighted mean {mean:.1f} deg; the cartilage "
            f"ends at {math.degrees(cap_half):.1f} deg) and the shaft had swung "
            f"{math.degrees(swing_angle(rotation(), model.shaft_axis)):.1f} deg"
        )
        recorder.set_status("incomplete", stop)
        logger.error("%s", stop)
    data["final_angle_deg"] = math.degrees(final)
    data["glenoid_points"] = probe.glenoid_points
    data["stop"] = stop
    return data


def _save_npz(path: Path, arrays: dict, comm: MPI.Comm) -> None:
    """Write ``arrays`` to ``path`` atomically (rank 0 writes, every rank waits)."""
    if comm.rank == 0:
        atomic_savez(path, arrays)
    comm.Barrier()


# ---- decoupled ------------------------------------------------------------------------------


class NodalLoads:
    """Given nodal forces (N) on a :class:`RigidSystem`, through its contact hook.

    External loads: subtracted from the residual; no tangent.
    """

    def __init__(self, V, points: np.ndarray):
        self.comm = V.mesh.comm
        n_owned = V.dofmap.index_map.size_local
        X = V.tabulate_dof_coordinates()[:n_owned]
        dist, idx = cKDTree(X).query(points) if n_owned else (np.full(len(points), np.inf), None)
        self._mine = np.flatnonzero(dist < 1e-9)
        self._rows = idx[self._mine] if idx is not None else np.zeros(0, dtype=np.int64)
        found = self.comm.allreduce(len(self._mine), op=MPI.SUM)
        if found != len(points):
            raise ValueError(
                f"decoupled part 2: {len(points) - found} of {len(points)} transferred load "
                "points are no node of the scapula mesh"
            )
        self.forces = np.zeros((len(points), 3))

    def add_residual(self, b: PETSc.Vec) -> None:
        """Subtract the forces from the owned rows of the (full) residual ``b``."""
        with b.localForm() as loc:
            arr = loc.array.reshape(-1, 3)
            arr[self._rows] -= self.forces[self._mine]

    def jacobian_matrix(self, K: PETSc.Mat) -> PETSc.Mat:
        """An empty matrix of the layout of ``K`` (dead loads have no tangent)."""
        A = PETSc.Mat().createAIJ(K.getSizes(), nnz=1, comm=self.comm)
        A.setUp()
        A.assemble()
        return A


def _finite_differences(times, translations, rotations):
    """Per output: velocity, acceleration (spatial) and body-frame Ω, dΩ/dt (backward)."""
    n = len(times)
    vel, acc = np.zeros((n, 3)), np.zeros((n, 3))
    om, dom = np.zeros((n, 3)), np.zeros((n, 3))
    for k in range(1, n):
        dt = times[k] - times[k - 1]
        vel[k] = (translations[k] - translations[k - 1]) / dt
        acc[k] = (vel[k] - vel[k - 1]) / dt
        om[k] = Rotation.from_matrix(rotations[k - 1].T @ rotations[k]).as_rotvec() / dt
        dom[k] = (om[k] - om[k - 1]) / dt
    return vel, acc, om, dom


def run_decoupled(model: ShoulderModel, run: RunContext) -> None:
    """Method #2: part 1 (rigid bones), then part 2 (scapula, linear, floating frame)."""
    recorder = run.recorder
    monitor = run.monitor
    fields_dir = run.fields
    options = run.options
    v = model.values
    sm = model.meshes["rigid-bone"]
    mesh, ct_ = sm.mesh, sm.cell_tags
    ft = _head_tags(model, mesh, sm.facet_tags)
    comm = mesh.comm
    V = dolfinx.fem.VectorFunctionSpace(mesh, ("Lagrange", 2))
    u = dolfinx.fem.Function(V, name="displacement")
    w = ufl.TestFunction(V)
    dx = ufl.Measure("dx", domain=mesh, subdomain_data=ct_, metadata=_quadrature(v))
    F = _soft_residual(u, w, dx)
    contact = _contact(V, u, ft, v)
    surf, stags = sm.bone_surface, sm.bone_surface_tags
    humerus = RigidBody("humerus", np.zeros(3))
    scapula_ref = patch_centroid(mesh, ft, S.MARKERS["glenoid_cartilage_bone"].id)
    scapula = RigidBody("scapula", scapula_ref)
    origin = patch_centroid(mesh, ft, S.MARKERS["subscapularis_origin"].id)
    actuator = RigidBody("actuator", origin, prescribed=True)
    springs, layout = [], spring_layout(v)
    for sp in layout:
        c = surface_centroid(surf, stags, sp["patch"])
        sp["centre"] = c
        springs.append(
            Spring(
                sp["name"],
                sp["bone"],
                c,
                GROUND,
                c + v["spring_length"] * sp["direction"],
                sp["stiffness"],
            )
        )
    ties = [
        Tie("humerus", n)
        for n in (
            "humeral_cartilage_bone",
            "subscapularis_insertion",
            "supraspinatus_insertion",
            "infraspinatus_insertion",
        )
    ]
    ties += [Tie("scapula", n) for n in SCAPULA_LOAD_SURFACES]
    ties.append(Tie("actuator", "subscapularis_origin"))
    surfaces = _surfaces(ft, [t.surface for t in ties])
    if _muscle_contact(v):
        # the humerus cells under the muscles' sliding master: carried whole by the humerus
        surfaces[S.HUMERUS_HEAD_LAYER.name] = (ct_, S.HUMERUS_HEAD_LAYER.id)
        ties.append(Tie("humerus", S.HUMERUS_HEAD_LAYER.name))
    system = RigidSystem(
        [humerus, scapula, actuator],
        springs,
        u=u,
        residual=F,
        surfaces=surfaces,
        ties=ties,
        name="shoulder_part1",
        options=SNES_OPTIONS | dict(options or {}),
        form_compiler_params=_quadrature(v),
        contact=contact,
    )
    n_owned = V.dofmap.index_map.size_local
    load_dofs = np.unique(
        np.concatenate(
            [
                dolfinx.fem.locate_dofs_topological(V, 2, ft.find(S.MARKERS[n].id))
                for n in SCAPULA_LOAD_SURFACES
            ]
        )
    )
    load_dofs = load_dofs[load_dofs < n_owned]
    X_load = V.tabulate_dof_coordinates()[load_dofs]
    transfer = {
        "angles": [],
        "forces": [],
        "translation": [],
        "rotation": [],
        "humerus_rotation": [],
    }

    def record_transfer(target: float) -> None:
        Fv = system.assembled_residual()
        f = -Fv.array_r.reshape(-1, 3)[load_dofs]
        transfer["angles"].append(target)
        transfer["forces"].append(_gather_rows(f, comm))
        transfer["translation"].append(scapula.translation.copy())
        transfer["rotation"].append(scapula.rotation.copy())
        transfer["humerus_rotation"].append(humerus.rotation.copy())

    probe = Probe(u, ct_, ft, contact, v)
    data = _run_steps(
        model,
        recorder,
        monitor,
        fields_dir,
        system,
        contact,
        actuator,
        lambda: humerus.rotation,
        probe,
        None,
        u,
        "part1",
        "part1",
        on_output_extra=record_transfer,
    )
    recorder.extra("dofs_part1", _unknowns(system))
    points = _gather_rows(X_load, comm)
    probe.destroy()
    system.destroy()
    transfer_path = fields_dir.parent / "transfer.npz"
    _save_npz(
        transfer_path,
        {
            "points": points,
            "forces": np.asarray(transfer["forces"]),
            "angles_rad": np.asarray(transfer["angles"]),
            "translation": np.asarray(transfer["translation"]),
            "rotation": np.asarray(transfer["rotation"]),
        },
        comm,
    )
    with monitor.stage("part2"):
        stress_vm, mesh2, ft2 = _part2(
            model, recorder, fields_dir, transfer, points, layout, scapula_ref, options, data
        )
    _save_results(model, data, stress_vm, mesh2, ft2, fields_dir.parent / "shoulder.npz")


def _part2(model, recorder, fields_dir, transfer, points, layout, ref, options, data):
    """The scapula in its floating frame, linear elastic, one factorization (collective)."""
    v = model.values
    sm = model.meshes["scapula"]
    mesh, ct_, ft = sm.mesh, sm.cell_tags, sm.facet_tags
    comm = mesh.comm
    V = dolfinx.fem.VectorFunctionSpace(mesh, ("Lagrange", 2))
    u = dolfinx.fem.Function(V, name="displacement")
    u_prev = dolfinx.fem.Function(V)
    w = ufl.TestFunction(V)
    dx = ufl.Measure("dx", domain=mesh, subdomain_data=ct_, metadata=_quadrature(v))
    rho, E = bone_fields(mesh, ct_, model.image, v)
    bone = materials.LinearElastic(E, materials.BONE_NU)
    a0 = dolfinx.fem.Constant(mesh, np.zeros(3))
    om = dolfinx.fem.Constant(mesh, np.zeros(3))
    dom = dolfinx.fem.Constant(mesh, np.zeros(3))
    inv_dt = dolfinx.fem.Constant(mesh, 0.0)
    relief_a = dolfinx.fem.Constant(mesh, np.zeros(3))
    relief_alpha = dolfinx.fem.Constant(mesh, np.zeros(3))
    r = ufl.SpatialCoordinate(mesh) - ufl.as_vector(ref)
    a_frame = a0 + ufl.cross(dom, r) + ufl.cross(om, ufl.cross(om, r))
    a_cor = 2 * ufl.cross(om, (u - u_prev) * inv_dt)
    # Inertia relief: part 1 is quasi-static, so its transferred loads balance the springs
    # without the inertia of the rigid motion; the resultant of the frame inertia (force and
    # moment) has nothing to balance it and would only drive a rigid motion of the floating
    # frame on the soft suspension. A rigid acceleration field a + alpha x r that cancels it is
    # added: the scapula is loaded by the self-equilibrated part of its inertia.
    a_relief = relief_a + ufl.cross(relief_alpha, r)
    F = vp.internal_power_linear(bone, u, w, dx)
    F += ufl.inner(rho * (a_frame + a_relief + a_cor), w) * dx
    inertia_forms = [dolfinx.fem.form(rho * a_frame[i] * dx) for i in range(3)]
    inertia_forms += [dolfinx.fem.form(rho * ufl.cross(r, a_frame)[i] * dx) for i in range(3)]
    coriolis_forms = [dolfinx.fem.form(rho * a_cor[i] * dx) for i in range(3)]

    def integral(expr) -> float:
        return comm.allreduce(dolfinx.fem.assemble_scalar(dolfinx.fem.form(expr * dx)), op=MPI.SUM)

    mass = integral(rho)
    first = np.array([integral(rho * r[i]) for i in range(3)])
    second = np.array([[integral(rho * r[i] * r[j]) for j in range(3)] for i in range(3)])
    # [m I, -hat(S); hat(S), J] (a, alpha) = -(F, M), J = tr(R2) I - R2 about ref
    relief_matrix = np.block(
        [
            [mass * np.eye(3), -hat(first)],
            [hat(first), np.trace(second) * np.eye(3) - second],
        ]
    )
    loads = NodalLoads(V, points)
    # The springs linearised about the recorded pose: their force there (floating-frame
    # components) is applied to their plate, their stiffness is that of the reference pose
    # (the ground end fixed in the floating frame). The floating-frame displacements are
    # microns, so the change of the springs' directions over them is negligible, and the
    # stiffness -- hence the factorization -- is the same at every angle.
    bodies, ties, springs, world = [], [], [], []
    for sp in layout:
        if sp["bone"] != "scapula":
            continue
        c = patch_centroid(mesh, ft, S.MARKERS[sp["name"]].id)
        bodies.append(RigidBody(sp["name"], c))
        ties.append(Tie(sp["name"], sp["name"]))
        end = c + v["spring_length"] * sp["direction"]
        springs.append(Spring(sp["name"], sp["name"], c, GROUND, end, sp["stiffness"]))
        world.append(Spring(sp["name"], "scapula", c, GROUND, end, sp["stiffness"]))
    lag = {
        "snes_lag_jacobian": -2,
        "snes_lag_jacobian_persists": True,
        "snes_lag_preconditioner": -2,
        "snes_lag_preconditioner_persists": True,
        # chord iterations converge linearly (rate ~0.15) to a round-off floor of ~3e-10 N
        "snes_rtol": 1e-8,
        "snes_atol": 1e-8,
        "snes_max_it": 50,
    }
    system = RigidSystem(
        bodies,
        springs,
        u=u,
        residual=F,
        surfaces=_surfaces(ft, [t.surface for t in ties]),
        ties=ties,
        name="shoulder_part2",
        options=lag | dict(options or {}),
        form_compiler_params=_quadrature(v),
        contact=loads,
        linear_ties=True,
    )
    stress_vm = VonMises(mesh, ct_, bone.stress(ufl.sym(ufl.grad(u))))
    angles = np.asarray(transfer["angles"])
    times = angles / v["final_angle"] * v["rotation_duration"]
    T = np.asarray(transfer["translation"])
    R = np.asarray(transfer["rotation"])
    vel, acc, omega, domega = _finite_differences(times, T, R)
    writer = dolfinx.io.XDMFFile(comm, str(fields_dir / "part2.xdmf"), "w")
    writer.write_mesh(mesh)
    P1 = dolfinx.fem.VectorFunctionSpace(mesh, ("Lagrange", 1))
    u1 = dolfinx.fem.Function(P1, name="displacement")
    iterations = 0
    worst = 0.0
    for k, target in enumerate(angles):
        x = math.degrees(target)
        Rk, tk = R[k], T[k]
        f = np.asarray(transfer["forces"][k])
        loads.forces[:] = f @ Rk  # R^T f per row: floating-frame components
        centre = ref + tk
        fs, ms = f.sum(axis=0), np.cross(points - ref, f @ Rk).sum(axis=0)
        ms = Rk @ ms
        for body, sp in zip(bodies, world, strict=True):
            pa = centre + Rk @ (np.asarray(sp.point_a) - ref)
            g = spring_response(sp, pa, np.asarray(sp.point_b)).gradient
            body.force = -Rk.T @ g
            fs, ms = fs - g, ms + np.cross(pa - centre, -g)
        a0.value[:] = Rk.T @ acc[k]
        om.value[:] = omega[k]
        dom.value[:] = domega[k]
        inv_dt.value = 1.0 / (times[k] - times[k - 1]) if k > 0 else 0.0
        resultant = np.array(
            [comm.allreduce(dolfinx.fem.assemble_scalar(g), op=MPI.SUM) for g in inertia_forms]
        )
        relief = np.linalg.solve(relief_matrix, -resultant)
        relief_a.value[:], relief_alpha.value[:] = relief[:3], relief[3:]
        iterations += system.solve(step=f"part2 {x:.0f} deg")
        # equilibrium of the transferred loads with the springs at the recorded rigid pose
        scale = float(np.abs(f).sum()) or 1.0
        lever = float(np.linalg.norm(points - ref, axis=1).max())
        resid = max(float(np.linalg.norm(fs)) / scale, float(np.linalg.norm(ms)) / (scale * lever))
        worst = max(worst, resid)
        recorder.add_series_point("transfer_equilibrium_residual", x, resid, "deg", "1")
        coriolis = np.array(
            [comm.allreduce(dolfinx.fem.assemble_scalar(g), op=MPI.SUM) for g in coriolis_forms]
        )
        recorder.add_series_point(
            "part2_inertia_force", x, float(np.linalg.norm(resultant[:3])), "deg", "N"
        )
        recorder.add_series_point(
            "part2_inertia_moment", x, float(np.linalg.norm(resultant[3:])), "deg", "N m"
        )
        recorder.add_series_point(
            "part2_coriolis_force", x, float(np.linalg.norm(coriolis)), "deg", "N"
        )
        recorder.add_series_point(
            "part2_transferred_force", x, float(np.linalg.norm(f, axis=1).sum()), "deg", "N"
        )
        _record_von_mises(recorder, stress_vm, x, data, comm)
        u1.interpolate(u)
        writer.write_function(u1, x)
        u_prev.x.array[:] = u.x.array
    writer.close()
    recorder.set_probe("transfer_equilibrium_residual", worst, "1")
    recorder.set_probe("part2_factorizations", system.stats.factorizations, "1")
    recorder.set_probe("part2_iterations", iterations, "1")
    recorder.add_solver_counts(system.stats, StepperStats(steps=len(angles)))
    recorder.extra("dofs_part2", V.dofmap.index_map.size_global * 3)
    system.destroy()
    return stress_vm, mesh, ft
