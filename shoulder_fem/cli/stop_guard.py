"""Rank 0's SIGTERM clean-up under mpirun, done by a small process of its own.

mpirun forwards SIGTERM to every rank and kills them ``odls_base_sigkill_timeout`` seconds
later (1 s by default). Python runs a signal handler only when the main thread is back in
Python: a rank inside a long C call (gmsh meshing, a MUMPS factorization, on a loaded machine
longer still) was killed before its handler removed the unfinished output. Python's own C-level
handler writes the signal's number to the ``signal.set_wakeup_fd`` file at once, whatever the
main thread is doing; this guard reads it from a pipe, removes the unfinished output folders,
removes the form-cache claims left unfinished, prints the command's one line, and tells the rank
it is done. When the rank's process ends (its control pipe closes) it removes the folders once
more (a rank still running may have written into them) and exits. The guard runs in a session
of its own, so mpirun's kill does not reach it.

This file is run as a script (``python stop_guard.py``) and imports only the standard library:
no MPI, no dolfinx. :class:`StopGuard` is the rank's side.
"""

from __future__ import annotations

import contextlib
import json
import os
import select
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

#: How long the rank's handler waits for the guard's clean-up before the process ends [s].
ACK_TIMEOUT_S = 5.0


def remove_unfinished_forms(cache: Path, since: float) -> list[Path]:
    """Remove the form-cache entries whose compilation a stopped process left unfinished.

    FFCx claims a form by creating ``<module>.c`` and marks it done with ``<module>.c.cached``;
    a process stopped in between leaves the claim, and every later run waits for it and dies
    with "JIT compilation timed out". The claims without their mark made since ``since``
    (``time.time()``, the run's start) are removed, so the next run compiles anew.
    """
    removed = []
    for claim in cache.glob("*.c") if cache.is_dir() else ():
        try:
            unfinished = not claim.with_suffix(".c.cached").exists()
            if unfinished and claim.stat().st_mtime >= since - 1.0:
                claim.unlink()
                removed.append(claim)
        except OSError:
            continue
    return removed


def _remove(folders: list[str]) -> None:
    for folder in folders:
        for _ in range(3):  # the rank may still be closing files inside
            shutil.rmtree(folder, ignore_errors=True)
            if not os.path.exists(folder):
                break


def guard(wakeup: int, control: int, ack: int) -> None:
    """The guard's loop, until the rank's process ends.

    ``wakeup`` carries signal numbers, ``control`` the rank's JSON lines (``{"remove": [...],
    "say": ..., "cache": ..., "started": ...}``, the latest value of each key wins), ``ack``
    goes back to the rank.
    """
    state: dict = {"remove": [], "say": None, "cache": None, "started": time.time()}
    pending = b""
    stopped = False
    while True:
        ready, _, _ = select.select([wakeup, control], [], [])
        if control in ready:
            data = os.read(control, 65536)
            if not data:  # the rank's process has ended
                if stopped:
                    _remove(state["remove"])
                return
            pending += data
            *lines, pending = pending.split(b"\n")
            for line in lines:
                state.update(json.loads(line))
        if wakeup in ready:
            signals = os.read(wakeup, 512)
            if signal.SIGTERM in signals and not stopped:
                stopped = True
                _remove(state["remove"])
                if state["cache"]:
                    remove_unfinished_forms(Path(state["cache"]), state["started"])
                if state["say"]:
                    print(f"shoulder-fem: error: {state['say']}", file=sys.stderr, flush=True)
                with contextlib.suppress(OSError):
                    os.write(ack, b"1")


class StopGuard:
    """The rank's side: starts the guard, keeps it told what to remove and what to say.

    Args:
        say: the line to print when stopped (without ``shoulder-fem: error:``).
        cache: the form cache's folder.
        started: the run's start (``time.time()``).
    """

    def __init__(self, say: str | None, cache: Path | None, started: float) -> None:
        wakeup_r, wakeup_w = os.pipe()
        control_r, self._control = os.pipe()
        self._ack, ack_w = os.pipe()
        os.set_blocking(wakeup_w, False)
        self.process = subprocess.Popen(
            [sys.executable, __file__, str(wakeup_r), str(control_r), str(ack_w)],
            pass_fds=(wakeup_r, control_r, ack_w),
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            start_new_session=True,
        )
        for fd in (wakeup_r, control_r, ack_w):
            os.close(fd)
        self._wakeup = wakeup_w
        self._closed = False
        signal.set_wakeup_fd(wakeup_w, warn_on_full_buffer=False)
        self.update(say=say, cache=cache, started=started, remove=[])

    def update(self, **state) -> None:
        """Tell the guard (a dict's keys: ``remove``, ``say``, ``cache``, ``started``)."""
        line = json.dumps({k: str(v) if isinstance(v, Path) else v for k, v in state.items()})
        with contextlib.suppress(OSError):
            os.write(self._control, line.encode() + b"\n")

    def close(self) -> None:
        """Stop watching (the command is over): the guard sees its pipe close and exits."""
        if self._closed:
            return
        self._closed = True
        previous = signal.set_wakeup_fd(-1)
        if previous != self._wakeup:
            signal.set_wakeup_fd(previous)  # another one was set since: it stays
        os.close(self._control)
        with contextlib.suppress(subprocess.TimeoutExpired):
            self.process.wait(timeout=ACK_TIMEOUT_S)
        os.close(self._wakeup)
        os.close(self._ack)

    def wait_done(self) -> bool:
        """After SIGTERM: wait until the guard has cleaned up.

        Returns:
            False if it did not say so in time, or was closed (its command is over).
        """
        if self._closed:
            return False
        ready, _, _ = select.select([self._ack], [], [], ACK_TIMEOUT_S)
        return bool(ready)


if __name__ == "__main__":
    guard(*(int(arg) for arg in sys.argv[1:4]))
