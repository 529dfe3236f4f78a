"""Shared fixtures: a temporary folder common to all MPI ranks, and a collective teardown.

Under mpirun the ranks agree on every test's outcome and a rank left inside a test that another
rank failed ends the job (``_lockstep``).
"""

from __future__ import annotations

import gc
import logging
from pathlib import Path

import pytest

# the hooks that keep the MPI ranks in step (pytest reads a conftest's hook functions by name)
from _lockstep import (  # noqa: F401
    pytest_collection_finish,
    pytest_configure,
    pytest_runtest_logstart,
    pytest_runtest_makereport,
    pytest_runtest_protocol,
    pytest_timeout_cancel_timer,
    pytest_timeout_set_timer,
    pytest_unconfigure,
)
from mpi4py import MPI

# every test's forms wait for another process's compilation as the runs do (JIT_TIMEOUT)
import shoulder_fem.engine.fem  # noqa: F401


@pytest.fixture
def comm_tmp(tmp_path: Path) -> Path:
    """Rank 0's ``tmp_path``, the same on every rank (each rank's own differs under mpirun)."""
    return Path(MPI.COMM_WORLD.bcast(str(tmp_path), root=0))


@pytest.fixture(autouse=True)
def _collective_teardown():
    root, package = logging.getLogger(), logging.getLogger("shoulder_fem")
    saved = (root.handlers[:], package.handlers[:], package.level, package.propagate)
    yield
    # a CLI test's handlers write to that test's captured stderr, closed after it
    root.handlers[:], package.handlers[:], package.level, package.propagate = saved
    gc.collect()
    MPI.COMM_WORLD.Barrier()
