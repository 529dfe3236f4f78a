"""Shared fixtures: a temporary folder common to all MPI ranks, and a collective teardown.

Under mpirun the ranks agree on every test's outcome and a rank left inside a test that another
rank failed ends the job (``_lockstep``).
"""

from __future__ import annotations

import gc
import logging
from pathlib import Path

# first: a pytest-xdist worker's environment without its controller's MPI (before MPI starts)
import _xdist_env  # noqa: F401
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

#: Fixture scopes that outlive a test: a test using one of this project's runs with the others
#: of its module on one xdist worker, so that the fixture is computed once.
_SHARED_SCOPES = ("module", "package", "session")


@pytest.hookimpl(tryfirst=True)  # before xdist's worker reads the groups
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Under ``pytest -n N --dist loadgroup`` (make test's serial phase): keep a module's
    tests that share one of its module-scoped fixtures on one worker, and start those groups
    first, so that the other workers take the single tests meanwhile (a long group started
    last would run alone at the end)."""
    if not hasattr(config, "workerinput"):
        return
    grouped, others = [], []
    for item in items:
        defs = [d[-1] for d in item._fixtureinfo.name2fixturedefs.values()]
        # a fixture of this project's (its baseid a test path; pytest's own have none)
        if any(d.scope in _SHARED_SCOPES and d.baseid.startswith("tests") for d in defs):
            item.add_marker(pytest.mark.xdist_group(item.nodeid.split("::")[0]))
            grouped.append(item)
        else:
            others.append(item)
    items[:] = grouped + others


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
