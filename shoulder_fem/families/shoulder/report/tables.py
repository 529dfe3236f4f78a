"""The shoulder report as text: the Markdown of ``report.md`` and the console's tables.

Everything here reads the report's JSON (as :func:`write_report` returns it or ``report.json``
holds it), so a report read back from disk prints the same tables.
"""

from __future__ import annotations

from shoulder_fem.families.shoulder.report.contents import (
    CONTACT_SERIES,
    FIGURES,
    METHODS,
    MOTION_SERIES,
    RESOURCE_COLUMNS,
    RESOURCE_LABELS,
    RESOURCE_ROWS,
    TIME_SPLIT,
    fmt,
)


def _metric_rows(report: dict) -> list[tuple[str, str]]:
    fa, st = report.get("final_angle_deg", {}), report.get("status", {})
    rows = [
        ("status (coupled / decoupled)", f"{st.get('coupled')} / {st.get('decoupled')}"),
        (
            "final angle deg (coupled / decoupled)",
            f"{fmt(fa.get('coupled'), 'g')} / {fmt(fa.get('decoupled'), 'g')}",
        ),
        (
            "angles compared deg",
            ", ".join(fmt(a, "g") for a in report.get("angles_compared_deg", [])) or "none",
        ),
        ("CPU speed-up (coupled / decoupled)", fmt(report.get("speedup_cpu"), ".2f")),
        ("wall speed-up (coupled / decoupled)", fmt(report.get("speedup_wall"), ".2f")),
        ("peak memory ratio (decoupled / coupled)", fmt(report.get("memory_ratio"), ".2f")),
        ("max pressure: largest relative error", fmt(report.get("max_pressure_rel_error"), ".2%")),
        (
            "muscle forces: largest relative error",
            fmt(report.get("muscle_force_rel_error"), ".2%"),
        ),
        (
            "contact force: largest relative error",
            fmt(report.get("contact_force_rel_error"), ".2%"),
        ),
        *(
            [
                (
                    "muscle-bone contact force: largest relative error",
                    fmt(report["muscle_bone_contact_force_rel_error"], ".2%"),
                )
            ]
            if report.get("muscle_bone_contact_force_rel_error") is not None
            else []
        ),
        (
            "contact region Jaccard index (min)",
            fmt(report.get("contact_region_jaccard_min"), ".3f"),
        ),
        ("von Mises correlation", fmt(report.get("von_mises_correlation"), ".4f")),
        ("von Mises slope (through origin)", fmt(report.get("von_mises_slope"), ".4f")),
        ("von Mises max abs error MPa", fmt(report.get("von_mises_max_abs_error_mpa"), ".3g")),
        (
            "von Mises max abs error / coupled max",
            fmt(report.get("von_mises_max_rel_error"), ".2%"),
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
                fmt(r["angle_deg"], "g"),
                fmt(r["max_pressure_mpa"]["coupled"], ".3f"),
                fmt(r["max_pressure_mpa"]["decoupled"], ".3f"),
                fmt(r["max_pressure_rel_error"], "+.2%"),
                fmt(r["infraspinatus_force_n"]["coupled"], ".2f"),
                fmt(r["infraspinatus_force_n"]["decoupled"], ".2f"),
                fmt(r["subscapularis_force_n"]["coupled"], ".2f"),
                fmt(r["subscapularis_force_n"]["decoupled"], ".2f"),
                fmt(r["contact_region_jaccard"], ".3f"),
            ]
        )
    return head, rows


def _time_rows(report: dict) -> tuple[list[str], list[list[str]]]:
    split = report.get("time_split") or {}
    head = ["wall s (slowest rank)", "coupled", "decoupled part 1"]
    rows = [
        [label] + [fmt((split.get(c) or {}).get(key), ".1f") for c in ("coupled", "part1")]
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
        rows.append([fmt(r["angle_deg"], "g")])
        for name, _ in MOTION_SERIES:
            m = r[f"{name}_deg"]
            rows[-1] += [fmt(m["coupled"], ".1f"), fmt(m["decoupled"], ".1f")]
    return head, rows


def _resource_rows(report: dict) -> tuple[list[str], list[list[str]]]:
    table = report.get("resources", {})
    head = [""] + [RESOURCE_LABELS[k] for k in RESOURCE_COLUMNS]
    rows = [
        [label] + [fmt(table.get(k, {}).get(key), spec) for k in RESOURCE_COLUMNS]
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


def _markdown_resources(report: dict) -> list[str]:
    """The Markdown of the resources table (Table II) and of where the Newton time went."""
    lines: list[str] = []
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
    return lines


def _markdown_motion(report: dict) -> list[str]:
    """The Markdown of the humeral swing and contact table (none if a value is missing)."""
    lines: list[str] = []
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
            f"in the humerus's reference geometry; the cartilage ends at {fmt(half, '.1f')} "
            "deg, and the margin is that edge's angle less the largest. A contact that reaches "
            "that edge (margin 0) has run off the articular surface.",
            "",
            _markdown_table(head, rows),
        ]
    return lines


def _markdown_cuff(report: dict) -> list[str]:
    """The Markdown of the muscles' contact forces on the bones (none without that contact)."""
    rows = report.get("per_angle", [])
    keys = [k for k in (rows[0] if rows else {}) if k.endswith("_contact_force_n")]
    if not keys:
        return []
    head = ["angle deg"]
    for k in keys:
        muscle, bone = k.split("_")[:2]
        head += [f"{muscle} on {bone} cpl N", f"{muscle} on {bone} dec N"]
    table = [
        [fmt(r["angle_deg"], "g")]
        + [fmt(r[k][m], ".3g") for k in keys for m in ("coupled", "decoupled")]
        for r in rows
    ]
    return [
        "",
        "## The rotator cuff on the bones",
        "",
        "Each muscle's contact force on the humerus (its deep faces over the head) and on the "
        "scapula (its deep faces over the blade and the glenoid neck): the magnitude of the "
        "force on the muscle's faces in each muscle-bone contact pair.",
        "",
        _markdown_table(head, table),
    ]


def _markdown_uncorrected(report: dict) -> list[str]:
    """The rigid decoupling's errors next to the compliant one's (a compliant run only)."""
    rigid = report.get("uncorrected")
    if not rigid:
        return []
    muscles = report.get("muscle_force_rel_errors", {})
    angles = sorted({a for by_angle in muscles.values() for a in by_angle}, key=float)
    slopes = {f"{r['angle_deg']:g}": r["scapula"]["slope"] for r in report["von_mises_per_angle"]}

    def worst(errors: dict, a: str) -> float | None:
        values = [abs(v[a]) for v in errors.values() if v.get(a) is not None]
        return 100 * max(values) if values else None

    def pct(value) -> str:
        return fmt(None if value is None else 100 * abs(value), ".3f")

    rows = [
        [
            a,
            fmt(worst(muscles, a), ".3f"),
            fmt(worst(rigid["muscle_force_rel_errors"], a), ".3f"),
            pct(report["max_pressure_rel_errors"].get(a)),
            pct(rigid["max_pressure_rel_errors"].get(a)),
            fmt(slopes.get(a), ".4f"),
            fmt(rigid["von_mises_slopes"].get(a), ".4f"),
        ]
        for a in angles
    ]
    head = ["angle deg", "muscles % compliant", "muscles % rigid", "pressure % compliant"]
    head += ["pressure % rigid", "vM slope compliant", "vM slope rigid"]
    return [
        "",
        "## The compliant part 1 against the rigid one",
        "",
        "This decoupled run has a compliant part 1 (`part1_bones`): part 1 solved again at each "
        "output angle with the bones' surfaces moved by their floating-frame displacements (the "
        "scapula's from part 2, the humerus's unless `compliant-scapula`), then part 2 again. "
        "Its rigid pass (the paper's decoupling) is in the same run (`uncorrected_`); both "
        "against the coupled run: the largest muscle-force error, the peak pressure's, and the "
        "nodal von Mises slope over the scapula.",
        "",
        _markdown_table(head, rows),
    ]


def _markdown_penalty(report: dict) -> list[str]:
    """The Markdown of the glenohumeral penalty's overlap and share (none without the series)."""
    rows = report.get("per_angle", [])
    series = [c for c in CONTACT_SERIES if rows and c[0] in rows[0]]
    if not series:
        return []
    head = ["angle deg"]
    for _, label, _, unit in series:
        head += [f"{label} cpl {unit}", f"{label} dec {unit}"]
    table = [
        [fmt(r["angle_deg"], "g")]
        + [
            fmt(None if r[name][m] is None else r[name][m] * scale, ".3g")
            for name, _, scale, _ in series
            for m in ("coupled", "decoupled")
        ]
        for r in rows
    ]
    return [
        "",
        "## The glenohumeral contact's penalty",
        "",
        "Deepest overlap: the largest penetration at a contact point. Under the pressure the "
        "bones approach by the penalty's overlap p / eps plus the two cartilage layers' "
        "compressions (each layer's thickness change under the glenoid's nodes in contact), "
        "all weighted by the nodal pressure; the penalty share is the overlap's part of that "
        "approach (issue 20: at most 10 % for a contact that does not set the pressure). "
        "Energy share: the penalty's stored energy over it plus the cartilages' strain energy, "
        "the penalty's share of the joint's series compliance measured over the whole contact "
        "(the nodal measure reads nodal pressures, which average the contact points' over "
        "each node's area, and layers that bulge at a small patch's edge).",
        "",
        _markdown_table(head, table),
    ]


def _von_mises_rows(report: dict) -> tuple[list[str], list[list[str]]]:
    """Per angle: the nodal von Mises agreement over the scapula and its glenoid region."""
    head = ["angle deg"]
    for region in ("scapula", "glenoid"):
        head += [
            f"{region} r",
            f"{region} slope",
            f"{region} max err % of max",
            f"{region} max MPa",
        ]
    rows = []
    for r in report.get("von_mises_per_angle", []):
        row = [fmt(r["angle_deg"], "g")]
        for key in ("scapula", "glenoid_region"):
            st = r[key]
            row += [
                fmt(st["correlation"], ".4f"),
                fmt(st["slope"], ".4f"),
                fmt(st["max_error_of_max"], ".2%"),
                fmt(st["coupled_max_mpa"], ".3g"),
            ]
        rows.append(row)
    return head, rows


def _markdown_von_mises(report: dict) -> list[str]:
    """The Markdown of the per-angle von Mises table (none for runs without the series)."""
    head, rows = _von_mises_rows(report)
    if not rows:
        return []
    region = report.get("von_mises_per_angle", [{}])[0].get("glenoid_region", {})
    return [
        "",
        "## Nodal von Mises stress at every output angle",
        "",
        f"Recovered by the `{report.get('nodal_stress') or 'tensor'}` recipe. r: correlation; "
        "slope: least squares through the origin, decoupled against coupled; max err: the "
        "largest nodal difference over the region's largest coupled value. Glenoid region: the "
        f"{region.get('nodes', '–')} scapula vertices within "
        f"{fmt(report.get('glenoid_region_radius_mm'), 'g')} mm of the glenoid's centre.",
        "",
        _markdown_table(head, rows),
    ]


def markdown_report(report: dict) -> str:
    """The report as Markdown (``report.md``): runs, key metrics, resources, per angle, figures.

    Args:
        report: as returned by :func:`write_report` (or read back from ``report.json``).

    Returns:
        The Markdown text (no final newline).
    """
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
        line += f"{fmt(report.get('final_angle_deg', {}).get(m), 'g')} deg"
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
    lines += _markdown_resources(report)
    head, rows = _per_angle_rows(report)
    lines += ["", "## Per output angle", ""]
    lines += [_markdown_table(head, rows)] if rows else ["No common output angle."]
    lines += _markdown_motion(report)
    lines += _markdown_cuff(report)
    lines += _markdown_penalty(report)
    lines += _markdown_uncorrected(report)
    lines += _markdown_von_mises(report)
    lines += ["", "## Figures", ""]
    for name, caption in FIGURES.items():
        lines += [f"### {caption}", "", f"![{caption}]({name})", ""]
    return "\n".join(lines)
