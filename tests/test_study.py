"""Parameter studies: one whole run per combination of values (``shoulder-fem study``).

On the spinning bar (seconds a run): each variant's root stress is the hand calculation's,
sigma_root = rho Omega^2 (r_out^2 - r_in^2)/2 = 91.8 Pa x Omega^2 (rho = 1800 kg/m^3, r_out =
0.32 m, r_in = 0.02 m; quasi-static, linear: test_cli's driver test); the study's rows are the
variants' own summaries. On the shoulder, a variant that stops short is recorded, the next one
runs, and the command exits 3 naming the variant; each summary records the soft tissues'
constants used. Bad input is refused before anything is solved or written.
"""

from __future__ import annotations

import json

import pytest
from mpi4py import MPI

from shoulder_fem.api import study
from shoulder_fem.scene import SceneError, load_scene

QUASI_STATIC = ["quasi_static=true", "end_time=0.1", "time_step=0.1"]


@pytest.mark.mpi
def test_a_study_of_the_spin_rate_gives_each_variant_the_hand_calculations_stress(comm_tmp):
    scene = load_scene("spinning-bar").with_overrides(QUASI_STATIC)
    out = comm_tmp / "study"
    data = study(scene, ["spin_rate=20,40rad/s"], out, "decoupled", "coarse", MPI.COMM_WORLD)
    assert data["finished"] and [r["values"] for r in data["variants"]] == [
        {"spin_rate": "20"},
        {"spin_rate": "40rad/s"},
    ]
    for row, rate in zip(data["variants"], (20.0, 40.0), strict=True):
        summary = json.loads((out / row["folder"] / "summary.json").read_text())
        assert summary["parameters"]["spin_rate"] == rate and row["status"] == "ok"
        # the hand calculation (module docstring), to the solver's tolerance
        assert summary["probes"]["root_axial_stress"] == pytest.approx(91.8 * rate**2, rel=1e-6)
        # the row is the variant's own measurement, not another number
        assert row["cpu_s"] == summary["resources"]["cpu_s"] > 0
        assert row["series"] == summary["series"]
    written = json.loads((out / "study.json").read_text())
    assert written["variants"][1]["values"] == {"spin_rate": "40rad/s"}
    assert (out / "study.png").stat().st_size > 5_000 and (out / "study.pdf").stat().st_size > 0


@pytest.mark.parametrize(
    ("settings", "message"),
    [
        (["spin_rate=10,20", "spin_rate=30"], "spin_rate is given twice"),
        (["no_such_key=1,2"], "unknown parameter 'no_such_key'"),
        (["spin_rate=10,-1"], "spin_rate = -1"),
        (["spin_rate="], "expected key=value"),
        ([], "no --set"),
    ],
)
def test_bad_input_is_refused_before_anything_is_solved_or_written(comm_tmp, settings, message):
    out = comm_tmp / "refused"
    with pytest.raises(SceneError, match=message):
        study("spinning-bar", settings, out, "decoupled", "coarse", MPI.COMM_WORLD)
    assert not out.exists()


def test_a_variant_that_stops_short_is_kept_and_the_study_exits_3(tmp_path, capfd):
    """The shoulder forced into one 8-deg step (test_cli's short run): with no cut-back the
    step does not converge and the variant stops short; with cut-backs allowed the next
    variant reaches 8 deg. The command ends with one line naming the short variant and exit
    status 3; both folders hold their summaries, with the Table I constants recorded."""
    from shoulder_fem.cli import EXIT_SOLVER, main

    out = tmp_path / "study"
    args = ["-q", "study", "shoulder-internal-rotation", "--level", "coarse"]
    for item in ("final_angle=8deg", "angle_step=8deg", "max_angle_step=8deg"):
        args += ["--set", item]
    args += ["--set", "output_angle=8deg", "--set", "max_cutbacks=0,4", "--out", str(out)]
    assert main(args) == EXIT_SOLVER
    captured = capfd.readouterr()
    lines = [ln for ln in captured.err.splitlines() if ln.startswith("shoulder-fem: error:")]
    assert len(lines) == 1, captured.err
    assert lines[0].startswith("shoulder-fem: error: study: 1 of 2 variant(s)"), lines[0]
    data = json.loads((out / "study.json").read_text())
    short, done = data["variants"]
    assert not data["finished"] and short["status"] == "incomplete" and done["status"] == "ok"
    assert short["folder"] in lines[0] and "stopped at" in lines[0]
    for row, cutbacks in ((short, 0), (done, 4)):
        summary = json.loads((out / row["folder"] / "summary.json").read_text())
        assert summary["parameters"]["max_cutbacks"] == cutbacks
        assert row["cpu_s"] == summary["resources"]["cpu_s"] > 0
        # the constants the run used (Table I: C10 = 1.79 MPa, alpha = 0.12 MPa, beta = 1)
        used = {k: summary["parameters"][k] for k in ("cartilage_c10", "muscle_alpha")}
        assert used == {"cartilage_c10": 1.79e6, "muscle_alpha": 0.12e6}
        assert summary["parameters"]["muscle_beta"] == 1.0
    assert done["series"]["humeral_angle"]["x"][-1] == pytest.approx(8.0)
    assert short["series"]["humeral_angle"]["x"][-1] < 8.0
