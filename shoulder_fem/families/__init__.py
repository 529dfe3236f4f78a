"""Scene families, one registry: a scene file's ``family`` names the module that runs it.

Each family module defines ``FAMILY`` (a :class:`~shoulder_fem.families.base.Family`); it is
imported only when a scene of that family is run.
"""

from __future__ import annotations

import importlib

from shoulder_fem.families.base import Family

__all__ = ["FAMILY_MODULES", "family", "family_names"]

FAMILY_MODULES = {
    "driven-body": "shoulder_fem.families.driven_body",
    "tumbling-body": "shoulder_fem.families.tumbling",
    "tied-block": "shoulder_fem.families.tied_block",
    "hertz": "shoulder_fem.families.hertz",
    "shoulder": "shoulder_fem.families.shoulder",
}
"""Family name -> the module holding its ``FAMILY``: the one list of families."""


def family_names() -> list[str]:
    """The known family names."""
    return list(FAMILY_MODULES)


def family(name: str) -> Family:
    """The family called ``name`` (imports its module).

    Raises:
        KeyError: for an unknown name.
    """
    return importlib.import_module(FAMILY_MODULES[name]).FAMILY
