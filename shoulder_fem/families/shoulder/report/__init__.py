"""The shoulder study's report: the decoupled run against the coupled one, the paper's figures.

Pure post-processing of two finished run folders (rank 0 only, no dolfinx, no MPI). The modules:
:mod:`.data` reads a run, :mod:`.geometry` projects, cuts and pairs points, :mod:`.metrics`
compares, :mod:`.figures` draws, :mod:`.tables` writes text, :mod:`.writer` puts them together.
"""

from shoulder_fem.families.shoulder.report.contents import FIGURES, TIME_SPLIT
from shoulder_fem.families.shoulder.report.data import RunData, load_run
from shoulder_fem.families.shoulder.report.geometry import (
    MATCH_TOLERANCE,
    glenoid_plane_coordinates,
    match_points,
    slice_tetrahedra,
)
from shoulder_fem.families.shoulder.report.tables import comparison_table
from shoulder_fem.families.shoulder.report.writer import bench_report, write_report

__all__ = [
    "FIGURES",
    "MATCH_TOLERANCE",
    "TIME_SPLIT",
    "RunData",
    "bench_report",
    "comparison_table",
    "glenoid_plane_coordinates",
    "load_run",
    "match_points",
    "slice_tetrahedra",
    "write_report",
]
