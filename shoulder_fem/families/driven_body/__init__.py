"""The ``driven-body`` family: a body clamped to a hub whose rotation is prescribed."""

from shoulder_fem.families.base import Family
from shoulder_fem.families.driven_body import coupled, decoupled
from shoulder_fem.families.driven_body.model import DrivenBody, build, dofs

__all__ = ["FAMILY", "DrivenBody"]

FAMILY = Family(
    name="driven-body",
    build=build,
    methods={"coupled": coupled.run_coupled, "decoupled": decoupled.run_decoupled},
    dofs=dofs,
)
