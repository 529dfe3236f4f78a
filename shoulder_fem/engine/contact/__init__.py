"""Large-sliding contact between a slave surface and analytic or mesh masters.

Modules: ``masters`` (what a slave presses on: mesh surfaces and rigid masters), ``pair`` (a
pair and its pressure law), ``geometry`` (triangle rules, closest points, clipping),
``surfaces`` (tagged facets, gathered mesh masters), ``points`` (contact points and their
pairing), ``evaluation`` (gaps, pressures, friction), ``jacobian`` (the tangent and its
sparsity), ``segment_tangent`` (the consistent tangent of segment integration), ``output``
(resultants, fields) and ``assembly`` (:class:`Contact`, the driver).
Simplices only (triangular facets of tetrahedra), P1 or P2 displacement.
"""

from shoulder_fem.engine.contact.assembly import Contact, ContactStats, record_resultants
from shoulder_fem.engine.contact.geometry import closest_points_on_triangles
from shoulder_fem.engine.contact.jacobian import add_to_pattern
from shoulder_fem.engine.contact.masters import (
    ContactError,
    MeshSurface,
    Plane,
    RigidMaster,
    Sphere,
)
from shoulder_fem.engine.contact.pair import ContactPair, penalty_law

__all__ = [
    "Contact",
    "ContactError",
    "ContactPair",
    "ContactStats",
    "MeshSurface",
    "Plane",
    "RigidMaster",
    "Sphere",
    "add_to_pattern",
    "closest_points_on_triangles",
    "penalty_law",
    "record_resultants",
]
