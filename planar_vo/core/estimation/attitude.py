"""The camera's attitude to the ground, estimated jointly with the planar motion.

A sprung body pitches, rolls and bounces, and nobody knows a mounting to better than a
degree, so the camera's rotation to the ground is not the configured one. Per frame k it is
``Rb(a_k) @ R_m``: the configured mounting ``R_m`` (optical -> base_link) tilted in base_link
by ``a_k = (roll, pitch, dh)``, with ``Rb = Ry(pitch) Rx(roll)`` (positive pitch looks down, as
the mounting's) and the camera height raised by ``dh``. base_link itself stays on the ground,
level: the odometry reports its planar motion, not the body's.

Between two frames the ground induces the general homography ``R + t n^T / d`` (DESIGN.md §6),
so the tilt of both frames is observable from the transfer error: the rotation between them
from any frame pair, the ground normal from the translation. The absolute height is not
(it is the scale): only its change is measured, and :class:`HeightWalk` sums the changes
about the configured height (the mean) into the next pair's first-frame ``dh``.

:func:`refine_with_attitude` is a two-frame sliding window: Gauss-Newton on the transfer
error over (x, y, yaw, a_1, a_2) with three priors: ``a_1`` from the previous frame's
posterior, ``a_2 - a_1`` a random walk (the body moves smoothly), and ``a_2`` near the learned
mean mounting offset. Numpy only; no ROS.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from planar_vo.core.estimation.ransac import PoseEstimationError
from planar_vo.core.geometry.camera import BODY_FROM_OPTICAL, Mounting

__all__ = ['AttitudePrior', 'HeightWalk', 'JointResult', 'body_tilt', 'tilted_mounting',
           'refine_with_attitude', 'transfer_residuals']

_E_X, _E_Y, _E_Z = np.eye(3)
# Residuals below this (px) are not believed: KLT on real images is never better.
_MIN_SIGMA_PX = 0.05


def body_tilt(roll: float, pitch: float) -> np.ndarray:
    """``Ry(pitch) @ Rx(roll)``: a tilt of the body about base_link's x and y axes, 3x3."""
    cr, sr, cp, sp = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch)
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    return ry @ rx


def tilted_mounting(mounting: Mounting, attitude: np.ndarray,
                    arm: np.ndarray | None = None) -> Mounting:
    """The Mounting whose camera is ``mounting`` tilted by ``attitude = (roll, pitch, dh)``.

    The body tilts about the pivot at ``camera - arm`` (default: the camera tilts in place).
    Exact: the composed rotation is converted back to the mounting's roll, pitch, yaw.
    """
    tilt = body_tilt(attitude[0], attitude[1])
    arm = np.zeros(3) if arm is None else np.asarray(arm, dtype=float)
    x, y, z = mounting.position - arm + tilt @ arm
    R = tilt @ mounting.base_from_optical @ BODY_FROM_OPTICAL.T
    roll = float(np.arctan2(R[2, 1], R[2, 2]))
    pitch = float(np.arcsin(np.clip(-R[2, 0], -1.0, 1.0)))
    yaw = float(np.arctan2(R[1, 0], R[0, 0]))
    return Mounting(x=float(x), y=float(y), height=float(z) + float(attitude[2]),
                    roll=roll, pitch=pitch, yaw=yaw)


@dataclass(frozen=True)
class AttitudePrior:
    """What is known of the attitude before a frame pair is seen.

    ``mean_1, cov_1``: the attitude at frame 1 (the previous posterior). ``step_cov``: how
    much it may change by frame 2 (random walk). ``offset, offset_cov``: where it stays on
    average (the learned mean mounting offset) and how far the body moves from there.
    """

    mean_1: np.ndarray  # (3,) roll, pitch (rad), dh (m)
    cov_1: np.ndarray  # (3, 3)
    step_cov: np.ndarray  # (3, 3)
    offset: np.ndarray  # (3,)
    offset_cov: np.ndarray  # (3, 3)


@dataclass
class JointResult:
    """Motion and both frames' attitudes after the joint refinement."""

    motion: np.ndarray  # (3,) x, y, yaw of base_link 2 in base_link 1
    covariance: np.ndarray  # (3, 3) marginal over (x, y, yaw)
    attitude: np.ndarray  # (3,) attitude at frame 2
    attitude_covariance: np.ndarray  # (3, 3) marginal at frame 2
    inliers: np.ndarray  # (N,) bool
    rms_px: float
    # What the image pair alone says of the attitude's change (roll, pitch, dh) from frame 1
    # to 2, without the priors, and its covariance: the innovation that tells how fast the
    # body really moves (see :meth:`planar_vo.core.odometry.VisualOdometry._learn_attitude_rate`).
    change: np.ndarray = field(default_factory=lambda: np.zeros(3))
    change_cov: np.ndarray = field(default_factory=lambda: np.eye(3))


def _ground(v1: np.ndarray, a1: np.ndarray, position: np.ndarray, arm: np.ndarray):
    """Frame-1 ground points (2, N) of base directions ``v1`` (3, N) tilted by ``a1``.

    The body tilts about a pivot ``arm`` below/behind the camera (camera - pivot), so the
    camera also moves. Also the derivatives (3, 2, N) with respect to (roll, pitch, dh),
    and where the ray meets the ground at all (N,).
    """
    Rb = body_tilt(a1[0], a1[1])
    d = Rb @ v1
    d_roll = Rb @ np.cross(_E_X, v1, axis=0)
    d_pitch = np.cross(_E_Y, d, axis=0)
    swung = Rb @ arm
    centre = position - arm + swung + np.array([0.0, 0.0, a1[2]])
    c_roll, c_pitch = Rb @ np.cross(_E_X, arm), np.cross(_E_Y, swung)
    down = d[2] < -1e-9
    h = centre[2]
    safe_z = np.where(down, d[2], -1.0)
    s = np.where(down, -h / safe_z, 0.0)
    points = centre[:2, None] + s * d[:2]
    jac = np.empty((3, 2, d.shape[1]))
    for j, (dd, dc) in enumerate(((d_roll, c_roll), (d_pitch, c_pitch))):
        jac[j] = s * (dd[:2] - d[:2] * (dd[2] / safe_z)) + dc[:2, None] - d[:2] * (dc[2] / safe_z)
    jac[2] = d[:2] * (s / h)
    return points, jac, down


def transfer_residuals(
    params: np.ndarray, v1: np.ndarray, m2: np.ndarray, mounting: Mounting,
    arm: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Residuals (2, N), Jacobian (9, 2, N) and validity (N,) of the tilted transfer.

    Args:
        params: (9,) x, y, yaw, then roll, pitch, dh of frame 1, then of frame 2.
        v1: (3, N) frame-1 rays rotated into base_link by the *configured* mounting.
        m2: (2, N) observed frame-2 normalized image coordinates.
        mounting: the configured mounting (its position and rotation).
        arm: (3,) camera position minus the body's tilt pivot, base_link (default: none,
            the camera tilts in place).
    """
    x, y, yaw = params[:3]
    a1, a2 = params[3:6], params[6:9]
    position = mounting.position
    arm = np.zeros(3) if arm is None else np.asarray(arm, dtype=float)
    p1, dp1, down = _ground(v1, a1, position, arm)
    Rb2 = body_tilt(a2[0], a2[1])
    swung_2 = Rb2 @ arm
    centre_2 = position - arm + swung_2 + np.array([0.0, 0.0, a2[2]])
    c, s = np.cos(yaw), np.sin(yaw)
    rz_t = np.array([[c, s], [-s, c]])
    q = rz_t @ (p1 - np.array([[x], [y]]))
    w = np.vstack([q - centre_2[:2, None], np.full((1, q.shape[1]), -centre_2[2])])
    rx_t = body_tilt(a2[0], 0.0).T
    ry_t = body_tilt(0.0, a2[1]).T
    optical_from_base = mounting.base_from_optical.T
    G = optical_from_base @ rx_t @ ry_t  # optical_2 from base_2 (tilted)
    u_y = ry_t @ w
    u = rx_t @ u_y
    P = optical_from_base @ u
    front = (P[2] > 1e-9) & down
    iz = np.divide(1.0, P[2], out=np.zeros_like(P[2]), where=front)
    m = P[:2] * iz
    dP = np.empty((9, 3, P.shape[1]))
    Gq = G[:, :2]
    dP[0:2] = -(Gq @ rz_t).T[:, :, None]  # d/d(x, y): q = Rz^T (p1 - t)
    dP[2] = Gq @ np.stack([q[1], -q[0]])
    Gq_rz = Gq @ rz_t
    for j in range(3):
        dP[3 + j] = Gq_rz @ dp1[j]
    # The camera also swings about the pivot: w = q - centre_2(a2).
    c_roll, c_pitch = Rb2 @ np.cross(_E_X, arm), np.cross(_E_Y, swung_2)
    dP[6] = optical_from_base @ np.stack([np.zeros_like(u[0]), u[2], -u[1]])
    dP[6] -= (G @ c_roll)[:, None]
    dP[7] = optical_from_base @ (rx_t @ -np.stack([u_y[2], np.zeros_like(u_y[0]), -u_y[0]]))
    dP[7] -= (G @ c_pitch)[:, None]
    dP[8] = -G[:, 2][:, None]
    J = (dP[:, :2] - dP[:, 2:3] * m) * iz
    return m - m2, J, front


def refine_with_attitude(
    motion: np.ndarray,
    v1: np.ndarray,
    m2: np.ndarray,
    mounting: Mounting,
    prior: AttitudePrior,
    *,
    focal_px: float,
    threshold_px: float,
    start_threshold_px: float | None = None,
    iterations: int = 10,
    arm: np.ndarray | None = None,
) -> JointResult:
    """Gauss-Newton over (motion, attitude 1, attitude 2) with the attitude priors.

    Inliers are chosen again at every step until the set settles, as in
    :func:`planar_vo.core.estimation.ransac.refine_motion`; the pixel noise that weighs the data
    against the
    priors is estimated from the inliers' residuals at every step too. The threshold starts
    at ``start_threshold_px`` and halves every step down to ``threshold_px``: a tilt that
    changed by more than the pixel noise between the frames (a jolt) moves every point off
    the start, which sees both frames at frame 1's attitude, and a tight threshold would
    then keep too few points to find it.

    Args:
        motion: (3,) starting motion (the RANSAC + 3-DoF estimate).
        v1: (N, 3) frame-1 rays in base_link through the configured mounting.
        m2: (N, 2) observed frame-2 normalized coordinates.
        threshold_px: inlier threshold on the transfer error.
        start_threshold_px: the first step's threshold (default ``threshold_px``).
        arm: (3,) camera position minus the body's tilt pivot (default: tilts in place).

    Raises:
        PoseEstimationError: fewer than 3 correspondences fit.
    """
    v1_t = np.ascontiguousarray(v1.T, dtype=float)
    m2_t = np.ascontiguousarray(m2.T, dtype=float)
    params = np.concatenate([motion, prior.mean_1, prior.mean_1])
    info_1 = np.linalg.inv(prior.cov_1)
    info_step = np.linalg.inv(prior.step_cov)
    info_offset = np.linalg.inv(prior.offset_cov)
    floor2 = (_MIN_SIGMA_PX / focal_px) ** 2
    wide = max(threshold_px, start_threshold_px or threshold_px)
    # The halvings down to threshold_px come on top of the iterations.
    iterations += int(np.ceil(np.log2(wide / threshold_px)))
    inliers = np.zeros(v1.shape[0], bool)
    for i in range(iterations + 1):
        threshold = max(threshold_px, wide * 0.5 ** i)
        threshold2 = (threshold / focal_px) ** 2
        r, J, front = transfer_residuals(params, v1_t, m2_t, mounting, arm)
        squared = r[0] * r[0] + r[1] * r[1]
        selected = front & (squared < threshold2)
        changed = not np.array_equal(selected, inliers)
        inliers = selected
        count = int(np.count_nonzero(inliers))
        if count < 3:
            raise PoseEstimationError(f'only {count} correspondences fit the tilted motion')
        # Information of one normalized coordinate: 1 / sigma^2, sigma from the residuals.
        weight = 1.0 / max(float(squared[inliers].sum()) / max(2 * count - 9, 1), floor2)
        J_in = (J * inliers).reshape(9, -1)
        H_data = weight * (J_in @ J.reshape(9, -1).T)
        g_data = weight * (J_in @ r.reshape(-1))
        H, g = H_data.copy(), g_data.copy()
        a1, a2 = params[3:6], params[6:9]
        H[3:6, 3:6] += info_1
        g[3:6] += info_1 @ (a1 - prior.mean_1)
        step_error = a2 - a1
        H[3:6, 3:6] += info_step
        H[6:9, 6:9] += info_step
        H[3:6, 6:9] -= info_step
        H[6:9, 3:6] -= info_step
        g[3:6] -= info_step @ step_error
        g[6:9] += info_step @ step_error
        H[6:9, 6:9] += info_offset
        g[6:9] += info_offset @ (a2 - prior.offset)
        if i == iterations:
            break
        step = -np.linalg.solve(H, g)
        params = params + step
        if np.max(np.abs(step)) < 1e-6 and not changed and threshold == threshold_px:
            break
    covariance = np.linalg.inv(H)
    rms = focal_px * float(np.sqrt(squared[inliers].mean()))
    change, change_cov = _data_change(params, H_data, g_data)
    return JointResult(params[:3].copy(), covariance[:3, :3].copy(), params[6:9].copy(),
                       covariance[6:9, 6:9].copy(), inliers, rms, change, change_cov)


# Everything but frame 1's height, which sets the scale (with it free, the data cannot tell
# a higher camera from a longer step).
_MEASURED = [0, 1, 2, 3, 4, 6, 7, 8]
_CHANGE = np.zeros((3, 8))
_CHANGE[[0, 1], [3, 4]], _CHANGE[[0, 1, 2], [5, 6, 7]] = -1.0, 1.0  # roll, pitch, dh: 2 - 1


def _data_change(params: np.ndarray, H_data: np.ndarray,
                 g_data: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The attitude change the data alone estimate (one Newton step), and its covariance."""
    H = H_data[np.ix_(_MEASURED, _MEASURED)]
    try:
        cov = np.linalg.inv(H)
    except np.linalg.LinAlgError:
        return np.zeros(3), np.eye(3)
    z = params[_MEASURED] - cov @ g_data[_MEASURED]
    change = _CHANGE @ z
    change[2] -= params[5]
    return change, _CHANGE @ cov @ _CHANGE.T


# The walk's leak keeps the bounce (1-3 Hz) but not its slow part (squat and dive over
# seconds): the part it misses, as a share of the walk's own variance. Measured 0.05-0.24
# on the `car` and `rough` drives (0.5 s leak); the largest is taken.
_SLOW_BOUNCE_SHARE = 0.25


@dataclass
class HeightWalk:
    """The camera height about its mean (the body's bounce), summed from the pairs' changes.

    A frame pair measures the height's *change* well (0.1-0.3 mm on the sprung scenarios) but
    not the height itself, which is the scale. The changes are summed with a leak of
    ``leak_s`` (the height about its recent mean), less their bias (KLT's, +0.02-0.06 mm a
    frame, which would pile up): the trend of the summed changes, a line fitted over
    ``bias_memory_s``. A trend, not the changes' mean: the mean over a window is the bounce's
    end minus its start over the window (0.1-0.2 mm a frame on ``rough`` over 5 s, more than
    the bias), while a line through every point of the window hardly moves for a bounce; it
    is shrunk to none by ``bias_prior`` (m/s) against the bounce's spread, so a drive's first
    seconds, which may well climb or sink, are not taken for bias. ``walk`` is the next
    pair's first-frame height. Summing from the configured height instead would take each
    frame's bounce as scale error (on ``rough``, 13 mm on 1.1 m). The walk's variance, less
    what the measurement noise gives it, is the bounce's (learned over ``variance_memory_s``
    from the configured ``variance``); the walk's error is the noise's part, the bounce's
    slow part that the leak misses, and what is left of the first frame's (it starts at the
    configured height: the bounce's whole spread).
    """

    leak_s: float = 0.5
    bias_memory_s: float = 5.0
    bias_prior: float = 0.002  # m/s: how large the bias may be, as a drift of the sum
    variance_memory_s: float = 1.0
    walk: float = 0.0  # m: the height about its recent mean
    noise_variance: float = 0.0  # m^2: what the measurement noise adds to ``walk``'s
    variance: float = 0.0  # m^2: the walk's, less the noise's (the bounce's)
    samples: int = 0
    drift: float = 0.0  # m/s: the bias, as the summed changes' trend
    start_variance: float = -1.0  # m^2: left of the first height's error (-1: ``variance``)
    # Weighted sums for the trend of the summed changes, time measured back from the last pair.
    _summed: float = 0.0
    _sums: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if self.start_variance < 0:
            self.start_variance = self.variance

    def add(self, change: float, change_variance: float, dt: float,
            true_variance: float = np.inf) -> None:
        """One pair's measured height change (m), its variance and its interval.

        ``true_variance``: how large (m^2) the body's own changes are over ``dt``. Each change
        counts by the share of it that is the body's, not the measurement's: a rigid mount
        (true changes near 0) sums nothing, and keeps the configured height.
        """
        self.samples += 1
        gain = 1.0 if np.isinf(true_variance) else true_variance / (
            true_variance + change_variance)
        self._summed += gain * change
        self.drift = self._trend(dt)
        keep = float(np.exp(-dt / self.leak_s))
        # The first pairs average over what they have: the height about the mean so far.
        keep_now = min(keep, 1.0 - 1.0 / self.samples)
        self.walk = keep_now * (self.walk + gain * change - self.drift * dt)
        self.noise_variance = keep_now * keep_now * (
            self.noise_variance + gain * gain * change_variance)
        self.start_variance *= keep * keep
        sample = self.walk * self.walk - self.noise_variance
        self.variance += min(dt / self.variance_memory_s, 1.0) * (sample - self.variance)

    def _trend(self, dt: float) -> float:
        """The summed changes' slope (m/s), a weighted line fit shrunk to none."""
        w, t, tt, y, ty = self._sums
        forget = float(np.exp(-dt / self.bias_memory_s))
        # The older points move dt further back; the new one is at time 0.
        tt = forget * (tt + 2.0 * dt * t + dt * dt * w)
        ty = forget * (ty + dt * y)
        t = forget * (t + dt * w)
        w, y = forget * w + 1.0, forget * y + self._summed
        self._sums = (w, t, tt, y, ty)
        spread_tt = tt - t * t / w
        ridge = max(self.variance, 0.0) / self.bias_prior ** 2
        if spread_tt + ridge <= 0.0:
            return 0.0
        # t counts back in time, so the slope forward in time is minus the fitted one.
        return -(ty - t * y / w) / (spread_tt + ridge)

    @property
    def error_variance(self) -> float:
        """Variance (m^2) of ``walk`` against the true height: the step's scale error."""
        return (self.noise_variance + self.start_variance
                + _SLOW_BOUNCE_SHARE * max(self.variance, 0.0))
