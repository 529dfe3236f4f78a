"""Benchmark: the humerus on the paper's 4 vertical distal elements against the scene's default.

    OMP_NUM_THREADS=1 python benchmarks/paper_supports.py --levels coarse medium \
        --out benchmarks/results

Both methods, 0-60 deg, with ``humerus_horizontal_stiffness`` = 0 (the paper's supports only)
and with the scene's value (two horizontal elements added). Per run, per output angle: the
humerus's swing, how far the contact reaches on the humeral cartilage (its edge is the cap's
half-angle), the peak pressure, the subscapularis force and the supports' forces. Writes
``paper_supports.json`` and ``paper_supports.png``. Every figure is measured; it asserts nothing.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import matplotlib

from shoulder_fem import load_scene, run
from shoulder_fem.io.output import atomic_write_json
from shoulder_fem.io.plots import plt, save_figure

SERIES = (
    "humeral_swing",
    "humeral_cap_contact_angle_max",
    "max_pressure",
    "subscapularis_force",
    "humerus_distal_support_force",
    "humerus_horizontal_support_force",
)
METHODS = ("coupled", "decoupled")


def one(level: str, horizontal: str | None, method: str, out: Path) -> dict:
    scene = load_scene("shoulder-internal-rotation")
    if horizontal is not None:
        scene = scene.with_overrides([f"humerus_horizontal_stiffness={horizontal}"])
    r = run(scene, method, level=level, out=out)
    return {
        "status": r.status,
        "final_angle_deg": r.probes["final_angle_deg"],
        "failed_steps": r.probes["failed_steps"],
        "newton_iterations": r.probes["newton_iterations"],
        "cap_half_angle_deg": r.probes["humeral_cap_half_angle_deg"],
        "cpu_s": r.resources["cpu_s"],
        "series": {k: {"x": r.series[k]["x"], "y": r.series[k]["y"]} for k in SERIES},
    }


def plot(data: dict, path: Path) -> None:
    fig, ax = plt.subplots(1, 4, figsize=(16, 3.9), layout="constrained")
    styles = {"paper": "-", "default": "--"}
    colours = {"coarse": "C0", "medium": "C3"}
    for level, cases in data["levels"].items():
        for case, runs in cases.items():
            r = runs["coupled"]
            kw = {"color": colours.get(level, "k"), "ls": styles[case]}
            lab = f"{level}, {case}"
            s = r["series"]
            ax[0].plot(s["humeral_swing"]["x"], s["humeral_swing"]["y"], label=lab, **kw)
            c = s["humeral_cap_contact_angle_max"]
            ax[1].plot(c["x"], c["y"], **kw)
            p = s["max_pressure"]
            ax[2].plot(p["x"], [v / 1e6 for v in p["y"]], **kw)
            v = s["humerus_distal_support_force"]
            ax[3].plot(v["x"], v["y"], **kw)
            if case == "default":
                h = s["humerus_horizontal_support_force"]
                ax[3].plot(h["x"], h["y"], color=kw["color"], ls=":")
        edge = next(iter(cases.values()))["coupled"]["cap_half_angle_deg"]
    ax[1].axhline(edge, color="k", lw=0.8)
    ax[1].text(32, edge - 5, "edge of the humeral cartilage", fontsize=7)
    ax[0].set(xlabel="internal rotation (deg)", ylabel="deg", title="humerus swing")
    ax[1].set(
        xlabel="internal rotation (deg)", ylabel="deg", title="contact's reach on the humeral cap"
    )
    ax[2].set(xlabel="internal rotation (deg)", ylabel="MPa", title="peak glenoid pressure")
    ax[3].set(
        xlabel="internal rotation (deg)",
        ylabel="N",
        title="supports: vertical (solid/dashed), horizontal (dotted)",
    )
    ax[0].legend(fontsize=7)
    fig.suptitle(
        "coupled method; paper = the 4 vertical elements only, default = + 2 horizontal", fontsize=9
    )
    save_figure(fig, path)


def main() -> None:
    matplotlib.use("Agg")
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--levels", nargs="+", default=["coarse", "medium"])
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results"))
    args = ap.parse_args()
    data = {"scene": "shoulder-internal-rotation", "levels": {}}
    with tempfile.TemporaryDirectory(prefix="supports-") as tmp:
        for level in args.levels:
            cases = {}
            for case, value in (("paper", "0N/mm"), ("default", None)):
                cases[case] = {
                    m: one(level, value, m, Path(tmp) / f"{level}-{case}-{m}") for m in METHODS
                }
                print(level, case, {m: cases[case][m]["status"] for m in METHODS}, flush=True)
            data["levels"][level] = cases
    args.out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(args.out / "paper_supports.json", data)
    plot(data, args.out / "paper_supports.png")


if __name__ == "__main__":
    main()
