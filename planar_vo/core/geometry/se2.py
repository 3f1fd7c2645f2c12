"""Planar rigid motions (SE(2)): composition, inverse, exponential and logarithm.

A motion or pose is ``[x, y, yaw]`` (m, m, rad; REP-103: x forward, y left, yaw counter-
clockwise): the pose of frame 2 in frame 1. Arrays broadcast over leading axes where the
docstring says so. Numpy only; no ROS.
"""

from __future__ import annotations

import numpy as np

__all__ = ['compose', 'inverse_motion', 'circular_motion', 'off_arc', 'step_length',
           'twist_motion', 'mean_twist', 'power']


def compose(
    pose: np.ndarray, covariance: np.ndarray, motion: np.ndarray, motion_cov: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``pose ∘ motion`` (3,) with first-order covariance propagation (3, 3)."""
    x, y, yaw = pose
    c, s = np.cos(yaw), np.sin(yaw)
    mx, my, myaw = motion
    new = np.array([x + c * mx - s * my, y + s * mx + c * my,
                    (yaw + myaw + np.pi) % (2 * np.pi) - np.pi])
    J_pose = np.array([[1.0, 0.0, -s * mx - c * my], [0.0, 1.0, c * mx - s * my],
                       [0.0, 0.0, 1.0]])
    J_motion = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return new, J_pose @ covariance @ J_pose.T + J_motion @ motion_cov @ J_motion.T


def inverse_motion(motion: np.ndarray) -> np.ndarray:
    """The planar motion (..., 3) back: base_link 1 in base_link 2, of 2 in 1."""
    x, y, yaw = motion[..., 0], motion[..., 1], motion[..., 2]
    c, s = np.cos(yaw), np.sin(yaw)
    return np.stack([-(c * x + s * y), s * x - c * y, -yaw], axis=-1)


def circular_motion(yaw: np.ndarray, rho: np.ndarray) -> np.ndarray:
    """Circular motion of the axle: travel ``rho`` along the chord at half the yaw, (..., 3)."""
    return np.stack([rho * np.cos(0.5 * yaw), rho * np.sin(0.5 * yaw), yaw], axis=-1)


def off_arc(motion: np.ndarray) -> float:
    """How far (m) a planar motion (x, y, yaw) ends beside the circular arc of its x and yaw.

    Moving along an arc (:func:`circular_motion`), the axle ends at y = x tan(yaw / 2).
    """
    x, y, yaw = motion
    return abs(float(y - x * np.tan(yaw / 2.0)))


def step_length(motion: np.ndarray) -> float:
    """How far (m) a planar motion (x, y, yaw) moves base_link: its translation's length."""
    return float(np.hypot(motion[0], motion[1]))


def twist_motion(twist: np.ndarray, dt: float) -> np.ndarray:
    """The motion (x, y, yaw) a constant body twist makes in ``dt``: the SE(2) exponential."""
    vx, vy, rate = twist
    yaw = rate * dt
    if abs(yaw) < 1e-9:
        return np.array([vx * dt, vy * dt, yaw])
    s, c = np.sin(yaw), np.cos(yaw)
    return np.array([(s * vx - (1 - c) * vy) / rate, ((1 - c) * vx + s * vy) / rate, yaw])


def mean_twist(motion: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The constant body twist (vx, vy, yaw rate) that moves by ``motion`` in ``dt``.

    The SE(2) logarithm over ``dt``: for circular motion (a car's rear axle) the speed
    along the arc, not the chord, and no sideways velocity. Returns the twist (3,) and its
    Jacobian (3, 3) with respect to ``motion`` (x, y, yaw).
    """
    x, y, yaw = motion
    half = 0.5 * yaw
    # V^-1 of the SE(2) exponential: (yaw / 2) [[cot(yaw/2), 1], [-1, cot(yaw/2)]].
    k = 1.0 - half * half / 3.0 if abs(half) < 1e-4 else half / np.tan(half)
    v_inv = np.array([[k, half], [-half, k]])
    # d k / d yaw, for the Jacobian (small-angle series near zero).
    dk = -half / 3.0 if abs(half) < 1e-4 else 0.5 * (
        1.0 / np.tan(half) - half / np.sin(half) ** 2)
    d_yaw = np.array([dk * x + 0.5 * y, -0.5 * x + dk * y])
    jac = np.zeros((3, 3))
    jac[:2, :2], jac[:2, 2], jac[2, 2] = v_inv, d_yaw, 1.0
    return np.append(v_inv @ np.array([x, y]), yaw) / dt, jac / dt


def power(motion: np.ndarray, s: np.ndarray | float) -> np.ndarray:
    """``motion`` to the power ``s``: the constant twist that makes it, held ``s`` times as long.

    ``exp(s log(motion))``, broadcast over leading axes of ``motion`` (..., 3) and ``s``.
    A circular motion stays circular (its yaw and arc length times ``s``); ``s = 1`` is the
    motion itself, ``s = 0`` none. Smooth through yaw = 0 (series there).
    """
    motion = np.asarray(motion)
    x, y, yaw = motion[..., 0], motion[..., 1], motion[..., 2]
    half = 0.5 * yaw
    small = np.abs(half) < 1e-4
    safe = np.where(small, 1.0, half)
    k = np.where(small, 1.0 - half * half / 3.0, safe / np.tan(safe))
    ux, uy = k * x + half * y, k * y - half * x  # the log's translation part
    a = yaw * s
    small_a = np.abs(a) < 1e-4
    safe_a = np.where(small_a, 1.0, a)
    sinc = np.where(small_a, 1.0 - a * a / 6.0, np.sin(safe_a) / safe_a)
    cosc = np.where(small_a, a / 2.0 - a ** 3 / 24.0, (1.0 - np.cos(safe_a)) / safe_a)
    return np.stack([s * (sinc * ux - cosc * uy), s * (cosc * ux + sinc * uy),
                     a * np.ones_like(x)], axis=-1)
