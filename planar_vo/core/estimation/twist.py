"""The body twist at the image stamp, from the motions measured between frames.

A frame-to-frame motion gives the *mean* twist over its interval, which is the twist at
the interval's middle, half a frame before the stamp: a filter reading it as the twist at
the stamp sees a biased speed whenever the vehicle accelerates. :class:`TwistAtStamp`
extrapolates the line through the last mean twists to the stamp (constant acceleration):
two, or three where the third's middle is within _FIT_SPAN_S of the stamp. Its covariance
is the measurement noise carried through that extrapolation plus what the model does not
know: the acceleration while only one interval is known, the jerk after, and where the
body jolted within an interval (a wheel lifted by a bump) the change itself.
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
# The yaw rate's 1, not 2, since stop 61: the renderer's drives reach 0.03-0.34 rad/s³ RMS
# (at most 1.06), and at 2 the three-step line below left `tight`'s NEES at 1.003.
_ACCELERATION = (4.0, 1.0, 1.0)
_JERK = (2.0, 1.0, 1.0)
# Two means extended to the stamp multiply their noise by 1.58 where it is uncorrelated (a
# constant speed on a clean image: the `straight` drive at 30 Hz with the vignetting's
# symmetric part from 3 m, 1.54x the step mean's error against the bar of 1.5); the
# least-squares line through three by 1.21, but its miss under a jerk is 2.1x theirs. Three
# are used where the oldest's middle is this close to the stamp (30 Hz: 83 ms; 20 and 15 Hz
# keep two): at 30 Hz `straight` 1.54x -> 0.99x, `tight` 0.37x, `car` 0.86x the step mean's
# error; at 15 Hz with three the jerk term took `bags/default`'s NEES to 0.53.
_FIT_SPAN_S = 0.09
# At a jolt the twist's variance takes this share of the squared change between the last two
# means. A rigid car over all four terrains (752x480, 20 Hz): the sideways speed's error at its
# 57 jolted pairs was 15 times its variance (the twist NEES 17.5 over the drive); with all of
# the change 0.53, with half 0.88 (NEES 1.15), the yaw rate's 0.32 and 0.40.
_JOLT_SHARE = 0.5


@dataclass(frozen=True)
class _Step:
    start: float
    end: float
    twist: np.ndarray  # (3,) mean over [start, end]
    covariance: np.ndarray  # (3, 3)
    jolt: bool = False  # measured where the body's motion jumped (a wheel lifted)


@dataclass(frozen=True)
class TwistAtStamp:
    """Twist at the end of the last measured interval, extrapolated with constant acceleration.

    Immutable: :meth:`add` returns the new state, so a caller can keep or drop it.
    """

    steps: tuple[_Step, ...] = ()  # the last three measured intervals, oldest first
    acceleration: tuple[float, float, float] = _ACCELERATION
    jerk: tuple[float, float, float] = _JERK

    def add(self, start: float, end: float, motion: np.ndarray,
            motion_covariance: np.ndarray, *, jolt: bool = False) -> TwistAtStamp:
        """The state after the motion (x, y, yaw) measured over ``[start, end]`` (s).

        An interval that does not start where the last one ended (tracking restarted)
        starts a new history. ``jolt``: the body's motion jumped within the interval (a
        wheel lifted by a bump): no line through the means follows it.
        """
        dt = max(end - start, 1e-6)
        twist, jac = mean_twist(np.asarray(motion, dtype=float), dt)
        step = _Step(start, end, twist, jac @ motion_covariance @ jac.T, jolt)
        adjacent = self.steps and abs(self.steps[-1].end - start) < 1e-6 * max(1.0, dt)
        return replace(self, steps=(*self.steps[-2:], step) if adjacent else (step,))

    def rate(self, end: float) -> np.ndarray | None:
        """The twist's rate of change (3,) (m/s², m/s², rad/s²) between the last two means.

        None unless two adjacent intervals are known and the last ends at ``end`` (s).
        """
        if len(self.steps) < 2 or abs(self.steps[-1].end - end) > 1e-6:
            return None
        prev, last = self.steps[-2:]
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
        oldest = self.steps[0]
        fitted = self.steps
        if len(fitted) > 2 and last.end - 0.5 * (oldest.start + oldest.end) > _FIT_SPAN_S:
            fitted = fitted[-2:]
        # Interval means sit at the midpoints (exact for constant acceleration): the least-
        # squares line through them, at the end of the last interval (t = 0; with two, the
        # line through both).
        t = np.array([0.5 * (step.start + step.end) - last.end for step in fitted])
        centred = t - t.mean()
        weights = 1.0 / len(t) - centred * t.mean() / float(centred @ centred)
        twist = sum(w * step.twist for w, step in zip(weights, fitted, strict=True))
        # A constant jerk j makes the line miss by j * miss (twist(t) = j t^2 / 2): the mean
        # of t^2 / 2 over each interval, through the same weights.
        miss = sum(w * _mean_half_square(step.start - last.end, step.end - last.end)
                   for w, step in zip(weights, fitted, strict=True))
        covariance = (sum(w * w * step.covariance for w, step in zip(weights, fitted, strict=True))
                      + np.diag((np.array(self.jerk) * miss) ** 2))
        if last.jolt:
            # A jolt's twist changes within a frame (a rear wheel climbing an 8 cm bump: the
            # body's sideways speed 0.09, 0.03, -0.08 m/s in three frames): the line misses
            # by the order of its last two means' difference.
            change = last.twist - self.steps[-2].twist
            covariance = covariance + np.diag(_JOLT_SHARE * change ** 2)
        return twist, covariance


def _mean_half_square(t0: float, t1: float) -> float:
    """Mean of t^2 / 2 over [t0, t1]."""
    return (t1 ** 3 - t0 ** 3) / (6.0 * (t1 - t0))
