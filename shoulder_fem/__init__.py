"""shoulder-fem: large motions with small strains, solved coupled and decoupled.

The API for drivers::

    from shoulder_fem import load_scene, run
    scene = load_scene("spinning-bar").with_values(spin_rate=50.0)
    result = run(scene, "decoupled", level="coarse", out="out/bar")
    print(result.probes["root_axial_stress"])
"""

import os

# One thread per MPI rank: OpenBLAS/OpenMP threads on top of MPI ranks slow MUMPS down here.
# Read by OpenBLAS when it loads, so this only helps when shoulder_fem is imported first.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

__version__ = "0.1.0"

from .api import Result, RunFailed, run  # noqa: E402
from .scene import Scene, SceneError, available_scenes, load_scene  # noqa: E402

__all__ = ["Result", "RunFailed", "Scene", "SceneError", "available_scenes", "load_scene", "run"]
