"""The head-shape study's two kinds of head (issue 21, item 3; ``benchmarks/head_shape.py``).

The anatomical head (24 mm) and a 22 mm implant whose cartilage ends on the anatomical neck
plane, each with the decoupled method at coarse to 20 deg: both finish, their pressures,
muscle forces and scapular stresses are finite and positive and differ (the shape reaches the
solve), and each run's transferred loads balance the scapula's springs at the recorded pose
(the invariant that holds whatever the mesh and the head: part 2's equilibrium of the loads
part 1 found), to issue 21's 1e-8: part 1's Newton goes on to |F| < 1e-6 N at the output
angles (``stepping.OUTPUT_ATOL``; the steps stop at 1e-3 N, which gave up to 3.1e-7 at 20 deg
on 2 ranks before). Measured: 1e-14 to 7.1e-9 over 0-60 deg at coarse. Serial and on 2 ranks.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI

from shoulder_fem import api
from shoulder_fem.scene import load_scene

pytestmark = pytest.mark.mpi  # serial and under mpirun -n 2 (78 s there)

SHORT = ["final_angle=20deg", "output_angle=10deg"]


def _implant(radius_mm: float) -> list[str]:
    """A prosthetic head of ``radius_mm`` and nothing else: its cartilage ends on the
    anatomical neck plane by default (``families.shoulder.model.resolve``)."""
    return ["head_shape=prosthetic", f"prosthesis_radius={radius_mm}mm"]


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, Path]:
    base = Path(MPI.COMM_WORLD.bcast(str(tmp_path_factory.mktemp("head_shape")), root=0))
    out = {}
    for name, sets in (("anatomical", []), ("implant R22", _implant(22.0))):
        scene = load_scene("shoulder-internal-rotation").with_overrides([*SHORT, *sets])
        out[name] = base / name.replace(" ", "_")
        api.run(scene, "decoupled", "coarse", out[name])
    return out


def _summary(folder: Path) -> dict:
    return json.loads((folder / "summary.json").read_text())


def test_two_head_shapes_give_different_finite_positive_results(runs):
    summaries = {name: _summary(f) for name, f in runs.items()}
    for name, s in summaries.items():
        assert s["status"] == "ok", (name, s["message"])
        assert s["series"]["max_pressure"]["x"] == pytest.approx([0.0, 10.0, 20.0])
    # the implant's cap is the neck plane's (68.09 deg by hand, test_shoulder_mesh), the
    # anatomical one 70 deg: measured on each run's mesh
    # nothing but the radius set: the cap derived from the neck plane, recorded as run
    # (cos(a) = 8.209 mm / 22 mm by hand, test_shoulder_mesh: a = 68.09 deg)
    used = math.degrees(summaries["implant R22"]["parameters"]["humeral_cartilage_angle"])
    assert used == pytest.approx(68.09, abs=0.01)
    caps = [s["probes"]["humeral_cap_half_angle_deg"] for s in summaries.values()]
    assert caps[0] == pytest.approx(70.0, abs=0.5) and caps[1] == pytest.approx(68.1, abs=0.5)
    keys = ("max_pressure", "subscapularis_force", "infraspinatus_force", "scapula_max_von_mises")
    values = {
        name: {k: np.asarray(s["series"][k]["y"][1:], dtype=float) for k in keys}
        for name, s in summaries.items()
    }
    for name, v in values.items():
        for k in keys:
            assert np.all(np.isfinite(v[k])) and np.all(v[k] > 0), (name, k, v[k])
    # a 4.3 mm radial mismatch against 2.3 mm moves the contact and its pressure: the peak
    # pressures at 20 deg differ by far more than the solver's tolerance (measured 52.7 and
    # 104.1 kPa over 0-60 deg runs at coarse)
    a, b = values["anatomical"]["max_pressure"][-1], values["implant R22"]["max_pressure"][-1]
    assert abs(a - b) > 0.05 * max(a, b), (a, b)


def test_transferred_loads_balance_the_springs_for_each_shape(runs):
    for name, folder in runs.items():
        s = _summary(folder)
        residual = np.asarray(s["series"]["transfer_equilibrium_residual"]["y"], dtype=float)
        assert len(residual) == 3 and np.all(residual <= 1e-8), (name, residual)
        assert s["probes"]["transfer_equilibrium_residual"] == pytest.approx(residual.max())
