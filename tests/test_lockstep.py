"""The MPI test phase stays in step: a test that fails on one rank fails on every rank, and a
rank left waiting in a collective ends the job instead of hanging (``_lockstep``,
pytest-timeout). Each case runs a small test file under ``mpirun -n 2`` in a subprocess."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

HERE = Path(__file__).parent
# Without the plugin the first case hangs for ever; this bounds the subprocess instead.
HANG_S = 180.0


def _run_on_two_ranks(tmp_path: Path, tests: str) -> tuple[int, float, dict[int | str, str]]:
    """Run ``tests`` (a test module's text) on 2 ranks; the status, the wall time and each
    rank's output (Open MPI's ``--output-filename`` keeps them apart)."""
    mpirun = shutil.which("mpirun")
    if mpirun is None:
        pytest.skip("no mpirun")
    (tmp_path / "conftest.py").write_text((HERE / "conftest.py").read_text())
    (tmp_path / "test_cases.py").write_text(textwrap.dedent(tests))
    env = dict(os.environ, OMP_NUM_THREADS="1")
    env.setdefault("OMPI_ALLOW_RUN_AS_ROOT", "1")  # as the Makefile sets them
    env.setdefault("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
    env["PYTHONPATH"] = os.pathsep.join([str(HERE), env.get("PYTHONPATH", "")])
    logs = tmp_path / "logs"
    cmd = [mpirun, "-n", "2", "--output-filename", str(logs), sys.executable, "-m", "mpi4py"]
    cmd += ["-m", "pytest", "-rA", "--color=no", "-p", "no:cacheprovider"]
    cmd += ["--rootdir", str(tmp_path), "-o", "timeout_method=thread", "test_cases.py"]
    start = time.monotonic()
    proc = subprocess.run(
        cmd, capture_output=True, text=True, env=env, cwd=tmp_path, timeout=HANG_S
    )
    elapsed = time.monotonic() - start
    out = {"mpirun": proc.stdout + proc.stderr}
    for rank in (0, 1):
        files = sorted(logs.glob(f"*/rank.{rank}/std*"))
        out[rank] = "".join(f.read_text() for f in files)
    return proc.returncode, elapsed, out


def test_a_failure_before_a_collective_ends_the_job_on_both_ranks(tmp_path: Path) -> None:
    # rank 1 fails, rank 0 waits in the allgather: the case that hung the MPI phase
    status, elapsed, out = _run_on_two_ranks(
        tmp_path,
        """
        from mpi4py import MPI

        def test_fails_on_rank_1_only():
            comm = MPI.COMM_WORLD
            assert comm.rank != 1
            comm.allgather(comm.rank)

        def test_never_reached():
            MPI.COMM_WORLD.Barrier()
        """,
    )
    assert status != 0, out
    # the grace period (10 s) plus two start-ups; a hang would have reached HANG_S
    assert elapsed < HANG_S / 2, out
    name = "test_cases.py::test_fails_on_rank_1_only"
    # rank 1 names its failure with the assertion; rank 0 names the test it is stuck in,
    # who failed it, and prints where it waits
    assert f"[rank 1] FAILED {name} (call): assert 1 != 1" in out[1], out[1]
    assert f"[rank 0] FAILED {name}: rank 1 left it early (assert 1 != 1)" in out[0], out[0]
    assert "in test_fails_on_rank_1_only" in out[0], out[0]  # its stack, at the allgather
    assert "test_never_reached PASSED" not in out[0] + out[1]


def test_a_failure_before_a_petsc_collective_ends_the_job(tmp_path: Path) -> None:
    # rank 0 waits inside PETSc, holding the GIL: its watchdog cannot run, rank 1 ends the job
    status, elapsed, out = _run_on_two_ranks(
        tmp_path,
        """
        from mpi4py import MPI
        from petsc4py import PETSc

        def test_fails_on_rank_1_only():
            assert MPI.COMM_WORLD.rank != 1
            PETSc.Vec().createMPI(10, comm=PETSc.COMM_WORLD).norm()
        """,
    )
    assert status != 0, out
    assert elapsed < HANG_S / 2, out
    name = "test_cases.py::test_fails_on_rank_1_only"
    assert f"[rank 1] FAILED {name}: this rank left it (assert 1 != 1)" in out[1], out[1]
    # rank 0's stack, printed as mpirun ended it, shows where it waited
    assert "in test_fails_on_rank_1_only" in out[0], out[0]


def test_a_skip_on_one_rank_before_a_collective_ends_the_job(tmp_path: Path) -> None:
    status, elapsed, out = _run_on_two_ranks(
        tmp_path,
        """
        import pytest
        from mpi4py import MPI

        def test_skips_on_rank_1_only():
            comm = MPI.COMM_WORLD
            if comm.rank == 1:
                pytest.skip("nothing to check on this rank")
            comm.allgather(comm.rank)
        """,
    )
    assert status != 0, out
    assert elapsed < HANG_S / 2, out
    name = "test_cases.py::test_skips_on_rank_1_only"
    assert f"[rank 0] FAILED {name}: rank 1 left it early (skipped)" in out[0], out[0]


def test_a_failure_after_the_last_collective_fails_on_both_ranks_and_the_run_goes_on(
    tmp_path: Path,
) -> None:
    status, _, out = _run_on_two_ranks(
        tmp_path,
        """
        from mpi4py import MPI

        def test_fails_on_rank_1_only():
            comm = MPI.COMM_WORLD
            assert comm.allgather(comm.rank) == [0, 1]
            assert comm.rank != 1

        def test_next():
            assert MPI.COMM_WORLD.allreduce(1) == 2
        """,
    )
    assert status != 0, out
    name = "test_cases.py::test_fails_on_rank_1_only"
    # rank 1: its own assertion; rank 0, where it passed: an error naming rank 1
    assert f"FAILED {name} - assert 1 != 1" in out[1], out[1]
    assert f"ERROR {name}" in out[0], out[0]
    assert "ERROR at teardown of test_fails_on_rank_1_only" in out[0], out[0]
    assert "failed on rank 1 (see its report)" in out[0], out[0]
    # the ranks stayed in step: the next test's collective completed on both
    for rank in (0, 1):
        assert "PASSED test_cases.py::test_next" in out[rank], out[rank]


def test_a_collective_that_never_completes_ends_at_the_time_limit(tmp_path: Path) -> None:
    # every rank waits for a message no rank sends: only the per-test limit can end it
    status, elapsed, out = _run_on_two_ranks(
        tmp_path,
        """
        import pytest
        from mpi4py import MPI

        @pytest.mark.timeout(5)
        def test_waits_for_ever():
            comm = MPI.COMM_WORLD
            comm.recv(source=(comm.rank + 1) % comm.size)
        """,
    )
    assert status != 0, out
    assert elapsed < HANG_S / 2, out
    both = out[0] + out[1]
    assert "Timeout" in both and "test_waits_for_ever" in both, both
