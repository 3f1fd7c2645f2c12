"""The covariance model of the odometry.

What a measured motion, a lost frame and a restart add to the pose's uncertainty.

Consecutive motions share most of their tracks and their errors are not independent.
Two parts, measured on the rendered drives as the pose's NEES over windows of 0.25-2 s
(test_consistency checks 1 s):

- Errors correlated over about ``ERROR_CORRELATION_S``: a sum of motions over a longer window
  has coth(dt / 2 tau) times the variance of independent ones (exponentially correlated
  errors): 9 at 30 Hz, 4.6 at 15 Hz. Sideways and yaw NEES stay flat from 0.25 to 2 s.
- A scale error that does not die out: along-track NEES grows with the window as N^2, not
  N, and takes 0.02-0.034 % of the distance on every rigid drive, at every window length
  and at 15 and 30 Hz alike (the scale ratio of whole drives says the same). A pose
  covariance of independent increments cannot carry a persistent error at every window;
  each step adds the variance that makes it right over ``SHARED_SCALE_WINDOW_S`` (half as
  much over 2 s windows, four times too much over 0.25 s).

The pose accumulates both; the twist, one motion at a time, neither.
"""

from __future__ import annotations

import numpy as np

__all__ = ['correlated_covariance', 'shared_error_covariance', 'unseen_motion_covariance',
           'LOST_TWIST_VARIANCE', 'RESTART_VARIANCE']

# Variance added per second when a frame gives no estimate: a vehicle can move about this
# much (m/s, rad/s) that we did not see. Generous on purpose: a filter should distrust us.
UNSEEN_SPEED, UNSEEN_YAW_RATE = 2.0, 0.5
LOST_TWIST_VARIANCE = 1e3
RESTART_VARIANCE = (1.0, 1.0, 0.1)  # m², m², rad² added when a time jump restarts tracking
ERROR_CORRELATION_S = 0.15
SHARED_SCALE_ERROR = 3e-4
SHARED_SCALE_WINDOW_S = 1.0


def correlated_covariance(covariance: np.ndarray, dt: float) -> np.ndarray:
    """A motion's covariance as one of a run of motions whose errors are correlated.

    What a sum of them over a window longer than ``ERROR_CORRELATION_S`` has per motion
    (coth(dt / 2 tau) times the independent one's): what the pose accumulates, and what a fit
    over many motions (self-calibration) must take each as.
    """
    return covariance / np.tanh(max(dt, 1e-3) / (2.0 * ERROR_CORRELATION_S))


def shared_error_covariance(motion: np.ndarray, covariance: np.ndarray,
                            dt: float) -> np.ndarray:
    """What one motion (3,) of ``dt`` s adds to the pose's covariance (3, 3).

    The errors it shares with the neighbouring motions included.
    """
    dt = max(dt, 1e-3)
    correlated = correlated_covariance(covariance, dt)
    along = np.r_[motion[:2], 0.0]
    steps_in_window = SHARED_SCALE_WINDOW_S / dt
    return correlated + SHARED_SCALE_ERROR ** 2 * steps_in_window * np.outer(along, along)


def unseen_motion_covariance(gap: float) -> np.ndarray:
    """Covariance (3, 3) of the motion a vehicle may make unseen over ``gap`` s."""
    return np.diag([(UNSEEN_SPEED * gap) ** 2] * 2 + [(UNSEEN_YAW_RATE * gap) ** 2])
