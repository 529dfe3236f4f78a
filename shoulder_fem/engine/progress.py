"""Progress of a long run on the terminal: a bar with the time left, on rank 0 only.

A bar (tqdm) appears only when rank 0's standard error is a terminal (not in a batch job's log
file, a pipe or a test) and ``SHOULDER_FEM_PROGRESS`` is not ``off``; it is removed when done.
"""

from __future__ import annotations

import os
import sys

from mpi4py import MPI

__all__ = ["Progress"]


class Progress:
    """How far a run has got between ``start`` and ``end`` (in ``unit``), with the time left.

    Args:
        start: Where the run starts (e.g. its first time, s, or angle, deg).
        end: Where it ends.
        label: What advances ("time", "angle").
        unit: Its unit.
    """

    def __init__(self, start: float, end: float, label: str, unit: str) -> None:
        self.start = float(start)
        self.bar = None
        shown = os.environ.get("SHOULDER_FEM_PROGRESS", "auto") != "off"
        if shown and MPI.COMM_WORLD.rank == 0 and sys.stderr.isatty():
            from tqdm import tqdm

            self.bar = tqdm(
                total=float(end) - self.start,
                desc=label,
                unit=unit,
                leave=False,
                ncols=100,
                bar_format="{desc} {percentage:3.0f}%|{bar}| {n:.4g}/{total:.4g} "
                + unit
                + " [{elapsed} elapsed, {remaining} left]",
            )

    def to(self, value: float) -> None:
        """The run has reached ``value``."""
        if self.bar is not None:
            self.bar.n = min(float(value) - self.start, self.bar.total)
            self.bar.refresh()

    def close(self) -> None:
        """Remove the bar."""
        if self.bar is not None:
            self.bar.close()
            self.bar = None

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
