"""Benchmark: the decoupled method's part 2 (the scapula) with MUMPS LU and with CG + GAMG.

    OMP_NUM_THREADS=1 python benchmarks/part2_solvers.py --out benchmarks/results

Runs ``shoulder-fem run shoulder-internal-rotation --method decoupled`` (0-60 deg, seven
output angles) with ``part2_solver`` = direct and iterative: at coarse, medium and paper on one
rank, and part 2 on the ``fine`` scapula from a part 1 at paper (``part2_level = fine``) on 1
and 2 ranks. From each run's ``summary.json``: part 2's wall and CPU time, the largest rank's
peak memory, chord (Newton) and CG iterations, DOFs; between the two solvers the largest
difference of the scapula's nodal von Mises stress over the seven angles (relative to its
maximum). Then a projection of part 2 at fine to 8-64 ranks (:func:`projection`, a model,
stated as such). Writes ``part2_solvers.json`` and ``part2_solvers.png``. Every figure is
measured; it asserts nothing.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import matplotlib
import numpy as np
from scipy.spatial import cKDTree

from shoulder_fem.io.output import atomic_write_json
from shoulder_fem.io.plots import plt, save_figure

SOLVERS = ("direct", "iterative")
#: (label, part 1's level, part 2's level, ranks)
CASES = (
    ("coarse", "coarse", "coarse", 1),
    ("medium", "medium", "medium", 1),
    ("paper", "paper", "paper", 1),
    ("fine", "paper", "fine", 1),
    ("fine", "paper", "fine", 2),
)
#: An MPI reduction's latency assumed by the projection (s): a cluster interconnect's order.
LATENCY = 20e-6


def run_case(level1: str, level2: str, ranks: int, solver: str, out: Path) -> dict:
    """One decoupled run in a process of its own; part 2's figures from its summary."""
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    cmd = [sys.executable, "-m", "shoulder_fem.cli", "-q", "run", "shoulder-internal-rotation"]
    cmd += ["--method", "decoupled", "--level", level1, "--out", str(out), "--force"]
    cmd += ["--set", f"part2_solver={solver}", "--set", f"part2_level={level2}"]
    if ranks > 1:
        cmd = ["mpirun", "-n", str(ranks), *cmd]
    subprocess.run(cmd, check=True, env=env, stdout=subprocess.DEVNULL)
    s = json.loads((out / "summary.json").read_text())
    stage = next(st for st in s["stages"] if st["name"] == "part2")
    p = s["probes"]
    return {
        "status": s["status"],
        "dofs_part2": s["dofs_part2"],
        "part2_wall_s": stage["wall_s"],
        "part2_cpu_s": stage["cpu_s"],
        "peak_rss_rank_max_mb": s["resources"]["peak_rss_rank_max_mb"],
        "run_wall_s": s["resources"]["wall_s"],
        "chord_iterations": p["part2_iterations"],
        "krylov_iterations": p["part2_krylov_iterations"],
        "krylov_per_solve": p["part2_krylov_iterations"] / p["part2_iterations"],
        "linear_s": p["part2_time_linear_s"],
        "residual_s": p["part2_time_residual_s"],
        "jacobian_s": p["part2_time_jacobian_s"],
    }


def von_mises_difference(a: Path, b: Path) -> float:
    """max |σ_a - σ_b| / max |σ_a| over the nodes and angles (nodes matched by position)."""
    A, B = np.load(a / "shoulder.npz"), np.load(b / "shoulder.npz")
    _, idx = cKDTree(B["scapula_points"]).query(A["scapula_points"])
    va, vb = A["scapula_von_mises_series"], B["scapula_von_mises_series"][:, idx]
    return float(np.abs(va - vb).max() / np.abs(va).max())


def projection(rows: list[dict], ranks: list[int]) -> list[dict]:
    """Part 2 at fine with CG + GAMG on N ranks: a cost model on the 1- and 2-rank runs.

    Part 2's wall = its linear solves (GAMG's set-up and the CG iterations, measured as
    ``part2_time_linear_s``) + the rest (assembly, residuals, stress recovery, output).

    * the rest: Amdahl, s + p / N, fitted to its 1- and 2-rank walls;
    * the linear solves: k CG iterations of w / N each, plus c reductions per iteration of
      latency α log2 N (c = 10 over the GAMG levels and CG's dot products; α =
      :data:`LATENCY`, a cluster interconnect's order). k and w from the 2-rank run (k, the
      iterations, stay as measured at 2 ranks: they doubled from 1 to 2 ranks and are taken
      flat beyond, which GAMG's processor-local aggregation does not promise).

    A projection, not a measurement.
    """
    fine = {r["ranks"]: r["iterative"] for r in rows if r["label"] == "fine"}
    one, two = fine[1], fine[2]
    rest1 = one["part2_wall_s"] - one["linear_s"]
    rest2 = two["part2_wall_s"] - two["linear_s"]
    p_rest = 2.0 * (rest1 - rest2)
    s_rest = rest1 - p_rest
    k = two["krylov_iterations"]
    per_it = 2.0 * two["linear_s"] / k  # one rank's work per iteration at the 2-rank pace
    out = []
    for n in ranks:
        linear = k * (per_it / n + 10 * LATENCY * math.log2(n))
        t = s_rest + p_rest / n + linear
        out.append({"ranks": n, "part2_wall_s": t, "linear_s": linear, "rest_s": t - linear})
    return out


def plot(rows: list[dict], proj: list[dict], path: Path) -> None:
    serial = [r for r in rows if r["ranks"] == 1]
    two = [r for r in rows if r["ranks"] == 2]
    dofs = [r["direct"]["dofs_part2"] for r in serial]
    fig, ax = plt.subplots(1, 4, figsize=(16, 3.9), layout="constrained")
    for solver, colour in zip(SOLVERS, ("C0", "C3"), strict=True):
        for group, mark, ranks in ((serial, "o-", 1), (two, "s", 2)):
            x = [r[solver]["dofs_part2"] for r in group]
            ax[0].loglog(
                x,
                [r[solver]["part2_wall_s"] for r in group],
                mark,
                color=colour,
                label=f"{solver}, {ranks} rank{'s' if ranks > 1 else ''}",
            )
            ax[2].semilogx(
                x, [r[solver]["peak_rss_rank_max_mb"] for r in group], mark, color=colour
            )
    ax[1].semilogx(
        dofs, [r["iterative"]["krylov_per_solve"] for r in serial], "o-", color="C3", label="1 rank"
    )
    ax[1].semilogx(
        [r["iterative"]["dofs_part2"] for r in two],
        [r["iterative"]["krylov_per_solve"] for r in two],
        "s",
        color="C3",
        label="2 ranks",
    )
    n = [p["ranks"] for p in proj]
    ax[3].loglog(n, [p["part2_wall_s"] for p in proj], "--", color="C3", label="projected")
    measured = sorted(
        (r["ranks"], r["iterative"]["part2_wall_s"]) for r in rows if r["label"] == "fine"
    )
    ax[3].loglog(*zip(*measured, strict=True), "s", color="C3", label="measured")
    ax[0].set(xlabel="part 2 DOFs", ylabel="s", title="part 2 wall (7 angles)")
    ax[1].set(xlabel="part 2 DOFs", ylabel="CG iterations", title="CG + GAMG per chord step")
    ax[1].set_ylim(0, None)
    ax[2].set(xlabel="part 2 DOFs", ylabel="MB", title="peak memory, largest rank (run)")
    ax[3].set(xlabel="MPI ranks", ylabel="s", title="fine, CG + GAMG: part 2 wall")
    for a in (ax[0], ax[1], ax[3]):
        a.legend(fontsize=7)
    save_figure(fig, path)


def main() -> None:
    matplotlib.use("Agg")
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results"))
    args = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="part2-"))
    rows = []
    try:
        for label, level1, level2, ranks in CASES:
            row = {"label": label, "part1_level": level1, "part2_level": level2, "ranks": ranks}
            for solver in SOLVERS:
                row[solver] = run_case(
                    level1, level2, ranks, solver, work / f"{label}{ranks}{solver}"
                )
            row["von_mises_difference"] = von_mises_difference(
                work / f"{label}{ranks}direct", work / f"{label}{ranks}iterative"
            )
            rows.append(row)
            print(
                label,
                ranks,
                {s: round(row[s]["part2_wall_s"], 1) for s in SOLVERS},
                f"{row['iterative']['krylov_per_solve']:.1f} CG its/solve",
                flush=True,
            )
    finally:
        shutil.rmtree(work, ignore_errors=True)
    proj = projection(rows, [1, 2, 8, 16, 32, 64])
    args.out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(
        args.out / "part2_solvers.json",
        {
            "scene": "shoulder-internal-rotation",
            "angles": "0-60 deg, 7 outputs",
            "runs": rows,
            "projection": proj,
            "projection_latency_s": LATENCY,
        },
    )
    plot(rows, proj, args.out / "part2_solvers.png")


if __name__ == "__main__":
    main()
