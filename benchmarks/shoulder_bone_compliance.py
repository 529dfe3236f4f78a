"""Benchmark: the decoupling's modelling error against the bones' stiffness (shoulder study).

    OMP_NUM_THREADS=1 python benchmarks/shoulder_bone_compliance.py --level coarse \
        --out benchmarks/results
    OMP_NUM_THREADS=1 python benchmarks/shoulder_bone_compliance.py --level medium \
        --variants 1,1 10,10 --out benchmarks/results

Part 1 of the decoupled method holds the bones rigid; the coupled method has them elastic,
E = E0 (rho/rho0)^2. If the difference of the two in the muscle forces and the glenoid
pressure is the decoupling's own modelling error (the bones' compliance, which rigid bones lack
by construction) and not a numerical one, it must vanish as the bones are made stiffer, in
proportion to 1/E: part 1's rigid bones are the coupled model's limit of an infinite modulus.

The script runs the decoupled method once (part 1 does not depend on E; part 2 is linear in
1/E) and the coupled method once per variant ``S,H``: the scapula's and the humerus's modulus
multiplied by S and H (scene keys ``scapula_modulus_factor``, ``humerus_modulus_factor``), each
over the scene's 0-60 deg. It writes ``shoulder_bone_compliance_<level>.json`` (per variant and
output angle: the coupled values and the relative differences (decoupled - coupled)/coupled
of the subscapularis and infraspinatus forces and of the maximum glenoid pressure; each run's
CPU time) and a chart of the same (rank 0). It asserts nothing.
"""

from __future__ import annotations

import argparse
import json
import logging
import shutil
import tempfile
import time
from pathlib import Path

import matplotlib
import numpy as np
from mpi4py import MPI

from shoulder_fem import api
from shoulder_fem.cli import setup_logging
from shoulder_fem.io.output import atomic_write_json
from shoulder_fem.io.plots import plt, save_figure
from shoulder_fem.scene import load_scene

SCENE = "shoulder-internal-rotation"
#: (scapula, humerus) modulus factors: the paper's bones, both stiffer (3 x, 10 x), each alone
DEFAULT_VARIANTS = ("1,1", "3,3", "10,10", "10,1", "1,10")
#: series compared: name -> (label, unit)
SERIES = {
    "subscapularis_force": ("subscapularis force", "N"),
    "infraspinatus_force": ("infraspinatus force", "N"),
    "max_pressure": ("max glenoid pressure", "Pa"),
}
log = logging.getLogger("shoulder_bone_compliance")


def _variant(text: str) -> tuple[float, float]:
    try:
        s, h = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"variant '{text}': expected two factors 'SCAPULA,HUMERUS', e.g. 10,1"
        ) from None
    if s <= 0 or h <= 0:
        raise argparse.ArgumentTypeError(f"variant '{text}': the factors must be positive")
    return s, h


def _at_outputs(data: dict, name: str) -> dict[float, float]:
    s = data["series"][name]
    return {round(float(x), 6): float(y) for x, y in zip(s["x"], s["y"], strict=True)}


def _run(scene, method: str, level: str, out: Path, comm) -> dict:
    t0 = time.perf_counter()
    data = api.run(scene, method, level, out, comm=comm, replace=True).data
    if data.get("status") != "ok":
        raise RuntimeError(f"{method} run {out}: {data.get('status')}: {data.get('message')}")
    log.info("%s %s: %.0f s wall", method, out.name, time.perf_counter() - t0)
    return data


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--level", default="coarse")
    parser.add_argument(
        "--variants",
        nargs="+",
        type=_variant,
        default=[_variant(v) for v in DEFAULT_VARIANTS],
        metavar="S,H",
        help="scapula,humerus modulus factors per coupled run (default: %(default)s)",
    )
    parser.add_argument("--out", type=Path, required=True, help="folder for the JSON and chart")
    parser.add_argument(
        "--chart-only", action="store_true", help="redraw the chart from the JSON in --out"
    )
    args = parser.parse_args(argv)
    if args.chart_only:
        path = args.out / f"shoulder_bone_compliance_{args.level}.json"
        if not path.is_file():
            parser.error(f"--chart-only: {path} does not exist (run without --chart-only first)")
        _chart(json.loads(path.read_text()), path.with_suffix(".png"))
        return 0
    setup_logging(1, False)  # the package's progress lines, rank 0; the form compiler quiet
    log.handlers[:] = logging.getLogger("shoulder_fem").handlers
    log.setLevel(logging.INFO)
    comm = MPI.COMM_WORLD
    if comm.rank == 0 and not args.out.is_dir():
        parser.error(f"--out {args.out}: no such folder")
    scene = load_scene(SCENE)
    work = Path(comm.bcast(tempfile.mkdtemp(prefix="bone_compliance_") if comm.rank == 0 else None))
    try:
        dec = _run(scene, "decoupled", args.level, work / "decoupled", comm)
        variants = []
        for s, h in args.variants:
            sc = scene.with_values(scapula_modulus_factor=s, humerus_modulus_factor=h)
            cpl = _run(sc, "coupled", args.level, work / f"coupled_{s:g}_{h:g}", comm)
            row = {
                "scapula_modulus_factor": s,
                "humerus_modulus_factor": h,
                "cpu_s": cpl["resources"]["cpu_s"],
                "series": {},
            }
            for name in SERIES:
                c, d = _at_outputs(cpl, name), _at_outputs(dec, name)
                angles = [a for a in sorted(c) if a in d and a > 0]
                row["series"][name] = {
                    "angle_deg": angles,
                    "coupled": [c[a] for a in angles],
                    "rel_difference": [(d[a] - c[a]) / c[a] for a in angles],
                }
            variants.append(row)
    finally:
        if comm.rank == 0:
            shutil.rmtree(work, ignore_errors=True)
    if comm.rank == 0:
        result = {
            "scene": SCENE,
            "level": args.level,
            "ranks": comm.size,
            "decoupled_cpu_s": dec["resources"]["cpu_s"],
            "definition": "rel_difference = (decoupled - coupled) / coupled at each output angle",
            "variants": variants,
        }
        path = args.out / f"shoulder_bone_compliance_{args.level}.json"
        atomic_write_json(path, result)
        _chart(result, args.out / f"shoulder_bone_compliance_{args.level}.png")
        for row in variants:
            sub = row["series"]["subscapularis_force"]
            print(
                f"scapula x{row['scapula_modulus_factor']:g} humerus x"
                f"{row['humerus_modulus_factor']:g}: subscapularis "
                + " ".join(f"{100 * e:+.2f}%" for e in sub["rel_difference"])
            )
        print(f"written: {path}")
    return 0


def _chart(result: dict, path: Path) -> None:
    matplotlib.use("Agg")
    fig, axes = plt.subplots(
        1, len(SERIES), figsize=(4.2 * len(SERIES), 3.9), sharex=True, constrained_layout=True
    )
    for ax, (name, (label, _)) in zip(axes, SERIES.items(), strict=True):
        for i, row in enumerate(result["variants"]):
            s = row["series"][name]
            ax.plot(
                s["angle_deg"],
                100 * np.asarray(s["rel_difference"]),
                "o-",
                color=f"C{i}",
                label=f"E x {row['scapula_modulus_factor']:g} scapula, "
                f"x {row['humerus_modulus_factor']:g} humerus",
                ms=4,
            )
        if name.endswith("_force"):
            for y in (-1.0, 1.0):  # the paper's criterion for the muscle forces
                ax.axhline(y, color="0.5", lw=0.8, ls=":")
        ax.axhline(0.0, color="k", lw=0.6)
        ax.set_title(label)
        ax.set_xlabel("internal rotation (deg)")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("(decoupled - coupled) / coupled (%)")
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, 0.0), ncol=5, fontsize=8)
    fig.suptitle(
        f"{result['scene']} ({result['level']}): the decoupling's error against the bones' "
        "stiffness (part 1's rigid bones = E x infinity)",
        fontsize=9,
    )
    save_figure(fig, path)


if __name__ == "__main__":
    raise SystemExit(main())
