"""What one image gave the odometry: :class:`FrameResult` and its :class:`FrameStatus`."""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np

__all__ = ['FrameStatus', 'FrameResult']


class FrameStatus(StrEnum):
    """How a frame was used; it compares and prints as its value (``'ok'``)."""

    FIRST = 'first'  # the first frame after a start or reset: tracks start here
    OK = 'ok'  # the motion since the reference frame was measured
    NO_ESTIMATE = 'no_estimate'  # tracked, but too few inliers: the pose is held
    REINITIALIZED = 'reinitialized'  # tracking was lost (or the image size changed)
    TIME_JUMP = 'time_jump'  # the stamp went backwards or jumped: tracking restarted
    BLANK = 'blank'  # a frame with nothing to track (lens cap, no exposure)
    SKIPPED = 'skipped'  # the image does not fit the CameraInfo
    DUPLICATE = 'duplicate'  # the previous frame's stamp again: nothing new to publish


@dataclass
class FrameResult:
    """What one image gave: pose in odom, body twist, covariances and stats."""

    stamp: float
    pose: np.ndarray  # (3,) x, y, yaw of base_link in odom
    pose_covariance: np.ndarray  # (3, 3) over (x, y, yaw)
    twist: np.ndarray  # (3,) vx, vy, yaw rate in base_link
    twist_covariance: np.ndarray  # (3, 3)
    status: FrameStatus
    message: str = ''  # why the frame gave no estimate
    tracks: int = 0
    correspondences: int = 0
    inliers: int = 0
    hypotheses: int = 0
    rms_px: float = 0.0
    timing_ms: dict[str, float] = field(default_factory=dict)
    inlier_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    outlier_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    stationary: bool = False  # the vehicle stands still (see planar_vo.core.odometry.standstill)
    stationary_s: float = 0.0  # for this long, s

    @property
    def estimated(self) -> bool:
        """True when this frame's motion was measured (not extrapolated or held)."""
        return self.status == FrameStatus.OK
