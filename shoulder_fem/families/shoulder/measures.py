"""What both methods measure on the joint at an output angle, with the same operators.

The glenoid's nodal contact pressure and shear, the muscles' forces at their scapular
footprints (:class:`Probe`), the scapula's nodal von Mises stress (:class:`VonMises`) and where
the glenoid presses on the humeral cartilage (:func:`cap_contact_angles`). One set of operators
for both methods, so that their outputs compare point for point.
"""

from __future__ import annotations

import math

import dolfinx
import dolfinx.fem.petsc as fem_petsc
import numpy as np
import ufl
from mpi4py import MPI
from petsc4py import PETSc

from shoulder_fem.engine.contact import Contact
from shoulder_fem.engine.mean_dilatation import VolumeChange
from shoulder_fem.engine.stress_recovery import NodalStress
from shoulder_fem.families.shoulder.geometry import cap_angles, gather_rows
from shoulder_fem.families.shoulder.interactions import muscle_forms
from shoulder_fem.families.shoulder.model import ShoulderParameters
from shoulder_fem.meshes import shoulder as S

__all__ = ["REPORTED_MUSCLES", "Probe", "VonMises", "cap_contact_angles"]

REPORTED_MUSCLES = ("subscapularis", "supraspinatus", "infraspinatus")
#: The soft bodies whose volume change is reported.
SOFT_BODIES = (
    S.HUMERAL_CARTILAGE,
    S.GLENOID_CARTILAGE,
    S.SUBSCAPULARIS,
    S.SUPRASPINATUS,
    S.INFRASPINATUS,
)


class Probe:
    """Per-output measurements shared by both methods (collective)."""

    def __init__(
        self,
        u,
        cell_tags,
        facet_tags,
        contact: Contact,
        params: ShoulderParameters,
        volumetric=None,
    ):
        V = u.function_space
        #: The soft tissue's mean-dilatation terms (or None): updated before the muscle forces.
        self.volumetric = volumetric
        mesh = V.mesh
        self.u, self.V, self.mesh, self.contact = u, V, mesh, contact
        self.cell_tags, self.facet_tags = cell_tags, facet_tags
        self.comm = mesh.comm
        dx = ufl.Measure("dx", domain=mesh, subdomain_data=cell_tags, metadata=params.quadrature())
        self._muscle = muscle_forms(u, ufl.TestFunction(V), dx, params, volumetric)
        self._volume = VolumeChange(u, dx, [b.id for b in SOFT_BODIES], params.quadrature())
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
        self.glenoid_points = gather_rows(Q.tabulate_dof_coordinates()[self._glenoid], self.comm)

    def muscle_forces(self) -> dict[str, np.ndarray]:
        """Force (N, vector) each muscle applies to its origin plate or bone footprint."""
        out = {}
        if self.volumetric is not None:
            self.volumetric.update()
        for name, form in self._muscle.items():
            with self._vec.localForm() as loc:
                loc.set(0.0)
            fem_petsc.assemble_vector(self._vec, form)
            self._vec.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
            f = self._vec.array_r.reshape(-1, 3)[self._origin[name]].sum(axis=0)
            out[name] = -self.comm.allreduce(f, op=MPI.SUM)
        return out

    def volume_changes(self) -> dict[str, float]:
        """Relative volume change ∫J dx / |Ω| − 1 of each soft body, by name (collective)."""
        changes = self._volume()
        return {b.name: changes[b.id] for b in SOFT_BODIES}

    def glenoid(self, pressure, shear) -> tuple[np.ndarray, np.ndarray]:
        """Nodal contact pressure and shear (Pa) at the glenoid points (gathered on every rank).

        ``pressure``, ``shear``: the contact's nodal fields (:meth:`Contact.pressure_fields`).
        """
        return (
            gather_rows(pressure.x.array[self._glenoid], self.comm),
            gather_rows(shear.x.array[self._glenoid], self.comm),
        )

    def destroy(self) -> None:
        """Free the PETSc vector."""
        self._vec.destroy()


class VonMises:
    """Nodal stress and von Mises stress (Pa) of the scapula (collective).

    Recovered by ``recipe`` (:class:`~shoulder_fem.engine.stress_recovery.NodalStress`):
    ``"tensor"``, as Abaqus and CalculiX do (the stress tensor extrapolated from the
    integration points to the vertices, averaged there over the scapula's cells, then von
    Mises), or ``"scalar"``, the earlier recipe (each cell's von Mises at its vertices,
    volume-weighted over the cells around a vertex).
    """

    def __init__(self, mesh, cell_tags, stress: ufl.core.expr.Expr, recipe: str = "tensor"):
        self.recovery = NodalStress(mesh, cell_tags.find(S.SCAPULA.id), stress, recipe)
        self.P = self.recovery.P
        self.field = self.recovery.von_mises
        self._p_dofs = self.recovery.cell_dofs
        self._nodes = self.recovery.nodes

    def update(self) -> dolfinx.fem.Function:
        """Evaluate at the current state; returns the P1 field (0 off the scapula)."""
        return self.recovery.update()

    def fields(self) -> tuple[dolfinx.fem.Function, ...]:
        """The nodal fields for ParaView, at the last :meth:`update`.

        ``von_mises`` and, with the tensor recipe, ``stress`` (9 components, Pa; zero off the
        scapula).
        """
        if self.recovery.recipe == "tensor":
            return (self.recovery.tensor, self.field)
        return (self.field,)

    def nodal(self, comm: MPI.Comm) -> tuple[np.ndarray, np.ndarray]:
        """(points m, von Mises Pa) of the scapula vertices, gathered on every rank."""
        X = self.P.tabulate_dof_coordinates()[self._nodes]
        return gather_rows(X, comm), gather_rows(self.field.x.array[self._nodes], comm)

    def cells(self, comm: MPI.Comm) -> tuple[np.ndarray, np.ndarray]:
        """(vertex points, tetrahedra) of the scapula, gathered on every rank.

        Vertices are deduplicated by their global P1 index.
        """
        imap = self.P.dofmap.index_map
        glob = imap.local_to_global(self._p_dofs.ravel().astype(np.int32)).reshape(-1, 4)
        X = self.P.tabulate_dof_coordinates()
        gl = gather_rows(glob, comm)
        xs = gather_rows(X[self._p_dofs.ravel()], comm)
        uniq, inverse = np.unique(gl.ravel(), return_inverse=True)
        points = np.zeros((len(uniq), 3))
        points[inverse] = xs
        return points, inverse.reshape(-1, 4)


def cap_contact_angles(
    contact: Contact, centre: np.ndarray, axis: np.ndarray, comm: MPI.Comm
) -> tuple[float, float]:
    """Where the glenoid presses on the humeral cartilage, in deg from the cartilage's axis.

    Force-weighted mean and largest angle, in the humerus's reference geometry (the cap of
    ``centre`` (m) and unit ``axis``, :func:`geometry.humeral_cap`) (collective).
    """
    X, f = contact.master_points("glenohumeral")
    a = cap_angles(X, centre, axis)
    fa, fs = (
        comm.allreduce(float((f * a).sum()), op=MPI.SUM),
        comm.allreduce(float(f.sum()), op=MPI.SUM),
    )
    top = comm.allreduce(float(a.max(initial=0.0)), op=MPI.MAX)
    return (math.degrees(fa / fs) if fs > 0 else 0.0), math.degrees(top)
