"""shoulder-fem: large motions with small strains, solved coupled and decoupled.

The API for drivers::

    from shoulder_fem import load_scene, run
    scene = load_scene("spinning-bar").with_values(spin_rate=50.0)
    result = run(scene, "decoupled", level="coarse", out="out/bar")
    print(result.probes["root_axial_stress"])
"""

__version__ = "0.1.0"

from .api import Result, RunFailed, run  # noqa: E402
from .scene import Scene, SceneError, available_scenes, load_scene  # noqa: E402

__all__ = ["Result", "RunFailed", "Scene", "SceneError", "available_scenes", "load_scene", "run"]
