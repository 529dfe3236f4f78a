"""Arguments shared by the scene commands (run, bench, mesh)."""

from __future__ import annotations

import argparse
from pathlib import Path

from shoulder_fem.scene import LEVELS


def add_scene_arguments(p: argparse.ArgumentParser, example: str = "spin_rate=600rpm") -> None:
    """``--level`` and ``--set KEY=VALUE`` (repeatable), shared by every scene command."""
    p.add_argument(
        "--level",
        choices=list(LEVELS),
        default=None,
        help="mesh level (default: the scene's)",
    )
    p.add_argument(
        "--set",
        dest="sets",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help=f"override a scene parameter (SI, or with a unit: {example})",
    )


def add_run_arguments(p: argparse.ArgumentParser) -> None:
    """The scene arguments plus ``--out`` and ``--linear-solver`` (run, bench)."""
    add_scene_arguments(p)
    p.add_argument("--out", type=Path, required=True, help="output folder (written atomically)")
    p.add_argument(
        "--linear-solver",
        choices=["direct", "iterative"],
        default="direct",
        help="MUMPS LU (default) or CG + GAMG with rigid-body near-nullspace",
    )
