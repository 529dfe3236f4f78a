"""Keep the ranks of an MPI pytest run in step: a test that fails on one rank fails on all.

pytest catches a failing test, so under ``mpirun`` a rank that fails before a collective goes on
to the next test while the others wait in that collective for ever. This plugin (active when
``COMM_WORLD`` has more than one rank) does two things:

* At the end of every test (its teardown report) the ranks agree on its outcome: a test that
  failed on any rank is reported failed on every rank ("failed on rank 1"), so they stay in step
  and every rank's summary and exit status say so.
* A rank that leaves a test early (a failed phase, a skip or xfail) tells the others at once
  (a message on a communicator of its own). A watchdog thread on each rank reads these
  messages; if this rank is still inside that test ``GRACE_S`` seconds later (most likely
  waiting in a collective the other rank will never enter), it prints the test's name, the
  reason and its own stack, and aborts the MPI job. A rank waiting in a PETSc or DOLFINx
  collective holds the GIL and cannot run its watchdog, so the rank that left also aborts the
  job if the test is not over everywhere ``LEFT_S`` seconds later; every rank prints its stacks
  as mpirun ends it (faulthandler on SIGTERM).

A collective that can never complete for another reason (every rank waiting) is ended by
pytest-timeout's per-test limit (``timeout_method = "thread"`` ends the process, and mpirun
the job), set in ``pyproject.toml``, with a backstop from C ``BACKSTOP_S`` later for a rank whose
main thread holds the GIL. ``--maxfail`` and a session that ends early on one rank (an
interrupt, a collection error) end every rank's.
"""

from __future__ import annotations

import faulthandler
import os
import signal
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
#: A rank that left a test early (failed or skipped it) ends the job if the others have not
#: finished it this long after: a rank stuck in a collective that holds the GIL (PETSc, DOLFINx)
#: cannot run its own watchdog [s].
LEFT_S = GRACE_S + 5.0
#: A test still running this long after pytest-timeout's limit is ended from C: its thread
#: cannot run either while a collective holds the GIL [s].
BACKSTOP_S = 60.0
#: How long a rank whose session has ended waits for the others' [s].
END_S = 60.0
#: The agreement's value of a rank whose session has ended.
_END = 2


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
        self.left: tuple[float, str] | None = None  # when and why this rank left it early
        self.received: dict[str, tuple[float, int, str]] = {}  # test -> (time, rank, reason)
        self.stop = threading.Event()
        capman = config.pluginmanager.getplugin("capturemanager")  # None under -p no:capture
        if capman is None:
            self.err_fd = os.dup(2)
        else:
            with capman.global_and_fixture_disabled():
                self.err_fd = os.dup(2)  # the terminal's stderr, not a test's captured one
        # mpirun ends the other ranks with SIGTERM: their stacks even inside a GIL-holding call
        faulthandler.register(signal.SIGTERM, file=self.err_fd, all_threads=True, chain=True)
        self.watchdog = threading.Thread(target=self._watch, name="lockstep", daemon=True)
        self.watchdog.start()

    # --- the main thread ---------------------------------------------------------------------

    def enter(self, nodeid: str) -> None:
        with self.lock:
            self.current, self.entered, self.failed_here = nodeid, time.monotonic(), []
            self.left = None

    def report(self, rep: pytest.TestReport) -> None:
        """Tell the other ranks at once when this rank leaves a test early (a failed phase, a
        skipped or xfailed setup or call); agree after the teardown."""
        if rep.failed:
            self.failed_here.append(rep.when)
        if (rep.failed or (rep.skipped and rep.when != "teardown")) and self.left is None:
            reason = "xfailed" if hasattr(rep, "wasxfail") else "skipped"
            reason = _one_line(rep) if rep.failed else reason
            with self.lock:
                self.left = (time.monotonic(), reason)
            if rep.failed:
                self._write(
                    f"[rank {self.rank}] FAILED {rep.nodeid} ({rep.when}): {reason}\n"
                    f"{rep.longreprtext}\n"
                )
            for other in range(self.size):
                if other != self.rank:
                    self.alerts.send((rep.nodeid, reason), dest=other, tag=_TAG)
        if rep.when == "teardown":
            flags = self._agree(int(bool(self.failed_here)))
            ended = [int(r) for r in np.flatnonzero(flags == _END)]
            if ended:
                self._write(
                    f"[rank {self.rank}] rank {', '.join(map(str, ended))} ended its pytest "
                    f"session (interrupted, --maxfail, a collection error) while this rank was in "
                    f"{rep.nodeid}; ending the MPI job\n"
                )
                MPI.COMM_WORLD.Abort(1)
            failed = [int(r) for r in np.flatnonzero(flags == 1)]
            with self.lock:
                self.received.pop(rep.nodeid, None)
                self.current = None
            others = [r for r in failed if r != self.rank]
            if others and not self.failed_here:
                rep.outcome = "failed"
                rep.longrepr = f"failed on rank {', '.join(map(str, others))} (see its report)"

    def _agree(self, value: int, limit: float | None = None) -> np.ndarray | None:
        """Every rank's value (collective on the agreement communicator); None after ``limit`` s."""
        flags = np.zeros(self.size, dtype=np.int32)
        req = self.agree.Iallgather(np.array([value], dtype=np.int32), flags)
        start = time.monotonic()
        # Test with short sleeps rather than Wait: Open MPI's Wait spins, taking the core from
        # the rank that is behind when the ranks outnumber the free cores.
        while not req.Test():
            if limit is not None and time.monotonic() - start > limit:
                return None
            time.sleep(0.002)
        return flags

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
                if stuck is not None:  # under the lock: the main thread cannot finish the test now
                    self._abort(*stuck)

    def _stuck(self) -> tuple[str, int, str] | None:
        """The current test, if another rank failed it more than GRACE_S ago, or this rank left it
        more than LEFT_S ago (source -1) and the others have not finished it (lock held)."""
        if self.current is not None and self.left is not None:
            if time.monotonic() - self.left[0] >= LEFT_S:
                return self.current, -1, self.left[1]
        if self.current is None or self.current not in self.received:
            return None
        received, source, reason = self.received[self.current]
        if time.monotonic() - max(received, self.entered) < GRACE_S:
            return None
        return self.current, source, reason

    def _abort(self, nodeid: str, source: int, reason: str) -> None:
        if source < 0:
            self._write(
                f"[rank {self.rank}] FAILED {nodeid}: this rank left it ({reason}) {LEFT_S:g} s "
                f"ago and the other ranks have not finished it, most likely waiting in a "
                f"collective this rank will not enter; ending the MPI job (each rank prints its "
                f"stacks as it ends)\n"
            )
            MPI.COMM_WORLD.Abort(1)
        self._write(
            f"[rank {self.rank}] FAILED {nodeid}: rank {source} left it early ({reason}) and this "
            f"rank is still inside it after {GRACE_S:g} s, most likely waiting in a collective "
            f"that rank {source} will not enter; ending the MPI job. This rank's stacks:\n"
        )
        faulthandler.dump_traceback(file=self.err_fd, all_threads=True)
        MPI.COMM_WORLD.Abort(1)

    def close(self) -> None:
        self.stop.set()
        self.watchdog.join()
        # every alert sent has been received by now (sent before agreeing); a rank still in a
        # test (it did not stop where this one did) sees _END in its agreement and ends the job
        flags = self._agree(_END, limit=END_S)
        if flags is None or (flags != _END).any():
            self._write(
                f"[rank {self.rank}] this rank's pytest session has ended and the other ranks' "
                f"have not (a rank stopped early); ending the MPI job\n"
            )
            MPI.COMM_WORLD.Abort(1)
        status = MPI.Status()
        while self.alerts.Iprobe(source=MPI.ANY_SOURCE, tag=_TAG, status=status):
            self.alerts.recv(source=status.Get_source(), tag=_TAG)
        self.agree.Free()
        self.alerts.Free()
        faulthandler.unregister(signal.SIGTERM)
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
    # with the collection errors: a rank whose collection failed stops, the others would not
    digests = MPI.COMM_WORLD.allgather((digest, len(session.items), session.testsfailed))
    if any(d != digests[0] for d in digests):
        raise pytest.UsageError(
            f"the ranks collected different tests (crc32, count, errors per rank: {digests})"
        )


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_logstart(nodeid: str, location: Any) -> None:
    lockstep = _STATE.get("lockstep")
    if lockstep is not None:
        lockstep.enter(nodeid)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None):
    """--maxfail=N counts failed reports: a rank that failed a test's call and its teardown has
    counted two, the others one; the ranks stop together if any of them stops."""
    yield
    lockstep = _STATE.get("lockstep")
    if lockstep is not None and item.config.option.maxfail > 1:
        session = item.session
        flags = lockstep._agree(int(bool(session.shouldfail or session.shouldstop)))
        if flags.any() and not (session.shouldfail or session.shouldstop):
            session.shouldfail = "another rank stopped"


@pytest.hookimpl(optionalhook=True)
def pytest_timeout_set_timer(item: pytest.Item, settings: Any) -> None:
    """A backstop from C (faulthandler's thread needs no GIL) BACKSTOP_S after pytest-timeout's
    limit; pytest-timeout's own timer then runs as before."""
    lockstep = _STATE.get("lockstep")
    if lockstep is not None:
        faulthandler.dump_traceback_later(
            settings.timeout + BACKSTOP_S, exit=True, file=lockstep.err_fd
        )


@pytest.hookimpl(optionalhook=True)
def pytest_timeout_cancel_timer(item: pytest.Item) -> None:
    if "lockstep" in _STATE:
        faulthandler.cancel_dump_traceback_later()


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]):
    outcome = yield
    lockstep = _STATE.get("lockstep")
    if lockstep is not None:
        lockstep.report(outcome.get_result())
