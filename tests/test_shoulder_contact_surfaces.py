"""The shoulder's curved articular surfaces (``contact_surfaces = curved``) and the contact's onset.

Part 1 at ``coarse``: with the articular surfaces' mid-edge nodes lifted onto the smooth
surfaces, the unloaded joint is not in contact (the flat facets' corners overlapped), and the
first step's Newton direction, which knows nothing of the contact's stiffness, drove the head
into the glenoid: the step was cut back twice (measured, before the onset limit of
``families/shoulder/trial.py``). With the limit no step fails. Serial and ``mpirun -n 2``.
"""

from __future__ import annotations

import pytest

from shoulder_fem import api
from shoulder_fem.scene import load_scene

pytestmark = pytest.mark.mpi


def test_curved_surfaces_leave_the_unloaded_joint_open_and_no_step_fails(comm_tmp):
    scene = load_scene("shoulder-internal-rotation").with_overrides(
        ["contact_surfaces=curved", "final_angle=3deg", "output_angle=3deg"]
    )
    result = api.run(scene, "decoupled", "coarse", comm_tmp / "curved")
    p = result.probes
    assert result.status == "ok" and p["failed_steps"] == 0, p
    area = result.series["contact_area"]["y"]
    assert area[0] == 0.0 and area[-1] > 0.0, area  # open at 0 deg, in contact at 3 deg
    # the penalty's share of the energy stays within its own compliance's order (1/eps
    # against the layers' ~0.16 mm/MPa: about 10 %; 26 % measured at coarse, 53 % flat)
    share = result.series["glenohumeral_penalty_energy_share"]["y"][-1]
    assert 0.0 < share < 0.5, share
