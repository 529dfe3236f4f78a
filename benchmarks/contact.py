"""Benchmark: cost of contact search + contact assembly as a fraction of one Newton iteration.

    OMP_NUM_THREADS=1 python benchmarks/contact.py --out benchmarks/results   # 8k, 27k, 106k DOF
    OMP_NUM_THREADS=1 mpirun -n 2 python benchmarks/contact.py --h 0.041 --variants segments \
        --out benchmarks/results --merge   # adds the 2-rank run under other_runs

Scene: two P1 linear-elastic blocks, lower 1 x 1 x 0.5 m, upper 0.9 x 0.9 x 0.5 m inset by
0.05 m, meshed independently with non-matching sizes (h_upper = 0.77 h_lower), the upper one
pressed on the lower one by a prescribed displacement of its top face; frictionless penalty
contact, slave = upper block's bottom, master = ``MeshSurface(lower block's top)``. Variants:
``segments`` (``mesh_integration="segments"``, the default: slave facets cut along the master
triangles) and ``points`` (``mesh_integration="points"``, ``quadrature_degree=0``: closest-point
projection of the slave facets' vertices).

Three load steps are solved with SNES (Newton, MUMPS LU). The first one widens the FE matrix's
pattern by the contact couplings (``pattern_merges``) and is reported apart; steps 2 and 3 are
the measured, steady state. In every SNES callback the wall time is split with the contact's
own counters (``Contact.stats``: ``search_s`` = evaluation incl. search / segmentation,
``assembly_s`` = residual + tangent assembly incl. the pattern merge). One Newton iteration is
taken as one residual + one Jacobian callback + one linear solve (means per call):

* FE assembly = residual + Jacobian callbacks minus the contact's share;
* linear solve = SNES solve wall time minus the callbacks, per Jacobian (MUMPS factorization +
  solve, and SNES's own vector work);
* contact fraction = (contact search + contact assembly) / that iteration's total.

Per-rank wall times are reduced with the maximum over ranks. Writes ``contact.json`` and
``contact.png`` (rank 0). It asserts nothing: the issue's target (contact < 10 % of a Newton
iteration at >= 100k DOF) is reported as measured.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import time
from pathlib import Path

import dolfinx
import numpy as np
import ufl
from mpi4py import MPI
from petsc4py import PETSc

from shoulder_fem.engine.contact import Contact, ContactPair, MeshSurface
from shoulder_fem.engine.solver import NonlinearSolver
from shoulder_fem.forms import materials
from shoulder_fem.forms import virtual_power as vp
from shoulder_fem.io.output import atomic_write_json
from shoulder_fem.io.resources import ResourceMonitor, blas_library, thread_settings
from shoulder_fem.meshes import contact_bodies as cb

E, NU = 1.0e9, 0.3
LOWER, UPPER = (1.0, 1.0, 0.5), (0.9, 0.9, 0.5)
#: The upper block sits inside the lower one's footprint: with coincident rims the points
#: variant's active set chatters between two states at the rim (Newton never converges).
OFFSET = (0.05, 0.05)
H_RATIO = 0.77  # h_upper / h_lower: non-matching interface meshes
#: h_lower (m) -> about 8k, 27k, 106k DOFs (0.033 m: about 200k, several times the LU time)
DEFAULT_H = (0.1, 0.068, 0.041)
TARGET = 0.10
VARIANTS = {
    "segments": dict(mesh_integration="segments"),  # the defaults
    "points": dict(mesh_integration="points", quadrature_degree=0),
}


def _component_bc(V, ft, tag: int, comp: int, value: float):
    dofs = dolfinx.fem.locate_dofs_topological(V.sub(comp), 2, ft.find(tag))
    const = dolfinx.fem.Constant(V.mesh, PETSc.ScalarType(value))
    return dolfinx.fem.dirichletbc(const, dofs, V.sub(comp)), const


class _Timer:
    """Wraps the solver's SNES callbacks and splits their wall time with Contact.stats."""

    def __init__(self, solver: NonlinearSolver, contact: Contact):
        self.solver, self.contact = solver, contact
        self.reset()
        solver.snes.setFunction(self._residual, solver._b)
        solver.snes.setJacobian(self._jacobian, solver._A, solver._P)

    def reset(self) -> None:
        self.t = {
            f"{kind}_{part}": 0.0
            for kind in ("residual", "jacobian")
            for part in ("s", "search_s", "assembly_s")
        }
        self.calls = {"residual": 0, "jacobian": 0}

    def _wrap(self, kind, fn, *args) -> None:
        st = self.contact.stats
        s0, a0 = st.search_s, st.assembly_s
        t0 = time.perf_counter()
        fn(*args)
        self.t[f"{kind}_s"] += time.perf_counter() - t0
        self.t[f"{kind}_search_s"] += st.search_s - s0
        self.t[f"{kind}_assembly_s"] += st.assembly_s - a0
        self.calls[kind] += 1

    def _residual(self, snes, x, b) -> None:
        self._wrap("residual", self.solver._residual, snes, x, b)

    def _jacobian(self, snes, x, A, P) -> None:
        self._wrap("jacobian", self.solver._jacobian, snes, x, A, P)


def _per_iteration(comm: MPI.Comm, records: list[dict]) -> dict:
    """Time of one Newton iteration = one residual + one Jacobian + one linear solve.

    Means per call over the given load steps (residual and Jacobian callbacks, the linear solve
    per Jacobian); each figure is the maximum over ranks.
    """
    tot = {k: sum(r["t"][k] for r in records) for k in records[0]["t"]}
    n_res = max(sum(r["calls"]["residual"] for r in records), 1)
    n_jac = max(sum(r["calls"]["jacobian"] for r in records), 1)
    linear = sum(r["solve_s"] - r["t"]["residual_s"] - r["t"]["jacobian_s"] for r in records)
    local = np.array(
        [
            tot["residual_search_s"] / n_res + tot["jacobian_search_s"] / n_jac,
            tot["residual_assembly_s"] / n_res + tot["jacobian_assembly_s"] / n_jac,
            (tot["residual_s"] - tot["residual_search_s"] - tot["residual_assembly_s"]) / n_res
            + (tot["jacobian_s"] - tot["jacobian_search_s"] - tot["jacobian_assembly_s"]) / n_jac,
            linear / n_jac,
        ]
    )
    red = np.empty_like(local)
    comm.Allreduce(local, red, op=MPI.MAX)
    search, assembly, fe, solve = (float(v) for v in red)
    total = search + assembly + fe + solve
    return {
        "total": total,
        "contact_search": search,
        "contact_assembly": assembly,
        "contact": search + assembly,
        "fe_assembly": fe,
        "linear_solve": solve,
        "contact_fraction": (search + assembly) / total,
    }


def run_case(comm: MPI.Comm, h: float, variant: str, delta: float, mon, say) -> dict:
    """Build, solve three load steps, return the measured figures (same on every rank)."""
    t0 = time.perf_counter()
    mesh, _, ft = cb.build_two_blocks(comm, LOWER, UPPER, h, H_RATIO * h, offset=OFFSET)
    mesh_s = time.perf_counter() - t0
    V = dolfinx.fem.VectorFunctionSpace(mesh, ("CG", 1))
    u = dolfinx.fem.Function(V)
    w = ufl.TestFunction(V)
    F = vp.internal_power_linear(materials.LinearElastic(E, NU), u, w, ufl.dx(domain=mesh))
    bcs = [
        _component_bc(V, ft, cb.LOWER_BOTTOM.id, 2, 0.0),
        _component_bc(V, ft, cb.LOWER_XMIN.id, 0, 0.0),
        _component_bc(V, ft, cb.LOWER_YMIN.id, 1, 0.0),
        _component_bc(V, ft, cb.UPPER_TOP.id, 2, 0.0),
        _component_bc(V, ft, cb.UPPER_XMIN.id, 0, 0.0),
        _component_bc(V, ft, cb.UPPER_YMIN.id, 1, 0.0),
    ]
    top = bcs[3][1]
    bcs = [b[0] for b in bcs]
    penalty = 1000 * E / (LOWER[2] + UPPER[2])
    pair = ContactPair("interface", (cb.UPPER_BOTTOM.id,), MeshSurface((cb.LOWER_TOP.id,)), penalty)
    t0 = time.perf_counter()
    contact = Contact(V, u, ft, [pair], bcs=bcs, **VARIANTS[variant])
    setup_s = time.perf_counter() - t0
    solver = NonlinearSolver(
        F,
        u,
        bcs,
        name="bench_contact",
        options={"snes_atol": 1e-6, "snes_rtol": 1e-10},
        contact=contact,
    )
    timer = _Timer(solver, contact)
    imap = V.dofmap.index_map
    dofs = 3 * imap.size_global
    steps, records = [], []
    fractions = (1 / 3, 2 / 3, 1.0)
    for k, frac in enumerate(fractions):
        top.value = -frac * delta
        timer.reset()
        merges0 = contact.stats.pattern_merges
        comm.Barrier()
        t0 = time.perf_counter()
        its = solver.solve(f"step {k + 1}")
        rec = {"t": dict(timer.t), "calls": dict(timer.calls), "solve_s": time.perf_counter() - t0}
        records.append(rec)
        per = _per_iteration(comm, [rec])
        step = {
            "step": k + 1,
            "top_displacement_m": -frac * delta,
            "newton_iterations": its,
            "residual_evaluations": rec["calls"]["residual"],
            "jacobian_evaluations": rec["calls"]["jacobian"],
            "pattern_merges": contact.stats.pattern_merges - merges0,
            "solve_s": comm.allreduce(rec["solve_s"], op=MPI.MAX),
            "per_iteration_s": per,
            "contact_fraction": per["contact_fraction"],
        }
        steps.append(step)
        say(
            f"  step {k + 1}: {its} Newton its, {step['solve_s']:.2f} s, contact "
            f"{100 * step['contact_fraction']:.1f} % of an iteration, "
            f"merges {step['pattern_merges']}"
        )
    measured = _per_iteration(comm, records[1:])
    st = contact._state[0]
    n_points = comm.allreduce(len(st["facet"]), op=MPI.SUM)
    n_active = comm.allreduce(int(np.count_nonzero(st["active"])), op=MPI.SUM)
    n_slave = comm.allreduce(len(contact._slaves[0].nodes), op=MPI.SUM)
    n_master = len(contact._masters[0].index)  # gathered on every rank
    force = contact.resultants()["interface"]["force"][2]
    solver.destroy()
    return {
        "label": f"{variant} h={h:g}",
        "variant": variant,
        "h_lower": h,
        "h_upper": H_RATIO * h,
        "dofs": dofs,
        "cells": mesh.topology.index_map(3).size_global,
        "ranks": comm.size,
        "slave_facets": n_slave,
        "master_facets": n_master,
        "interface_facets": n_slave + n_master,
        "contact_points": n_points,
        "active_points": n_active,
        "contact_force_z_n": float(force),
        "mesh_s": mesh_s,
        "contact_setup_s": comm.allreduce(setup_s, op=MPI.MAX),
        "steps": steps,
        "first_step": steps[0],
        "newton_iterations": [s["newton_iterations"] for s in steps],
        "per_iteration_s": measured,
        "contact_fraction": measured["contact_fraction"],
        "pattern_merges": contact.stats.pattern_merges,
        "evaluations": contact.stats.evaluations,
    }


def plot(points: list[dict], path: Path, ranks: int, extra: list[dict] = ()) -> None:
    """Fraction vs DOFs; time per Newton iteration stacked, in seconds and in shares.

    ``extra``: points of runs with another rank count, drawn as stars on the left.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from shoulder_fem.io.plots import save_figure

    fig, (ax1, ax2, ax3) = plt.subplots(1, 3, figsize=(17, 4.8))
    colors = {"segments": "C0", "points": "C2"}
    variants = sorted({p["variant"] for p in points}, key=list(VARIANTS).index)
    for v, marker in zip(variants, "os", strict=False):
        pv = sorted((p for p in points if p["variant"] == v), key=lambda p: p["dofs"])
        dofs = [p["dofs"] for p in pv]
        ax1.plot(
            dofs,
            [100 * p["contact_fraction"] for p in pv],
            marker=marker,
            color=colors[v],
            label=f"{v}, steps 2-3",
        )
        ax1.plot(
            dofs,
            [100 * p["first_step"]["contact_fraction"] for p in pv],
            marker=marker,
            color=colors[v],
            ls=":",
            alpha=0.5,
            label=f"{v}, step 1",
        )
    for p in extra:
        ax1.plot(
            p["dofs"],
            100 * p["contact_fraction"],
            marker="*",
            ms=14,
            ls="none",
            color=colors[p["variant"]],
            mec="k",
            label=f"{p['variant']}, {p['ranks']} MPI ranks, steps 2-3",
        )
    ax1.axhline(100 * TARGET, color="k", ls="--", lw=1, label="target 10 %")
    ax1.axvline(1e5, color="0.6", lw=0.8)
    ax1.set_xscale("log")
    ax1.set_xlabel("DOFs")
    ax1.set_ylabel("contact search + assembly / Newton iteration [%]")
    ax1.set_ylim(bottom=0)
    ax1.grid(True, which="both", alpha=0.3)
    ax1.legend(fontsize=7)
    ax1.set_title(f"contact share of one Newton iteration ({ranks} rank(s))", fontsize=10)

    order = sorted(points, key=lambda p: (list(VARIANTS).index(p["variant"]), p["dofs"]))
    parts = [
        ("fe_assembly", "FE assembly", "C0"),
        ("linear_solve", "linear solve (MUMPS LU)", "0.6"),
        ("contact_search", "contact search / evaluation", "C3"),
        ("contact_assembly", "contact assembly", "C1"),
    ]
    x = np.arange(len(order))
    labels = [f"{p['variant']}\n{p['dofs'] / 1e3:.0f}k" for p in order]
    totals = np.array([p["per_iteration_s"]["total"] for p in order])
    for ax, scale in ((ax2, np.ones(len(order))), (ax3, 100 / totals)):
        bottom = np.zeros(len(order))
        for key, name, color in parts:
            vals = np.array([p["per_iteration_s"][key] for p in order]) * scale
            ax.bar(x, vals, bottom=bottom, color=color, label=name)
            bottom += vals
        ax.set_xticks(x)
        ax.set_xticklabels(labels, fontsize=8)
    for xi, p, t in zip(x, order, totals, strict=True):
        ax2.text(xi, t, f"{t:.2f} s", ha="center", va="bottom", fontsize=7)
        ax3.text(
            xi, 101, f"{100 * p['contact_fraction']:.0f}%", ha="center", va="bottom", fontsize=7
        )
    ax2.set_ylabel("wall time per Newton iteration [s]")
    ax2.set_ylim(0, 1.35 * totals.max())  # room for the legend
    ax2.set_title("time per Newton iteration (steps 2-3), stacked", fontsize=10)
    ax2.legend(fontsize=7)
    ax3.axhline(100 * (1 - TARGET), color="k", ls="--", lw=1)
    ax3.set_ylim(0, 110)
    ax3.set_ylabel("share of one Newton iteration [%]")
    ax3.set_title("shares (contact % on top; dashed: contact target)", fontsize=10)
    save_figure(fig, path)


def main(argv: list[str] | None = None) -> int:
    """Run the sweep; rank 0 writes the JSON and the chart."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--h", type=float, nargs="+", default=list(DEFAULT_H), help="h_lower, m")
    parser.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    parser.add_argument("--delta", type=float, default=1e-3, help="top displacement, m")
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results"))
    parser.add_argument("--name", default="contact", help="output file stem")
    parser.add_argument(
        "--merge",
        action="store_true",
        help="keep the runs with other rank counts already in the JSON (under other_runs); a "
        "run with a different rank count than the file's main one is added there",
    )
    args = parser.parse_args(argv)
    comm = MPI.COMM_WORLD
    logging.basicConfig(level=logging.WARNING)

    def say(text: str) -> None:
        if comm.rank == 0:
            print(text, flush=True)

    say(f"BLAS: {blas_library()}")
    say(f"threads: {thread_settings()}, MPI ranks: {comm.size}")
    mon = ResourceMonitor(comm)
    points = []
    for h in args.h:
        for variant in args.variants:
            say(f"{variant} h_lower={h:g}:")
            with mon.stage(f"{variant} h={h:g}"):
                points.append(run_case(comm, h, variant, args.delta, mon, say))
    resources = mon.finish(args.out if comm.rank == 0 else Path("."))
    for p, stage in zip(points, mon.stages, strict=True):
        p["peak_rss_mb"] = stage["peak_rss_mb"]
    big = [p for p in points if p["dofs"] >= 100_000]
    record = {
        "benchmark": "contact",
        "scene": {
            "lower": LOWER,
            "upper": UPPER,
            "h_ratio_upper_lower": H_RATIO,
            "youngs_modulus": E,
            "poisson_ratio": NU,
            "top_displacement_m": args.delta,
            "upper_offset": OFFSET,
            "load_steps": [args.delta / 3, 2 * args.delta / 3, args.delta],
            "penalty": "1000 E / H",
            "friction": 0.0,
            "slave": "upper_bottom",
            "master": "MeshSurface(lower_top)",
            "element": "P1 tetrahedra",
            "linear_solver": "MUMPS LU (preonly)",
        },
        "definitions": {
            "per_iteration_s": "one residual + one Jacobian callback + one linear solve: mean "
            "per call over load steps 2 and 3 (step 1 holds the pattern merges); max over ranks",
            "contact_search": "Contact.stats.search_s (evaluation incl. search/segmentation)",
            "contact_assembly": "Contact.stats.assembly_s (residual + tangent + pattern merge)",
            "fe_assembly": "residual + Jacobian callbacks minus the contact's share",
            "linear_solve": "SNES wall time minus the callbacks, per Jacobian (MUMPS LU + solve)",
            "contact_fraction": "(contact_search + contact_assembly) / total",
            "peak_rss_mb": "peak resident memory during the case, summed over ranks "
            "(ResourceMonitor stage; memory kept from an earlier case counts in)",
            "contact_force_z_n": "resultant contact force at the last step (N)",
        },
        "target_fraction": TARGET,
        "blas": blas_library(),
        "threads": thread_settings(),
        "ranks": comm.size,
        "load_average_1_5_15min_at_end": list(os.getloadavg()),
        "resources": resources,
        "points": points,
        "at_least_100k_dofs": [
            {
                "variant": p["variant"],
                "dofs": p["dofs"],
                "contact_fraction": p["contact_fraction"],
                "meets_target": p["contact_fraction"] < TARGET,
            }
            for p in big
        ],
    }
    if comm.rank == 0:
        args.out.mkdir(parents=True, exist_ok=True)
        path = args.out / f"{args.name}.json"
        if args.merge and path.exists():
            old = json.loads(path.read_text())
            others = old.pop("other_runs", {})
            if old.get("ranks") == comm.size:
                record["other_runs"] = others
            else:
                others[f"ranks={comm.size}"] = record
                old["other_runs"] = others
                record = old
        atomic_write_json(path, record)
        extra = [p for run in record.get("other_runs", {}).values() for p in run["points"]]
        plot(record["points"], args.out / f"{args.name}.png", record["ranks"], extra)
        head = (
            f"{'variant':9s} {'DOFs':>7s} {'facets s/m':>11s} {'points':>7s} {'its':>9s} "
            f"{'total':>7s} {'search':>7s} {'c.asm':>7s} {'FE asm':>7s} {'solve':>7s} "
            f"{'frac':>6s} {'1st':>6s} {'MB':>6s}"
        )
        print(head)
        for p in points:
            t = p["per_iteration_s"]
            print(
                f"{p['variant']:9s} {p['dofs']:7d} {p['slave_facets']:5d}/{p['master_facets']:<5d} "
                f"{p['contact_points']:7d} {str(p['newton_iterations']):>9s} {t['total']:7.3f} "
                f"{t['contact_search']:7.3f} {t['contact_assembly']:7.3f} "
                f"{t['fe_assembly']:7.3f} {t['linear_solve']:7.3f} "
                f"{100 * p['contact_fraction']:5.1f}% "
                f"{100 * p['first_step']['contact_fraction']:5.1f}% {p['peak_rss_mb']:6.0f}"
            )
        print(f"wrote {args.out / (args.name + '.json')} and {args.out / (args.name + '.png')}")
    comm.Barrier()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
