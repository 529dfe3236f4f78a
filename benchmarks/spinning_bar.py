"""Benchmark: spinning bar, both methods at several mesh levels — CPU time against error.

    python benchmarks/spinning_bar.py --levels coarse medium --out benchmarks/results
    mpirun -n 2 python benchmarks/spinning_bar.py --out /tmp/bench-np2

The reference is the coupled run at the finest level given. A run's error is the largest
difference of its tip-deflection history from the reference's, relative to the reference's
peak (the bending response to the spin-up is what distinguishes the methods); the root axial
stress is also compared with its analytic steady value. Writes ``spinning_bar.json`` and
``spinning_bar.png``; prints the BLAS library in use, the ranks and DOFs. It asserts nothing
about time: ratios measured in the same run are what to read.
"""

from __future__ import annotations

import argparse
import logging
import shutil
import tempfile
from pathlib import Path

from mpi4py import MPI

from shoulder_fem import load_scene, run
from shoulder_fem.io.compare import series_metrics
from shoulder_fem.io.output import atomic_write_json
from shoulder_fem.io.resources import blas_library, thread_settings

METHODS = ("coupled", "decoupled")


def main(argv: list[str] | None = None) -> int:
    """Run the sweep; rank 0 writes the JSON and the chart."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="spinning-bar")
    parser.add_argument("--levels", nargs="+", default=["coarse", "medium"])
    parser.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results"))
    parser.add_argument("--keep-runs", action="store_true", help="keep each run's output folder")
    args = parser.parse_args(argv)
    comm = MPI.COMM_WORLD
    logging.basicConfig(level=logging.WARNING)

    def say(text: str) -> None:
        if comm.rank == 0:
            print(text, flush=True)

    scene = load_scene(args.scene).with_overrides(args.sets)
    say(f"BLAS: {blas_library()}")
    say(f"threads: {thread_settings()}, MPI ranks: {comm.size}")
    scratch = Path(comm.bcast(tempfile.mkdtemp(prefix="sfem-bench-") if comm.rank == 0 else None))
    runs_dir = args.out / "runs" if args.keep_runs else scratch
    summaries = {}
    for level in args.levels:
        for method in METHODS:
            result = run(
                scene, method, level, runs_dir / f"{level}-{method}", comm=comm, replace=True
            )
            summaries[(level, method)] = result.data
            res = result.resources
            say(
                f"{level:7s} {method:9s} {result.dofs:7d} DOFs  CPU {res['cpu_s']:8.2f} s  "
                f"wall {res['wall_s']:8.2f} s  peak {res['peak_rss_mb']:6.0f} MB"
            )
    ref = summaries[(args.levels[-1], "coupled")]
    points = []
    for (level, method), s in summaries.items():
        tip = series_metrics(ref["series"]["tip_deflection"], s["series"]["tip_deflection"])
        root = s["probes"]["root_axial_stress"]
        exact = s["probes"]["root_axial_stress_analytic"]
        points.append(
            {
                "label": f"{method} {level}",
                "level": level,
                "method": method,
                "dofs": s["dofs"],
                "ranks": s["ranks"],
                "cpu_s": s["resources"]["cpu_s"],
                "wall_s": s["resources"]["wall_s"],
                "peak_rss_mb": s["resources"]["peak_rss_mb"],
                "results_disk_mb": s["resources"]["results_disk_mb"],
                "error": tip["max_rel_diff"],
                "tip_deflection_error": tip["max_rel_diff"],
                "root_stress_error_vs_analytic": (root - exact) / exact,
                "peak_tip_deflection": s["probes"]["peak_tip_deflection"],
                "solver": s["solver"],
            }
        )
    ratios = {
        level: {
            "speedup_cpu": summaries[(level, "coupled")]["resources"]["cpu_s"]
            / summaries[(level, "decoupled")]["resources"]["cpu_s"],
            "memory_ratio": summaries[(level, "decoupled")]["resources"]["peak_rss_mb"]
            / summaries[(level, "coupled")]["resources"]["peak_rss_mb"],
        }
        for level in args.levels
    }
    record = {
        "benchmark": "spinning_bar",
        "scene": scene.name,
        "parameters": scene.values(),
        "parameter_units": scene.units(),
        "reference": f"coupled {args.levels[-1]}",
        "error_definition": "max |tip(t) - tip_ref(t)| / max |tip_ref| over the run",
        "blas": blas_library(),
        "threads": thread_settings(),
        "ranks": comm.size,
        "points": points,
        "ratios": ratios,
    }
    if comm.rank == 0:
        import matplotlib

        matplotlib.use("Agg")
        from shoulder_fem.io import plots

        args.out.mkdir(parents=True, exist_ok=True)
        atomic_write_json(args.out / "spinning_bar.json", record)
        plots.plot_cpu_vs_error(
            points,
            args.out / "spinning_bar.png",
            f"spinning bar ({comm.size} rank(s)): CPU time vs tip-deflection error",
        )
        print(f"{'run':18s} {'DOFs':>7s} {'CPU s':>8s} {'error':>9s} {'root σ vs analytic':>19s}")
        for p in points:
            print(
                f"{p['label']:18s} {p['dofs']:7d} {p['cpu_s']:8.2f} {p['error']:9.2e} "
                f"{p['root_stress_error_vs_analytic']:+19.2e}"
            )
        for level, r in ratios.items():
            print(
                f"{level}: speed-up (CPU) {r['speedup_cpu']:.2f}x, memory ratio "
                f"{r['memory_ratio']:.2f}"
            )
        print(f"wrote {args.out / 'spinning_bar.json'} and {args.out / 'spinning_bar.png'}")
        shutil.rmtree(scratch, ignore_errors=True)
    comm.Barrier()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
