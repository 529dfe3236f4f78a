"""Benchmark: does an anatomical humeral cartilage keep the joint's contact off its edge?

    OMP_NUM_THREADS=1 python benchmarks/cartilage_cap.py --levels coarse medium \
        --out benchmarks/results

Issue 20, item 4. The scene's humeral cartilage ends 70 deg from its axis (head height 15.8 mm);
Iannotti 1992's head height, 19 +/- 2.4 mm, is a cap of about 78 deg, the option
``meshes.shoulder.ANATOMICAL_CAP`` (the cap and the insertion footprints turned clear of it).
The decoupled method (part 1 and part 2; the coupled runs place the contact within 0.2 deg of
it, ``test_shoulder``) turns the humerus 0-60 deg on both caps at each level. Per run and output
angle: where the glenoid presses on the humeral cartilage (force-weighted mean and farthest
point, deg from the cartilage's axis), the margin of the farthest point to the cartilage's
edge, the humerus's swing, the peak glenoid pressure and the muscle forces; per run its status,
steps, failed steps, Newton iterations and CPU time. Writes ``cartilage_cap.json`` and
``cartilage_cap.png``. Every figure is measured; it asserts nothing.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import matplotlib
from model_changes import one  # a sibling script: benchmarks/ is sys.path[0]

from shoulder_fem.io.output import atomic_write_json
from shoulder_fem.io.plots import plt, save_figure
from shoulder_fem.meshes.shoulder import ANATOMICAL_CAP

CAPS = {"70 deg (default)": [], "78 deg (anatomical)": list(ANATOMICAL_CAP)}
SERIES = (
    "humeral_cap_contact_angle",
    "humeral_cap_contact_angle_max",
    "humeral_cap_edge_margin",
    "humeral_swing",
    "max_pressure",
    "subscapularis_force",
    "infraspinatus_force",
    "supraspinatus_force",
    "scapula_max_von_mises",
)


def plot(data: dict, path: Path) -> None:
    """Contact position, margin, swing and peak pressure against the twist, per cap and level."""
    fig, axes = plt.subplots(1, 4, figsize=(17, 4.4), layout="constrained")
    colours = dict(zip(CAPS, ("C0", "C3"), strict=True))
    styles = {"coarse": ":", "medium": "-", "paper": "--"}
    for level, cases in data["levels"].items():
        for case, r in cases.items():
            s, kw = r["series"], {"color": colours[case], "ls": styles.get(level, "-")}
            ax = axes[0]
            ax.plot(*_xy(s, "humeral_cap_contact_angle_max"), **kw, label=f"{case}, {level}")
            ax.plot(*_xy(s, "humeral_cap_contact_angle"), **kw, marker=".", lw=0.8)
            ax.axhline(r["cap_half_angle_deg"], color=colours[case], lw=0.6)
            axes[1].plot(*_xy(s, "humeral_cap_edge_margin"), **kw)
            axes[2].plot(*_xy(s, "humeral_swing"), **kw)
            axes[3].plot(*_xy(s, "max_pressure", 1e-6), **kw)
    titles = (
        ("contact on the humeral cartilage:\nfarthest (line), mean (dots); edges (thin)", "deg"),
        ("margin of the farthest contact point\nto the cartilage's edge", "deg"),
        ("humerus swing (paper's supports)", "deg"),
        ("peak glenoid pressure", "MPa"),
    )
    for ax, (title, unit) in zip(axes, titles, strict=True):
        ax.set(xlabel="internal rotation (deg)", ylabel=unit, title=title)
    axes[0].legend(fontsize=7)
    fig.suptitle("decoupled method, the scene with the 70 deg cap and the anatomical 78 deg cap")
    save_figure(fig, path)


def _xy(series: dict, key: str, scale: float = 1.0) -> tuple[list, list]:
    return series[key]["x"], [v * scale for v in series[key]["y"]]


def main() -> None:
    matplotlib.use("Agg")
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--levels", nargs="+", default=["coarse", "medium"])
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results"))
    args = ap.parse_args()
    data = {"scene": "shoulder-internal-rotation", "caps": CAPS, "levels": {}}
    with tempfile.TemporaryDirectory(prefix="cartilage-cap-") as tmp:
        for level in args.levels:
            cases = {}
            for k, (case, overrides) in enumerate(CAPS.items()):
                out = Path(tmp) / f"{level}-{k}"
                cases[case] = one(level, overrides, "decoupled", out, series=SERIES)
                print(level, case, cases[case]["status"], f"{cases[case]['cpu_s']:.1f} s")
            data["levels"][level] = cases
    args.out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(args.out / "cartilage_cap.json", data)
    plot(data, args.out / "cartilage_cap.png")


if __name__ == "__main__":
    main()
