"""Benchmark: what a sweep over the scapula costs against its part 1 (issue 21, item 1).

    OMP_NUM_THREADS=1 python benchmarks/sweep_cost.py --level paper --out benchmarks/results

Runs the decoupled method once (0-60 deg; or takes ``--from RUN``, a finished decoupled run),
then ``api.sweep`` over ``--set`` (default ``scapula_modulus_factor=0.5,1,2``): one part 2 per
value on the recorded part 1. Per variant: total CPU, part 2's CPU, the mesh stage's (every
variant reads the run's scapula, ``scapula_mesh.xdmf``; a run written before it kept one has
its joint meshed again by the first variant), part 2 as a fraction of part 1's CPU, and the
scapula's largest nodal von Mises stress at the last angle, over the bone and within 20 mm of the
glenoid's centre; with the run's own value, the largest difference of its nodal von Mises
stress from the run's own part 2 (relative to the maximum). Targets (issue 21): at ``paper``
each variant <= 5 CPU s and <= 2 % of part 1's CPU. Writes ``sweep_cost_<level>.json`` and
``.png``. Every figure is measured; it asserts nothing.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import matplotlib
import numpy as np
from scipy.spatial import cKDTree

from shoulder_fem import load_scene, run
from shoulder_fem.api import sweep
from shoulder_fem.io.output import atomic_write_json
from shoulder_fem.io.plots import plt, save_figure

SCENE = "shoulder-internal-rotation"
TARGET_CPU_S = 5.0
TARGET_FRACTION = 0.02


def _own_value_error(source: Path, variant: Path) -> float:
    """Largest |von Mises| difference of ``variant`` from ``source`` over all output angles,
    relative to the source's maximum (vertices matched by position)."""
    with np.load(source / "shoulder.npz") as a:
        ref, X = a["scapula_von_mises_series"], a["scapula_points"]
    with np.load(variant / "shoulder.npz") as b:
        mine, Y = b["scapula_von_mises_series"], b["scapula_points"]
    _, index = cKDTree(Y).query(X)
    return float(np.abs(mine[:, index] - ref).max() / ref.max())


def _same(recorded, value: str) -> bool:
    """Whether a swept value (text, SI) is the recorded run's (a number or a text)."""
    try:
        return float(recorded) == float(value)
    except (TypeError, ValueError):
        return str(recorded) == value


def measure(level: str, source: Path | None, settings: list[str], work: Path) -> dict:
    """Part 1 once (unless ``source``), then the sweep; the figures of both."""
    if source is None:
        source = work / "decoupled"
        run(load_scene(SCENE), "decoupled", level=level, out=source)
    summary = json.loads((source / "summary.json").read_text())
    stages = {s["name"]: s.get("cpu_s") for s in summary["stages"]}
    part1 = stages.get("part1")
    data = sweep(load_scene(SCENE), source, settings, work / "sweep")
    recorded = summary["parameters"]
    for row in data["variants"]:
        row["part2_fraction_of_part1"] = row["part2_cpu_s"] / part1 if part1 else None
        if all(_same(recorded.get(k), v) for k, v in row["values"].items()):  # its own values
            row["own_value_von_mises_error"] = _own_value_error(
                source, work / "sweep" / row["folder"]
            )
    return {
        "scene": SCENE,
        "level": level,
        "source": str(source),
        "settings": settings,
        "part1_cpu_s": part1,
        "decoupled_cpu_s": summary["resources"]["cpu_s"],
        "decoupled_part2_cpu_s": stages.get("part2"),
        "targets": {"variant_cpu_s": TARGET_CPU_S, "part2_fraction_of_part1": TARGET_FRACTION},
        "sweep": data,
    }


def plot(data: dict, path: Path) -> None:
    """CPU per variant (meshing, part 2, the rest) against the targets."""
    rows = data["sweep"]["variants"]
    labels = [", ".join(f"{k}={v}" for k, v in r["values"].items()) for r in rows]
    x = np.arange(len(rows))
    mesh = np.array([r.get("mesh_cpu_s") or 0.0 for r in rows])
    part2 = np.array([r.get("part2_cpu_s") or 0.0 for r in rows])
    rest = np.array([r["cpu_s"] for r in rows]) - mesh - part2
    fig, ax = plt.subplots(figsize=(7.5, 4.2), layout="constrained")
    ax.bar(
        x,
        mesh,
        color="0.7",
        label="mesh stage (reading the run's scapula, scapula_mesh.xdmf)",
    )
    ax.bar(x, part2, bottom=mesh, color="C2", label="part 2")
    ax.bar(x, rest, bottom=mesh + part2, color="C0", label="the rest (reading part 1, output)")
    ax.axhline(data["targets"]["variant_cpu_s"], color="C3", ls="--", label="target: 5 CPU s")
    if data["part1_cpu_s"]:
        two = TARGET_FRACTION * data["part1_cpu_s"]
        ax.axhline(two, color="C1", ls=":", label=f"2 % of part 1 ({data['part1_cpu_s']:.1f} s)")
    ax.set_xticks(x, labels, fontsize=8)
    ax.set(ylabel="CPU s")
    ax.set_title(
        f"{data['scene']} ({data['level']}): one part 2 per variant from one part 1", fontsize=9
    )
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3, axis="y")
    save_figure(fig, path)


def main() -> None:
    matplotlib.use("Agg")
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--level", default="paper")
    ap.add_argument("--from", dest="source", type=Path, help="a finished decoupled run")
    ap.add_argument("--set", dest="sets", action="append", help="KEY=V1,V2,... (repeatable)")
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results"))
    args = ap.parse_args()
    settings = args.sets or ["scapula_modulus_factor=0.5,1,2"]
    with tempfile.TemporaryDirectory(prefix="sweep-cost-") as tmp:
        data = measure(args.level, args.source, settings, Path(tmp))
    args.out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(args.out / f"sweep_cost_{args.level}.json", data)
    plot(data, args.out / f"sweep_cost_{args.level}.png")


if __name__ == "__main__":
    main()
