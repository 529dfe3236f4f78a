"""Benchmark: strong scaling of the shoulder study over MPI ranks (issue 22).

    OMP_NUM_THREADS=1 python benchmarks/scaling.py --level paper --ranks 1 2 \
        --out benchmarks/results

For each rank count the script runs ``shoulder-fem bench shoulder-internal-rotation`` (both
methods, the scene as it is, 0-60 deg) under ``mpirun -n N`` in a process of its own, and
reads the two runs' ``summary.json``: wall time (the slowest rank), CPU time (summed over
ranks), peak memory (summed, and the largest rank's own), Newton iterations, DOFs, and where
the Newton time went (:func:`time_split`). It writes ``scaling_<level>.json`` (with the
code's commit) and ``scaling_<level>.png`` (wall time and parallel efficiency T_1 / (N T_N)
per method, memory per rank, the time split). Every figure is measured; it asserts nothing.

Part 2 on the ``fine`` scapula (1 and 2 ranks, LU and CG + GAMG, with the projection to 64
ranks) is measured by ``benchmarks/part2_solvers.py`` (``part2_solvers.{json,png}``).
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

METHODS = ("coupled", "decoupled")


def run_bench(level: str, ranks: int, out: Path) -> dict:
    """One ``bench`` under ``mpirun -n ranks``; the two summaries' figures."""
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    cmd = [sys.executable, "-m", "shoulder_fem.cli", "bench", "shoulder-internal-rotation"]
    cmd += ["--level", level, "--out", str(out), "--force"]
    if ranks > 1:
        cmd = ["mpirun", "-n", str(ranks), *cmd]
    subprocess.run(cmd, check=True, env=env, stdout=subprocess.DEVNULL)
    row = {"ranks": ranks}
    for m in METHODS:
        s = json.loads((out / m / "summary.json").read_text())
        res = s["resources"]
        row[m] = {
            "status": s["status"],
            "wall_s": res["wall_s"],
            "cpu_s": res["cpu_s"],
            "peak_rss_mb": res["peak_rss_mb"],
            "peak_rss_rank_max_mb": res.get("peak_rss_rank_max_mb"),
            "newton_iterations": s["solver"]["newton_iterations"],
            "factorizations": s["solver"]["factorizations"],
            "dofs": s.get("dofs"),
            "time_split_s": time_split(s["probes"]),
        }
    return row


#: Where the Newton time went (the runs' ``<stepping>_time_<key>_s`` probes, slowest rank),
#: summed over a method's steppings (the decoupled method's part 1 and part 2); ``other``: the
#: rest of the Newton time (the residuals' FE assembly, the rigid terms, the line search).
SPLIT = ("linear", "jacobian_fe_assembly", "jacobian_reduction", "contact")


def time_split(probes: dict) -> dict:
    """``{key: s}`` for :data:`SPLIT`, ``newton`` and ``other``, summed over the steppings."""
    out = {k: 0.0 for k in ("newton", *SPLIT)}
    for name, value in probes.items():
        _, sep, key = name.partition("_time_")
        if sep and key.endswith("_s") and key[:-2] in out:
            out[key[:-2]] += value
    out["other"] = out["newton"] - sum(out[k] for k in SPLIT)
    return out


def efficiencies(rows: list[dict]) -> None:
    """Add each method's speed-up T_1 / T_N and parallel efficiency T_1 / (N T_N) (wall)."""
    base = next(r for r in rows if r["ranks"] == 1)
    for r in rows:
        for m in METHODS:
            speed = base[m]["wall_s"] / r[m]["wall_s"]
            r[m]["wall_speedup"] = speed
            r[m]["parallel_efficiency"] = speed / r["ranks"]


def plot(rows: list[dict], level: str, path: Path) -> None:
    ranks = [r["ranks"] for r in rows]
    fig, axes = plt.subplots(1, 4, figsize=(16, 3.8), layout="constrained")
    for m, colour in zip(METHODS, ("C0", "C3"), strict=True):
        axes[0].plot(ranks, [r[m]["wall_s"] for r in rows], "o-", color=colour, label=m)
        axes[1].plot(ranks, [r[m]["parallel_efficiency"] for r in rows], "o-", color=colour)
        per_rank = [r[m]["peak_rss_rank_max_mb"] for r in rows]
        axes[2].plot(ranks, per_rank, "o-", color=colour)
    axes[0].set(xlabel="MPI ranks", ylabel="wall time (s)", title="wall time, 0-60 deg")
    axes[1].set(xlabel="MPI ranks", ylabel="T1 / (N TN)", title="parallel efficiency (wall)")
    axes[1].set_ylim(0, 1.1)
    axes[2].set(xlabel="MPI ranks", ylabel="MB", title="peak memory of the largest rank")
    axes[0].legend()
    bars = [(m, r) for m in METHODS for r in rows]
    bottom = np.zeros(len(bars))
    for key in (*SPLIT, "other"):
        height = np.array([max(r[m]["time_split_s"][key], 0.0) for m, r in bars])
        axes[3].bar(range(len(bars)), height, bottom=bottom, label=key.replace("jacobian_", ""))
        bottom += height
    axes[3].set_xticks(range(len(bars)), [f"{m[:3]}, {r['ranks']}" for m, r in bars])
    axes[3].set(ylabel="s (slowest rank)", title="Newton time: method, ranks")
    axes[3].legend(fontsize=7)
    for ax in axes[:3]:
        ax.set_xticks(ranks)
        ax.grid(alpha=0.3)
    fig.suptitle(f"Strong scaling, shoulder study at `{level}` (both methods, one bench each)")
    save_figure(fig, path)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--level", default="paper")
    ap.add_argument("--ranks", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results"))
    args = ap.parse_args()
    matplotlib.use("Agg")  # figures are files
    if 1 not in args.ranks:
        ap.error("--ranks must include 1 (the efficiency's reference)")
    work = Path(tempfile.mkdtemp(prefix="scaling-"))
    try:
        rows = [run_bench(args.level, n, work / f"n{n}") for n in sorted(args.ranks)]
    finally:
        shutil.rmtree(work, ignore_errors=True)
    efficiencies(rows)
    args.out.mkdir(parents=True, exist_ok=True)
    commit = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=False
    ).stdout.strip()
    record = {"level": args.level, "commit": commit, "runs": rows}
    atomic_write_json(args.out / f"scaling_{args.level}.json", record)
    plot(rows, args.level, args.out / f"scaling_{args.level}.png")
    for r in rows:
        print(
            r["ranks"],
            *(
                f"{m}: wall {r[m]['wall_s']:.1f} s, eff {r[m]['parallel_efficiency']:.2f}"
                for m in METHODS
            ),
        )


if __name__ == "__main__":
    main()
