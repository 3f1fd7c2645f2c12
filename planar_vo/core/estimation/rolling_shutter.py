"""Rolling-shutter cameras: each image row exposed at its own time (DESIGN.md §7).

Row ``v`` (a pixel row, as the sensor reads it: the distorted image) of an ``H``-row image
with readout ``T`` is exposed at ``t + (v / H - c) T``, ``c`` = 0, 0.5 or 1 for a stamp at
the start, the middle or the end of the readout. Over a frame pair the body twist ``xi`` is
constant to first order, so the motion between a track's two observations, at rows ``v1``
(reference image, stamp ``t1``) and ``v2`` (stamp ``t2 = t1 + dt``), is

    exp(-xi tau1) M exp(xi tau2) = exp(xi (dt + tau2 - tau1)) = M ** s,
    s = 1 + (tau2 - tau1) / dt = 1 + (v2 - v1) T / (H dt),

with ``M = exp(xi dt)`` the frame motion (between the stamps): the twist is tied to the
frame motion, so the unknowns stay its 3, the 1-point hypotheses stay one correspondence
each (the motion a track gives is ``M ** s``: ``M`` is it to the power ``1 / s``) and the
refinement's Jacobian is chained through :func:`~planar_vo.core.geometry.se2.power`. The stamp
convention ``c`` cancels in ``tau2 - tau1``: it says which row's pose the stamp (and so the
published pose) is, to first order nothing more.

The readout is learned from the drive (:class:`ReadoutCalibrator`): each estimated pair
gives one Gauss-Newton step in (motion, T) from the working readout, whose T and variance
(the motion marginalised) are averaged over the drive. The shear the readout makes grows with
how far tracks move between rows: forward speed moves the near ground down the image, turns
move it across.

Numpy only; no ROS.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from planar_vo.core.estimation.ransac import TransferModel, _residuals_and_jacobian_stretched

__all__ = ['STAMP_FRACTION', 'ShutterModel', 'ReadoutEstimate', 'ReadoutCalibrator',
           'readout_measurement', 'readout_advice']

#: The stamp's place in the readout: the fraction c of the readout before it.
STAMP_FRACTION = {'start': 0.0, 'middle': 0.5, 'end': 1.0}
# A learned readout is used once known this well (s).
_APPLY_STD = 1e-3
# Users are told to change rolling_shutter_readout once the drive says it is off by this
# much (s) and knows it to a third of that.
_ADVICE = 2e-3


@dataclass(frozen=True)
class ShutterModel:
    """The camera's shutter: ``readout`` s from the first row to the last (0: global)."""

    readout: float = 0.0
    stamp: str = 'middle'

    @property
    def global_shutter(self) -> bool:
        return self.readout == 0.0

    def row_time(self, v: np.ndarray, height: int) -> np.ndarray:
        """Exposure time of pixel rows ``v`` relative to the image stamp, s."""
        return (np.asarray(v, dtype=float) / height - STAMP_FRACTION[self.stamp]) * self.readout

    def stretch(self, v1: np.ndarray, v2: np.ndarray, height: int,
                dt: float) -> np.ndarray | None:
        """Each track's ``s = 1 + (tau2 - tau1) / dt`` (None for a global shutter).

        ``v1``, ``v2``: the track's pixel rows in the reference and the current image;
        ``dt``: seconds between their stamps.
        """
        if self.global_shutter:
            return None
        return 1.0 + (self.row_time(v2, height) - self.row_time(v1, height)) / max(dt, 1e-6)

    def describe(self) -> str:
        """The shutter model, as /diagnostics says it."""
        if self.global_shutter:
            return 'global shutter'
        return (f'rolling shutter, readout {1e3 * self.readout:.2f} ms, stamp at the '
                f'{self.stamp} of the readout')


def readout_measurement(motion: np.ndarray, p1: np.ndarray, m2: np.ndarray,
                        rows: tuple[np.ndarray, np.ndarray, int, float],
                        shutter: ShutterModel, model: TransferModel,
                        inliers: np.ndarray) -> tuple[float, float] | None:
    """One pair's readout (s) and its variance, from the working ``shutter``.

    One Gauss-Newton step in (x, y, yaw, T) on the inliers' transfer errors, from
    ``motion`` (estimated with ``shutter``); the motion is marginalised out. ``rows``:
    (v1, v2, image height, dt) of the correspondences. None when the pair says nothing
    (too few inliers, no shear).
    """
    v1, v2, height, dt = rows
    n = int(np.count_nonzero(inliers))
    if n < 8:
        return None
    p1_t = np.ascontiguousarray(p1[inliers].T)
    m2_t = np.ascontiguousarray(m2[inliers].T)
    v1, v2 = v1[inliers], v2[inliers]

    def stretch(readout: float) -> np.ndarray:  # (the convention cancels: see the module)
        return 1.0 + (v2 - v1) * readout / (height * max(dt, 1e-6))

    T = shutter.readout
    r, J, front = _residuals_and_jacobian_stretched(motion, stretch(T), p1_t, m2_t, model)
    h = 1e-4
    r_plus, _, _ = _residuals_and_jacobian_stretched(motion, stretch(T + h), p1_t, m2_t, model)
    r_minus, _, _ = _residuals_and_jacobian_stretched(motion, stretch(T - h), p1_t, m2_t,
                                                      model)
    J_T = (r_plus - r_minus) / (2 * h)
    J4 = np.concatenate([J, J_T[None]]) * front  # (4, 2, N)
    J4 = J4.reshape(4, -1)
    residual = (r * front).reshape(-1)
    H = J4 @ J4.T
    if np.linalg.cond(H) > 1e14:
        return None
    H_inv = np.linalg.inv(H)
    step = -H_inv @ (J4 @ residual)
    sigma2 = float(residual @ residual) / max(2 * n - 4, 1)
    variance = float(H_inv[3, 3]) * sigma2
    if not (math.isfinite(variance) and variance > 0):
        return None
    return T + float(step[3]), variance


@dataclass(frozen=True)
class ReadoutEstimate:
    """The readout learned so far (s), its standard deviation, and the drive behind it."""

    readout: float
    std: float  # inf: nothing learned yet
    seconds: float
    pairs: int


class ReadoutCalibrator:
    """Averages the pairs' readout measurements over the drive (information-weighted).

    The pairs share errors (the same tracks, the same texture), so the standard deviation is
    the weighted mean's scaled by the measurements' own dispersion when that is larger.
    Its state is a few floats, replaced never changed in place (a shallow copy is a snapshot).
    """

    def __init__(self, configured: float) -> None:
        self.configured = configured
        self._info = 0.0
        self._weighted = 0.0
        self._weighted_sq = 0.0
        self._pairs = 0
        self._seconds = 0.0

    def add(self, readout: float, variance: float, dt: float) -> None:
        info = 1.0 / variance
        self._info += info
        self._weighted += info * readout
        self._weighted_sq += info * readout * readout
        self._pairs += 1
        self._seconds += dt

    def estimate(self) -> ReadoutEstimate:
        if self._pairs == 0:
            return ReadoutEstimate(self.configured, math.inf, 0.0, 0)
        mean = self._weighted / self._info
        chi2 = max(self._weighted_sq - self._info * mean * mean, 0.0)
        dispersion = max(1.0, chi2 / max(self._pairs - 1, 1)) if self._pairs > 2 else math.inf
        std = math.sqrt(dispersion / self._info)
        return ReadoutEstimate(max(mean, 0.0), std, self._seconds, self._pairs)

    def usable(self) -> float | None:
        """The learned readout once known to :data:`_APPLY_STD`, else None."""
        estimate = self.estimate()
        return estimate.readout if estimate.std < _APPLY_STD else None


def readout_advice(configured: float, estimate: ReadoutEstimate) -> dict[str, str]:
    """One line when the drive says ``rolling_shutter_readout`` is off (> 2 ms)."""
    off = estimate.readout - configured
    if abs(off) <= _ADVICE or not estimate.std < _ADVICE / 3:
        return {}
    return {'rolling_shutter_readout': (
        f'rolling_shutter_readout is configured as {1e3 * configured:.1f} ms but the drive '
        f'says {1e3 * estimate.readout:.1f} +- {1e3 * estimate.std:.1f} ms: set '
        f'rolling_shutter_readout: {estimate.readout:.4f} (or run planar_vo_calibrate on a '
        'recorded drive)')}
