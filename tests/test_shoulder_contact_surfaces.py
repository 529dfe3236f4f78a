"""The shoulder's curved articular surfaces (the default) and the engagement of the open joint.

With the articular surfaces' mid-edge nodes lifted onto the smooth surfaces, the unloaded
joint is open (the flat facets' corners overlapped), and the angle-controlled Newton system is
nearly singular there: without :mod:`shoulder_fem.families.shoulder.engage` the coupled run to
3 deg at ``coarse`` fails 4 steps (measured with ``ENGAGE_FORCE`` = 0 on the incompressible
cartilage at 200 MPa/mm: 4 cut-backs, 115 Newton iterations; 3 and 90 on the compressible one at
100 MPa/mm). The joint is now engaged by the plate's travel first (measured: 7 solves to 1.57
deg, no step failed, 51 Newton iterations). Serial and ``mpirun -n 2``.
"""

from __future__ import annotations

import numpy as np
import pytest

from shoulder_fem import api
from shoulder_fem.families.shoulder import engage
from shoulder_fem.scene import load_scene

pytestmark = pytest.mark.mpi

TO_3_DEG = ["final_angle=3deg", "output_angle=3deg"]


def _scene(*overrides: str):
    return load_scene("shoulder-internal-rotation").with_overrides([*TO_3_DEG, *overrides])


def test_the_open_joint_is_engaged_by_travel_and_no_coupled_step_fails(comm_tmp):
    result = api.run(_scene(), "coupled", "coarse", comm_tmp / "coupled")
    p = result.probes
    assert result.status == "ok" and p["failed_steps"] == 0, p
    # the engagement ran (open at 0 deg) and handed over below the first output
    assert p["engaging_steps"] >= 1 and 0.0 < p["engaged_angle_deg"] < 3.0, p
    area, force = result.series["contact_area"]["y"], result.series["contact_force"]["y"]
    # open or barely touching at 0 deg (measured: open with nu = 0.49 muscles; 0.58 mm^2 under
    # 1.1e-4 N with the incompressible ones), in contact at 3 deg
    assert area[0] < 1e-6 and force[0] < 1e-3 * engage.ENGAGE_FORCE, (area, force)
    assert area[-1] > 0.0 and force[-1] > 1e3 * force[0], (area, force)
    # the penalty's share of the energy at 3 deg, just engaged, stays within its own
    # compliance's order: a sanity bound, not an independent number (measured at coarse with
    # the incompressible muscles 0.55, under 2 ranks, and 0.20-0.30 over 10-60 deg, where the
    # stabilised one-element cartilage layers are stiff; 0.06-0.16 with nu = 0.49 muscles)
    share = result.series["glenohumeral_penalty_energy_share"]["y"][-1]
    assert 0.0 < share < 0.75, share


def test_the_engagement_changes_the_path_not_the_state(comm_tmp, monkeypatch):
    """Part 1 to 3 deg with and without the engagement (``ENGAGE_FORCE`` = 0: the angle control
    from the open joint, as before): the same equilibrium, to the solver's tolerance (the
    outputs are polished to |F| < 1e-6 N). The incompressible cartilage's multipliers are
    converged to 1e-6 here: at the scene's 1e-4 each path stops its updates at its own state
    within that tolerance (measured: the joint forces 1.5e-4 apart; 1e-9 is out of the steps'
    Newton tolerance's reach)."""
    tight = "soft_tissue_volume_tolerance=1e-6"
    engaged = api.run(_scene(tight), "decoupled", "coarse", comm_tmp / "engaged")
    monkeypatch.setattr(engage, "ENGAGE_FORCE", 0.0)
    direct = api.run(_scene(tight), "decoupled", "coarse", comm_tmp / "direct")
    assert engaged.status == direct.status == "ok"
    assert direct.probes["engaging_steps"] == 0 and engaged.probes["engaging_steps"] >= 1
    for key in ("contact_force", "subscapularis_force", "infraspinatus_force", "max_pressure"):
        a = np.asarray(engaged.series[key]["y"])
        b = np.asarray(direct.series[key]["y"])
        # the peak pressure is one node's: 2.0-2.1e-6 (of its largest value) apart at 3 deg,
        # measured twice on 2026-11-29 (1e-6 before that day's contact and retry changes; which
        # of them moved it was not isolated); the resultants agree to 6e-7, bound 1e-6
        rtol = 1e-5 if key == "max_pressure" else 1e-6
        assert np.allclose(a, b, rtol=rtol, atol=rtol * np.abs(b).max()), (key, a, b)
