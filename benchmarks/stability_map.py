"""Stability map: where each decoupled variant follows the coupled method, and where it fails.

    python benchmarks/stability_map.py --out benchmarks/results
    python benchmarks/stability_map.py --ratios 0.5 1.5 --ramp-times 15 --out /tmp/map  # quick

Sweeps the spin-up beam's final spin rate Ωs relative to its first bending frequency ω1 and the
spin-up time T. For each point it runs the coupled method and each decoupled variant, and
records the tip-deflection error against coupled (largest difference over the run relative to
the coupled peak), whether the run diverged (solver failure, non-finite values, or a tip
deflection beyond the beam's length), and the two indicators a decoupled run computes from its
own results. Writes ``stability_map.json`` and ``stability_map.png``; asserts nothing.
"""

from __future__ import annotations

import argparse
import logging
import math
import shutil
import tempfile
from pathlib import Path

import numpy as np
from mpi4py import MPI

from shoulder_fem import RunFailed, load_scene, run
from shoulder_fem.io.compare import series_metrics
from shoulder_fem.io.output import atomic_write_json
from shoulder_fem.io.resources import blas_library

VARIANTS = ("paper", "spin-softening", "stress-stiffening")


def first_bending_frequency(p: dict) -> float:
    """Cantilever: ω1 = 1.8751² √(EI/(ρA L⁴)), I = a⁴/12 (rad/s)."""
    a, length = p["side"], p["outer_radius"] - p["inner_radius"]
    return 1.8751**2 * math.sqrt(p["youngs_modulus"] * a**2 / 12 / p["density"]) / length**2


def main(argv: list[str] | None = None) -> int:
    """Run the sweep; rank 0 writes the JSON and the map."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ratios", type=float, nargs="+", default=[0.25, 0.5, 1.0, 1.5, 2.0, 3.44])
    parser.add_argument("--ramp-times", type=float, nargs="+", default=[15.0, 7.5])
    parser.add_argument("--level", default="coarse")
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results"))
    args = parser.parse_args(argv)
    comm = MPI.COMM_WORLD
    logging.basicConfig(level=logging.ERROR)
    base = load_scene("spin-up-beam")
    p = base.values()
    omega1 = first_bending_frequency(p)
    length = p["outer_radius"] - p["inner_radius"]
    scratch = Path(comm.bcast(tempfile.mkdtemp(prefix="sfem-map-") if comm.rank == 0 else None))
    if comm.rank == 0:
        print(f"BLAS: {blas_library()}; ranks: {comm.size}; ω1 = {omega1:.4f} rad/s", flush=True)
    points = []
    for ramp in args.ramp_times:
        for ratio in args.ratios:
            rate = ratio * omega1
            # Coupled rotation error (ΩΔt)²/6 ≤ 0.2 %; Δt ≤ 20 ms keeps the scene's numerical
            # damping (needed by the coupled run at high spin) from dominating the small errors.
            dt = min(0.02, 0.1 / rate)
            scene = base.with_values(
                spin_rate=rate,
                spin_up_time=ramp,
                end_time=ramp + 5.0,
                time_step=dt,
                field_outputs=1,
            )
            ref = run(
                scene, "coupled", args.level, scratch / "coupled", comm=comm, replace=True
            ).data
            point = {
                "ratio": ratio,
                "spin_rate": rate,
                "ramp_time": ramp,
                "time_step": dt,
                "coupled_peak": ref["probes"]["peak_tip_deflection"],
                "coupled_cpu_s": ref["resources"]["cpu_s"],
                "variants": {},
            }
            for variant in VARIANTS:
                entry = {"diverged": False}
                try:
                    other = run(
                        scene.with_values(decoupled_variant=variant),
                        "decoupled",
                        args.level,
                        scratch / variant,
                        comm=comm,
                        replace=True,
                    ).data
                except RunFailed as err:
                    entry.update(diverged=True, reason=str(err))
                    other = err.summary.data
                tip = np.asarray(other["series"]["tip_deflection"]["y"], dtype=float)
                if not np.all(np.isfinite(tip)) or np.max(np.abs(tip)) > length:
                    entry["diverged"] = True
                metrics = series_metrics(
                    ref["series"]["tip_deflection"], other["series"]["tip_deflection"]
                )
                entry.update(
                    error=metrics["max_rel_diff"],
                    peak=other["probes"].get("peak_tip_deflection"),
                    decoupling_indicator=other["probes"].get("max_decoupling_indicator"),
                    spin_stiffness_ratio=other["probes"].get("max_spin_stiffness_ratio"),
                    cpu_s=other["resources"]["cpu_s"],
                )
                point["variants"][variant] = entry
            points.append(point)
            if comm.rank == 0:
                line = "  ".join(
                    f"{v}: " + ("DIVERGED" if e["diverged"] else f"{e['error']:.2e}")
                    for v, e in point["variants"].items()
                )
                print(f"Ωs/ω1 = {ratio:4.2f}, T = {ramp:4.1f} s: {line}", flush=True)
    record = {
        "benchmark": "stability_map",
        "scene": "spin-up-beam",
        "level": args.level,
        "omega1": omega1,
        "blas": blas_library(),
        "ranks": comm.size,
        "points": points,
        "error_definition": "max |tip(t) - tip_coupled(t)| / max |tip_coupled|",
    }
    if comm.rank == 0:
        args.out.mkdir(parents=True, exist_ok=True)
        atomic_write_json(args.out / "stability_map.json", record)
        plot(points, args.out / "stability_map.png", omega1)
        print(f"wrote {args.out / 'stability_map.json'} and {args.out / 'stability_map.png'}")
        shutil.rmtree(scratch, ignore_errors=True)
    comm.Barrier()
    return 0


def plot(points: list[dict], path: Path, omega1: float) -> None:
    """One panel per variant (Ωs/ω1 against T, colour = log10 error, × = diverged), and the
    indicators against the error."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(VARIANTS) + 1, figsize=(18, 4.6), layout="constrained")
    for ax, variant in zip(axes, VARIANTS, strict=False):
        for pt in points:
            e = pt["variants"][variant]
            if e["diverged"]:
                ax.plot(pt["ratio"], pt["ramp_time"], "kx", ms=12, mew=2)
            else:
                sc = ax.scatter(
                    pt["ratio"],
                    pt["ramp_time"],
                    c=[np.log10(max(e["error"], 1e-6))],
                    cmap="viridis",
                    vmin=-4,
                    vmax=0,
                    s=180,
                )
        ax.axvline(1.0, color="grey", ls=":")
        ax.set_xlabel("Ωs / ω1")
        ax.set_ylabel("spin-up time T [s]")
        ax.set_title(f"{variant}")
        ax.grid(alpha=0.3)
    fig.colorbar(sc, ax=list(axes[: len(VARIANTS)]), label="log10 tip-deflection error vs coupled")
    ax = axes[-1]
    for variant, marker in zip(VARIANTS, "os^", strict=True):
        xs = [
            pt["variants"][variant]["spin_stiffness_ratio"]
            for pt in points
            if not pt["variants"][variant]["diverged"]
        ]
        ys = [
            pt["variants"][variant]["error"]
            for pt in points
            if not pt["variants"][variant]["diverged"]
        ]
        ax.loglog(xs, ys, marker, label=variant, alpha=0.8)
    ax.set_xlabel("spin-stiffness ratio Ω²∫ρ|ũ⊥|²/∫σ:ε (decoupled run)")
    ax.set_ylabel("tip-deflection error vs coupled")
    ax.set_title("the indicator predicts the error")
    ax.grid(alpha=0.3, which="both")
    ax.legend()
    fig.suptitle(f"spin-up beam (ω1 = {omega1:.2f} rad/s): decoupled variants against coupled")
    fig.savefig(path, dpi=130)
    plt.close(fig)


if __name__ == "__main__":
    raise SystemExit(main())
