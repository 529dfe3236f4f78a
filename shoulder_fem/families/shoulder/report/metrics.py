"""The comparison of a decoupled shoulder run with the coupled one (the reference).

Relative errors of the maximum glenoid pressure, the muscle and contact forces, the overlap of
the contact regions (Jaccard), the nodal von Mises stresses and the resources (Table II).
Runs that stopped early are compared at their common output angles only; the nodal von Mises
stresses only if both runs give them at the same angle (otherwise a note says why).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from shoulder_fem.families.shoulder.report.contents import (
    CONTACT_SERIES,
    MOTION_SERIES,
    MPA,
    RESOURCE_ROWS,
    TIME_SPLIT,
    fmt,
)
from shoulder_fem.families.shoulder.report.data import ANGLE_TOLERANCE, RunData, angle_index
from shoulder_fem.families.shoulder.report.geometry import MATCH_TOLERANCE, match_points
from shoulder_fem.io.compare import resource_ratios

MIN_MATCHED_FRACTION = 0.99
"""Fewer matched points than this fraction means the two runs are not on the same mesh."""


CONTACT_THRESHOLD = 0.01
"""A glenoid point is in contact if its pressure exceeds this fraction of the coupled maximum."""

GLENOID_REGION = 0.02
"""Radius (m) about the glenoid's centre of the scapula's glenoid region (its vertices)."""

MUSCLES = ("infraspinatus", "subscapularis")
"""Muscles whose forces are compared (Fig. 3); the supraspinatus is drawn too."""


def _common_angles(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The angles of ``a`` that ``b`` also reached."""
    return np.array([x for x in a if angle_index(b, x) is not None], dtype=float)


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
        rc, rd = angle_index(cpl.angles, a), angle_index(dec.angles, a)
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
            f"von Mises stresses not compared: coupled at {fmt(a_c, 'g')} deg, "
            f"decoupled at {fmt(a_d, 'g')} deg"
        )
        return result
    if not len(i_c):
        result["von_mises_note"] = "von Mises stresses not compared: no scapula vertices"
        return result
    c = np.asarray(cpl.arrays["scapula_von_mises"], dtype=float)[i_c]
    d = np.asarray(dec.arrays["scapula_von_mises"], dtype=float)[i_d]
    stats = von_mises_stats(c, d)
    for key in ("correlation", "slope", "max_abs_error_mpa", "rms_error_mpa", "coupled_max_mpa"):
        result[f"von_mises_{key}"] = stats[key]
    result["von_mises_max_rel_error"] = stats["max_error_of_max"]
    return result


def von_mises_stats(c: np.ndarray, d: np.ndarray) -> dict[str, float | None]:
    """Agreement of matched nodal von Mises stresses ``d`` (decoupled) with ``c`` (Pa).

    ``correlation`` r, ``slope`` of the least-squares line through the origin, the largest and
    rms difference (MPa), the largest difference over the largest ``c`` (``max_error_of_max``),
    and ``nodes``.
    """
    out: dict[str, float | None] = dict.fromkeys(
        ("correlation", "slope", "max_abs_error_mpa", "rms_error_mpa", "max_error_of_max")
    )
    out["nodes"] = len(c)
    out["coupled_max_mpa"] = None
    if not len(c):
        return out
    diff = d - c
    cmax = float(np.max(np.abs(c)))
    cc = float(np.dot(c, c))
    if len(c) > 1 and np.std(c) > 0 and np.std(d) > 0:
        out["correlation"] = float(np.corrcoef(c, d)[0, 1])
    out["slope"] = float(np.dot(c, d) / cc) if cc > 0 else None
    out["max_abs_error_mpa"] = float(np.max(np.abs(diff))) * MPA
    out["rms_error_mpa"] = float(np.sqrt(np.mean(diff**2))) * MPA
    out["max_error_of_max"] = float(np.max(np.abs(diff))) / cmax if cmax > 0 else None
    out["coupled_max_mpa"] = cmax * MPA
    return out


def von_mises_by_angle(cpl: RunData, dec: RunData, pair: tuple) -> list[dict[str, Any]]:
    """:func:`von_mises_stats` at every output angle both runs recorded.

    Over the whole scapula and over its glenoid region (vertices within
    :data:`GLENOID_REGION` of the glenoid's centre, in the reference geometry). Empty for runs
    without the series.
    """
    i_c, i_d = pair
    if "scapula_von_mises_series" not in cpl.arrays or "scapula_von_mises_series" not in dec.arrays:
        return []
    a_c = np.asarray(cpl.arrays["von_mises_angles_deg"], dtype=float)
    a_d = np.asarray(dec.arrays["von_mises_angles_deg"], dtype=float)
    X = np.asarray(cpl.arrays["scapula_points"], dtype=float)[i_c]
    centre = np.asarray(cpl.arrays["glenoid_centre"], dtype=float)
    near = np.linalg.norm(X - centre, axis=1) <= GLENOID_REGION
    out = []
    for k, a in enumerate(a_c):
        j = angle_index(a_d, a)
        if j is None:
            continue
        c = np.asarray(cpl.arrays["scapula_von_mises_series"][k], dtype=float)[i_c]
        d = np.asarray(dec.arrays["scapula_von_mises_series"][j], dtype=float)[i_d]
        out.append(
            {
                "angle_deg": float(a),
                "scapula": von_mises_stats(c, d),
                "glenoid_region": von_mises_stats(c[near], d[near]),
            }
        )
    return out


def _stage(summary: dict, name: str) -> dict | None:
    """The first stage of that name (the innermost, as stages are listed when they end)."""
    for st in summary.get("stages") or summary.get("resources", {}).get("stages") or []:
        if st.get("name") == name:
            return st
    return None


def _int_or_none(value: Any) -> int | None:
    return int(value) if isinstance(value, int | float) and not isinstance(value, bool) else None


def resource_table(cpl: RunData, dec: RunData) -> dict[str, dict[str, Any]]:
    """Table II: per method (whole run) and per decoupled part (its stage).

    With a compliant part 1 (``part1_bones``), part 1 with the humerus's deformation (its CPU
    and its DOFs) and its correction, and part 2's two passes.

    Returns:
        A row per column of the table (``coupled``, ``decoupled_part1``, ``decoupled_part2``,
        ``decoupled``): the keys of :data:`RESOURCE_ROWS` (CPU and wall seconds, MB, ranks,
        DOFs; None where not measured).
    """
    keys = [k for k, _, _ in RESOURCE_ROWS]

    def whole(run: RunData, dofs: int | None) -> dict[str, Any]:
        res = run.summary.get("resources", {})
        row = {k: res.get(k) for k in keys if k not in ("ranks", "dofs")}
        row["ranks"] = _int_or_none(res.get("ranks", run.summary.get("ranks")))
        row["dofs"] = dofs
        return row

    def part(names: tuple[str, ...], dofs_key: str) -> dict[str, Any]:
        # a compliant run's part 1 includes its correction, its part 2 both passes: times add
        stages = [st for st in (_stage(dec.summary, n) for n in names) if st]
        st = dict(stages[0]) if stages else {}
        for extra in stages[1:]:
            for k in ("cpu_s", "wall_s"):
                st[k] = (st.get(k) or 0.0) + (extra.get(k) or 0.0)
            st["peak_rss_mb"] = max(st.get("peak_rss_mb") or 0.0, extra.get("peak_rss_mb") or 0.0)
        row = {k: st.get(k) for k in keys if k not in ("ranks", "dofs")}
        row["ranks"] = _int_or_none(dec.summary.get("resources", {}).get("ranks"))
        row["dofs"] = _int_or_none(dec.summary.get(dofs_key))
        return row

    dofs_c = _int_or_none(cpl.summary.get("dofs", cpl.summary.get("dofs_coupled")))
    p1 = part(("part1", "humerus", "part1_correction"), "dofs_part1")
    humerus = _int_or_none(dec.summary.get("dofs_humerus"))  # a compliant part 1's own solve
    if p1["dofs"] is not None and humerus is not None:
        p1["dofs"] += humerus
    p2 = part(("part2", "part2_uncorrected"), "dofs_part2")
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


#: The muscle-bone contact's forces per muscle and bone (runs with ``muscle_contact``):
#: ``<muscle>_<bone>_contact_force`` series, for the bones of ``CUFF_BONES``.
CUFF_MUSCLES = ("subscapularis", "supraspinatus", "infraspinatus")
CUFF_BONES = ("humerus", "scapula")


def _cuff_on_bones(cpl: RunData, dec: RunData, angles: np.ndarray) -> dict[str, dict]:
    """Each muscle's contact force on each bone (N) at ``angles``, both methods.

    The series the coupled run has (none without muscle contact).
    """
    out = {}
    for bone in CUFF_BONES:
        for muscle in CUFF_MUSCLES:
            name = f"{muscle}_{bone}_contact_force"
            c = cpl.series_at(name, angles)
            if np.all(np.isnan(c)):
                continue
            d = dec.series_at(name, angles)
            out[name] = {"coupled": _listed(c), "decoupled": _listed(d)}
    return out


def _listed(a: np.ndarray) -> list:
    return [None if math.isnan(v) else float(v) for v in a]


def _muscle_forces(
    cpl: RunData, dec: RunData, angles: np.ndarray
) -> tuple[dict[str, dict[str, np.ndarray]], dict[str, dict[str, float | None]]]:
    """Each muscle's force [N] per method at ``angles``, and its relative error per angle."""
    forces: dict[str, dict[str, np.ndarray]] = {}
    f_err: dict[str, dict[str, float | None]] = {}
    for muscle in (*MUSCLES, "supraspinatus"):
        fc = cpl.series_at(f"{muscle}_force", angles)
        fd = dec.series_at(f"{muscle}_force", angles)
        forces[muscle] = {"coupled": fc, "decoupled": fd}
        f_err[muscle] = {
            _key(a): _rel(fd[i], fc[i]) for i, a in enumerate(angles) if a > ANGLE_TOLERANCE
        }
    return forces, f_err


def _matched_pairs(cpl: RunData, dec: RunData) -> tuple[tuple, tuple]:
    """The pairs of coinciding glenoid points and of coinciding scapula vertices of the runs.

    Raises:
        ValueError: if the glenoid points or the scapula vertices of the runs do not coincide.
    """
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
    return g_pair, s_pair


def _both_series(cpl: RunData, dec: RunData, angles: np.ndarray) -> dict[str, dict]:
    """Both runs' series compared per angle as they are.

    The humerus's swing and where the glenoid presses on the humeral cartilage
    (``<series>_deg``), and the glenohumeral penalty's overlap and share of the joint's
    approach (where the coupled run has them).
    """
    out = {
        f"{name}_deg": {
            "coupled": cpl.series_at(name, angles),
            "decoupled": dec.series_at(name, angles),
        }
        for name, _ in MOTION_SERIES
    }
    for name, *_ in CONTACT_SERIES:
        c = cpl.series_at(name, angles)
        if not np.all(np.isnan(c)):
            out[name] = {"coupled": c, "decoupled": dec.series_at(name, angles)}
    return out


def compare_runs(cpl: RunData, dec: RunData) -> tuple[dict[str, Any], tuple]:
    """Every metric between the two runs (not yet JSON-converted), and the scapula vertex pairs.

    Args:
        cpl: the coupled run (the reference).
        dec: the decoupled run.

    Returns:
        ``(metrics, pair)``: the metrics (the keys of ``report.json``, ``per_angle`` included;
        pressures in MPa, forces in N, errors relative to the coupled value) and the indices of
        the matched scapula vertices (coupled, decoupled).

    Raises:
        ValueError: if the glenoid points or the scapula vertices of the runs do not coincide.
    """
    angles = _common_angles(cpl.angles, dec.angles)
    p_c, p_d = cpl.max_pressure(angles), dec.max_pressure(angles)
    p_err = {_key(a): _rel(p_d[i], p_c[i]) for i, a in enumerate(angles)}
    forces, f_err = _muscle_forces(cpl, dec, angles)
    cf_c = cpl.series_at("contact_force", angles)
    cf_d = dec.series_at("contact_force", angles)
    cf_err = {_key(a): _rel(cf_d[i], cf_c[i]) for i, a in enumerate(angles)}
    # the rotator cuff pressing on the bones (runs with muscle_contact only): in all, each
    mb_c, mb_d = (r.series_at("muscle_bone_contact_force", angles) for r in (cpl, dec))
    mb_err = {_key(a): _rel(mb_d[i], mb_c[i]) for i, a in enumerate(angles)}
    cuff = _cuff_on_bones(cpl, dec, angles)
    g_pair, s_pair = _matched_pairs(cpl, dec)
    jac = _jaccard(cpl, dec, angles, g_pair[:2])
    both = _both_series(cpl, dec, angles)
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
        for key, m in both.items():
            row[key] = {"coupled": m["coupled"][i], "decoupled": m["decoupled"][i]}
        for key, m in cuff.items():
            row[f"{key}_n"] = {"coupled": m["coupled"][i], "decoupled": m["decoupled"][i]}
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
    out["von_mises_per_angle"] = von_mises_by_angle(cpl, dec, s_pair[:2])
    out["glenoid_region_radius_mm"] = GLENOID_REGION * 1e3
    out["per_angle"] = per_angle
    return out, s_pair[:2]


def time_split(cpl: RunData, dec: RunData) -> dict[str, dict[str, float | None]]:
    """Wall seconds per Newton task: coupled (its rotation) and decoupled part 1."""
    out = {}
    for column, run, label in (("coupled", cpl, "coupled"), ("part1", dec, "part1")):
        probes = run.summary.get("probes", {})
        out[column] = {k: probes.get(f"{label}_time_{k}_s") for k, _ in TIME_SPLIT}
    return out
