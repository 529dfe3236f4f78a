"""Large-sliding contact between a slave surface and analytic or mesh masters."""

from shoulder_fem.engine.contact.assembly import (
    Contact,
    ContactError,
    ContactPair,
    ContactStats,
    MeshSurface,
    Plane,
    Sphere,
    add_to_pattern,
    closest_points_on_triangles,
    penalty_law,
)

__all__ = [
    "Contact",
    "ContactError",
    "ContactPair",
    "ContactStats",
    "MeshSurface",
    "Plane",
    "Sphere",
    "add_to_pattern",
    "closest_points_on_triangles",
    "penalty_law",
]
