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

The refinements that tilt each frame (the local ground, the attitude) see a global shutter:
each track's two observations are first moved to where they would be at their frames' stamps
(:func:`at_stamp`), the vehicle carried on by the 3-DoF motion over the row's time offset.

The readout is learned from the drive (:class:`ReadoutCalibrator`): each estimated pair
gives one Gauss-Newton step from the working readout, in (motion, T, camera tilt) through the
plane (:func:`readout_measurement`) or in (motion, body rotation, the road's grade and
cross-slope, T) through the local ground (:func:`readout_on_surface`), whose T and variance
(the rest marginalised) are averaged over the drive. The shear the readout makes
grows with how far tracks move between rows: forward speed moves the near ground down the
image, turns move it across.

Numpy only; no ROS.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from planar_vo.core.estimation.attitude import tilted_mounting
from planar_vo.core.estimation.ransac import TransferModel, _residuals_and_jacobian_stretched
from planar_vo.core.geometry.camera import rays_through
from planar_vo.core.geometry.se2 import mean_twist, power

__all__ = ['STAMP_FRACTION', 'ShutterModel', 'ReadoutEstimate', 'ReadoutCalibrator',
           'ShutterWatch', 'at_stamp', 'accelerated', 'carry', 'readout_measurement',
           'readout_on_surface', 'readout_advice', 'contradicts']

#: The stamp's place in the readout: the fraction c of the readout before it.
STAMP_FRACTION = {'start': 0.0, 'middle': 0.5, 'end': 1.0}
# A learned readout is used once known this well (s), from at least this many pairs (the
# dispersion of a few pairs says little: after 7 it once claimed 1 ms and was 10 off).
_APPLY_STD = 1e-3
_APPLY_PAIRS = 20
# Users are told to change rolling_shutter_readout once the drive says it is off by this
# much (s) and knows it to a third of that.
_ADVICE = 2e-3
# A camera configured as a global shutter is found to be a rolling one when both of the
# drive's readings (ShutterWatch) are over this (s) by this many standard deviations.
_FOUND_READOUT = 8e-3
_FOUND_SIGMAS = 3.0
_FOUND_PAIRS = 40
# ... and from this much road (m) or time (s) on. A road's bend reads as a readout for as long
# as the camera sees it: the camera over all four terrains, sprung, a global shutter,
# read 22 +- 1 ms through the surface over its first 40 pairs (7 m, a vertical curve ahead)
# and was taken for a rolling shutter there (2 of 10 seeds); by 15 m both such readings had
# fallen under the bar. A rolling shutter reads the same everywhere. The time bounds the wait
# of a slow vehicle, whose shear is small.
_FOUND_METRES = 15.0
_FOUND_SECONDS = 3.0


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

    def seen_in_other(self, points: np.ndarray, rows: np.ndarray, motion: np.ndarray,
                      dt: float, pixels, height: int, *, forward: bool,
                      iterations: int = 2) -> np.ndarray:
        """Pixels (N, 2) where ground points seen at pixel ``rows`` are in the other image.

        ``points`` (N, 2): ground points in base_link at their rows' times; in the image
        before ``motion`` (``forward``: seen in the next one) or after it (seen in the
        reference one); ``motion`` over ``dt`` s between the two stamps; ``pixels``: base_link
        ground points (N, 2) to pixels (N, 2). Each point moves by the motion stretched by its
        two rows' times (see the module), the other row found by ``iterations`` fixed-point
        steps from a global shutter's.
        """
        tau = self.row_time(rows, height)
        s = np.ones(len(points))
        for _ in range(iterations + 1):
            step = power(motion, s)
            if forward:  # base_link after the motion: R^T (p - t)
                c, sn = np.cos(step[:, 2]), np.sin(step[:, 2])
                x, y = points[:, 0] - step[:, 0], points[:, 1] - step[:, 1]
                other = pixels(np.c_[c * x + sn * y, c * y - sn * x])
                s = 1.0 + (self.row_time(other[:, 1], height) - tau) / max(dt, 1e-6)
            else:
                other = pixels(carry(step, points))
                s = 1.0 + (tau - self.row_time(other[:, 1], height)) / max(dt, 1e-6)
            s = np.where(np.isfinite(s), s, 1.0)
        return other

    def describe(self) -> str:
        """The shutter model, as /diagnostics says it."""
        if self.global_shutter:
            return 'global shutter'
        return (f'rolling shutter, readout {1e3 * self.readout:.2f} ms, stamp at the '
                f'{self.stamp} of the readout')


def _exp(xi: np.ndarray) -> np.ndarray:
    """The SE(2) exponentials (N, 3) of small twists ``xi`` (N, 3) (series: |yaw| < 1e-2)."""
    vx, vy, yaw = xi[:, 0], xi[:, 1], xi[:, 2]
    sinc, cosc = 1.0 - yaw * yaw / 6.0, yaw / 2.0 - yaw ** 3 / 24.0
    return np.c_[sinc * vx - cosc * vy, cosc * vx + sinc * vy, yaw]


def _bracket(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The Lie bracket ``[a, b]`` (N, 3) of twists (N, 3) (x, y, yaw): no rotation part."""
    return np.c_[-a[:, 2] * b[:, 1] + b[:, 2] * a[:, 1], a[:, 2] * b[:, 0] - b[:, 2] * a[:, 0],
                 np.zeros(len(a))]


def carry(motion: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Points (N, 2) in the frame a motion (N, 3) ends in, in the frame it starts from."""
    c, s = np.cos(motion[:, 2]), np.sin(motion[:, 2])
    x, y = points[:, 0], points[:, 1]
    return np.c_[motion[:, 0] + c * x - s * y, motion[:, 1] + s * x + c * y]


def accelerated(points: np.ndarray, offsets: tuple[np.ndarray, np.ndarray], dt: float,
                rate: np.ndarray, twist: np.ndarray | None = None) -> np.ndarray:
    """Frame-1 ground points (N, 2) moved for a twist that changes over the pair.

    The stretch holds the twist constant; one changing at ``rate`` (3,) per second,
    ``xi(t) = xi_m + rate (t - t_m)`` about the pair's middle ``t_m``, moves a track seen at
    ``t1 + tau1`` and ``t2 + tau2`` (``offsets``, :meth:`ShutterModel.row_time`) by
    ``exp((b - a) xi_m + (b - a) tau rate)``, ``b - a = s dt``, ``tau = (tau1 + tau2) / 2``:
    ``M ** s`` after the small motion ``exp(s dt tau rate)`` (to first order). The returned
    points are the frame-1 points seen from where that small motion ends, so that ``M ** s``
    takes them to frame 2 (the estimators run unchanged). Without it, a pair's estimate
    is the motion over an interval shifted by the tracks' mean row time (6 ms for the ground
    below the middle row with a 20 ms readout): the speed and yaw rate a few ms late.
    ``twist`` (3,), the pair's (a prediction will do): the small motion is corrected for
    coming before ``M ** s`` (their commutator; 0.1 mm at 8 m/s and a yaw rate changing by
    1 rad/s per second).
    """
    tau1, tau2 = (np.asarray(t, dtype=float) for t in offsets)
    span = dt + tau2 - tau1
    small = (span * 0.5 * (tau1 + tau2))[:, None] * rate
    if twist is not None:  # exp(c) exp(a) = exp(a + b) with c = b + [a, b] / 2
        small = small + 0.5 * _bracket(span[:, None] * twist, small)
    step = _exp(small)
    # The inverse of the small motion applied to the points.
    c, s = np.cos(step[:, 2]), np.sin(step[:, 2])
    x, y = points[:, 0] - step[:, 0], points[:, 1] - step[:, 1]
    return np.c_[c * x + s * y, c * y - s * x]


def at_stamp(points: np.ndarray, offset: np.ndarray, motion: np.ndarray, dt: float,
             model: TransferModel, rate: np.ndarray | None = None,
             centre: float = 0.0, height: np.ndarray | None = None) -> np.ndarray:
    """Normalized coordinates (N, 2) of ground points seen off their frame's stamp, at it.

    ``points`` (N, 2): ground points in base_link at their rows' times, seen ``offset`` (N,)
    s after the frame's stamp (:meth:`ShutterModel.row_time`). With the twist constant over
    the pair, base_link at that time is ``motion ** (offset / dt)`` in base_link at the stamp
    (``motion`` the pair's, over ``dt`` s): the points are carried into it and projected
    with ``model`` (a global shutter's image, taken at the stamp). With the twist changing
    at ``rate`` (see :func:`accelerated`; ``centre``: the frame's stamp minus the pair's
    middle, s), base_link moves on by ``exp(offset (offset / 2 + centre) rate)`` more.
    ``height`` (N,): the points stand that far above the plane (the road ahead is not flat).
    """
    offset = np.asarray(offset, dtype=float)
    moved = power(motion, offset / max(dt, 1e-6))  # (N, 3)
    if rate is not None:  # exp(a) exp(c) = exp(a + b) with c = b - [a, b] / 2
        small = (offset * (0.5 * offset + centre))[:, None] * rate
        twist = mean_twist(np.asarray(motion, dtype=float), max(dt, 1e-6))[0]
        small = small - 0.5 * _bracket(offset[:, None] * twist, small)
        points = carry(_exp(small), points)
    return model.project(carry(moved, points), height)


def readout_measurement(motion: np.ndarray, p1: np.ndarray, m2: np.ndarray,
                        rows: tuple[np.ndarray, np.ndarray, int, float],
                        shutter: ShutterModel, model: TransferModel,
                        inliers: np.ndarray) -> tuple[float, float] | None:
    """One pair's readout (s) and its variance, from the working ``shutter``.

    One Gauss-Newton step in (x, y, yaw, T, camera roll, camera pitch) on the inliers'
    transfer errors, from ``motion`` (estimated with ``shutter`` and ``model``); all but T are
    marginalised out. The camera's tilt is free because a pitch off by 0.3 deg reads as
    18 ms of readout (on a 752x480 drive; freeing it costs 7 % of each pair's information):
    the readout must not inherit the tilt self-calibration learned, which an unmodelled
    readout itself biases. ``rows``: (v1, v2, image height, dt) of the correspondences. None
    when the pair says nothing (too few inliers, no shear).
    """
    v1, v2, height, dt = rows
    n = int(np.count_nonzero(inliers))
    if n < 8:
        return None
    rays1 = rays_through(model.project(p1[inliers]))
    m2_t = np.ascontiguousarray(m2[inliers].T)
    v1, v2 = v1[inliers], v2[inliers]

    def residuals(readout: float, tilt: tuple[float, float] = (0.0, 0.0)) -> tuple:
        # The convention cancels in the stretch (see the module).
        stretch = 1.0 + (v2 - v1) * readout / (height * max(dt, 1e-6))
        if tilt == (0.0, 0.0):
            tilted, p1_t = model, p1[inliers]
        else:
            mounting = tilted_mounting(model.mounting, np.r_[tilt, 0.0])
            tilted = TransferModel(*mounting.ground_to_optical(), model.focal_px, mounting)
            p1_t = mounting.ground_points(rays1)[0]
        return _residuals_and_jacobian_stretched(motion, stretch, np.ascontiguousarray(p1_t.T),
                                                 m2_t, tilted)

    T = shutter.readout
    r, J, front = residuals(T)
    h, a = 1e-4, 1e-4  # s, rad
    columns = [*J, (residuals(T + h)[0] - residuals(T - h)[0]) / (2 * h),
               (residuals(T, (a, 0.0))[0] - residuals(T, (-a, 0.0))[0]) / (2 * a),
               (residuals(T, (0.0, a))[0] - residuals(T, (0.0, -a))[0]) / (2 * a)]
    J6 = (np.stack(columns) * front).reshape(len(columns), -1)
    residual = (r * front).reshape(-1)
    H = J6 @ J6.T
    if not np.all(np.isfinite(H)) or np.linalg.cond(H) > 1e14:
        return None
    H_inv = np.linalg.inv(H)
    step = -H_inv @ (J6 @ residual)
    sigma2 = float(residual @ residual) / max(2 * n - len(columns), 1)
    variance = float(H_inv[3, 3]) * sigma2
    if not (math.isfinite(variance) and variance > 0):
        return None
    return T + float(step[3]), variance


def readout_on_surface(residuals: Callable[[float], tuple[np.ndarray, np.ndarray, np.ndarray]],
                       readout: float, step: float = 1e-3) -> tuple[float, float] | None:
    """One pair's readout (s) and its variance, through the local ground's refinement.

    ``residuals(T)``: the refinement's weighted residuals at its solution with the tracks
    moved to their stamps by a readout ``T``: (2, N), the Jacobian (K, 2, N) of the K
    parameters marginalised and the weights (N,). One Gauss-Newton step in (the K
    parameters, T) from ``readout``, T's derivative by central differences. Through the
    plane under the wheels with the camera's tilt free (:func:`readout_measurement`) a sprung
    body's roll and pitch and the road's grades read as readout (a rendered sprung car with a
    33 ms readout: 22.5 ms read from a readout of 0); the body's rotation and the surface's
    grade and cross-slope are marginalised here (the same car: 28.4 ms read from 0, 33.8 ms
    learned). None when the pair says nothing (too few tracks).
    """
    r, J, weights = residuals(readout)
    ahead, behind = residuals(readout + step)[0], residuals(readout - step)[0]
    used = (weights > 0.0) & np.all(np.isfinite(ahead) & np.isfinite(behind), axis=0)
    n = int(np.count_nonzero(used))
    k = len(J) + 1
    if n < 2 * k:
        return None
    column = (ahead[:, used] - behind[:, used]) / (2.0 * step)
    J_all = np.concatenate([J[:, :, used], column[None]]).reshape(k, -1)
    w = np.tile(weights[used], 2)
    residual = r[:, used].reshape(-1)
    H = (J_all * w) @ J_all.T
    if not np.all(np.isfinite(H)) or np.linalg.cond(H) > 1e14:
        return None
    H_inv = np.linalg.inv(H)
    delta = -H_inv @ ((J_all * w) @ residual)
    # The noise from the residuals before the step: a pair far from the readout in use (its
    # shear unexplained) weighs less, and its one step is the least linear (after the step:
    # seven rendered rolling-shutter drives 2.10 -> 2.36 % t_rel in sum).
    sigma2 = float(residual * w @ residual) / max(2 * n - k, 1)
    variance = float(H_inv[-1, -1]) * sigma2
    if not (math.isfinite(variance) and variance > 0):
        return None
    return readout + float(delta[-1]), variance


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
        known = estimate.std < _APPLY_STD and estimate.pairs >= _APPLY_PAIRS
        return estimate.readout if known else None


class ShutterWatch:
    """Watches a drive configured as a global shutter for a rolling shutter's shear.

    Two readings of the readout are averaged over the drive, each pair's taken from a readout
    of 0: through the plane with the camera's tilt free (:func:`readout_measurement`) and
    through the local ground (:func:`readout_on_surface`). On a global shutter each is biased
    by what it cannot model (the plane: a sprung body and the grades; the surface: the road's
    bends): over whole rendered drives by at most 10.4 and 14.4 ms (12 cm bumps, 7 % grades,
    0.45 m hills), over their first 10-15 m by up to 55 and 22 ms; rolling shutters of 20-33
    ms read 16.2-30.0 and 17.0-29.0 ms. A rolling shutter is found once both are over
    :data:`_FOUND_READOUT` by :data:`_FOUND_SIGMAS` standard deviations, from
    :data:`_FOUND_PAIRS` pairs and :data:`_FOUND_METRES` of road (or :data:`_FOUND_SECONDS`)
    on: on 43 rendered global-shutter drives that bound, the lower of the two, then reached
    8.2 ms once (the level camera, docs/rolling-shutter.md) and otherwise at most 4.5 ms; the 7
    rolling shutters were found after 45-60 pairs. A global shutter is ruled out once either is
    under the bar by as much (from 40 pairs). Replaced, never changed in place.
    """

    def __init__(self) -> None:
        self.plane = ReadoutCalibrator(0.0)
        self.surface = ReadoutCalibrator(0.0)
        self.metres = 0.0  # the road the readings were taken over

    def add(self, plane: tuple[float, float], surface: tuple[float, float], dt: float,
            metres: float) -> ShutterWatch:
        """The watch with one more pair's two readings (readout s, variance) over ``metres``."""
        watch = ShutterWatch()
        watch.plane, watch.surface = copy.copy(self.plane), copy.copy(self.surface)
        watch.plane.add(*plane, dt)
        watch.surface.add(*surface, dt)
        watch.metres = self.metres + metres
        return watch

    def found(self) -> bool:
        """Whether both readings say surely a rolling shutter."""
        far_enough = (self.metres >= _FOUND_METRES
                      or self.surface.estimate().seconds >= _FOUND_SECONDS)
        return far_enough and all(
            e.pairs >= _FOUND_PAIRS and e.readout - _FOUND_SIGMAS * e.std > _FOUND_READOUT
            for e in (self.plane.estimate(), self.surface.estimate()))

    def ruled_out(self) -> bool:
        """Whether either reading says surely no rolling shutter the watch would find."""
        return any(e.pairs >= _FOUND_PAIRS and e.readout + _FOUND_SIGMAS * e.std < _FOUND_READOUT
                   for e in (self.plane.estimate(), self.surface.estimate()))


def contradicts(found: ReadoutEstimate, since: ReadoutEstimate) -> bool:
    """Whether the readings since a rolling shutter was found say it was not one.

    A rolling shutter reads the same everywhere; a global shutter found for one read what the
    road or the body did over its first metres. Found is retracted once the readings since are
    below those that found it by more than :data:`_FOUND_READOUT`, by :data:`_FOUND_SIGMAS`
    of their standard deviation, over :data:`_FOUND_PAIRS` pairs: a sprung body pitching about
    its rear axle over all four terrains (a global shutter) was found at 18.3 +- 1.1 ms and
    read 0 +- 1.2 ms over the 40 pairs after; eight rolling shutters of 20-33 ms read 0.92-1.21
    times what found them for the rest of their drives.
    """
    return (since.pairs >= _FOUND_PAIRS
            and since.readout + _FOUND_SIGMAS * since.std < found.readout - _FOUND_READOUT)


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
