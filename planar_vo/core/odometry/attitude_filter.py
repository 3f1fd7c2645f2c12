"""The camera's attitude to the ground, tracked frame to frame.

A sprung body's tilt and bounce, the rate they move at (learned), and the static mounting
(self-calibration).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from planar_vo.core.estimation.attitude import (
    AttitudePrior,
    HeightWalk,
    refine_with_attitude,
    tilted_mounting,
)
from planar_vo.core.estimation.calibration import MountingCalibrator
from planar_vo.core.estimation.ransac import PoseEstimationError, RansacResult, TransferModel
from planar_vo.core.geometry.camera import Mounting
from planar_vo.core.odometry.covariance import correlated_covariance

__all__ = ['JOLT_SIGMAS', 'AttitudeNoise', 'AttitudeFilter', 'jolt_threshold']

# How fast the body moves is learned over about this long (s); never below (rad/s, m/s).
# A rigid mount learns the floor: its tilt is then averaged over many frames. 3e-3 rad/s
# (0.1 mrad a frame at 30 Hz) let each pair's roll error, which the yaw shares, through:
# 3e-4 took the attitude on rigid mounts from 0.047 to 0.038 % on four `car` drives.
_RATE_MEMORY_S = 2.0
_MIN_RATE = np.array([3e-4, 3e-4, 1e-6])
# A tilt change of this many standard deviations (the learned rate) between two frames still
# finds its inliers: the hypotheses see both frames at frame 1's attitude.
JOLT_SIGMAS = 3.0
FIXED_HEIGHT = 1e-6  # m, m/s: the height's spread and rate when it is not estimated


def jolt_threshold(rate2: np.ndarray, inlier_threshold: float, focal_px: float,
                   dt: float) -> float:
    """The hypotheses' inlier threshold (px) through a jolt of ``JOLT_SIGMAS`` learned rates.

    ``rate2``: the squared roll and pitch rates first; ``dt``: seconds since the reference.
    """
    tilt = float(np.sqrt(rate2[0] + rate2[1])) * dt
    return max(inlier_threshold, JOLT_SIGMAS * focal_px * tilt)


@dataclass(frozen=True)
class AttitudeNoise:
    """How the camera's attitude to the ground moves: spread around its mean, and rate."""

    tilt_sigma: float  # rad
    tilt_rate: float  # rad/s
    height_sigma: float  # m
    height_rate: float  # m/s
    pivot_arm: np.ndarray = field(default_factory=lambda: np.zeros(3))  # camera - pivot, m

    @classmethod
    def from_params(cls, params: Any) -> AttitudeNoise:
        """From the ``attitude_*`` and ``bounce_*`` parameters."""
        arm = np.array([params['body_pivot_behind_camera'], 0.0,
                        params['body_pivot_below_camera']])
        if not params['estimate_height']:  # the height held at the configured one
            return cls(params['attitude_sigma'], params['attitude_rate'], FIXED_HEIGHT,
                       FIXED_HEIGHT, arm)
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


class AttitudeFilter:
    """The attitude (roll, pitch, height change) of the camera to the ground, per frame.

    Refined jointly with each motion (:func:`refine_with_attitude`), held near its learned
    mean by a prior, with the body's rate learned from what the pairs measured. With
    ``self_calibrate`` the static mounting is learned too (:class:`MountingCalibrator`).
    Its state is the attributes set in :meth:`reset` and the calibrator; each is replaced,
    never changed in place, so a shallow copy is a snapshot.
    """

    def __init__(self, noise: AttitudeNoise, mounting: Mounting, *,
                 self_calibrate: bool) -> None:
        self.noise = noise
        self.self_calibrate = self_calibrate
        self.calibrator = MountingCalibrator(mounting)
        self.reset()

    def reset(self) -> None:
        """Attitude known only as well as the body's spread around its learned mean."""
        noise = self.noise
        self.attitude = self._offset()
        self.attitude_covariance = noise.offset_cov
        self.rate2 = noise.rates ** 2
        self.rate_samples = 0
        self.height = HeightWalk(variance=noise.offset_cov[2, 2])

    def restart(self) -> None:
        """Tracking restarts: the attitude is known only to the body's spread again."""
        self.attitude_covariance = self.noise.offset_cov

    def _offset(self) -> np.ndarray:
        if not self.self_calibrate:
            return np.zeros(3)
        return np.r_[self.calibrator.mean_tilt, 0.0]

    def tilted(self, mounting: Mounting) -> Mounting:
        """``mounting`` tilted by the current attitude estimate."""
        return tilted_mounting(mounting, self.attitude, self.noise.pivot_arm)

    def hypothesis_threshold(self, inlier_threshold: float, focal_px: float,
                             dt: float) -> float:
        """Inlier threshold (px) for what sees both frames at the reference's attitude.

        ``dt``: seconds since the reference. The tilt's change since the reference (the
        learned rate) moves the points off any planar motion by up to ``JOLT_SIGMAS`` of
        it: a jolt on a rough road at 20 Hz is 0.35 deg, 5 px, and at the inlier threshold
        the hypotheses then found 3-7 inliers of 500 and the frame was lost. The joint
        refinement comes down from this threshold to the inlier threshold.
        """
        return jolt_threshold(self.rate2, inlier_threshold, focal_px, dt)

    def refine(self, est: RansacResult, rays1: np.ndarray, m2: np.ndarray,
               mounting: Mounting, model: TransferModel, *, dt: float,
               inlier_threshold: float, start_threshold: float,
               min_inliers: int) -> tuple[RansacResult, Mounting | None]:
        """Refine the motion jointly with both frames' attitude; learn the mounting.

        Returns the refined result and the self-calibrated mounting to use from now on
        (None when it did not change). Raises PoseEstimationError, before anything changes,
        when fewer than ``min_inliers`` fit.
        """
        noise = self.noise
        dt = max(dt, 1e-3)
        step_cov = np.diag(self.rate2 * dt * dt)
        prior = AttitudePrior(self.attitude, self.attitude_covariance, step_cov,
                              self._offset(), noise.offset_cov)
        v1 = rays1 @ mounting.base_from_optical.T
        joint = refine_with_attitude(
            est.motion, v1, m2, mounting, prior, focal_px=model.focal_px,
            threshold_px=inlier_threshold, start_threshold_px=start_threshold,
            arm=noise.pivot_arm)
        # A pair too thin to count as estimated must not teach the attitude, its rate, the
        # height or the mounting anything: reject it before any of them changes.
        count = int(np.count_nonzero(joint.inliers))
        if count < min_inliers:
            raise PoseEstimationError(f'{count} inliers, fewer than {min_inliers}')
        # The next pair starts from the height the changes summed to (the bounce about the
        # mean, which is the configured height and the scale), held there: how far that
        # walk may be from the truth is the step's scale uncertainty, as the step is
        # proportional to the first frame's height.
        self.height = dataclasses.replace(self.height)  # replaced, not changed in place
        scale_variance = min(self.height.error_variance, noise.offset_cov[2, 2])
        self.height.add(joint.change[2], joint.change_cov[2, 2], dt, self.rate2[2] * dt * dt)
        attitude, covariance = joint.attitude.copy(), joint.attitude_covariance.copy()
        attitude[2] = self.height.walk
        covariance[2, :] = covariance[:, 2] = 0.0
        covariance[2, 2] = FIXED_HEIGHT ** 2
        # The next pair shares most of this pair's tracks and so its tilt error: the tilt
        # carried over is believed as one of a run of correlated measurements (a rigid mount,
        # 150 frames of `straight` with 600 tracks: t_rel 0.043 -> 0.038 %).
        covariance[:2, :2] = correlated_covariance(covariance[:2, :2], dt)
        self.attitude, self.attitude_covariance = attitude, covariance
        per_metre = np.r_[joint.motion[:2], 0.0] / mounting.height
        motion_cov = joint.covariance + scale_variance * np.outer(per_metre, per_metre)
        self._learn_rate(joint.change, joint.change_cov, dt)
        calibrated = None
        if self.self_calibrate:
            # Its slip fit takes many steps: their errors are correlated.
            slip_cov = correlated_covariance(joint.covariance, dt)
            calibrated, applied = self.calibrator.step(joint.motion, slip_cov, joint.attitude, dt)
            motion_cov = motion_cov + applied
        return RansacResult(joint.motion, motion_cov, joint.inliers, est.hypotheses,
                            joint.rms_px), calibrated

    def _learn_rate(self, change: np.ndarray, change_cov: np.ndarray, dt: float) -> None:
        """How fast the body really tilts and bounces, from what each image pair measured.

        Covariance matching: the measured change's square, less its own noise, is one sample
        of the true change's variance. A rigid mount learns a rate near zero (the attitude is
        then averaged over many frames: no loss of accuracy against a fixed mounting); a
        sprung body learns its own, up to ``attitude_rate``.
        """
        sample = (change ** 2 - np.diag(change_cov)) / (dt * dt)
        self.rate_samples += 1  # the first samples replace the configured bound
        alpha = min(max(dt / _RATE_MEMORY_S, 1.0 / self.rate_samples), 1.0)
        self.rate2 = np.clip(self.rate2 + alpha * (sample - self.rate2), _MIN_RATE ** 2,
                             self.noise.rates ** 2)
