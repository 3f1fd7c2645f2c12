"""The paper's reduced models of planar motion and their minimal and least-squares solvers.

Choi et al., "Numerical Solutions to Relative Pose Problem under Planar Motion" (URAI 2010).
Everything here works on normalized rays ``[X, Y, Z]`` of a *level* camera in the paper's
(and the ROS optical) convention: x right, y down, z forward; the ground is ``Y = d``.

Motion of camera 2 relative to camera 1 is ``(theta, phi, rho)`` (paper eq. 1)::

    R21 = Ry(theta),  T1 = rho * [sin phi, 0, cos phi],  x2 = R12 x1 + T2

``theta`` turns about the camera's y axis, which points *down*: positive ``theta`` is a
turn to the right, the opposite of ROS yaw. :func:`paper_to_planar` converts.

Every solver is vectorised: arrays of rays have shape ``(..., N, 3)`` or ``(N, 3)``.
Numpy only; no ROS.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = [
    'PaperMotion',
    'essential_matrix',
    'ground_homography',
    'essential_1point',
    'essential_2point',
    'essential_select',
    'homography_1point',
    'homography_2point',
    'homography_npoint',
    'paper_to_planar',
    'planar_to_paper',
]


class PaperMotion(NamedTuple):
    """Planar motion in the paper's convention (arrays broadcast together)."""

    theta: np.ndarray  # rotation about the camera's y (down) axis, rad
    phi: np.ndarray  # direction of travel in camera 1, rad (0 = straight ahead, + = right)
    rho: np.ndarray  # distance travelled, in units of the camera height d when from rays


def _r12_t2(theta: float, phi: float, rho: float) -> tuple[np.ndarray, np.ndarray]:
    c, s = np.cos(theta), np.sin(theta)
    r12 = np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])  # R21 transposed
    t2 = rho * np.array([np.sin(theta - phi), 0.0, -np.cos(theta - phi)])
    return r12, t2


def essential_matrix(theta: float, phi: float) -> np.ndarray:
    """Reduced essential matrix ``E = [T2]x R12`` (paper eq. 7), for unit ``rho``."""
    r12, t2 = _r12_t2(theta, phi, 1.0)
    tx = np.array([[0.0, -t2[2], t2[1]], [t2[2], 0.0, -t2[0]], [-t2[1], t2[0], 0.0]])
    return tx @ r12


def ground_homography(theta: float, phi: float, rho_over_d: float) -> np.ndarray:
    """Reduced ground-plane homography ``H = R12 + T2 N^T / d``, ``N = [0,1,0]`` (eq. 10)."""
    r12, t2 = _r12_t2(theta, phi, rho_over_d)
    return r12 + np.outer(t2, [0.0, 1.0, 0.0])


def _wrap(angle: np.ndarray) -> np.ndarray:
    return (angle + np.pi) % (2.0 * np.pi) - np.pi


def _circular_phi(x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """Paper eq. 16: ``tan phi = -(X2 Y1 - X1 Y2) / (Z2 Y1 + Z1 Y2)``, root in (-pi/2, pi/2)."""
    X1, Y1, Z1 = np.moveaxis(x1, -1, 0)
    X2, Y2, Z2 = np.moveaxis(x2, -1, 0)
    num = -(X2 * Y1 - X1 * Y2)
    den = Z2 * Y1 + Z1 * Y2
    # atan of the ratio (not atan2): the sign of (num, den) is not fixed by the constraint.
    return np.arctan(num / np.where(den == 0.0, np.finfo(float).tiny, den))


def essential_1point(x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """Circular-motion essential solver (paper eq. 16): both roots ``phi`` and ``phi + pi``.

    Args:
        x1, x2: rays, shape (..., 3), of one correspondence each.

    Returns:
        phi, shape (..., 2); theta = 2 phi. The essential matrix has no scale: pick the root
        with :func:`essential_select` (points in front of both cameras).
    """
    phi = _circular_phi(x1, x2)
    return np.stack([phi, _wrap(phi + np.pi)], axis=-1)


def essential_2point(x1: np.ndarray, x2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Planar-motion essential solver from two correspondences (paper eq. 11-15).

    ``A a = B b`` with ``a = [sin phi, cos phi]``, ``b = [sin(theta-phi), cos(theta-phi)]``,
    rows ``A_i = [Z1 Y2, -X1 Y2]``, ``B_i = [-Z2 Y1, -X2 Y1]``; with ``C = A^-1 B`` the unit
    norms of ``a`` and ``b`` give ``b^T (C^T C - I) b = 0`` (eq. 15). Written in the angle
    ``psi = theta - phi`` this is ``P + Q cos 2psi + S sin 2psi = 0``, solved in closed form.

    Args:
        x1, x2: rays, shape (..., 2, 3).

    Returns:
        (theta, phi), each shape (..., 4): two roots of eq. 15, each with both signs of the
        translation. Where noise leaves no real root, the double root closest to one is given.
    """
    X1, Y1, Z1 = np.moveaxis(x1, -1, 0)
    X2, Y2, Z2 = np.moveaxis(x2, -1, 0)
    A = np.stack([Z1 * Y2, -X1 * Y2], axis=-1)  # (..., 2, 2)
    B = np.stack([-Z2 * Y1, -X2 * Y1], axis=-1)
    C = np.linalg.solve(A, B)
    M = np.swapaxes(C, -1, -2) @ C - np.eye(2)
    p = 0.5 * (M[..., 0, 0] + M[..., 1, 1])
    q = 0.5 * (M[..., 1, 1] - M[..., 0, 0])
    s = M[..., 0, 1]
    amplitude = np.hypot(q, s)
    delta = np.arctan2(s, q)
    spread = np.arccos(np.clip(-p / np.where(amplitude == 0, 1.0, amplitude), -1.0, 1.0))
    psi = np.stack([0.5 * (delta + spread), 0.5 * (delta - spread)], axis=-1)  # (..., 2)
    psi = np.concatenate([psi, psi + np.pi], axis=-1)  # b and -b
    b = np.stack([np.sin(psi), np.cos(psi)], axis=-2)  # (..., 2, 4)
    a = C @ b
    phi = np.arctan2(a[..., 0, :], a[..., 1, :])
    return _wrap(psi + phi), phi


def essential_select(
    theta: np.ndarray, phi: np.ndarray, x1: np.ndarray, x2: np.ndarray
) -> tuple[float, float]:
    """Pick the physical motion among essential-matrix candidates.

    Candidates that fit the correspondences worst (Sampson error) are dropped first; of the
    rest (a motion and its reversed translation fit equally well), the one that puts most
    points in front of both cameras (cheirality) wins.

    Args:
        theta, phi: candidate motions, shape (K,).
        x1, x2: rays of the correspondences, shape (N, 3).
    """
    theta, phi = np.atleast_1d(theta), np.atleast_1d(phi)
    errors, in_front = [], []
    for k in range(len(theta)):
        E = essential_matrix(theta[k], phi[k])
        Ex1, Etx2 = x1 @ E.T, x2 @ E
        num = np.einsum('ni,ni->n', x2, Ex1) ** 2
        den = Ex1[:, 0] ** 2 + Ex1[:, 1] ** 2 + Etx2[:, 0] ** 2 + Etx2[:, 1] ** 2
        errors.append(float(np.sum(num / np.maximum(den, 1e-300))))
        r12, t2 = _r12_t2(theta[k], phi[k], 1.0)
        # Depths (s1, s2) with s2 x2 = s1 R12 x1 + T2, per point, in least squares.
        m = np.stack([x1 @ r12.T, -x2], axis=-1)  # (N, 3, 2)
        mt = np.swapaxes(m, -1, -2)
        s = np.linalg.solve(mt @ m + 1e-12 * np.eye(2), (mt @ -t2)[..., None])[..., 0]
        in_front.append(int(np.count_nonzero((s[:, 0] > 0) & (s[:, 1] > 0))))
    errors = np.asarray(errors)
    fits = errors <= 1.01 * errors.min() + 1e-18
    best = max(np.flatnonzero(fits), key=lambda k: in_front[k])
    return float(theta[best]), float(phi[best])


def _homography_rows(x1: np.ndarray, x2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two equations per ground correspondence, linear in ``a`` (paper eq. 17-19).

    ``a = [cos theta, sin theta, u cos(theta-phi), u sin(theta-phi)]``, ``u = rho / d``.
    Returns rows (..., N, 2, 4) and right-hand sides (..., N, 2).
    """
    X1, Y1, Z1 = np.moveaxis(x1, -1, 0)
    X2, Y2, Z2 = np.moveaxis(x2, -1, 0)
    zero = np.zeros_like(X1)
    rows = np.stack(
        [
            np.stack([X1 * Y2, -Z1 * Y2, zero, Y1 * Y2], axis=-1),
            np.stack([Z1 * Y2, X1 * Y2, -Y1 * Y2, zero], axis=-1),
        ],
        axis=-2,
    )
    rhs = np.stack([X2 * Y1, Z2 * Y1], axis=-1)
    return rows, rhs


def _motion_from_a(a: np.ndarray) -> PaperMotion:
    theta = np.arctan2(a[..., 1], a[..., 0])
    phi = _wrap(theta - np.arctan2(a[..., 3], a[..., 2]))
    return PaperMotion(theta, phi, np.hypot(a[..., 2], a[..., 3]))


def homography_1point(x1: np.ndarray, x2: np.ndarray) -> PaperMotion:
    """Circular-motion homography solver: one ground correspondence gives the motion.

    ``phi`` from paper eq. 16, ``theta = 2 phi``, then ``u = rho/d`` by least squares from
    the two equations of eq. 17; of the roots ``phi`` and ``phi + pi`` the one with ``u >= 0``
    is kept, so the answer is unique. With noise and a far point ``u`` can come out slightly
    negative, which reverses the heading (3 in 1000 trials at 1 px in the paper's set-up):
    RANSAC scores every hypothesis on all points, so such a hypothesis simply loses.

    Args:
        x1, x2: rays, shape (..., 3); any number of correspondences, each solved on its own.

    Returns:
        PaperMotion with arrays of shape (...); ``rho`` in units of the camera height ``d``.
    """
    phi = _circular_phi(x1, x2)
    theta = 2.0 * phi
    X1, Y1, Z1 = np.moveaxis(x1, -1, 0)
    X2, Y2, Z2 = np.moveaxis(x2, -1, 0)
    c, s = np.cos(theta), np.sin(theta)
    r_x = X2 * Y1 - Y2 * (c * X1 - s * Z1)  # = Y1 Y2 u sin(theta - phi)
    r_z = Z2 * Y1 - Y2 * (s * X1 + c * Z1)  # = -Y1 Y2 u cos(theta - phi)
    u = (r_x * np.sin(phi) - r_z * np.cos(phi)) / (Y1 * Y2)
    flip = u < 0
    return PaperMotion(theta, np.where(flip, _wrap(phi + np.pi), phi), np.abs(u))


def homography_npoint(x1: np.ndarray, x2: np.ndarray) -> PaperMotion:
    """Planar-motion homography solver, linear least squares over N >= 2 correspondences.

    With exactly two points this is the paper's 2-point algorithm (eq. 18-19, ``a = A^-1 b``).

    Args:
        x1, x2: rays, shape (..., N, 3).
    """
    rows, rhs = _homography_rows(x1, x2)
    shape = rows.shape[:-3]
    A = rows.reshape(*shape, -1, 4)
    b = rhs.reshape(*shape, -1)
    At = np.swapaxes(A, -1, -2)
    a = np.linalg.solve(At @ A, (At @ b[..., None]))[..., 0]
    return _motion_from_a(a)


def homography_2point(x1: np.ndarray, x2: np.ndarray) -> PaperMotion:
    """The paper's 2-point homography solver (eq. 18-19): rays of shape (..., 2, 3)."""
    if x1.shape[-2] != 2:
        raise ValueError(f'the 2-point solver takes 2 correspondences, got {x1.shape[-2]}')
    return homography_npoint(x1, x2)


def paper_to_planar(theta: np.ndarray, phi: np.ndarray, rho: np.ndarray) -> np.ndarray:
    """Paper motion of a level camera → REP-103 planar motion ``[x, y, yaw]`` of that camera.

    The paper's x is right and its theta turns right; ROS's y is left and yaw turns left.
    Returns shape (..., 3).
    """
    return np.stack([rho * np.cos(phi), -rho * np.sin(phi), -np.asarray(theta)], axis=-1)


def planar_to_paper(x: np.ndarray, y: np.ndarray, yaw: np.ndarray) -> PaperMotion:
    """Inverse of :func:`paper_to_planar`; ``phi`` is arbitrary (0) when there is no motion."""
    return PaperMotion(-np.asarray(yaw), np.arctan2(-np.asarray(y), x), np.hypot(x, y))
