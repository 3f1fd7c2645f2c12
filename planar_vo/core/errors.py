"""What the ROS-free core raises. Only the node and the CLIs turn these into messages."""

from __future__ import annotations

__all__ = ['ConfigError', 'CameraModelError', 'PoseEstimationError']


class ConfigError(ValueError):
    """A parameter file or value that cannot be used (the schema says why)."""


class CameraModelError(ValueError):
    """The calibration cannot be used (uncalibrated, unknown model, wrong coefficients)."""


class PoseEstimationError(RuntimeError):
    """Too few usable correspondences to estimate a motion (the frame gives no estimate)."""
