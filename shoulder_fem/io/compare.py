"""Metrics between a reference run (normally coupled) and another run (normally decoupled).

Everything here works on two ``summary.json`` dicts, so any two runs of the same scene can be
compared after the fact: probes (relative differences), series (the other run interpolated onto
the reference's abscissae), and the resources ratios that the benchmark tables quote.
"""

from __future__ import annotations

import math

import numpy as np


def relative_difference(ref: float, other: float, floor: float = 0.0) -> float:
    """(other − ref)/|ref|, with |ref| floored by ``floor`` (avoid dividing by ~0)."""
    scale = max(abs(ref), floor)
    if scale == 0.0:
        return 0.0 if other == ref else math.inf
    return (other - ref) / scale


def series_metrics(ref: dict, other: dict) -> dict:
    """Differences of two series {x, y}: the other interpolated onto the reference's x.

    Returns:
        max_abs_diff, rms_diff (y units), max_rel_diff (max |Δy| / max |y_ref|), correlation
        and least-squares slope of other against ref (through the origin, as the paper's
        Fig. 5), and n (points compared).
    """
    xr, yr = np.asarray(ref["x"], float), np.asarray(ref["y"], float)
    xo, yo = np.asarray(other["x"], float), np.asarray(other["y"], float)
    lo, hi = max(xr.min(), xo.min()), min(xr.max(), xo.max())
    keep = (xr >= lo - 1e-12 * abs(lo)) & (xr <= hi + 1e-12 * abs(hi))
    xr, yr = xr[keep], yr[keep]
    yi = np.interp(xr, xo, yo) if not np.array_equal(xr, xo[: len(xr)]) else yo[: len(xr)]
    diff = yi - yr
    scale = float(np.max(np.abs(yr))) if len(yr) else 0.0
    corr = float(np.corrcoef(yr, yi)[0, 1]) if len(yr) > 1 and np.std(yr) > 0 else math.nan
    slope = float(np.dot(yr, yi) / np.dot(yr, yr)) if np.dot(yr, yr) > 0 else math.nan
    return {
        "n": int(len(yr)),
        "max_abs_diff": float(np.max(np.abs(diff))) if len(diff) else math.nan,
        "rms_diff": float(np.sqrt(np.mean(diff**2))) if len(diff) else math.nan,
        "max_rel_diff": float(np.max(np.abs(diff)) / scale) if scale > 0 else math.nan,
        "correlation": corr,
        "slope": slope,
    }


def resource_ratios(ref: dict, other: dict) -> dict:
    """Ratios the tables quote: speedup_cpu = ref CPU / other CPU, memory_ratio = other / ref."""
    r, o = ref["resources"], other["resources"]

    def ratio(a: float, b: float) -> float:
        return a / b if b else math.nan

    return {
        "speedup_cpu": ratio(r["cpu_s"], o["cpu_s"]),
        "speedup_wall": ratio(r["wall_s"], o["wall_s"]),
        "memory_ratio": ratio(o["peak_rss_mb"], r["peak_rss_mb"]),
        "results_disk_ratio": ratio(o["results_disk_mb"], r["results_disk_mb"]),
    }


def _run_info(summary: dict) -> dict:
    """Method, level, status and validity (``inside``/``outside`` with its reason, or None)."""
    return {
        "method": summary.get("method"),
        "level": summary.get("level"),
        "status": summary.get("status"),
        "validity": summary.get("validity"),
        "validity_reason": summary.get("validity_reason"),
    }


def compare_summaries(ref: dict, other: dict) -> dict:
    """All metrics between two runs' summaries (JSON-ready)."""
    if ref.get("scene") != other.get("scene"):
        raise ValueError(
            f"cannot compare runs of different scenes: '{ref.get('scene')}' and "
            f"'{other.get('scene')}'"
        )
    probes = {}
    for name in sorted(set(ref["probes"]) & set(other["probes"])):
        a, b = ref["probes"][name], other["probes"][name]
        if isinstance(a, int | float) and isinstance(b, int | float):
            probes[name] = {
                "reference": a,
                "other": b,
                "relative_difference": relative_difference(a, b),
            }
    series = {
        name: series_metrics(ref["series"][name], other["series"][name])
        for name in sorted(set(ref["series"]) & set(other["series"]))
        if len(ref["series"][name]["x"]) and len(other["series"][name]["x"])
    }
    return {
        "scene": ref.get("scene"),
        "reference": _run_info(ref),
        "other": _run_info(other),
        "probes": probes,
        "series": series,
        "resources": {
            "reference": ref["resources"],
            "other": other["resources"],
            **resource_ratios(ref, other),
        },
    }


def resources_table(runs: dict[str, dict]) -> str:
    """A Markdown table of resources per run and stage (the paper's Table II, extended)."""
    lines = [
        "| run | stage | CPU s | wall s | peak memory MB | temp disk MB | results disk MB "
        "| ranks | DOFs |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for label, s in runs.items():
        res = s["resources"]
        lines.append(
            f"| {label} | total | {res['cpu_s']:.2f} | {res['wall_s']:.2f} | "
            f"{res['peak_rss_mb']:.0f} | {res['temp_disk_mb']:.2f} | {res['results_disk_mb']:.2f} "
            f"| {res['ranks']} | {s.get('dofs', '')} |"
        )
        for st in s.get("stages", []):
            lines.append(
                f"| {label} | {st['name']} | {st['cpu_s']:.2f} | {st['wall_s']:.2f} | "
                f"{st['peak_rss_mb']:.0f} | | | | |"
            )
    return "\n".join(lines)
