"""How much of the glenohumeral joint's normal approach the contact penalty takes.

Under a contact pressure p the two bones approach by the compression of the two cartilage
layers plus the penalty's own overlap p / eps. The penalty's share of that approach,
pressure-weighted over the glenoid's nodes in contact,

    share = sum p (p / eps) / sum p (p / eps + c_glenoid + c_humeral),

says how far the penalty, not the cartilage, sets the pressure (issue 20, item 3: at most
10 %). A layer's compression c at an articular node is the shortening of the segment from that
node to the point of the layer's bonded face straight below it (the humeral layer's at the
humeral articular node nearest to the glenoid node's current position); a rigid motion of the
layer does not change it.

That nodal measure is noisy where a patch is a few elements wide (a loaded node whose layer
bulges reads a thickening). :class:`EnergyShare` measures the same split globally: in springs in
series under one load each stores energy in proportion to its compliance, so the penalty's
share of the joint's normal compliance is its stored energy 1/2 int p (-g) dA
(:func:`~shoulder_fem.engine.contact.output.pair_resultants`) over that plus the two cartilage
layers' strain energy int W dV.
"""

from __future__ import annotations

import dolfinx
import numpy as np
import ufl
from dolfinx.cpp.mesh import entities_to_geometry as _entities_to_geometry
from scipy.spatial import cKDTree

from shoulder_fem.engine.contact.geometry import closest_points_on_triangles
from shoulder_fem.families.shoulder.geometry import gather_rows
from shoulder_fem.families.shoulder.interactions import mixed_law, soft_tissue_laws
from shoulder_fem.forms.kinematics import deformation_gradient, right_cauchy_green
from shoulder_fem.meshes import shoulder as S

__all__ = ["EnergyShare", "PenaltyShare"]

#: Bonded-face triangles tested per articular node (the nearest centroids).
CANDIDATES = 12


class _Layer:
    """The articular nodes of one cartilage layer, each with its foot on the bonded face.

    The foot is the closest point of the bonded face (its facets' flat triangles, gathered) to
    the articular node in the reference configuration: for a layer of constant thickness, the
    point straight below it. Its displacement is interpolated linearly on that triangle.
    """

    def __init__(self, u: dolfinx.fem.Function, facet_tags, articular: str, bonded: str):
        V = u.function_space
        mesh = V.mesh
        self.u, self.comm = u, mesh.comm
        n_owned = V.dofmap.index_map.size_local
        X_dofs = V.tabulate_dof_coordinates()
        d = dolfinx.fem.locate_dofs_topological(V, 2, facet_tags.find(S.MARKERS[articular].id))
        self.articular = d[d < n_owned]
        self.X_a = gather_rows(X_dofs[self.articular], self.comm)
        # the bonded face's facets (interior: cartilage on one side, bone on the other)
        mesh.topology.create_connectivity(2, 0)
        faces = facet_tags.find(S.MARKERS[bonded].id)
        faces = faces[faces < mesh.topology.index_map(2).size_local]
        corners = mesh.geometry.x[
            _entities_to_geometry(mesh._mesh, 2, faces.astype(np.int32), False)
        ]
        corners = corners.reshape(-1, 3, 3)
        nodes = dolfinx.fem.locate_dofs_topological(V, 2, faces)
        self.corner_dofs = (
            nodes[cKDTree(X_dofs[nodes]).query(corners.reshape(-1, 3))[1]].reshape(-1, 3)
            if len(nodes)
            else np.zeros((0, 3), dtype=np.int32)
        )
        tri = gather_rows(corners, self.comm)  # (nt, 3, 3)
        near = cKDTree(tri.mean(axis=1)).query(self.X_a, k=min(CANDIDATES, len(tri)))[1]
        near = near.reshape(len(self.X_a), -1)
        q, bary, dist2, _ = closest_points_on_triangles(
            self.X_a[:, None, :], tri[near, 0], tri[near, 1], tri[near, 2]
        )
        best = np.argmin(dist2, axis=1)
        rows = np.arange(len(self.X_a))
        self.tri = near[rows, best]  # (n,) gathered bonded triangle of each articular node
        self.bary = bary[rows, best]  # (n, 3)
        self.X_foot = q[rows, best]

    def compression(self) -> tuple[np.ndarray, np.ndarray]:
        """(current articular positions (m), compression (m) at each articular node)."""
        u = self.u.x.array.reshape(-1, 3)
        x_a = self.X_a + gather_rows(u[self.articular], self.comm)
        u_face = gather_rows(u[self.corner_dofs], self.comm)  # (nt, 3, 3)
        x_foot = self.X_foot + np.einsum("nk,nki->ni", self.bary, u_face[self.tri])
        before = np.linalg.norm(self.X_a - self.X_foot, axis=1)
        return x_a, before - np.linalg.norm(x_a - x_foot, axis=1)


class PenaltyShare:
    """The penalty's share of the joint's normal approach (module docstring; collective).

    Args:
        u: The displacement (P2; the cartilage layers' nodes, also those tied to a rigid bone).
        facet_tags: The mesh's facet tags (:data:`meshes.shoulder.MARKERS`).
        penalty: The glenohumeral penalty eps (Pa/m).
    """

    def __init__(self, u: dolfinx.fem.Function, facet_tags, penalty: float):
        self.penalty = penalty
        self.glenoid = _Layer(u, facet_tags, "glenoid_articular", "glenoid_cartilage_bone")
        self.humeral = _Layer(u, facet_tags, "humeral_articular", "humeral_cartilage_bone")
        #: the glenoid's articular nodes in the reference geometry, to find its pressure nodes
        self._glenoid_nodes = cKDTree(self.glenoid.X_a)

    def __call__(self, points: np.ndarray, pressure: np.ndarray) -> dict[str, float]:
        """The share at nodal ``pressure`` (Pa) on the glenoid ``points`` (m, reference).

        Returns ``share`` and, pressure-weighted, the penalty's overlap and the two layers'
        compressions (m). All zero without pressure.
        """
        x_g, c_g = self.glenoid.compression()
        x_h, c_h = self.humeral.compression()
        on = np.flatnonzero(pressure > 0)
        zero = {"share": 0.0, "overlap": 0.0, "glenoid_layer": 0.0, "humeral_layer": 0.0}
        if len(on) == 0 or len(x_g) == 0 or len(x_h) == 0:
            return zero
        # the glenoid's pressure nodes (P1) among its articular nodes (P2), by position
        g = self._glenoid_nodes.query(points[on])[1]
        h = cKDTree(x_h).query(x_g[g])[1]
        p = pressure[on]
        w = p / p.sum()
        overlap = float(w @ (p / self.penalty))
        layers = float(w @ c_g[g]), float(w @ c_h[h])
        approach = overlap + sum(layers)
        share = overlap / approach if approach > 0 else 0.0
        return {
            "share": share,
            "overlap": overlap,
            "glenoid_layer": layers[0],
            "humeral_layer": layers[1],
        }


class EnergyShare:
    """The penalty's share of the joint's normal compliance, by stored energy (collective).

    Args:
        u: The displacement (P2).
        cell_tags: The mesh's cell tags (the two cartilage layers: :data:`meshes.shoulder`).
        law: The energy counted in the cartilage (for an incompressible cartilage its
            pointwise part, :func:`mixed_law`: the volumetric energy vanishes with the volume
            change).
        quadrature: Form-compiler parameters of the volume forms.
    """

    def __init__(self, u: dolfinx.fem.Function, cell_tags, law, quadrature):
        mesh = u.function_space.mesh
        self.comm = mesh.comm
        dx = ufl.Measure("dx", domain=mesh, subdomain_data=cell_tags, metadata=quadrature)
        W = law.strain_energy(right_cauchy_green(deformation_gradient(u)))
        ids = (S.HUMERAL_CARTILAGE.id, S.GLENOID_CARTILAGE.id)
        self.form = dolfinx.fem.form(W * dx(ids), form_compiler_params=quadrature)

    @classmethod
    def of_model(cls, u: dolfinx.fem.Function, cell_tags, params) -> EnergyShare:
        """The share for the shoulder's cartilage law (``ShoulderParameters`` ``params``)."""
        law = soft_tissue_laws(params, u.function_space.mesh)[0]
        if params.incompressible_cartilage:
            law = mixed_law(law, params)
        return cls(u, cell_tags, law, params.quadrature())

    def cartilage_energy(self) -> float:
        """The two cartilage layers' strain energy (J)."""
        local = dolfinx.fem.assemble_scalar(self.form)
        return float(self.comm.allreduce(local))

    def __call__(self, penalty_energy: float) -> dict[str, float]:
        """``share`` = penalty / (penalty + cartilage) energy, and both energies (J)."""
        layers = self.cartilage_energy()
        total = penalty_energy + layers
        share = penalty_energy / total if total > 0 else 0.0
        return {"share": share, "penalty_energy": penalty_energy, "cartilage_energy": layers}
