"""Sweeps over the scapula's material from one part 1 (``shoulder-fem sweep``, :func:`api.sweep`).

Every variant is a decoupled run whose part 1 is the recorded one of ``--from``
(:mod:`.reuse`): one part 2 each (one assembly, one factorization, a few solves per output
angle). Only :data:`~.reuse.PART2_KEYS` may be swept; every variant is built and checked
before the first is solved. Writes one run folder per variant and ``sweep.json`` +
``sweep.png``: the scapula's largest nodal von Mises stress, over the whole bone and within
:data:`~.report.metrics.GLENOID_REGION` of the glenoid's centre, at every output angle,
against the swept values.
"""

from __future__ import annotations

import itertools
import logging
from pathlib import Path

import numpy as np

from shoulder_fem.families.shoulder.report.metrics import GLENOID_REGION
from shoulder_fem.families.shoulder.reuse import PART2_KEYS, check_source, read_source
from shoulder_fem.scene import Scene, SceneError

__all__ = ["glenoid_von_mises", "plan", "variant_row", "write_sweep"]

logger = logging.getLogger(__name__)


def plan(scene: Scene, source: Path, settings: list[str]) -> tuple[Scene, str, list[list[str]]]:
    """The recorded run's scene and level, and every variant's ``key=value`` list (checked).

    Nothing is solved: the scene holds the recorded run's values, each variant is a list of
    ``--set`` assignments on it.

    ``settings``: ``key=v1,v2,...`` each; the variants are all their combinations.

    Raises:
        SceneError: A bad ``--from``, a key part 1 depends on, an unknown key, a bad value.
    """
    recorded = read_source(source)
    level = recorded["level"]
    base = scene.with_values(f"--from {source}", **recorded_values(scene, recorded))
    check_source(base, level, recorded, f"--from {source}")
    axes = []
    for text in settings:
        key, sep, raw = text.partition("=")
        key = key.strip()
        if not sep or not key or not raw.strip():
            raise SceneError(f"--set {text}: expected key=value[,value...]")
        if key not in scene.parameters:
            base.with_overrides([text])  # the scene's own message for an unknown key
        if key not in PART2_KEYS:
            raise SceneError(
                f"--set {text}: part 1 depends on {key}, so a sweep cannot reuse it; study "
                f"it with a whole run per value (shoulder-fem study {scene.name} --set "
                f"{text}). A sweep takes {', '.join(PART2_KEYS)}"
            )
        axes.append([f"{key}={v.strip()}" for v in raw.split(",")])
    if not axes:
        raise SceneError("sweep: no --set key=v1,v2,... given")
    swept = {a[0].partition("=")[0] for a in axes}
    if swept & {"ct_density_intercept", "ct_density_slope"} and not base["ct_image"]:
        logger.warning(
            "sweep: the run's bones use the built-in phantom, whose HU values are made with "
            "the scene's own calibration: a calibration sweep changes nothing there "
            "(set ct_image to a scan)"
        )
    variants = [list(v) for v in itertools.product(*axes)]
    for v in variants:
        base.with_overrides(v)  # every value checked before anything is solved
    return base, level, variants


def recorded_values(scene: Scene, recorded: dict) -> dict:
    """The recorded run's parameter values that this scene has and that differ from it (SI).

    Only those count as given, so a key the run left at the file's value (a prosthesis key
    of a spherical head) is not taken for a setting of the variants.
    """
    values = recorded.get("parameters", {})
    return {k: v for k, v in values.items() if k in scene.parameters and v != scene[k]}


def write_sweep(data: dict, out: Path) -> None:
    """``sweep.json`` and ``sweep.png`` into ``out`` (rank 0 only)."""
    from shoulder_fem.io.output import atomic_write_json

    atomic_write_json(out / "sweep.json", data)
    _plot(data, out / "sweep.png")


def glenoid_von_mises(folder: Path) -> list[float | None]:
    """A run's largest nodal von Mises stress (MPa) near the glenoid, at every output angle.

    Within :data:`GLENOID_REGION` of the glenoid's centre, from the run's ``shoulder.npz``;
    None where no node lies there.
    """
    with np.load(folder / "shoulder.npz") as res:
        X, series = res["scapula_points"], res["scapula_von_mises_series"]
        near = np.linalg.norm(X - res["glenoid_centre"], axis=1) <= GLENOID_REGION
    return [float(v[near].max()) * 1e-6 if near.any() else None for v in series]


def variant_row(variant: list[str], name: str, result, folder: Path) -> dict:
    """One variant's values, cost and von Mises maxima (MPa) at every output angle."""
    stages = {s["name"]: s for s in result.stages}
    vm = result.series["scapula_max_von_mises"]
    glenoid = glenoid_von_mises(folder)
    return {
        "values": dict(s.split("=", 1) for s in variant),
        "folder": name,
        "status": result.status,
        "cpu_s": result.resources["cpu_s"],
        "part2_cpu_s": stages.get("part2", {}).get("cpu_s"),
        "mesh_cpu_s": stages.get("mesh", {}).get("cpu_s"),
        "angles_deg": list(vm["x"]),
        "von_mises_max_mpa": [v * 1e-6 for v in vm["y"]],
        "glenoid_von_mises_max_mpa": glenoid,
    }


def _plot(data: dict, path: Path) -> None:
    """The von Mises maxima against the variants, one line per output angle."""
    from shoulder_fem.io.plots import plt, save_figure

    rows = data["variants"]
    keys = data["keys"]
    try:  # one numeric key: against its values
        x = [float(r["values"][keys[0]]) for r in rows] if len(keys) == 1 else None
    except ValueError:
        x = None
    ticks = None
    if x is None:
        x = list(range(len(rows)))
        ticks = [", ".join(f"{k}={v}" for k, v in r["values"].items()) for r in rows]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), layout="constrained")
    angles = rows[0]["angles_deg"] if rows else []
    for j, a in enumerate(angles):
        if a == 0:
            continue
        for ax, key in zip(axes, ("von_mises_max_mpa", "glenoid_von_mises_max_mpa"), strict=True):
            y = [r[key][j] if r[key][j] is not None else np.nan for r in rows]
            ax.plot(x, y, "o-", label=f"{a:g} deg")
    radius = data["glenoid_region_radius_m"] * 1e3
    titles = ("scapula: largest nodal von Mises", f"glenoid region ({radius:g} mm)")
    for ax, title in zip(axes, titles, strict=True):
        ax.set(title=title, ylabel="MPa", xlabel=keys[0] if ticks is None else "variant")
        if ticks is not None:
            ax.set_xticks(x, ticks, rotation=30, ha="right", fontsize=7)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7, title="rotation")
    fig.suptitle(f"{data['scene']} ({data['level']}): part 2 from one part 1", fontsize=10)
    save_figure(fig, path)
