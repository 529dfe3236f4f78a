"""A finished shoulder run as the report reads it: its summary and its arrays.

A run folder of the ``shoulder`` scene family holds ``summary.json``
(:class:`shoulder_fem.io.results.Recorder`) and ``shoulder.npz`` (written by
:mod:`shoulder_fem.families.shoulder.model`) with

* ``angles_deg`` (n_out,): the output angles reached (normally 0, 10, ..., 60);
* ``glenoid_points`` (n_g, 3) [m], ``glenoid_pressure`` and ``glenoid_shear`` (n_out, n_g) [Pa],
  ``glenoid_centre`` (3,) [m] and ``glenoid_axis`` (3,) (unit, out of the glenoid);
* ``scapula_points`` (n_s, 3) [m], ``scapula_cells`` (n_c, 4) tetrahedra,
  ``scapula_von_mises`` (n_s,) [Pa] at ``von_mises_angle_deg`` (the last output angle), and
  ``scapula_von_mises_series`` (n_vm, n_s) [Pa] at every output angle ``von_mises_angles_deg``
  (n_vm,) (absent in runs written before 2026-11-26);
* ``section_z`` [m]: height of the horizontal section of the scapula through the contact.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from shoulder_fem.io.results import load_summary

NPZ_NAME = "shoulder.npz"
"""File name of a run's arrays inside its output folder."""

ANGLE_TOLERANCE = 1e-3
"""Two output angles are the same if they differ by less than this [deg]."""


@dataclass
class RunData:
    """One run folder: its ``summary.json`` and the arrays of ``shoulder.npz``."""

    folder: Path
    summary: dict
    arrays: dict[str, np.ndarray]

    @property
    def method(self) -> str:
        """The method named in the summary."""
        return str(self.summary.get("method"))

    @property
    def angles(self) -> np.ndarray:
        """Output angles reached [deg]."""
        return np.asarray(self.arrays.get("angles_deg", np.zeros(0)), dtype=float).reshape(-1)

    @property
    def final_angle(self) -> float | None:
        """The angle the run reached [deg]: probe ``final_angle_deg``, else the last output."""
        value = _probe(self.summary, "final_angle_deg")
        if value is None and "final_angle_deg" in self.arrays:
            value = float(self.arrays["final_angle_deg"])
        if value is None and len(self.angles):
            value = float(self.angles[-1])
        return value if value is None or math.isfinite(value) else None

    @property
    def von_mises_angle(self) -> float | None:
        """Angle of the nodal von Mises stresses [deg] (None if unknown)."""
        a = float(self.arrays.get("von_mises_angle_deg", math.nan))
        return a if math.isfinite(a) else None

    def series_at(self, name: str, angles: np.ndarray) -> np.ndarray:
        """Values of summary series ``name`` at ``angles`` (NaN where absent)."""
        out = np.full(len(angles), math.nan)
        ser = self.summary.get("series", {}).get(name)
        if not ser:
            return out
        x = np.array([math.nan if v is None else v for v in ser["x"]], dtype=float)
        y = np.array([math.nan if v is None else v for v in ser["y"]], dtype=float)
        for i, a in enumerate(angles):
            hit = np.flatnonzero(np.abs(x - a) < ANGLE_TOLERANCE)
            if len(hit):
                out[i] = y[hit[-1]]
        return out

    def max_pressure(self, angles: np.ndarray) -> np.ndarray:
        """Largest glenoid pressure at ``angles`` [Pa]: series ``max_pressure``, else the map."""
        p = self.series_at("max_pressure", angles)
        pressure = self.arrays.get("glenoid_pressure")
        if pressure is not None and pressure.size:
            for i, a in enumerate(angles):
                row = angle_index(self.angles, a)
                if not math.isfinite(p[i]) and row is not None:
                    p[i] = float(np.max(pressure[row]))
        return p


def _probe(summary: dict, name: str) -> float | None:
    """A numeric probe of a summary (plain value, or ``{"value": v, ...}``), or None."""
    value = summary.get("probes", {}).get(name)
    if isinstance(value, dict):
        value = value.get("value")
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    return float(value)


def angle_index(angles: np.ndarray, angle: float) -> int | None:
    """The index of ``angle`` [deg] in ``angles`` (within :data:`ANGLE_TOLERANCE`), or None."""
    hit = np.flatnonzero(np.abs(np.asarray(angles) - angle) < ANGLE_TOLERANCE)
    return int(hit[0]) if len(hit) else None


def uncorrected(run: RunData) -> RunData | None:
    """The paper's rigid decoupling inside a run with a compliant part 1 (``part1_bones``), or None.

    Such a run keeps the rigid pass's series, probes and arrays under the prefix
    ``uncorrected_`` (:mod:`shoulder_fem.families.shoulder.correction`): this is the run as if
    they were its results (its resources stay those of the whole run).
    """
    prefix = "uncorrected_"
    if prefix + "angles_deg" not in run.arrays:
        return None
    summary = dict(run.summary)
    for part in ("series", "probes"):
        values = dict(run.summary.get(part, {}))
        for name in [n for n in values if n.startswith(prefix)]:
            values[name[len(prefix) :]] = values.pop(name)
        summary[part] = values
    arrays = dict(run.arrays)
    for name in [n for n in arrays if n.startswith(prefix)]:
        arrays[name[len(prefix) :]] = arrays.pop(name)
    series = arrays.get("scapula_von_mises_series")
    if series is not None and len(series):  # the last angle's field, as in shoulder.npz
        arrays["scapula_von_mises"] = series[-1]
        arrays["von_mises_angle_deg"] = arrays["von_mises_angles_deg"][-1]
    return RunData(run.folder, summary, _maps_by_angle(arrays))


def _maps_by_angle(arrays: dict) -> dict:
    """``arrays`` with the glenoid's pressure and shear maps as (n_out, n_g) (in place)."""
    n_out = len(np.asarray(arrays.get("angles_deg", [])).reshape(-1))
    for key in ("glenoid_pressure", "glenoid_shear"):
        if key in arrays:
            arrays[key] = np.asarray(arrays[key], dtype=float).reshape(n_out, -1)
    return arrays


def load_run(folder: str | os.PathLike[str]) -> RunData:
    """Read a shoulder run folder.

    Args:
        folder: the run's output folder (with ``summary.json`` and ``shoulder.npz``).

    Returns:
        The run's data.

    Raises:
        FileNotFoundError: if either file is missing.
    """
    folder = Path(folder)
    summary = load_summary(folder)
    npz = folder / NPZ_NAME
    if not npz.is_file():
        raise FileNotFoundError(
            f"no {NPZ_NAME} in {folder} (status {summary.get('status')!r}: "
            f"{summary.get('message')}); cannot make the shoulder report"
        )
    with np.load(npz, allow_pickle=False) as data:
        arrays = {k: np.asarray(data[k]) for k in data.files}
    return RunData(folder, summary, _maps_by_angle(arrays))
