"""The shoulder report (post-processing only): synthetic run folders with known answers."""

from __future__ import annotations

import json
from itertools import permutations, product
from pathlib import Path

import numpy as np
import pytest

from shoulder_fem.families.shoulder.report import (
    FIGURES,
    comparison_table,
    glenoid_plane_coordinates,
    match_points,
    slice_tetrahedra,
    write_report,
)

ANGLES = np.arange(0.0, 61.0, 10.0)
AXIS = np.array([1.0, 0.0, 0.0])
CENTRE = np.array([0.03, 0.0, 0.0])
SECTION_Z = 0.003


def kuhn_mesh(n: int, h: float, origin=(0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """(n+1)^3 grid points, every cube split into 6 tetrahedra (conforming Kuhn split)."""

    def idx(i, j, k):
        return (i * (n + 1) + j) * (n + 1) + k

    pts = np.array(list(product(range(n + 1), repeat=3)), dtype=float) * h + np.asarray(origin)
    cells = []
    for ijk in product(range(n), repeat=3):
        for perm in permutations(range(3)):
            v = list(ijk)
            tet = [idx(*v)]
            for ax in perm:
                v[ax] += 1
                tet.append(idx(*v))
            cells.append(tet)
    return pts, np.array(cells, dtype=np.int64)


def polygon_area(p: np.ndarray) -> float:
    x, y = p[:, 0], p[:, 1]
    return 0.5 * abs(float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)))


def glenoid_points() -> np.ndarray:
    g = np.linspace(-0.015, 0.015, 16)
    yz = np.array([(y, z) for y in g for z in g if y * y + z * z <= 0.015**2])
    return np.column_stack([np.full(len(yz), CENTRE[0]), yz])


def pressure(angle: float, pts: np.ndarray) -> np.ndarray:
    """A Hertz-like bump moving superiorly with the angle [Pa]."""
    centre = np.array([0.0, 0.005 * angle / 60.0])
    r2 = np.sum((pts[:, 1:] - centre) ** 2, axis=1)
    return 2e6 * (1.0 + angle / 60.0) * np.clip(1.0 - r2 / 0.008**2, 0.0, None)


def von_mises(pts: np.ndarray) -> np.ndarray:
    x, y, z = (pts[:, i] / 0.02 for i in range(3))
    return 1e6 * (2.0 + x + 0.5 * y**2 - 0.3 * z + x * y)


def series(angles, values, unit):
    return {"x": list(angles), "y": [float(v) for v in values], "x_unit": "deg", "y_unit": unit}


def make_run(
    folder: Path,
    method: str,
    *,
    angles=ANGLES,
    scale: float = 1.0,
    status: str = "ok",
    muscle_contact: bool = False,
    permute: bool = False,
    shift: float = 0.0,
    glenoid_factor: float = 1.0,
    recipe: str | None = "tensor",
) -> Path:
    """A run folder with summary.json and shoulder.npz; ``scale`` multiplies every result."""
    folder.mkdir(parents=True)
    angles = np.asarray(angles, dtype=float)
    gp = glenoid_points()
    sp, cells = kuhn_mesh(4, 0.01, origin=(-0.02, -0.02, -0.02))
    vm = von_mises(sp)
    if permute:
        rng = np.random.default_rng(1)
        order = rng.permutation(len(sp))  # new vertex i is old vertex order[i]
        inverse = np.argsort(order)
        sp, vm, cells = sp[order], vm[order], inverse[cells]
        gp = gp[rng.permutation(len(gp))]
    sp = sp + shift
    near = np.linalg.norm(sp - CENTRE, axis=1) <= 0.02  # the report's glenoid region
    vm = np.where(near, glenoid_factor, 1.0) * vm
    p = np.array([pressure(a, gp) for a in angles]) * scale
    muscles = {
        "infraspinatus": 100.0 + angles,
        "subscapularis": 200.0 + 2.0 * angles,
        "supraspinatus": 50.0 + 0.0 * angles,
    }
    np.savez(
        folder / "shoulder.npz",
        angles_deg=angles,
        glenoid_points=gp,
        glenoid_pressure=p,
        glenoid_shear=0.1 * p,
        glenoid_centre=CENTRE,
        glenoid_axis=AXIS,
        scapula_points=sp,
        scapula_cells=cells,
        scapula_von_mises=vm * scale * (1.0 + angles[-1] / 60.0),
        von_mises_angle_deg=float(angles[-1]),
        von_mises_angles_deg=angles,
        scapula_von_mises_series=np.array([vm * scale * (1.0 + a / 60.0) for a in angles]),
        section_z=SECTION_Z,
    )
    if method == "coupled":
        resources = dict(
            cpu_s=100.0,
            wall_s=110.0,
            peak_rss_mb=1000.0,
            temp_disk_mb=5.0,
            results_disk_mb=50.0,
            ranks=1,
            peak_rss_stage_reset=True,
        )
        stages = [
            dict(name="mesh", cpu_s=2.0, wall_s=2.0, peak_rss_mb=300.0),
            dict(name="coupled", cpu_s=95.0, wall_s=100.0, peak_rss_mb=1000.0),
            dict(name="coupled", cpu_s=96.0, wall_s=101.0, peak_rss_mb=1000.0),
        ]
        extra = {"dofs": 90000}
    else:
        resources = dict(
            cpu_s=20.0,
            wall_s=25.0,
            peak_rss_mb=400.0,
            temp_disk_mb=2.0,
            results_disk_mb=30.0,
            ranks=1,
            peak_rss_stage_reset=True,
        )
        stages = [
            dict(name="mesh", cpu_s=2.0, wall_s=2.0, peak_rss_mb=300.0),
            dict(name="part1", cpu_s=12.0, wall_s=14.0, peak_rss_mb=350.0),
            dict(name="part2", cpu_s=5.0, wall_s=6.0, peak_rss_mb=400.0),
            dict(name="decoupled", cpu_s=17.5, wall_s=20.5, peak_rss_mb=400.0),
        ]
        extra = {"dofs": 80000, "dofs_part1": 50018, "dofs_part2": 30000}
    summary = {
        "scene": "shoulder-internal-rotation",
        "method": method,
        "level": "coarse",
        "status": status,
        "message": None if status == "ok" else "every cutback failed at 43 deg",
        "ranks": 1,
        "resources": resources,
        "stages": stages,
        "series": {
            "max_pressure": series(angles, p.max(axis=1), "Pa"),
            "contact_force": series(angles, scale * (300.0 + angles), "N"),
            **{f"{m}_force": series(angles, scale * f, "N") for m, f in muscles.items()},
            **(
                {
                    "muscle_bone_contact_force": series(angles, scale * (1.0 + angles), "N"),
                    "infraspinatus_scapula_contact_force": series(angles, scale * angles, "N"),
                }
                if muscle_contact
                else {}
            ),
        },
        "probes": {"final_angle_deg": float(angles[-1])},
        **({"parameters": {"nodal_stress": recipe}} if recipe else {}),
        "probe_units": {"final_angle_deg": "deg"},
        **extra,
    }
    (folder / "summary.json").write_text(json.dumps(summary))
    return folder


def no_nan(path: Path) -> dict:
    def refuse(token):
        raise AssertionError(f"bare {token} in {path}")

    return json.loads(path.read_text(), parse_constant=refuse)


# ---- geometry ------------------------------------------------------------------------------


@pytest.mark.parametrize("z", [0.37, 1.0 / 3.0, 1.0])
def test_slice_of_linear_field_is_exact(z):
    pts, cells = kuhn_mesh(3, 1.0 / 3.0)

    def f(x, y, zz):
        return 1.0 + 2.0 * x - 3.0 * y + 0.5 * zz

    polys, vals = slice_tetrahedra(pts, cells, f(*pts.T), z)
    assert polys and len(polys) == len(vals)
    for p, v in zip(polys, vals, strict=True):
        assert len(p) in (3, 4) and p.shape == (len(v), 2)
        np.testing.assert_allclose(v, f(p[:, 0], p[:, 1], z), rtol=0, atol=1e-12)
    # the section of the unit cube is the unit square, covered once (no gaps, no doubles)
    assert sum(polygon_area(p) for p in polys) == pytest.approx(1.0, abs=1e-12)


def test_slice_single_tetrahedron_triangle_and_quad():
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
    cells = np.array([[0, 1, 2, 3]])
    polys, vals = slice_tetrahedra(pts, cells, pts[:, 2] * 10.0, 0.5)
    assert len(polys) == 1 and len(polys[0]) == 3
    assert polygon_area(polys[0]) == pytest.approx(0.125)
    np.testing.assert_allclose(vals[0], 5.0)
    # two vertices on each side: a quadrilateral
    pts2 = np.array([[0, 0, 0], [1, 0, 0], [0, 0, 1], [1, 1, 1]], dtype=float)
    polys, vals = slice_tetrahedra(pts2, cells, pts2[:, 0], 0.5)
    assert len(polys) == 1 and len(polys[0]) == 4
    # outside: nothing
    assert slice_tetrahedra(pts, cells, pts[:, 0], 2.0) == ([], [])


def test_glenoid_plane_coordinates():
    q = glenoid_plane_coordinates(CENTRE + np.array([[0.0, 0.01, 0.02]]), CENTRE, AXIS)
    np.testing.assert_allclose(q, [[0.01, 0.02]], atol=1e-15)
    # a tilted glenoid: the basis is orthonormal, superior is as close to +z as possible
    axis = np.array([1.0, -0.4, 0.3])
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(20, 3))
    pts -= np.outer(pts @ axis, axis) / (axis @ axis)  # points in the plane through 0
    q = glenoid_plane_coordinates(pts, np.zeros(3), axis)
    d = np.linalg.norm(pts[:, None] - pts[None], axis=2)
    dq = np.linalg.norm(q[:, None] - q[None], axis=2)
    np.testing.assert_allclose(dq, d, atol=1e-12)
    e = glenoid_plane_coordinates(np.array([[0, 0, 1.0], [0, 1.0, 0]]), np.zeros(3), axis)
    n = axis / np.linalg.norm(axis)
    assert e[0, 1] == pytest.approx(np.sqrt(1 - n[2] ** 2))  # |projection of z|
    assert e[0, 0] == pytest.approx(0.0, abs=1e-15)
    assert e[1, 0] > 0  # +y is anterior


def test_match_points_partial_and_permuted():
    a = np.random.default_rng(2).random((50, 3))
    perm = np.random.default_rng(3).permutation(50)
    i, j, frac = match_points(a, a[perm])
    assert frac == 1.0
    np.testing.assert_array_equal(a[i], a[perm][j])
    b = a.copy()
    b[:10] += 1e-6
    i, j, frac = match_points(a, b)
    assert frac == pytest.approx(0.8)
    np.testing.assert_array_equal(i, np.arange(10, 50))


# ---- report --------------------------------------------------------------------------------


def test_identical_runs(tmp_path):
    c = make_run(tmp_path / "coupled", "coupled")
    d = make_run(tmp_path / "decoupled", "decoupled")
    rep = write_report(c, d, tmp_path / "report", "coarse")
    out = tmp_path / "report"
    for name in (*FIGURES, "report.json", "report.md"):
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    for name in FIGURES:  # each figure in a vector format too, for print
        pdf = (out / name).with_suffix(".pdf")
        assert pdf.read_bytes()[:5] == b"%PDF-", name
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # no temporary files left
    assert no_nan(out / "report.json") == rep
    assert rep["von_mises_correlation"] == pytest.approx(1.0)
    assert rep["von_mises_slope"] == pytest.approx(1.0)
    assert rep["von_mises_max_abs_error_mpa"] == 0.0
    assert rep["max_pressure_rel_error"] == 0.0
    assert rep["muscle_force_rel_error"] == 0.0
    assert rep["muscle_bone_contact_force_rel_error"] is None  # no muscle contact in the runs
    assert rep["contact_region_jaccard_min"] == 1.0
    assert rep["angles_compared_deg"] == list(ANGLES)
    assert rep["final_angle_deg"] == {"coupled": 60.0, "decoupled": 60.0}
    assert rep["status"] == {"coupled": "ok", "decoupled": "ok"}
    assert rep["level"] == "coarse"
    assert rep["section_polygons"]["coupled"] == rep["section_polygons"]["decoupled"] > 0
    md = (out / "report.md").read_text()
    for text in ("Table II", "decoupled part 1", "temporary disk MB", "DOFs", "![", "| 60 |"):
        assert text in md


def test_scaled_results_and_resources(tmp_path):
    c = make_run(tmp_path / "coupled", "coupled", muscle_contact=True)
    d = make_run(tmp_path / "decoupled", "decoupled", scale=1.02, muscle_contact=True)
    rep = write_report(c, d, tmp_path / "report", "coarse")
    assert rep["muscle_bone_contact_force_rel_error"] == pytest.approx(0.02)
    assert "muscle-bone contact force" in comparison_table(rep)
    last = rep["per_angle"][-1]["infraspinatus_scapula_contact_force_n"]
    assert last["decoupled"] == pytest.approx(1.02 * last["coupled"])
    md = (tmp_path / "report" / "report.md").read_text()
    assert "## The rotator cuff on the bones" in md and "infraspinatus on scapula cpl N" in md
    assert rep["von_mises_slope"] == pytest.approx(1.02, rel=1e-12)
    assert rep["von_mises_correlation"] == pytest.approx(1.0)
    vm_max = 2 * von_mises(kuhn_mesh(4, 0.01, (-0.02, -0.02, -0.02))[0]).max()
    assert rep["von_mises_max_abs_error_mpa"] == pytest.approx(0.02 * vm_max * 1e-6)
    assert rep["von_mises_max_rel_error"] == pytest.approx(0.02)
    assert rep["max_pressure_rel_error"] == pytest.approx(0.02)
    for a in ANGLES:
        assert rep["max_pressure_rel_errors"][f"{a:g}"] == pytest.approx(0.02)
    assert rep["muscle_force_rel_error"] == pytest.approx(0.02)
    assert "0" not in rep["muscle_force_rel_errors"]["infraspinatus"]  # angles > 0 only
    assert rep["contact_force_rel_error"] == pytest.approx(0.02)
    assert 0.9 < rep["contact_region_jaccard_min"] <= 1.0
    assert rep["speedup_cpu"] == pytest.approx(5.0)
    assert rep["memory_ratio"] == pytest.approx(0.4)
    res = rep["resources"]
    assert res["coupled"]["cpu_s"] == 100.0 and res["coupled"]["dofs"] == 90000
    assert res["decoupled_part1"] == {
        "cpu_s": 12.0,
        "wall_s": 14.0,
        "peak_rss_mb": 350.0,
        "temp_disk_mb": None,
        "results_disk_mb": None,
        "ranks": 1,
        "dofs": 50018,
    }
    assert res["decoupled_part2"]["cpu_s"] == 5.0 and res["decoupled_part2"]["dofs"] == 30000
    assert res["decoupled"]["dofs"] == 80018 and res["decoupled"]["results_disk_mb"] == 30.0
    text = comparison_table(rep)
    assert "CPU speed-up" in text and "5.00" in text and "+2.00%" in text


def test_von_mises_at_every_angle_over_the_scapula_and_its_glenoid_region(tmp_path):
    """The von Mises table per angle: a decoupled run 5 % higher within 20 mm of the glenoid
    centre only reads slope 1.05 there at every angle, and over the whole scapula the slope of
    those numbers by hand; a run of the earlier recipe beside one of the tensor recipe is
    named in a note (not like with like)."""
    c = make_run(tmp_path / "coupled", "coupled")
    d = make_run(tmp_path / "decoupled", "decoupled", glenoid_factor=1.05)
    rep = write_report(c, d, tmp_path / "report", "coarse")
    rows = rep["von_mises_per_angle"]
    assert [r["angle_deg"] for r in rows] == list(ANGLES)
    sp = kuhn_mesh(4, 0.01, (-0.02, -0.02, -0.02))[0]
    near = np.linalg.norm(sp - CENTRE, axis=1) <= 0.02
    vm = von_mises(sp)
    dv = np.where(near, 1.05, 1.0) * vm
    whole = float(np.dot(vm, dv) / np.dot(vm, vm))
    assert 0 < near.sum() < len(sp)
    for r in rows:
        assert r["glenoid_region"]["nodes"] == near.sum()
        assert r["glenoid_region"]["slope"] == pytest.approx(1.05, rel=1e-12)
        assert r["scapula"]["slope"] == pytest.approx(whole, rel=1e-12)
        assert r["scapula"]["nodes"] == len(sp)
    assert rep["nodal_stress"] == "tensor" and not rep["notes"]
    md = (tmp_path / "report" / "report.md").read_text()
    table = md.split("## Nodal von Mises stress at every output angle")[1].split("## Figures")[0]
    assert "| 60 | " in table and "1.0500" in table
    e = make_run(tmp_path / "scalar", "decoupled", recipe="scalar")
    rep = write_report(c, e, tmp_path / "report2", "coarse")
    assert any("not like with like" in n for n in rep["notes"])


def test_run_stopped_early(tmp_path):
    c = make_run(tmp_path / "coupled", "coupled")
    d = make_run(
        tmp_path / "decoupled", "decoupled", angles=ANGLES[:5], status="incomplete", scale=1.02
    )
    rep = write_report(c, d, tmp_path / "report", "coarse")
    assert rep["final_angle_deg"] == {"coupled": 60.0, "decoupled": 40.0}
    assert rep["angles_compared_deg"] == [0.0, 10.0, 20.0, 30.0, 40.0]
    assert sorted(rep["max_pressure_rel_errors"], key=float) == ["0", "10", "20", "30", "40"]
    assert [r["angle_deg"] for r in rep["per_angle"]] == [0.0, 10.0, 20.0, 30.0, 40.0]
    assert rep["max_pressure_rel_error"] == pytest.approx(0.02)
    assert rep["status"]["decoupled"] == "incomplete"
    assert rep["messages"]["decoupled"].startswith("every cutback")
    # the von Mises fields are at 60 and 40 deg: not compared
    assert rep["von_mises_correlation"] is None and rep["von_mises_slope"] is None
    assert rep["von_mises_angle_deg"] == {"coupled": 60.0, "decoupled": 40.0}
    assert any("60" in n and "40" in n for n in rep["notes"])
    md = (tmp_path / "report" / "report.md").read_text()
    assert "reached 40 deg" in md and "reached 60 deg" in md
    assert "60 / 40" in comparison_table(rep)


def test_permuted_scapula_vertices_are_matched(tmp_path):
    c = make_run(tmp_path / "coupled", "coupled")
    d = make_run(tmp_path / "decoupled", "decoupled", permute=True)
    rep = write_report(c, d, tmp_path / "report", "coarse")
    assert rep["scapula_vertices_matched_fraction"] == 1.0
    assert rep["von_mises_nodes_compared"] == 125
    assert rep["von_mises_correlation"] == pytest.approx(1.0)
    assert rep["von_mises_slope"] == pytest.approx(1.0)
    assert rep["von_mises_max_abs_error_mpa"] == 0.0
    assert rep["contact_region_jaccard_min"] == 1.0  # glenoid points matched too
    assert rep["section_polygons"]["coupled"] == rep["section_polygons"]["decoupled"]


def test_mismatching_mesh_raises(tmp_path):
    c = make_run(tmp_path / "coupled", "coupled")
    d = make_run(tmp_path / "decoupled", "decoupled", shift=1e-3)
    with pytest.raises(ValueError, match="scapula") as err:
        write_report(c, d, tmp_path / "report", "coarse")
    assert str(c) in str(err.value) and str(d) in str(err.value)
    assert not (tmp_path / "report" / "report.json").exists()


def test_missing_npz_is_named(tmp_path):
    c = make_run(tmp_path / "coupled", "coupled")
    d = make_run(tmp_path / "decoupled", "decoupled")
    (d / "shoulder.npz").unlink()
    with pytest.raises(FileNotFoundError, match="shoulder.npz"):
        write_report(c, d, tmp_path / "report", "coarse")
