"""Standstill: the vehicle stands still when its ground tracks do not move.

The test is the motion measured on the ground tracks (the 1-point RANSAC's inliers, so other
road users, off the plane and not moving with it, do not count) against zero motion, with its
covariance: ``chi2 = m^T C^-1 m`` over (x, y, yaw). ``C`` is the refinement's covariance from
the inliers' residuals; the KLT errors of one image pair share a part (illumination, the
noise of the common image), so ``chi2`` of a truly still pair is far above 3 (median ~100
on the rendered stops, 99th percentile ~300, the largest of 390 still pairs 446), while a
vehicle creeping at 2 cm/s at 20 Hz gives 760 at least (1 mm a frame; median 1800).

Hysteresis:

- *moving -> stationary*: one frame pair (measured against the previous frame) with
  ``chi2 < ENTER_CHI2``. That frame's motion is not composed and the previous frame stays the
  reference: the tracks, their positions in the reference image and the image are *held*.
- *stationary -> moving*: each frame is tracked from the held reference image directly (no
  KLT chain, so no drift however long the stop), the motion since the reference measured,
  and the vehicle moves again once ``chi2 > EXIT_CHI2``. The whole motion since the reference
  is composed then: what moved unseen during the stop (below the test) is not lost, only
  attributed to the last interval.

While stationary the twist is exactly zero with the covariance :data:`TWIST_SIGMA` (about
the speed a vehicle pulling away has when the exit test sees it: ~1 mm from rest at
2.4 m/s^2 is 2.6 cm/s), the pose is held and its covariance does not grow.
Numpy only; no ROS.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planar_vo.core.geometry.se2 import step_length

__all__ = ['Standstill', 'HeldReference', 'ENTER_CHI2', 'EXIT_CHI2', 'TWIST_SIGMA',
           'zero_motion_chi2']

ENTER_CHI2 = 150.0
EXIT_CHI2 = 600.0
TWIST_SIGMA = (0.02, 0.02, 0.01)  # m/s, m/s, rad/s: the published twist's sigma while still
# A step longer than this is never a stop, however loose its covariance: a wheel hitting a
# speed bump shakes every track off any rigid motion, and the loose fit's 0.3 m step passed
# the chi-square test (measured on a rendered drive; the held reference then lost the tracks).
MAX_STILL_STEP = 0.01  # m


def zero_motion_chi2(motion: np.ndarray, covariance: np.ndarray) -> float:
    """``m^T C^-1 m``: how far the motion (x, y, yaw) is from none, in its own covariance."""
    motion = np.asarray(motion, dtype=float)
    try:
        return float(motion @ np.linalg.solve(covariance, motion))
    except np.linalg.LinAlgError:
        return float('inf')


@dataclass(frozen=True)
class HeldReference:
    """The reference frame kept while the vehicle stands still."""

    image: np.ndarray  # the reference frame's grey image
    points: np.ndarray  # (N, 2) float32 the ground tracks' pixels in it
    normalized: np.ndarray  # (N, 2) the same, undistorted
    stamp: float  # the reference frame's stamp


class Standstill:
    """Moving or stationary, with hysteresis (see the module's docstring).

    Its state is replaced, never changed in place, so a shallow copy is a snapshot.
    """

    def __init__(self, enter_chi2: float = ENTER_CHI2, exit_chi2: float = EXIT_CHI2) -> None:
        self.enter_chi2, self.exit_chi2 = enter_chi2, exit_chi2
        self.reset()

    def reset(self) -> None:
        """Moving (nothing known): a stop is decided again from the next frame pairs."""
        self.held: HeldReference | None = None
        self.since: float | None = None  # stamp of the first stationary frame
        self.last_still: float | None = None  # stamp of the last frame found still
        self.last_motion: tuple | None = None  # (motion, covariance) since the reference then
        self.chi2 = float('nan')  # the last test's statistic

    @property
    def stationary(self) -> bool:
        return self.held is not None

    def quiet(self, motion: np.ndarray, covariance: np.ndarray,
              refined: np.ndarray | None = None) -> bool:
        """True when a frame-to-frame motion is zero within the test (moving -> stationary).

        ``refined``: the same step on the local ground, which must be as short. A jolt (a car at
        6 m/s, its front wheels on a bump) once made the rigid motion look still (7 mm, within
        the test) where the local ground saw its 0.32 m: held, the tracks were lost.
        """
        self.chi2 = zero_motion_chi2(motion, covariance)
        return (self.chi2 < self.enter_chi2 and step_length(motion) < MAX_STILL_STEP
                and (refined is None or step_length(refined) < MAX_STILL_STEP))

    def moved(self, motion: np.ndarray, covariance: np.ndarray) -> bool:
        """True when the motion since the held reference is not zero (stationary -> moving)."""
        self.chi2 = zero_motion_chi2(motion, covariance)
        return self.chi2 > self.exit_chi2

    def enter(self, held: HeldReference, stamp: float) -> None:
        """Stationary from ``stamp`` on, the reference held."""
        self.held, self.since, self.last_still = held, stamp, stamp

    def still(self, stamp: float, motion: np.ndarray, covariance: np.ndarray) -> None:
        """The frame at ``stamp`` was found still; ``motion`` since the reference."""
        self.last_still = stamp
        self.last_motion = (motion, covariance)

    def seconds(self, stamp: float | None) -> float:
        """How long the vehicle has stood still at ``stamp`` (0 while moving)."""
        if self.held is None or stamp is None or self.since is None:
            return 0.0
        return max(stamp - self.since, 0.0)

    @staticmethod
    def twist_covariance() -> np.ndarray:
        """The published twist's covariance (3, 3) while stationary."""
        return np.diag(np.square(TWIST_SIGMA))
