"""The shoulder report's entry points: :func:`write_report` and the ``bench`` hook.

Pure post-processing of the two finished run folders (rank 0 only, no dolfinx): compares the
decoupled run with the coupled one and writes ``report.json`` (metrics, per-angle values,
resources table; no bare NaN), ``report.md`` and the figures of :data:`FIGURES`.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from shoulder_fem.families.base import BenchReport
from shoulder_fem.families.shoulder.report.contents import FIGURES
from shoulder_fem.families.shoulder.report.data import RunData, load_run, uncorrected
from shoulder_fem.families.shoulder.report.figures import write_figures
from shoulder_fem.families.shoulder.report.metrics import compare_runs, resource_table, time_split
from shoulder_fem.families.shoulder.report.tables import comparison_table, markdown_report
from shoulder_fem.io.output import atomic_write_json, atomic_write_text, to_jsonable

ANGLE_MATCH_DEG = 0.05
"""Two runs reached the same final angle if they differ by less than this [deg] (each is
hit to within 1e-6 deg of its last target by the angle-controlled steps)."""


def _notes(
    runs: dict[str, RunData], fa: dict[str, float | None], metrics: dict[str, Any]
) -> list[str]:
    """The report's notes: what was not compared, and why."""
    dec = runs["decoupled"]
    notes = []
    if (
        any(r.summary.get("status") != "ok" for r in runs.values())
        or None in fa.values()
        or max(fa.values()) - min(fa.values()) > ANGLE_MATCH_DEG
    ):
        notes.append(
            "runs reached different angles or did not complete: compared at the common "
            "output angles "
            + (", ".join(f"{a:g}" for a in metrics["angles_compared_deg"]) or "(none)")
            + " deg"
        )
    if metrics.get("von_mises_note"):
        notes.append(metrics["von_mises_note"])
    if dec.summary.get("resources", {}).get("peak_rss_stage_reset") is False:
        notes.append(
            "per-part peak memory is the process peak up to the end of each part "
            "(the high-water mark could not be reset)"
        )
    return notes


def write_report(coupled_dir: Path, decoupled_dir: Path, out_dir: Path, level: str) -> dict:
    """Compare a coupled (reference) and a decoupled shoulder run; write figures and report.

    Rank 0 only (pure post-processing, no MPI). Writes ``report.json``, ``report.md`` and the
    figures of :data:`FIGURES` into ``out_dir`` (created if missing), each atomically.

    Args:
        coupled_dir: the coupled run's output folder (the reference).
        decoupled_dir: the decoupled run's output folder.
        out_dir: folder for the report.
        level: the runs' refinement level (stated in the report).

    Returns:
        The report as written to ``report.json`` (JSON types; NaN as None).

    Raises:
        FileNotFoundError: if a run folder lacks ``summary.json`` or ``shoulder.npz``.
        ValueError: if the runs' scapula meshes (or glenoid points) do not coincide
            (fewer than 99 % of the points within 1e-9 m).
    """
    cpl, dec = load_run(coupled_dir), load_run(decoupled_dir)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    runs = {"coupled": cpl, "decoupled": dec}
    metrics, pair = compare_runs(cpl, dec)

    fa = {m: r.final_angle for m, r in runs.items()}
    notes = _notes(runs, fa, metrics)
    recipes = {
        m: r.summary.get("parameters", {}).get("nodal_stress", "scalar") for m, r in runs.items()
    }
    if recipes["coupled"] != recipes["decoupled"]:
        notes.append(
            f"the nodal stresses are recovered differently (coupled: {recipes['coupled']}, "
            f"decoupled: {recipes['decoupled']}): their von Mises comparison is not like with like"
        )
    resources = resource_table(cpl, dec)
    n_polys = write_figures(runs, metrics, pair, resources, out_dir)
    rigid = uncorrected(dec)
    rigid_metrics = None if rigid is None else rigid_summary(compare_runs(cpl, rigid)[0])

    report: dict[str, Any] = {
        "scene": cpl.summary.get("scene"),
        "level": level,
        "runs": {"coupled": str(cpl.folder), "decoupled": str(dec.folder)},
        "status": {m: r.summary.get("status") for m, r in runs.items()},
        "messages": {m: r.summary.get("message") for m, r in runs.items()},
        "final_angle_deg": fa,
        "nodal_stress": recipes["coupled"],
        **{k: v for k, v in metrics.items() if k != "per_angle"},
        "section_z_m": {m: float(r.arrays.get("section_z", math.nan)) for m, r in runs.items()},
        "section_polygons": n_polys,
        "per_angle": metrics["per_angle"],
        "uncorrected": rigid_metrics,
        "resources": resources,
        "time_split": time_split(cpl, dec),
        "notes": notes,
        "figures": list(FIGURES),
    }
    report = to_jsonable(report)
    atomic_write_json(out_dir / "report.json", report)
    atomic_write_text(out_dir / "report.md", markdown_report(report) + "\n")
    return report


def rigid_summary(metrics: dict) -> dict:
    """What the report keeps of the rigid decoupling's comparison (a compliant run's)."""
    keys = (
        "max_pressure_rel_error",
        "max_pressure_rel_errors",
        "muscle_force_rel_error",
        "muscle_force_rel_errors",
        "contact_force_rel_error",
        "von_mises_correlation",
        "von_mises_slope",
    )
    out = {k: metrics.get(k) for k in keys}
    out["von_mises_slopes"] = {
        f"{row['angle_deg']:g}": row["scapula"]["slope"] for row in metrics["von_mises_per_angle"]
    }
    return out


def bench_report(bench: BenchReport) -> str:
    """The ``bench`` hook: :func:`write_report` of the two runs; returns the comparison table."""
    table = None
    if bench.comm.rank == 0:
        report = write_report(
            bench.folder / "coupled", bench.folder / "decoupled", bench.folder, bench.level
        )
        table = comparison_table(report)
    return bench.comm.bcast(table, root=0)
