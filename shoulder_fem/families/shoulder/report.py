"""The shoulder study's report: coupled (reference) against decoupled, the paper's figures.

Pure post-processing of two finished run folders of the ``shoulder`` scene family (rank 0 only,
no dolfinx, no MPI). Each folder holds ``summary.json`` (:class:`shoulder_fem.results.Recorder`)
and ``shoulder.npz`` (written by :mod:`shoulder_fem.shoulder`) with

* ``angles_deg`` (n_out,): the output angles reached (normally 0, 10, ..., 60);
* ``glenoid_points`` (n_g, 3) [m], ``glenoid_pressure`` and ``glenoid_shear`` (n_out, n_g) [Pa],
  ``glenoid_centre`` (3,) [m] and ``glenoid_axis`` (3,) (unit, out of the glenoid);
* ``scapula_points`` (n_s, 3) [m], ``scapula_cells`` (n_c, 4) tetrahedra,
  ``scapula_von_mises`` (n_s,) [Pa] at ``von_mises_angle_deg`` (the last output angle);
* ``section_z`` [m]: height of the horizontal section of the scapula through the contact.

:func:`write_report` writes into the report folder:

* ``pressure_maps.png`` (paper Fig. 2), ``max_pressure.png``, ``muscle_forces.png`` (Fig. 3),
  ``section_von_mises.png`` (Fig. 4), ``von_mises_scatter.png`` (Fig. 5),
  ``von_mises_error_histogram.png``, ``resources.png``;
* ``report.json`` (metrics, per-angle values, resources table; no bare NaN) and ``report.md``.

Runs that stopped early are compared at their common output angles only; the angle each run
reached is stated. The nodal von Mises stresses are compared only if both runs give them at the
same angle (otherwise the figures are drawn, the metrics are null and a note says why).
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import matplotlib.tri as mtri
import numpy as np
from matplotlib.collections import PolyCollection
from matplotlib.ticker import MaxNLocator

from shoulder_fem.families.base import BenchReport
from shoulder_fem.io.compare import resource_ratios
from shoulder_fem.io.plots import METHOD_STYLE, save_figure
from shoulder_fem.io.results import atomic_write_json, atomic_write_text, load_summary, to_jsonable

__all__ = [
    "FIGURES",
    "MATCH_TOLERANCE",
    "RunData",
    "comparison_table",
    "glenoid_plane_coordinates",
    "load_run",
    "match_points",
    "slice_tetrahedra",
    "write_report",
]

NPZ_NAME = "shoulder.npz"
"""File name of a run's arrays inside its output folder."""

MATCH_TOLERANCE = 1e-9
"""Two points of the two runs are the same point if they are this close [m]."""

MIN_MATCHED_FRACTION = 0.99
"""Fewer matched points than this fraction means the two runs are not on the same mesh."""

ANGLE_TOLERANCE = 1e-3
"""Two output angles are the same if they differ by less than this [deg]."""

ANGLE_MATCH_DEG = 0.05
"""Two runs reached the same final angle if they differ by less than this [deg] (each is
within the scene's ``angle_tolerance`` of its last target, 0.01 deg by default)."""

CONTACT_THRESHOLD = 0.01
"""A glenoid point is in contact if its pressure exceeds this fraction of the coupled maximum."""

MUSCLES = ("infraspinatus", "subscapularis")
"""Muscles whose forces are compared (Fig. 3); the supraspinatus is drawn too."""

FIGURES = {
    "pressure_maps.png": "Glenoid contact pressure every 10 deg (Fig. 2)",
    "max_pressure.png": "Maximum glenoid pressure against the rotation angle",
    "muscle_forces.png": "Muscle forces against the rotation angle (Fig. 3)",
    "section_von_mises.png": "Von Mises stress in the horizontal section of the scapula (Fig. 4)",
    "von_mises_scatter.png": "Nodal von Mises stress, decoupled against coupled (Fig. 5)",
    "von_mises_error_histogram.png": "Histogram of the nodal von Mises differences",
    "resources.png": "CPU time, peak memory and results disk per method and part",
}
"""The figures :func:`write_report` writes, with their captions."""

METHODS = ("coupled", "decoupled")
RESOURCE_COLUMNS = ("coupled", "decoupled_part1", "decoupled_part2", "decoupled")
RESOURCE_LABELS = {
    "coupled": "coupled",
    "decoupled_part1": "decoupled part 1",
    "decoupled_part2": "decoupled part 2",
    "decoupled": "decoupled total",
}
RESOURCE_ROWS = (
    ("cpu_s", "CPU s", ".1f"),
    ("peak_rss_mb", "peak memory MB", ".0f"),
    ("temp_disk_mb", "temporary disk MB", ".2f"),
    ("results_disk_mb", "results disk MB", ".2f"),
    ("wall_s", "wall s", ".1f"),
    ("ranks", "ranks", "d"),
    ("dofs", "DOFs", "d"),
)
MPA = 1e-6


# --------------------------------------------------------------------------------------------
# Geometry helpers
# --------------------------------------------------------------------------------------------


def glenoid_plane_coordinates(
    points: np.ndarray, centre: np.ndarray, axis: np.ndarray
) -> np.ndarray:
    """Project points onto the glenoid plane: (anterior, superior) coordinates.

    The in-plane basis is e_sup, the unit projection of +z (superior) onto the plane normal to
    ``axis`` (+y if ``axis`` is parallel to z), and e_ant = ±axis × e_sup with the sign making
    it point to +y (anterior).

    Args:
        points: (n, 3) points [m].
        centre: (3,) origin of the plane coordinates [m].
        axis: (3,) normal of the glenoid plane (any length but zero).

    Returns:
        (n, 2) array: column 0 anterior, column 1 superior [m], relative to ``centre``.

    Raises:
        ValueError: if ``axis`` is zero.
    """
    n = np.asarray(axis, dtype=float)
    norm = np.linalg.norm(n)
    if not norm > 0:
        raise ValueError(f"glenoid axis must not be zero: {axis}")
    n = n / norm

    def in_plane(v: np.ndarray) -> np.ndarray | None:
        w = v - np.dot(v, n) * n
        length = np.linalg.norm(w)
        return w / length if length > 1e-8 else None

    e_sup = in_plane(np.array([0.0, 0.0, 1.0]))
    if e_sup is None:
        e_sup = in_plane(np.array([0.0, 1.0, 0.0]))
    assert e_sup is not None
    e_ant = np.cross(n, e_sup)
    if e_ant[1] < 0 or (e_ant[1] == 0 and e_ant[0] < 0):
        e_ant = -e_ant
    d = np.asarray(points, dtype=float).reshape(-1, 3) - np.asarray(centre, dtype=float)
    return np.column_stack([d @ e_ant, d @ e_sup])


def slice_tetrahedra(
    points: np.ndarray, cells: np.ndarray, values: np.ndarray, z: float
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Cut a tetrahedral mesh with the horizontal plane ``z`` = const.

    Every tetrahedron whose vertices lie on both sides of the plane is cut (a vertex exactly on
    the plane counts as above it, so a face lying in the plane is produced once, by the
    tetrahedron below it; a plane through the lowest vertices of the mesh therefore cuts
    nothing). The cut points are on the cut edges; the nodal values are
    interpolated linearly along them. One vertex on one side gives a triangle, two on each side
    a quadrilateral (vertices in cyclic order). Polygons of zero area are dropped.

    Args:
        points: (n, 3) vertex coordinates.
        cells: (m, 4) vertex indices of the tetrahedra.
        values: (n,) nodal values.
        z: height of the plane (same unit as ``points``).

    Returns:
        ``(polygons, polygon_values)``: lists of (k, 2) arrays of the (x, y) of the cut points
        and of (k,) arrays of the interpolated values, k = 3 or 4.

    Raises:
        ValueError: on inconsistent array shapes.
    """
    points = np.asarray(points, dtype=float)
    cells = np.asarray(cells, dtype=np.int64)
    values = np.asarray(values, dtype=float)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must be (n, 3), not {points.shape}")
    if values.shape != (len(points),):
        raise ValueError(f"values must be ({len(points)},), not {values.shape}")
    if cells.size == 0:
        return [], []
    if cells.ndim != 2 or cells.shape[1] != 4:
        raise ValueError(f"cells must be (m, 4), not {cells.shape}")
    s = points[cells, 2] - float(z)
    above = s >= 0.0
    k = above.sum(axis=1)
    order = np.argsort(~above, axis=1, kind="stable")  # vertices above the plane first
    V = np.take_along_axis(cells, order, axis=1)
    S = np.take_along_axis(s, order, axis=1)

    def cut(rows: np.ndarray, edges: Sequence[tuple[int, int]]) -> tuple[np.ndarray, np.ndarray]:
        xy, f = [], []
        for i, j in edges:
            a, b = V[rows, i], V[rows, j]
            t = S[rows, i] / (S[rows, i] - S[rows, j])  # never 0/0: signs differ
            xy.append(points[a, :2] + t[:, None] * (points[b, :2] - points[a, :2]))
            f.append(values[a] + t * (values[b] - values[a]))
        return np.stack(xy, axis=1), np.stack(f, axis=1)

    pieces = [
        cut(np.flatnonzero(k == 1), ((0, 1), (0, 2), (0, 3))),
        cut(np.flatnonzero(k == 3), ((3, 0), (3, 1), (3, 2))),
        cut(np.flatnonzero(k == 2), ((0, 2), (0, 3), (1, 3), (1, 2))),
    ]
    extent = float(np.ptp(points[:, :2], axis=0).max()) if len(points) else 0.0
    tiny = 1e-14 * extent**2
    polygons: list[np.ndarray] = []
    polygon_values: list[np.ndarray] = []
    for xy, f in pieces:
        if not len(xy):
            continue
        x, y = xy[..., 0], xy[..., 1]
        area = 0.5 * np.abs(np.sum(x * np.roll(y, -1, axis=1) - np.roll(x, -1, axis=1) * y, 1))
        keep = area > tiny
        polygons.extend(xy[keep])
        polygon_values.extend(f[keep])
    return polygons, polygon_values


def match_points(
    reference: np.ndarray, other: np.ndarray, tol: float = MATCH_TOLERANCE
) -> tuple[np.ndarray, np.ndarray, float]:
    """Pair the points of two clouds that coincide (within ``tol``).

    Args:
        reference: (n, 3) points.
        other: (m, 3) points.
        tol: largest distance of a pair.

    Returns:
        ``(i_ref, i_other, fraction)``: indices of the pairs (``reference[i_ref[k]]`` is
        ``other[i_other[k]]``) and the number of pairs over max(n, m) (1 for two empty clouds).
    """
    from scipy.spatial import cKDTree

    reference = np.asarray(reference, dtype=float).reshape(-1, 3)
    other = np.asarray(other, dtype=float).reshape(-1, 3)
    n = max(len(reference), len(other))
    if n == 0:
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty, 1.0
    if len(reference) == 0 or len(other) == 0:
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty, 0.0
    if reference.shape == other.shape and np.all(np.abs(reference - other) <= tol):
        idx = np.arange(len(reference))
        return idx, idx.copy(), 1.0
    dist, j = cKDTree(other).query(reference, distance_upper_bound=tol)
    ok = np.isfinite(dist) & (dist <= tol)
    i_ref, i_other = np.flatnonzero(ok), j[ok].astype(np.int64)
    # one-to-one: a point of ``other`` paired twice counts once
    i_other, first = np.unique(i_other, return_index=True)
    i_ref = i_ref[first]
    order = np.argsort(i_ref)
    return i_ref[order], i_other[order], len(i_ref) / n


# --------------------------------------------------------------------------------------------
# Loading a run
# --------------------------------------------------------------------------------------------


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
                row = _angle_index(self.angles, a)
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


def _angle_index(angles: np.ndarray, angle: float) -> int | None:
    hit = np.flatnonzero(np.abs(np.asarray(angles) - angle) < ANGLE_TOLERANCE)
    return int(hit[0]) if len(hit) else None


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
    n_out = len(np.asarray(arrays.get("angles_deg", [])).reshape(-1))
    for key in ("glenoid_pressure", "glenoid_shear"):
        if key in arrays:
            arrays[key] = np.asarray(arrays[key], dtype=float).reshape(n_out, -1)
    return RunData(folder, summary, arrays)


# --------------------------------------------------------------------------------------------
# Metrics
# --------------------------------------------------------------------------------------------


def _common_angles(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The angles of ``a`` that ``b`` also reached."""
    return np.array([x for x in a if _angle_index(b, x) is not None], dtype=float)


def _key(angle: float) -> str:
    return f"{angle:g}"


def _rel(other: float, ref: float) -> float | None:
    """(other - ref)/ref, or None if ref is not positive or a value is missing."""
    if not (math.isfinite(other) and math.isfinite(ref)) or ref <= 0:
        return None
    return (other - ref) / ref


def _max_abs(values: Sequence[float | None]) -> float | None:
    finite = [abs(v) for v in values if v is not None and math.isfinite(v)]
    return max(finite) if finite else None


def _jaccard(cpl: RunData, dec: RunData, angles: np.ndarray, pair: tuple) -> dict[str, Any]:
    """Overlap of the contact regions (points above 1 % of the coupled maximum) per angle."""
    i_c, i_d = pair
    out: dict[str, Any] = {}
    for a in angles:
        rc, rd = _angle_index(cpl.angles, a), _angle_index(dec.angles, a)
        pc = cpl.arrays["glenoid_pressure"][rc][i_c]
        pd = dec.arrays["glenoid_pressure"][rd][i_d]
        threshold = CONTACT_THRESHOLD * float(np.max(pc)) if len(pc) else 0.0
        in_c, in_d = pc > threshold, pd > threshold
        union = int(np.sum(in_c | in_d))
        out[_key(a)] = int(np.sum(in_c & in_d)) / union if union else None
    return out


def _von_mises_metrics(cpl: RunData, dec: RunData, pair: tuple) -> dict[str, Any]:
    """Correlation, slope and errors of the matched nodal von Mises stresses."""
    i_c, i_d = pair
    a_c, a_d = cpl.von_mises_angle, dec.von_mises_angle
    result: dict[str, Any] = {
        "von_mises_angle_deg": {"coupled": a_c, "decoupled": a_d},
        "von_mises_nodes_compared": int(len(i_c)),
        "von_mises_correlation": None,
        "von_mises_slope": None,
        "von_mises_max_abs_error_mpa": None,
        "von_mises_rms_error_mpa": None,
        "von_mises_max_rel_error": None,
        "von_mises_coupled_max_mpa": None,
        "von_mises_note": None,
    }
    if a_c is None or a_d is None or abs(a_c - a_d) >= ANGLE_TOLERANCE:
        result["von_mises_note"] = (
            f"von Mises stresses not compared: coupled at {_fmt(a_c, 'g')} deg, "
            f"decoupled at {_fmt(a_d, 'g')} deg"
        )
        return result
    if not len(i_c):
        result["von_mises_note"] = "von Mises stresses not compared: no scapula vertices"
        return result
    c = np.asarray(cpl.arrays["scapula_von_mises"], dtype=float)[i_c]
    d = np.asarray(dec.arrays["scapula_von_mises"], dtype=float)[i_d]
    diff = d - c
    cmax = float(np.max(np.abs(c)))
    cc = float(np.dot(c, c))
    if len(c) > 1 and np.std(c) > 0 and np.std(d) > 0:
        result["von_mises_correlation"] = float(np.corrcoef(c, d)[0, 1])
    result["von_mises_slope"] = float(np.dot(c, d) / cc) if cc > 0 else None
    result["von_mises_max_abs_error_mpa"] = float(np.max(np.abs(diff))) * MPA
    result["von_mises_rms_error_mpa"] = float(np.sqrt(np.mean(diff**2))) * MPA
    result["von_mises_max_rel_error"] = float(np.max(np.abs(diff))) / cmax if cmax > 0 else None
    result["von_mises_coupled_max_mpa"] = cmax * MPA
    return result


def _stage(summary: dict, name: str) -> dict | None:
    """The first stage of that name (the innermost, as stages are listed when they end)."""
    for st in summary.get("stages") or summary.get("resources", {}).get("stages") or []:
        if st.get("name") == name:
            return st
    return None


def _int_or_none(value: Any) -> int | None:
    return int(value) if isinstance(value, int | float) and not isinstance(value, bool) else None


def _resources(cpl: RunData, dec: RunData) -> dict[str, dict[str, Any]]:
    """Table II: per method (whole run) and per decoupled part (its stage)."""
    keys = [k for k, _, _ in RESOURCE_ROWS]

    def whole(run: RunData, dofs: int | None) -> dict[str, Any]:
        res = run.summary.get("resources", {})
        row = {k: res.get(k) for k in keys if k not in ("ranks", "dofs")}
        row["ranks"] = _int_or_none(res.get("ranks", run.summary.get("ranks")))
        row["dofs"] = dofs
        return row

    def part(name: str, dofs_key: str) -> dict[str, Any]:
        st = _stage(dec.summary, name) or {}
        row = {k: st.get(k) for k in keys if k not in ("ranks", "dofs")}
        row["ranks"] = _int_or_none(dec.summary.get("resources", {}).get("ranks"))
        row["dofs"] = _int_or_none(dec.summary.get(dofs_key))
        return row

    dofs_c = _int_or_none(cpl.summary.get("dofs", cpl.summary.get("dofs_coupled")))
    p1, p2 = part("part1", "dofs_part1"), part("part2", "dofs_part2")
    if p1["dofs"] is not None and p2["dofs"] is not None:
        dofs_d = p1["dofs"] + p2["dofs"]
    else:
        dofs_d = _int_or_none(dec.summary.get("dofs"))
    return {
        "coupled": whole(cpl, dofs_c),
        "decoupled_part1": p1,
        "decoupled_part2": p2,
        "decoupled": whole(dec, dofs_d),
    }


def _compare(cpl: RunData, dec: RunData) -> tuple[dict[str, Any], tuple]:
    """Every metric between the two runs (not yet JSON-converted), and the scapula vertex pairs.

    Raises:
        ValueError: if the glenoid points or the scapula vertices of the runs do not coincide.
    """
    angles = _common_angles(cpl.angles, dec.angles)
    p_c, p_d = cpl.max_pressure(angles), dec.max_pressure(angles)
    p_err = {_key(a): _rel(p_d[i], p_c[i]) for i, a in enumerate(angles)}

    forces: dict[str, dict[str, np.ndarray]] = {}
    f_err: dict[str, dict[str, float | None]] = {}
    for muscle in (*MUSCLES, "supraspinatus"):
        fc = cpl.series_at(f"{muscle}_force", angles)
        fd = dec.series_at(f"{muscle}_force", angles)
        forces[muscle] = {"coupled": fc, "decoupled": fd}
        f_err[muscle] = {
            _key(a): _rel(fd[i], fc[i]) for i, a in enumerate(angles) if a > ANGLE_TOLERANCE
        }
    cf_c = cpl.series_at("contact_force", angles)
    cf_d = dec.series_at("contact_force", angles)
    cf_err = {_key(a): _rel(cf_d[i], cf_c[i]) for i, a in enumerate(angles)}
    # the rotator cuff pressing on the humeral head (runs with muscle_contact only)
    mb_c = cpl.series_at("muscle_bone_contact_force", angles)
    mb_d = dec.series_at("muscle_bone_contact_force", angles)
    mb_err = {_key(a): _rel(mb_d[i], mb_c[i]) for i, a in enumerate(angles)}

    g_pair = match_points(cpl.arrays["glenoid_points"], dec.arrays["glenoid_points"])
    if g_pair[2] < MIN_MATCHED_FRACTION:
        raise ValueError(
            f"the glenoid contact points of {cpl.folder} and {dec.folder} differ: only "
            f"{g_pair[2]:.1%} coincide within {MATCH_TOLERANCE:g} m"
        )
    s_pair = match_points(cpl.arrays["scapula_points"], dec.arrays["scapula_points"])
    if s_pair[2] < MIN_MATCHED_FRACTION:
        raise ValueError(
            f"the scapula meshes of {cpl.folder} ({len(cpl.arrays['scapula_points'])} vertices) "
            f"and {dec.folder} ({len(dec.arrays['scapula_points'])} vertices) differ: only "
            f"{s_pair[2]:.1%} of the vertices coincide within {MATCH_TOLERANCE:g} m "
            f"(at least {MIN_MATCHED_FRACTION:.0%} needed)"
        )
    jac = _jaccard(cpl, dec, angles, g_pair[:2])
    # the humerus's swing and where the glenoid presses on the humeral cartilage (deg)
    motion = {
        f"{name}_deg": {
            "coupled": cpl.series_at(name, angles),
            "decoupled": dec.series_at(name, angles),
        }
        for name, _ in MOTION_SERIES
    }
    per_angle = []
    for i, a in enumerate(angles):
        row: dict[str, Any] = {
            "angle_deg": float(a),
            "max_pressure_mpa": {"coupled": p_c[i] * MPA, "decoupled": p_d[i] * MPA},
            "max_pressure_rel_error": p_err[_key(a)],
            "contact_force_n": {"coupled": cf_c[i], "decoupled": cf_d[i]},
            "contact_region_jaccard": jac[_key(a)],
        }
        for muscle, f in forces.items():
            row[f"{muscle}_force_n"] = {"coupled": f["coupled"][i], "decoupled": f["decoupled"][i]}
            row[f"{muscle}_force_rel_error"] = f_err[muscle].get(_key(a))
        for key, m in motion.items():
            row[key] = {"coupled": m["coupled"][i], "decoupled": m["decoupled"][i]}
        per_angle.append(row)

    ratios = resource_ratios(cpl.summary, dec.summary)
    out: dict[str, Any] = {
        "speedup_cpu": ratios["speedup_cpu"],
        "speedup_wall": ratios["speedup_wall"],
        "memory_ratio": ratios["memory_ratio"],
        "results_disk_ratio": ratios["results_disk_ratio"],
        "angles_compared_deg": [float(a) for a in angles],
        "max_pressure_rel_error": _max_abs(list(p_err.values())),
        "max_pressure_rel_errors": p_err,
        "muscle_force_rel_error": _max_abs([v for m in MUSCLES for v in f_err[m].values()]),
        "muscle_force_rel_errors": f_err,
        "contact_force_rel_error": _max_abs(list(cf_err.values())),
        "muscle_bone_contact_force_rel_error": _max_abs(list(mb_err.values())),
        "contact_region_jaccard": jac,
        "contact_region_jaccard_min": min((v for v in jac.values() if v is not None), default=None),
        "glenoid_points_compared": int(len(g_pair[0])),
        "scapula_vertices_matched_fraction": float(s_pair[2]),
        "humeral_cap_half_angle_deg": cpl.summary.get("probes", {}).get(
            "humeral_cap_half_angle_deg"
        ),
    }
    out.update(_von_mises_metrics(cpl, dec, s_pair[:2]))
    out["per_angle"] = per_angle
    return out, s_pair[:2]


# --------------------------------------------------------------------------------------------
# Figures
# --------------------------------------------------------------------------------------------


def _map_angles(runs: Sequence[RunData]) -> list[float]:
    """The columns of the pressure maps: every angle reached that is a multiple of 10 deg."""
    all_angles = sorted({round(float(a), 6) for r in runs for a in r.angles})
    tens = [a for a in all_angles if abs(a / 10.0 - round(a / 10.0)) * 10.0 < ANGLE_TOLERANCE]
    return tens or all_angles


def _glenoid_triangulation(xy: np.ndarray) -> mtri.Triangulation | None:
    """Delaunay triangulation of the projected points, long (hull-bridging) triangles masked."""
    if len(xy) < 3:
        return None
    try:
        tri = mtri.Triangulation(xy[:, 0], xy[:, 1])
    except (ValueError, RuntimeError):
        return None
    t = tri.triangles
    edges = np.stack(
        [np.linalg.norm(xy[t[:, i]] - xy[t[:, (i + 1) % 3]], axis=1) for i in range(3)], 1
    )
    long = edges.max(axis=1) > 3.0 * np.median(edges)
    # peel long triangles from the hull inwards only: no holes inside the surface
    neighbours = tri.neighbors
    mask = np.zeros(len(t), dtype=bool)
    while True:
        open_side = np.any(neighbours < 0, axis=1) | np.any(
            mask[np.where(neighbours < 0, 0, neighbours)] & (neighbours >= 0), axis=1
        )
        peel = long & open_side & ~mask
        if not peel.any():
            break
        mask |= peel
    tri.set_mask(mask)
    return tri


def _plot_pressure_maps(runs: dict[str, RunData], path: Path) -> None:
    angles = _map_angles(list(runs.values()))
    ncols = max(len(angles), 1)
    vmax = 0.0
    xy: dict[str, np.ndarray] = {}
    for m, r in runs.items():
        p = r.arrays.get("glenoid_pressure")
        if p is not None and p.size:
            vmax = max(vmax, float(np.max(p)) * MPA)
        xy[m] = (
            glenoid_plane_coordinates(
                r.arrays["glenoid_points"], r.arrays["glenoid_centre"], r.arrays["glenoid_axis"]
            )
            * 1e3
        )
    vmax = vmax if vmax > 0 else 1.0
    levels = MaxNLocator(nbins=20).tick_values(0.0, vmax)
    cmap = plt.get_cmap("YlOrRd")
    all_xy = np.concatenate([v for v in xy.values() if len(v)] or [np.zeros((1, 2))])
    lo, hi = all_xy.min(axis=0), all_xy.max(axis=0)
    pad = 0.05 * max(float(np.max(hi - lo)), 1e-6)
    fig, axes = plt.subplots(
        2,
        ncols,
        figsize=(1.9 * ncols + 1.6, 5.0),
        squeeze=False,
        sharex=True,
        sharey=True,
        layout="constrained",
    )
    mappable = None
    for row, (m, r) in enumerate(runs.items()):
        tri = _glenoid_triangulation(xy[m])
        for col, a in enumerate(angles):
            ax = axes[row, col]
            ax.set_aspect("equal")
            ax.set_xlim(lo[0] - pad, hi[0] + pad)
            ax.set_ylim(lo[1] - pad, hi[1] + pad)
            if row == 0:
                ax.set_title(f"{a:g}°")
            if col == 0:
                ax.set_ylabel(f"{m}\nsuperior (mm)")
            if row == 1:
                ax.set_xlabel("anterior (mm)")
            i = _angle_index(r.angles, a)
            ax.plot(xy[m][:, 0], xy[m][:, 1], ",", color="0.75")
            if i is None:
                ax.text(
                    0.5,
                    0.5,
                    "not reached",
                    transform=ax.transAxes,
                    ha="center",
                    va="center",
                    color="0.4",
                    fontsize=9,
                )
                continue
            p = r.arrays["glenoid_pressure"][i] * MPA
            if tri is not None:
                mappable = ax.tricontourf(tri, np.clip(p, 0, vmax), levels=levels, cmap=cmap)
            else:
                mappable = ax.scatter(
                    xy[m][:, 0], xy[m][:, 1], c=p, s=6, cmap=cmap, vmin=0, vmax=vmax
                )
    if mappable is not None:
        fig.colorbar(mappable, ax=axes, shrink=0.85, label="contact pressure (MPa)")
    fig.suptitle("Glenoid contact pressure (view along the glenoid axis)")
    save_figure(fig, path)


def _plot_max_pressure(runs: dict[str, RunData], path: Path) -> None:
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for m, r in runs.items():
        a = r.angles
        ax.plot(a, r.max_pressure(a) * MPA, marker="o", ms=4, label=m, **METHOD_STYLE.get(m, {}))
    ax.set_xlabel("humeral internal rotation (deg)")
    ax.set_ylabel("maximum glenoid pressure (MPa)")
    ax.set_title("Maximum glenoid contact pressure")
    ax.grid(alpha=0.3)
    ax.legend()
    save_figure(fig, path)


def _plot_muscle_forces(runs: dict[str, RunData], path: Path) -> None:
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    colours = {"infraspinatus": "C0", "subscapularis": "C1", "supraspinatus": "C2"}
    for muscle, colour in colours.items():
        alpha = 0.45 if muscle == "supraspinatus" else 1.0
        for m, r in runs.items():
            ser = r.summary.get("series", {}).get(f"{muscle}_force")
            if not ser:
                continue
            ls = "-" if m == "coupled" else "--"
            marker = "o" if m == "coupled" else "s"
            ax.plot(
                ser["x"],
                ser["y"],
                ls=ls,
                marker=marker,
                ms=4,
                color=colour,
                alpha=alpha,
                mfc="none" if m != "coupled" else colour,
                label=f"{muscle} ({m})",
            )
    ax.set_xlabel("humeral internal rotation (deg)")
    ax.set_ylabel("muscle force (N)")
    ax.set_title("Muscle forces at the scapular footprints")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, ncol=2)
    save_figure(fig, path)


def _plot_section(runs: dict[str, RunData], path: Path) -> dict[str, int]:
    """Fig. 4; returns the number of section polygons per run."""
    sections = {}
    vmax = 0.0
    for m, r in runs.items():
        z = float(r.arrays.get("section_z", math.nan))
        polys, vals = (
            slice_tetrahedra(
                r.arrays["scapula_points"],
                r.arrays["scapula_cells"],
                r.arrays["scapula_von_mises"],
                z,
            )
            if math.isfinite(z)
            else ([], [])
        )
        face = np.array([float(np.mean(v)) for v in vals]) * MPA
        sections[m] = ([p * 1e3 for p in polys], face, z)
        if len(face):
            vmax = max(vmax, float(face.max()))
    vmax = vmax if vmax > 0 else 1.0
    # one panel per run, stacked: the blade's section is long and thin
    bounds = [p for s in sections.values() for p in s[0]]
    aspect = 0.3
    if bounds:
        allp = np.concatenate(bounds)
        span = np.ptp(allp[:, :2], axis=0)
        aspect = float(np.clip(span[1] / max(span[0], 1e-9), 0.1, 1.0))
    fig, axes = plt.subplots(
        len(runs), 1, figsize=(9.0, len(runs) * (7.0 * aspect + 0.9) + 0.8), squeeze=False
    )
    axes = axes.T
    coll = None
    for ax, (m, (polys, face, z)) in zip(axes[0], sections.items(), strict=True):
        r = runs[m]
        ax.set_title(f"{m}: {_fmt(r.von_mises_angle, 'g')}°, z = {z * 1e3:.1f} mm")
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
        ax.set_aspect("equal")
        if not polys:
            ax.text(
                0.5,
                0.5,
                "the plane misses the scapula",
                transform=ax.transAxes,
                ha="center",
                va="center",
            )
            continue
        coll = PolyCollection(polys, array=face, cmap="viridis", edgecolors="face", linewidths=0.2)
        coll.set_clim(0.0, vmax)
        ax.add_collection(coll)
        allp = np.concatenate(bounds)
        ax.set_xlim(allp[:, 0].min(), allp[:, 0].max())
        ax.set_ylim(allp[:, 1].min(), allp[:, 1].max())
    if coll is not None:
        fig.colorbar(coll, ax=axes[0].tolist(), shrink=0.9, label="von Mises stress (MPa)")
    fig.suptitle("Von Mises stress in the horizontal section of the scapula")
    save_figure(fig, path)
    return {m: len(s[0]) for m, s in sections.items()}


def _plot_von_mises(
    cpl: RunData, dec: RunData, metrics: dict, pair: tuple, scatter: Path, hist: Path
) -> None:
    i_c, i_d = pair
    c = np.asarray(cpl.arrays["scapula_von_mises"], dtype=float)[i_c] * MPA
    d = np.asarray(dec.arrays["scapula_von_mises"], dtype=float)[i_d] * MPA
    note = metrics.get("von_mises_note")
    a_c, a_d = _fmt(cpl.von_mises_angle, "g"), _fmt(dec.von_mises_angle, "g")
    angles = f"coupled {a_c}°, decoupled {a_d}°"

    fig, ax = plt.subplots(figsize=(5.4, 5.0))
    ax.plot(c, d, ".", ms=3, alpha=0.5, color="C0", label=f"{len(c)} scapula vertices")
    top = max(float(c.max()) if len(c) else 0.0, float(d.max()) if len(d) else 0.0, 1e-12)
    ax.plot([0, top], [0, top], color="k", lw=0.8, label="y = x")
    slope, corr = metrics.get("von_mises_slope"), metrics.get("von_mises_correlation")
    if slope is not None:
        ax.plot(
            [0, top],
            [0, slope * top],
            color="C3",
            lw=1.0,
            ls="--",
            label=f"least squares: slope {slope:.4f}, r = {_fmt(corr, '.4f')}",
        )
    ax.set_xlim(0, top * 1.03)
    ax.set_ylim(0, top * 1.03)
    ax.set_aspect("equal")
    ax.set_xlabel("von Mises, coupled (MPa)")
    ax.set_ylabel("von Mises, decoupled (MPa)")
    ax.set_title(f"Nodal von Mises stress ({angles})" + (f"\n{note}" if note else ""), fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper left")
    save_figure(fig, scatter)

    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    diff = d - c
    cmax = float(np.max(np.abs(c))) if len(c) else 0.0
    if len(diff):
        ax.hist(
            diff,
            bins=60,
            color="C0",
            alpha=0.8,
            label=f"mean {diff.mean():.3g} MPa, std {diff.std():.3g} MPa",
        )
        ax.legend(fontsize=8)
    ax.axvline(0.0, color="k", lw=0.8)
    ax.set_xlabel("von Mises, decoupled − coupled (MPa)")
    ax.set_ylabel("vertices")
    if cmax > 0:
        sec = ax.secondary_xaxis(
            "top", functions=(lambda x: 100.0 * x / cmax, lambda x: x * cmax / 100.0)
        )
        sec.set_xlabel("% of the coupled maximum")
    ax.set_title(
        f"Nodal von Mises differences ({angles})" + (f"\n{note}" if note else ""), fontsize=9
    )
    ax.grid(alpha=0.3)
    save_figure(fig, hist)


def _plot_resources(table: dict[str, dict[str, Any]], path: Path) -> None:
    labels = [RESOURCE_LABELS[k].replace(" ", "\n", 1) for k in RESOURCE_COLUMNS]
    colours = ["C0", "#f4a3a0", "#f4a3a0", "C3"]
    fig, axes = plt.subplots(1, 3, figsize=(12.0, 3.8))
    for ax, (key, name) in zip(
        axes,
        (
            ("cpu_s", "CPU time (s)"),
            ("peak_rss_mb", "peak memory (MB)"),
            ("results_disk_mb", "results disk (MB)"),
        ),
        strict=True,
    ):
        vals = [table[k].get(key) for k in RESOURCE_COLUMNS]
        x = np.arange(len(vals))
        heights = [v if isinstance(v, int | float) and math.isfinite(v) else 0.0 for v in vals]
        bars = ax.bar(x, heights, color=colours)
        for bar, v in zip(bars, vals, strict=True):
            ok = isinstance(v, int | float) and math.isfinite(v)
            text = (_fmt(v, ".0f" if abs(v) >= 100 else ".3g")) if ok else "n/a"
            ax.annotate(
                text,
                (bar.get_x() + bar.get_width() / 2, bar.get_height()),
                ha="center",
                va="bottom",
                fontsize=8,
                xytext=(0, 2),
                textcoords="offset points",
            )
        ax.set_xticks(x, labels, fontsize=8)
        ax.set_ylabel(name)
        ax.grid(axis="y", alpha=0.3)
        ax.margins(y=0.15)
    fig.suptitle("Resources (sums over ranks; part figures are the stages of the decoupled run)")
    fig.tight_layout()
    save_figure(fig, path)


# --------------------------------------------------------------------------------------------
# Text
# --------------------------------------------------------------------------------------------


def _fmt(value: Any, spec: str = ".3g") -> str:
    """A number formatted, or ``–`` for None/NaN."""
    if value is None or isinstance(value, bool):
        return "–" if value is None else str(value)
    if isinstance(value, int | float):
        if not math.isfinite(value):
            return "–"
        if spec == "d":
            return f"{int(round(value)):d}"
        return f"{value:{spec}}"
    return str(value)


def _metric_rows(report: dict) -> list[tuple[str, str]]:
    fa, st = report.get("final_angle_deg", {}), report.get("status", {})
    rows = [
        ("status (coupled / decoupled)", f"{st.get('coupled')} / {st.get('decoupled')}"),
        (
            "final angle deg (coupled / decoupled)",
            f"{_fmt(fa.get('coupled'), 'g')} / {_fmt(fa.get('decoupled'), 'g')}",
        ),
        (
            "angles compared deg",
            ", ".join(_fmt(a, "g") for a in report.get("angles_compared_deg", [])) or "none",
        ),
        ("CPU speed-up (coupled / decoupled)", _fmt(report.get("speedup_cpu"), ".2f")),
        ("wall speed-up (coupled / decoupled)", _fmt(report.get("speedup_wall"), ".2f")),
        ("peak memory ratio (decoupled / coupled)", _fmt(report.get("memory_ratio"), ".2f")),
        ("max pressure: largest relative error", _fmt(report.get("max_pressure_rel_error"), ".2%")),
        (
            "muscle forces: largest relative error",
            _fmt(report.get("muscle_force_rel_error"), ".2%"),
        ),
        (
            "contact force: largest relative error",
            _fmt(report.get("contact_force_rel_error"), ".2%"),
        ),
        *(
            [
                (
                    "cuff-on-head contact force: largest relative error",
                    _fmt(report["muscle_bone_contact_force_rel_error"], ".2%"),
                )
            ]
            if report.get("muscle_bone_contact_force_rel_error") is not None
            else []
        ),
        (
            "contact region Jaccard index (min)",
            _fmt(report.get("contact_region_jaccard_min"), ".3f"),
        ),
        ("von Mises correlation", _fmt(report.get("von_mises_correlation"), ".4f")),
        ("von Mises slope (through origin)", _fmt(report.get("von_mises_slope"), ".4f")),
        ("von Mises max abs error MPa", _fmt(report.get("von_mises_max_abs_error_mpa"), ".3g")),
        (
            "von Mises max abs error / coupled max",
            _fmt(report.get("von_mises_max_rel_error"), ".2%"),
        ),
    ]
    return rows


def _per_angle_rows(report: dict) -> tuple[list[str], list[list[str]]]:
    head = [
        "angle deg",
        "p max cpl MPa",
        "p max dec MPa",
        "rel err",
        "infra cpl N",
        "infra dec N",
        "subscap cpl N",
        "subscap dec N",
        "Jaccard",
    ]
    rows = []
    for r in report.get("per_angle", []):
        rows.append(
            [
                _fmt(r["angle_deg"], "g"),
                _fmt(r["max_pressure_mpa"]["coupled"], ".3f"),
                _fmt(r["max_pressure_mpa"]["decoupled"], ".3f"),
                _fmt(r["max_pressure_rel_error"], "+.2%"),
                _fmt(r["infraspinatus_force_n"]["coupled"], ".2f"),
                _fmt(r["infraspinatus_force_n"]["decoupled"], ".2f"),
                _fmt(r["subscapularis_force_n"]["coupled"], ".2f"),
                _fmt(r["subscapularis_force_n"]["decoupled"], ".2f"),
                _fmt(r["contact_region_jaccard"], ".3f"),
            ]
        )
    return head, rows


#: The humerus's motion series compared per angle (``<series>_deg`` in ``per_angle``) and
#: their column labels: the swing and where the glenoid presses on the humeral cartilage.
MOTION_SERIES = (
    ("humeral_swing", "swing"),
    ("humeral_cap_contact_angle", "contact mean"),
    ("humeral_cap_contact_angle_max", "contact max"),
)

#: Where the Newton time went (probes ``<stepping>_time_<key>_s`` of the runs), in table order.
TIME_SPLIT = (
    ("newton", "Newton solves, in all"),
    ("residual", "residual evaluations"),
    ("jacobian", "Jacobian evaluations"),
    ("jacobian_fe_assembly", "of which FE residual and matrix assembly"),
    ("jacobian_reduction", "of which reduction P^T K P (rigid bodies)"),
    ("linear", "linear solves (LU)"),
    ("contact", "contact search and assembly (in residual and Jacobian)"),
)


def _time_split(cpl: RunData, dec: RunData) -> dict[str, dict[str, float | None]]:
    """Wall seconds per Newton task: coupled (its rotation) and decoupled part 1."""
    out = {}
    for column, run, label in (("coupled", cpl, "coupled"), ("part1", dec, "part1")):
        probes = run.summary.get("probes", {})
        out[column] = {k: probes.get(f"{label}_time_{k}_s") for k, _ in TIME_SPLIT}
    return out


def _time_rows(report: dict) -> tuple[list[str], list[list[str]]]:
    split = report.get("time_split") or {}
    head = ["wall s (slowest rank)", "coupled", "decoupled part 1"]
    rows = [
        [label] + [_fmt((split.get(c) or {}).get(key), ".1f") for c in ("coupled", "part1")]
        for key, label in TIME_SPLIT
    ]
    return head, rows


def _motion_rows(report: dict) -> tuple[list[str], list[list[str]]]:
    """Per angle: the humerus's swing and the contact's place on the humeral cartilage."""
    head = ["angle deg"]
    for _, label in MOTION_SERIES:
        head += [f"{label} cpl deg", f"{label} dec deg"]
    rows = []
    for r in report.get("per_angle", []):
        if "humeral_swing_deg" not in r:
            continue
        rows.append([_fmt(r["angle_deg"], "g")])
        for name, _ in MOTION_SERIES:
            m = r[f"{name}_deg"]
            rows[-1] += [_fmt(m["coupled"], ".1f"), _fmt(m["decoupled"], ".1f")]
    return head, rows


def _resource_rows(report: dict) -> tuple[list[str], list[list[str]]]:
    table = report.get("resources", {})
    head = [""] + [RESOURCE_LABELS[k] for k in RESOURCE_COLUMNS]
    rows = [
        [label] + [_fmt(table.get(k, {}).get(key), spec) for k in RESOURCE_COLUMNS]
        for key, label, spec in RESOURCE_ROWS
    ]
    return head, rows


def _markdown_table(head: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(head) + " |", "|---|" + "|".join(["--:"] * (len(head) - 1)) + "|"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def _text_table(head: list[str], rows: list[list[str]]) -> str:
    widths = [max(len(str(x)) for x in col) for col in zip(head, *rows, strict=True)]
    fmt = "  ".join(f"{{:<{w}}}" if i == 0 else f"{{:>{w}}}" for i, w in enumerate(widths))
    lines = [fmt.format(*head), "  ".join("-" * w for w in widths)]
    lines += [fmt.format(*r) for r in rows]
    return "\n".join(lines)


def comparison_table(report: dict) -> str:
    """The report's key numbers as a plain-text table (for the console).

    Args:
        report: as returned by :func:`write_report` (or read back from ``report.json``).

    Returns:
        Several aligned tables: key metrics, per-angle values and resources.
    """
    title = f"{report.get('scene') or 'shoulder'} ({report.get('level')}): coupled vs decoupled"
    parts = [
        title,
        "=" * len(title),
        _text_table(["metric", "value"], [list(r) for r in _metric_rows(report)]),
    ]
    for note in report.get("notes", []):
        parts.append(f"note: {note}")
    head, rows = _per_angle_rows(report)
    if rows:
        parts += ["", _text_table(head, rows)]
    head, rows = _resource_rows(report)
    parts += ["", _text_table(["resources"] + head[1:], rows)]
    return "\n".join(parts)


def _markdown(report: dict) -> str:
    st, msg = report.get("status", {}), report.get("messages", {})
    lines = [
        f"# Shoulder internal rotation: coupled against decoupled ({report.get('level')})",
        "",
        f"Scene `{report.get('scene')}`, level `{report.get('level')}`. Reference: the coupled "
        "run; relative errors are (decoupled − coupled) / coupled.",
        "",
    ]
    for m in METHODS:
        line = f"- **{m}**: status `{st.get(m)}`, reached "
        line += f"{_fmt(report.get('final_angle_deg', {}).get(m), 'g')} deg"
        if msg.get(m):
            line += f" ({msg[m]})"
        lines.append(line)
    lines += [
        "",
        "## Key metrics",
        "",
        _markdown_table(["metric", "value"], [list(r) for r in _metric_rows(report)]),
    ]
    notes = report.get("notes", [])
    if notes:
        for n in notes:
            lines += ["", f"*Note:* {n}"]
    head, rows = _resource_rows(report)
    lines += [
        "",
        "## Resources (Table II)",
        "",
        _markdown_table(head, rows),
        "",
        "CPU time and memory are sums over ranks; the totals are whole runs (meshing "
        "included), the parts are the stages of the decoupled run. Temporary and results disk "
        "are measured per run only (– per part). Each run's peak memory is measured from its "
        "own start (freed memory given back first), though both ran in one process. DOFs: the "
        "coupled displacement DOFs; part 1: its Newton unknowns (the free soft-tissue DOFs and "
        "6 per rigid body; the tied bone nodes are not unknowns); part 2: the scapula's DOFs.",
    ]
    head, rows = _time_rows(report)
    if any(cell != "–" for row in rows for cell in row[1:]):
        lines += [
            "",
            "Where the Newton time went (wall seconds; part 2 is one LU and a few solves):",
            "",
            _markdown_table(head, rows),
        ]
    head, rows = _per_angle_rows(report)
    lines += ["", "## Per output angle", ""]
    lines += [_markdown_table(head, rows)] if rows else ["No common output angle."]
    head, rows = _motion_rows(report)
    half = report.get("humeral_cap_half_angle_deg")
    if rows and all(cell != "–" for row in rows for cell in row[1:]):
        lines += [
            "",
            "## Humeral swing and the contact on the humeral cartilage",
            "",
            "Swing: the angle by which the humerus's shaft axis turns (the rotation's part that "
            "is not a twist about it). Contact: where the glenoid presses on the humeral "
            "cartilage, in degrees from the cartilage's axis (force-weighted mean and largest), "
            f"in the humerus's reference geometry; the cartilage ends at {_fmt(half, '.1f')} "
            "deg. A contact that reaches that edge has run off the articular surface.",
            "",
            _markdown_table(head, rows),
        ]
    lines += ["", "## Figures", ""]
    for name, caption in FIGURES.items():
        lines += [f"### {caption}", "", f"![{caption}]({name})", ""]
    return "\n".join(lines)


# --------------------------------------------------------------------------------------------
# Entry point
# --------------------------------------------------------------------------------------------


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
    metrics, pair = _compare(cpl, dec)

    notes = []
    fa = {m: r.final_angle for m, r in runs.items()}
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

    _plot_pressure_maps(runs, out_dir / "pressure_maps.png")
    _plot_max_pressure(runs, out_dir / "max_pressure.png")
    _plot_muscle_forces(runs, out_dir / "muscle_forces.png")
    n_polys = _plot_section(runs, out_dir / "section_von_mises.png")
    _plot_von_mises(
        cpl,
        dec,
        metrics,
        pair,
        out_dir / "von_mises_scatter.png",
        out_dir / "von_mises_error_histogram.png",
    )
    resources = _resources(cpl, dec)
    _plot_resources(resources, out_dir / "resources.png")

    report: dict[str, Any] = {
        "scene": cpl.summary.get("scene"),
        "level": level,
        "runs": {"coupled": str(cpl.folder), "decoupled": str(dec.folder)},
        "status": {m: r.summary.get("status") for m, r in runs.items()},
        "messages": {m: r.summary.get("message") for m, r in runs.items()},
        "final_angle_deg": fa,
        **{k: v for k, v in metrics.items() if k != "per_angle"},
        "section_z_m": {m: float(r.arrays.get("section_z", math.nan)) for m, r in runs.items()},
        "section_polygons": n_polys,
        "per_angle": metrics["per_angle"],
        "resources": resources,
        "time_split": _time_split(cpl, dec),
        "notes": notes,
        "figures": list(FIGURES),
    }
    report = to_jsonable(report)
    atomic_write_json(out_dir / "report.json", report)
    atomic_write_text(out_dir / "report.md", _markdown(report) + "\n")
    return report


def bench_report(bench: BenchReport) -> str:
    """The ``bench`` hook: :func:`write_report` of the two runs; returns the comparison table."""
    table = None
    if bench.comm.rank == 0:
        report = write_report(
            bench.folder / "coupled", bench.folder / "decoupled", bench.folder, bench.level
        )
        table = comparison_table(report)
    return bench.comm.bcast(table, root=0)
