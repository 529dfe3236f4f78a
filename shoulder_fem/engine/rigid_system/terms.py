"""The rigid rows of the reduced system: tie loads, springs, inertia, applied loads.

Functions of the bodies' current state (numpy; the only collectives are the sums over ranks of
tie loads and of spring ends on FE nodes), apart from the SNES driver so that each term reads
as the formula it implements.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import dolfinx
import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from shoulder_fem.engine.rigid_system.bodies import RigidBody
from shoulder_fem.engine.so3 import hat, hats, right_jacobian
from shoulder_fem.engine.springs import Spring, spring_response

__all__ = [
    "RigidTerms",
    "SpringEnd",
    "d_jr_times",
    "end_states",
    "external_loads",
    "inertia_terms",
    "left_jacobian",
    "rigid_terms",
    "spring_load_on",
    "spring_terms",
    "tie_loads",
]


def left_jacobian(phi: np.ndarray) -> np.ndarray:
    """Left Jacobian of SO(3), ``exp(hat(φ + δ)) ≈ exp(hat(J_l δ)) exp(hat φ)``."""
    return right_jacobian(-np.asarray(phi, dtype=float))


def d_jr_times(phi: np.ndarray, m: np.ndarray) -> np.ndarray:
    """∂(J_r(φ) m)/∂φ for a fixed vector m: (3, 3).

    J_r m = m - b φ×m + c φ×(φ×m), b = (1 - cos θ)/θ², c = (θ - sin θ)/θ³, θ = |φ|, so
    ∂/∂φ = b hat(m) - (φ×m)(b'/θ) φᵀ + c((φ·m) I + φ mᵀ - 2 m φᵀ) + (φ×(φ×m))(c'/θ) φᵀ.
    Below θ = 1e-3 the coefficients come from their Taylor series (error < 1e-16).
    """
    theta = float(np.linalg.norm(phi))
    t2 = theta * theta
    if theta < 1e-3:
        b = 0.5 - t2 / 24.0 + t2 * t2 / 720.0
        c = 1.0 / 6.0 - t2 / 120.0 + t2 * t2 / 5040.0
        db = -1.0 / 12.0 + t2 / 180.0
        dc = -1.0 / 60.0 + t2 / 1260.0
    else:
        s, co = math.sin(theta), math.cos(theta)
        b = (1.0 - co) / t2
        c = (theta - s) / theta**3
        db = (theta * s - 2.0 * (1.0 - co)) / theta**4
        dc = (1.0 - co) / theta**4 - 3.0 * (theta - s) / theta**5
    pm = np.cross(phi, m)
    ppm = np.cross(phi, pm)
    return (
        b * hat(m)
        - db * np.outer(pm, phi)
        + c * (float(phi @ m) * np.eye(3) + np.outer(phi, m) - 2.0 * np.outer(m, phi))
        + dc * np.outer(ppm, phi)
    )


class SpringEnd(NamedTuple):
    """One end of a spring, resolved to the system's DOFs (the same on every rank).

    Attributes:
        kind: ``"ground"``, ``"rigid"`` (a rigid body, or an FE node tied to one) or ``"node"``
            (a free FE node).
        body: Index of the rigid body (``"rigid"``), else -1.
        point: Reference position of the end (m).
        owner: Rank owning the free node (``"node"``), else -1.
        node: Local index of the free node on ``owner`` (``"node"``), else -1.
        col0: Global reduced index of the free node's x DOF (``"node"``), else -1.
    """

    kind: str
    body: int
    point: np.ndarray
    owner: int
    node: int
    col0: int


def end_states(
    ends: Sequence[SpringEnd],
    bodies: Sequence[RigidBody],
    u: dolfinx.fem.Function | None,
    comm: MPI.Comm,
) -> list[tuple[np.ndarray, np.ndarray]]:
    """(current position m, lever ρ = R(P - X_ref) m) of every spring end (collective)."""
    node_u = np.zeros((len(ends), 3))
    for i, (kind, _, _, owner, k, _) in enumerate(ends):
        if kind == "node" and comm.rank == owner:
            node_u[i] = u.x.array.reshape(-1, 3)[k]
    if any(e[0] == "node" for e in ends):
        node_u = comm.allreduce(node_u, op=MPI.SUM)
    states = []
    for i, (kind, b, point, *_) in enumerate(ends):
        if kind == "rigid":
            body = bodies[b]
            lever = body.rotation @ (point - body.reference_point)
            states.append((body.position(point), lever))
        elif kind == "node":
            states.append((point + node_u[i], np.zeros(3)))
        else:
            states.append((point, np.zeros(3)))
    return states


def tie_loads(
    bodies: Sequence[RigidBody],
    X: np.ndarray | None,
    tied_owned: Sequence[np.ndarray],
    F: PETSc.Vec | None,
    comm: MPI.Comm,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per body: Σ f_i (N), Σ r_i × f_i (N·m) and G = Σ hat(f_i) hat(r_i) (collective).

    Args:
        bodies: The rigid bodies (current rotations).
        X: The body points the local FE nodes are tied at (m; their reference coordinates
            unless offset); ``None`` without an FE part.
        tied_owned: Per body, the owned local nodes tied to it.
        F: The assembled FE residual (N) at the nodes, f_i; ``None`` without an FE part.
        comm: Communicator of the sums.
    """
    nb = len(bodies)
    local = np.zeros((nb, 15))
    if F is not None:
        f_all = F.array_r.reshape(-1, 3)
        for b, owned in enumerate(tied_owned):
            body = bodies[b]
            f = f_all[owned]
            r = (X[owned] - body.reference_point) @ body.rotation.T
            G = np.einsum("nij,njk->ik", hats(f), hats(r))
            local[b] = np.r_[f.sum(axis=0), np.cross(r, f).sum(axis=0), G.ravel()]
    total = comm.allreduce(local, op=MPI.SUM)
    return total[:, :3], total[:, 3:6], total[:, 6:].reshape(nb, 3, 3)


def spring_terms(
    springs: Sequence[Spring],
    ends: Sequence[SpringEnd],
    states: Sequence[tuple[np.ndarray, np.ndarray]],
    nb: int,
) -> tuple[np.ndarray, np.ndarray, list, list]:
    """Springs' residual and tangent in spatial rigid coordinates (t, θ).

    Spring j has the ends ``2j`` and ``2j + 1`` of ``ends`` and ``states`` (:func:`end_states`);
    ``nb`` is the number of rigid bodies.

    Returns the rigid residual (6 per body), the rigid-rigid tangent (6nb × 6nb), the
    residual blocks of free FE nodes ``[(end index, vector3)]`` and the tangent blocks
    touching them ``[(row end, col end, block)]`` where an end is a spring-end index and a
    rigid side is still in (t, θ) coordinates.
    """
    res = np.zeros(6 * nb)
    tan = np.zeros((6 * nb, 6 * nb))
    node_res, node_tan = [], []
    for j, spring in enumerate(springs):
        ia, ib = 2 * j, 2 * j + 1
        resp = spring_response(spring, states[ia][0], states[ib][0])
        g, kt = resp.gradient, resp.tangent
        maps = []  # (end index, kind, body, sign * B)
        for i, sign in ((ia, 1.0), (ib, -1.0)):
            kind, b = ends[i][0], ends[i][1]
            if kind == "rigid":
                rho = states[i][1]
                B = np.hstack([np.eye(3), -hat(rho)])
                res[6 * b : 6 * b + 6] += sign * (B.T @ g)
                tan[6 * b + 3 : 6 * b + 6, 6 * b + 3 : 6 * b + 6] += sign * hat(g) @ hat(rho)
                maps.append((i, kind, b, sign * B))
            elif kind == "node":
                node_res.append((i, sign * g))
                maps.append((i, kind, -1, sign * np.eye(3)))
        for i, kind_i, b, Bi in maps:
            for k, kind_k, c, Bk in maps:
                block = Bi.T @ kt @ Bk
                if kind_i == "rigid" and kind_k == "rigid":
                    tan[6 * b : 6 * b + 6, 6 * c : 6 * c + 6] += block
                else:
                    node_tan.append((i, k, block))
    return res, tan, node_res, node_tan


def spring_load_on(
    b: int,
    springs: Sequence[Spring],
    ends: Sequence[SpringEnd],
    states: Sequence[tuple[np.ndarray, np.ndarray]],
) -> tuple[np.ndarray, np.ndarray]:
    """Force (N) and moment about the current reference point (N·m) of the springs on body b."""
    spring_f, spring_m = np.zeros(3), np.zeros(3)
    for j, spring in enumerate(springs):
        ia, ib = 2 * j, 2 * j + 1
        gradient = spring_response(spring, states[ia][0], states[ib][0]).gradient
        for i, sign in ((ia, -1.0), (ib, 1.0)):
            if ends[i][0] == "rigid" and ends[i][1] == b:
                spring_f += sign * gradient
                spring_m += np.cross(states[i][1], sign * gradient)
    return spring_f, spring_m


def inertia_terms(
    body: RigidBody,
    h: float,
    start: tuple,
    loads: np.ndarray,
    phi: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Inertia rows of a body during a dynamic step of ``h`` (s) and their derivative.

    ``start`` is the body's ``(x_G, v, R, Ω, L)`` at the step's start, ``loads`` its external
    force and moment about G there (2, 3), ``phi`` its rotation increment φ.
    Returns ``(f_I, m_I + ρ × f_I)`` (spatial rows, N and N·m about the reference point,
    see :class:`shoulder_fem.engine.rigid_system.dynamics.StepState`) and its exact derivative
    with respect to (t, φ), (6, 6): with δθ = J_l(φ) δφ the spatial rotation increment,
    δρ = δθ × ρ, δθ_body = R_nᵀ δφ,

        ∂f_I/∂t = k I,   ∂f_I/∂φ = -k hat(ρ) J_l,                       k = 4m/h²
        ∂m_I/∂φ = (2/h)(-hat(R_{n+1} w) J_l + (2/h) R_{n+1} I_G R_nᵀ),    w = I_G (2θ/h - Ω_n)
        ∂(ρ × f_I)/∂(t, φ) = hat(ρ) ∂f_I - hat(f_I) ∂ρ,                 ∂ρ/∂φ = -hat(ρ) J_l.
    """
    xg_n, v_n, R_n, w_n, L_n = start
    F_n, M_n = loads
    R = body.rotation
    rho = R @ (body.centre - body.reference_point)
    xg = body.reference_point + body.translation + rho
    theta = R_n.T @ phi
    k = 4.0 * body.mass / (h * h)
    f = k * (xg - xg_n - h * v_n) - F_n
    Rw = R @ (body.inertia @ ((2.0 / h) * theta - w_n))
    m = (2.0 / h) * (Rw - L_n) - M_n
    jl = left_jacobian(phi)
    H = hat(rho)
    D = np.zeros((6, 6))
    D[:3, :3] = k * np.eye(3)
    D[:3, 3:] = -k * H @ jl
    D[3:, :3] = k * H
    D[3:, 3:] = (
        (2.0 / h) * (-hat(Rw) @ jl + (2.0 / h) * R @ body.inertia @ R_n.T)
        - k * H @ H @ jl
        + hat(f) @ H @ jl
    )
    return np.r_[f, m + np.cross(rho, f)], D


@dataclass
class RigidTerms:
    """The reduced rigid rows (:func:`rigid_terms`).

    Attributes:
        residual: Reduced residual of the rigid DOFs, 6 per body (N; N·m), in (t, φ).
        tangent: Its derivative with respect to (t, φ), (6nb, 6nb).
        node_residual: Spring residual blocks on free FE nodes ``[(end index, vector3)]`` (N).
        node_tangent: Spring tangent blocks touching free FE nodes ``[(row end, col end,
            block)]``, a rigid side still in (t, θ) coordinates.
        T: ``diag(I, J_l(φ))`` per body, (6nb, 6nb): maps (t, φ) increments to (t, θ).
    """

    residual: np.ndarray
    tangent: np.ndarray
    node_residual: list
    node_tangent: list
    T: np.ndarray


def rigid_terms(
    bodies: Sequence[RigidBody],
    springs: tuple[np.ndarray, np.ndarray, list, list],
    tie_m: np.ndarray,
    G: np.ndarray,
    inertia: Mapping[int, tuple[np.ndarray, np.ndarray]],
    phi: np.ndarray,
    linear_ties: bool,
) -> RigidTerms:
    """Reduced residual and tangent of springs, loads, inertia and the ties' rotation terms (φ).

    The reduced residual is ``r = Pᵀ F + r_rigid`` (F the FE residual, N, assembled without
    boundary conditions); this returns ``r_rigid``, for body b ``-(applied force) +
    Σ_springs dE/dt`` and ``J_lᵀ (-(applied moment) + Σ_springs dE/dθ)`` (plus the inertia rows
    during a dynamic step). Body b's rows of r say that the tie forces, springs and loads on b
    balance: ``Σ f_i - F_springs - F_applied = 0`` and ``Σ r_i × f_i - M_springs - M_applied =
    0``. The tangent holds ``Tᵀ (K_springs + G_ties) T`` with ``T = diag(I, J_l(φ))``, where
    ``r_i`` turns with the body, δ(r_i × f_i) = (δθ × r_i) × f_i = hat(f_i) hat(r_i) δθ, so

        G_θθ = Σ_i hat(f_i) hat(r_i)      (not symmetric away from equilibrium),

    plus the inertia rows' derivative and, on the (φ, φ) block, ``∂(J_l(φ)ᵀ m)/∂φ`` with m the
    body's whole spatial moment residual (ties, springs, loads): it vanishes at equilibrium, but
    keeping it makes the tangent the exact derivative of the reduced residual everywhere (the
    Taylor test passes at any state, tested).

    Args:
        bodies: The rigid bodies (applied ``force`` and ``moment``).
        springs: :func:`spring_terms` at the current state (its arrays are updated in place).
        tie_m: Per body Σ r_i × f_i (N·m), (nb, 3) (:func:`tie_loads`).
        G: Per body Σ hat(f_i) hat(r_i) (N·m), (nb, 3, 3).
        inertia: Per inertial body during a dynamic step, :func:`inertia_terms`.
        phi: The bodies' rotation increments φ (nb, 3) (rad).
        linear_ties: Small-rotation ties (T = I, no ∂J_l term).
    """
    nb = len(bodies)
    res, tan, node_res, node_tan = springs
    T = np.zeros((6 * nb, 6 * nb))
    moments = np.zeros((nb, 3))
    inertia_tangents = {}
    for b, body in enumerate(bodies):
        res[6 * b : 6 * b + 3] -= body.force
        res[6 * b + 3 : 6 * b + 6] -= body.moment
        if b in inertia:
            r_inertia, inertia_tangents[b] = inertia[b]
            res[6 * b : 6 * b + 6] += r_inertia
        moments[b] = res[6 * b + 3 : 6 * b + 6] + tie_m[b]
        tan[6 * b + 3 : 6 * b + 6, 6 * b + 3 : 6 * b + 6] += G[b]
        T[6 * b : 6 * b + 3, 6 * b : 6 * b + 3] = np.eye(3)
        T[6 * b + 3 : 6 * b + 6, 6 * b + 3 : 6 * b + 6] = (
            np.eye(3) if linear_ties else left_jacobian(phi[b])
        )
    tan = T.T @ tan @ T
    for b, D in inertia_tangents.items():
        # D is already a derivative with respect to (t, φ): only the rows are mapped.
        Tb = T[6 * b : 6 * b + 6, 6 * b : 6 * b + 6]
        tan[6 * b : 6 * b + 6, 6 * b : 6 * b + 6] += Tb.T @ D
    for b in range(0 if linear_ties else nb):
        # J_l(φ)ᵀ = J_r(φ): the derivative of the rotation rows' J_lᵀ factor.
        tan[6 * b + 3 : 6 * b + 6, 6 * b + 3 : 6 * b + 6] += d_jr_times(phi[b], moments[b])
    return RigidTerms(T.T @ res, tan, node_res, node_tan, T)


def external_loads(
    bodies: Sequence[RigidBody],
    tie_f: np.ndarray,
    tie_m: np.ndarray,
    spring_res: np.ndarray,
) -> np.ndarray:
    """Per body, the total external force F (N) and moment about G (N·m), (nb, 2, 3).

    External: ties (``tie_f``, ``tie_m``: the sums of the FE residual at the tied nodes, whose
    opposite acts on the body), springs (their residual rows ``spring_res``, 6 per body) and the
    applied loads.
    """
    nb = len(bodies)
    out = np.zeros((nb, 2, 3))
    for b, body in enumerate(bodies):
        F = body.force - spring_res[6 * b : 6 * b + 3] - tie_f[b]
        M_ref = body.moment - spring_res[6 * b + 3 : 6 * b + 6] - tie_m[b]
        rho = body.rotation @ (body.centre - body.reference_point)
        out[b] = F, M_ref - np.cross(rho, F)
    return out
