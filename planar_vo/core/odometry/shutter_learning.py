"""Which rolling-shutter readout the odometry uses, and how it comes to know it.

Three ways (:mod:`planar_vo.core.estimation.rolling_shutter` has the measurements):
configured, the readout used as given; learned (``learn_rolling_shutter``), every pair's
reading averaged until the readout is known; watched for (a global shutter configured on the
local ground, ``detect_rolling_shutter``), each pair read through the plane under the wheels
and through the local ground until a rolling shutter is found or ruled out. Until then the
configured readout is in use. Numpy only; no ROS.
"""

from __future__ import annotations

import copy
from collections.abc import Callable

import numpy as np

from planar_vo.core.estimation.ransac import RansacResult, TransferModel
from planar_vo.core.estimation.rolling_shutter import (
    ReadoutCalibrator,
    ReadoutEstimate,
    ShutterModel,
    ShutterWatch,
    contradicts,
    readout_advice,
    readout_measurement,
    readout_on_surface,
)

__all__ = ['ShutterLearning', 'SurfaceResiduals']

#: The local ground's residuals of a pair seen through a given shutter (see readout_on_surface).
SurfaceResiduals = Callable[[ShutterModel], tuple[np.ndarray, np.ndarray, np.ndarray]]


class ShutterLearning:
    """The shutter in use, and what learns or watches for its readout. Not thread-safe.

    Its parts are replaced, never changed in place (the odometry's snapshot copies them
    shallowly).
    """

    def __init__(self, readout: float, stamp: str, *, learn: bool, watch: bool) -> None:
        self.configured = ShutterModel(readout, stamp)
        self.shutter = self.configured
        self.calibrator = ReadoutCalibrator(readout) if learn else None
        self.watch = ShutterWatch() if watch and not learn and readout == 0.0 else None
        # Once the watch found a rolling shutter: what found it, and the readings since.
        self.found: ReadoutEstimate | None = None
        self.since_found: ReadoutCalibrator | None = None

    @property
    def learning(self) -> bool:
        """True while learn_rolling_shutter is on and the readout is not yet known."""
        return self.calibrator is not None and self.calibrator.usable() is None

    def wants(self, refined: bool) -> bool:
        """Whether this pair is read: always while learning, while watching on the surface."""
        return self.calibrator is not None or (self.watch is not None and refined)

    def estimate(self) -> ReadoutEstimate | None:
        """The readout learned so far (None unless learn_rolling_shutter)."""
        return None if self.calibrator is None else self.calibrator.estimate()

    def diagnostics(self) -> tuple[dict[str, str], dict[str, str]]:
        """(key/values, advice) while the readout is learned; nothing otherwise."""
        readout = self.estimate()
        if readout is None:
            return {}, {}
        configured = self.configured.readout
        values = {
            'rolling_shutter_readout estimated (ms)':
                f'{1e3 * readout.readout:.2f} +- {1e3 * readout.std:.2f}',
            'rolling_shutter_readout configured (ms)': f'{1e3 * configured:.2f}',
            'rolling_shutter_readout in use (ms)': f'{1e3 * self.shutter.readout:.2f}'}
        return values, readout_advice(configured, readout)

    def read_on_plane(self, est: RansacResult, p1: np.ndarray, m2: np.ndarray,
                      rows: tuple[np.ndarray, np.ndarray], height: int, dt: float,
                      model: TransferModel) -> None:
        """Add this pair's readout read through the plane under the wheels."""
        measured = readout_measurement(est.motion, p1, m2, (*rows, height, dt), self.shutter,
                                       model, est.inliers)
        if measured is not None:
            self.add_reading(*measured, dt)

    def read_on_surface(self, residuals: SurfaceResiduals, dt: float) -> None:
        """Add this pair's readout read through the local ground (see readout_on_surface)."""
        measured = self._on_surface(residuals)
        if measured is not None:
            self.add_reading(*measured, dt)

    def watch_pair(self, planar: RansacResult, p1: np.ndarray, m2: np.ndarray,
                   rows: tuple[np.ndarray, np.ndarray], height: int, dt: float,
                   model: TransferModel, residuals: SurfaceResiduals, step: float) -> bool:
        """Add this pair's two readings to the watch; True when a rolling shutter is found."""
        plane = readout_measurement(planar.motion, p1, m2, (*rows, height, dt), self.shutter,
                                    model, planar.inliers)
        surface = self._on_surface(residuals)
        if plane is None or surface is None:
            return False
        return self.add_watched(plane, surface, dt, step)

    def add_watched(self, plane: tuple[float, float], surface: tuple[float, float], dt: float,
                    metres: float) -> bool:
        """Add a pair's two readings (readout s, variance) to the watch; True when found.

        From then on the readout is learned as with learn_rolling_shutter, from the readings
        through the local ground so far (see ShutterWatch), and used once known to 1 ms. Not
        at once: a global shutter taken for one (a body pitching about its rear axle over all
        four terrains, found at 18 ms) lost 0.32 -> 0.88 % t_rel that way even though taken
        back 40 pairs later (:meth:`add_reading`), while the rolling shutter it helped (all
        four terrains, sprung, 30 ms) gained 3.10 -> 1.60 %.
        """
        watch = self.watch.add(plane, surface, dt, metres)
        if watch.ruled_out():
            self.watch = None
            return False
        if not watch.found():
            self.watch = watch
            return False
        self.watch = None
        self.found, self.since_found = watch.surface.estimate(), ReadoutCalibrator(0.0)
        self._take(watch.surface)
        return True

    def _on_surface(self, residuals: SurfaceResiduals) -> tuple[float, float] | None:
        """The pair's readout and its variance through the local ground, from the one in use."""
        stamp = self.shutter.stamp
        return readout_on_surface(lambda readout: residuals(ShutterModel(readout, stamp)),
                                  self.shutter.readout)

    def add_reading(self, readout: float, variance: float, dt: float) -> None:
        """Add a pair's reading (readout s, variance) to the learner (see ``calibrator``).

        After the watch found a rolling shutter, a global shutter is taken back once the
        readings since contradict it (see ``contradicts``).
        """
        calibrator = copy.copy(self.calibrator)  # replaced, never changed in place
        calibrator.add(readout, variance, dt)
        self._take(calibrator)
        if self.since_found is None:
            return
        since = copy.copy(self.since_found)
        since.add(readout, variance, dt)
        self.since_found = since
        if contradicts(self.found, since.estimate()):
            # Not a rolling shutter after all: the global shutter configured, not watched again.
            self.shutter, self.calibrator = self.configured, None
            self.found = self.since_found = None

    def _take(self, calibrator: ReadoutCalibrator) -> None:
        """Learn the readout with ``calibrator``; use its readout once known."""
        self.calibrator = calibrator
        usable = calibrator.usable()
        if usable is not None:
            self.shutter = ShutterModel(usable, self.shutter.stamp)
