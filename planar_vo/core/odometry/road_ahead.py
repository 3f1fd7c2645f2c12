"""The road the camera has seen and the wheels have yet to reach.

Two memories of it, moved on with the vehicle pair by pair: the bumps found square across the
path as bands off the smooth surface (:class:`~planar_vo.core.odometry.bumps_ahead.BumpsAhead`)
and the ground seen above the road, cell by cell
(:class:`~planar_vo.core.odometry.raised_ground.RaisedGround`). When the front wheels reach
what was seen, they stand that high: the local surface is hinged there at that height
(:meth:`RoadAhead.hinge`). Frozen, each pair makes a new one, so the ground filter's shallow
copy stays a snapshot. Numpy only; no ROS.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from planar_vo.core.estimation.local_ground import Hinge, LocalGroundResult
from planar_vo.core.geometry.camera import Mounting
from planar_vo.core.odometry.bumps_ahead import BumpsAhead
from planar_vo.core.odometry.raised_ground import RaisedGround
from planar_vo.core.odometry.surface_bands import (
    BAND_M,
    bands_of,
    flow_excess,
    track_noise,
    wheel_plane_lateral,
)

__all__ = ['RoadAhead']

# Bumps are looked for (bands_of) once the rates are learned (from _BUMP_PAIRS pairs), on
# pairs driving forward without a lift, over a surface whose curvatures are under
# _RAISED_CURVATURE; over _BUMP_CURVATURE (1/m) a band is a bump only once a later pair's band
# confirms it (BumpsAhead, _CONFIRM). With the surface through the centre line, one band at
# 0.01 /m found bands of hills for bumps (all four 0.18 -> 0.28 %); through the wheels'
# contacts (stop 36), 34 rendered drives 5.10 -> 4.78 in sum at 0.01, 4.89 at 0.0075, 4.84 at
# 0.015, 5.14 at 0.02. Stop 51, bands confirmed over 0.01 (none looked for there before): 93
# drives 20.89 -> 20.46 % summed (14 better by over 0.02, 13 worse), the 20 held-out all-four
# sprung drives 14 -> 18 of 20 at or under 0.2 %; searched on to 0.03 or 0.05 /m, 20.41 and
# 20.65.
_BUMP_PAIRS = 10
_BUMP_CURVATURE = 0.01
# The raised ground's samples (RaisedGround) are taken on road curved up to this (1/m): a cell
# counts only from several samples of several pairs, which a hill's bend does not make. The 60
# rendered drives 5.907 -> 5.742 in sum at 0.02 (5.779 at 0.015, 5.873 at 0.03; with RANSAC's
# seed 1 5.998 -> 5.877), steep hills with bumps 0.363 -> 0.318; two 10 Hz drives worse.
_RAISED_CURVATURE = 0.02
# m: the front wheels' height on a bump that counts as known (from a band, or to sample under)
_KNOWN_HEIGHT = 0.005


@dataclass(frozen=True)
class RoadAhead:
    """Bumps and raised ground ahead, in base_link.

    ``raised_seen``: the raised ground with the last pair's samples, taken on when the vehicle
    moves on (:meth:`moved`): the pair's fit may yet be refused.
    """

    bumps: BumpsAhead = field(default_factory=BumpsAhead)
    raised: RaisedGround = field(default_factory=RaisedGround)
    raised_seen: RaisedGround | None = None
    # The raised ground under the front wheels, read once: the hinge is asked for several
    # times a pair, and this instance's samples never change.
    _under: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def hinge(self, at: float, track: float, camera_height: float) -> Hinge:
        """Where the surface meets the front wheels (``at`` m ahead of base_link), how high.

        A bump found ahead as a band (square across the path) gives the front wheels' height
        while they are on it; otherwise the raised ground seen under each front wheel
        (``track`` apart) does (a bump crossed at an angle: 34 rendered drives 3.47 -> 3.22 %
        t_rel summed, stop 41). ``camera_height``: m over the wheel plane, for the samples'
        heights.
        """
        height = -self.bumps.front_height
        if not (self.bumps.at_front(at) or self.bumps.front_height > _KNOWN_HEIGHT):
            under = self._raised_under_wheels(at, track, camera_height)
            if np.any(under > 0.0):
                height = min(height, -float(np.mean(under)))
        return Hinge(at, track, height)

    def _raised_under_wheels(self, at: float, track: float, camera_height: float) -> np.ndarray:
        """How far (m) the ground under the left and the right front wheel is raised (2,)."""
        key = (at, track, camera_height)
        if key not in self._under:
            wheels = np.array([[at, 0.5 * track], [at, -0.5 * track]])
            self._under.clear()
            self._under[key] = self.raised.height_at(wheels, camera_height)
        return self._under[key]

    def after_pair(self, fit: LocalGroundResult, surface: np.ndarray, *, lifted: bool,
                   rate_samples: int, rays1: np.ndarray, v1: np.ndarray, m2: np.ndarray,
                   camera: Mounting, hinge: Hinge, distance: np.ndarray,
                   focal_px: float) -> RoadAhead:
        """Self after a pair: the bumps and raised ground it shows, the front wheels' height.

        ``surface``: the pair's prior surface (the smooth road the bands stand out from);
        ``lifted``: the pair lifted a wheel (then the front axle's rise over the smooth road
        is the front wheels' climb); ``rate_samples``: how many pairs the body's rate has
        learned from; ``rays1``, ``v1``, ``m2``, ``distance``: the pair's tracks (rays in the
        camera and in base_link, second image points, where the rays meet the wheel plane);
        ``focal_px``: the tracks' noise in pixels is the fit's, their flow is normalized.
        """
        bumps, raised_seen = self.bumps, self.raised_seen
        curvature = float(np.max(np.abs(surface[2:])))
        if (not lifted and rate_samples >= _BUMP_PAIRS and fit.motion[0] > 0.0
                and curvature < _RAISED_CURVATURE):
            excess, usable, flow = flow_excess(fit.motion, fit.rotation, surface, v1,
                                               rays1[:, :2] / rays1[:, 2:], m2, camera, hinge)
            noise = track_noise(fit.rms_px, focal_px) / flow
            bumps = bumps.seen(distance[bands_of(excess, usable, distance, noise)], BAND_M,
                               confirm=curvature >= _BUMP_CURVATURE)
            if abs(hinge.height) < _KNOWN_HEIGHT:
                # Samples only while the front wheels are on the road: on a bump the surface's
                # hinge is only as right as the height it was given.
                ground = np.c_[distance, wheel_plane_lateral(camera, v1)][usable]
                raised_seen = self.raised.seen(camera.position, ground, excess[usable],
                                               hinge.x)
        rise = None
        if lifted:
            ahead = float(fit.motion[0])
            smooth = fit.surface[0] * ahead + 0.5 * fit.surface[2] * ahead * ahead
            rise = float(fit.rotation[2] - hinge.x * np.sin(fit.rotation[1]) - smooth)
        after = RoadAhead(bumps.lifted(rise, hinge.x), self.raised, raised_seen)
        after._under.update(self._under)  # the same raised ground: what was read holds
        return after

    def moved(self, motion: np.ndarray, camera_x: float, hinge: float) -> RoadAhead:
        """Self after the vehicle moved by ``motion`` (x, y, yaw), the last pair's samples kept.

        ``camera_x``: the camera's x in base_link (bumps behind its view go); ``hinge``: the
        front axle's x (samples behind it go).
        """
        seen = self.raised if self.raised_seen is None else self.raised_seen
        return RoadAhead(self.bumps.moved(float(motion[0]), camera_x),
                         seen.moved(np.asarray(motion, dtype=float), hinge))
