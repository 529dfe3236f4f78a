"""Benchmark: are the shoulder's outputs mesh-converged? Roache's GCI over coarse/medium/paper.

    OMP_NUM_THREADS=1 python benchmarks/mesh_convergence.py --out benchmarks/results

From three ``shoulder-fem bench shoulder-internal-rotation --level L`` folders of the default
model (0-60 deg; by default the committed ``shoulder_incompressible_<level>_0-60deg``), for
each method and each output angle: the output at the three levels, the apparent order, the
extrapolated value and the grid convergence index on the finest mesh
(:mod:`shoulder_fem.io.convergence`, Celik et al. 2008), and a verdict per output over the
angles. The representative size is the level's ``h_joint`` (the cartilages' and the glenoid's
element size, where the contact outputs are made: 12.5, 5 and 3 mm); the muscles' own size stops
at 6 mm from ``medium`` on, so their forces see the joint's refinement only there. Outputs:
the peak nodal contact pressure (a peak: at the cartilage's edge from 40-50 deg it is a
singular quantity), the contact force, the contact area and the mean contact pressure (force
over area), the three muscle forces and the scapula's largest nodal von Mises stress. Writes
``mesh_convergence.json``, ``mesh_convergence.md`` (the verdicts) and
``mesh_convergence.png`` / ``.pdf``; asserts nothing.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from shoulder_fem.io.convergence import CONVERGED_GCI, SETTLED_CHANGE, gci
from shoulder_fem.io.output import atomic_write_bytes, atomic_write_json
from shoulder_fem.io.plots import PRINT_STYLE, plt, save_figure

LEVELS = ("paper", "medium", "coarse")  # finest first
RESULTS = Path(__file__).parent / "results"
DEFAULT = [RESULTS / f"shoulder_incompressible_{level}_0-60deg" for level in LEVELS]
#: Output -> (label, unit shown, factor from SI).
OUTPUTS = {
    "max_pressure": ("peak contact pressure", "MPa", 1e-6),
    "mean_pressure": ("mean contact pressure", "MPa", 1e-6),
    "contact_force": ("contact force", "N", 1.0),
    "contact_area": ("contact area", "mm^2", 1e6),
    "subscapularis_force": ("subscapularis force", "N", 1.0),
    "supraspinatus_force": ("supraspinatus force", "N", 1.0),
    "infraspinatus_force": ("infraspinatus force", "N", 1.0),
    "scapula_max_von_mises": ("scapula's largest von Mises", "MPa", 1e-6),
}
METHODS = ("decoupled", "coupled")
#: The extrapolated values drawn: those of a band this narrow (wider ones extrapolate a
#: fitted order far outside the data).
SHOWN_GCI = 0.5


def _series(summary: dict, name: str) -> tuple[np.ndarray, np.ndarray]:
    ser = summary["series"]
    if name == "mean_pressure":  # force over area (the pressure-weighted mean pressure)
        x, force = ser["contact_force"]["x"], np.asarray(ser["contact_force"]["y"], float)
        area = np.asarray(ser["contact_area"]["y"], float)
        return np.asarray(x, float), np.divide(
            force, area, out=np.zeros_like(force), where=area > 0
        )
    return np.asarray(ser[name]["x"], float), np.asarray(ser[name]["y"], float)


def study(folders: list[Path]) -> dict:
    """Every output's convergence per method and angle from the three bench folders."""
    summaries, sources = {}, {}
    for folder in folders:
        for method in METHODS:
            s = json.loads((folder / f"{method}_summary.json").read_text())
            summaries[(s["level"], method)] = s
            sources[f"{s['level']}/{method}"] = {"folder": str(folder), "created": s["created"]}
    levels = sorted(
        {lv for lv, _ in summaries},
        key=lambda lv: summaries[(lv, "decoupled")]["level_settings"]["h_joint"],
    )
    if len(levels) != 3:
        raise SystemExit(f"mesh_convergence: three levels needed, got {levels}")
    h = tuple(summaries[(lv, "decoupled")]["level_settings"]["h_joint"] for lv in levels)
    out = {
        "scene": summaries[(levels[0], "decoupled")]["scene"],
        "levels": levels,
        "h_joint_m": list(h),
        "sources": sources,
        "converged_gci": CONVERGED_GCI,
        "settled_change": SETTLED_CHANGE,
        "methods": {},
    }
    for method in METHODS:
        rows = {}
        for name in OUTPUTS:
            per_level = [_series(summaries[(lv, method)], name) for lv in levels]
            angles = per_level[0][0]
            per_angle = []
            for j, angle in enumerate(angles):
                if angle <= 0:  # the unloaded joint: nothing to converge
                    continue
                phi = tuple(float(p[1][j]) for p in per_level)
                result = gci(h, phi)
                per_angle.append(
                    {"angle_deg": float(angle), "values": list(phi)} | result.as_dict()
                )
            verdicts = {r["verdict"] for r in per_angle}
            changes = [r["relative_change"] for r in per_angle]
            bands = [r["gci_fine"] for r in per_angle if r["gci_fine"] is not None]
            rows[name] = {
                "verdict": _overall(verdicts),
                "largest_last_change": max(changes),  # |phi_paper/phi_medium - 1|
                "largest_gci_fine": max(bands) if bands else None,
                "per_angle": per_angle,
            }
        out["methods"][method] = rows
    return out


def _overall(verdicts: set[str]) -> str:
    """One word for an output over the angles: the worst of its verdicts, named."""
    for word in ("diverging", "oscillatory", "converging", "settled"):
        if word in verdicts:
            return word if len(verdicts) == 1 else f"{word} at some angles"
    return "converged"


def plot(data: dict, path: Path) -> None:
    """Per output: its value at the three levels against the angle (decoupled), with the
    extrapolated value where the convergence is monotone; one scale per panel."""
    rows = data["methods"]["decoupled"]
    with plt.rc_context(PRINT_STYLE):
        fig, axes = plt.subplots(2, 4, figsize=(7.0, 3.8))
        for ax, (name, (label, unit, factor)) in zip(axes.flat, OUTPUTS.items(), strict=True):
            per = rows[name]["per_angle"]
            angles = [r["angle_deg"] for r in per]
            for k, level in enumerate(data["levels"]):
                ax.plot(
                    angles,
                    [r["values"][k] * factor for r in per],
                    "o-",
                    ms=2,
                    lw=0.8,
                    label=f"{level} ({data['h_joint_m'][k] * 1e3:g} mm)",
                )
            ext = [
                r["extrapolated"] * factor
                if r["gci_fine"] is not None and r["gci_fine"] <= SHOWN_GCI
                else np.nan
                for r in per
            ]
            ax.plot(
                angles, ext, "k+", ms=4, label=f"extrapolated (monotone, GCI <= {SHOWN_GCI:.0%})"
            )
            ax.set_title(f"{label}\n{rows[name]['verdict']}")
            ax.set_xlabel("rotation [deg]")
            ax.set_ylabel(f"[{unit}]")
            ax.grid(alpha=0.3)
        handles, labels = axes.flat[0].get_legend_handles_labels()
        fig.legend(handles, labels, loc="lower center", ncol=4, frameon=False)
        fig.suptitle(
            f"{data['scene']}, decoupled, over the mesh levels (converged: monotone, GCI <= "
            f"{data['converged_gci']:.0%}; settled: last change <= {data['settled_change']:.0%})"
        )
        fig.tight_layout(rect=(0, 0.06, 1, 1))
        save_figure(fig, path, vector=True)


def table(data: dict) -> str:
    """The verdicts as a Markdown table (``mesh_convergence.md``)."""
    levels = data["levels"]
    sizes = ", ".join(
        f"{lv} {h * 1e3:g} mm" for lv, h in zip(levels, data["h_joint_m"], strict=True)
    )
    lines = [
        f"# Mesh convergence of {data['scene']}'s outputs",
        "",
        f"Levels (h_joint): {sizes}. Written by `benchmarks/mesh_convergence.py` from the "
        "bench folders in `mesh_convergence.json` (`sources`). Converged: the differences "
        f"shrink monotonically and the GCI on the finest mesh is <= {data['converged_gci']:.0%}; "
        f"settled: not monotone, but the last refinement changed the value by <= "
        f"{data['settled_change']:.0%}. A peak (the contact pressure at the cartilage's edge, "
        "the bone's largest von Mises stress at a support) is a singular quantity and need not "
        "converge; the contact force, the mean pressure and the muscle forces may.",
        "",
    ]
    for method, rows in data["methods"].items():
        lines += [
            f"## {method}",
            "",
            "| output | verdict | largest last change | GCI_fine range | at 60 deg: "
            + " / ".join(levels)
            + " | extrapolated |",
            "|---|---|--:|--:|--:|--:|",
        ]
        for name, row in rows.items():
            label, unit, factor = OUTPUTS[name]
            last = row["per_angle"][-1]
            bands = [r["gci_fine"] for r in row["per_angle"] if r["gci_fine"] is not None]
            band = f"{min(bands):.1%} - {max(bands):.1%}" if bands else "-"
            values = " / ".join(f"{v * factor:.4g}" for v in last["values"])
            ext = last["extrapolated"]
            ext = f"{ext * factor:.4g}" if ext is not None else "-"
            lines.append(
                f"| {label} ({unit}) | {row['verdict']} | {row['largest_last_change']:.1%} | "
                f"{band} | {values} | {ext} |"
            )
        lines.append("")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--benches",
        nargs=3,
        type=Path,
        default=DEFAULT,
        help="three bench folders of the same scene at three levels",
    )
    ap.add_argument("--out", type=Path, default=RESULTS)
    args = ap.parse_args()
    data = study(args.benches)
    args.out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(args.out / "mesh_convergence.json", data)
    plot(data, args.out / "mesh_convergence.png")
    atomic_write_bytes(
        args.out / "mesh_convergence.md", lambda f: f.write(table(data).encode() + b"\n")
    )
    for method, rows in data["methods"].items():
        print(f"{method}:")
        for name, row in rows.items():
            band = row["largest_gci_fine"]
            print(
                f"  {name:24s} {row['verdict']:28s} last refinement changes it by up to "
                f"{row['largest_last_change']:.1%}"
                + (f", largest GCI {band:.1%}" if band is not None else "")
            )


if __name__ == "__main__":
    main()
