"""Figures: run against run, run against theory, resources (PNG, written atomically).

The backend is the caller's choice (the command line and the benchmarks select Agg).
"""

from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from shoulder_fem.io.output import atomic_write_bytes

METHOD_STYLE = {"coupled": dict(color="C0", lw=2.0), "decoupled": dict(color="C3", lw=1.2, ls="--")}


#: Font sizes of figures that print at a journal's double column (7 in): plt.rc_context(it).
PRINT_STYLE = {"font.size": 7, "axes.titlesize": 7, "legend.fontsize": 6}


def save_figure(fig, path: Path, vector: bool = False) -> Path:
    """Write a figure as PNG atomically (:func:`atomic_write_bytes`) and close it.

    ``vector``: a PDF beside it too (the same name, ``.pdf``), for print.
    """
    path = Path(path)
    atomic_write_bytes(path, lambda f: fig.savefig(f, format="png", dpi=150, bbox_inches="tight"))
    if vector:
        pdf = path.with_suffix(".pdf")
        atomic_write_bytes(pdf, lambda f: fig.savefig(f, format="pdf", bbox_inches="tight"))
    plt.close(fig)
    return path


def _label(summary: dict) -> str:
    return f"{summary.get('method')} ({summary.get('level')})"


#: Units shown in a reader's scale: (unit shown, factor from SI).
DISPLAY_UNITS = {"Pa": ("MPa", 1e-6), "m": ("mm", 1e3), "1": ("", 1.0)}


def _display(unit: str) -> tuple[str, float]:
    """(label unit, factor) of an SI unit on a plot axis: Pa as MPa, m as mm."""
    return DISPLAY_UNITS.get(unit, (unit, 1.0))


def plot_series(
    runs: list[dict],
    name: str,
    path: Path,
    title: str | None = None,
    reference: tuple[np.ndarray, np.ndarray, str] | None = None,
) -> Path:
    """Series ``name`` of several runs on one axis; optional analytic reference curve."""
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    ser = runs[0]["series"][name]
    (x_unit, fx), (y_unit, fy) = _display(ser["x_unit"]), _display(ser["y_unit"])
    for s in runs:
        ser = s["series"][name]
        x, y = fx * np.asarray(ser["x"], float), fy * np.asarray(ser["y"], float)
        ax.plot(x, y, label=_label(s), **METHOD_STYLE.get(s.get("method"), {}))
    if reference is not None:
        x, y, label = reference
        ax.plot(
            fx * np.asarray(x, float),
            fy * np.asarray(y, float),
            color="k",
            lw=0.8,
            ls=":",
            label=label,
        )
    ser = runs[0]["series"][name]
    x_name = "time" if ser["x_unit"] == "s" else ("position" if ser["x_unit"] == "m" else "x")
    ax.set_xlabel(f"{x_name} [{x_unit}]" if x_unit else x_name)
    ylabel = name.replace("_", " ")
    ax.set_ylabel(f"{ylabel} [{y_unit}]" if y_unit else ylabel)
    ax.set_title(title or f"{runs[0].get('scene')}: {name.replace('_', ' ')}")
    ax.grid(alpha=0.3)
    ax.legend()
    return save_figure(fig, path)


def plot_resources(runs: dict[str, dict], path: Path) -> Path:
    """Bars of CPU time and peak memory per run (the paper's Table II as a chart)."""
    labels = list(runs)
    cpu = [runs[k]["resources"]["cpu_s"] for k in labels]
    mem = [runs[k]["resources"]["peak_rss_mb"] for k in labels]
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(7.5, 3.2))
    a1.bar(labels, cpu, color=["C0", "C3"][: len(labels)])
    a1.set_ylabel("CPU time [s] (sum over ranks)")
    a2.bar(labels, mem, color=["C0", "C3"][: len(labels)])
    a2.set_ylabel("peak memory [MB] (sum over ranks)")
    for ax in (a1, a2):
        ax.grid(axis="y", alpha=0.3)
    fig.suptitle(f"{next(iter(runs.values())).get('scene')}: resources")
    return save_figure(fig, path)


def plot_cpu_vs_error(points: list[dict], path: Path, title: str) -> Path:
    """CPU time against error, one marker per run (label, method, cpu_s, error).

    A point with zero error is the reference itself: drawn as a vertical line at its CPU time.
    """
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for p in points:
        color = "C0" if p["method"] == "coupled" else "C3"
        if p["error"] == 0.0:
            ax.axvline(p["cpu_s"], color=color, ls=":", lw=1.2)
            ax.annotate(
                f"reference: {p['label']}",
                (p["cpu_s"], 0.5),
                xycoords=("data", "axes fraction"),
                rotation=90,
                ha="right",
                va="center",
                fontsize=8,
                color=color,
            )
            continue
        marker = "o" if p["method"] == "coupled" else "s"
        ax.loglog(p["cpu_s"], p["error"], marker, color=color, ms=7)
        ax.annotate(
            p["label"],
            (p["cpu_s"], p["error"]),
            textcoords="offset points",
            xytext=(5, 4),
            fontsize=8,
        )
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("CPU time [s] (sum over ranks)")
    ax.set_ylabel("relative error")
    ax.set_title(title)
    ax.grid(alpha=0.3, which="both")
    return save_figure(fig, path)


def plot_pressure_profile(
    r: np.ndarray,
    p: np.ndarray,
    theory: tuple[np.ndarray, np.ndarray],
    path: Path,
    title: str = "contact pressure",
    fitted: tuple[np.ndarray, np.ndarray] | None = None,
) -> Path:
    """Contact pressure at the contact points against their distance from the axis.

    With the analytic profile ``theory`` = (r, p), e.g. Hertz's p0 sqrt(1 - r²/a²), and
    optionally the same profile ``fitted`` to the points; SI in, mm and MPa on the axes.
    """
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    ax.plot(
        np.asarray(r) * 1e3, np.asarray(p) * 1e-6, ".", ms=3, color="C0", label="FE contact points"
    )
    ax.plot(
        np.asarray(theory[0]) * 1e3,
        np.asarray(theory[1]) * 1e-6,
        "-",
        color="k",
        lw=1.5,
        label="Hertz",
    )
    if fitted is not None:
        ax.plot(
            np.asarray(fitted[0]) * 1e3,
            np.asarray(fitted[1]) * 1e-6,
            "--",
            color="C3",
            lw=1.2,
            label="Hertz profile fitted to the points",
        )
    ax.set_xlabel("distance from the axis (mm)")
    ax.set_ylabel("contact pressure (MPa)")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend()
    return save_figure(fig, path)
