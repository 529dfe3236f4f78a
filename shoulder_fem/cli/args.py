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


def add_out_arguments(p: argparse.ArgumentParser, what: str = "output folder") -> None:
    """``--out`` and ``--force`` (every command that writes a folder)."""
    p.add_argument("--out", type=Path, required=True, help=f"{what} (written atomically)")
    p.add_argument(
        "--force", action="store_true", help="replace a previous result in --out (else refused)"
    )


def add_run_arguments(p: argparse.ArgumentParser) -> None:
    """The scene arguments plus ``--out``, ``--force`` and the solver's (run, bench)."""
    add_scene_arguments(p)
    add_out_arguments(p)
    p.add_argument(
        "--linear-solver",
        choices=["direct", "iterative"],
        default=None,
        help="every solver of the run with MUMPS LU, or CG + GAMG with the rigid-body "
        "near-nullspace (default: each solver's own choice, LU unless the scene asks "
        "otherwise, e.g. the shoulder's part2_solver)",
    )
    p.add_argument(
        "--petsc",
        dest="petsc",
        action="append",
        default=[],
        metavar="KEY[=VALUE]",
        help="a PETSc option for every solver of the run, under its prefix "
        "(e.g. snes_monitor, ksp_view, mat_mumps_icntl_14=50; with its dash: "
        "--petsc=-snes_monitor); repeatable; one that no solver reads is a warning",
    )


def petsc_options(items: list[str]) -> dict[str, str]:
    """``--petsc`` items as a dict (key without its dash; a key alone has the value '')."""
    from shoulder_fem.scene import SceneError

    out = {}
    for item in items:
        key, _, value = item.partition("=")
        key = key.strip().lstrip("-")
        if not key or any(c.isspace() for c in key):
            raise SceneError(f"--petsc {item!r}: expected KEY or KEY=VALUE (e.g. snes_monitor)")
        out[key] = value.strip()
    return out
