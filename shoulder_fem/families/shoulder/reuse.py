"""Part 2 again from a finished decoupled run's part 1 (the sweeps over the bone).

Part 1 takes the bones as rigid: a change of the scapula's material or density, of the stress
recovery or of part 2's solver leaves it as it was. Such a change is one more part 2 from the
recorded transfer (``transfer.npz``: the loads on the scapula and its rigid motion at every
output angle) and the glenoid's contact outputs (``shoulder.npz``), without solving part 1
again. :data:`PART2_KEYS` are the scene keys that may differ from the recorded run; a change of
any other key (geometry, contact, soft tissue, supports, stepping) changes part 1 and is
refused, with what to run instead.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from shoulder_fem.families.shoulder.geometry import patch_centroid
from shoulder_fem.families.shoulder.model import ShoulderModel
from shoulder_fem.meshes import shoulder as S
from shoulder_fem.scene import Scene, SceneError

__all__ = ["PART2_KEYS", "check_source", "load_part1", "read_source"]

#: The scene keys part 1 does not depend on (its bones are rigid): the scapula's stiffness
#: factor and CT calibration and image (its density and modulus), the rotation's duration (the
#: frame inertia of part 2 only), the nodal-stress recipe and the linear solvers of part 2 and of
#: the coupled method.
PART2_KEYS = (
    "scapula_modulus_factor",
    "ct_image",
    "ct_density_intercept",
    "ct_density_slope",
    "rotation_duration",
    "nodal_stress",
    "part2_solver",
    "coupled_solver",
)


def read_source(folder: str | Path) -> dict:
    """The ``summary.json`` of a finished decoupled run in ``folder`` (checked).

    Raises:
        SceneError: No such run, not a decoupled run, not finished, or without its transfer.
    """
    folder = Path(folder)
    summary = folder / "summary.json"
    if not summary.is_file():
        raise SceneError(f"--from {folder}: no summary.json there (not a run's output folder)")
    data = json.loads(summary.read_text())
    where = f"--from {folder}"
    if data.get("method") != "decoupled":
        method = data.get("method")
        raise SceneError(f"{where}: a {method!r} run; part 1 comes from a decoupled one")
    if data.get("status") != "ok":
        raise SceneError(
            f"{where}: its status is {data.get('status')!r} ({data.get('message')}); part 2 "
            "needs every output angle of a finished part 1"
        )
    for name in ("transfer.npz", "shoulder.npz"):
        if not (folder / name).is_file():
            raise SceneError(f"{where}: {name} is missing (written by part 1 of a decoupled run)")
    return data


def check_source(scene: Scene, level: str, source: dict, where: str) -> None:
    """Refuse a part 2 from ``source`` (:func:`read_source`) that part 1 would not give.

    Raises:
        SceneError: Another scene or level, or a key outside :data:`PART2_KEYS` with another
            value than the recorded run's (named, with what to run instead).
    """
    if source.get("scene") != scene.name:
        raise SceneError(f"{where}: a run of scene {source.get('scene')!r}, not {scene.name!r}")
    if source.get("level") != level:
        raise SceneError(f"{where}: a run at level {source.get('level')!r}, not {level!r}")
    # runs made before part1_bones and the soft-tissue constants were keys had the paper's
    # rigid part 1 and Table I's constants
    before = {"part1_bones": "rigid", "cartilage_c10": 1.79e6, "muscle_alpha": 0.12e6}
    recorded = before | {"muscle_beta": 1.0} | source.get("parameters", {})
    if recorded["part1_bones"] != "rigid":
        raise SceneError(
            f"{where}: its part 1 is part1_bones = {recorded['part1_bones']!r}, which depends "
            "on the bones' stiffness (it was corrected by that run's part 2): its loads do "
            "not hold for another bone. Sweep from a run with part1_bones = rigid"
        )
    changed = [
        key
        for key, value in scene.values().items()
        if key not in PART2_KEYS and not _same(recorded.get(key), value)
    ]
    if changed:
        values = scene.values()
        listed = ", ".join(f"{k} = {values[k]!r} (run: {recorded.get(k)!r})" for k in changed)
        raise SceneError(
            f"{where}: {listed}: part 1 depends on {'it' if len(changed) == 1 else 'them'}, so "
            "its recorded loads do not hold; run the decoupled method with the new value(s) "
            f"(shoulder-fem run {scene.name} --method decoupled --set ...). Only "
            f"{', '.join(PART2_KEYS)} may differ"
        )


def _same(a, b) -> bool:
    if isinstance(a, int | float) and isinstance(b, int | float):
        return math.isclose(float(a), float(b), rel_tol=1e-12, abs_tol=0.0)
    return a == b


def load_part1(model: ShoulderModel, folder: Path) -> tuple[dict, dict]:
    """Part 1's outputs and transfer from the run in ``folder``, for this model's part 2.

    ``folder`` is the run's ``part1_from``, which :func:`shoulder_fem.api.run` has checked
    (:func:`read_source`, :func:`check_source`) before anything was written.

    Returns:
        (the stepping's outputs that part 2 and ``shoulder.npz`` use, the fields of the
        :class:`~shoulder_fem.families.shoulder.decoupled.Transfer`).
    """
    with np.load(folder / "transfer.npz") as tr:
        if "reference" in tr:  # part 1's reference point of the scapula, as it computed it
            ref = np.asarray(tr["reference"])
        else:  # a run written before transfer.npz kept it: from part 1's mesh
            sm = model.meshes["rigid-bone"]
            ref = patch_centroid(sm.mesh, sm.facet_tags, S.MARKERS["glenoid_cartilage_bone"].id)
        transfer = {
            "reference": ref,
            "points": tr["points"],
            "angles": list(tr["angles_rad"]),
            "forces": list(tr["forces"]),
            "translation": list(tr["translation"]),
            "rotation": list(tr["rotation"]),
        }
    with np.load(folder / "shoulder.npz") as res:
        data = {
            "angles_deg": list(res["angles_deg"]),
            "glenoid_points": res["glenoid_points"],
            "glenoid_pressure": list(res["glenoid_pressure"]),
            "glenoid_shear": list(res["glenoid_shear"]),
            "final_angle_deg": float(res["final_angle_deg"]),
        }
    return data, transfer
