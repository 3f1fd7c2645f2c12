"""The base_link pose in odom and the body twist at the last stamp, with covariances."""

from __future__ import annotations

import numpy as np

from planar_vo.core.estimation.twist import TwistAtStamp
from planar_vo.core.geometry.se2 import compose, twist_motion
from planar_vo.core.odometry.covariance import (
    LOST_TWIST_VARIANCE,
    RESTART_VARIANCE,
    shared_error_covariance,
    unseen_motion_covariance,
)

__all__ = ['PoseIntegrator']


class PoseIntegrator:
    """Composes the measured motions into the pose; the twist at each measured stamp.

    Its state is the five attributes set in :meth:`reset`, each replaced by every change
    (never changed in place), so a shallow copy is a snapshot.
    """

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        """At the origin, known exactly; no twist."""
        self.pose = np.zeros(3)
        self.pose_covariance = np.diag([1e-9, 1e-9, 1e-9])
        self.twist = np.zeros(3)
        self.twist_covariance = np.eye(3) * LOST_TWIST_VARIANCE
        self.twist_at_stamp = TwistAtStamp()

    @property
    def twist_known(self) -> bool:
        """True when the last twist was measured (it can predict the next motion)."""
        return bool(np.any(self.twist)) and self.twist_covariance[0, 0] < LOST_TWIST_VARIANCE

    def add(self, start: float, dt: float, motion: np.ndarray, motion_cov: np.ndarray, *,
            jolt: bool = False) -> None:
        """Compose the motion measured from ``start`` over ``dt`` s; the twist at its end.

        ``jolt``: the body's motion jumped within the interval (TwistAtStamp.add).
        """
        self.pose, self.pose_covariance = compose(
            self.pose, self.pose_covariance, motion,
            shared_error_covariance(motion, motion_cov, dt))
        self.twist_at_stamp = self.twist_at_stamp.add(start, start + dt, motion, motion_cov,
                                                      jolt=jolt)
        self.twist, self.twist_covariance = self.twist_at_stamp.estimate()

    def hold(self, start: float, end: float, motion_cov: np.ndarray,
             twist_cov: np.ndarray) -> None:
        """The vehicle stood still over ``[start, end]``: the pose and its covariance stay.

        The twist is exactly zero with ``twist_cov``.
        The interval is a zero motion (covariance ``motion_cov``) for the twist of the next
        measured interval, which extrapolates from it.
        """
        self.twist_at_stamp = self.twist_at_stamp.add(start, end, np.zeros(3), motion_cov)
        self.twist = np.zeros(3)
        self.twist_covariance = np.asarray(twist_cov, dtype=float).copy()

    def restart(self, gap: float, *, extrapolate: bool) -> None:
        """Tracking restarts; the pose keeps going but is distrusted.

        When tracks are lost the unseen motion over ``gap`` is extrapolated from the last
        twist; after a time jump it is not (the gap means nothing).
        """
        if extrapolate and gap > 0:
            # The last twist held over the gap; the twist itself is kept as it was.
            self.pose, self.pose_covariance = compose(
                self.pose, self.pose_covariance, twist_motion(self.twist, gap),
                unseen_motion_covariance(gap))
        else:
            self.pose_covariance = self.pose_covariance + np.diag(RESTART_VARIANCE)
        self.twist_covariance = np.eye(3) * LOST_TWIST_VARIANCE
        self.twist_at_stamp = TwistAtStamp()  # the next measured interval starts here

    def set_pose(self, pose: np.ndarray, covariance: np.ndarray) -> None:
        """Continue from ``pose`` (x, y, yaw in odom) with ``covariance`` (3x3)."""
        self.pose = np.asarray(pose, dtype=float).reshape(3).copy()
        self.pose[2] = (self.pose[2] + np.pi) % (2 * np.pi) - np.pi
        self.pose_covariance = np.asarray(covariance, dtype=float).reshape(3, 3).copy()

    def reported(self, unseen_gap: float | None) -> tuple[np.ndarray, ...]:
        """(pose, covariance, twist, twist covariance) copies to report.

        ``unseen_gap``: seconds since the reference for a frame that measured nothing (the
        pose held may have moved since, unseen); None for a measured frame.
        """
        pose, cov = self.pose.copy(), self.pose_covariance.copy()
        twist, twist_cov = self.twist.copy(), self.twist_covariance.copy()
        if unseen_gap is not None:
            cov += unseen_motion_covariance(unseen_gap)
            twist_cov = np.eye(3) * LOST_TWIST_VARIANCE
        return pose, cov, twist, twist_cov
