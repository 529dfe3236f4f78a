"""SO(3) utilities: hat/vee, exponential and logarithm, Jacobians, rotation checks.

Pure numpy, used by the rigid dynamics and every module that rotates vectors. Conventions for
the whole package:

* ``R`` maps body-frame components to inertial-frame components: ``x = x_G + R X_body``.
* ``omega`` is the **body-frame** angular velocity, ``Ṙ = R hat(omega)``; the inertial-frame
  (spatial) angular velocity is ``R omega``.
* Rotations are updated multiplicatively on SO(3): ``R ← R exp(hat(dθ))`` for a body-frame
  increment, ``R ← exp(hat(dθ)) R`` for a spatial one, never by adding angles.
* Rotation vectors ``phi`` (rad) parametrise SO(3) through :func:`exp_so3`; :func:`log_so3` returns
  the one with ``|phi| <= π``.
* SI units: m, s, kg, N, N·m, rad.

The ``*_unchecked`` kernels and :func:`norm3` skip the input checks: they are for trusted (3,)
float arrays in inner loops (the rigid integrator), with the same arithmetic as the checked maps.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

#: Machine epsilon of float64 (dimensionless).
EPS = float(np.finfo(float).eps)
# Below this angle (rad) the trigonometric coefficients are evaluated by truncated Taylor series;
# the first neglected term is O(θ⁶) ≲ 1e-24, far below round-off.
_SMALL_ANGLE = 1.0e-4
#: The (3, 3) identity, read-only (shared, never to be written).
I3 = np.eye(3)
I3.flags.writeable = False

__all__ = [
    "EPS",
    "I3",
    "as_matrix3",
    "as_vector3",
    "exp_so3",
    "exp_so3_unchecked",
    "hat",
    "hat_unchecked",
    "hats",
    "inverse_right_jacobian",
    "is_rotation",
    "log_so3",
    "norm3",
    "project_to_so3",
    "right_jacobian",
    "right_jacobian_unchecked",
    "rotation_about",
    "vee",
]


def as_vector3(v: ArrayLike, name: str) -> FloatArray:
    """Return ``v`` as a finite float array of shape (3,), or raise ValueError naming it.

    Args:
        v: the vector to check, any unit.
        name: its name in the error message.
    """
    a = np.asarray(v, dtype=float)
    if a.shape != (3,):
        raise ValueError(f"{name} must have shape (3,), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite, got {a}")
    return a


def as_matrix3(m: ArrayLike, name: str) -> FloatArray:
    """Return ``m`` as a finite float array of shape (3, 3), or raise ValueError naming it.

    Args:
        m: the matrix to check, any unit.
        name: its name in the error message.
    """
    a = np.asarray(m, dtype=float)
    if a.shape != (3, 3):
        raise ValueError(f"{name} must have shape (3, 3), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite")
    return a


def hat(v: ArrayLike) -> FloatArray:
    """Skew-symmetric matrix of a 3-vector: ``hat(v) @ w == np.cross(v, w)``.

    Args:
        v: Vector of shape (3,), any unit (the matrix carries the same unit).

    Returns:
        The (3, 3) skew-symmetric matrix ``[v]×``.
    """
    return hat_unchecked(as_vector3(v, "v"))


def hats(v: ArrayLike) -> FloatArray:
    """:func:`hat` of every vector of ``v`` (..., 3): the matrices (..., 3, 3)."""
    v = np.asarray(v, dtype=float)
    h = np.zeros(v.shape + (3,))
    h[..., 0, 1], h[..., 0, 2] = -v[..., 2], v[..., 1]
    h[..., 1, 0], h[..., 1, 2] = v[..., 2], -v[..., 0]
    h[..., 2, 0], h[..., 2, 1] = -v[..., 1], v[..., 0]
    return h


def hat_unchecked(v: FloatArray) -> FloatArray:
    """:func:`hat` with no input check: for trusted (3,) float arrays in inner loops."""
    x, y, z = v
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def norm3(v: FloatArray) -> float:
    """Euclidean norm of a (3,) float array, no input check (cheaper than np.linalg.norm)."""
    return math.sqrt(float(v @ v))


def vee(W: ArrayLike) -> FloatArray:
    """Inverse of :func:`hat`: the axial vector of the skew-symmetric part of ``W``.

    Args:
        W: (3, 3) matrix. Only its skew-symmetric part ``(W - Wᵀ)/2`` is used, so
            ``vee(hat(v)) == v`` exactly and a slightly non-skew input is projected.

    Returns:
        Vector of shape (3,) with ``hat(vee(W)) == (W - Wᵀ)/2``.
    """
    a = as_matrix3(W, "W")
    return 0.5 * np.array([a[2, 1] - a[1, 2], a[0, 2] - a[2, 0], a[1, 0] - a[0, 1]])


def _exp_coefficients(theta: float) -> tuple[float, float]:
    """Return ``A = sin θ/θ`` and ``B = (1 - cos θ)/θ²``, accurate for every θ >= 0."""
    if theta < _SMALL_ANGLE:
        t2 = theta * theta
        return 1.0 - t2 / 6.0 * (1.0 - t2 / 20.0), 0.5 - t2 / 24.0 * (1.0 - t2 / 30.0)
    half_sin = math.sin(0.5 * theta)
    # 1 - cos θ = 2 sin²(θ/2) avoids the cancellation of 1 - cos θ at moderate angles.
    return math.sin(theta) / theta, 2.0 * half_sin * half_sin / (theta * theta)


def exp_so3(phi: ArrayLike) -> FloatArray:
    """Rotation matrix of a rotation vector (Rodrigues' formula).

    ``exp(hat(phi)) = I + (sin θ/θ) K + ((1 - cos θ)/θ²) K²`` with ``K = hat(phi)``, θ = |phi|. The
    coefficients use Taylor series below 1e-4 rad and ``1 - cos θ = 2 sin²(θ/2)`` above, so the
    result is orthogonal to round-off for tiny, moderate and near-π (or larger) angles.

    Args:
        phi: Rotation vector (rad), shape (3,): axis ``phi/|phi|``, angle ``|phi|``.

    Returns:
        The (3, 3) rotation matrix.
    """
    return exp_so3_unchecked(as_vector3(phi, "phi"))


def exp_so3_unchecked(phi: FloatArray) -> FloatArray:
    """:func:`exp_so3` with no input check: for trusted (3,) float arrays in inner loops."""
    a, b = _exp_coefficients(norm3(phi))
    K = hat_unchecked(phi)
    return I3 + a * K + b * (K @ K)


def log_so3(R: ArrayLike) -> FloatArray:
    """Rotation vector of a rotation matrix, the inverse of :func:`exp_so3` on ``|phi| <= π``.

    The angle is ``atan2(sin θ, cos θ)`` with ``sin θ = |vee(R - Rᵀ)|/2`` and
    ``cos θ = (tr R - 1)/2``, which is accurate to round-off at every angle (``acos`` of the trace
    alone loses half the digits near 0 and π). For θ <= π/2 the axis comes from the
    skew-symmetric part; for θ > π/2, where ``sin θ`` goes to zero, it comes from the symmetric
    part ``(R + Rᵀ)/2 - cos θ I = (1 - cos θ) n nᵀ``, with the sign taken from the skew part.

    Args:
        R: (3, 3) rotation matrix (not checked; use :func:`project_to_so3` first if in doubt).

    Returns:
        Rotation vector ``phi`` (rad), shape (3,), with ``|phi| <= π`` and ``exp_so3(phi) ≈ R``.
        At exactly θ = π both ``±phi`` are valid; one of them is returned.
    """
    R = as_matrix3(R, "R")
    w = vee(R)  # = sin θ · n
    s = math.sqrt(float(w @ w))
    c = 0.5 * (float(np.trace(R)) - 1.0)
    theta = math.atan2(s, c)
    if c >= 0.0:
        if theta < _SMALL_ANGLE:
            # θ/sin θ = 1 + θ²/6 + 7θ⁴/360 + ...
            t2 = theta * theta
            return (1.0 + t2 / 6.0 * (1.0 + 7.0 * t2 / 60.0)) * w
        return (theta / s) * w
    B = 0.5 * (R + R.T) - c * np.eye(3)  # (1 - c) n nᵀ, 1 - c >= 1 here
    i = int(np.argmax(np.diag(B)))
    n = B[:, i] / math.sqrt(max(B[i, i], 0.0) * (1.0 - c))
    n /= np.linalg.norm(n)
    if float(n @ w) < 0.0:
        n = -n
    return theta * n


def right_jacobian(phi: ArrayLike) -> FloatArray:
    """Right Jacobian of SO(3): ``exp(hat(phi + δ)) ≈ exp(hat(phi)) exp(hat(J_r(phi) δ))``.

    ``J_r = I - ((1 - cos θ)/θ²) K + ((θ - sin θ)/θ³) K²`` with ``K = hat(phi)``. The left
    Jacobian is ``J_r(-phi)``. It also maps the rate of the rotation vector to the body angular
    velocity: ``omega = J_r(phi) dphi/dt``.

    Args:
        phi: Rotation vector (rad), shape (3,).

    Returns:
        The (3, 3) dimensionless Jacobian.
    """
    return right_jacobian_unchecked(as_vector3(phi, "phi"))


def right_jacobian_unchecked(phi: FloatArray) -> FloatArray:
    """:func:`right_jacobian` with no input check: for trusted (3,) float arrays in inner loops."""
    theta = norm3(phi)
    _, b = _exp_coefficients(theta)
    if theta < _SMALL_ANGLE:
        t2 = theta * theta
        c = 1.0 / 6.0 - t2 / 120.0 * (1.0 - t2 / 42.0)
    else:
        c = (theta - math.sin(theta)) / theta**3
    K = hat_unchecked(phi)
    return I3 - b * K + c * (K @ K)


def inverse_right_jacobian(phi: ArrayLike) -> FloatArray:
    """Inverse of :func:`right_jacobian`: ``dphi/dt = J_r(phi)⁻¹ omega``.

    ``J_r⁻¹ = I + K/2 + (1/θ² - (1 + cos θ)/(2 θ sin θ)) K²``; singular at θ = 2π, fine for the
    ``|phi| <= π`` range of :func:`log_so3`.

    Args:
        phi: Rotation vector (rad), shape (3,), ``|phi| < 2π``.

    Returns:
        The (3, 3) dimensionless inverse Jacobian.
    """
    phi = as_vector3(phi, "phi")
    theta = math.sqrt(float(phi @ phi))
    if theta >= 2.0 * math.pi - 1e-8:
        raise ValueError(f"phi: inverse right Jacobian is singular at |phi| = 2π (|phi|={theta})")
    if theta < _SMALL_ANGLE:
        t2 = theta * theta
        d = 1.0 / 12.0 + t2 / 720.0 * (1.0 + t2 / 42.0)
    else:
        d = 1.0 / theta**2 - (1.0 + math.cos(theta)) / (2.0 * theta * math.sin(theta))
    K = hat(phi)
    return np.eye(3) + 0.5 * K + d * (K @ K)


def rotation_about(axis: ArrayLike, angle: float) -> FloatArray:
    """Rotation by ``angle`` (rad, right-hand rule) about ``axis`` (any nonzero length).

    Args:
        axis: Rotation axis, shape (3,), normalised here.
        angle: Rotation angle (rad).

    Returns:
        The (3, 3) rotation matrix ``exp(hat(angle · axis/|axis|))``.
    """
    n = as_vector3(axis, "axis")
    norm = float(np.linalg.norm(n))
    if norm == 0.0:
        raise ValueError("axis must be nonzero")
    if not math.isfinite(angle):
        raise ValueError(f"angle must be finite, got {angle}")
    return exp_so3((float(angle) / norm) * n)


def is_rotation(R: ArrayLike, tol: float = 1e-10) -> bool:
    """Whether ``R`` is a rotation: ``max|RᵀR - I| <= tol`` and ``|det R - 1| <= tol``.

    Args:
        R: Candidate matrix; anything not (3, 3) and finite gives False.
        tol: Absolute tolerance (dimensionless).

    Returns:
        True if ``R`` is in SO(3) to ``tol``.
    """
    a = np.asarray(R, dtype=float)
    if a.shape != (3, 3) or not np.all(np.isfinite(a)):
        return False
    orth = float(np.max(np.abs(a.T @ a - np.eye(3))))
    return orth <= tol and abs(float(np.linalg.det(a)) - 1.0) <= tol


def project_to_so3(R: ArrayLike) -> FloatArray:
    """Closest rotation to ``R`` in the Frobenius norm (the polar factor, through an SVD).

    ``R = U S Vᵀ`` gives ``U diag(1, 1, det(U Vᵀ)) Vᵀ``; for ``det R > 0`` this is the orthogonal
    factor of the polar decomposition. Used to remove round-off drift from a rotation.

    Args:
        R: (3, 3) matrix, typically a rotation polluted by round-off.

    Returns:
        The (3, 3) rotation matrix nearest to ``R``.
    """
    a = as_matrix3(R, "R")
    U, _, Vt = np.linalg.svd(a)
    d = 1.0 if np.linalg.det(U @ Vt) > 0.0 else -1.0
    return (U * np.array([1.0, 1.0, d])) @ Vt
