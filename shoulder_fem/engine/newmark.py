"""The Newmark time rule of the driven body's methods (and of the tumbling body's part 2).

Owns the rule's parameters for a numerical damping δ and the state it carries from step to step
(displacement, velocity, acceleration): as UFL expressions of the unknown for the residual, and
as array updates once a step has converged.
"""

from __future__ import annotations

import dolfinx
import numpy as np


def newmark_parameters(damping: float) -> tuple[float, float]:
    """Newmark (β, γ) for a numerical damping δ = γ − 1/2 ≥ 0, with β = (γ + 1/2)²/4.

    δ = 0 is the average-acceleration (trapezoidal) rule: second order, no numerical
    dissipation, unconditionally stable for linear problems — but not energy-stable for stiff
    nonlinear elastodynamics, where unresolved axial–bending modes can pump energy until Newton
    fails (a slender spinning beam does this). δ > 0 damps the high frequencies (the β above is
    the choice with the most high-frequency dissipation); the scheme is then first order, with a
    damping ratio ≈ δ ω Δt / 2 on a mode of frequency ω.
    """
    if not damping >= 0.0:
        raise ValueError(f"numerical_damping = {damping}: must be >= 0")
    gamma = 0.5 + damping
    return (gamma + 0.5) ** 2 / 4.0, gamma


class NewmarkState:
    """The unknown displacement and the last step's state of the Newmark rule.

    ``u`` is the unknown of the step; ``u_n, v_n, a_n`` the displacement, velocity and
    acceleration at the start of the step. :meth:`acceleration` and :meth:`velocity` are the
    rule's end-of-step values as UFL expressions of ``u`` (for the residual); :meth:`advance`
    applies the same rule to the arrays once the step has converged.
    """

    def __init__(self, V: dolfinx.fem.FunctionSpace, name: str, damping: float = 0.0):
        self.beta, self.gamma = newmark_parameters(damping)
        self.u = dolfinx.fem.Function(V, name=name)
        self.u_n, self.v_n, self.a_n = (dolfinx.fem.Function(V) for _ in range(3))

    def acceleration(self, dt):
        """a_{n+1} = (u − u_n − Δt v_n)/(βΔt²) − (1/(2β) − 1) a_n (UFL, ``dt`` a Constant)."""
        beta = self.beta
        return (self.u - self.u_n - dt * self.v_n) / (beta * dt**2) - (
            1.0 / (2 * beta) - 1.0
        ) * self.a_n

    def velocity(self, dt):
        """v_{n+1} = v_n + Δt((1 − γ) a_n + γ a_{n+1}) (UFL)."""
        gamma = self.gamma
        return self.v_n + dt * ((1 - gamma) * self.a_n + gamma * self.acceleration(dt))

    def advance(self, h: float, dynamic: bool = True) -> None:
        """Make the converged ``u`` the start of the next step (Δt = ``h`` s)."""
        beta, gamma = self.beta, self.gamma
        u, u_n, v_n, a_n = (f.x.array for f in (self.u, self.u_n, self.v_n, self.a_n))
        if dynamic:
            a_next = (u - u_n - h * v_n) / (beta * h**2) - (1.0 / (2 * beta) - 1.0) * a_n
            v_n[:] += h * ((1 - gamma) * a_n + gamma * a_next)
            a_n[:] = a_next
        u_n[:] = u

    def save(self) -> list[np.ndarray]:
        """A snapshot of the four arrays (for a step cut-back)."""
        return [f.x.array.copy() for f in (self.u, self.u_n, self.v_n, self.a_n)]

    def restore(self, snapshot: list[np.ndarray]) -> None:
        """Put a :meth:`save` snapshot back."""
        for f, arr in zip((self.u, self.u_n, self.v_n, self.a_n), snapshot, strict=True):
            f.x.array[:] = arr
