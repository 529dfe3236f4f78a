"""The tag table type shared by every mesh builder."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Marker:
    """A named tag (physical group): the single source of tag numbers.

    Attributes:
        name: the name used in scene files and outputs.
        id: the tag number in the mesh tags.
        dim: topological dimension of the tagged entities (3 cells, 2 facets, ...).
    """

    name: str
    id: int
    dim: int
