"""The compliant decoupling (``part1_bones = compliant``): part 1 sees the bones' compliance.

The paper's part 1 takes the bones as rigid, so the joint and the muscles meet the bones where
rigid ones would be. The elastic scapula is not quite there: its glenoid, the muscles' origins
and its springs' attachments move by part 2's floating-frame displacement ``o``, and the
coupled method sees that; so does the humerus's head under the joint's pressure. It is the
decoupling's own modelling error (it falls as 1/E of the bones; with the whole model, up to
0.8 % on the muscle forces and 1.4-2.8 % on the peak pressure,
``benchmarks/results/compliant_decoupling.json``).

The correction, after the rigid part 1 and its part 2 (whose results stay in the summary as
the ``uncorrected_`` series, probes and arrays):

1. The humerus alone, linear elastic in its floating frame, under part 1's loads on it at
   each output angle (:mod:`.humerus`; not with ``compliant-scapula``): its displacement, in
   the frame of the best rigid fit of its nodes, where part 1 ties the humerus.
2. Each output angle's converged part-1 state is solved again, from that state, with the
   scapula's tied nodes (the glenoid cartilage's bone face, the muscles' origins, the cells
   under the muscles' sliding master) and its springs' ends moved by ``o`` in the scapula's
   frame, and the humerus's (the humeral cartilage's bone face, the muscles' insertions, the
   cells under the head's sliding master, its springs) by its own displacement
   (:meth:`RigidSystem.set_tie_offsets`): each rigid body is then the deformed bone moved
   rigidly, balanced about its deformed shape as the coupled bone is. The humeral angle is
   the same (the plate's travel is again the unknown of the angle equation). The static
   equilibrium at an angle does not depend on the way there (hyperelastic tissues,
   frictionless contact), so a few Newton iterations from that angle's state do it; the path
   is not stepped again.
3. Part 2 runs again with these states' forces, each spring's force where part 1 had it
   (its plate's spring then responds to the plate's motion from ``o``), and the couple by
   which ``o`` turns the loads, ``sum o x f``, given back through the inertia relief (part 2
   balances about the reference shape: without it, that couple alone turns the scapula on its
   suspension, and the plates moved twice ``o``). Part 2 then finds ``o`` again at the plates
   (to 0.2 % at coarse).

One pass: a second one changed nothing (measured at medium with the scapula's offsets). The
errors against coupled and the cost at each level: README, "A decoupling that sees the bones'
compliance".
"""

from __future__ import annotations

import copy
import logging
import math
from dataclasses import dataclass, replace

import numpy as np
from mpi4py import MPI
from scipy.spatial import cKDTree

from shoulder_fem.engine.solver import ConvergenceError
from shoulder_fem.families.base import RunContext
from shoulder_fem.families.shoulder.newton import solve_with_fallback
from shoulder_fem.families.shoulder.outputs import UNCORRECTED
from shoulder_fem.families.shoulder.part2 import owned_nodes
from shoulder_fem.families.shoulder.stepping import AngleOutputs, StepLog, output_tolerance
from shoulder_fem.families.shoulder.volume import Keeping, augment
from shoulder_fem.io.results import Recorder

__all__ = ["UNCORRECTED", "NodalValues", "Offsets", "adopt", "correct_part1"]

logger = logging.getLogger(__name__)

#: Newton's absolute tolerance (N) of the correction's solves: each starts from a converged
#: state, a small change away, and converges quadratically, so a tolerance 100 x tighter than
#: the stepping's outputs (:data:`.stepping.OUTPUT_ATOL`) costs at most one more iteration; it
#: keeps the transferred loads in balance to 1e-8 of them at 0 deg too, where they are ten
#: times smaller than at 60 deg (measured at coarse with the humerus offset: 2.8e-8 at 1e-6 N).
CORRECTION_ATOL = 1e-8


class NodalValues:
    """A vector field's values at given nodes of its mesh, in their order, on every rank.

    Args:
        V: The field's space (a 3D vector Lagrange space).
        points: The nodes' coordinates (m, (n, 3)), the same on every rank.
        what: Names the points in the error.

    Raises:
        ValueError: A point that is no node of ``V`` (:func:`.part2.owned_nodes`).
    """

    def __init__(self, V, points: np.ndarray, what: str):
        self.comm = V.mesh.comm
        self.n = len(points)
        self._mine, self._rows = owned_nodes(V, points, what)

    def __call__(self, u) -> np.ndarray:
        """``u``'s values (n, 3) at the points (collective)."""
        out = np.zeros((self.n, 3))
        out[self._mine] = u.x.array.reshape(-1, 3)[self._rows]
        return self.comm.allreduce(out, op=MPI.SUM)


def _lookup(tree: cKDTree, values: np.ndarray, body: str):
    """Callable(X) -> ``values`` at the gathered nodes (``tree``'s points) at X."""

    def at_nodes(X: np.ndarray) -> np.ndarray:
        dist, idx = tree.query(X)
        if len(dist) and dist.max() > 1e-9:
            where = X[int(np.argmax(dist))].tolist()
            raise ValueError(f"part 1 correction: a {body} node not gathered ({where} m)")
        return values[idx]

    return at_nodes


@dataclass
class Offsets:
    """A bone's floating-frame displacement (m) at one output angle, where part 1 needs it.

    The scapula's is part 2's; the humerus's that of :mod:`.humerus` (in the frame of the best
    rigid fit of its nodes).

    Attributes:
        nodes: At part 1's nodes tied to the bone (:meth:`RigidSystem.tied_positions`), (n, 3).
        springs: At each of the bone's spring attachments, by name (the scapula's: its plate's
            translation).
    """

    nodes: np.ndarray
    springs: dict


def adopt(recorder: Recorder, scratch: Recorder, replace_plain: bool) -> None:
    """Keep ``scratch``'s series and probes in ``recorder``.

    ``replace_plain``: ``scratch`` holds the corrected values of series the run already has:
    they take the plain names, the run's go to ``uncorrected_<name>``. Otherwise ``scratch``
    holds the rigid decoupling's: they go to ``uncorrected_<name>``.
    """
    for name, entry in scratch.series.items():
        if replace_plain:
            if name in recorder.series and UNCORRECTED + name not in recorder.series:
                recorder.series[UNCORRECTED + name] = recorder.series[name]
            recorder.series[name] = entry
        else:
            recorder.series[UNCORRECTED + name] = entry
    for name, value in scratch.probes.items():
        if replace_plain:
            if name in recorder.probes:
                unit = recorder.probe_units.get(name)
                recorder.set_probe(UNCORRECTED + name, recorder.probes[name], unit)
            recorder.set_probe(name, value, scratch.probe_units.get(name))
        else:
            recorder.set_probe(UNCORRECTED + name, value, scratch.probe_units.get(name))
    for key, n in scratch.solver_stats.items():
        recorder.count(key, n)


#: The continuation's pieces when the offsets at once do not converge: they are then applied
#: in that many equal increments, each solved from the last.
OFFSET_PIECES = 4


def _scaled(moved: dict, share: float) -> dict:
    """``moved`` with every offset times ``share``."""
    return {
        body: (lambda X, f=at_nodes: share * f(X), {n: share * o for n, o in springs.items()})
        for body, (at_nodes, springs) in moved.items()
    }


def _resolve(part1, k: int, moved: dict, log: StepLog, keeping: Keeping) -> tuple[int, int]:
    """Part 1 from output ``k``'s state with the bones' offsets: (its solve's, the updates') its.

    The updates: the incompressible tissue's multipliers after the solve (:func:`augment`).
    If the offsets at once do not converge, they are applied again from that state in
    :data:`OFFSET_PIECES` increments (a continuation: at ``coarse`` with incompressible
    muscles, whose smallest J is 0.011 at 60 deg, the whole offset stalled at |F| = 3 kN).

    ``moved``: {body: (callable(X) -> offsets at its tied nodes, {spring: offset})}.
    """
    system = part1.system
    snap, target, multipliers = part1.states[k]
    name = f"part1 correction {math.degrees(part1.transfer.angles[k]):.0f} deg"
    for pieces in (1, OFFSET_PIECES):
        system.restore(snap)
        if multipliers is not None:
            part1.volumetric.multiplier[:] = multipliers
        system.control.target = target
        its = 0
        try:
            for j in range(1, pieces + 1):
                for body, (at_nodes, springs) in _scaled(moved, j / pieces).items():
                    system.set_tie_offsets(body, at_nodes, springs)
                step = name if pieces == 1 else f"{name} ({j}/{pieces} of the offsets)"
                its += solve_with_fallback(system, step, system.snapshot(), None, log)
            break
        except ConvergenceError as err:
            if pieces == OFFSET_PIECES:
                raise
            why = err.reason
            logger.warning("%s: %s; the offsets again in %d pieces", name, why, OFFSET_PIECES)
    updates = augment(system, name, keeping)
    part1.contact.commit()
    return its, updates


def correct_part1(
    part1, nodes: dict, offsets: list[dict], run: RunContext
) -> tuple[dict, object, str | None]:
    """Solve part 1 again at each output angle with the bones' offsets (collective).

    Args:
        part1: The rigid part 1 after its :meth:`~.decoupled.Part1.run` (kept alive, with
            its states).
        nodes: Per body (``scapula``, and ``humerus`` if it is offset too), part 1's nodes
            tied to it (m; :meth:`RigidSystem.tied_positions`, gathered): the rows of each of
            its :attr:`Offsets.nodes`.
        offsets: Per output angle, {body: its displacement where part 1 needs it}.
        run: The run's context (its recorder gets the corrected series; the rigid ones become
            ``uncorrected_``).

    Returns:
        (the outputs for ``shoulder.npz``, the corrected transfer, None or why the correction
        stopped before the last angle).
    """
    system, job, rec = part1.system, part1.job, run.recorder
    trees = {body: cKDTree(X) for body, X in nodes.items()}
    # the same points and reference; the lists filled at each corrected output
    lists = ("angles", "forces", "translation", "rotation", "humerus_rotation")
    lists += ("spring_offsets", "point_offsets")
    corrected = replace(part1.transfer, **{name: [] for name in lists})
    record = copy.copy(part1.record)
    record.transfer = corrected
    scratch = Recorder(rec.comm, rec.folder)
    outputs = AngleOutputs(
        part1.model, scratch, replace(job, label="part1_corrected", on_output=record), run.fields
    )
    log = StepLog()
    before = (system.stats.newton_iterations, system.stats.factorizations)
    stop = None
    keeping = Keeping.of(part1.model.params)  # augment does nothing without volumetric terms
    try:
        with output_tolerance(system, CORRECTION_ATOL):  # these are outputs
            for k, by_body in enumerate(offsets):  # one per output state
                deg = math.degrees(part1.transfer.angles[k])
                moved = {
                    body: (_lookup(trees[body], o.nodes, body), o.springs)
                    for body, o in by_body.items()
                }
                try:
                    its, updates = _resolve(part1, k, moved, log, keeping)
                except ConvergenceError as err:
                    stop = f"part 1's correction did not converge at {deg:.0f} deg ({err.reason})"
                    logger.error("%s", stop)
                    break
                corrected.spring_offsets.append(by_body["scapula"].springs)
                corrected.point_offsets.append(moved["scapula"][0](corrected.points))
                scratch.add_series_point("part1_correction_iterations", deg, its, "deg", "1")
                scratch.add_series_point(
                    "part1_correction_volume_iterations", deg, updates, "deg", "1"
                )
                for body, o in by_body.items():
                    move = float(np.linalg.norm(o.nodes, axis=1).max(initial=0.0))
                    name = "part1_correction_offset" + ("" if body == "scapula" else f"_{body}")
                    scratch.add_series_point(name, deg, move, "deg", "m")
                logger.info(
                    "part 1 correction at %.0f deg: %d + %d Newton iterations (multipliers)",
                    deg,
                    its,
                    updates,
                )
                outputs(part1.transfer.angles[k])
    finally:
        outputs.close()
    newton = system.stats.newton_iterations - before[0]
    scratch.set_probe("part1_correction_newton_iterations", newton, "1")
    scratch.set_probe("part1_correction_fallbacks", log.fallbacks, "1")
    rec.count("newton_iterations", newton)
    rec.count("linear_solves", newton)
    rec.count("factorizations", system.stats.factorizations - before[1])
    adopt(rec, scratch, replace_plain=True)
    data = dict(outputs.data)
    return data, corrected, stop
