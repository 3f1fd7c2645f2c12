"""The body twist at the image stamp, from the motions measured between frames.

A frame-to-frame motion gives the *mean* twist over its interval, which is the twist at
the interval's middle, half a frame before the stamp: a filter reading it as the twist at
the stamp sees a biased speed whenever the vehicle accelerates. :class:`TwistAtStamp`
extrapolates the last two mean twists to the stamp (constant acceleration), and its
covariance is the measurement noise carried through that extrapolation plus what the
model does not know: the acceleration while only one interval is known, the jerk after.
Numpy only; no ROS.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from planar_vo.core.geometry.se2 import mean_twist

__all__ = ['TwistAtStamp']

# What a car may do that a constant-acceleration extrapolation cannot see, per axis of
# (vx, vy, yaw rate): its acceleration (m/s², rad/s²) and jerk (m/s³, rad/s³). Generous:
# hard braking is ~8 m/s², a comfortable jerk ~1-2 m/s³; the rendered drives reach 4 m/s³.
# The jerk in vx 2, not 4, since stop 58: with the vignetting divided out the twist of
# bags/default was so much better that at 4 its NEES fell to 0.95 (1.30 at 2; 1.41 before).
_ACCELERATION = (4.0, 1.0, 1.0)
_JERK = (2.0, 1.0, 2.0)


@dataclass(frozen=True)
class _Step:
    start: float
    end: float
    twist: np.ndarray  # (3,) mean over [start, end]
    covariance: np.ndarray  # (3, 3)


@dataclass(frozen=True)
class TwistAtStamp:
    """Twist at the end of the last measured interval, extrapolated with constant acceleration.

    Immutable: :meth:`add` returns the new state, so a caller can keep or drop it.
    """

    steps: tuple[_Step, ...] = ()  # the last two measured intervals, oldest first
    acceleration: tuple[float, float, float] = _ACCELERATION
    jerk: tuple[float, float, float] = _JERK

    def add(self, start: float, end: float, motion: np.ndarray,
            motion_covariance: np.ndarray) -> TwistAtStamp:
        """The state after the motion (x, y, yaw) measured over ``[start, end]`` (s).

        An interval that does not start where the last one ended (tracking restarted)
        starts a new history.
        """
        dt = max(end - start, 1e-6)
        twist, jac = mean_twist(np.asarray(motion, dtype=float), dt)
        step = _Step(start, end, twist, jac @ motion_covariance @ jac.T)
        adjacent = self.steps and abs(self.steps[-1].end - start) < 1e-6 * max(1.0, dt)
        return replace(self, steps=(self.steps[-1], step) if adjacent else (step,))

    def rate(self, end: float) -> np.ndarray | None:
        """The twist's rate of change (3,) (m/s², m/s², rad/s²) between the last two means.

        None unless two adjacent intervals are known and the last ends at ``end`` (s).
        """
        if len(self.steps) < 2 or abs(self.steps[-1].end - end) > 1e-6:
            return None
        prev, last = self.steps
        span = 0.5 * (last.start + last.end) - 0.5 * (prev.start + prev.end)
        return (last.twist - prev.twist) / max(span, 1e-6)

    def rate_to(self, start: float, end: float, motion: np.ndarray) -> np.ndarray | None:
        """The twist's rate of change (3,) from the last interval's mean to ``motion``'s.

        ``motion`` measured over ``[start, end]`` (s), the interval after the last one (None
        when it does not start where the last one ended, or nothing is known yet).
        """
        if not self.steps or abs(self.steps[-1].end - start) > 1e-6:
            return None
        last = self.steps[-1]
        twist, _ = mean_twist(np.asarray(motion, dtype=float), max(end - start, 1e-6))
        span = 0.5 * (start + end) - 0.5 * (last.start + last.end)
        return (twist - last.twist) / max(span, 1e-6)

    def estimate(self) -> tuple[np.ndarray, np.ndarray]:
        """The twist (3,) at the end of the last interval and its covariance (3, 3)."""
        if not self.steps:
            raise ValueError('no interval measured yet')
        last = self.steps[-1]
        if len(self.steps) == 1:
            # The mean is the twist half an interval ago; the acceleration since is unknown.
            lag = 0.5 * (last.end - last.start)
            return last.twist, last.covariance + np.diag((np.array(self.acceleration) * lag) ** 2)
        prev = self.steps[0]
        # Interval means sit at the midpoints (exact for constant acceleration): extend the
        # line through them to the end of the last interval.
        mid_last, mid_prev = 0.5 * (last.start + last.end), 0.5 * (prev.start + prev.end)
        a = (last.end - mid_last) / (mid_last - mid_prev)
        twist = (1 + a) * last.twist - a * prev.twist
        # A constant jerk j makes the line miss by j * miss (twist(t) = j t^2 / 2, t = 0 at
        # the stamp): mean of t^2 / 2 over each interval, extrapolated the same way.
        miss = (1 + a) * _mean_half_square(last.start - last.end, 0.0) - a * _mean_half_square(
            prev.start - last.end, prev.end - last.end)
        covariance = ((1 + a) ** 2 * last.covariance + a ** 2 * prev.covariance
                      + np.diag((np.array(self.jerk) * miss) ** 2))
        return twist, covariance


def _mean_half_square(t0: float, t1: float) -> float:
    """Mean of t^2 / 2 over [t0, t1]."""
    return (t1 ** 3 - t0 ** 3) / (6.0 * (t1 - t0))
