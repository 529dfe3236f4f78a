"""Output folder, summary.json, XDMF fields and resource accounting.

Tests marked ``mpi`` also run under ``mpirun -n 2 python -m mpi4py -m pytest -m mpi``; they use
``comm_tmp`` (conftest), a folder shared by all ranks.
"""

from __future__ import annotations

import json
import math
import mmap
import os
import re
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI

from shoulder_fem import __version__
from shoulder_fem.io.fields import FieldWriter
from shoulder_fem.io.output import (
    SUMMARY_NAME,
    OutputDir,
    OutputError,
    atomic_write_json,
    to_jsonable,
)
from shoulder_fem.io.resources import (
    MB,
    ResourceMonitor,
    blas_library,
    dir_size_bytes,
    thread_settings,
)
from shoulder_fem.io.results import Recorder, load_summary

COMM = MPI.COMM_WORLD


def _partials(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if ".partial-" in p.name)


# --------------------------------------------------------------------------------------------
# JSON
# --------------------------------------------------------------------------------------------


def test_atomic_write_json_numpy_and_nonfinite(tmp_path: Path) -> None:
    """NumPy scalars/arrays become plain JSON; NaN and inf become null."""
    data = {
        "a": np.float64(1.5),
        "i": np.int32(7),
        "b": np.bool_(True),
        "arr": np.arange(6.0).reshape(2, 3),
        "nan": float("nan"),
        "inf": np.inf,
        "nested": [np.array([1.0, np.nan]), (np.int64(2), Path("/x/y"))],
        np.int64(3): "int key",
    }
    path = tmp_path / "d.json"
    atomic_write_json(path, data)
    text = path.read_text()
    assert "NaN" not in text and "Infinity" not in text
    back = json.loads(text)
    assert back == {
        "a": 1.5,
        "i": 7,
        "b": True,
        "arr": [[0.0, 1.0, 2.0], [3.0, 4.0, 5.0]],
        "nan": None,
        "inf": None,
        "nested": [[1.0, None], [2, "/x/y"]],
        "3": "int key",
    }
    assert sorted(os.listdir(tmp_path)) == ["d.json"]


def test_atomic_write_json_failure_leaves_nothing(tmp_path: Path) -> None:
    """A value with no JSON form leaves neither a file nor a temporary file."""
    with pytest.raises(TypeError):
        atomic_write_json(tmp_path / "bad.json", {"x": object()})
    assert os.listdir(tmp_path) == []
    # An existing file is left untouched by a failed write.
    atomic_write_json(tmp_path / "good.json", {"x": 1})
    with pytest.raises(TypeError):
        atomic_write_json(tmp_path / "good.json", {"x": 1j})
    assert json.loads((tmp_path / "good.json").read_text()) == {"x": 1}
    assert os.listdir(tmp_path) == ["good.json"]


def test_to_jsonable_rejects_objects() -> None:
    """Arbitrary objects are refused with a TypeError naming the type."""
    with pytest.raises(TypeError, match="object"):
        to_jsonable([1, object()])


# --------------------------------------------------------------------------------------------
# OutputDir
# --------------------------------------------------------------------------------------------


@pytest.mark.mpi
def test_output_commit(comm_tmp: Path) -> None:
    """commit() publishes the final folder without scratch or staging folders."""
    final = comm_tmp / "run"
    out = OutputDir(final, COMM)
    assert out.path.is_dir() and out.scratch.is_dir()
    assert out.path.parent == comm_tmp and ".partial-" in out.path.name
    if COMM.rank == 0:
        (out.path / "a.txt").write_text("a")
        (out.scratch / "tmp.bin").write_bytes(b"0" * 100)
    out.commit()
    assert out.commit() == final  # idempotent
    assert (final / "a.txt").read_text() == "a"
    assert not (final / "scratch").exists()
    assert _partials(comm_tmp) == []


@pytest.mark.mpi
def test_output_abort_and_exception_leave_nothing(comm_tmp: Path) -> None:
    """abort() and an exception inside ``with`` remove the staging folder."""
    out = OutputDir(comm_tmp / "aborted", COMM)
    out.abort()
    COMM.Barrier()
    assert os.listdir(comm_tmp) == []
    COMM.Barrier()  # all ranks have looked before rank 0 creates the next folder

    with pytest.raises(RuntimeError, match="boom"):
        with OutputDir(comm_tmp / "crashed", COMM) as out:
            if COMM.rank == 0:
                (out.path / "half.txt").write_text("x")
            COMM.Barrier()
            raise RuntimeError("boom")
    COMM.Barrier()
    assert os.listdir(comm_tmp) == []


@pytest.mark.mpi
def test_output_commit_before_reraise_keeps_results(comm_tmp: Path) -> None:
    """Committing before re-raising keeps the steps written so far."""
    final = comm_tmp / "diverged"
    with pytest.raises(RuntimeError, match="diverged"):
        with OutputDir(final, COMM) as out:
            if COMM.rank == 0:
                (out.path / "steps.txt").write_text("3 steps")
            try:
                raise RuntimeError("diverged at step 4")
            except RuntimeError:
                out.commit()
                raise
    COMM.Barrier()
    assert (final / "steps.txt").read_text() == "3 steps"
    assert _partials(comm_tmp) == []


@pytest.mark.mpi
def test_output_context_commits_on_normal_exit(comm_tmp: Path) -> None:
    """Leaving ``with`` normally commits."""
    with OutputDir(comm_tmp / "ok", COMM) as out:
        if COMM.rank == 0:
            (out.path / "x").write_text("1")
    assert out.state == "committed"
    assert (comm_tmp / "ok" / "x").is_file()
    assert _partials(comm_tmp) == []


@pytest.mark.mpi
def test_output_missing_parent(comm_tmp: Path) -> None:
    """A missing parent is refused on every rank before anything is created."""
    final = comm_tmp / "nope" / "run"
    with pytest.raises(OutputError, match=r"parent folder .*nope does not exist") as info:
        OutputDir(final, COMM)
    assert str(final) in str(info.value)
    assert "\n" not in str(info.value)
    COMM.Barrier()
    assert os.listdir(comm_tmp) == []


@pytest.mark.mpi
def test_output_replaces_previous_result(comm_tmp: Path) -> None:
    """A previous result (has summary.json) is refused unless ``replace`` (``--force``), and
    then replaced only at commit."""
    final = comm_tmp / "run"
    if COMM.rank == 0:
        final.mkdir()
        (final / SUMMARY_NAME).write_text('{"old": true}')
        (final / "old_only.txt").write_text("old")
    COMM.Barrier()
    refused = r"holds a previous result \(summary.json\); give --force"
    with pytest.raises(OutputError, match=refused):
        OutputDir(final, COMM)
    assert load_summary(final) == {"old": True}
    assert sorted(os.listdir(comm_tmp)) == ["run"]
    COMM.Barrier()  # all ranks have looked before rank 0 creates the staging folder
    with OutputDir(final, COMM, replace=True) as out:
        if COMM.rank == 0:
            atomic_write_json(out.path / SUMMARY_NAME, {"new": True})
        assert load_summary(final) == {"old": True}  # old result readable until commit
    assert load_summary(final) == {"new": True}
    assert not (final / "old_only.txt").exists()
    assert sorted(os.listdir(comm_tmp)) == ["run"]  # no partial, no trash


@pytest.mark.mpi
def test_output_refuses_foreign_folder(comm_tmp: Path) -> None:
    """A non-empty folder that is not ours is refused and left untouched."""
    final = comm_tmp / "photos"
    if COMM.rank == 0:
        final.mkdir()
        (final / "holiday.jpg").write_bytes(b"\xff\xd8")
    COMM.Barrier()
    with pytest.raises(OutputError, match="not a shoulder-fem result"):
        OutputDir(final, COMM)
    COMM.Barrier()
    assert sorted(os.listdir(comm_tmp)) == ["photos"]
    assert os.listdir(final) == ["holiday.jpg"]


def test_output_accepts_empty_existing_folder(tmp_path: Path) -> None:
    """An existing empty folder can become the output folder."""
    (tmp_path / "empty").mkdir()
    with OutputDir(tmp_path / "empty", COMM) as out:
        (out.path / "f").write_text("1")
    assert (tmp_path / "empty" / "f").is_file()


# --------------------------------------------------------------------------------------------
# ResourceMonitor
# --------------------------------------------------------------------------------------------


def _hwm_rss_mb() -> tuple[float, float]:
    text = Path("/proc/self/status").read_text()
    hwm = int(re.search(r"VmHWM:\s+(\d+)", text).group(1)) / 1024
    rss = int(re.search(r"VmRSS:\s+(\d+)", text).group(1)) / 1024
    return hwm, rss


@pytest.mark.mpi
def test_resource_monitor(comm_tmp: Path) -> None:
    """Stage memory, CPU and peak scratch size are measured and reduced over ranks."""
    size = COMM.size
    scratch = comm_tmp / "scratch"
    results = comm_tmp / "results"
    if COMM.rank == 0:
        scratch.mkdir()
        results.mkdir()
        (results / "field.bin").write_bytes(b"1" * MB)
    COMM.Barrier()
    mon = ResourceMonitor(COMM, scratch_dir=scratch)

    with mon.stage("idle"):
        time.sleep(0.05)
    # Allocate 100 MB above the process peak so the test holds with or without the reset.
    hwm, rss = _hwm_rss_mb()
    nbytes = int((max(hwm - rss, 0.0) + 100.0) * MB)
    with mon.stage("alloc"):
        # An anonymous mapping, touched page by page and unmapped at close: the memory goes back
        # to the system for sure (a malloc'ed block may stay in the heap after earlier tests).
        buf = mmap.mmap(-1, nbytes)
        block = np.frombuffer(buf, dtype=np.uint8)
        block[:] = 1
        assert int(block[::4096].sum()) == len(block[::4096])
        del block
        buf.close()
    with mon.stage("idle-after"):
        time.sleep(0.05)
    with mon.stage("busy"):
        # Spin until this process has used 0.5 s of CPU: other jobs on the machine then stretch
        # the wall time but not the CPU time.
        end = time.process_time() + 0.5
        x = 0
        while time.process_time() < end:
            x += 1
    with mon.stage("temp-file"):
        if COMM.rank == 0:
            (scratch / "tmp.bin").write_bytes(b"0" * 5_000_000)
        COMM.Barrier()
        mon.sample()
        COMM.Barrier()
        if COMM.rank == 0:
            (scratch / "tmp.bin").unlink()
            (scratch / "left.bin").write_bytes(b"0" * 1000)
        COMM.Barrier()

    res = mon.finish(scratch.parent)
    stages = {s["name"]: s for s in mon.stages}
    assert [s["name"] for s in mon.stages] == ["idle", "alloc", "idle-after", "busy", "temp-file"]
    assert set(res) >= {"wall_s", "cpu_s", "peak_rss_mb", "temp_disk_mb", "results_disk_mb"}
    assert res["ranks"] == size

    # Memory: the 100 MB block shows on every rank, summed over ranks.
    assert stages["alloc"]["peak_rss_mb"] >= stages["idle"]["peak_rss_mb"] + 90 * size
    assert res["peak_rss_mb"] >= max(s["peak_rss_mb"] for s in mon.stages) - 1e-9
    # the largest rank's own peak: at least the 100 MB block, at least the mean, at most the sum
    peak_max = res["peak_rss_rank_max_mb"]
    assert 90 <= peak_max and res["peak_rss_mb"] / size - 1e-9 <= peak_max <= res["peak_rss_mb"]
    if res["peak_rss_stage_reset"]:
        assert stages["idle-after"]["peak_rss_mb"] < stages["alloc"]["peak_rss_mb"] - 50 * size

    # CPU: 0.5 s per rank, summed over ranks; a single-threaded loop cannot beat wall x ranks.
    busy = stages["busy"]
    assert 0.45 * size <= busy["cpu_s"] <= 0.7 * size
    assert busy["cpu_s"] <= 1.1 * busy["wall_s"] * size + 0.05
    assert res["wall_s"] >= max(s["wall_s"] for s in mon.stages)
    assert res["cpu_s"] >= busy["cpu_s"]

    # Disk: the deleted 5 MB scratch file is caught; the results size excludes the scratch folder.
    assert res["temp_disk_mb"] >= 5_000_000 / MB
    assert res["temp_disk_mb"] < 5_000_000 / MB + 1
    assert res["results_disk_mb"] == pytest.approx(1.0)


def test_resource_monitor_excludes_scratch_and_falls_back(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Without the HWM reset, stages report the process peak; scratch is not a result."""
    import shoulder_fem.io.resources as resources

    monkeypatch.setattr(resources, "_reset_hwm", lambda: False)
    (tmp_path / "scratch").mkdir()
    (tmp_path / "scratch" / "t.bin").write_bytes(b"0" * 3 * MB)
    (tmp_path / "r.bin").write_bytes(b"0" * MB)
    mon = ResourceMonitor(COMM, scratch_dir=tmp_path / "scratch")
    with mon.stage("outer"):
        with mon.stage("inner"):
            pass
    res = mon.finish(tmp_path)
    assert res["peak_rss_stage_reset"] is False
    assert res["results_disk_mb"] == pytest.approx(1.0)
    assert res["temp_disk_mb"] == pytest.approx(3.0)
    # Without the reset a stage reports the process peak up to its end.
    hwm, _ = _hwm_rss_mb()
    assert [s["name"] for s in mon.stages] == ["inner", "outer"]
    assert mon.stages[1]["peak_rss_mb"] <= hwm + 1e-9
    assert mon.stages[1]["peak_rss_mb"] == pytest.approx(res["peak_rss_mb"], abs=1.0)


def test_resource_monitor_keeps_peak_across_monitors(tmp_path: Path) -> None:
    """A monitor made later measures from its own start; an older one keeps the earlier peak.

    ``bench`` runs both methods in one process: the second run must not report the first's
    peak, yet a monitor that was alive throughout must still see it.
    """
    outer = ResourceMonitor(COMM)
    hwm, rss = _hwm_rss_mb()
    block = np.ones(int((max(hwm - rss, 0.0) + 100.0) * MB) // 8)
    top = _hwm_rss_mb()[0]
    del block
    inner = ResourceMonitor(COMM)
    with inner.stage("small"):
        pass
    assert outer.finish(tmp_path)["peak_rss_mb"] >= COMM.size * (top - 1.0)
    res = inner.finish(tmp_path)
    if res["peak_rss_stage_reset"]:  # the kernel let the mark restart: 100 MB were freed
        assert res["peak_rss_mb"] <= COMM.size * (top - 50.0)
        assert res["start_rss_mb"] <= res["peak_rss_mb"] + 1e-9


def test_dir_size_bytes(tmp_path: Path) -> None:
    """Sizes of regular files, symlinks not followed, excluded folder skipped."""
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "x").write_bytes(b"1" * 10)
    (tmp_path / "y").write_bytes(b"1" * 5)
    os.symlink(tmp_path / "y", tmp_path / "link")
    assert dir_size_bytes(tmp_path) == 15
    assert dir_size_bytes(tmp_path, exclude=tmp_path / "a") == 5
    assert dir_size_bytes(tmp_path / "missing") == 0


def test_blas_library_names_existing_file() -> None:
    """The reported BLAS names a library file that exists."""
    text = blas_library()
    assert text and not text.startswith("unknown")
    path = re.search(r"(/\S+)", text).group(1)
    assert os.path.isfile(path), text
    assert "blas" in path.lower() or "mkl" in path.lower()


def test_blas_library_does_not_initialise_petsc() -> None:
    """Safe on one rank: PETSc's libraries are mapped, PETSc itself is not initialised."""
    code = (
        "import sys; from shoulder_fem.io.resources import blas_library; text = blas_library(); "
        "assert 'petsc4py.PETSc' not in sys.modules; print(text)"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=False
    )
    assert done.returncode == 0, done.stderr
    assert re.search(r"/\S*blas\S*", done.stdout), done.stdout


def test_thread_settings(monkeypatch: pytest.MonkeyPatch) -> None:
    """Thread variables are reported, None where unset."""
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    threads = thread_settings()
    assert threads["OMP_NUM_THREADS"] == "1"
    assert threads["OPENBLAS_NUM_THREADS"] is None


# --------------------------------------------------------------------------------------------
# Recorder + FieldWriter
# --------------------------------------------------------------------------------------------


def test_recorder_checks(tmp_path: Path) -> None:
    """Recorder refuses inconsistent units, unknown counters and reserved keys."""
    rec = Recorder(COMM, tmp_path)
    rec.add_series_point("angle", 0.0, 0.1, "s", "rad")
    with pytest.raises(ValueError, match="units"):
        rec.add_series_point("angle", 0.1, 0.2, "s", "deg")
    with pytest.raises(KeyError, match="newton_iterations"):
        rec.count("newton_iteration")
    with pytest.raises(ValueError, match="status"):
        rec.set_status("maybe")
    with pytest.raises(ValueError, match="reserved"):
        rec.extra("probes", 1)
    with pytest.raises(ValueError, match="without a unit"):
        rec.set_parameters({"E": 1e9, "nu": 0.3}, {"E": "Pa"})
    with pytest.raises(ValueError, match="x values"):
        rec.set_series("s", [1, 2], [1], "s", "m")
    with pytest.raises(TypeError):
        rec.set_probe("p", object())


@pytest.mark.mpi
def test_recorder_and_fields_roundtrip(comm_tmp: Path) -> None:
    """A run writes fields (P2 vector, DG0 tensor and scalar) and a summary that read back."""
    from dolfinx import fem, mesh

    h5py = pytest.importorskip("h5py")

    final = comm_tmp / "run"
    with OutputDir(final, COMM) as out:
        mon = ResourceMonitor(COMM, scratch_dir=out.scratch)
        rec = Recorder(COMM, out)
        rec.set_meta(scene="spinning-bar", method="decoupled", level="coarse")
        rec.set_parameter("omega", np.float64(10.0), "rad/s")
        rec.set_parameters({"E": 17e9, "nu": 0.3}, {"E": "Pa", "nu": "1"})
        rec.set_probe("max_von_mises", np.float64(1.25e6), "Pa")
        rec.set_probe("undefined", float("nan"))
        rec.extra("blas", blas_library())
        rec.extra("dofs", {"u": np.int64(375)})

        with mon.stage("part2-stress"):
            domain = mesh.create_unit_cube(COMM, 2, 2, 2)
            V = fem.VectorFunctionSpace(domain, ("Lagrange", 2))
            S = fem.TensorFunctionSpace(domain, ("DG", 0))
            Q = fem.FunctionSpace(domain, ("DG", 0))
            u = fem.Function(V, name="u")
            sigma = fem.Function(S, name="sigma")
            vm = fem.Function(Q, name="von_mises")
            with FieldWriter(COMM, domain, out.field_file("bone")) as writer:
                for t in (0.0, 0.5):
                    u.interpolate(lambda x, t=t: np.stack([t * x[0] ** 2, x[1] * x[2], 0 * x[0]]))
                    sigma.x.array[:] = t + 1.0
                    vm.x.array[:] = 2.0 * (t + 1.0)
                    writer.write([u, sigma, vm], t)
                    rec.add_series_point("time_tip", t, np.array([t, 0.0, -t]), "s", "m")
                    rec.count("steps")
                    rec.count("linear_solves", 2)
                    mon.sample()
                with pytest.raises(ValueError, match="not after"):
                    writer.write([u], 0.5)
                assert writer.times == {
                    "u": [0.0, 0.5],
                    "sigma": [0.0, 0.5],
                    "von_mises": [0.0, 0.5],
                }
        rec.set_series("energy", np.array([0.0, 0.5]), [1.0, np.inf], "s", "J")
        resources = mon.finish(out.path)
        written = rec.write_summary(resources, mon.stages)

    assert _partials(comm_tmp) == []
    summary = load_summary(final)
    assert summary == written
    assert summary == load_summary(final / SUMMARY_NAME)
    for key in (
        "scene", "method", "level", "status", "message", "parameters", "parameter_units",
        "resources", "stages", "solver", "series", "probes", "probe_units", "version",
        "created", "ranks", "blas", "dofs",
    ):  # fmt: skip
        assert key in summary, key
    assert summary["version"] == __version__
    assert summary["ranks"] == COMM.size
    assert summary["status"] == "ok" and summary["message"] is None
    assert summary["parameters"] == {"omega": 10.0, "E": 17e9, "nu": 0.3}
    assert summary["parameter_units"] == {"omega": "rad/s", "E": "Pa", "nu": "1"}
    assert summary["probes"] == {"max_von_mises": 1.25e6, "undefined": None}
    assert summary["probe_units"]["max_von_mises"] == "Pa"
    assert summary["series"]["time_tip"] == {
        "x": [0.0, 0.5],
        "y": [[0.0, 0.0, -0.0], [0.5, 0.0, -0.5]],
        "x_unit": "s",
        "y_unit": "m",
    }
    assert summary["series"]["energy"]["y"] == [1.0, None]
    assert summary["solver"] == {
        "steps": 2,
        "newton_iterations": 0,
        "linear_solves": 4,
        "factorizations": 0,
        "cutbacks": 0,
    }
    assert [s["name"] for s in summary["stages"]] == ["part2-stress"]
    assert summary["resources"]["results_disk_mb"] > 0
    assert summary["dofs"] == {"u": 375}

    xdmf, h5 = final / "fields" / "bone.xdmf", final / "fields" / "bone.h5"
    assert xdmf.is_file() and h5.is_file()
    n_cells = 6 * 2**3
    if COMM.rank == 0:
        # XDMF: one temporal collection per field, two time steps each.
        root = ET.parse(xdmf).getroot()
        collections = {
            g.get("Name"): g for g in root.iter("Grid") if g.get("GridType") == "Collection"
        }
        assert set(collections) == {"u", "sigma", "von_mises"}
        for grid in collections.values():
            times = [float(t.get("Value")) for t in grid.iter("Time")]
            assert times == [0.0, 0.5]
        with h5py.File(h5, "r") as f:
            geometry = f["Mesh/mesh/geometry"][:]
            assert sorted(f["Function"]) == ["sigma", "u", "von_mises"]
            steps = sorted(f["Function/u"], key=float)
            assert len(steps) == 2
            u_last = f[f"Function/u/{steps[-1]}"][:]
            x = geometry
            exact = np.stack([0.5 * x[:, 0] ** 2, x[:, 1] * x[:, 2], 0 * x[:, 0]], axis=1)
            assert u_last.shape == geometry.shape
            assert np.allclose(u_last, exact, atol=1e-12)
            vm_last = f[f"Function/von_mises/{sorted(f['Function/von_mises'], key=float)[-1]}"][:]
            assert vm_last.shape == (n_cells, 1)
            assert np.allclose(vm_last, 3.0)
            sig = f["Function/sigma"]
            assert len(sig) == 2
            assert sig[sorted(sig, key=float)[0]].shape == (n_cells, 9)

    meshio = pytest.importorskip("meshio")
    if COMM.rank == 0:
        with meshio.xdmf.TimeSeriesReader(str(xdmf)) as reader:
            points, cells = reader.read_points_cells()
            assert len(points) == len(geometry)
            assert sum(len(c.data) for c in cells) == n_cells


def test_load_summary_missing(tmp_path: Path) -> None:
    """Reading a folder without summary.json says so."""
    with pytest.raises(FileNotFoundError, match="summary.json"):
        load_summary(tmp_path)


def test_summary_handles_nan_resources(tmp_path: Path) -> None:
    """A failed run's summary is written with its message; NaN becomes null."""
    rec = Recorder(COMM, tmp_path)
    rec.set_status("failed", "Newton diverged at step 3 (DIVERGED_MAX_IT, 50 iterations)")
    data = rec.write_summary({"wall_s": math.nan}, [])
    assert data["resources"]["wall_s"] is None
    back = load_summary(tmp_path)
    assert back["status"] == "failed" and "step 3" in back["message"]
