"""Speed against accuracy: every scene, method (and decoupled variant) and mesh level.

    python benchmarks/speed_accuracy.py --out benchmarks/results
    python benchmarks/speed_accuracy.py --scenes spinning-bar --levels coarse medium

For each scene, the reference is the coupled run at the finest level given; every run's error
is its key result's difference from the reference's (a history: largest difference relative to
the reference's peak; a scalar: relative difference). One PNG with a panel per scene, CPU time
against error, the Pareto front (no other run both cheaper and more accurate) drawn as a line;
one JSON of all the points. Asserts nothing about time. New scenes join by adding a line to
``SCENES`` (its key result and the settings that keep the sweep affordable).
"""

from __future__ import annotations

import argparse
import logging
import shutil
import tempfile
from pathlib import Path

import numpy as np
from mpi4py import MPI

from shoulder_fem import RunFailed, load_scene, run
from shoulder_fem.families import family_names
from shoulder_fem.io.compare import relative_difference, series_metrics
from shoulder_fem.io.output import atomic_write_json
from shoulder_fem.io.resources import blas_library

#: scene → (kind of key result, its name, overrides that keep the sweep affordable)
SCENES = {
    "spinning-bar": ("series", "tip_deflection", {}),
    "spin-up-beam": ("series", "tip_deflection", {"end_time": 15.0, "time_step": 0.025}),
    "tied-block": ("probe", "plate_rotation", {}),
    "tumbling-body": ("series", "omega_body_y", {}),
}
VARIANTS = ("paper", "spin-softening", "stress-stiffening")


def error(kind: str, name: str, ref: dict, other: dict) -> float:
    """The key result's error of ``other`` against ``ref`` (dimensionless)."""
    if kind == "series":
        return series_metrics(ref["series"][name], other["series"][name])["max_rel_diff"]
    return abs(relative_difference(ref["probes"][name], other["probes"][name]))


def pareto(points: list[dict]) -> list[dict]:
    """Points no other point beats in both CPU time and error, by increasing CPU time."""
    front, best = [], np.inf
    for p in sorted(points, key=lambda q: q["cpu_s"]):
        if p["error"] < best:
            front.append(p)
            best = p["error"]
    return front


def main(argv: list[str] | None = None) -> int:
    """Run the sweep; rank 0 writes the JSON and the chart."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", default=list(SCENES))
    parser.add_argument("--levels", nargs="+", default=["coarse", "medium"])
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results"))
    args = parser.parse_args(argv)
    comm = MPI.COMM_WORLD
    logging.basicConfig(level=logging.ERROR)
    scratch = Path(comm.bcast(tempfile.mkdtemp(prefix="sfem-sa-") if comm.rank == 0 else None))
    if comm.rank == 0:
        print(f"BLAS: {blas_library()}; ranks: {comm.size}", flush=True)
    results: dict[str, list[dict]] = {}
    for name in args.scenes:
        if name not in SCENES:
            raise SystemExit(f"speed_accuracy: no key result defined for scene '{name}'")
        kind, key, overrides = SCENES[name]
        scene = load_scene(name)
        if scene.family not in family_names():
            if comm.rank == 0:
                print(f"{name}: family '{scene.family}' cannot run yet, skipped", flush=True)
            continue
        scene = scene.with_values(**{k: v for k, v in overrides.items() if k in scene.parameters})
        variants = VARIANTS if "decoupled_variant" in scene.parameters else (None,)
        runs = []
        for level in args.levels:
            configs = [("coupled", None)] + [("decoupled", v) for v in variants]
            for method, variant in configs:
                s = scene.with_values(decoupled_variant=variant) if variant else scene
                label = f"{method}{'/' + variant if variant else ''} {level}"
                try:
                    data = run(s, method, level, scratch / "run", comm=comm, replace=True).data
                    failed = False
                except RunFailed as err:
                    data, failed = err.summary.data, True
                runs.append(
                    {
                        "label": label,
                        "method": method,
                        "variant": variant,
                        "level": level,
                        "data": data,
                        "failed": failed,
                    }
                )
        ref = next(r for r in reversed(runs) if r["method"] == "coupled" and not r["failed"])
        points = []
        for r in runs:
            err = np.inf if r["failed"] else error(kind, key, ref["data"], r["data"])
            points.append(
                {
                    "label": r["label"],
                    "method": r["method"],
                    "variant": r["variant"],
                    "level": r["level"],
                    "dofs": r["data"].get("dofs"),
                    "cpu_s": r["data"]["resources"]["cpu_s"],
                    "peak_rss_mb": r["data"]["resources"]["peak_rss_mb"],
                    "error": float(err),
                    "failed": r["failed"],
                    "reference": r is ref,
                }
            )
        results[name] = points
        if comm.rank == 0:
            for p in points:
                shown = "(reference)" if p["reference"] else f"{p['error']:.2e}"
                print(
                    f"{name:14s} {p['label']:34s} CPU {p['cpu_s']:8.2f} s  error {shown}",
                    flush=True,
                )
    if comm.rank == 0:
        args.out.mkdir(parents=True, exist_ok=True)
        record = {
            "benchmark": "speed_accuracy",
            "blas": blas_library(),
            "ranks": comm.size,
            "levels": args.levels,
            "scenes": results,
            "pareto": {
                n: [
                    p["label"]
                    for p in pareto(
                        [q for q in pts if not q["reference"] and np.isfinite(q["error"])]
                    )
                ]
                for n, pts in results.items()
            },
        }
        atomic_write_json(args.out / "speed_accuracy.json", record)
        plot(results, args.out / "speed_accuracy.png")
        print(f"wrote {args.out / 'speed_accuracy.json'} and {args.out / 'speed_accuracy.png'}")
        shutil.rmtree(scratch, ignore_errors=True)
    comm.Barrier()
    return 0


def plot(results: dict[str, list[dict]], path: Path) -> None:
    """A panel per scene: CPU time against error, Pareto front as a line."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colours = {None: "C0", "paper": "C3", "spin-softening": "C1", "stress-stiffening": "C2"}
    fig, axes = plt.subplots(
        1, max(1, len(results)), figsize=(6.2 * max(1, len(results)), 4.4), squeeze=False
    )
    for ax, (name, points) in zip(axes[0], results.items(), strict=False):
        for p in points:
            colour = colours.get(p["variant"], "C0") if p["method"] == "decoupled" else "C0"
            if p["reference"]:
                ax.axvline(p["cpu_s"], color="C0", ls=":")
                ax.annotate(
                    f"reference: {p['label']}",
                    (p["cpu_s"], 0.5),
                    xycoords=("data", "axes fraction"),
                    rotation=90,
                    ha="right",
                    va="center",
                    fontsize=7,
                    color="C0",
                )
                continue
            if not np.isfinite(p["error"]) or p["error"] > 1e3:
                ax.annotate(
                    f"{p['label']}: diverged",
                    (p["cpu_s"], 0.95),
                    xycoords=("data", "axes fraction"),
                    fontsize=7,
                    color=colour,
                    rotation=90,
                    va="top",
                )
                continue
            marker = "o" if p["method"] == "coupled" else "s"
            ax.loglog(p["cpu_s"], max(p["error"], 1e-12), marker, color=colour, ms=7)
            ax.annotate(
                p["label"],
                (p["cpu_s"], max(p["error"], 1e-12)),
                textcoords="offset points",
                xytext=(4, 3),
                fontsize=7,
            )
        front = pareto(
            [
                p
                for p in points
                if not p["reference"] and np.isfinite(p["error"]) and p["error"] <= 1e3
            ]
        )
        if front:
            ax.loglog(
                [p["cpu_s"] for p in front],
                [max(p["error"], 1e-12) for p in front],
                "k--",
                lw=0.8,
                label="Pareto front",
            )
            ax.legend(fontsize=8)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("CPU time [s] (sum over ranks)")
        ax.set_ylabel("error vs finest coupled run")
        ax.set_title(name)
        ax.grid(alpha=0.3, which="both")
    fig.suptitle("speed against accuracy: coupled (blue circles) and decoupled variants (squares)")
    fig.savefig(path, dpi=130, bbox_inches="tight")
    plt.close(fig)


if __name__ == "__main__":
    raise SystemExit(main())
