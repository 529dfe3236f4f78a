"""The decoupled method's operator on a driven body: A0 + ωG + ω²Q + ω̇E about the fixed spin axis.

The floating-frame Jacobian is affine in ω̇ and quadratic in ω (Coriolis in G; spin softening
and stress stiffening in Q; the strained Euler term in E). :class:`RateOperator` assembles the
four parts once per time step size and combines them per step, so a step costs no re-assembly;
the solver's GMRES around the factorization of an earlier operator absorbs the drift.
"""

from __future__ import annotations

from petsc4py import PETSc

from shoulder_fem.engine.solver import NonlinearSolver
from shoulder_fem.families.driven_body.frame import FloatingFrame


class RateOperator:
    """The operator of the current step, from parts assembled once per Δt.

    Args:
        frame: the floating frame (its rates are set to assemble the parts, then put back).
        nominal_dt: the scene's time step (s); Δt is keyed relative to it.
        rate_dependent: whether the operator depends on ω and ω̇ at all (else only on Δt).
    """

    def __init__(self, frame: FloatingFrame, nominal_dt: float, rate_dependent: bool):
        self.frame = frame
        self.nominal_dt = nominal_dt
        self.rate_dependent = rate_dependent
        #: (A0, G, Q, E) by Δt key
        self.parts: dict = {}
        self.dt_key = 1.0
        self.rates = (0.0, 0.0)
        self.current = None

    def fill(self, A: PETSc.Mat) -> None:
        """Write A0 + ωG + ω²Q + ω̇E of the selected step into ``A`` (the solver's callback)."""
        a0, g, q, e = self.parts[self.dt_key]
        rate, rate_dot = self.rates
        a0.copy(A, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
        for coefficient, mat in ((rate, g), (rate**2, q), (rate_dot, e)):
            if coefficient != 0.0:
                A.axpy(coefficient, mat, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)

    def select(self, solver: NonlinearSolver, h: float, rate: float, rate_dot: float) -> None:
        """Make the step of size ``h`` (s) at spin rate ω, ω̇ the solver's operator.

        The operator depends on Δt, ω and ω̇ only (Δt to 1e-9 relative: linspace round-off);
        the solver is told only when that key changes.
        """
        self.dt_key = round(h / self.nominal_dt, 9)
        self.rates = (rate, rate_dot)
        key = (self.dt_key, *self.rates) if self.rate_dependent else (self.dt_key,)
        if key != self.current:
            if self.rate_dependent:
                self.assemble_parts(solver)
            solver.operator_changed()
            self.current = key

    def assemble_parts(self, solver: NonlinearSolver) -> None:
        """Assemble A0, G, Q, E at the selected Δt (J is affine in ω̇ and quadratic in ω)."""
        dt_key = self.dt_key
        if dt_key in self.parts:
            return
        frame = self.frame
        saved = frame.save_rates()

        def jac(rate: float, rate_dot: float):
            frame.set_rate(rate, rate_dot)
            return solver.assemble_jacobian()

        a0, plus, minus, e = jac(0.0, 0.0), jac(1.0, 0.0), jac(-1.0, 0.0), jac(0.0, 1.0)
        same = PETSc.Mat.Structure.SAME_NONZERO_PATTERN
        g = plus.copy()
        g.axpy(-1.0, minus, structure=same)
        g.scale(0.5)  # G = (J(1) − J(−1))/2
        q = plus
        q.axpy(1.0, minus, structure=same)
        q.scale(0.5)
        q.axpy(-1.0, a0, structure=same)  # Q = (J(1) + J(−1))/2 − A0
        e.axpy(-1.0, a0, structure=same)  # E = J(ω̇ = 1) − A0
        minus.destroy()
        self.parts[dt_key] = (a0, g, q, e)
        frame.restore_rates(saved)

    def destroy(self) -> None:
        """Free the assembled parts."""
        for mats in self.parts.values():
            for mat in mats:
                mat.destroy()
