"""Benchmark: the coupled method's linear solver, MUMPS LU against the stiff / soft split.

    OMP_NUM_THREADS=1 python benchmarks/coupled_solvers.py --out benchmarks/results

Runs ``shoulder-fem run shoulder-internal-rotation --method coupled`` from the unloaded
seating to ``--angle`` (default 1 deg) with ``coupled_solver`` = direct and split, at coarse,
medium and paper, 1 rank. From each run's ``summary.json``: wall and CPU time, peak memory, the
Newton iterations and linear solves of the whole run (the seating included), the Krylov
iterations (FGMRES's, outside the split), the time in the linear solves (the Newton time less
the residuals and Jacobians); between the two solvers the largest difference of any recorded
series (relative to the series' largest value). Writes ``coupled_solvers.json`` and
``coupled_solvers.png``. Every figure is measured; it asserts nothing.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import matplotlib
import numpy as np

from shoulder_fem.io.output import atomic_write_json
from shoulder_fem.io.plots import plt, save_figure

SOLVERS = ("direct", "split")
LEVELS = ("coarse", "medium", "paper")


def run_case(level: str, solver: str, angle: float, out: Path) -> dict:
    """One coupled run in a process of its own; its figures from its summary."""
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    cmd = [sys.executable, "-m", "shoulder_fem.cli", "-q", "run", "shoulder-internal-rotation"]
    cmd += ["--method", "coupled", "--level", level, "--out", str(out), "--force"]
    cmd += ["--set", f"coupled_solver={solver}", "--set", f"final_angle={angle}deg"]
    subprocess.run(cmd, check=True, env=env, stdout=subprocess.DEVNULL)
    s = json.loads((out / "summary.json").read_text())
    p, solves = s["probes"], s["solver"]["linear_solves"]
    return {
        "status": s["status"],
        "dofs": s["dofs"],
        "wall_s": s["resources"]["wall_s"],
        "cpu_s": s["resources"]["cpu_s"],
        "peak_rss_mb": s["resources"]["peak_rss_rank_max_mb"],
        "newton_iterations": s["solver"]["newton_iterations"],
        "linear_solves": solves,
        "krylov_iterations": p["krylov_iterations"],
        "krylov_per_solve": p["krylov_iterations"] / solves,
        "linear_s": p["coupled_time_linear_s"],
        "linear_s_per_solve": p["coupled_time_linear_s"] / solves,
        "newton_s": p["coupled_time_newton_s"],
    }


def series_difference(a: Path, b: Path) -> tuple[float, str]:
    """The largest |a - b| / max |a| over the series both runs recorded, and which series."""
    A = json.loads((a / "summary.json").read_text())["series"]
    B = json.loads((b / "summary.json").read_text())["series"]
    worst, name = 0.0, ""
    for key, sa in A.items():
        ya, yb = np.asarray(sa["y"], float), np.asarray(B[key]["y"], float)
        scale = np.abs(ya).max(initial=0.0)
        if len(ya) != len(yb) or scale == 0.0:
            continue
        d = float(np.abs(ya - yb).max() / scale)
        if d > worst:
            worst, name = d, key
    return worst, name


def plot(rows: list[dict], path: Path) -> None:
    fig, ax = plt.subplots(1, 3, figsize=(13, 3.9), layout="constrained")
    for solver, colour in zip(SOLVERS, ("C0", "C3"), strict=True):
        x = [r[solver]["dofs"] for r in rows]
        ax[0].loglog(x, [r[solver]["linear_s_per_solve"] for r in rows], "o-", color=colour,
                     label=solver)  # fmt: skip
        ax[2].semilogx(x, [r[solver]["peak_rss_mb"] for r in rows], "o-", color=colour,
                       label=solver)  # fmt: skip
    x = [r["split"]["dofs"] for r in rows]
    ax[1].semilogx(x, [r["split"]["krylov_per_solve"] for r in rows], "o-", color="C3")
    ax[0].set(xlabel="coupled DOFs", ylabel="s", title="linear solve, per Newton iteration")
    ax[1].set(xlabel="coupled DOFs", ylabel="FGMRES iterations", title="split: per linear solve")
    ax[1].set_ylim(0, None)
    ax[2].set(xlabel="coupled DOFs", ylabel="MB", title="peak memory (run)")
    for a in (ax[0], ax[2]):
        a.legend(fontsize=7)
    save_figure(fig, path)


def main() -> None:
    matplotlib.use("Agg")
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results"))
    ap.add_argument("--angle", type=float, default=1.0, help="final angle (deg)")
    ap.add_argument("--levels", nargs="+", default=list(LEVELS), choices=LEVELS)
    args = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="coupled-solvers-"))
    rows = []
    try:
        for level in args.levels:
            row = {"level": level}
            for solver in SOLVERS:
                row[solver] = run_case(level, solver, args.angle, work / f"{level}{solver}")
            row["series_difference"], row["series_difference_of"] = series_difference(
                work / f"{level}direct", work / f"{level}split"
            )
            rows.append(row)
            print(
                level,
                {s: round(row[s]["linear_s_per_solve"], 2) for s in SOLVERS},
                f"s per solve, {row['split']['krylov_per_solve']:.1f} FGMRES its/solve,",
                f"series within {row['series_difference']:.1e}",
                flush=True,
            )
    finally:
        shutil.rmtree(work, ignore_errors=True)
    args.out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(
        args.out / "coupled_solvers.json",
        {
            "scene": "shoulder-internal-rotation",
            "method": "coupled",
            "angles": f"seating, then 0-{args.angle:g} deg",
            "ranks": 1,
            "runs": rows,
        },
    )
    plot(rows, args.out / "coupled_solvers.png")


if __name__ == "__main__":
    main()
