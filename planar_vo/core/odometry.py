"""Per-frame planar visual odometry: a grey image and its stamp in, the base_link pose out.

track (KLT) → undistort → intersect the ground (rays well below the horizon) → 1-point
RANSAC + refinement against the reference frame → metric motion of base_link → compose.
No ROS imports: the node and the replay CLI are thin adapters around :class:`VisualOdometry`.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from planar_vo.core.estimation.attitude import (
    AttitudePrior,
    HeightWalk,
    refine_with_attitude,
    tilted_mounting,
)
from planar_vo.core.estimation.calibration import (
    MountingCalibrator,
    MountingEstimate,
    calibrated_params,
    mounting_advice,
)
from planar_vo.core.estimation.opencv_motion import homography_motion
from planar_vo.core.estimation.ransac import (
    PoseEstimationError,
    RansacResult,
    TransferModel,
    estimate_motion,
    refine_motion,
    transfer_errors,
)
from planar_vo.core.estimation.twist import TwistAtStamp, twist_motion
from planar_vo.core.frontend.motion_search import GroundMotionSearch
from planar_vo.core.frontend.tracker import Tracker
from planar_vo.core.frontend.warp import GroundWarp
from planar_vo.core.geometry.camera import (
    MAX_ROUND_TRIP_PX,
    CameraModel,
    CameraModelError,
    Mounting,
    rays_through,
)

__all__ = ['VisualOdometry', 'FrameResult', 'compose', 'ground_mask']

# Variance added per second when a frame gives no estimate: a vehicle can move about this
# much (m/s, rad/s) that we did not see. Generous on purpose: a filter should distrust us.
_UNSEEN_SPEED, _UNSEEN_YAW_RATE = 2.0, 0.5
_LOST_TWIST_VARIANCE = 1e3
_MAX_FAILED_FRAMES = 3  # frames in a row without an estimate before tracking counts as lost
_RESTART_VARIANCE = (1.0, 1.0, 0.1)  # m², m², rad² added when a time jump restarts tracking
# Consecutive motions share most of their tracks and their errors are not independent.
# Two parts, measured on the rendered drives as the pose's NEES over windows of 0.25-2 s
# (test_consistency checks 1 s):
# - Errors correlated over about _ERROR_CORRELATION_S: a sum of motions over a longer window
#   has coth(dt / 2 tau) times the variance of independent ones (exponentially correlated
#   errors): 9 at 30 Hz, 4.6 at 15 Hz. Sideways and yaw NEES stay flat from 0.25 to 2 s.
# - A scale error that does not die out: along-track NEES grows with the window as N^2, not
#   N, and takes 0.02-0.034 % of the distance on every rigid drive, at every window length
#   and at 15 and 30 Hz alike (the scale ratio of whole drives says the same). A pose
#   covariance of independent increments cannot carry a persistent error at every window;
#   each step adds the variance that makes it right over _SHARED_SCALE_WINDOW_S (half as
#   much over 2 s windows, four times too much over 0.25 s).
# The pose accumulates both; the twist, one motion at a time, neither.
_ERROR_CORRELATION_S = 0.15
_SHARED_SCALE_ERROR = 3e-4
_SHARED_SCALE_WINDOW_S = 1.0
# How fast the body moves is learned over about this long (s); never below (rad/s, m/s).
# A rigid mount learns the floor: its tilt is then averaged over many frames. 3e-3 rad/s
# (0.1 mrad a frame at 30 Hz) let each pair's roll error, which the yaw shares, through:
# 3e-4 took the attitude on rigid mounts from 0.047 to 0.038 % on four `car` drives.
_RATE_MEMORY_S = 2.0
_MIN_RATE = np.array([3e-4, 3e-4, 1e-6])
# A tilt change of this many standard deviations (the learned rate) between two frames still
# finds its inliers: the hypotheses see both frames at frame 1's attitude.
_JOLT_SIGMAS = 3.0
_FIXED_HEIGHT = 1e-6  # m, m/s: the height's spread and rate when it is not estimated
_MASK_REDRAW_YAW = np.radians(0.5)
_WARPED_KLT_WINDOW = 25


@dataclass
class FrameResult:
    """What one image gave: pose in odom, body twist, covariances and stats."""

    stamp: float
    pose: np.ndarray  # (3,) x, y, yaw of base_link in odom
    pose_covariance: np.ndarray  # (3, 3) over (x, y, yaw)
    twist: np.ndarray  # (3,) vx, vy, yaw rate in base_link
    twist_covariance: np.ndarray  # (3, 3)
    # 'first', 'ok', 'no_estimate', 'reinitialized', 'time_jump', 'blank', 'skipped',
    # 'duplicate' (the stamp of the previous frame again: nothing new to publish)
    status: str
    message: str = ''  # why the frame gave no estimate
    tracks: int = 0
    correspondences: int = 0
    inliers: int = 0
    hypotheses: int = 0
    rms_px: float = 0.0
    timing_ms: dict[str, float] = field(default_factory=dict)
    inlier_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    outlier_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))

    @property
    def estimated(self) -> bool:
        """True when this frame's motion was measured (not extrapolated or held)."""
        return self.status == 'ok'


def compose(
    pose: np.ndarray, covariance: np.ndarray, motion: np.ndarray, motion_cov: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """SE(2) ``pose ∘ motion`` with first-order covariance propagation."""
    x, y, yaw = pose
    c, s = np.cos(yaw), np.sin(yaw)
    mx, my, myaw = motion
    new = np.array([x + c * mx - s * my, y + s * mx + c * my,
                    (yaw + myaw + np.pi) % (2 * np.pi) - np.pi])
    J_pose = np.array([[1.0, 0.0, -s * mx - c * my], [0.0, 1.0, c * mx - s * my],
                       [0.0, 0.0, 1.0]])
    J_motion = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return new, J_pose @ covariance @ J_pose.T + J_motion @ motion_cov @ J_motion.T


def ground_mask(camera: CameraModel, mounting: Mounting, horizon_margin: float,
                border: int = 8, *, check_round_trip: bool = False) -> np.ndarray:
    """uint8 mask (H, W) of pixels whose rays hit the ground ``horizon_margin`` below it.

    With ``check_round_trip``, a lens model that cannot be inverted where it will be used
    raises CameraModelError: undistortion gives no ray for some pixel, or undistorting and
    distorting again moves a ground pixel by more than MAX_ROUND_TRIP_PX (garbage tracks
    would follow otherwise).
    """
    step = 4
    h, w = camera.height, camera.width
    xs, ys = np.meshgrid(np.arange(0, w, step), np.arange(0, h, step))
    grid = np.stack([xs.ravel(), ys.ravel()], axis=1).astype(np.float64)
    rays = camera.rays(grid)
    _, valid = mounting.ground_points(rays, horizon_margin)
    if check_round_trip:
        _check_round_trip(camera, grid, rays, valid)
    coarse = valid.reshape(xs.shape).astype(np.uint8) * 255
    mask = cv2.resize(coarse, (xs.shape[1] * step, xs.shape[0] * step),
                      interpolation=cv2.INTER_NEAREST)[:h, :w].copy()
    mask[:border], mask[-border:], mask[:, :border], mask[:, -border:] = 0, 0, 0, 0
    return mask


def _check_round_trip(camera: CameraModel, grid: np.ndarray, rays: np.ndarray,
                      ground: np.ndarray) -> None:
    """Raise CameraModelError if ``camera`` cannot be inverted over the ground pixels."""
    where = f'{camera.distortion_model} D = {np.round(camera.D, 6).tolist()}'
    no_ray = ~np.all(np.isfinite(rays), axis=1)
    if no_ray.any():
        u, v = grid[np.argmax(no_ray)]
        raise CameraModelError(f'undistortion gives no ray at pixel ({u:.0f}, {v:.0f}) with '
                               f'{where}: check the distortion coefficients')
    if not ground.any():
        return
    error = camera.round_trip_px(grid[ground])
    worst = int(np.argmax(error))
    if error[worst] > MAX_ROUND_TRIP_PX:
        u, v = grid[ground][worst]
        raise CameraModelError(
            f'lens model cannot be inverted over the ground: undistort/distort moves pixel '
            f'({u:.0f}, {v:.0f}) by {error[worst]:.3g} px (limit {MAX_ROUND_TRIP_PX:g}) with '
            f'{where}: check the distortion coefficients and model')


class VisualOdometry:
    """Planar odometry of base_link from one ground-looking camera. Not thread-safe."""

    def __init__(
        self,
        camera: CameraModel,
        mounting: Mounting,
        *,
        tracker: Tracker | None = None,
        horizon_margin: float = np.radians(12.0),
        ransac_method: str = '1point',
        inlier_threshold: float = 0.5,
        ransac_confidence: float = 0.999,
        circular_refine: bool = False,
        min_inliers: int = 12,
        max_frame_gap: float = 1.0,
        attitude: AttitudeNoise | None = None,
        self_calibrate: bool = True,
        klt_prewarp: bool = True,
        klt_first_search: bool = True,
    ) -> None:
        # The defaults are the parameter schema's (a test holds them to it); the tracker's
        # window is the one for the warp (Tracker's own default suits KLT without it).
        self.tracker = tracker if tracker is not None else Tracker(window=_WARPED_KLT_WINDOW)
        self.horizon_margin = horizon_margin
        self.ransac_method = ransac_method
        self.inlier_threshold = inlier_threshold
        self.ransac_confidence = ransac_confidence
        self.circular_refine = circular_refine
        self.min_inliers = min_inliers
        self.max_frame_gap = max_frame_gap
        self.counters = {'frames': 0, 'estimated': 0, 'no_estimate': 0, 'reinitialized': 0,
                         'time_jumps': 0, 'blank': 0, 'skipped': 0}
        self._rng = np.random.default_rng(0)
        self.attitude_noise = attitude  # None: the mounting is taken as rigid and exact
        # Camera position minus the body's tilt pivot, base_link: the camera swings with it.
        self.pivot_arm = np.zeros(3) if attitude is None else attitude.pivot_arm
        self.self_calibrate = self_calibrate and attitude is not None
        self.klt_prewarp = klt_prewarp  # see planar_vo.core.frontend.warp
        self.klt_first_search = klt_first_search  # see planar_vo.core.frontend.motion_search
        self.configured_mounting = mounting
        self.calibrator = MountingCalibrator(mounting)
        self._update_geometry(camera, mounting, check_round_trip=True)
        self.reset()

    @classmethod
    def from_params(cls, camera: CameraModel, params: dict[str, Any]) -> VisualOdometry:
        """Build from the parameter schema's values (see :mod:`planar_vo.core.config`)."""
        tracker = Tracker(
            max_features=params['max_features'], quality_level=params['quality_level'],
            min_distance=params['min_distance'], window=params['klt_window'],
            levels=params['klt_levels'], fb_threshold=params['fb_threshold'])
        return cls(
            camera, mounting_from_params(params), tracker=tracker,
            horizon_margin=params['horizon_margin'], ransac_method=params['ransac_method'],
            inlier_threshold=params['inlier_threshold'],
            ransac_confidence=params['ransac_confidence'],
            circular_refine=params['circular_refine'], min_inliers=params['min_inliers'],
            max_frame_gap=params['max_frame_gap'],
            attitude=AttitudeNoise.from_params(params) if params['estimate_attitude'] else None,
            self_calibrate=params['self_calibrate'], klt_prewarp=params['klt_prewarp'],
            klt_first_search=params['klt_first_search'])

    def reset(self) -> None:
        """Restart at the origin with no tracks."""
        self.tracker.reset()
        self.pose = np.zeros(3)
        self.pose_covariance = np.diag([1e-9, 1e-9, 1e-9])
        self.twist = np.zeros(3)
        self.twist_covariance = np.eye(3) * _LOST_TWIST_VARIANCE
        self._twist_at_stamp = TwistAtStamp()
        self._ref_stamp: float | None = None
        self._last_stamp: float | None = None
        self._failed_frames = 0
        self._reset_attitude()
        self._warp: GroundWarp | None = None
        self._search: GroundMotionSearch | None = None

    def _reset_attitude(self) -> None:
        """Attitude known only as well as the body's spread around its learned mean."""
        noise = self.attitude_noise
        self.attitude = self._attitude_offset()
        self.attitude_covariance = noise.offset_cov if noise else np.zeros((3, 3))
        self._rate2 = noise.rates ** 2 if noise else np.zeros(3)
        self._rate_samples = 0
        self._height = HeightWalk(variance=noise.offset_cov[2, 2] if noise else 0.0)

    def _attitude_offset(self) -> np.ndarray:
        if not self.self_calibrate:
            return np.zeros(3)
        return np.r_[self.calibrator.mean_tilt, 0.0]

    def mounting_estimate(self) -> MountingEstimate:
        """The self-calibrated static mounting so far, with standard deviations."""
        return self.calibrator.estimate()

    def mounting_diagnostics(self) -> tuple[dict[str, str], dict[str, str]]:
        """(key/values for diagnostics, advice per parameter the drive says is off).

        Empty while self-calibration is off.
        """
        if not self.self_calibrate:
            return {}, {}
        estimate, configured = self.mounting_estimate(), self.configured_mounting
        now = calibrated_params(configured)
        values = {}
        for name, value in estimate.as_params().items():
            std = estimate.std[name]
            if name == 'camera_x':
                values[f'{name} estimated (m)'] = f'{value:.3f} +- {std:.3f}'
                values[f'{name} configured (m)'] = f'{now[name]:.3f}'
            else:
                values[f'{name} estimated (deg)'] = (f'{np.degrees(value):.3f} +- '
                                                     f'{np.degrees(std):.3f}')
                values[f'{name} configured (deg)'] = f'{np.degrees(now[name]):.3f}'
        values['calibration drive (s)'] = f'{estimate.seconds:.1f}'
        return values, mounting_advice(configured, estimate)

    def set_camera(self, camera: CameraModel) -> None:
        """New intrinsics (e.g. a changed CameraInfo); tracks stay.

        Tracking restarts only when the next image processed differs in size from the last
        one tracked: a camera briefly of another size (a wrong CameraInfo, then the right one
        again) costs only the frames it made unusable.

        Raises CameraModelError (and keeps the old camera) when the lens model cannot be
        inverted over the ground region.
        """
        self._update_geometry(camera, self.mounting, check_round_trip=True)

    def set_pose(self, pose: np.ndarray, covariance: np.ndarray) -> None:
        """Continue from ``pose`` (x, y, yaw in odom) with ``covariance`` (3x3); tracks stay.

        The next measured motion is composed onto it, as robot_localization's set_pose does.
        """
        self.pose = np.asarray(pose, dtype=float).reshape(3).copy()
        self.pose[2] = (self.pose[2] + np.pi) % (2 * np.pi) - np.pi
        self.pose_covariance = np.asarray(covariance, dtype=float).reshape(3, 3).copy()

    def set_mounting(self, mounting: Mounting) -> None:
        """New camera mounting (run-time parameter change); tracks stay, calibration restarts."""
        self._update_geometry(self.camera, mounting)
        self.configured_mounting = mounting
        self.calibrator = MountingCalibrator(mounting)
        self._reset_attitude()

    def diagnostics(self) -> dict[str, str]:
        """The estimator's state as /diagnostics key/values (the node adds them as they are)."""
        c, m = self.counters, self.mounting
        return {
            'frames processed': str(c['frames']), 'frames estimated': str(c['estimated']),
            'frames without estimate': str(c['no_estimate']),
            'tracking restarts': str(c['reinitialized']), 'time jumps': str(c['time_jumps']),
            'blank frames': str(c['blank']), 'frames skipped': str(c['skipped']),
            'camera mounting (x y z m, roll pitch yaw rad)': (
                f'{m.x:.3f} {m.y:.3f} {m.height:.3f}, {m.roll:.4f} {m.pitch:.4f} {m.yaw:.4f}'),
            'camera': (f'{self.camera.width}x{self.camera.height}, fx {self.camera.K[0, 0]:.1f}, '
                       f'{self.camera.distortion_model}'),
        }

    def _update_geometry(self, camera: CameraModel, mounting: Mounting, *,
                         check_round_trip: bool = False) -> None:
        """Switch to ``camera`` and ``mounting``, or change nothing if that raises."""
        mask = None
        if camera.width > 0 and camera.height > 0:
            mask = ground_mask(camera, mounting, self.horizon_margin,
                               check_round_trip=check_round_trip)
        self._model = TransferModel.from_camera(mounting, camera)
        self.camera, self.mounting, self._mask = camera, mounting, mask
        self._mask_yaw = mounting.yaw
        self.tracker.set_normalize(camera.normalize)

    def process(self, gray: np.ndarray, stamp: float) -> FrameResult:
        """Add one grey image (uint8, HxW) taken at ``stamp`` (s); return the new state.

        If anything raises, the state (tracks, stamps, pose, counters) is left as it was
        before the call and the exception propagates: a caller that survives it can go on.
        """
        saved = (dict(vars(self)), dict(vars(self.tracker)), dict(self.counters),
                 dict(vars(self.calibrator)))
        try:
            return self._process(gray, stamp)
        except BaseException:
            # Every piece of state is an attribute that is replaced, never changed in place,
            # except the counters: restoring the attributes restores the state.
            vars(self).update(saved[0])
            vars(self.tracker).update(saved[1])
            self.counters = saved[2]
            vars(self.calibrator).update(saved[3])
            raise

    def _process(self, gray: np.ndarray, stamp: float) -> FrameResult:
        t0 = time.perf_counter()
        self.counters['frames'] += 1
        h, w = gray.shape
        if self.camera.width and (self.camera.width, self.camera.height) != (w, h):
            self.counters['skipped'] += 1
            return self._result(stamp, 'skipped', t0, message=(
                f'image is {w}x{h} but CameraInfo says {self.camera.width}x'
                f'{self.camera.height} (after its binning and ROI): frame skipped'))
        if self._mask is None:
            self._update_geometry(_with_size(self.camera, gray.shape), self.mounting,
                                  check_round_trip=True)
        if self._last_stamp is not None and stamp == self._last_stamp:
            self.counters['skipped'] += 1
            return self._result(stamp, 'duplicate', t0,
                                message='duplicate stamp: frame skipped, no odometry for it')
        if float(gray[::8, ::8].std()) < 2.0:  # lens cap, no exposure: keep the tracks
            self.counters['blank'] += 1
            return self._result(stamp, 'blank', t0, message='blank image skipped')
        if self._last_stamp is not None and (
                stamp < self._last_stamp or stamp - self._last_stamp > self.max_frame_gap):
            gap = stamp - self._last_stamp
            self.counters['time_jumps'] += 1
            self._restart(stamp, extrapolate=False)
            self._detect(is_reference=True, gray=gray)
            why = (f'stamp went backwards by {-gap:.3f} s' if gap < 0 else
                   f'stamps {gap:.3f} s apart, over max_frame_gap {self.max_frame_gap:g} s')
            return self._result(stamp, 'time_jump', t0,
                                message=f'time jumped ({why}): tracking restarted')
        last = self.tracker.image_shape
        if last is not None and last != gray.shape and self._last_stamp is not None:
            self._restart(stamp, extrapolate=True)
            self._detect(is_reference=True, gray=gray)
            return self._result(stamp, 'reinitialized', t0,
                                message='image size changed: tracking restarted')
        previous, self._last_stamp = self._last_stamp, stamp
        if self._ref_stamp is None:
            self._ref_stamp = stamp
            self._detect(is_reference=True, gray=gray)
            return self._result(stamp, 'first', t0)
        mounting, model = self._current_geometry()
        motion = self._predicted_motion(gray, stamp - previous, model)
        predicted = None if motion is None else self._predict_tracks(motion, mounting, model)
        warp = None
        if predicted is not None and self.klt_prewarp and self._ref_stamp == previous:
            if self._warp is None or self._warp.camera is not self.camera:
                self._warp = GroundWarp(self.camera)
            warp = self._warp.pixel_map(model, motion)
        self.tracker.track(gray, predicted, warp)
        t_track = time.perf_counter()
        result = self._estimate(stamp, t0)
        result.timing_ms['track'] = 1e3 * (t_track - t0)
        self._detect(is_reference=result.status in ('ok', 'reinitialized'))
        result.tracks = len(self.tracker)
        result.timing_ms['total'] = 1e3 * (time.perf_counter() - t0)
        return result

    def _predicted_motion(self, gray: np.ndarray, dt: float,
                          model: TransferModel) -> np.ndarray | None:
        """The motion KLT starts from: the last twist held over ``dt``.

        With no twist to trust (the first pair after a start or a restart), the motion that
        aligns the last image with ``gray`` through the ground (``model``'s), if any.
        """
        if np.any(self.twist) and self.twist_covariance[0, 0] < _LOST_TWIST_VARIANCE:
            return twist_motion(self.twist, dt)
        if not self.klt_first_search or not len(self.tracker.points):
            return None
        if self._search is None or self._search.camera is not self.camera:
            self._search = GroundMotionSearch(self.camera)
        return self._search.search(self.tracker.last_image, gray, dt, model,
                                   self.horizon_margin)

    def _predict_tracks(self, motion: np.ndarray, mounting: Mounting,
                        model: TransferModel) -> np.ndarray | None:
        """Pixels (N, 2) where ground tracks should be after ``motion``.

        ``mounting`` and ``model``: the current geometry (:meth:`_current_geometry`).
        """
        points = self.tracker.points
        if not len(points):
            return None
        ground, valid = mounting.ground_points(rays_through(self.tracker.points_normalized))
        predicted = points.astype(np.float64)
        moved = model.transfer(motion, ground[valid])
        ok = np.all(np.isfinite(moved), axis=1)
        rows = np.flatnonzero(valid)[ok]
        predicted[rows] = self.camera.distort(moved[ok])
        return predicted

    def _window_inside(self, pixels: np.ndarray) -> np.ndarray:
        """(N,) True where the KLT window around each pixel lies inside the image.

        Where it does not, KLT lags behind the true motion (measured on the rendered
        scenarios: 0.08-0.4 px at the bottom edge with a 15 px window), which is nothing to
        a rigid 3-DoF fit but tilts the estimated ground once the attitude is estimated
        (0.06 deg of pitch, 0.25 % of scale). The rigid model keeps those tracks.
        """
        margin = self.tracker.window // 2 + 1
        u, v = pixels[:, 0], pixels[:, 1]
        return ((u >= margin) & (u < self.camera.width - margin) & (v >= margin)
                & (v < self.camera.height - margin))

    def _current_geometry(self) -> tuple[Mounting, TransferModel]:
        """The mounting tilted by the current attitude estimate, and its transfer model."""
        if self.attitude_noise is None:
            return self.mounting, self._model
        mounting = tilted_mounting(self.mounting, self.attitude, self.pivot_arm)
        return mounting, TransferModel.from_camera(mounting, self.camera)

    def _estimate(self, stamp: float, t0: float) -> FrameResult:
        idx, ref_px, cur_px = self.tracker.correspondences()
        m2 = self.tracker.points_normalized[idx]
        rays1 = rays_through(self.tracker.reference_normalized[idx])
        # Both frames seen through the attitude of the reference frame: good enough to pick
        # hypotheses and inliers; the refinement then tilts each frame on its own.
        mounting, model = self._current_geometry()
        p1, v1 = mounting.ground_points(rays1, self.horizon_margin)
        p2, v2 = mounting.ground_points(rays_through(m2), self.horizon_margin)
        ok = v1 & v2
        if self.attitude_noise is not None:
            ok &= self._window_inside(ref_px) & self._window_inside(cur_px)
        n = int(np.count_nonzero(ok))
        t_pose = time.perf_counter()
        try:
            if self.ransac_method == 'opencv_homography':
                est = self._estimate_with_opencv(p1[ok], m2[ok], model)
            else:
                est = estimate_motion(
                    p1[ok], p2[ok], m2[ok], model, method=self.ransac_method,
                    threshold_px=self._hypothesis_threshold(stamp),
                    confidence=self.ransac_confidence,
                    circular_refine=self.circular_refine, rng=self._rng)
                if self.attitude_noise is not None:
                    est = self._refine_attitude(est, rays1[ok], m2[ok], stamp, model)
            self._require_inliers(est.inliers)
        except PoseEstimationError as err:
            pose_ms = 1e3 * (time.perf_counter() - t_pose)
            self._failed_frames += 1
            # Too few tracks to ever match the reference again, or too many frames in a row
            # without a match (the surviving tracks are likely wrong): tracking is lost.
            if n < self.min_inliers or self._failed_frames > _MAX_FAILED_FRAMES:
                self._restart(stamp, extrapolate=True)
                return self._result(stamp, 'reinitialized', t0, correspondences=n,
                                    message=f'tracking lost ({err}): restarted',
                                    pose_ms=pose_ms)
            self.counters['no_estimate'] += 1
            return self._result(stamp, 'no_estimate', t0, correspondences=n, message=str(err),
                                pose_ms=pose_ms)
        pose_ms = 1e3 * (time.perf_counter() - t_pose)
        self._failed_frames = 0
        dt = stamp - self._ref_stamp
        self._ref_pose_update(est.motion, est.covariance, dt)
        self._ref_stamp = stamp
        # Tracks far off the motion are obstacles or mismatches: free their grid cells.
        errors = transfer_errors(est.motion, p1[ok], m2[ok], model)
        self.tracker.drop(idx[ok][errors > 3.0 * self.inlier_threshold])
        self.counters['estimated'] += 1
        used = cur_px[ok]
        return self._result(
            stamp, 'ok', t0, correspondences=n, inliers=int(np.count_nonzero(est.inliers)),
            hypotheses=est.hypotheses, rms_px=est.rms_px, pose_ms=pose_ms,
            inlier_points=used[est.inliers], outlier_points=used[~est.inliers])

    def _require_inliers(self, inliers: np.ndarray) -> None:
        """Raise PoseEstimationError when fewer than ``min_inliers`` fit."""
        count = int(np.count_nonzero(inliers))
        if count < self.min_inliers:
            raise PoseEstimationError(f'{count} inliers, fewer than {self.min_inliers}')

    def _estimate_with_opencv(self, p1: np.ndarray, m2: np.ndarray,
                              model: TransferModel) -> RansacResult:
        """The plain-OpenCV baseline (4-point homography), for comparison only."""
        motion, inliers = homography_motion(
            model.project(p1), m2, model.mounting,
            threshold=self.inlier_threshold / model.focal_px)
        if np.count_nonzero(inliers) < 3:
            raise PoseEstimationError('the OpenCV homography has fewer than 3 inliers')
        _, covariance, rms, _ = refine_motion(motion, p1[inliers], m2[inliers], model,
                                              iterations=0)
        return RansacResult(motion, covariance, inliers, 0, rms)

    def _hypothesis_threshold(self, stamp: float) -> float:
        """Inlier threshold (px) for what sees both frames at the reference's attitude.

        With the attitude estimated, the tilt's change since the reference (the learned
        rate) moves the points off any planar motion by up to ``_JOLT_SIGMAS`` of it: a jolt
        on a rough road at 20 Hz is 0.35 deg, 5 px, and at the inlier threshold the
        hypotheses then found 3-7 inliers of 500 and the frame was lost. The joint
        refinement comes down from this threshold to the inlier threshold.
        """
        if self.attitude_noise is None:
            return self.inlier_threshold
        tilt = float(np.sqrt(self._rate2[0] + self._rate2[1])) * (stamp - self._ref_stamp)
        return max(self.inlier_threshold, _JOLT_SIGMAS * self._model.focal_px * tilt)

    def _refine_attitude(self, est: RansacResult, rays1: np.ndarray, m2: np.ndarray,
                         stamp: float, model: TransferModel) -> RansacResult:
        """Refine the motion jointly with both frames' attitude; learn the mounting."""
        noise = self.attitude_noise
        dt = max(stamp - self._ref_stamp, 1e-3)
        step_cov = np.diag(self._rate2 * dt * dt)
        prior = AttitudePrior(self.attitude, self.attitude_covariance, step_cov,
                              self._attitude_offset(), noise.offset_cov)
        v1 = rays1 @ self.mounting.base_from_optical.T
        joint = refine_with_attitude(
            est.motion, v1, m2, self.mounting, prior, focal_px=model.focal_px,
            threshold_px=self.inlier_threshold,
            start_threshold_px=self._hypothesis_threshold(stamp), arm=self.pivot_arm)
        # A pair too thin to count as estimated must not teach the attitude, its rate, the
        # height or the mounting anything: reject it before any of them changes.
        self._require_inliers(joint.inliers)
        # The next pair starts from the height the changes summed to (the bounce about the
        # mean, which is the configured height and the scale), held there: how far that
        # walk may be from the truth is the step's scale uncertainty, as the step is
        # proportional to the first frame's height.
        # Replaced, not changed in place: process() restores attributes when a frame fails.
        self._height = dataclasses.replace(self._height)
        scale_variance = min(self._height.error_variance, noise.offset_cov[2, 2])
        self._height.add(joint.change[2], joint.change_cov[2, 2], dt, self._rate2[2] * dt * dt)
        attitude, covariance = joint.attitude.copy(), joint.attitude_covariance.copy()
        attitude[2] = self._height.walk
        covariance[2, :] = covariance[:, 2] = 0.0
        covariance[2, 2] = _FIXED_HEIGHT ** 2
        self.attitude, self.attitude_covariance = attitude, covariance
        per_metre = np.r_[joint.motion[:2], 0.0] / self.mounting.height
        motion_cov = joint.covariance + scale_variance * np.outer(per_metre, per_metre)
        self._learn_attitude_rate(joint.change, joint.change_cov, dt)
        if self.self_calibrate:
            self.calibrator.add(joint.motion, joint.covariance, joint.attitude, dt)
            if self.calibrator.apply():
                self._use_mounting(self.calibrator.working)
            # What self-calibration applied is known only so well: a yaw off by eta moves
            # the step sideways by x * eta (and rotates it), a camera_x off by dx by
            # -yaw * dx. Right for one step (the twist); the pose, which adds the steps as
            # if their errors were nearly independent, still undercounts this persistent one.
            x, y, yaw = joint.motion
            J = np.array([[-y, 0.0], [x, -yaw], [0.0, 0.0]])
            motion_cov = motion_cov + J @ self.calibrator.applied_covariance() @ J.T
        return RansacResult(joint.motion, motion_cov, joint.inliers, est.hypotheses,
                            joint.rms_px)

    def _use_mounting(self, mounting: Mounting) -> None:
        """Switch to a self-calibrated mounting.

        The ground mask (13 ms) is drawn again only when the yaw moved visibly since it was
        drawn: camera_x does not move it, and small yaws hardly do.
        """
        if abs(mounting.yaw - self._mask_yaw) > _MASK_REDRAW_YAW:
            self._update_geometry(self.camera, mounting)
        else:
            self.mounting, self._model = mounting, TransferModel.from_camera(mounting, self.camera)

    def _learn_attitude_rate(self, change: np.ndarray, change_cov: np.ndarray,
                             dt: float) -> None:
        """How fast the body really tilts and bounces, from what each image pair measured.

        Covariance matching: the measured change's square, less its own noise, is one sample
        of the true change's variance. A rigid mount learns a rate near zero (the attitude is
        then averaged over many frames: no loss of accuracy against a fixed mounting); a
        sprung body learns its own, up to ``attitude_rate``.
        """
        sample = (change ** 2 - np.diag(change_cov)) / (dt * dt)
        self._rate_samples += 1  # the first samples replace the configured bound
        alpha = min(max(dt / _RATE_MEMORY_S, 1.0 / self._rate_samples), 1.0)
        self._rate2 = np.clip(self._rate2 + alpha * (sample - self._rate2), _MIN_RATE ** 2,
                              self.attitude_noise.rates ** 2)

    def _ref_pose_update(self, motion: np.ndarray, motion_cov: np.ndarray, dt: float) -> None:
        """Compose the motion measured since the reference; the twist at the new stamp."""
        self.pose, self.pose_covariance = compose(
            self.pose, self.pose_covariance, motion,
            _shared_error_covariance(motion, motion_cov, dt))
        self._twist_at_stamp = self._twist_at_stamp.add(
            self._ref_stamp, self._ref_stamp + dt, motion, motion_cov)
        self.twist, self.twist_covariance = self._twist_at_stamp.estimate()

    def _restart(self, stamp: float, *, extrapolate: bool) -> None:
        """Restart tracking; the pose keeps going but is distrusted.

        When tracks are lost the unseen motion since the reference is extrapolated from the
        last twist; after a time jump it is not (the gap means nothing).
        """
        self.counters['reinitialized'] += 1
        gap = 0.0 if self._ref_stamp is None else max(stamp - self._ref_stamp, 0.0)
        if extrapolate and gap > 0:
            # The last twist held over the gap; the twist itself is kept as it was.
            unseen = np.diag([(_UNSEEN_SPEED * gap) ** 2] * 2 + [(_UNSEEN_YAW_RATE * gap) ** 2])
            self.pose, self.pose_covariance = compose(
                self.pose, self.pose_covariance, twist_motion(self.twist, gap), unseen)
        else:
            self.pose_covariance = self.pose_covariance + np.diag(_RESTART_VARIANCE)
        self.twist_covariance = np.eye(3) * _LOST_TWIST_VARIANCE
        self._twist_at_stamp = TwistAtStamp()  # the next measured interval starts here
        self._failed_frames = 0
        self.tracker.reset()
        if self.attitude_noise is not None:
            self.attitude_covariance = self.attitude_noise.offset_cov
        self._ref_stamp = stamp
        self._last_stamp = stamp

    def _detect(self, *, is_reference: bool, gray: np.ndarray | None = None) -> None:
        if gray is not None:
            self.tracker.track(gray)  # no tracks yet: just stores the image
        self.tracker.replenish(self._mask, is_reference=is_reference)
        if is_reference:
            self.tracker.set_reference()

    def _result(self, stamp: float, status: str, t0: float, *, message: str = '',
                correspondences: int = 0, inliers: int = 0, hypotheses: int = 0,
                rms_px: float = 0.0, pose_ms: float = 0.0,
                inlier_points: np.ndarray | None = None,
                outlier_points: np.ndarray | None = None) -> FrameResult:
        pose, cov = self.pose.copy(), self.pose_covariance.copy()
        twist, twist_cov = self.twist.copy(), self.twist_covariance.copy()
        if status != 'ok' and self._ref_stamp is not None:
            # Reported pose is the reference pose; it may have moved since, unseen.
            gap = max(stamp - self._ref_stamp, 0.0)
            cov += np.diag([(_UNSEEN_SPEED * gap) ** 2] * 2 + [(_UNSEEN_YAW_RATE * gap) ** 2])
            twist_cov = np.eye(3) * _LOST_TWIST_VARIANCE
        return FrameResult(
            stamp=stamp, pose=pose, pose_covariance=cov, twist=twist,
            twist_covariance=twist_cov, status=status, message=message,
            tracks=len(self.tracker), correspondences=correspondences, inliers=inliers,
            hypotheses=hypotheses, rms_px=rms_px,
            timing_ms={'pose': pose_ms, 'total': 1e3 * (time.perf_counter() - t0)},
            inlier_points=inlier_points if inlier_points is not None else np.zeros((0, 2)),
            outlier_points=outlier_points if outlier_points is not None else np.zeros((0, 2)))


@dataclass(frozen=True)
class AttitudeNoise:
    """How the camera's attitude to the ground moves: spread around its mean, and rate."""

    tilt_sigma: float  # rad
    tilt_rate: float  # rad/s
    height_sigma: float  # m
    height_rate: float  # m/s
    pivot_arm: np.ndarray = field(default_factory=lambda: np.zeros(3))  # camera - pivot, m

    @classmethod
    def from_params(cls, params: dict[str, Any]) -> AttitudeNoise:
        """From the ``attitude_*`` and ``bounce_*`` parameters."""
        arm = np.array([params['body_pivot_behind_camera'], 0.0,
                        params['body_pivot_below_camera']])
        if not params['estimate_height']:  # the height held at the configured one
            return cls(params['attitude_sigma'], params['attitude_rate'], _FIXED_HEIGHT,
                       _FIXED_HEIGHT, arm)
        return cls(params['attitude_sigma'], params['attitude_rate'], params['bounce_sigma'],
                   params['bounce_rate'], arm)

    @property
    def offset_cov(self) -> np.ndarray:
        """Covariance (3, 3) of the attitude around its mean."""
        return np.diag([self.tilt_sigma ** 2] * 2 + [self.height_sigma ** 2])

    @property
    def rates(self) -> np.ndarray:
        """Upper bounds (3,) of the roll, pitch (rad/s) and height (m/s) rates."""
        return np.array([self.tilt_rate, self.tilt_rate, self.height_rate])


def mounting_from_params(params: dict[str, Any]) -> Mounting:
    """The Mounting the ``camera_*`` parameters describe."""
    return Mounting(x=params['camera_x'], y=params['camera_y'], height=params['camera_height'],
                    roll=params['camera_roll'], pitch=params['camera_pitch'],
                    yaw=params['camera_yaw'])


def _shared_error_covariance(motion: np.ndarray, covariance: np.ndarray,
                             dt: float) -> np.ndarray:
    """What one motion of ``dt`` s adds to the pose's covariance, errors shared included."""
    dt = max(dt, 1e-3)
    correlated = covariance / np.tanh(dt / (2.0 * _ERROR_CORRELATION_S))
    along = np.r_[motion[:2], 0.0]
    steps_in_window = _SHARED_SCALE_WINDOW_S / dt
    return correlated + _SHARED_SCALE_ERROR ** 2 * steps_in_window * np.outer(along, along)


def _with_size(camera: CameraModel, shape: tuple[int, int]) -> CameraModel:
    return CameraModel(camera.K, camera.D, camera.distortion_model, shape[1], shape[0])

