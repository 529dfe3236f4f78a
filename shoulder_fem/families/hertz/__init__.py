"""The ``hertz`` scene family: an elastic ball pressed on a flat or into a socket, against Hertz.

The verification scene of the contact code (:mod:`shoulder_fem.engine.contact`): Hertz's
solution and the profile fit (:mod:`.theory`), the typed parameters and mesh (:mod:`.model`),
the ball driven by its approach (:mod:`.problem`) and the run (:mod:`.run`).
"""

from shoulder_fem.families.base import Family
from shoulder_fem.families.hertz.model import HertzModel, build, dofs
from shoulder_fem.families.hertz.problem import HertzProblem
from shoulder_fem.families.hertz.run import run_coupled
from shoulder_fem.families.hertz.theory import HertzSolution, hertz_solution

__all__ = ["FAMILY", "HertzModel", "HertzProblem", "HertzSolution", "build", "hertz_solution"]

# One method: there is no rigid motion to split, so "coupled" is the only pipeline.
FAMILY = Family(name="hertz", build=build, methods={"coupled": run_coupled}, dofs=dofs)
