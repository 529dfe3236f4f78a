"""The shoulder study end to end at the coarse level: both methods from 0 to 60 deg.

The module fixture runs the scene as it is (0-60 deg, adaptive steps, outputs every 10 deg)
with both methods and writes the report. The tests check the outputs, the decoupled method
against the coupled reference (``COARSE_TOLERANCES``, measured values in the README), the swing
and the contact's place on the humeral cartilage (the same with both methods), what the
earlier model's horizontal distal elements change (with them the humerus hardly swings), the
bones' compliance (on the earlier model), the transfer of part 1's
loads to part 2, the scapula's suspension, a stalled rotation, and (under ``mpirun -n 2``)
parallel against serial on a short rotation.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import dolfinx
import numpy as np
import pytest
import ufl
from mpi4py import MPI
from scipy.spatial.transform import Rotation

from shoulder_fem import api
from shoulder_fem.engine.so3 import hat
from shoulder_fem.families.shoulder import geometry as SG
from shoulder_fem.families.shoulder import interactions as SI
from shoulder_fem.families.shoulder import model as SH
from shoulder_fem.families.shoulder import report as shoulder_report
from shoulder_fem.io import ct
from shoulder_fem.meshes import shoulder as MS
from shoulder_fem.scene import load_scene

FINAL, EVERY = 60.0, 10.0
#: Decoupled vs coupled at the coarse level, 0-60 deg (measured values in the README): the
#: paper's criteria (issue 20). Measured on the scene as it is (the cuff on both bones, the
#: 60 MPa/mm penalty): correlation 1.0000, slope 1.0054, pressure 2.8 % (at 30 deg), muscle
#: forces 0.78 % (the supraspinatus at 60 deg). (With the earlier 5 MPa/mm the supraspinatus
#: differed by 1.009 % at 60 deg and the bound was 1.25 %.)
#: The articular surfaces as the mesh's flat facets at 60 MPa/mm with the compressible
#: cartilage (the default before the curved surfaces): their unloaded joint is seated (the
#: facets' corners overlap), the scenario the seating's and the Newton tangent's tests below
#: were measured on (the Jacobian-pattern test counts no volumetric block).
FLAT = ["contact_surfaces=flat", "contact_penalty=60MPa/mm", "soft_tissue_formulation=compressible"]
COARSE_TOLERANCES = {
    "von_mises_correlation_min": 0.999,
    "von_mises_slope": (0.98, 1.02),
    "max_pressure_rel_error": 0.05,
    "muscle_force_rel_error": 0.01,
}
SERIES = (
    "humeral_angle",
    "max_pressure",
    "max_shear",
    "contact_force",
    "glenohumeral_penetration",
    "contact_area",
    "subscapularis_force",
    "supraspinatus_force",
    "infraspinatus_force",
    "actuation",
    "scapula_max_von_mises",
    "humeral_swing",
    "humeral_swing_elevation",
    "humeral_swing_azimuth",
    "soft_tissue_max_i1bar",
    "humeral_cartilage_volume_change",
    "glenoid_cartilage_volume_change",
    "subscapularis_volume_change",
    "supraspinatus_volume_change",
    "infraspinatus_volume_change",
    "humerus_distal_support_force",
    "humerus_horizontal_support_force",
    "humeral_cap_contact_angle",
    "humeral_cap_contact_angle_max",
    "humeral_cap_edge_margin",
)


@pytest.fixture(scope="module")
def study(tmp_path_factory) -> dict:
    """Both methods on the scene as it is (0-60 deg) and their report."""
    comm = MPI.COMM_WORLD
    base = Path(comm.bcast(str(tmp_path_factory.mktemp("shoulder")), root=0))
    scene = load_scene("shoulder-internal-rotation")
    assert scene.values()["final_angle"] == pytest.approx(math.radians(FINAL))
    results = {
        m: api.run(scene, m, "coarse", base / m, comm=comm) for m in ("coupled", "decoupled")
    }
    report = None
    if comm.rank == 0:
        report = shoulder_report.write_report(
            base / "coupled", base / "decoupled", base / "report", "coarse"
        )
    return {"base": base, "results": results, "report": comm.bcast(report, root=0)}


def _steps(group) -> list[str]:
    """The steps of an XDMF field's HDF5 group in time order (dolfinx names a step by its time,
    "." written "_")."""
    return sorted(group, key=lambda key: float(key.replace("_", ".")))


def _series(result, name: str) -> np.ndarray:
    s = result.data["series"][name]
    return np.asarray(s["x"], dtype=float), np.asarray(s["y"], dtype=float)


def _vtk_last_step(pvd: Path, field: str) -> tuple[np.ndarray, np.ndarray]:
    """(points, values) of ``field`` at the last step of a dolfinx VTK series, read as XML
    (ascii; every piece, ghost points dropped): ParaView's input, read independently."""
    import xml.etree.ElementTree as ET

    last = ET.parse(pvd).getroot().findall(".//DataSet")[-1].get("file")
    pieces = [p.get("Source") for p in ET.parse(pvd.parent / last).getroot().iter("Piece")]
    points, values = [], []
    for piece in pieces:
        root = ET.parse(pvd.parent / piece).getroot()
        arrays = {a.get("Name"): a for a in root.iter("DataArray")}

        def read(a, n):
            return np.array(a.text.split(), dtype=float).reshape(-1, n)

        pts = read(root.find(".//Points/DataArray"), 3)
        ghost = read(root.find(".//PointData/DataArray[@Name='vtkGhostType']"), 1).ravel()
        vals = read(arrays[field], int(arrays[field].get("NumberOfComponents", 1)))
        points.append(pts[ghost == 0])
        values.append(vals[ghost == 0])
    return np.concatenate(points), np.concatenate(values)


def test_p2_displacement_is_written_whole(study):
    """The P2 displacement at all its nodes (``<file>_displacement.pvd``, VTK Lagrange cells;
    the XDMF file holds the vertices only): as many points as P2 nodes (the XDMF mesh's
    vertices and edges, counted here), and at the vertices the XDMF file's values (issue 23)."""
    import h5py
    from scipy.spatial import cKDTree

    base = study["base"]
    for method, name in (("coupled", "coupled"), ("decoupled", "part1"), ("decoupled", "part2")):
        folder = base / method / "fields"
        X, u = _vtk_last_step(folder / f"{name}_displacement.pvd", "displacement")
        with h5py.File(folder / f"{name}.h5", "r") as h5:
            Xv = h5["Mesh/mesh/geometry"][:]
            uv = _last_step(h5, "displacement")
            tets = h5["Mesh/mesh/topology"][:]
        pairs = tets[:, [[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]]].reshape(-1, 2)
        edges = np.unique(np.sort(pairs, axis=1), axis=0)
        assert len(X) == len(Xv) + len(edges), (name, len(X), len(Xv), len(edges))
        # the cut-open interfaces (the subscapularis origin) hold two nodes at one place:
        # each vertex is compared with the closer in value of the VTK points there
        dist, idx = cKDTree(X).query(Xv, k=2)
        assert dist[:, 0].max() < 1e-12, name
        diff = np.linalg.norm(u[idx] - uv[:, None, :], axis=2)
        diff[dist >= 1e-12] = np.inf
        scale = np.abs(uv).max()
        assert scale > 0
        assert diff.min(axis=1).max() <= 1e-12 * scale, name


def _last_step(h5, field: str) -> np.ndarray:
    return h5[f"Function/{field}"][_steps(h5[f"Function/{field}"])[-1]][:]


def test_part2_global_fields_put_the_scapula_where_the_coupled_run_has_it(study):
    """part2.xdmf's global-frame fields at 60 deg (issue 23): ``displacement_global`` (part
    1's rigid motion of the scapula applied to part 2's floating-frame displacement) against
    the coupled run's own scapula displacement at the same vertices (an independent solve; the
    rigid motion turns the scapula by about 4 deg and moves it by mm, so a wrong frame would
    be off by mm); ``stress_global`` turned from the floating frame: the same von Mises."""
    import h5py
    from scipy.spatial import cKDTree

    base = study["base"]
    with h5py.File(base / "decoupled" / "fields" / "part2.h5", "r") as h5:
        X2 = h5["Mesh/mesh/geometry"][:]
        d2 = _last_step(h5, "displacement_global")
        d2_float = _last_step(h5, "displacement")
        sig = _last_step(h5, "stress").reshape(-1, 3, 3)
        sig_g = _last_step(h5, "stress_global").reshape(-1, 3, 3)
        vm = _last_step(h5, "von_mises").ravel()
    with h5py.File(base / "coupled" / "fields" / "coupled.h5", "r") as h5:
        Xc = h5["Mesh/mesh/geometry"][:]
        dc = _last_step(h5, "displacement")
    # the same gmsh model: the scapula's vertices coincide with the coupled mesh's; where the
    # coupled mesh is cut open (the subscapularis origin) two nodes share the place: the
    # scapula's is the one whose motion is the closer
    dist, idx = cKDTree(Xc).query(X2, k=2)
    assert dist[:, 0].max() < 1e-9
    gap = np.linalg.norm(dc[idx] - d2[:, None, :], axis=2)
    gap[dist >= 1e-9] = np.inf
    dc = dc[idx[np.arange(len(idx)), gap.argmin(axis=1)]]
    scale = np.linalg.norm(dc, axis=1).max()
    assert scale > 1e-3  # the scapula moved by mm
    assert np.linalg.norm(d2 - d2_float, axis=1).max() > 0.5 * scale  # the frames differ
    err = np.linalg.norm(d2 - dc, axis=1).max() / scale
    # the decoupling's own difference (measured 0.86 % of the 10.7 mm motion at coarse); a
    # wrong frame (R for R^T, the rotation about another point) is off by tens of percent
    assert err < 0.02, err

    def von_mises(s):
        dev = s - np.trace(s, axis1=1, axis2=2)[:, None, None] * np.eye(3) / 3
        return np.sqrt(1.5 * np.einsum("nij,nij->n", dev, dev))

    assert np.allclose(von_mises(sig_g), vm, rtol=1e-9, atol=1e-9 * vm.max())
    assert np.abs(sig_g - sig).max() > 1e-3 * np.abs(sig).max()  # turned, not copied


def test_both_methods_reach_the_final_angle_with_every_output(study):
    angles = np.arange(0.0, FINAL + 0.5 * EVERY, EVERY)
    for method, result in study["results"].items():
        assert result.status == "ok", (method, result.data.get("message"))
        assert result.probes["final_angle_deg"] == pytest.approx(FINAL, abs=1e-9)
        # angle-controlled steps, every solve converged (issue 19): no cut-back in part 1, one
        # in the coupled run (measured: 3.2 -> 5.5 deg, where the humerus's swing grows
        # fastest; test_every_step_converges_in_a_few_newton_iterations)
        assert result.probes["failed_steps"] <= (1 if method == "coupled" else 0), method
        # the mesh sizes the run used, as the scene file's [levels.coarse] states them (m)
        assert result.level_settings == {"h_joint": 0.0125, "h_bone": 0.040, "h_muscle": 0.025}
        for name in SERIES:
            x, y = _series(result, name)
            assert np.allclose(x, angles), (method, name, x)
            assert np.all(np.isfinite(y)), (method, name, y)
        # the measured humeral angle hits each target to 1e-6 deg (the angle is an equation of
        # the Newton system, residual scale 1e5 N/rad, atol 1e-3 N: 6e-7 deg at most), except
        # at 0 deg: the initial seating of the faceted cartilages turns it a little (measured
        # 0.38 deg at coarse, with the plate at rest)
        x, y = _series(result, "humeral_angle")
        assert np.allclose(y[1:], x[1:], rtol=0, atol=1e-6), (method, y - x)
        assert abs(y[0]) < 0.5
        # the soft tissues at equilibrium are inside the trial states' bounds (J > 0); with the
        # muscles incompressible the smallest J at their points falls to 0.011-0.013 at 60 deg at
        # coarse (25 mm muscles; 0.17 at medium), at one point of a subscapularis cell next to
        # its insertion footprint, held by the pointwise stabilisation (0.003 and a stall near
        # 40 deg without it; README); with nu = 0.49 muscles it was 0.47
        _, jmin = _series(result, "soft_tissue_min_j")
        assert np.all(jmin > 0.005) and np.all(np.diff(jmin[1:]) < 0), (method, jmin)
        # the subscapularis pulls harder as the humerus turns (0.4 -> 48 N measured over
        # 0-60 deg; 0.5 N is a floor, not a fit); the contact is loaded
        _, fsub = _series(result, "subscapularis_force")
        assert np.all(np.diff(fsub) > 0) and fsub[-1] > 0.5, fsub
        _, pmax = _series(result, "max_pressure")
        assert pmax[-1] > 0
        with np.load(Path(result.folder) / "shoulder.npz") as npz:
            assert np.allclose(npz["angles_deg"], angles)
            for key in ("glenoid_pressure", "glenoid_shear", "scapula_von_mises", "scapula_points"):
                assert np.all(np.isfinite(npz[key])), (method, key)
            assert npz["glenoid_pressure"].shape == (len(angles), len(npz["glenoid_points"]))
            series = npz["scapula_von_mises_series"]
            assert np.allclose(npz["von_mises_angles_deg"], angles)
            assert series.shape == (len(angles), len(npz["scapula_points"]))
            assert np.array_equal(series[-1], npz["scapula_von_mises"])
        # ParaView's fields: the nodal stress tensor and von Mises stress at every output
        # angle (XDMF "Time" = the angle in deg), the same values as shoulder.npz's
        import h5py

        first = "coupled" if method == "coupled" else "part1"  # the joint, with its contact
        with h5py.File(Path(result.folder) / "fields" / f"{first}.h5", "r") as h5:
            for field in ("displacement", "contact_pressure", "contact_shear", "body"):
                times = [float(k.replace("_", ".")) for k in _steps(h5[f"Function/{field}"])]
                assert np.allclose(times, angles, rtol=0, atol=1e-9), (field, times)
            p_60 = h5["Function/contact_pressure"][_steps(h5["Function/contact_pressure"])[-1]][:]
            body = h5["Function/body"][_steps(h5["Function/body"])[-1]][:]
            X = h5["Mesh/mesh/geometry"][:]
        with np.load(Path(result.folder) / "shoulder.npz") as npz:
            glenoid = npz["glenoid_points"]
        from scipy.spatial import cKDTree

        # the glenoid (the slave) at its nodes: the series' pressure; the humeral cartilage (the
        # master) has its own nodal values (issue 23: both articular surfaces)
        on_glenoid = np.zeros(len(X), dtype=bool)
        dist, idx = cKDTree(X).query(glenoid, k=2)
        assert dist[:, 0].max() < 1e-12
        on_glenoid[idx[dist < 1e-12]] = True
        _, pmax = _series(result, "max_pressure")
        assert p_60.ravel()[on_glenoid].max() == pytest.approx(pmax[-1], rel=1e-12)
        assert np.count_nonzero(p_60.ravel()[~on_glenoid] > 0) > 3, method
        assert {MS.HUMERAL_CARTILAGE.id, MS.GLENOID_CARTILAGE.id} <= set(
            np.unique(body).astype(int)
        )
        name = "coupled" if method == "coupled" else "part2"
        with h5py.File(Path(result.folder) / "fields" / f"{name}.h5", "r") as h5:
            for field in ("displacement", "stress", "von_mises"):
                times = [float(k.replace("_", ".")) for k in _steps(h5[f"Function/{field}"])]
                assert np.allclose(times, angles, rtol=0, atol=1e-9), (field, times)
            vm_60 = h5["Function/von_mises"][_steps(h5["Function/von_mises"])[-1]][:]
            sig_60 = h5["Function/stress"][_steps(h5["Function/stress"])[-1]][:]
        assert sig_60.shape[1] == 9
        assert vm_60.max() == pytest.approx(series[-1].max(), rel=1e-12)
        assert (Path(result.folder) / "fields").is_dir()
    report = study["report"]
    for key in (
        "speedup_cpu",
        "memory_ratio",
        "von_mises_correlation",
        "von_mises_slope",
        "max_pressure_rel_error",
        "muscle_force_rel_error",
    ):
        assert report[key] is not None and math.isfinite(report[key]), key
    for name in shoulder_report.FIGURES:
        assert (study["base"] / "report" / name).stat().st_size > 10_000, name
    on_disk = json.loads((study["base"] / "report" / "report.json").read_text())
    assert on_disk == report  # report.json is what write_report returned


def test_every_step_converges_in_a_few_newton_iterations(study):
    """At most 7 Newton iterations per step on average, the failed tries counted (issue 19 took
    the solve from about 15 per step to about 6). Measured at coarse: 4.4 coupled and 5.4 part 1
    with the 5 MPa/mm penalty; with the 60 MPa/mm default (stop 33) 6.44 coupled (251 in 39
    steps) and part 1 6.31 (246 in 39) on that session's machine, and part 1 6.51 (254 in 39,
    the same code) on the next one's: the count moves with the platform's round-off (where
    a full step fails and the l2 retry starts), so the bound is 7, not the 6.5 it was. No step of
    part 1 is cut back; the coupled run one: on the paper's supports the humerus swings 14 deg
    in the first 10 deg of twist, and the step 3.2 -> 5.5 deg fails in both line searches and
    converges halved (measured). With the curved surfaces at 100 MPa/mm (the default since),
    the engagement's 7 solves counted as steps: coupled 179 in 36 (4.97; the step 6.26 -> 8.13
    deg cut back), part 1 198 in 36 (5.5), none cut back. With the incompressible cartilage at
    200 MPa/mm (the default since) the multipliers' updates after the steps are counted apart
    (``volume_update_iterations``): coupled 242 + 68 in 44 steps (5.5; one cut back), part 1
    243 + 68 in 42 (5.8), none cut back. With the cuff's faces over the head in the scapula's
    pair too (the default since) the coupled run cut back 3 steps; with the retries from the
    step's start first (:func:`~shoulder_fem.families.shoulder.newton.solve_with_fallback`)
    none: coupled 232 + 67 in 41 steps (5.7), part 1 262 + 68 in 42 (6.2; its retry at 8.13
    deg converged from the prediction after 20 iterations in vain from the start). A stepper
    then retries first from the start that converged last (``newton.RetryOrder``): at most one
    retry per run fails from its first start (measured: coupled 0, part 1 1, its retry at 28.48
    deg then converging from the prediction in 9; at paper part 1 lost 20 iterations in each of
    5 retries before). With the muscles incompressible too (the default since 2026-11-29) the
    multipliers' updates take about as many iterations as the steps (coupled 240 + 215 in 38
    steps, 6.3; part 1 300 + 255 in 44, 6.8; none cut back) and the learnt order is right in
    at least half the retries (coupled: 0 of 4 failed from the first start, part 1 2 of 6). With
    the multipliers predicted by the secant (``soft_tissue_multiplier_prediction``, the default
    since) and the penalty raised where updates gain little: coupled 217 + 116 in 35 steps
    (6.2), part 1 277 + 132 in 42 (6.6), none cut back. The coupled steps' bone rotations are
    finite (:mod:`shoulder_fem.engine.rigid_system.corotation`): with linear ones the coupled
    run took 310 iterations in 43 steps, two solves of 24 and 45 iterations among them, and at
    medium a cut-back at 11 deg (with them, 2 cut-backs there: 1.4 -> 2.8 and 12.5 -> 15
    deg)."""
    for method, result in study["results"].items():
        p = result.probes
        assert p["failed_steps"] <= (1 if method == "coupled" else 0), (method, p["failed_steps"])
        # the steps' own solves: the cartilages' multiplier updates after them (1-2 Newton
        # iterations each, counted apart) do not set the steps' length
        steps_own = p["newton_iterations"] - p["volume_update_iterations"]
        assert 0 < p["volume_update_iterations"] < steps_own, (method, p)
        assert steps_own <= 7.0 * p["steps"], (method, p["newton_iterations"])
        retries = p["linesearch_fallbacks"]
        assert p["first_retries_failed"] <= (retries + 1) // 2, (method, retries, p)


def test_the_soft_bodies_keep_their_volume(study):
    """Table I: the cartilages and the muscles are incompressible (``soft_tissue_formulation =
    incompressible``, the default since 2026-11-29). The augmented Lagrangian holds every
    soft-tissue vertex's |ln theta| to ``soft_tissue_volume_tolerance`` (1e-4), so no soft
    body's volume changes by more than that at any output, with either method (the earlier
    cartilage, nu = 0.4, lost 0.35 % of the glenoid layer by 60 deg; the earlier muscles, nu =
    0.49, grew by 0.2-0.6 %)."""
    scene = load_scene("shoulder-internal-rotation")
    assert scene.values()["soft_tissue_formulation"] == "incompressible"
    tolerance = scene.values()["soft_tissue_volume_tolerance"]
    bodies = ("humeral_cartilage", "glenoid_cartilage", *MS.MUSCLES)
    for method, result in study["results"].items():
        for body in bodies:
            _, change = _series(result, f"{body}_volume_change")
            assert np.abs(change).max() <= tolerance, (method, body, change)


def test_a_forced_large_step_is_shortened_inside_the_solve_not_cut_back(comm_tmp):
    """Part 1 at coarse, one forced step from the unloaded state to 4 deg (the scene's first
    step is 1.25 deg; on the flat facets, whose unloaded joint is seated, not engaged by
    travel): full Newton steps from there would invert soft-tissue elements. The
    guard halves them inside the solve (measured with the 60 MPa/mm penalty: 7 steps
    shortened, 17 halvings, 31 iterations; a forced 5 deg step is cut back once; with the
    earlier 5 MPa/mm the same held for 6 deg: 2 shortened, 4 halvings, 11 iterations) and the
    step converges on its target."""
    scene = load_scene("shoulder-internal-rotation").with_overrides(
        ["final_angle=4deg", "angle_step=4deg", "max_angle_step=4deg", "output_angle=4deg", *FLAT]
    )
    result = api.run(scene, "decoupled", "coarse", comm_tmp / "forced")
    p = result.probes
    assert result.status == "ok" and p["failed_steps"] == 0 and p["steps"] == 1, p
    assert p["shortened_newton_steps"] >= 1 and p["newton_step_halvings"] >= 1, p
    x, y = _series(result, "humeral_angle")
    assert x[-1] == pytest.approx(4.0) and y[-1] == pytest.approx(4.0, abs=1e-6), y


def test_a_cut_back_step_is_an_info_line_with_the_reason_at_debug(comm_tmp, caplog):
    """Part 1 at coarse, one forced 8-deg step (measured: its solve ends in a NaN residual even
    with the guard; the halved steps converge): the log says "cut back" at info level, the
    PETSc reason only at debug level, and no warning."""
    import logging

    scene = load_scene("shoulder-internal-rotation").with_overrides(
        ["final_angle=8deg", "angle_step=8deg", "max_angle_step=8deg", "output_angle=8deg"]
    )
    name = "shoulder_fem.families.shoulder.stepping"
    with caplog.at_level(logging.DEBUG, logger=name):
        result = api.run(scene, "decoupled", "coarse", comm_tmp / "cut")
    assert result.status == "ok" and result.probes["failed_steps"] >= 1
    mine = [r for r in caplog.records if r.name == name]
    cut = [r for r in mine if "cut back (1/6)" in r.getMessage()]
    assert cut and all(r.levelno == logging.INFO for r in cut), [r.getMessage() for r in mine]
    reasons = [r for r in mine if "DIVERGED" in r.getMessage()]
    assert reasons and all(r.levelno == logging.DEBUG for r in reasons)
    assert not [r for r in mine if r.levelno >= logging.WARNING]


def test_decoupled_matches_coupled_within_the_coarse_tolerances(study):
    m = study["report"]
    tol = COARSE_TOLERANCES
    assert m["von_mises_correlation"] >= tol["von_mises_correlation_min"], m
    lo, hi = tol["von_mises_slope"]
    assert lo <= m["von_mises_slope"] <= hi, m
    assert m["max_pressure_rel_error"] <= tol["max_pressure_rel_error"], m
    errors = m["muscle_force_rel_errors"]  # muscle -> {angle: relative error}
    assert set(errors) == {"infraspinatus", "subscapularis", "supraspinatus"}, errors
    for muscle, by_angle in errors.items():
        assert [float(a) for a in by_angle] == [10.0, 20.0, 30.0, 40.0, 50.0, 60.0], by_angle
        largest = max(abs(e) for e in by_angle.values())
        # the report's figure is the paper's two muscles' (Fig. 3); every muscle, the
        # supraspinatus too, within the paper's 1 % (measured 0.78 % for it at 60 deg with the
        # 60 MPa/mm penalty; 1.009 % with the earlier 5 MPa/mm)
        if muscle != "supraspinatus":
            assert largest <= m["muscle_force_rel_error"], (muscle, by_angle)
        assert largest <= tol["muscle_force_rel_error"], (muscle, by_angle)
    assert m["muscle_force_rel_error"] <= tol["muscle_force_rel_error"], m
    # the nodal von Mises stress (tensor recipe, Abaqus/CalculiX) at every output angle, over
    # the scapula and its glenoid region: the paper's criteria (measured at coarse with the
    # 60 MPa/mm penalty: scapula r >= 0.99997, slopes 0.9993-1.0072; glenoid region
    # r >= 0.99957, slopes 0.9991-1.0076. With 5 MPa/mm the glenoid region missed them at
    # 60 deg: r 0.9989, slope 1.045)
    rows = m["von_mises_per_angle"]
    assert np.allclose([r["angle_deg"] for r in rows], np.arange(0.0, 61.0, 10.0), atol=1e-9)
    for r in rows:
        for region in ("scapula", "glenoid_region"):
            assert r[region]["correlation"] >= tol["von_mises_correlation_min"], r
            assert lo <= r[region]["slope"] <= hi, r


@pytest.fixture(scope="module")
def compliant(study) -> dict:
    """The decoupled method with ``part1_bones = compliant`` on the study's scene, and its
    report against the study's coupled run."""
    comm = MPI.COMM_WORLD
    base = study["base"]
    scene = load_scene("shoulder-internal-rotation").with_overrides(["part1_bones=compliant"])
    result = api.run(scene, "decoupled", "coarse", base / "compliant", comm=comm)
    report = None
    if comm.rank == 0:
        report = shoulder_report.write_report(
            base / "coupled", base / "compliant", base / "report_compliant", "coarse"
        )
    return {"result": result, "report": comm.bcast(report, root=0)}


def test_compliant_decoupling_is_closer_to_coupled_at_every_angle(study, compliant):
    """``part1_bones = compliant`` (families/shoulder/correction.py, humerus.py): part 1 solved
    again at each output angle with the scapula's surfaces moved by part 2's displacement and
    the humerus's by its own floating-frame displacement, then part 2 again. Against the
    coupled run: the muscle forces and the peak pressure are closer than the rigid
    decoupling's (kept in the same run as ``uncorrected_``) at every output angle, unless both
    are within part 1's Newton tolerance of each other (|F| < 1e-3 N: the muscle forces at
    0-10 deg are 0.2-7 N); the errors are within the issue's 0.2 % (measured: muscles
    0.008 %, pressure 0.044 %, against 0.78 % and 2.8 % rigid) and the nodal von Mises slope
    within 0.998-1.002 at every angle."""
    res, rigid = compliant["result"], study["results"]["decoupled"]
    assert res.status == "ok", res.data.get("message")
    cpl = study["results"]["coupled"]
    # the rigid pass of the compliant run is the plain decoupled run
    for name in ("subscapularis_force", "max_pressure", "scapula_max_von_mises"):
        a, b = _series(res, f"uncorrected_{name}")[1], _series(rigid, name)[1]
        assert np.allclose(a, b, rtol=1e-9, atol=1e-9 * np.abs(b).max()), (name, a, b)
    for name in ("subscapularis_force", "supraspinatus_force", "infraspinatus_force"):
        c = _series(cpl, name)[1]
        new, old = _series(res, name)[1], _series(res, f"uncorrected_{name}")[1]
        closer = (np.abs(new - c) <= np.abs(old - c)) | (np.abs(new - old) < 2e-3)
        assert np.all(closer), (name, c, new, old)
        assert np.all(np.abs(new - c)[1:] <= 2e-3 * c[1:]), (name, c, new)
    c, new = _series(cpl, "max_pressure")[1], _series(res, "max_pressure")[1]
    old = _series(res, "uncorrected_max_pressure")[1]
    # the unloaded joint (curved surfaces) is open or barely touches in every method (measured
    # with the incompressible muscles at 0 deg: 0.49 Pa, 1e-4 N in all, its differences
    # within part 1's Newton tolerance); loaded from 10 deg (46 kPa)
    loaded = c > 1e3
    assert np.all(new[~loaded] < 1e3) and np.all(old[~loaded] < 1e3), (c, new, old)
    assert np.all(np.abs(new - c)[loaded] < np.abs(old - c)[loaded]), (c, new, old)
    assert np.all(np.abs(new - c)[loaded] <= 2e-3 * c[loaded]), (c, new)
    m = compliant["report"]
    assert m["uncorrected"]["muscle_force_rel_error"] == pytest.approx(
        study["report"]["muscle_force_rel_error"], rel=1e-6
    )
    for row in m["von_mises_per_angle"]:
        assert 0.998 <= row["scapula"]["slope"] <= 1.002, row
        assert row["scapula"]["correlation"] >= 0.9999, row
    # part 2 again finds the deformation part 1 was given: its plates where the offsets put
    # them (relative to the offsets' 86 um at 60 deg, measured 0.2 %), and the transferred
    # loads balance the springs where part 1 had them, to its Newton tolerance
    assert res.probes["transfer_equilibrium_residual"] < 1e-8
    _, offset = _series(res, "part1_correction_offset")
    assert np.all(offset[1:] > 0) and offset[-1] < 1e-3, offset
    # the humerus's fixed distal section takes the springs' force that part 1 balanced against
    # its soft tissues (a conservation law: part 1's loads on the humerus and its springs'
    # forces are computed apart), to part 1's Newton tolerance (measured 1e-7 at 0 deg on the
    # flat facets' seated joint; the open joint's 1e-3 N there is compared in N)
    assert res.probes["humerus_section_balance"] < 1e-6
    _, hum = _series(res, "part1_correction_offset_humerus")
    assert np.all(hum[1:] > 0) and hum[-1] < 1e-4, hum  # measured 1.9 um at 60 deg
    # each correction is a small perturbation of part 1's state: a few Newton iterations (2-6
    # measured at 0-50 deg), except at 60 deg, where the contact stands on the cartilage's
    # edge and the scapula's surfaces move by 0.26 mm: there the full-step solve runs out of
    # its 15 iterations and the l2 retry converges (measured 23 in all); the incompressible
    # cartilage's multipliers need no update after a correction (measured 0)
    _, its = _series(res, "part1_correction_iterations")
    assert len(its) == 7 and np.all(its[:-1] <= 10) and its[-1] <= 15 + 60, its
    _, updates = _series(res, "part1_correction_volume_iterations")
    assert len(updates) == 7 and np.all(updates <= 10), updates
    names = [s["name"] for s in res.data["stages"]]
    for stage in ("part1", "part2_uncorrected", "humerus", "part1_correction", "part2"):
        assert stage in names, names


def test_the_humerus_compliance_brings_the_muscles_closer(study, compliant, comm_tmp):
    """The humerus's share of the compliant decoupling: with the scapula's compliance only
    (``part1_bones = compliant-scapula``) the largest muscle-force error against the coupled
    run, 10-60 deg, is larger than with both bones' (measured 0.038 % against 0.008 %), at
    every output angle, and the same rigid pass underlies both."""
    scene = load_scene("shoulder-internal-rotation").with_overrides(
        ["part1_bones=compliant-scapula"]
    )
    scap = api.run(scene, "decoupled", "coarse", comm_tmp / "scapula-only", comm=MPI.COMM_WORLD)
    assert scap.status == "ok", scap.data.get("message")
    assert "part1_correction_offset_humerus" not in scap.data["series"]
    both, cpl = compliant["result"], study["results"]["coupled"]
    worst = {}
    for label, res in (("both", both), ("scapula", scap)):
        errors = []
        for name in ("subscapularis_force", "supraspinatus_force", "infraspinatus_force"):
            c = _series(cpl, name)[1][1:]
            errors.append(np.abs(_series(res, name)[1][1:] - c) / c)
        worst[label] = np.max(errors, axis=0)
    assert np.all(worst["both"] < worst["scapula"]), worst
    assert worst["both"].max() < 2e-4, worst
    a, b = (
        _series(scap, "uncorrected_max_pressure")[1],
        _series(both, "uncorrected_max_pressure")[1],
    )
    assert np.allclose(a, b, rtol=1e-9), (a, b)


def test_compliant_decoupling_refuses_what_it_cannot_do(study, compliant, comm_tmp):
    """A compliant part 1 on another part-2 level, and a sweep from a compliant run, are
    refused before anything is solved, naming the key."""
    from shoulder_fem.scene import SceneError

    scene = load_scene("shoulder-internal-rotation").with_overrides(
        ["part1_bones=compliant", "part2_level=medium"]
    )
    with pytest.raises(SceneError, match="part1_bones = compliant needs part 2 on part 1"):
        api.run(scene, "decoupled", "coarse", comm_tmp / "refused", comm=MPI.COMM_WORLD)
    plain = load_scene("shoulder-internal-rotation")
    with pytest.raises(SceneError, match="part1_bones = 'compliant'.*rigid"):
        api.sweep(
            plain,
            study["base"] / "compliant",
            ["scapula_modulus_factor=2"],
            comm_tmp / "sweep",
            comm=MPI.COMM_WORLD,
        )


def test_swing_and_twist_by_hand():
    """Twist and swing of known rotations: about the axis (pure twist), about a perpendicular
    axis (pure swing), and their product (the axis turns by the swing only)."""
    axis = np.array([0.0, 0.0, 1.0])
    twist = Rotation.from_rotvec(np.radians(40.0) * axis).as_matrix()
    swing = Rotation.from_rotvec(np.radians(25.0) * np.array([1.0, 0.0, 0.0])).as_matrix()
    assert math.degrees(SG.twist_angle(twist, axis)) == pytest.approx(40.0)
    assert math.degrees(SG.swing_angle(twist, axis)) == pytest.approx(0.0, abs=1e-6)
    assert math.degrees(SG.twist_angle(swing, axis)) == pytest.approx(0.0, abs=1e-12)
    assert math.degrees(SG.swing_angle(swing, axis)) == pytest.approx(25.0)
    both = swing @ twist  # twist first, then swing: the swing-twist decomposition
    assert math.degrees(SG.twist_angle(both, axis)) == pytest.approx(40.0)
    assert math.degrees(SG.swing_angle(both, axis)) == pytest.approx(25.0)


def test_swing_parts_by_hand():
    """The swing split into elevation and azimuth, for a shaft 50 deg from the vertical in the
    x-z plane (distal end lateral and down, as the scene's): a turn about the vertical changes
    its azimuth only, a turn about the y axis its elevation only, and a twist about the shaft
    neither; for a general rotation the two parts give back the total swing (spherical law of
    cosines)."""
    e0 = math.radians(50.0)
    up = -np.array([math.sin(e0), 0.0, -math.cos(e0)])  # the shaft axis points proximally
    about_z = Rotation.from_rotvec(np.radians(30.0) * np.array([0.0, 0.0, 1.0])).as_matrix()
    assert np.degrees(SG.swing_parts(about_z, up)) == pytest.approx([0.0, 30.0], abs=1e-9)
    # about -y: the distal end (+x, -z) rises towards +x: abduction by 12 deg
    about_y = Rotation.from_rotvec(np.radians(-12.0) * np.array([0.0, 1.0, 0.0])).as_matrix()
    assert np.degrees(SG.swing_parts(about_y, up)) == pytest.approx([12.0, 0.0], abs=1e-9)
    twist = Rotation.from_rotvec(np.radians(60.0) * up).as_matrix()
    assert np.degrees(SG.swing_parts(twist, up)) == pytest.approx([0.0, 0.0], abs=1e-9)
    R = Rotation.from_rotvec([0.3, -0.2, 0.5]).as_matrix() @ twist
    d_elev, d_azim = SG.swing_parts(R, up)
    e1 = e0 + d_elev
    cos_swing = math.sin(e0) * math.sin(e1) * math.cos(d_azim) + math.cos(e0) * math.cos(e1)
    assert math.acos(cos_swing) == pytest.approx(SG.swing_angle(R, up), abs=1e-12)


def test_cap_angles_by_hand():
    """Angles from a cap's axis seen from its centre: on the axis, at 45 and 90 deg, behind."""
    centre, axis = np.array([1.0, 2.0, 3.0]), np.array([0.0, 1.0, 0.0])
    X = centre + np.array([[0, 2, 0], [1, 1, 0], [0, 0, 3], [0, -1, 0]], dtype=float)
    assert np.degrees(SG.cap_angles(X, centre, axis)) == pytest.approx([0, 45, 90, 180])


def test_swing_and_the_contact_on_the_humeral_cartilage(study):
    """The humerus's swing and where the glenoid presses on the humeral cartilage: the same
    with both methods (a rigid humerus's rotation against the coupled humerus's best fit;
    measured to 0.115 deg and 0.12 deg over 0-60 deg); on the paper's supports the shaft swings
    (measured 13.9 deg at 10 deg of twist, 36.9 at 60: the vertical elements do not hold a
    horizontal swing); the contact moving away from the cartilage's axis as the humerus turns,
    and never beyond the cartilage as meshed (its half-angle, the scene's 70 deg on its
    nodes)."""
    cpl, dec = study["results"]["coupled"], study["results"]["decoupled"]
    half = cpl.probes["humeral_cap_half_angle_deg"]
    assert half == pytest.approx(70.0, abs=0.5)  # the scene's humeral_cartilage_angle
    assert dec.probes["humeral_cap_half_angle_deg"] == pytest.approx(half)
    _, swing_c = _series(cpl, "humeral_swing")
    _, swing_d = _series(dec, "humeral_swing")
    # the other method (measured: within 0.115 deg over 0-60 deg, at 60 deg, where the cuff
    # presses on part 1's rigid scapula and on the coupled deformable one; 0.077 deg with the
    # cuff on the head alone, 0.090 deg at medium)
    assert np.allclose(swing_c, swing_d, atol=0.15), (swing_c, swing_d)
    # the paper's supports: a swing that grows with the twist (held under 1.5 deg by the
    # earlier model's horizontal elements: test_horizontal_elements_hold_the_swing)
    assert swing_c[1] > 10.0 and np.all(np.diff(swing_c) > 0), swing_c
    # its two parts (measured at 60 deg: elevation -26.7 deg, azimuth +45.1 deg) give back the
    # swing, with the shaft's elevation from the downward vertical at rest (spherical cosines)
    _, elev = _series(cpl, "humeral_swing_elevation")
    _, azim = _series(cpl, "humeral_swing_azimuth")
    geometry = MS.geometry_from_values(load_scene("shoulder-internal-rotation").values())
    distal = MS.layout(geometry).rot @ MS.shaft_axis(geometry)[0]
    e0 = math.acos(-distal[2] / np.linalg.norm(distal))  # 50 deg: the arm is abducted
    e1, a = e0 + np.radians(elev), np.radians(azim)
    back = np.degrees(np.arccos(np.sin(e0) * np.sin(e1) * np.cos(a) + np.cos(e0) * np.cos(e1)))
    assert np.allclose(back, swing_c, atol=1e-6), (back, swing_c)
    _, mean_c = _series(cpl, "humeral_cap_contact_angle")
    _, mean_d = _series(dec, "humeral_cap_contact_angle")
    # the other method (measured: within 0.2 deg over 0-60 deg)
    assert np.allclose(mean_c, mean_d, atol=0.5), (mean_c, mean_d)
    assert np.all(np.diff(mean_c) > 0), mean_c
    for result in (cpl, dec):
        _, top = _series(result, "humeral_cap_contact_angle_max")
        # no contact point beyond the cartilage's edge; the farthest one is not nearer the axis
        # than the force-weighted mean (1 deg for the two runs' means differing)
        assert np.all(top <= half + 1e-9) and np.all(top >= mean_c - 1.0), top
    report = study["report"]  # the report's table of them
    assert report["humeral_cap_half_angle_deg"] == pytest.approx(half)
    last = report["per_angle"][-1]
    assert last["humeral_swing_deg"]["decoupled"] == pytest.approx(swing_d[-1])
    assert last["humeral_cap_contact_angle_deg"]["coupled"] == pytest.approx(mean_c[-1])
    md = (study["base"] / "report" / "report.md").read_text()
    assert "## Humeral swing and the contact on the humeral cartilage" in md


def test_where_the_newton_time_went_adds_up(study):
    """The Newton time split of both steppings: every part is timed inside the Newton solves
    (residual and Jacobian callbacks, contact within them, assembly and reduction within the
    Jacobian), so the parts cannot exceed their wholes; the report tabulates them."""
    for method, label in (("coupled", "coupled"), ("decoupled", "part1")):
        p = study["results"][method].probes
        t = {k: p[f"{label}_time_{k}_s"] for k, _ in shoulder_report.TIME_SPLIT}
        assert all(v >= 0 for v in t.values()), t
        assert t["residual"] + t["jacobian"] <= t["newton"] * (1 + 1e-9), t
        assert t["jacobian_fe_assembly"] + t["jacobian_reduction"] <= t["jacobian"], t
        assert 0 < t["contact"] <= t["residual"] + t["jacobian"], t
        assert t["linear"] == pytest.approx(t["newton"] - t["residual"] - t["jacobian"])
        assert study["report"]["time_split"][label]["newton"] == pytest.approx(t["newton"])
    md = (study["base"] / "report" / "report.md").read_text()
    assert "Where the Newton time went" in md


def test_transferred_loads_balance_the_springs_and_part2_factorizes_once(study):
    """Part 1's loads on the scapula (glenoid, supraspinatus, infraspinatus) and its springs at
    the recorded pose are in equilibrium (a conservation law of part 1); part 2 reuses one
    factorization for every angle."""
    dec = study["results"]["decoupled"]
    # relative to the transferred loads (~10-100 N); at the output angles Newton goes on to
    # |F| < 1e-6 N (stepping.OUTPUT_ATOL)
    assert dec.probes["transfer_equilibrium_residual"] < 1e-8
    assert dec.probes["part2_factorizations"] == 1
    _, inertia = _series(dec, "part2_inertia_force")
    _, loads = _series(dec, "part2_transferred_force")
    assert np.all(np.isfinite(inertia)) and np.all(inertia < 1e-3 * loads.max())
    # what part 2 leaves out of its springs: the recorded tension's geometric stiffness, N/l
    # = k |l - L0| / l, i.e. each spring's strain at the recorded pose: at most a few percent
    # of k for a scapula that moves millimetres on 100 mm springs (measured 0.6 % at paper);
    # and the plates move microns in the floating frame (measured up to 92 um)
    _, ratio = _series(dec, "part2_spring_geometric_stiffness_ratio")
    _, plate = _series(dec, "part2_spring_plate_displacement")
    assert np.all((ratio > 0) & (ratio < 0.05)), ratio
    assert np.all(plate[1:] > 0) and np.all(plate < 1e-3), plate


def test_a_ct_scan_of_the_phantom_gives_the_phantoms_results(study, comm_tmp):
    """``ct_image``: the built-in phantom written as a NIfTI scan (HU in float32, mm) and read
    back by a decoupled run gives the built-in phantom's results (the same density up to the
    float32 HU: relative 1e-7); a scan 5 m away is refused before anything runs, saying where
    the image and the mesh lie."""
    from shoulder_fem.scene import SceneError

    comm = MPI.COMM_WORLD
    scene = load_scene("shoulder-internal-rotation")
    geometry = MS.geometry_from_values(scene.values())
    image = ct.shoulder_phantom(geometry, calibration=ct.Calibration())
    scan = comm_tmp / "phantom.nii.gz"
    if comm.rank == 0:
        ct.write_nifti(image, scan)
    comm.Barrier()
    result = api.run(
        scene.with_overrides([f"ct_image={scan}"]),
        "decoupled",
        "coarse",
        comm_tmp / "ct",
        comm=comm,
    )
    ref = study["results"]["decoupled"]
    for name in ("scapula_max_von_mises", "subscapularis_force", "max_pressure"):
        _, a = _series(result, name)
        _, b = _series(ref, name)
        assert np.allclose(a, b, rtol=1e-5, atol=1e-9 * np.abs(b).max()), name
    far = ct.CTImage(image.hu[:20, :20, :20], image.affine.copy())
    far.affine[:3, 3] += 5.0
    if comm.rank == 0:
        ct.write_nifti(far, comm_tmp / "far.nii.gz")
    comm.Barrier()
    with pytest.raises(SceneError, match="lie outside the image .image from .* mesh from"):
        api.run(
            scene.with_overrides([f"ct_image={comm_tmp / 'far.nii.gz'}"]),
            "decoupled",
            "coarse",
            comm_tmp / "far",
            comm=comm,
        )
    assert not (comm_tmp / "far").exists()


def test_scapula_suspension_stiffness_is_symmetric_positive_definite():
    """The 6 x 6 stiffness of the scapula's 21 springs about the glenoid (hand-assembled from
    the layout: sum k B^T n n^T B, B = [I, -hat(r)]) holds every rigid motion."""
    comm = MPI.COMM_WORLD
    scene = load_scene("shoulder-internal-rotation")
    values = scene.values()
    geometry = MS.geometry_from_values(values)
    sm = MS.build_shoulder_mesh(comm, geometry, scene.level("coarse"), "scapula")
    ref = SG.patch_centroid(sm.mesh, sm.facet_tags, MS.MARKERS["glenoid_cartilage_bone"].id)
    K = np.zeros((6, 6))
    springs = [
        sp
        for sp in SI.spring_layout(SH.ShoulderParameters.from_values(values))
        if sp["bone"] == "scapula"
    ]
    assert len(springs) == 21
    for sp in springs:
        c = SG.patch_centroid(sm.mesh, sm.facet_tags, MS.MARKERS[sp["name"]].id)
        B = np.hstack([np.eye(3), -hat(c - ref)])
        n = sp["direction"]
        K += sp["stiffness"] * B.T @ np.outer(n, n) @ B
    assert np.allclose(K, K.T)
    eig = np.linalg.eigvalsh(K)
    assert eig.min() > 0, eig


def test_horizontal_distal_elements_act_at_the_distal_section_centroid():
    """``humerus_horizontal_stiffness``: the scene's 0 gives the paper's 25 elements; 5 N/mm
    (the earlier model) adds a lateral and an anterior element, horizontal, acting at the
    distal section's centroid; every humerus element's coupled plate is the whole distal
    section."""
    scene = load_scene("shoulder-internal-rotation")
    assert scene.values()["humerus_horizontal_stiffness"] == 0.0  # the paper's supports
    base = SI.spring_layout(SH.ShoulderParameters.from_values(scene.values()))
    assert len(base) == 25 and all(sp["patch"] == sp["name"] for sp in base)
    held = scene.with_overrides(["humerus_horizontal_stiffness=5N/mm"])
    more = SI.spring_layout(SH.ShoulderParameters.from_values(held.values()))
    assert [sp["name"] for sp in more[:25]] == [sp["name"] for sp in base]
    extra = more[25:]
    assert len(more) == 27 and len({sp["name"] for sp in more}) == 27
    assert [sp["patch"] for sp in extra] == [SI.DISTAL_SECTION] * 2
    for sp in more:
        assert sp["plate"] == (SI.DISTAL_SECTION if sp["bone"] == "humerus" else sp["patch"])
    for sp in extra:
        assert sp["bone"] == "humerus" and sp["stiffness"] == pytest.approx(5000.0)
        assert sp["direction"][2] == 0.0 and np.linalg.norm(sp["direction"]) == pytest.approx(1)
    assert abs(np.dot(extra[0]["direction"], extra[1]["direction"])) < 1e-12


def test_the_distal_section_centroid_is_on_the_shaft_axis():
    """Where the horizontal elements act: on the shaft axis of the geometry (its direction at
    the neck-shaft angle, through the point ``head_offset`` lateral of the head centre), so a
    twist about the shaft does not stretch them; on both meshes that carry them."""
    scene = load_scene("shoulder-internal-rotation")
    geometry = MS.geometry_from_values(scene.values())
    lay = MS.layout(geometry)
    direction, point_mm = (lay.rot @ v for v in MS.shaft_axis(geometry))
    level = scene.level("coarse")
    for variant in ("deformable", "rigid-bone"):
        sm = MS.build_shoulder_mesh(MPI.COMM_WORLD, geometry, level, variant)
        mesh, tags = (
            (sm.mesh, sm.facet_tags)
            if variant == "deformable"
            else (sm.bone_surface, sm.bone_surface_tags)
        )
        c = 1e3 * SG.surface_centroid(mesh, tags, SI.DISTAL_SECTION) - point_mm
        off_axis = np.linalg.norm(c - np.dot(c, direction) * direction)
        # mm: on the axis by the patches' symmetry (measured 0.0005 mm, round-off of gmsh's
        # facets; the section is 22 mm across)
        assert off_axis < 0.005, (variant, off_axis)
        # the geometry's shaft_length (120 mm): the section is cut that far along the axis
        # from the head centre's level (measured 120.000 mm)
        assert np.dot(c, direction) == pytest.approx(120.0, abs=0.01)


@pytest.mark.mpi
def test_modulus_factors_scale_each_bone_alone():
    """``scapula_modulus_factor`` and ``humerus_modulus_factor`` multiply E on their own bone's
    cells and nowhere else: the integral of E over each bone scales by exactly its factor, on
    any partition (the factor is cell-wise)."""
    comm = MPI.COMM_WORLD
    scene = load_scene("shoulder-internal-rotation")
    values = scene.values()
    assert values["scapula_modulus_factor"] == values["humerus_modulus_factor"] == 1.0
    geometry = MS.geometry_from_values(values)
    sm = MS.build_shoulder_mesh(comm, geometry, scene.level("coarse"), "deformable")
    image = ct.shoulder_phantom(geometry)
    dx = ufl.Measure("dx", domain=sm.mesh, subdomain_data=sm.cell_tags)
    tags = (MS.SCAPULA.id, MS.HUMERUS.id, MS.MARKERS["glenoid_cartilage"].id)

    def integrals(scapula: float, humerus: float) -> np.ndarray:
        v = values | {"scapula_modulus_factor": scapula, "humerus_modulus_factor": humerus}
        _, E = SI.bone_fields(sm.mesh, sm.cell_tags, image, SH.ShoulderParameters.from_values(v))
        return np.array(
            [comm.allreduce(dolfinx.fem.assemble_scalar(dolfinx.fem.form(E * dx(t)))) for t in tags]
        )

    base, scaled = integrals(1.0, 1.0), integrals(10.0, 0.5)
    assert np.all(base > 0), base
    assert scaled / base == pytest.approx([10.0, 0.5, 1.0], rel=1e-12)


def test_stiffer_bones_bring_the_coupled_run_onto_part_1(comm_tmp):
    """Part 1's rigid bones are the coupled model's limit of an infinite modulus, so the
    decoupled-coupled difference of the subscapularis force is the bones' compliance: with E x
    10 in both bones it shrinks about 10 x (first order in 1/E). On the earlier model (the
    horizontal distal elements, no muscle contact: a difference large enough at 20 deg; on the
    whole model it is 0.06 % there), 0-20 deg, coupled with E and E x 10 against decoupled;
    measured at coarse: 0.59 % -> 0.07 % at 20 deg (ratio 0.12;
    benchmarks/results/shoulder_bone_compliance_coarse.json)."""
    earlier = ["final_angle=20deg", "humerus_horizontal_stiffness=5N/mm", "muscle_contact=none"]
    scene = load_scene("shoulder-internal-rotation").with_overrides(earlier)
    stiff_scene = scene.with_overrides(["scapula_modulus_factor=10", "humerus_modulus_factor=10"])
    comm = MPI.COMM_WORLD
    runs = {
        name: api.run(sc, method, "coarse", comm_tmp / name, comm=comm)
        for name, sc, method in (
            ("coupled", scene, "coupled"),
            ("stiff", stiff_scene, "coupled"),
            ("decoupled", scene, "decoupled"),
        )
    }
    assert all(r.data["status"] == "ok" for r in runs.values())
    f = {name: _series(r, "subscapularis_force")[1][-1] for name, r in runs.items()}
    err = abs(f["decoupled"] - f["coupled"]) / f["coupled"]
    err_stiff = abs(f["decoupled"] - f["stiff"]) / f["stiff"]
    assert err > 0.002, err  # a real difference with the paper's bones (measured 0.59 %)
    assert 0.03 < err_stiff / err < 0.25, (err, err_stiff)  # 1/E predicts 0.1


def test_horizontal_elements_hold_the_swing(study, comm_tmp):
    """The earlier model's two horizontal distal elements (``humerus_horizontal_stiffness`` =
    5 N/mm, not in the paper): both methods turn the humerus to 10 deg with its shaft swinging
    under 1 deg (measured 0.6 deg, the same with both within 0.1 deg), where on the paper's
    supports alone (the study fixture) it swings more than 10 deg (measured 13.9 deg). The
    supports' forces (Σ|tension| of the vertical and of the horizontal elements) are reported,
    zero for the horizontal ones when they are absent, and the two methods agree on them
    within 5 %."""
    scene = load_scene("shoulder-internal-rotation").with_overrides(
        ["final_angle=10deg", "humerus_horizontal_stiffness=5N/mm"]
    )
    swing, held = {}, {}
    for method in ("coupled", "decoupled"):
        result = api.run(scene, method, "coarse", comm_tmp / method)
        assert result.status == "ok", result.data.get("message")
        _, swing[method] = _series(result, "humeral_swing")
        _, held[method] = _series(result, "humerus_horizontal_support_force")
    assert swing["coupled"][-1] < 1.0, swing
    assert np.allclose(swing["coupled"], swing["decoupled"], atol=0.1), swing
    # measured 0.78 N at 10 deg, the decoupled run within 1.3 % of it
    assert held["coupled"][-1] > 0.1 and np.allclose(held["coupled"], held["decoupled"], rtol=0.05)
    x, free = _series(study["results"]["coupled"], "humeral_swing")
    assert x[1] == pytest.approx(10.0) and free[1] > 10.0, free
    for method, result in study["results"].items():
        assert np.all(_series(result, "humerus_horizontal_support_force")[1] == 0.0), method
    vertical = {
        m: _series(r, "humerus_distal_support_force")[1] for m, r in study["results"].items()
    }
    # the paper's vertical elements carry a little (measured 0.35 N at 10 deg, 3.4 N at 60)
    assert vertical["coupled"][-1] > 0.1, vertical
    assert np.allclose(vertical["coupled"], vertical["decoupled"], rtol=0.05), vertical


def test_a_stalled_rotation_ends_incomplete_and_keeps_the_angles_reached(comm_tmp):
    """Asked for 80 deg, part 1 stalls where the glenoid reaches the rim of the humeral
    cartilage (measured at coarse: 71.0 deg on the curved surfaces; 65.07 deg on the flat
    facets, the contact up to 69.8 deg from the cartilage's axis, which ends at 70.1 deg; with
    the incompressible muscles at 60.00 deg, the first step past it failing, the contact up to
    70.0 deg): with
    one cutback allowed the run ends ``incomplete`` after more than 2 x max_cutbacks failed
    tries towards the next output angle, with a message naming the step and the reason; the
    outputs before it are kept (part 2 runs on them) and the report states the angle
    reached."""
    scene = load_scene("shoulder-internal-rotation").with_overrides(
        ["final_angle=80deg", "max_cutbacks=1"]
    )
    out = comm_tmp / "stalled"
    result = api.run(scene, "decoupled", "coarse", out)
    assert result.status == "incomplete"
    reached = result.probes["final_angle_deg"]
    assert 60.0 - 1e-9 < reached < 80.0
    goal = 10.0 * (math.floor(reached / 10.0 + 1e-9) + 1)  # the output angle it stepped to
    message = result.data["message"]
    assert f"stopped at {reached:.2f} deg of 80 deg" in message, message
    assert f"towards {goal:.1f} deg did not converge" in message, message
    # where the contact had got to on the humeral cartilage, and the swing
    assert "pressed on the humeral cartilage up to" in message, message
    # humeral_cap_half_angle_deg at coarse: the scene's 70 deg, measured on the mesh's nodes
    assert "the cartilage ends at 70.1 deg" in message, message
    assert "the shaft had swung" in message, message
    assert result.probes["failed_steps"] >= 2  # the failed step and its cutback
    x, _ = _series(result, "max_pressure")
    assert np.allclose(x, np.arange(0.0, goal - 9.0, 10.0)), x
    x2, vm = _series(result, "scapula_max_von_mises")  # part 2 on the angles reached
    assert np.allclose(x2, x) and np.all(np.isfinite(vm)) and np.all(vm > 0)
    with np.load(out / "shoulder.npz") as npz:
        assert npz["final_angle_deg"] == pytest.approx(reached)
        assert np.allclose(npz["angles_deg"], x)
    if MPI.COMM_WORLD.rank == 0:
        report = shoulder_report.write_report(out, out, comm_tmp / "report", "coarse")
        assert report["final_angle_deg"]["decoupled"] == pytest.approx(reached)
        md = (comm_tmp / "report" / "report.md").read_text()
        assert "status `incomplete`, reached" in md, md[:2000]


@pytest.mark.mpi
@pytest.mark.parametrize(
    "method, muscle_contact",
    [("decoupled", "bones"), ("coupled", "bones"), ("decoupled", "humeral-head")],
)
def test_two_ranks_give_the_serial_results(method, muscle_contact, comm_tmp):
    """Under ``mpirun -n 2``: the run on both ranks and the same run on rank 0 alone (COMM_SELF)
    give the same series and probes (to the solver tolerances), with the muscle-bone contact
    (whose master's nodes may be owned by a rank holding none of its facets: that case failed
    before the master gather took every owned node). ``bones`` (the default) holds every
    contact pair of the scene, the glenohumeral one and both muscle-bone ones, for both
    methods; ``humeral-head`` the humerus's other master surface (the head alone)."""
    scene = load_scene("shoulder-internal-rotation").with_overrides(
        ["final_angle=2deg", "angle_step=2deg", "output_angle=2deg"]
        + [f"muscle_contact={muscle_contact}"]
    )
    names = [n for n in SERIES if n != "actuation"] + (
        ["transfer_equilibrium_residual"] if method == "decoupled" else []
    )
    if muscle_contact != "none":
        names.append("muscle_bone_contact_force")
    if muscle_contact == "bones":
        names += [f"{m}_scapula_contact_force" for m in MS.MUSCLES]
    _same_on_two_ranks(scene, method, names, comm_tmp)


@pytest.mark.mpi
def test_two_ranks_give_the_serial_compliant_decoupling(comm_tmp):
    """Under ``mpirun -n 2``: ``part1_bones = compliant`` (part 2's displacement gathered at
    part 1's scapula nodes, which the two ranks split differently in the two meshes) gives the
    serial run's corrected and uncorrected series.

    The soft tissues' volume is kept to 1e-6 here, not the default 1e-4: the augmented
    Lagrangian stops at the first multiplier update below the tolerance, and round-off (the
    two partitions, or one run after another in the same process) can move that update by one.
    At the default that moved the subscapularis force at 6 deg by 2.2e-5 (21 against 22
    updates, measured), more than the 1e-5 compared; at 1e-6 three runs agreed within 3e-8.

    The scapula's offset at 0 deg (6.0e-9 m, 1/1700 of its largest) is the response to the
    unloaded joint's residual loads, which the solves leave at their absolute tolerance (1e-6
    N at the outputs), not relative: two runs gave 6.01191e-9 and 6.01213e-9 m (3.8e-5 of it,
    2.2e-8 of the series' largest; CI, stop 51). The offsets are compared to 1e-7 of their
    largest in absolute terms (1e-6 N is a few 1e-7 of the few N the scapula carries at 6 deg),
    the rest as everywhere."""
    scene = load_scene("shoulder-internal-rotation").with_overrides(
        [
            "final_angle=6deg",
            "angle_step=3deg",
            "output_angle=3deg",
            "part1_bones=compliant",
            "soft_tissue_volume_tolerance=1e-6",
        ]
    )
    names = ["subscapularis_force", "max_pressure", "scapula_max_von_mises"]
    names += [f"uncorrected_{n}" for n in names]
    names += ["part1_correction_offset", "part1_correction_offset_humerus"]
    floor = {name: 1e-7 for name in names if name.startswith("part1_correction_offset")}
    par = _same_on_two_ranks(scene, "decoupled", names, comm_tmp, floor=floor)
    assert par.probes["transfer_equilibrium_residual"] < 1e-8


@pytest.mark.mpi
@pytest.mark.parametrize("method", ["decoupled", "coupled"])
def test_two_ranks_with_the_jacobian_rebuilt_before_every_solve(method, comm_tmp, monkeypatch):
    """Under ``mpirun -n 2``, J rebuilt without its stale contact entries before every solve
    (``STALE_FRACTION`` < 0; collective: the ranks decide on global counts) gives the serial
    results, 0-4 deg in two steps."""
    from shoulder_fem.engine.rigid_system import problem as RP

    monkeypatch.setattr(RP, "STALE_FRACTION", -1.0)
    scene = load_scene("shoulder-internal-rotation").with_overrides(
        ["final_angle=4deg", "angle_step=2deg", "max_angle_step=2deg", "output_angle=2deg"]
    )
    names = ["humeral_angle", "max_pressure", "contact_force", "subscapularis_force"]
    par = _same_on_two_ranks(scene, method, names, comm_tmp)
    assert par.probes["jacobian_pattern_rebuilds"] >= 2


@pytest.mark.mpi
@pytest.mark.slow
def test_two_ranks_coupled_past_a_widened_jacobian_pattern(comm_tmp):
    """Coupled, 0-10 deg on 2 ranks: at the fifth step the Jacobian's pattern grows (new
    contact entries merged beside the angle-control row, 963 423 -> 964 395 nonzeros) and
    MUMPS, reusing the old analysis, aborted (free(): invalid pointer) until the Jacobian
    callback reset the factorization on growth. Now the same series as serial."""
    scene = load_scene("shoulder-internal-rotation").with_overrides(["final_angle=10deg"])
    names = ["humeral_angle", "max_pressure", "contact_force", "subscapularis_force"]
    _same_on_two_ranks(scene, "coupled", names, comm_tmp)


def _same_on_two_ranks(scene, method: str, names: list[str], comm_tmp, floor=None):
    """The run on both ranks and on rank 0 alone (COMM_SELF) give the same series ``names``
    (to the solver tolerances) and the same final angle; the parallel result.

    ``floor`` maps a name to the absolute tolerance of its series as a fraction of its largest
    value (1e-9 unless given): for a series whose small values are set by a solver's absolute
    tolerance."""
    world = MPI.COMM_WORLD
    if world.size == 1:
        pytest.skip("compares a parallel run with a serial one: run under mpirun -n 2")
    par = api.run(scene, method, "coarse", comm_tmp / "parallel", comm=world)
    ser = None
    if world.rank == 0:
        ser = api.run(scene, method, "coarse", comm_tmp / "serial", comm=MPI.COMM_SELF).data
    ser = world.bcast(ser, root=0)
    assert par.status == ser["status"] == "ok"
    assert par.data["ranks"] == 2 and ser["ranks"] == 1
    for name in names:
        a = np.asarray(par.data["series"][name]["y"])
        b = np.asarray(ser["series"][name]["y"])
        if name == "transfer_equilibrium_residual":
            assert np.all(a < 1e-8) and np.all(b < 1e-8)
            continue
        # an incompressible body's volume change is round-off about 0 (measured 1e-15 at 0
        # deg, 1e-7 at 2 deg, the two runs 5e-15 apart): compared in absolute terms
        share = (floor or {}).get(name, 1e-9)
        atol = 1e-12 if name.endswith("_volume_change") else share * np.abs(b).max()
        assert np.allclose(a, b, rtol=1e-5, atol=atol), (name, a, b)
    reached = ser["probes"]["final_angle_deg"]
    assert par.probes["final_angle_deg"] == pytest.approx(reached, abs=1e-6)
    return par


def test_muscle_contact_keeps_the_infraspinatus_out_of_the_humeral_head(tmp_path_factory):
    """``muscle_contact = humeral-head``, decoupled part 1 to 40 deg: the infraspinatus wraps
    the head instead of passing through it. Independent check on the output field: its nodes
    stay outside the head's bone sphere (radius 22.5 mm about the articular centre) less the
    sag of the faceted head surface (1.35 mm at coarse) and the penalty overlap (< 2 mm here):
    19.2 mm. Measured without the contact (README): its nodes reach 17.1 mm from the centre at
    40 deg."""
    import dolfinx
    import h5py

    from shoulder_fem.meshes import shoulder as S

    comm = MPI.COMM_WORLD
    out = Path(comm.bcast(str(tmp_path_factory.mktemp("wrap")), root=0)) / "decoupled"
    scene = load_scene("shoulder-internal-rotation").with_overrides(
        ["final_angle=40deg", "muscle_contact=humeral-head"]
    )
    result = api.run(scene, "decoupled", "coarse", out, comm=comm)
    assert result.status == "ok"
    x, pen = _series(result, "muscle_bone_penetration")
    x, force = _series(result, "muscle_bone_contact_force")
    assert np.all(pen < 2e-3) and force[-1] > force[1] > 0  # the cuff presses on the head
    model = SH.build(scene, "coarse", MPI.COMM_SELF, "decoupled")
    sm = model.meshes["rigid-bone"]
    ft = SH.head_tags(model, sm.mesh, sm.facet_tags)
    r_bone = model.geometry.subchondral_radius
    head = ft.find(S.HUMERUS_HEAD_SURFACE.id)
    mid = dolfinx.mesh.compute_midpoints(sm.mesh, 2, head)
    sag = float((r_bone - np.linalg.norm(mid, axis=1)).max())  # faceting of the head
    X = sm.mesh.geometry.x
    cells = sm.mesh.geometry.dofmap.array.reshape(-1, 4)
    infra = np.unique(cells[sm.cell_tags.find(S.INFRASPINATUS.id)].ravel())
    bond = np.unique(cells[sm.cell_tags.find(S.HUMERAL_CARTILAGE.id)].ravel())
    with h5py.File(out / "fields" / "part1.h5", "r") as h5:
        group = h5["Function/displacement"]
        U = group[max(group, key=float)][:]
    # the humerus's rigid motion: best fit of the humeral cartilage's nodes (carried by it up
    # to the cartilage's strain, microns against millimetres)
    A, B = X[bond], X[bond] + U[bond]
    R = SG.best_fit_rotation(A, B, MPI.COMM_SELF)
    centre = B.mean(0) - R @ A.mean(0)  # the articular centre (the origin) moved
    nearest = np.linalg.norm(X[infra] + U[infra] - centre, axis=1).min()
    assert nearest > r_bone - sag - 2e-3, (nearest, r_bone, sag)


def _scapula_overlap(h5path: Path) -> dict[str, float]:
    """The deepest vertex of each muscle's free surface inside the scapula (m; 0 if none) at
    the last output of a coupled run's ``fields/coupled.h5``, read independently of the run:
    the mesh, the cells' bodies and the displacement at the vertices from the file. The free
    surface: the muscle's faces on the mesh's boundary, less its bonded or driven origin
    footprint (its vertices at the scapula's); the depth: the distance to the deformed
    scapula's boundary of a vertex inside one of its tetrahedra."""
    import h5py
    from scipy.spatial import cKDTree

    from shoulder_fem.engine.contact import closest_points_on_triangles

    with h5py.File(h5path, "r") as h5:
        X = h5["Mesh/mesh/geometry"][:]
        cells = h5["Mesh/mesh/topology"][:].astype(np.int64)
        last = max(h5["Function/displacement"], key=lambda k: float(k.replace("_", ".")))
        U = h5["Function/displacement"][last][:]
        body = np.rint(h5["Function/body"][last][:, 0]).astype(int)
    x = X + U
    local = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])

    def faces(which):
        f = np.sort(cells[which][:, local].reshape(-1, 3), axis=1)
        key, count = np.unique(f, axis=0, return_counts=True)
        return key, count

    scap = body == MS.SCAPULA.id
    skey, scount = faces(scap)
    shell = skey[scount == 1]  # the scapula's boundary (interfaces included)
    tets = x[cells[scap]]
    centre = tets.mean(axis=1)
    reach = float(np.linalg.norm(tets - centre[:, None], axis=2).max())
    T = (tets[:, 1:] - tets[:, :1]).transpose(0, 2, 1)  # columns: the edges from vertex 0
    akey, acount = faces(np.ones(len(cells), dtype=bool))
    outer = {tuple(f) for f in akey[acount == 1]}
    bone_nodes = cKDTree(X[np.unique(cells[scap])])
    out = {}
    for m in MS.MUSCLES:
        mkey, _ = faces(body == MS.MARKERS[m].id)
        free = np.unique(np.array([f for f in mkey if tuple(f) in outer]))
        d, _ = bone_nodes.query(X[free])
        nodes = free[d > 1e-9]  # not on the origin footprint
        depth = 0.0
        for k, near in zip(nodes, cKDTree(centre).query_ball_point(x[nodes], reach), strict=True):
            if not near:
                continue
            lam = np.linalg.solve(T[near], (x[k] - tets[near, 0])[:, :, None])[:, :, 0]
            inside = np.all(lam >= -1e-12, axis=1) & (lam.sum(axis=1) <= 1 + 1e-12)
            if inside.any():
                p = np.broadcast_to(x[k], (len(shell), 3))
                tri = x[shell]
                _, _, d2, _ = closest_points_on_triangles(p, tri[:, 0], tri[:, 1], tri[:, 2])
                depth = max(depth, float(np.sqrt(d2.min())))
        out[m] = depth
    return out


def test_the_cuff_slides_on_the_scapula(study):
    """The default scene (``muscle_contact = bones``): the muscles' deep faces slide on the
    scapula as well as on the humeral head. Measured at coarse: the infraspinatus reaches the
    glenoid neck at 40 deg and the supraspinatus the lateral blade at 60 deg (coupled 5.3 and
    0.8 N at 60 deg); without the scapula's pair (``humeral-head``) the infraspinatus's
    free-surface vertices were 5.2 mm and the supraspinatus's 1.2 mm inside the scapula at 60
    deg (this test's check of the output field), with it none is inside, and the pair's own
    points overlap by what its penalty law allows (1.1 mm at 60 deg, 0.53 MPa at 0.5 MPa/mm).
    Per muscle, the recorded forces add up to the pair's (as vectors: their magnitudes bound
    it; equal where one muscle alone presses). The scapula's pair looks at the muscles' faces
    over the head too: the subscapularis's deep face over the head lies over the glenoid's
    anterior neck, and while only the head's pair looked at it one of its vertices was 0.86 mm
    inside the scapula at 60 deg (coarse, incompressible cartilage); with it that muscle
    presses on the scapula with 1.3 N at 60 deg and overlaps it by the pair's penalty law
    (0.54 mm, the pair's deepest point 0.57 mm; measured at coarse)."""
    scene = load_scene("shoulder-internal-rotation")
    assert scene.values()["muscle_contact"] == "bones"
    eps = scene.values()["muscle_contact_penalty"]
    for method, result in study["results"].items():
        x, pair = _series(result, "muscle_scapula_contact_force")
        _, pen = _series(result, "muscle_scapula_penetration")
        muscles = np.array([_series(result, f"{m}_scapula_contact_force")[1] for m in MS.MUSCLES])
        assert pair[-1] > 1.0 and muscles[2, -1] > 1.0, (method, pair, muscles)  # infraspinatus
        tol = 1e-9 * max(pair.max(), 1.0)
        assert np.all(pair <= muscles.sum(axis=0) + tol), (method, pair, muscles)
        assert np.all(pair >= 2 * muscles.max(axis=0) - muscles.sum(axis=0) - tol)
        # the penalty's overlap: 1 MPa at 2 mm, far below the search depth (4 mm)
        assert np.all(pen < 1.5e-3) and pen[-1] * eps < 1e6, (method, pen)
        _, head = _series(result, "muscle_humerus_contact_force")
        _, total = _series(result, "muscle_bone_contact_force")
        assert np.all(total <= pair + head + tol) and np.all(head > 0), (method, head)
    _, pen = _series(study["results"]["coupled"], "muscle_scapula_penetration")
    inside = _scapula_overlap(study["base"] / "coupled" / "fields" / "coupled.h5")
    assert max(inside.values()) <= pen.max() + 5e-5, (inside, pen)
    _, sub = _series(study["results"]["coupled"], "subscapularis_scapula_contact_force")
    # the subscapularis on the glenoid's neck at 60 deg (0 while no pair looked at its faces
    # over the head; measured at coarse 1.30 N with nu = 0.49 muscles, 3.4e-3 N with the
    # incompressible ones, 3.75 N at medium)
    assert sub[-1] > 0, sub


def _part1_system(options: dict):
    """Decoupled part 1 at coarse as a bare RigidSystem (serial): (system, contact, actuator)."""
    from shoulder_fem.engine.rigid_system import RigidBody, RigidSystem
    from shoulder_fem.families.shoulder import decoupled as SD

    scene = load_scene("shoulder-internal-rotation").with_overrides(FLAT)
    model = SH.build(scene, "coarse", MPI.COMM_SELF, "decoupled")
    p = model.params
    sm = model.meshes["rigid-bone"]
    mesh, cells = sm.mesh, sm.cell_tags
    ft = SH.head_tags(model, mesh, sm.facet_tags)
    V = dolfinx.fem.VectorFunctionSpace(mesh, ("Lagrange", 2))
    u = dolfinx.fem.Function(V)
    dx = ufl.Measure("dx", domain=mesh, subdomain_data=cells, metadata=p.quadrature())
    residual, volumetric = SI.soft_tissue_residual(u, ufl.TestFunction(V), dx, cells, p)
    contact = SI.joint_contact(V, u, ft, p)
    glenoid = SG.patch_centroid(mesh, ft, MS.MARKERS["glenoid_cartilage_bone"].id)
    origin = SG.patch_centroid(mesh, ft, MS.MARKERS["subscapularis_origin"].id)
    actuator = RigidBody("actuator", origin, prescribed=True)
    bodies = [RigidBody("humerus", np.zeros(3)), RigidBody("scapula", glenoid), actuator]
    layout = SI.spring_layout(p)
    springs = SD.part1_springs(sm.bone_surface, sm.bone_surface_tags, layout, p.spring_length)
    ties, tied = SD.part1_ties(ft, cells, p)
    system = RigidSystem(
        bodies,
        springs,
        u=u,
        residual=residual,
        volumetric=volumetric,
        surfaces=tied,
        ties=ties,
        name="order_test",
        options=options,
        form_compiler_params=p.quadrature(),
        contact=contact,
    )
    return system, contact, actuator


def test_part1_newton_converges_quadratically_to_the_end():
    """Issue 19, item 3: the last Newton iterations of a part-1 step converge at order >= 1.8.

    Decoupled part 1 at coarse, the actuator moved 2 mm then 4 mm from the unloaded state,
    each step solved to |F| <= 1e-9 N. With the segments' consistent tangent
    (:mod:`shoulder_fem.engine.contact.segment_tangent`) the measured histories end
    ... 1.17, 2.5e-4, 1.4e-6, 5.3e-11 N (order 1.97; 8 iterations) and ... 1.79, 3.4e-3,
    3.4e-5, 3.1e-11 N (order 3.0; 8 iterations); with the point-wise tangent they fell by a
    constant 0.44 and 0.56 per iteration (order 1.0) from 1e-1 N down: 27 and 37 iterations
    for the same tolerance. The converged states are the same (u within 1e-12 m). (Those were
    measured with the earlier model; with the whole model the 2 mm step ends ... 0.081,
    5.1e-3, 6.1e-7, 8.0e-11 N.)"""
    from shoulder_fem.families.shoulder.seating import seat
    from shoulder_fem.families.shoulder.stepping import ACTUATION_DIRECTION, SNES_OPTIONS

    options = SNES_OPTIONS | {"snes_atol": 1e-9, "snes_rtol": 1e-14, "snes_stol": 0.0}
    system, contact, actuator = _part1_system(options)
    seat(system, contact, "0 mm")  # as the stepping does: by continuation in the penalty
    contact.commit()
    for d in (2e-3, 4e-3):
        actuator.prescribe(d * SG.unit(ACTUATION_DIRECTION), np.eye(3))
        system.solve(f"{d * 1e3:.0f} mm")
        contact.commit()
        r = np.asarray(system.stats.residual_histories[-1])
        # the order over each three successive iterates below 0.1 N: with the whole model the
        # last falls to the round-off floor (measured ... 0.081, 5.1e-3, 6.1e-7, 8.0e-11 N:
        # orders 3.2 then 0.99), so the best of them is the tail's
        tail = r[r < 0.1]
        orders = [
            math.log(c / b) / math.log(b / a)
            for a, b, c in zip(tail, tail[1:], tail[2:], strict=False)
        ]
        assert orders and max(orders) >= 1.8, (d, r)
        # from 0.1 N to 1e-7 N in at most 4 iterations (linear at 0.56 per iteration: ~23);
        # below that the 60 MPa/mm penalty's round-off floor (measured at 4 mm: 0.052, 0.012,
        # 1.9e-4, 7.0e-7, then 5.6e-9, 7.3e-11 N)
        assert np.count_nonzero((r < 0.1) & (r >= 1e-7)) <= 4, (d, r)
    system.destroy()


def test_a_jacobian_rebuilt_without_stale_contact_entries_gives_the_same_solves(monkeypatch):
    """Part 1 at coarse, the actuator moved 2, 4, 6 mm: J's pattern gathers the contact entries
    of every state it met. Rebuilt before every solve (``STALE_FRACTION`` < 0), J holds only
    the FE product's and the current contact product's entries (measured at 6 mm: 237 492
    against 240 174 grown; FE product 227 862, contact product 13 356, the two overlap), and
    the solves take the same Newton iterations (8, 6, 7, 6) to the same states (u within
    1e-12 m) as with the ever-growing pattern."""
    from shoulder_fem.engine.rigid_system import problem as RP
    from shoulder_fem.families.shoulder.seating import seat
    from shoulder_fem.families.shoulder.stepping import ACTUATION_DIRECTION, SNES_OPTIONS

    runs = {}
    for name, fraction in (("grown", math.inf), ("rebuilt", -1.0)):
        monkeypatch.setattr(RP, "STALE_FRACTION", fraction)
        system, contact, actuator = _part1_system(dict(SNES_OPTIONS))
        seat(system, contact, "0 mm")
        contact.commit()
        nonzeros = []
        for d in (2e-3, 4e-3, 6e-3):
            actuator.prescribe(d * SG.unit(ACTUATION_DIRECTION), np.eye(3))
            system.solve(f"{d * 1e3:.0f} mm")
            contact.commit()
            pb = system._problem
            nz = {
                k: M.getInfo()["nz_used"]
                for k, M in (("J", pb.J), ("fe", pb.C), ("c", pb.contact.C))
            }
            nonzeros.append(nz)
        runs[name] = (system.stats.history[:], system.u.x.array.copy(), nonzeros, system.stats)
        system.destroy()
    grown, rebuilt = runs["grown"], runs["rebuilt"]
    assert grown[0] == rebuilt[0]  # Newton iterations of every solve
    assert np.max(np.abs(grown[1] - rebuilt[1])) < 1e-12
    assert grown[3].pattern_rebuilds == 0 and rebuilt[3].pattern_rebuilds >= 2
    last = rebuilt[2][-1]
    # the rigid rows and the springs' blocks are a few hundred entries beyond the two products
    assert last["J"] <= last["fe"] + last["c"] + 0.05 * last["fe"], last
    assert grown[2][-1]["J"] > last["J"], (grown[2][-1], last)


def test_nearly_incompressible_tissue_is_seated_by_continuation(tmp_path_factory, monkeypatch):
    """The unloaded solve with incompressible soft tissue (kappa/mu = 1000): a continuation in
    the bulk modulus (x 10 per solve from kappa/mu = 10). The factors by hand; at kappa/mu = 100,
    which also seats directly, the continuation's state is the direct solve's to the solver's
    tolerance (|F| <= 1e-3 N); at 1000 the direct solve with full Newton steps fails at 0 deg
    (measured: DIVERGED_MAX_IT) and the continuation seats the joint (decoupled, coarse, to 0.5
    deg); the direct solve retried with the l2 line search (the seating's retry) seats it too,
    in the same state."""
    from shoulder_fem.families.shoulder import newton, seating

    assert seating.bulk_factors(None) == [1.0] and seating.bulk_factors(10.0) == [1.0]
    assert np.allclose(seating.bulk_factors(1000.0), [0.01, 0.1, 1.0], rtol=1e-12)
    comm = MPI.COMM_WORLD
    base = Path(comm.bcast(str(tmp_path_factory.mktemp("seat_bulk")), root=0))

    def run(ratio: float, direct: bool, name: str):
        monkeypatch.setattr(seating, "SEATING_BULK_RATIO", 1e30 if direct else 10.0)
        scene = load_scene("shoulder-internal-rotation").with_overrides(
            [
                *FLAT,  # a seated joint (its compressible cartilage overridden next)
                "soft_tissue_formulation=incompressible",
                f"soft_tissue_bulk_ratio={ratio:g}",
                "soft_tissue_volume_tolerance=0",  # a plain penalty: the seating alone
                "final_angle=0.5deg",
            ]
        )
        return api.run(scene, "decoupled", "coarse", base / name, comm=comm)

    direct, stages = run(100.0, True, "direct"), run(100.0, False, "stages")
    for key in ("contact_force", "subscapularis_force", "infraspinatus_force"):
        a, b = _series(direct, key)[1], _series(stages, key)[1]
        assert np.abs(a - b).max() <= 1e-3, (key, a, b)
    whole = run(1000.0, False, "whole")
    assert whole.status == "ok"
    # full Newton steps alone (no line-search retry): the direct seating fails
    monkeypatch.setattr(newton, "FALLBACK_LINESEARCH", "basic")
    with pytest.raises(api.RunFailed, match="0 deg"):
        run(1000.0, True, "whole_direct")
    # with the seating's l2 retry the direct solve seats too, in the continuation's state
    monkeypatch.setattr(newton, "FALLBACK_LINESEARCH", "l2")
    retried = run(1000.0, True, "whole_retried")
    for key in ("contact_force", "subscapularis_force", "infraspinatus_force"):
        a, b = _series(retried, key)[1], _series(whole, key)[1]
        assert np.abs(a - b).max() <= 1e-3, (key, a, b)


def test_a_stiff_contact_penalty_is_seated_by_continuation(tmp_path_factory, monkeypatch):
    """The unloaded solve with a penalty above 5 MPa/mm: a continuation in the penalty (x 3 per
    solve). The factors by hand; on the earlier model (the horizontal distal elements, no
    muscle contact), whose joint 15 MPa/mm also seats directly, the continuation's state is the
    direct solve's, to the solver's tolerance (|F| <= 1e-3 N: the joint force within 1e-3 N,
    measured 6.5e-4 of 1.61 N); on the whole model (the scene) the direct solve fails at 0 deg
    at 15 MPa/mm with full Newton steps (measured: DIVERGED_MAX_IT) and the continuation seats
    the joint (decoupled, coarse, to 1 deg). (Before the segments' centroid fan, the earlier
    model's direct solve failed at 50 MPa/mm; it converges now.)"""
    from shoulder_fem.families.shoulder import newton, seating

    assert seating.seating_factors(5e9) == [1.0] and seating.seating_factors(1e9) == [1.0]
    assert np.allclose(seating.seating_factors(5e10), [0.1, 0.3, 0.9, 1.0], rtol=1e-12)
    comm = MPI.COMM_WORLD
    base = Path(comm.bcast(str(tmp_path_factory.mktemp("seat")), root=0))
    earlier = ["humerus_horizontal_stiffness=5N/mm", "muscle_contact=none"]

    def run(model: list[str], direct: bool, name: str):
        monkeypatch.setattr(seating, "SEATING_PENALTY", 1e30 if direct else 5e9)
        scene = load_scene("shoulder-internal-rotation").with_overrides(
            [*FLAT, "contact_penalty=15MPa/mm", "final_angle=1deg", *model]
        )
        return api.run(scene, "decoupled", "coarse", base / name, comm=comm)

    direct, stages = run(earlier, True, "direct"), run(earlier, False, "stages")
    for key in ("contact_force", "subscapularis_force", "infraspinatus_force"):
        a, b = _series(direct, key)[1], _series(stages, key)[1]
        assert np.abs(a - b).max() <= 1e-3, (key, a, b)
    assert run([], False, "whole").status == "ok"
    monkeypatch.setattr(newton, "FALLBACK_LINESEARCH", "basic")  # full Newton steps alone
    with pytest.raises(api.RunFailed, match="0 deg"):
        run([], True, "whole_direct")
    # the failed run's solver is destroyed all the same: the MUMPS options it kept for its
    # factorizations left PETSc's database with it (they stayed there before, under its prefix)
    from petsc4py import PETSc

    assert not [k for k in PETSc.Options().getAll() if k.startswith("shoulder_part1")]
