"""The per-frame odometry: :class:`VisualOdometry` and the parts it orchestrates.

- :mod:`.visual_odometry`: the orchestrator (one image and its stamp in, a FrameResult out);
- :mod:`.frame_gate`: which images may be tracked (size, repeated stamps, blank, time jumps);
- :mod:`.attitude_filter`: the camera's attitude to the ground, self-calibration;
- :mod:`.pose_integrator`: pose and twist; :mod:`.covariance`: the covariance model;
- :mod:`.result`: FrameResult and FrameStatus.

The tracking front end lives in :mod:`planar_vo.core.frontend.ground_frontend`.
"""

from planar_vo.core.odometry.attitude_filter import AttitudeNoise
from planar_vo.core.odometry.result import FrameResult, FrameStatus
from planar_vo.core.odometry.visual_odometry import VisualOdometry

__all__ = ['VisualOdometry', 'FrameResult', 'FrameStatus', 'AttitudeNoise']
