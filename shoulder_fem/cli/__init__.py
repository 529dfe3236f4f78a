"""The ``shoulder-fem`` command line (``main(argv) -> int``)."""

from shoulder_fem.cli.main import (
    EXIT_INPUT,
    EXIT_INTERRUPTED,
    EXIT_SOLVER,
    EXIT_TERMINATED,
    build_parser,
    main,
    setup_logging,
)

__all__ = [
    "EXIT_INPUT",
    "EXIT_INTERRUPTED",
    "EXIT_SOLVER",
    "EXIT_TERMINATED",
    "build_parser",
    "main",
    "setup_logging",
]
