"""The ``shoulder`` family: the paper's glenohumeral internal rotation, coupled and decoupled."""

from shoulder_fem.families.base import Family
from shoulder_fem.families.shoulder.coupled import run_coupled
from shoulder_fem.families.shoulder.decoupled import run_decoupled
from shoulder_fem.families.shoulder.model import (
    ShoulderModel,
    build,
    check_bench,
    dofs,
    resolve,
)
from shoulder_fem.families.shoulder.report import bench_report

__all__ = ["FAMILY", "ShoulderModel"]

FAMILY = Family(
    name="shoulder",
    build=build,
    methods={"coupled": run_coupled, "decoupled": run_decoupled},
    dofs=dofs,
    report=bench_report,
    check_bench=check_bench,
    resolve=resolve,
)
