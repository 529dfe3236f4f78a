"""Curved contact surfaces (engine/contact/curved.py): mid-edge nodes lifted onto the sphere.

On a gmsh ball of radius R (straight-sided tetrahedra, P2 displacement) the mid-edge nodes of
the spherical surface lie up to h^2 / (8 R) inside the sphere; lifted, they lie on it to
O(h^4 / R^3), whether the surface is seen from outside (convex) or from inside (concave, the
facets turned over). A contact pair with ``curved`` sees those positions, the volume mesh does
not. Serial and ``mpirun -n 2`` (the lifts are gathered: every rank lifts its nodes alike).
"""

from __future__ import annotations

import dolfinx
import numpy as np
import pytest
from mpi4py import MPI

from shoulder_fem.engine.contact import Contact, ContactPair, Plane
from shoulder_fem.engine.contact.curved import midside_lifts
from shoulder_fem.engine.contact.surfaces import Facets, surface_facets
from shoulder_fem.meshes import contact_bodies as cb

pytestmark = pytest.mark.mpi

R, H = 1.0, 0.25


@pytest.fixture(scope="module")
def ball():
    mesh, _, ft = cb.build_hemisphere(MPI.COMM_WORLD, R, H, H, 0.0, quarter=False)
    V = dolfinx.fem.VectorFunctionSpace(mesh, ("Lagrange", 2))
    Q = dolfinx.fem.FunctionSpace(mesh, ("CG", 1))
    facets = surface_facets(V, ft, (cb.CONTACT.id,), Q, "ball")
    imap = V.dofmap.index_map
    l2g = imap.local_to_global(np.arange(imap.size_local + imap.num_ghosts, dtype=np.int32))
    return V, ft, facets, l2g


def _radial_error(X: np.ndarray) -> np.ndarray:
    return np.linalg.norm(X - np.array([0.0, 0.0, R]), axis=1) - R


def _mid_nodes(facets: Facets, l2g):
    mids = facets.nodes[:, 3:].ravel()
    return mids, l2g[mids], facets.X[:, 3:].reshape(-1, 3)


@pytest.mark.parametrize("side", ["convex", "concave"])
def test_lifted_mid_edge_nodes_lie_on_the_sphere(ball, side):
    V, _, facets, l2g = ball
    if side == "concave":  # the same facets seen from inside: turned over (v0 v2 v1 e20 e12 e01)
        turn = [0, 2, 1, 5, 4, 3]
        facets = Facets(facets.nodes[:, turn], facets.X[:, turn], facets.p1, facets.tags)
    lifts = midside_lifts([facets], l2g, MPI.COMM_WORLD)
    _, g, X = _mid_nodes(facets, l2g)
    flat = _radial_error(X)
    lifted = _radial_error(X + np.array([lifts[int(k)] for k in g]))
    # the edges of the boundary facets (gmsh's size ~H: the sagitta h^2/(8R) is ~0.008)
    e = np.linalg.norm(facets.X[:, 1] - facets.X[:, 0], axis=1)
    worst_flat = MPI.COMM_WORLD.allreduce(float(-flat.min(initial=0.0)), op=MPI.MAX)
    worst_lifted = MPI.COMM_WORLD.allreduce(float(np.abs(lifted).max(initial=0.0)), op=MPI.MAX)
    h = MPI.COMM_WORLD.allreduce(float(e.max(initial=0.0)), op=MPI.MAX)
    assert np.all(flat <= 1e-12)  # chords lie inside the sphere
    assert worst_flat == pytest.approx(h**2 / (8 * R), rel=0.5)
    # Max's vertex normals are exact for vertices on a sphere (the rim's reflected in from
    # their inner neighbours): what is left is the O(h^4) of the lift's first-order formula
    # (measured 8.2e-5 against 1.3e-2 flat; 3.1e-3 with area-weighted normals, 3.9e-5 at the
    # rim's edges once its normals were reflected in)
    assert worst_lifted < 0.02 * worst_flat
    assert worst_lifted < h**4 / R**3


def test_only_a_curved_pair_sees_the_lifted_nodes(ball):
    V, ft, facets, l2g = ball
    u = dolfinx.fem.Function(V)
    plane = Plane((0.0, 0.0, 0.0), (0.0, 0.0, 1.0))
    flat = Contact(V, u, ft, [ContactPair("c", (cb.CONTACT.id,), plane, 1e9)])
    curved = Contact(V, u, ft, [ContactPair("c", (cb.CONTACT.id,), plane, 1e9, curved=True)])
    assert flat.lifted == 0
    g_mid = np.unique(np.concatenate(MPI.COMM_WORLD.allgather(l2g[facets.nodes[:, 3:]].ravel())))
    assert curved.lifted == len(g_mid)
    moved = np.linalg.norm(curved._X - flat._X, axis=1)
    # this rank's mid-edge nodes, also those of facets held by another rank (ghosts)
    mids = np.flatnonzero(np.isin(l2g, g_mid))
    others = np.setdiff1d(np.arange(len(moved)), mids)
    assert np.all(moved[others] == 0.0)  # vertices and interior nodes stay
    assert np.all(np.abs(_radial_error(curved._X[mids])) < 0.02 * H**2 / (8 * R))
    # the mesh itself is untouched
    assert np.array_equal(flat._X, V.tabulate_dof_coordinates())
