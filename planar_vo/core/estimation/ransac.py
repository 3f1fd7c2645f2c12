"""Robust planar motion from ground correspondences: 1-point RANSAC and refinement.

Hypotheses come from the paper's circular-motion homography solver (eq. 16) applied to a
virtual level camera on the rear axle (see :func:`planar_vo.core.geometry.camera.level_to_base`):
the
circular constraint holds at the axle, not at a camera mounted ahead of it. Hypotheses
are scored by their transfer error in the *real* image, in pixels, on all correspondences
at once, then refined in 3 DoF by Gauss-Newton on the inliers.

Motions are REP-103 planar motions of base_link, ``[x, y, yaw]``: the pose of base_link
at frame 2 in base_link at frame 1 (metres, rad). Numpy only; no ROS.

A rolling shutter (:mod:`planar_vo.core.estimation.rolling_shutter`) enters as a
``stretch`` per correspondence: with a constant twist over the pair, the motion between the
two rows a track was seen in is the frame motion to the power ``s_i = 1 + (tau2 - tau1) /
dt`` (:func:`~planar_vo.core.geometry.se2.power`). Every function here takes it (None: a
global shutter, every ``s_i = 1``, the code paths of before).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from planar_vo.core.errors import PoseEstimationError
from planar_vo.core.geometry.camera import CameraModel, Mounting, level_to_base
from planar_vo.core.geometry.se2 import circular_motion, power
from planar_vo.core.geometry.solvers import homography_npoint, paper_to_planar

__all__ = ['TransferModel', 'RansacResult', 'PoseEstimationError', 'estimate_motion',
           'refine_motion', 'motion_covariance', 'transfer_errors']


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

        ``motion`` (3,) or (K, 3): then (K, N, 2), one row per motion. NaN where the point
        would be behind the camera.
        """
        P = _predict(np.asarray(motion, dtype=float), points, self)
        z = np.where(P[..., 2] > 1e-6, P[..., 2], np.nan)
        return P[..., :2] / z[..., None]

    def project(self, points: np.ndarray, height: np.ndarray | None = None) -> np.ndarray:
        """Normalized image coordinates (N, 2) of ground points (N, 2) seen from frame 1.

        ``height`` (N,): the points stand that far above the ground plane (m).
        """
        P = points @ self.A.T + self.b
        if height is not None:
            P = P + np.outer(height, self.mounting.base_from_optical[2])
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


def _predict(motions: np.ndarray, p1: np.ndarray, model: TransferModel) -> np.ndarray:
    """Optical-frame points (..., N, 3) where frame-1 ground points appear in frame 2."""
    x, y, yaw = motions[..., 0:1], motions[..., 1:2], motions[..., 2:3]
    c, s = np.cos(yaw), np.sin(yaw)
    dx, dy = p1[:, 0] - x, p1[:, 1] - y
    qx, qy = c * dx + s * dy, c * dy - s * dx  # R(yaw)^T (p1 - t)
    return (qx[..., None] * model.A[:, 0] + qy[..., None] * model.A[:, 1] + model.b)


def _predict_per_point(motions: np.ndarray, p1: np.ndarray,
                       model: TransferModel) -> np.ndarray:
    """Optical-frame points (B, N, 3) of ground points (N, 2), each its own motion (B, N, 3)."""
    x, y, yaw = motions[..., 0], motions[..., 1], motions[..., 2]
    c, s = np.cos(yaw), np.sin(yaw)
    dx, dy = p1[:, 0] - x, p1[:, 1] - y
    qx, qy = c * dx + s * dy, c * dy - s * dx
    return qx[..., None] * model.A[:, 0] + qy[..., None] * model.A[:, 1] + model.b


def _squared_errors(motions: np.ndarray, p1: np.ndarray, m2: np.ndarray,
                    model: TransferModel, stretch: np.ndarray | None = None) -> np.ndarray:
    """Squared transfer errors (B, N) in normalized units, inf behind the camera.

    The RANSAC hot path: float32, a handful of in-place operations on (B, N) arrays.
    ``stretch`` (N,): each point's motion is the hypothesis to that power.
    """
    A, b = model.A.astype(np.float32), model.b.astype(np.float32)
    if stretch is None:
        mx, my, yaw = (motions[:, i:i + 1].astype(np.float32) for i in range(3))
    else:
        per_point = power(motions[:, None, :], stretch[None, :]).astype(np.float32)
        mx, my, yaw = per_point[..., 0], per_point[..., 1], per_point[..., 2]
    c, s = np.cos(yaw), np.sin(yaw)
    dx = p1[:, 0] - mx
    dy = p1[:, 1] - my
    qx = c * dx
    qx += s * dy
    qy = dy
    qy *= c
    dx *= s
    qy -= dx  # R(yaw)^T (p1 - t)
    z = A[2, 0] * qx
    z += A[2, 1] * qy
    z += b[2]
    eu = A[0, 0] * qx
    eu += A[0, 1] * qy
    eu += b[0]
    eu -= m2[:, 0] * z
    ev = A[1, 0] * qx
    ev += A[1, 1] * qy
    ev += b[1]
    ev -= m2[:, 1] * z
    eu *= eu
    ev *= ev
    eu += ev
    z *= z
    eu /= z
    eu[z <= 0] = np.inf
    return eu


def transfer_errors(
    motions: np.ndarray, p1: np.ndarray, m2: np.ndarray, model: TransferModel,
    stretch: np.ndarray | None = None,
) -> np.ndarray:
    """Pixel distance between predicted and observed frame-2 points.

    Args:
        motions: (3,) or (B, 3) candidate motions.
        p1: (N, 2) frame-1 ground points in base_link.
        m2: (N, 2) observed frame-2 normalized image coordinates.
        stretch: (N,) rolling-shutter stretch of each point's motion (None: global shutter).

    Returns:
        (N,) or (B, N) errors in pixels; inf where the point would be behind the camera.
    """
    motions = np.asarray(motions, dtype=float)
    if stretch is None:
        P = _predict(motions.reshape(-1, 3), p1, model)
    else:
        P = _predict_per_point(power(motions.reshape(-1, 1, 3), stretch[None, :]), p1, model)
    z = P[..., 2]
    safe = np.where(z > 1e-6, z, 1.0)
    du = P[..., 0] / safe - m2[:, 0]
    dv = P[..., 1] / safe - m2[:, 1]
    errors = np.where(z > 1e-6, np.hypot(du, dv) * model.focal_px, np.inf)
    return errors.reshape(motions.shape[:-1] + (len(p1),))


_QUARTER_TURN = np.array([[0.0, 1.0], [-1.0, 0.0]])  # dq/dyaw = _QUARTER_TURN @ q


def _residuals_and_jacobian(
    motion: np.ndarray, p1_t: np.ndarray, m2_t: np.ndarray, model: TransferModel
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Residuals (2, N), Jacobian (3, 2, N) of the transfer, and where it is defined (N,).

    Inputs are transposed, (2, N). With ``q = R^T (p1 - t)`` the optical point is
    ``P = A q + b``: translation enters through the constant ``-A R^T`` and yaw through
    ``A Q R^T (p1 - t)``, so everything is a handful of whole-array operations (this runs
    every Gauss-Newton step of every frame). Behind the camera the Jacobian is zero.
    """
    x, y, yaw = motion
    c, s = np.cos(yaw), np.sin(yaw)
    a_rt = model.A @ np.array([[c, s], [-s, c]])  # (3, 2)
    d = p1_t - np.array([[x], [y]])
    P = a_rt @ d
    P += model.b[:, None]
    front = P[2] > 1e-9
    iz = np.divide(1.0, P[2], out=np.zeros_like(P[2]), where=front)
    m = P[:2] * iz
    d_yaw = (a_rt @ _QUARTER_TURN) @ d  # dP/dyaw, (3, N)
    J = np.empty((3, 2, len(iz)))
    J[:2] = -a_rt[:2].T[:, :, None] + a_rt[2][:, None, None] * m  # dP/d(x, y) = -A R^T
    J[2] = d_yaw[:2] - d_yaw[2] * m
    J *= iz
    return m - m2_t, J, front


def _residuals_and_jacobian_stretched(
    motion: np.ndarray, stretch: np.ndarray, p1_t: np.ndarray, m2_t: np.ndarray,
    model: TransferModel
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_residuals_and_jacobian` with each point's motion ``power(motion, stretch_i)``.

    The Jacobian is with respect to the frame motion: the per-point transfer's analytic one
    chained with d power / d motion (central differences, 3 x 2 evaluations over N).
    """
    per_point = power(motion, stretch)  # (N, 3)
    c, s = np.cos(per_point[:, 2]), np.sin(per_point[:, 2])
    dx, dy = p1_t[0] - per_point[:, 0], p1_t[1] - per_point[:, 1]
    q = np.stack([c * dx + s * dy, c * dy - s * dx])
    A = model.A
    P = A @ q + model.b[:, None]
    front = P[2] > 1e-9
    iz = np.divide(1.0, P[2], out=np.zeros_like(P[2]), where=front)
    m = P[:2] * iz
    dq = np.stack([np.stack([-c, s]), np.stack([-s, -c]), np.stack([q[1], -q[0]])])  # (3, 2, N)
    dP = np.einsum('ij,kjn->kin', A, dq)  # (3, 3, N)
    J_point = (dP[:, :2] - dP[:, 2:3] * m) * iz  # d m / d per-point motion, (3, 2, N)
    h = 1e-6
    D = np.empty((3, 3, len(stretch)))  # D[j, k] = d per_point_k / d motion_j
    for j in range(3):
        step = np.zeros(3)
        step[j] = h
        D[j] = ((power(motion + step, stretch) - power(motion - step, stretch)) / (2 * h)).T
    J = np.einsum('jkn,kin->jin', D, J_point)
    return m - m2_t, J, front


def refine_motion(
    motion: np.ndarray,
    p1: np.ndarray,
    m2: np.ndarray,
    model: TransferModel,
    *,
    circular: bool = False,
    iterations: int = 10,
    threshold_px: float | None = None,
    stretch: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
    """Gauss-Newton on the transfer error, in 3 DoF or on the circular 2-DoF manifold.

    With ``threshold_px`` the inliers are chosen again among all the points at every step,
    until the set no longer changes: refinement and inlier selection converge together.
    (Freezing the set earlier, chosen around a motion not yet converged, biases the result
    by about one standard deviation when the noise is near the threshold; a test pins it.)
    Without ``threshold_px`` every point is used. ``stretch`` (N,): the rolling shutter's
    (see the module docstring).

    Returns:
        (motion (3,), covariance (3, 3) of (x, y, yaw), rms inlier error in pixels, inliers
        (N,) bool). The covariance is :func:`motion_covariance` of the inliers.
    """
    motion = np.asarray(motion, dtype=float).copy()
    p1_t, m2_t = np.ascontiguousarray(p1.T, dtype=float), np.ascontiguousarray(m2.T, dtype=float)
    if circular:  # state (rho, yaw): signed travel along the chord, and yaw
        rho, yaw = motion[0] * np.cos(motion[2] / 2) + motion[1] * np.sin(motion[2] / 2), motion[2]
        motion = circular_motion(yaw, rho)
    threshold2 = np.inf if threshold_px is None else (threshold_px / model.focal_px) ** 2
    inliers, predicted_drop = np.ones(len(p1), bool), 0.0
    for i in range(iterations + 1):
        if stretch is None:
            r, J, front = _residuals_and_jacobian(motion, p1_t, m2_t, model)
        else:
            r, J, front = _residuals_and_jacobian_stretched(motion, stretch, p1_t, m2_t, model)
        squared = r[0] * r[0] + r[1] * r[1]
        selected = front & (squared < threshold2)
        changed = not np.array_equal(selected, inliers)
        inliers = selected
        count = np.count_nonzero(inliers)
        if count < 3:
            raise PoseEstimationError(f'only {count} correspondences fit the motion')
        J_in = (J * inliers).reshape(3, -1)
        JJt, g = J_in @ J.reshape(3, -1).T, J_in @ r.reshape(-1)
        if circular:
            G = _circular_jacobian(rho, yaw)
            JJt, g = G.T @ JJt @ G, G.T @ g
        if i == iterations:
            break
        step = -np.linalg.solve(JJt + 1e-15 * np.eye(len(g)), g)
        if circular:
            rho, yaw = rho + step[0], yaw + step[1]
            motion = circular_motion(yaw, rho)
        else:
            motion = motion + step
        # Converged: Gauss-Newton converges quadratically here (small residuals), so after a
        # step under 10 micrometres / microradians the next would be far below the noise.
        # The Jacobian from just before this step serves; the residual drops by the
        # linearised model's predicted amount, g . step.
        if np.max(np.abs(step)) < 1e-5 and not changed:
            predicted_drop = float(g @ step)
            break
    sum_squared = max(float(squared[inliers].sum()) + predicted_drop, 0.0)
    # Each inlier's gradient; the last step (under 10 micrometres) is left out of it.
    scores = J[:, 0] * r[0] + J[:, 1] * r[1]
    scores *= inliers
    if circular:
        scores = G.T @ scores
    covariance = motion_covariance(JJt, scores, sum_squared, count, threshold2)
    if circular:
        covariance = G @ covariance @ G.T
    rms = model.focal_px * float(np.sqrt(sum_squared / count))
    return motion, covariance, rms, inliers


def motion_covariance(information: np.ndarray, scores: np.ndarray, sum_squared: float,
                      count: int, threshold2: float = np.inf) -> np.ndarray:
    """Covariance (P, P) of a least-squares motion from its inliers' residuals.

    Args:
        information: (P, P) ``J^T J`` over the inliers (P parameters).
        scores: (P, N) each inlier's gradient ``g_i = J_i^T r_i`` (zero for the others).
        sum_squared: sum of the inliers' squared residuals (normalized units).
        count: number of inliers (2 residuals each).
        threshold2: squared inlier threshold the residuals were selected with.

    Two effects make the textbook ``sigma^2 (J^T J)^-1`` optimistic on real tracks, and both
    are corrected here. The noise differs from point to point (distortion stretches it at
    the image edges; far points are noisier on the ground), and the noisy points are the
    ones with leverage: the sandwich ``H^-1 (sum_i g_i g_i^T) H^-1`` with each point's own
    gradient follows the actual residuals instead of their average. And inliers are the
    points whose residual is under the threshold, so their spread underestimates the
    noise: for 2-D Gaussian residuals cut at radius ``tau`` the mean square is
    ``2 sigma^2 (1 - a e^-a / (1 - e^-a))``, ``a = tau^2 / (2 sigma^2)``, which is
    inverted for sigma.
    """
    n_params = len(information)
    H_inv = np.linalg.inv(information + 1e-15 * np.eye(n_params))
    dof = max(2 * count - n_params, 1)
    # (noise-free data: the small multiple of H keeps the matrix valid)
    meat = scores @ scores.T * (2 * count / dof) + 1e-14 * information
    return H_inv @ meat @ H_inv * _truncation_inflation(sum_squared / dof, threshold2)


def _truncation_inflation(mean_square: float, threshold2: float) -> float:
    """How much larger the noise variance (per axis) is than ``mean_square``.

    ``mean_square`` is the per-axis variance of residuals kept only inside the radius
    ``sqrt(threshold2)``; the noise is taken as 2-D Gaussian. Capped at 4 (residuals that
    fill the threshold's disc say little about the noise beyond it).
    """
    if not math.isfinite(threshold2) or mean_square <= 0:
        return 1.0
    # mean_square / threshold2 = kept(a) / (2 a), decreasing in a = threshold2 / (2 sigma^2)
    a = float(np.interp(mean_square / threshold2, _TRUNCATED_SQUARE, _TRUNCATION_A))
    return 1.0 / max(_kept_fraction(a), 0.25)


def _kept_fraction(a: np.ndarray | float) -> np.ndarray | float:
    """Mean square of a 2-D Gaussian cut at radius^2 = 2 a sigma^2, over 2 sigma^2."""
    return 1.0 - a * np.exp(-a) / -np.expm1(-a)


_TRUNCATION_A = np.logspace(3, -2, 2000)  # a, decreasing, so the ratio below increases
_TRUNCATED_SQUARE = _kept_fraction(_TRUNCATION_A) / (2 * _TRUNCATION_A)


def _circular_jacobian(rho: float, yaw: float) -> np.ndarray:
    """d(x, y, yaw) / d(rho, yaw) of :func:`circular_motion`, (3, 2)."""
    c, s = np.cos(yaw / 2), np.sin(yaw / 2)
    return np.array([[c, -rho / 2 * s], [s, rho / 2 * c], [0.0, 1.0]])


def _hypotheses_1point(p1: np.ndarray, p2: np.ndarray) -> np.ndarray:
    """One circular motion of the axle per correspondence, (N, 3).

    This is paper eq. 16 (:func:`planar_vo.core.geometry.solvers.homography_1point`) for the
    virtual
    level camera on the axle, whose rays are ``[-y, h, x]``: it reduces to
    ``tan(yaw / 2) = (y1 - y2) / (x1 + x2)`` and ``rho = c (x1 - x2) + s (y1 + y2)`` with
    ``(c, s)`` of ``yaw / 2``, where ``rho < 0`` is driving backwards. Written out because
    it runs for every correspondence of every frame.
    """
    half = np.arctan((p1[:, 1] - p2[:, 1]) / (p1[:, 0] + p2[:, 0]))
    c, s = np.cos(half), np.sin(half)
    rho = c * (p1[:, 0] - p2[:, 0]) + s * (p1[:, 1] + p2[:, 1])
    return np.stack([rho * c, rho * s, 2.0 * half], axis=-1)


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
    batch: int = 16,
    max_hypotheses: int | None = None,
    circular_refine: bool = False,
    scored: int = 128,
    rng: np.random.Generator | None = None,
    stretch: np.ndarray | None = None,
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
        scored: hypotheses are scored on a random subset of this many correspondences
            (enough to rank them); the refinement then uses every correspondence.
        stretch: (N,) rolling-shutter stretch of each correspondence (None: a global
            shutter). A 1-point hypothesis is then the motion between the track's two rows:
            the frame motion is it to the power ``1 / s_i``.

    Raises:
        PoseEstimationError: fewer than 3 correspondences, or no hypothesis with 3 inliers.
    """
    n = len(p1)
    if n < 3:
        raise PoseEstimationError(f'{n} ground correspondences; at least 3 are needed')
    rng = rng if rng is not None else np.random.default_rng(0)
    sample = 2 if method == '2point' else 1
    if method == 'histogram':
        hyp = _hypotheses_1point(p1, p2)
        if stretch is not None:
            hyp = power(hyp, 1.0 / stretch)
        yaw = float(np.median(hyp[:, 2]))
        # Signed travel along the chord: outliers scatter on both signs, so the median holds.
        chord = hyp[:, 0] * np.cos(hyp[:, 2] / 2) + hyp[:, 1] * np.sin(hyp[:, 2] / 2)
        best = circular_motion(yaw, float(np.median(chord)))
        tried = n
    elif method in ('1point', '2point'):
        cap = max_hypotheses or (n if sample == 1 else 20 * n)
        order = rng.permutation(n)
        subset = order[:scored]
        p1_32, m2_32 = p1[subset].astype(np.float32), m2[subset].astype(np.float32)
        s_32 = None if stretch is None else stretch[subset]
        threshold2 = np.float32((threshold_px / model.focal_px) ** 2)
        best, best_cost, best_count, tried, needed = None, np.inf, 0, 0, cap
        while tried < min(cap, needed):
            k = min(batch, cap - tried)
            if sample == 1:
                idx = order[tried:tried + k]
                hyp = _hypotheses_1point(p1[idx], p2[idx])
                if stretch is not None:
                    hyp = power(hyp, 1.0 / stretch[idx])
            else:
                pairs = _random_pairs(rng, n, k)
                hyp = _hypotheses_2point(p1, p2, model.height, pairs)
                if stretch is not None:
                    hyp = power(hyp, 1.0 / stretch[pairs].mean(axis=1))
            err2 = _squared_errors(hyp, p1_32, m2_32, model, s_32)
            # MSAC cost: inliers count by how well they fit, outliers at the threshold.
            np.minimum(err2, threshold2, out=err2)
            cost = err2.sum(axis=1)
            cost[~np.all(np.isfinite(hyp), axis=1)] = np.inf
            j = int(np.argmin(cost))
            tried += k
            if cost[j] < best_cost:
                best, best_cost = hyp[j], cost[j]
                best_count = int(np.count_nonzero(err2[j] < threshold2))
                needed = _needed_hypotheses(best_count / len(subset), sample, confidence)
    else:
        raise ValueError(f'unknown method {method!r}: use 1point, 2point or histogram')
    if best is None:
        raise PoseEstimationError('no motion hypothesis could be formed')
    motion, covariance, rms, inliers = refine_motion(
        best, p1, m2, model, circular=circular_refine, threshold_px=threshold_px, iterations=20,
        stretch=stretch)
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
