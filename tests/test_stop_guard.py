"""Rank 0's stop guard (``shoulder_fem/cli/stop_guard.py``): SIGTERM's clean-up happens at once
even while the main thread is inside a long C call, where Python cannot run a handler."""

from __future__ import annotations

import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

# The process under test: a Python handler for SIGTERM (as the CLI has), a guard told to remove
# a folder, then a sort of 5 million shuffled numbers: C code that holds the GIL for seconds and
# never checks for signals, as gmsh or MUMPS do in a run.
CHILD = textwrap.dedent(
    """
    import os, signal, sys, time
    import numpy as np
    from shoulder_fem.cli.stop_guard import StopGuard

    folder, cache, use_guard = sys.argv[1], sys.argv[2], sys.argv[3] == "1"
    def stop(signum, frame):
        if not (use_guard and guard.wait_done()):
            import shutil
            shutil.rmtree(folder)
            print("shoulder-fem: error: removed by the handler", file=sys.stderr, flush=True)
        os._exit(143)
    signal.signal(signal.SIGTERM, stop)
    if use_guard:
        guard = StopGuard("stopped by SIGTERM: the unfinished output was removed", cache, 0.0)
        guard.update(remove=[folder])
    data = np.random.default_rng(0).permutation(5_000_000).tolist()
    print("ready", flush=True)
    sorted(data)
    sorted(data)
    print("sorted", flush=True)
    """
)


def _terminate_during_a_c_call(tmp_path: Path, use_guard: bool) -> tuple[str, Path, Path]:
    """SIGTERM, then SIGKILL 0.5 s later (mpirun's kill, with a short sigkill timeout)."""
    folder = tmp_path / "out.partial-1234"
    (folder / "fields").mkdir(parents=True)
    (folder / "fields" / "u.h5").write_bytes(b"0" * 1000)
    cache = tmp_path / "cache"
    cache.mkdir()
    (cache / "libffcx_forms_done.c").write_text("int x;")
    (cache / "libffcx_forms_done.c.cached").write_text("")
    (cache / "libffcx_forms_claimed.c").write_text("int y;")  # claimed, never finished
    proc = subprocess.Popen(
        [sys.executable, "-c", CHILD, str(folder), str(cache), "1" if use_guard else "0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout.readline() == "ready\n"
    proc.send_signal(signal.SIGTERM)
    time.sleep(0.5)
    proc.send_signal(signal.SIGKILL)
    _, err = proc.communicate(timeout=60)
    deadline = time.monotonic() + 10.0  # the guard's second pass, after the process ended
    while folder.exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    return err, folder, cache


def test_the_guard_cleans_up_while_the_main_thread_is_in_c(tmp_path: Path) -> None:
    err, folder, cache = _terminate_during_a_c_call(tmp_path, use_guard=True)
    assert not folder.exists(), err
    line = "shoulder-fem: error: stopped by SIGTERM: the unfinished output was removed"
    assert err.strip() == line, err
    # the claim made by this run and never marked done is removed, the finished form kept
    assert sorted(p.name for p in cache.iterdir()) == [
        "libffcx_forms_done.c",
        "libffcx_forms_done.c.cached",
    ]


def test_without_the_guard_the_handler_never_runs(tmp_path: Path) -> None:
    # the control case: the same process with only its Python handler is killed in the sort
    err, folder, _ = _terminate_during_a_c_call(tmp_path, use_guard=False)
    if not folder.exists():
        pytest.skip("the sort ended within 0.5 s here: the control case shows nothing")
    assert "removed by the handler" not in err


def test_the_guard_ends_with_the_command_and_does_nothing(tmp_path: Path) -> None:
    from shoulder_fem.cli.stop_guard import StopGuard

    folder = tmp_path / "out.partial-1"
    folder.mkdir()
    previous = signal.signal(signal.SIGTERM, lambda *args: None)
    try:
        guard = StopGuard("stopped", None, time.time())
        guard.update(remove=[str(folder)])
        guard.close()
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert guard.process.returncode == 0
    assert folder.exists()  # not stopped: nothing removed
    assert signal.set_wakeup_fd(-1) == -1  # the wakeup fd was given back
    assert guard.wait_done() is False  # a handler left behind by an ended command falls back
