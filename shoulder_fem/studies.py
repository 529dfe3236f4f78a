"""Parameter studies: one whole run per combination of values (``shoulder-fem study``).

Unlike a sweep (part 2 again from one part 1, :mod:`.families.shoulder.sweep`), a study may
vary any key, part 1's included (the soft tissues' constants, the implant's radius): each
variant is a run of its own, in its own folder under the study's, and ``study.json`` lists per
variant its values, status, CPU time, wall time and memory, and its series against the output
angles; ``study.png`` (and ``study.pdf``) plots the chosen outputs of every variant on one
scale per panel. Every variant is checked before the first is solved; a variant that stops
short is recorded as such and the study goes on with the next.
"""

from __future__ import annotations

import itertools
import logging
from pathlib import Path

from shoulder_fem.scene import Scene, SceneError

__all__ = ["PLOTTED", "plan", "row", "write_study"]

logger = logging.getLogger(__name__)

#: The series a study's figure shows when the runs have them (the shoulder's outputs the
#: paper compares); else the first four series of the runs.
PLOTTED = (
    "subscapularis_force",
    "infraspinatus_force",
    "max_pressure",
    "scapula_max_von_mises",
)


def plan(scene: Scene, settings: list[str]) -> list[tuple[list[str], Scene]]:
    """Every combination of ``settings`` (``key=v1,v2,...`` each) with its scene (checked).

    Raises:
        SceneError: A malformed setting, an unknown key, a bad value or a key repeated.
    """
    axes, keys = [], []
    for text in settings:
        key, sep, raw = text.partition("=")
        key = key.strip()
        if not sep or not key or not raw.strip():
            raise SceneError(f"--set {text}: expected key=value[,value...]")
        if key in keys:
            raise SceneError(f"--set {text}: {key} is given twice (list its values in one --set)")
        keys.append(key)
        axes.append([f"{key}={v.strip()}" for v in raw.split(",")])
    if not axes:
        raise SceneError("study: no --set key=v1,v2,... given")
    variants = []
    for values in itertools.product(*axes):
        variant = scene.with_overrides(list(values))
        if scene.family == "shoulder":  # a key without effect in the variant's head shape
            from shoulder_fem.families.shoulder.model import check_effective

            check_effective(variant)
        variants.append((list(values), variant))
    return variants


def row(values: list[str], name: str, summary: dict) -> dict:
    """One variant's values, outcome, cost and series (SI) from its ``summary.json``."""
    res = summary.get("resources", {})
    return {
        "values": dict(v.split("=", 1) for v in values),
        "folder": name,
        "status": summary.get("status"),
        "message": summary.get("message"),
        "cpu_s": res.get("cpu_s"),
        "wall_s": res.get("wall_s"),
        "peak_rss_mb": res.get("peak_rss_mb"),
        "series": summary.get("series", {}),
    }


def write_study(data: dict, out: Path) -> None:
    """``study.json``, ``study.png`` and ``study.pdf`` into ``out`` (rank 0 only)."""
    from shoulder_fem.io.output import atomic_write_json

    atomic_write_json(out / "study.json", data)
    _plot(data, out / "study.png")


def _plot(data: dict, path: Path) -> None:
    """The plotted series against the angle, one line per variant, one scale per panel.

    Sized for a journal's double column (7 in), a variant that stopped short dashed; the
    points are the output angles, joined by straight lines.
    """
    from shoulder_fem.io.plots import PRINT_STYLE, plt

    rows = data["variants"]
    names = [n for n in PLOTTED if any(n in r["series"] for r in rows)]
    if not names:
        names = sorted({n for r in rows for n in r["series"]})[:4]
    if not names:
        return
    with plt.rc_context(PRINT_STYLE):
        _draw(data, rows, names, path)


def _draw(data: dict, rows: list, names: list, path: Path) -> None:
    from shoulder_fem.io.plots import DISPLAY_UNITS, plt, save_figure

    fig, axes = plt.subplots(1, len(names), figsize=(1.75 * len(names) + 0.5, 2.4))
    axes = [axes] if len(names) == 1 else list(axes)
    short = any(r["status"] != "ok" for r in rows)
    keys = list(rows[0]["values"]) if rows else []
    varied = [k for k in keys if len({r["values"][k] for r in rows}) > 1]
    fixed = [f"{k}={rows[0]['values'][k]}" for k in keys if k not in varied]
    for ax, name in zip(axes, names, strict=True):
        for r in rows:
            s = r["series"].get(name)
            if not s:
                continue
            x_unit, fx = DISPLAY_UNITS.get(s["x_unit"], (s["x_unit"], 1.0))
            y_unit, fy = DISPLAY_UNITS.get(s["y_unit"], (s["y_unit"], 1.0))
            x = [v * fx for v in s["x"]]
            y = [v * fy if v is not None else float("nan") for v in s["y"]]
            label = ", ".join(f"{k}={r['values'][k]}" for k in varied) or r["folder"]
            ok = r["status"] == "ok"
            ax.plot(x, y, "o-" if ok else "o--", ms=2.5, lw=1, label=label + ("" if ok else " *"))
            ax.set_xlabel(f"rotation [{x_unit}]" if x_unit == "deg" else f"[{x_unit}]")
            ax.set_ylabel(f"[{y_unit}]" if y_unit else "[-]")
        ax.set_title(name.replace("_", " "))
        ax.grid(alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(
        handles,
        labels,
        loc="lower center",
        ncol=min(len(labels), 4),
        title="* stopped short" if short else None,
        frameon=False,
    )
    title = f"{data['scene']} ({data['level']}, {data['method']})"
    fig.suptitle(title + (f": {', '.join(fixed)}" if fixed else ""))
    fig.tight_layout(rect=(0, 0.05 + 0.05 * ((len(labels) + 3) // 4), 1, 1))
    save_figure(fig, path, vector=True)
