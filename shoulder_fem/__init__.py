"""shoulder-fem: large motions with small strains, solved coupled and decoupled.

The API for drivers::

    from shoulder_fem import load_scene, run
    scene = load_scene("spinning-bar").with_values(spin_rate=50.0)
    result = run(scene, "decoupled", level="coarse", out="out/bar")
    print(result.probes["root_axial_stress"])

Importing the package has no side effects: the names below load their modules (and MPI,
PETSc) on first use.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

__version__ = "0.1.0"

_EXPORTS = {
    "Result": "shoulder_fem.api",
    "RunFailed": "shoulder_fem.api",
    "run": "shoulder_fem.api",
    "study": "shoulder_fem.api",
    "sweep": "shoulder_fem.api",
    "Scene": "shoulder_fem.scene",
    "SceneError": "shoulder_fem.scene",
    "available_scenes": "shoulder_fem.scene",
    "load_scene": "shoulder_fem.scene",
}

__all__ = [
    "Result",
    "RunFailed",
    "Scene",
    "SceneError",
    "available_scenes",
    "load_scene",
    "run",
    "study",
    "sweep",
]

if TYPE_CHECKING:
    from shoulder_fem.api import Result, RunFailed, run, study, sweep
    from shoulder_fem.scene import Scene, SceneError, available_scenes, load_scene


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'shoulder_fem' has no attribute {name!r}")
