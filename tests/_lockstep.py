"""Keep the ranks of an MPI pytest run in step: a test that fails on one rank fails on all.

pytest catches a failing test, so under ``mpirun`` a rank that fails before a collective goes on
to the next test while the others wait in that collective for ever. This plugin (active when
``COMM_WORLD`` has more than one rank) does two things:

* At the end of every test (its teardown report) the ranks agree on its outcome: a test that
  failed on any rank is reported failed on every rank ("failed on rank 1"), so they stay in step
  and every rank's summary and exit status say so.
* A rank whose test fails tells the others at once (a message on a communicator of its own). A
  watchdog thread on each rank reads these messages; if this rank is still inside that test
  ``GRACE_S`` seconds later (most likely waiting in a collective the failing rank will never
  enter), it prints the test's name, the reason and its own stack, and aborts the MPI job.

A collective that can never complete for another reason (every rank waiting) is ended by
pytest-timeout's per-test limit (``timeout_method = "thread"`` ends the process, and mpirun
the job), set in ``pyproject.toml``.
"""

from __future__ import annotations

import faulthandler
import os
import threading
import time
import zlib
from typing import Any

import numpy as np
import pytest
from mpi4py import MPI

#: How long a rank may stay inside a test that another rank failed before the job is aborted [s].
GRACE_S = 10.0
#: How often the watchdog looks for messages [s].
POLL_S = 0.1
_TAG = 7


class Lockstep:
    """The agreement and the watchdog of one pytest session on ``comm``."""

    def __init__(self, config: pytest.Config, comm: MPI.Comm) -> None:
        self.config = config
        self.rank = comm.rank
        self.size = comm.size
        self.agree = comm.Dup()  # the end-of-test agreement (never mixed with a test's own calls)
        self.alerts = comm.Dup()  # "this rank failed test X" messages
        self.lock = threading.Lock()
        self.current: str | None = None  # the test the main thread is in, until its agreement
        self.entered = 0.0  # when it entered it (time.monotonic)
        self.failed_here: list[str] = []  # this rank's failing phases of the current test
        self.received: dict[str, tuple[float, int, str]] = {}  # test -> (time, rank, reason)
        self.stop = threading.Event()
        capman = config.pluginmanager.getplugin("capturemanager")
        with capman.global_and_fixture_disabled():
            self.err_fd = os.dup(2)  # the terminal's stderr, not a test's captured one
        self.watchdog = threading.Thread(target=self._watch, name="lockstep", daemon=True)
        self.watchdog.start()

    # --- the main thread ---------------------------------------------------------------------

    def enter(self, nodeid: str) -> None:
        with self.lock:
            self.current, self.entered, self.failed_here = nodeid, time.monotonic(), []

    def report(self, rep: pytest.TestReport) -> None:
        """Tell the other ranks at once when a phase fails here; agree after the teardown."""
        if rep.failed:
            first = not self.failed_here
            self.failed_here.append(rep.when)
            if first:
                reason = _one_line(rep)
                self._write(
                    f"[rank {self.rank}] FAILED {rep.nodeid} ({rep.when}): {reason}\n"
                    f"{rep.longreprtext}\n"
                )
                for other in range(self.size):
                    if other != self.rank:
                        self.alerts.send((rep.nodeid, reason), dest=other, tag=_TAG)
        if rep.when == "teardown":
            failed = self._agree(bool(self.failed_here))
            with self.lock:
                self.received.pop(rep.nodeid, None)
                self.current = None
            others = [r for r in failed if r != self.rank]
            if others and not self.failed_here:
                rep.outcome = "failed"
                rep.longrepr = f"failed on rank {', '.join(map(str, others))} (see its report)"

    def _agree(self, failed: bool) -> list[int]:
        """The ranks on which the test failed (collective on the agreement communicator)."""
        flags = np.zeros(self.size, dtype=np.int32)
        req = self.agree.Iallgather(np.array([int(failed)], dtype=np.int32), flags)
        # Test with short sleeps rather than Wait: Open MPI's Wait spins, taking the core from
        # the rank that is behind when the ranks outnumber the free cores.
        while not req.Test():
            time.sleep(0.002)
        return [int(r) for r in np.flatnonzero(flags)]

    def _write(self, text: str) -> None:
        os.write(self.err_fd, text.encode())

    # --- the watchdog thread -----------------------------------------------------------------

    def _watch(self) -> None:
        status = MPI.Status()
        while not self.stop.wait(POLL_S):
            while self.alerts.Iprobe(source=MPI.ANY_SOURCE, tag=_TAG, status=status):
                source = status.Get_source()
                nodeid, reason = self.alerts.recv(source=source, tag=_TAG)
                with self.lock:
                    self.received[nodeid] = (time.monotonic(), source, reason)
            with self.lock:
                stuck = self._stuck()
            if stuck is not None:
                self._abort(*stuck)

    def _stuck(self) -> tuple[str, int, str] | None:
        """The current test, if another rank failed it more than GRACE_S ago (lock held)."""
        if self.current is None or self.current not in self.received:
            return None
        received, source, reason = self.received[self.current]
        if time.monotonic() - max(received, self.entered) < GRACE_S:
            return None
        return self.current, source, reason

    def _abort(self, nodeid: str, source: int, reason: str) -> None:
        self._write(
            f"[rank {self.rank}] FAILED {nodeid}: rank {source} failed it ({reason}) and this "
            f"rank is still inside it after {GRACE_S:g} s, most likely waiting in a collective "
            f"that rank {source} will not enter; ending the MPI job. This rank's stacks:\n"
        )
        faulthandler.dump_traceback(file=self.err_fd, all_threads=True)
        MPI.COMM_WORLD.Abort(1)

    def close(self) -> None:
        self.stop.set()
        self.watchdog.join()
        self.agree.Barrier()  # every alert sent has been received by now (sent before agreeing)
        status = MPI.Status()
        while self.alerts.Iprobe(source=MPI.ANY_SOURCE, tag=_TAG, status=status):
            self.alerts.recv(source=status.Get_source(), tag=_TAG)
        self.agree.Free()
        self.alerts.Free()
        os.close(self.err_fd)


def _one_line(rep: pytest.TestReport) -> str:
    crash = getattr(rep.longrepr, "reprcrash", None)
    text = crash.message if crash is not None else str(rep.longrepr)
    lines = text.strip().splitlines()
    return lines[0] if lines else "no message"


_STATE: dict[str, Lockstep] = {}


def pytest_configure(config: pytest.Config) -> None:
    if MPI.COMM_WORLD.size > 1:
        _STATE["lockstep"] = Lockstep(config, MPI.COMM_WORLD)


def pytest_unconfigure(config: pytest.Config) -> None:
    lockstep = _STATE.pop("lockstep", None)
    if lockstep is not None:
        lockstep.close()


def pytest_collection_finish(session: pytest.Session) -> None:
    """Every rank must run the same tests in the same order."""
    if "lockstep" not in _STATE:
        return
    digest = zlib.crc32("\n".join(item.nodeid for item in session.items).encode())
    digests = MPI.COMM_WORLD.allgather((digest, len(session.items)))
    if any(d != digests[0] for d in digests):
        raise pytest.UsageError(
            f"the ranks collected different tests (crc32, count per rank: {digests})"
        )


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_logstart(nodeid: str, location: Any) -> None:
    lockstep = _STATE.get("lockstep")
    if lockstep is not None:
        lockstep.enter(nodeid)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]):
    outcome = yield
    lockstep = _STATE.get("lockstep")
    if lockstep is not None:
        lockstep.report(outcome.get_result())
