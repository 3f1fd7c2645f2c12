"""Robust planar motion from ground correspondences: 1-point RANSAC and refinement.

Hypotheses come from the paper's circular-motion homography solver (eq. 16) applied to a
virtual level camera on the rear axle (see :func:`planar_vo.camera.level_to_base`): the
circular constraint holds at the axle, not at a camera mounted ahead of it. Hypotheses
are scored by their transfer error in the *real* image, in pixels, on all correspondences
at once, then refined in 3 DoF by Gauss-Newton on the inliers.

Motions are REP-103 planar motions of base_link, ``[x, y, yaw]``: the pose of base_link
at frame 2 in base_link at frame 1 (metres, rad). Numpy only; no ROS.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planar_vo.camera import CameraModel, Mounting, level_to_base
from planar_vo.solvers import homography_1point, homography_npoint, paper_to_planar

__all__ = ['TransferModel', 'RansacResult', 'PoseEstimationError', 'estimate_motion',
           'refine_motion', 'transfer_errors', 'circular_motion']


class PoseEstimationError(RuntimeError):
    """Too few usable correspondences to estimate a motion."""


@dataclass(frozen=True)
class TransferModel:
    """What it takes to predict where a ground point appears in the real image."""

    A: np.ndarray  # (3, 2) ground xy → optical point, linear part
    b: np.ndarray  # (3,) offset
    focal_px: float
    mounting: Mounting

    @property
    def height(self) -> float:
        """Camera height above the ground, m."""
        return self.mounting.height

    @classmethod
    def from_camera(cls, mounting: Mounting, camera: CameraModel) -> TransferModel:
        """Build from the mounting and the intrinsics (only the focal length is used)."""
        A, b = mounting.ground_to_optical()
        return cls(A, b, camera.focal_px, mounting)

    def transfer(self, motion: np.ndarray, points: np.ndarray) -> np.ndarray:
        """Normalized coordinates (N, 2) where frame-1 ground points appear after ``motion``.

        NaN where the point would be behind the camera.
        """
        P = _predict(np.asarray(motion, dtype=float), points, self)
        z = np.where(P[:, 2] > 1e-6, P[:, 2], np.nan)
        return P[:, :2] / z[:, None]

    def project(self, points: np.ndarray) -> np.ndarray:
        """Normalized image coordinates (N, 2) of ground points (N, 2) seen from frame 1."""
        P = points @ self.A.T + self.b
        return P[:, :2] / P[:, 2:]


@dataclass
class RansacResult:
    """A robust planar motion and how it was found."""

    motion: np.ndarray  # (3,) x, y, yaw of base_link 2 in base_link 1
    covariance: np.ndarray  # (3, 3) over (x, y, yaw)
    inliers: np.ndarray  # (N,) bool
    hypotheses: int  # how many hypotheses were scored
    rms_px: float  # transfer error of the inliers after refinement

    @property
    def paper_motion(self) -> np.ndarray:
        """The motion as the paper's ``(theta, phi, rho)`` (level camera on the axle)."""
        x, y, yaw = self.motion
        return np.array([-yaw, np.arctan2(-y, x), np.hypot(x, y)])

    @property
    def paper_covariance(self) -> np.ndarray:
        """3x3 covariance of ``(theta, phi, rho)``, by first-order propagation."""
        x, y, _ = self.motion
        r2 = max(x * x + y * y, 1e-18)
        r = np.sqrt(r2)
        G = np.array([[0.0, 0.0, -1.0], [y / r2, -x / r2, 0.0], [x / r, y / r, 0.0]])
        return G @ self.covariance @ G.T


def circular_motion(yaw: np.ndarray, rho: np.ndarray) -> np.ndarray:
    """Circular motion of the axle: travel ``rho`` along the chord at half the yaw, (..., 3)."""
    return np.stack([rho * np.cos(0.5 * yaw), rho * np.sin(0.5 * yaw), yaw], axis=-1)


def _predict(motions: np.ndarray, p1: np.ndarray, model: TransferModel) -> np.ndarray:
    """Optical-frame points (..., N, 3) where frame-1 ground points appear in frame 2."""
    x, y, yaw = motions[..., 0:1], motions[..., 1:2], motions[..., 2:3]
    c, s = np.cos(yaw), np.sin(yaw)
    dx, dy = p1[:, 0] - x, p1[:, 1] - y
    qx, qy = c * dx + s * dy, c * dy - s * dx  # R(yaw)^T (p1 - t)
    return (qx[..., None] * model.A[:, 0] + qy[..., None] * model.A[:, 1] + model.b)


def transfer_errors(
    motions: np.ndarray, p1: np.ndarray, m2: np.ndarray, model: TransferModel
) -> np.ndarray:
    """Pixel distance between predicted and observed frame-2 points.

    Args:
        motions: (3,) or (B, 3) candidate motions.
        p1: (N, 2) frame-1 ground points in base_link.
        m2: (N, 2) observed frame-2 normalized image coordinates.

    Returns:
        (N,) or (B, N) errors in pixels; inf where the point would be behind the camera.
    """
    P = _predict(np.asarray(motions, dtype=float), p1, model)
    z = P[..., 2]
    safe = np.where(z > 1e-6, z, 1.0)
    du = P[..., 0] / safe - m2[:, 0]
    dv = P[..., 1] / safe - m2[:, 1]
    return np.where(z > 1e-6, np.hypot(du, dv) * model.focal_px, np.inf)


def _residuals_and_jacobian(
    motion: np.ndarray, p1: np.ndarray, m2: np.ndarray, model: TransferModel
) -> tuple[np.ndarray, np.ndarray]:
    """Stacked pixel residuals (2N,) and their Jacobian (2N, 3) w.r.t. (x, y, yaw)."""
    x, y, yaw = motion
    c, s = np.cos(yaw), np.sin(yaw)
    dx, dy = p1[:, 0] - x, p1[:, 1] - y
    q = np.stack([c * dx + s * dy, c * dy - s * dx], axis=1)
    P = q @ model.A.T + model.b
    z = P[:, 2]
    u, v = P[:, 0] / z, P[:, 1] / z
    # dq/d(x, y, yaw): translation enters as -R^T, yaw rotates (p1 - t).
    dq = np.empty((len(p1), 2, 3))
    dq[:, 0, 0], dq[:, 1, 0] = -c, s
    dq[:, 0, 1], dq[:, 1, 1] = -s, -c
    dq[:, 0, 2], dq[:, 1, 2] = -s * dx + c * dy, -c * dx - s * dy
    dP = np.einsum('ij,njk->nik', model.A, dq)
    J = np.empty((len(p1), 2, 3))
    J[:, 0] = (dP[:, 0] - u[:, None] * dP[:, 2]) / z[:, None]
    J[:, 1] = (dP[:, 1] - v[:, None] * dP[:, 2]) / z[:, None]
    r = np.stack([u - m2[:, 0], v - m2[:, 1]], axis=1)
    f = model.focal_px
    return f * r.ravel(), f * J.reshape(-1, 3)


def refine_motion(
    motion: np.ndarray,
    p1: np.ndarray,
    m2: np.ndarray,
    model: TransferModel,
    *,
    circular: bool = False,
    iterations: int = 10,
) -> tuple[np.ndarray, np.ndarray, float]:
    """Gauss-Newton on the pixel transfer error, in 3 DoF or on the circular 2-DoF manifold.

    Returns:
        (motion (3,), covariance (3, 3) of (x, y, yaw), rms error in pixels). The covariance
        is ``sigma^2 (J^T J)^-1`` with sigma estimated from the residuals.
    """
    motion = np.asarray(motion, dtype=float).copy()
    if circular:  # state (rho, yaw): signed travel along the chord, and yaw
        rho, yaw = motion[0] * np.cos(motion[2] / 2) + motion[1] * np.sin(motion[2] / 2), motion[2]
        motion = circular_motion(yaw, rho)
    for _ in range(iterations):
        r, J = _residuals_and_jacobian(motion, p1, m2, model)
        if circular:
            step = np.linalg.lstsq(J @ _circular_jacobian(rho, yaw), -r, rcond=None)[0]
            rho, yaw = rho + step[0], yaw + step[1]
            motion = circular_motion(yaw, rho)
        else:
            step = np.linalg.lstsq(J, -r, rcond=None)[0]
            motion = motion + step
        if np.max(np.abs(step)) < 1e-10:
            break
    r, J = _residuals_and_jacobian(motion, p1, m2, model)
    sigma2 = max(float(r @ r) / max(len(r) - (2 if circular else 3), 1), 1e-6)
    if circular:
        G = _circular_jacobian(rho, yaw)
        covariance = G @ np.linalg.pinv(G.T @ J.T @ J @ G) @ G.T * sigma2
    else:
        covariance = np.linalg.pinv(J.T @ J) * sigma2
    rms = float(np.sqrt(r @ r / max(len(p1), 1)))
    return motion, covariance, rms


def _circular_jacobian(rho: float, yaw: float) -> np.ndarray:
    """d(x, y, yaw) / d(rho, yaw) of :func:`circular_motion`, (3, 2)."""
    c, s = np.cos(yaw / 2), np.sin(yaw / 2)
    return np.array([[c, -rho / 2 * s], [s, rho / 2 * c], [0.0, 1.0]])


def _hypotheses_1point(p1: np.ndarray, p2: np.ndarray, height: float) -> np.ndarray:
    """One circular motion of the axle per correspondence (paper eq. 16), (N, 3)."""
    m = homography_1point(level_to_base(p1, height), level_to_base(p2, height))
    return paper_to_planar(m.theta, m.phi, m.rho * height)


def _hypotheses_2point(
    p1: np.ndarray, p2: np.ndarray, height: float, pairs: np.ndarray
) -> np.ndarray:
    """One planar motion per pair of correspondences (paper eq. 18-19), (K, 3)."""
    r1, r2 = level_to_base(p1, height), level_to_base(p2, height)
    with np.errstate(all='ignore'):
        m = homography_npoint(r1[pairs], r2[pairs])
    return paper_to_planar(m.theta, m.phi, m.rho * height)


def estimate_motion(
    p1: np.ndarray,
    p2: np.ndarray,
    m2: np.ndarray,
    model: TransferModel,
    *,
    method: str = '1point',
    threshold_px: float = 1.0,
    confidence: float = 0.999,
    batch: int = 32,
    max_hypotheses: int | None = None,
    circular_refine: bool = False,
    rng: np.random.Generator | None = None,
) -> RansacResult:
    """Robust planar motion from ground correspondences.

    Args:
        p1, p2: (N, 2) ground points of frames 1 and 2 in their own base_link, metres.
        m2: (N, 2) frame-2 normalized image coordinates (what the camera measured).
        model: transfer model (mounting and focal length).
        method: ``'1point'`` (RANSAC, every correspondence a hypothesis, drawn in random
            order in batches with adaptive stopping), ``'2point'`` (RANSAC on pairs) or
            ``'histogram'`` (Scaramuzza's median voting over all 1-point hypotheses).
        threshold_px: inlier threshold on the transfer error.
        confidence: RANSAC's probability of drawing at least one all-inlier sample.
        batch: hypotheses scored together (vectorised).
        max_hypotheses: cap on hypotheses (default: N for 1-point, 20 N for 2-point).
        circular_refine: keep the circular constraint in the refinement too.

    Raises:
        PoseEstimationError: fewer than 3 correspondences, or no hypothesis with 3 inliers.
    """
    n = len(p1)
    if n < 3:
        raise PoseEstimationError(f'{n} ground correspondences; at least 3 are needed')
    rng = rng if rng is not None else np.random.default_rng(0)
    sample = 2 if method == '2point' else 1
    if method == 'histogram':
        hyp = _hypotheses_1point(p1, p2, model.height)
        yaw = float(np.median(hyp[:, 2]))
        # Signed travel along the chord: outliers scatter on both signs, so the median holds.
        chord = hyp[:, 0] * np.cos(hyp[:, 2] / 2) + hyp[:, 1] * np.sin(hyp[:, 2] / 2)
        best = circular_motion(yaw, float(np.median(chord)))
        tried = n
    elif method in ('1point', '2point'):
        cap = max_hypotheses or (n if sample == 1 else 20 * n)
        order = rng.permutation(n) if sample == 1 else None
        best, best_cost, best_count, tried, needed = None, np.inf, 0, 0, cap
        while tried < min(cap, needed):
            k = min(batch, cap - tried)
            if sample == 1:
                idx = order[tried:tried + k]
                hyp = _hypotheses_1point(p1[idx], p2[idx], model.height)
            else:
                hyp = _hypotheses_2point(p1, p2, model.height, _random_pairs(rng, n, k))
            err = transfer_errors(hyp, p1, m2, model)
            # MSAC cost: inliers count by how well they fit, outliers at the threshold.
            cost = np.minimum(err, threshold_px) ** 2
            cost = np.where(np.isfinite(cost), cost, threshold_px ** 2).sum(axis=1)
            cost[~np.all(np.isfinite(hyp), axis=1)] = np.inf
            j = int(np.argmin(cost))
            tried += k
            if cost[j] < best_cost:
                best, best_cost = hyp[j], cost[j]
                best_count = int(np.count_nonzero(err[j] < threshold_px))
                needed = _needed_hypotheses(best_count / n, sample, confidence)
    else:
        raise ValueError(f'unknown method {method!r}: use 1point, 2point or histogram')
    if best is None:
        raise PoseEstimationError('no motion hypothesis could be formed')
    motion, inliers = best, transfer_errors(best, p1, m2, model) < threshold_px
    for _ in range(5):  # refine, re-select the inliers with the better motion, until stable
        if np.count_nonzero(inliers) < 3:
            raise PoseEstimationError(
                f'only {np.count_nonzero(inliers)} correspondences fit the best motion')
        motion, covariance, rms = refine_motion(
            motion, p1[inliers], m2[inliers], model, circular=circular_refine)
        selected = transfer_errors(motion, p1, m2, model) < threshold_px
        if np.array_equal(selected, inliers):
            break
        inliers = selected
    return RansacResult(motion, covariance, inliers, tried, rms)


def _random_pairs(rng: np.random.Generator, n: int, k: int) -> np.ndarray:
    first = rng.integers(0, n, k)
    second = (first + rng.integers(1, n, k)) % n  # never the same point twice
    return np.stack([first, second], axis=1)


def _needed_hypotheses(inlier_ratio: float, sample: int, confidence: float) -> int:
    """Standard RANSAC bound: draws for ``confidence`` of one all-inlier sample."""
    good = inlier_ratio ** sample
    if good >= 1.0:
        return 1
    if good <= 0.0:
        return np.iinfo(np.int32).max
    return int(np.ceil(np.log(1.0 - confidence) / np.log(1.0 - good)))
