"""Benchmark: how fine the muscles' mesh must be (issue 20, item 9).

    OMP_NUM_THREADS=1 python benchmarks/muscle_mesh.py --level medium \
        --h-muscle 25 16 12 8 6 --out benchmarks/results

The levels refined the joint and the bones but long kept the muscles at 25 mm (they are 8 mm
thick). This runs the shoulder scene at one level with only ``h_muscle`` changed, 0-60 deg,
with the decoupled method by default (part 1 carries the muscles; part 2 gives the scapula's
stress from their loads) or any of ``--methods``. Per run and output angle: the peak glenoid
pressure, the three muscle forces, the cuff's force on the bones, the scapula's largest nodal
von Mises stress, the soft tissues' smallest J at the points and the humerus's swing; per run
its status, DOFs, steps, failed steps, Newton iterations and CPU time. Each quantity's change
from one size to the next finer one says where it has converged. Writes
``muscle_mesh_<level>.json`` and ``muscle_mesh_<level>.png``. Every figure is measured; it
asserts nothing.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import tempfile
from pathlib import Path

import matplotlib
from model_changes import record  # a sibling script: benchmarks/ is sys.path[0]

from shoulder_fem import load_scene, run
from shoulder_fem.io.output import atomic_write_json
from shoulder_fem.io.plots import plt, save_figure

SERIES = (
    "max_pressure",
    "subscapularis_force",
    "infraspinatus_force",
    "supraspinatus_force",
    "muscle_bone_contact_force",
    "scapula_max_von_mises",
    "soft_tissue_min_j",
    "humeral_swing",
)
PANELS = (
    ("max_pressure", 1e-6, "MPa", "peak glenoid pressure"),
    ("subscapularis_force", 1.0, "N", "subscapularis force"),
    ("supraspinatus_force", 1.0, "N", "supraspinatus force"),
    ("infraspinatus_force", 1.0, "N", "infraspinatus force"),
    ("scapula_max_von_mises", 1e-6, "MPa", "scapula's largest nodal von Mises"),
    ("soft_tissue_min_j", 1.0, "-", "soft tissues' smallest J at the points"),
)


def one(level: str, h_muscle_mm: float, method: str, overrides: list[str], out: Path) -> dict:
    """One run at ``level`` with the muscles meshed at ``h_muscle_mm``."""
    scene = load_scene("shoulder-internal-rotation").with_overrides(overrides)
    sizes = dict(scene.level(level), h_muscle=h_muscle_mm * 1e-3)
    scene = dataclasses.replace(scene, levels={**scene.levels, level: sizes})
    r = run(scene, method, level=level, out=out)
    return {
        "h_muscle_mm": h_muscle_mm,
        "method": method,
        "message": r.message,
        "dofs": r.dofs,
        "dofs_part1": r.data.get("dofs_part1"),
        **record(r, SERIES),
    }


def dofs(r: dict) -> str:
    """A run's unknowns for a legend: part 1's (it holds the muscles) or the coupled run's."""
    if r.get("dofs_part1"):
        return f"part 1: {r['dofs_part1']} DOF"
    return f"{r['dofs']} DOF"


def plot(data: dict, path: Path) -> None:
    """One panel per quantity against the angle, one line per muscle size (and method)."""
    fig, axes = plt.subplots(2, 3, figsize=(14, 7.5), layout="constrained")
    sizes = sorted({r["h_muscle_mm"] for r in data["runs"]}, reverse=True)
    cmap = plt.get_cmap("viridis")
    for r in data["runs"]:
        k = sizes.index(r["h_muscle_mm"])
        colour = cmap(k / max(1, len(sizes) - 1))
        ls = "-" if r["method"] == "decoupled" else "--"
        for ax, (key, scale, unit, title) in zip(axes.flat, PANELS, strict=True):
            s = r["series"].get(key)
            if s:
                ax.plot(
                    s["x"],
                    [v * scale for v in s["y"]],
                    color=colour,
                    ls=ls,
                    marker="o",
                    ms=3,
                    label=f"{r['h_muscle_mm']:g} mm, {r['method']} ({dofs(r)})",
                )
            ax.set(xlabel="internal rotation (deg)", ylabel=unit, title=title)
    axes.flat[0].legend(fontsize=7)
    fig.suptitle(
        f"level {data['level']} (joint and bones as the level has them), only the muscles' "
        "element size h_muscle changed",
        fontsize=9,
    )
    save_figure(fig, path)


def main() -> None:
    matplotlib.use("Agg")
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--level", default="medium")
    ap.add_argument("--h-muscle", nargs="+", type=float, default=[25.0, 16.0, 12.0, 8.0, 6.0])
    ap.add_argument("--methods", nargs="+", default=["decoupled"])
    ap.add_argument("--set", dest="overrides", action="append", default=[])
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results"))
    ap.add_argument(
        "--append",
        action="store_true",
        help="keep the runs of an existing muscle_mesh_<level>.json (same overrides) and add these",
    )
    args = ap.parse_args()
    path = args.out / f"muscle_mesh_{args.level}.json"
    data = {
        "scene": "shoulder-internal-rotation",
        "level": args.level,
        "overrides": args.overrides,
        "runs": [],
    }
    if args.append and path.is_file():
        old = json.loads(path.read_text())
        if old.get("overrides") != args.overrides:
            raise SystemExit(
                f"--append: {path} was run with --set {old.get('overrides')}, not {args.overrides}"
            )
        data["runs"] = old["runs"]
    with tempfile.TemporaryDirectory(prefix="muscle-mesh-") as tmp:
        for h in args.h_muscle:
            for m in args.methods:
                r = one(args.level, h, m, args.overrides, Path(tmp) / f"{h:g}-{m}")
                data["runs"].append(r)
                print(
                    f"h_muscle {h:g} mm {m}: {r['status']} {r['final_angle_deg']:.2f} deg, "
                    f"{r['dofs']} DOF, {r['newton_iterations']} Newton, {r['cpu_s']:.0f} s",
                    flush=True,
                )
    data["runs"].sort(key=lambda r: (-r["h_muscle_mm"], r["method"]))
    args.out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(path, data)
    plot(data, path.with_suffix(".png"))


if __name__ == "__main__":
    main()
