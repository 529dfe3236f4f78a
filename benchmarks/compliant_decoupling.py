"""Benchmark: the compliant decoupling against the paper's rigid one (issue 21, item 2).

    OMP_NUM_THREADS=1 python benchmarks/compliant_decoupling.py --levels medium paper \
        --out benchmarks/results

At each level the scene runs four times, each ``shoulder-fem run`` in a process of its own
(so that each peak memory is its own): coupled (the reference), decoupled with the paper's
rigid part 1, decoupled with ``part1_bones = compliant`` (part 1 sees both bones' compliance:
:mod:`shoulder_fem.families.shoulder.correction`, :mod:`shoulder_fem.families.shoulder.humerus`)
and with ``part1_bones = compliant-scapula`` (the scapula's only: the humerus's share of the
correction). The decoupled runs go through the study's
report against the coupled one: per output angle, the largest relative error of the three
muscle forces, the peak pressure's, and the slope and correlation of the nodal von Mises
stress over the scapula and its glenoid region; and each run's CPU time, peak memory and
stages. The compliant run also holds its own rigid pass (``uncorrected_``): its errors are
reported next to the rigid run's. Writes ``compliant_decoupling.json`` and
``compliant_decoupling.png`` (the reports themselves stay in the runs' folder). Every figure is
measured; it asserts nothing.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import matplotlib
import numpy as np

from shoulder_fem.families.shoulder.report.writer import write_report
from shoulder_fem.io.output import atomic_write_json
from shoulder_fem.io.plots import plt, save_figure
from shoulder_fem.io.results import load_summary

SCENE = "shoulder-internal-rotation"
RUNS = {
    "coupled": ("coupled", []),
    "rigid": ("decoupled", []),
    "compliant": ("decoupled", ["--set", "part1_bones=compliant"]),
    "compliant-scapula": ("decoupled", ["--set", "part1_bones=compliant-scapula"]),
}
#: The decoupled variants, compared with the coupled run.
DECOUPLED = ("rigid", "compliant-scapula", "compliant")
MUSCLES = ("subscapularis", "supraspinatus", "infraspinatus")


def run_apart(level: str, name: str, folder: Path) -> dict:
    """``shoulder-fem run`` of one variant in its own process (a finished folder is reused)."""
    method, extra = RUNS[name]
    if not (folder / "summary.json").is_file():
        cmd = [sys.executable, "-m", "shoulder_fem.cli", "run", SCENE, "--method", method]
        cmd += ["--level", level, "--out", str(folder), *extra]
        subprocess.run(cmd, check=True)
    s = load_summary(folder)
    wanted = "rigid" if name in ("coupled", "rigid") else name
    got = s["parameters"].get("part1_bones", "rigid")
    if s["method"] != method or s["level"] != level or (method == "decoupled" and got != wanted):
        raise SystemExit(f"{folder}: holds another run ({s['method']}, {s['level']}, {got})")
    if name == "compliant" and "humerus" not in [st["name"] for st in s["stages"]]:
        raise SystemExit(f"{folder}: a compliant run from before the humerus's correction")
    return s


def errors(report: dict) -> dict:
    """Per output angle: the largest muscle-force error, the pressure error, the slopes."""
    angles = [a for a in report["angles_compared_deg"] if a > 0]
    muscle = [
        max(abs(report["muscle_force_rel_errors"][m][f"{a:g}"]) for m in MUSCLES) for a in angles
    ]
    pressure = [abs(report["max_pressure_rel_errors"][f"{a:g}"]) for a in angles]
    rows = {round(r["angle_deg"], 6): r for r in report["von_mises_per_angle"]}
    return {
        "angles_deg": angles,
        "muscle_force_rel_error": muscle,
        "max_pressure_rel_error": pressure,
        "von_mises_slope": [rows[round(a, 6)]["scapula"]["slope"] for a in angles],
        "von_mises_correlation": [rows[round(a, 6)]["scapula"]["correlation"] for a in angles],
        "glenoid_von_mises_slope": [rows[round(a, 6)]["glenoid_region"]["slope"] for a in angles],
    }


def cost(s: dict) -> dict:
    return {
        "cpu_s": s["resources"]["cpu_s"],
        "wall_s": s["resources"]["wall_s"],
        "peak_rss_mb": s["resources"]["peak_rss_mb"],
        "stage_cpu_s": {st["name"]: st["cpu_s"] for st in s["stages"]},
        "newton_iterations": s["solver"]["newton_iterations"],
    }


def level_row(level: str, runs_dir: Path, out: Path) -> dict:
    runs_dir.mkdir(parents=True, exist_ok=True)
    folders = {name: runs_dir / f"{level}-{name}" for name in RUNS}
    summaries = {name: run_apart(level, name, folders[name]) for name in RUNS}
    row = {"runs": {name: cost(s) for name, s in summaries.items()}, "errors": {}}
    for name in DECOUPLED:
        report = write_report(folders["coupled"], folders[name], out / f"{level}-{name}", level)
        row["errors"][name] = errors(report)
        if name == "compliant":
            row["in_run_rigid_muscle_force_rel_error"] = report["uncorrected"][
                "muscle_force_rel_error"
            ]
    rigid = row["runs"]["rigid"]
    for name in ("compliant", "compliant-scapula"):
        run = row["runs"][name]
        row[f"cpu_ratio_{name}_to_rigid"] = run["cpu_s"] / rigid["cpu_s"]
        row[f"memory_ratio_{name}_to_rigid"] = run["peak_rss_mb"] / rigid["peak_rss_mb"]
    return row


def plot(data: dict, path: Path) -> None:
    fig, axes = plt.subplots(2, 2, figsize=(11, 8))
    styles = {"rigid": "--", "compliant-scapula": ":", "compliant": "-"}
    colours = dict(zip(data["levels"], ("tab:blue", "tab:red", "tab:green"), strict=False))
    panels = (
        (axes[0, 0], "muscle_force_rel_error", "largest muscle-force error (%)", 100),
        (axes[0, 1], "max_pressure_rel_error", "peak-pressure error (%)", 100),
        (axes[1, 0], "von_mises_slope", "nodal von Mises slope (scapula)", 1),
    )
    for ax, key, label, scale in panels:
        for level, row in data["levels"].items():
            for name, style in styles.items():
                if name not in row["errors"]:  # a table from before compliant-scapula
                    continue
                e = row["errors"][name]
                y = np.asarray(e[key]) * scale
                ax.plot(
                    e["angles_deg"],
                    y,
                    style,
                    marker="o",
                    color=colours[level],
                    label=f"{level}, {name}",
                )
        ax.set_xlabel("humeral angle (deg)")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    for ax in (axes[0, 0], axes[0, 1]):  # the target; errors over three decades
        ax.axhline(0.2, color="k", lw=0.8)
        ax.set_yscale("log")
    for b in (0.998, 1.002):
        axes[1, 0].axhline(b, color="k", lw=0.8)
    axes[0, 0].legend(fontsize=8)
    ax = axes[1, 1]
    levels = list(data["levels"])
    x = np.arange(len(levels))
    for i, name in enumerate(("coupled", *DECOUPLED)):
        cpu = [data["levels"][lv]["runs"].get(name, {}).get("cpu_s", np.nan) for lv in levels]
        ax.bar(x + (i - 1.5) * 0.2, cpu, 0.2, label=name)
    ax.set_xticks(x, levels)
    ax.set_yscale("log")
    ax.set_ylabel("CPU time of the run (s)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, axis="y")
    fig.suptitle("Decoupled against coupled: the paper's rigid part 1 and the compliant ones")
    fig.tight_layout()
    save_figure(fig, path)


def main() -> None:
    matplotlib.use("Agg")
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--levels", nargs="+", default=["medium", "paper"])
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results"))
    ap.add_argument(
        "--runs",
        type=Path,
        help="the run folders (default TMPDIR/compliant-decoupling-runs); finished runs there "
        "are read, not run again",
    )
    ap.add_argument("--replot", action="store_true", help="redraw the figure only")
    args = ap.parse_args()
    target = args.out / "compliant_decoupling.json"
    if args.replot:
        plot(json.loads(target.read_text()), target.with_suffix(".png"))
        return
    runs_dir = args.runs or Path(tempfile.gettempdir()) / "compliant-decoupling-runs"
    data = {
        "scene": SCENE,
        "omp_num_threads": os.environ.get("OMP_NUM_THREADS"),
        "levels": {},
    }
    reports = runs_dir / "reports"  # the study's reports of each pair (figures and all)
    for level in args.levels:
        data["levels"][level] = level_row(level, runs_dir, reports)
        print(level, json.dumps(data["levels"][level]["errors"]), flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(target, data)
    plot(data, target.with_suffix(".png"))


if __name__ == "__main__":
    main()
