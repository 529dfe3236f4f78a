"""Sweeps over the scapula's material from one part 1 (``shoulder-fem sweep``, issue 21 item 1).

From a short decoupled run at coarse (0-10 deg): a variant with the run's own values
reproduces its part 2 (the nodal von Mises stress at every output angle) to 1e-10 of its
maximum; another value changes the stress but not the transferred loads, which balance the
springs' reaction to the same 1e-12 as the run's own; a key that part 1 depends on, an unknown
key and a value out of bounds are refused before anything is solved or written. Serial and
under ``mpirun -n 2`` (the source run then on 2 ranks too).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI
from scipy.spatial import cKDTree

from shoulder_fem import api
from shoulder_fem.api import sweep
from shoulder_fem.scene import SceneError, load_scene


@pytest.fixture(scope="module")
def source(tmp_path_factory) -> Path:
    base = Path(MPI.COMM_WORLD.bcast(str(tmp_path_factory.mktemp("sweep_source")), root=0))
    scene = load_scene("shoulder-internal-rotation").with_overrides(
        ["final_angle=10deg", "output_angle=5deg"]
    )
    api.run(scene, "decoupled", "coarse", base / "run")
    return base / "run"


def _von_mises(folder: Path, order_of: Path | None = None) -> np.ndarray:
    """The nodal von Mises series (angles x scapula vertices), in ``order_of``'s vertex order
    (two runs under mpirun may partition, and so order, the mesh differently)."""
    with np.load(folder / "shoulder.npz") as res:
        series, X = res["scapula_von_mises_series"], res["scapula_points"]
    if order_of is None:
        return series
    with np.load(order_of / "shoulder.npz") as res:
        dist, index = cKDTree(X).query(res["scapula_points"])
    assert dist.max() < 1e-12
    return series[:, index]


def _series(folder: Path, name: str) -> np.ndarray:
    return np.asarray(json.loads((folder / "summary.json").read_text())["series"][name]["y"])


@pytest.mark.mpi
def test_a_variant_with_the_runs_own_values_reproduces_its_part2(source, comm_tmp):
    scene = load_scene("shoulder-internal-rotation")
    out = comm_tmp / "sweep"
    # the run's own value second: its part 2 on the meshes the first variant made
    data = sweep(scene, source, ["scapula_modulus_factor=2,1"], out, MPI.COMM_WORLD)
    rows = data["variants"]
    assert [r["values"] for r in rows] == [
        {"scapula_modulus_factor": "2"},
        {"scapula_modulus_factor": "1"},
    ]
    assert all(r["status"] == "ok" for r in rows) and data["level"] == "coarse"
    ref = _von_mises(source)
    stiffer, own = (_von_mises(out / r["folder"], order_of=source) for r in rows)
    assert ref.shape == own.shape == (3, ref.shape[1]) and ref.max() > 0
    # the same part 2 on the same loads and the same mesh: equal up to round-off (and the
    # solver's |F| < 1e-8 N on loads of 10-100 N)
    assert np.abs(own - ref).max() <= 1e-10 * ref.max()
    # another modulus: another stress field, finite and positive (the springs share the load
    # with the bone's stiffness; measured at coarse, 60 deg: peaks of 2.657 and 2.677 MPa) ...
    assert np.all(np.isfinite(stiffer)) and stiffer.max() > 0
    assert np.abs(stiffer - ref).max() > 1e-6 * ref.max()
    # ... under the same transferred loads, in equilibrium with the springs at the same pose
    residual = _series(source, "transfer_equilibrium_residual")
    for r in rows:
        mine = _series(out / r["folder"], "transfer_equilibrium_residual")
        # the same imbalance as the run's own (part 1's Newton goes on to |F| < 1e-6 N at the
        # output angles, on loads of 10-100 N: below 1e-8); at 0 deg the open joint carries
        # 1e-4 N, and the imbalance relative to it is round-off (measured 1.3e-9 and 3.2e-9)
        assert np.abs(mine - residual)[1:].max() <= 1e-12 and mine.max() < 1e-8
    # sweep.json's maxima are the run's own series (MPa), as the nodal fields above
    peak = _series(source, "scapula_max_von_mises") * 1e-6
    # (at 0 deg the open joint's 40 Pa carry round-off: atol against the series' largest)
    assert np.allclose(rows[1]["von_mises_max_mpa"], peak, rtol=1e-10, atol=1e-10 * peak.max())
    # one part 2 each: a single factorization, no part 1
    for r in rows:
        summary = json.loads((out / r["folder"] / "summary.json").read_text())
        assert summary["probes"]["part2_factorizations"] == 1
        # not meshed at all: every variant reads the source run's scapula
        # (scapula_mesh.xdmf), so only the scapula was built: the run's DOFs are part 2's
        # (the source's: the joint too); the mesh stage's CPU is in benchmarks/sweep_cost.py
        assert summary["dofs"] == summary["dofs_part2"], summary["dofs"]
        assert [s["name"] for s in summary["stages"]] == ["mesh", "part2", "decoupled"]
    # a figure with its two panels (88 kB for a coarse sweep), not an empty file
    assert (out / "sweep.json").is_file() and (out / "sweep.png").stat().st_size > 10_000


@pytest.mark.parametrize(
    "setting, message",
    [
        ("contact_penalty=10MPa/mm", "part 1 depends on contact_penalty"),
        ("head_radius=25mm", "part 1 depends on head_radius"),
        ("scapula_modulus_factor=-1", "scapula_modulus_factor"),
        ("no_such_key=1", "unknown parameter 'no_such_key'"),
        ("scapula_modulus_factor=", "expected key=value"),
    ],
)
def test_a_key_part1_depends_on_or_a_bad_value_is_refused_before_anything(
    source, comm_tmp, setting, message
):
    out = comm_tmp / "refused"
    scene = load_scene("shoulder-internal-rotation")
    with pytest.raises(SceneError, match=message):
        sweep(scene, source, [setting], out, MPI.COMM_WORLD)
    assert not out.exists()


def test_a_coupled_or_unfinished_run_is_no_source(source, comm_tmp):
    scene = load_scene("shoulder-internal-rotation")
    summary = json.loads((source / "summary.json").read_text())
    fake = comm_tmp / "coupled"
    if MPI.COMM_WORLD.rank == 0:
        fake.mkdir()
        (fake / "summary.json").write_text(json.dumps(summary | {"method": "coupled"}))
    MPI.COMM_WORLD.Barrier()
    with pytest.raises(SceneError, match="part 1 comes from a decoupled one"):
        sweep(scene, fake, ["scapula_modulus_factor=2"], comm_tmp / "x", MPI.COMM_WORLD)
    with pytest.raises(SceneError, match="no summary.json"):
        sweep(scene, comm_tmp / "nowhere", ["scapula_modulus_factor=2"], comm_tmp / "y")


def test_the_command_line_refuses_a_part1_key_in_one_line(source, tmp_path):
    """``shoulder-fem sweep`` with a key part 1 depends on: exit status 2 (bad input), one line
    naming the key and what to run instead, nothing written."""
    import subprocess
    import sys

    if MPI.COMM_WORLD.size > 1:
        pytest.skip("a serial command line")
    out = tmp_path / "sweep"
    cmd = [sys.executable, "-m", "shoulder_fem.cli", "sweep", "shoulder-internal-rotation"]
    cmd += ["--from", str(source), "--set", "contact_penalty=10MPa/mm", "--out", str(out)]
    done = subprocess.run(cmd, capture_output=True, text=True)
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "part 1 depends on contact_penalty" in lines[0], lines
    assert "shoulder-fem study" in lines[0] and not out.exists()
