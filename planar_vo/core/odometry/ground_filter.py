"""The local ground under and ahead of the vehicle, tracked frame to frame.

Each frame pair is refined over the road surface ahead (:mod:`planar_vo.core.estimation.
local_ground`, as :mod:`planar_vo.core.odometry.pair_fit` tries it): the surface's grade,
cross-slope, curvature and twist relative to the wheels, and the vehicle's rotation between
the frames. What one pair learned is the next pair's prior, moved on by the distance
travelled (the road ahead changes with distance, not time). The mean grade and cross-slope
over a drive are the camera's static pitch and roll offsets (the road ahead is, on average,
the road the wheels later stand on): self-calibration learns them with the yaw and
camera_x (:class:`MountingCalibrator`).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from planar_vo.core.errors import PoseEstimationError
from planar_vo.core.estimation.attitude import body_tilt, tilted_mounting
from planar_vo.core.estimation.calibration import MountingCalibrator
from planar_vo.core.estimation.local_ground import (
    GroundPrior,
    Hinge,
    LocalGroundResult,
    ray_coefficients,
    relief_on_rays,
    surface_residuals,
)
from planar_vo.core.estimation.ransac import RansacResult, TransferModel
from planar_vo.core.geometry.camera import Mounting
from planar_vo.core.geometry.se2 import step_length
from planar_vo.core.odometry.attitude_filter import jolt_threshold
from planar_vo.core.odometry.covariance import correlated_covariance
from planar_vo.core.odometry.pair_fit import HALF_TRACK, IRREGULAR_LIFT, PairFit, samples_near
from planar_vo.core.odometry.raised_ground import height_from_excess
from planar_vo.core.odometry.road_ahead import RoadAhead
from planar_vo.core.odometry.road_heights import RoadHeights, chord_grade
from planar_vo.core.odometry.road_profile import SAMPLES_AHEAD, RoadProfile
from planar_vo.core.odometry.sprung_body import SprungBody
from planar_vo.core.odometry.surface_bands import (
    BAND_REACH,
    flow_excess,
    side_offsets,
    wheel_plane_distance,
    wheel_plane_lateral,
)

__all__ = ['LocalGroundFilter']

# The surface before anything is seen (grade, cross-slope in rad; curvatures, twist in 1/m),
# and how fast each may change per metre travelled: a 4 % grade change over a 10 m vertical
# curve, 20 m hills of 0.3 m (curvature 0.03 /m), 8 cm speed bumps. Measured on rendered
# drives: looser lets the surface bend onto bumps, tighter cannot follow hills.
_SURFACE_SIGMA = np.array([0.05, 0.05, 0.03, 0.03, 0.03])
_SURFACE_PER_METRE = np.array([0.035, 0.035, 0.014, 0.014, 0.014])
_SURFACE_FLOOR = np.array([1e-4, 1e-4, 1e-5, 1e-5, 1e-5])
_RATE_MEMORY_S = 2.0
_MIN_RATE = np.array([0.05, 0.05, 0.01])  # rad/s, rad/s, m/s: the learned rate's floor
_IRREGULAR_SIGMAS = 3.0  # a surface this many prior sigmas from the last: irregular ground
_IRREGULAR_INFLATION = 4.0  # its motion's covariance then grows this much
# Self-calibration of the static tilt (_tilt_sample): from the road ahead only pairs over
# smooth ground (curvatures and twist two sigmas inside this, 1/m) count; the mean is shrunk by its
# significance, its samples correlated over about _TERRAIN_CORRELATION_S (a grade every
# ~15 m). Shrunk at 2 sigmas: at 3 a sprung body's spread kept a mounting 1 deg off in pitch
# learned at 0.55-0.7 deg over the whole drive (0.309 % t_rel; 0.272 at 2, and 32 drives
# summed 4.63 -> 4.53 %, none worse by over 0.01). Stop 30 had chosen 3 because the
# road's history read a few hundredths of a degree on a crowned road (camber drives 0.077 /
# 0.066 -> 0.12 / 0.10 % at 2 sigmas then; docs/terrain-notes.md has today's); at 4 a
# sprung car's rolling-shutter drive learned its tilt too late (scale 1.0021, its test's bar
# 0.002). Samples from the history only while driving forward (standing with traffic
# crossing, or reversing, its readings moved the pose and lost the tracks).
_CALM_CURVATURE = 0.01
_TERRAIN_CORRELATION_S = 3.0
_SHRINK_SIGMAS = 2.0
_HISTORY_TRAVEL = 0.01  # m: a pair this far forward gives the history's reading
# The road ahead is read as the camera's tilt only after this much travel (m) in which the
# history could not read it: a car's camera sees past its front wheels and its history reads
# within 2-3 m, sooner than the road ahead averages out. Read from the start, a drive that
# began over a crest (-2.7 % ahead of the wheels, curvature -0.008 /m, calm by the test
# below) took -1.26 deg of pitch from four pairs, three steps 3 % long before the history
# corrected it (stop 44: 20 drives 5.570 -> 5.379 in sum, that drive 0.225 -> 0.196 %; the
# mounting 1 deg off 0.058 -> 0.068; 3 m and 10 m the same).
_UNREAD_TRAVEL = 5.0
# On uneven ground the surface (a quadratic hinged at the front axle) holds only so far: the
# tracks beyond _UNEVEN_REACH (m from the camera, over the ground) carry its error into the
# motion. The ground ahead is uneven when the last pair was irregular or one of its
# curvatures or its twist is over _CALM_AHEAD (1/m) and over _CALM_SIGMAS of its own spread
# (the noisy curvature of a coarse image is not a hill); on calm ground the far tracks carry
# information (they hold the yaw best), and at least _KEPT_AT_LEAST of the tracks are kept
# (reversing, or a higher camera, most of them are far). Measured on 42 rendered drives (a
# car's camera 1.1 m up, its view 1.5-5.2 m ahead): t_rel summed 6.18 -> 5.04 %, the flat
# ones unchanged; 8 drives rendered after the choice 1.50 -> 1.40 (docs/terrain-notes.md). A cut
# at 4.1 m everywhere cost the flat bags/default 0.023 -> 0.036 %; at 3.6 m two drives lost
# their yaw (0.66, 0.54 %); at 4.6 m the sum was 5.85.
_UNEVEN_REACH = 4.1
_CALM_AHEAD = 0.005
_CALM_SIGMAS = 3.0
_KEPT_AT_LEAST = 0.75
# The road beyond surface_half_width on a side is left out of the fit while its tracks are
# off the surface, along their flow, by over _SIDE_SIGMAS standard errors in the mean over
# _SIDE_MEMORY_M of travel (a crowned road: the far side of the crown falls away; fitted, it
# turned a car 3-5 mdeg a metre). Rendered drives, a pair's figure: flat, grades and a
# mounting 1 deg off within +-2 (10th-90th percentile); beyond a crown 1.75 m left +0.2 to +6.
_SIDE_SIGMAS = 2.0
_SIDE_MEMORY_M = 5.0
# The body's pivot (SprungBody.pivot_x) is learned on flat road only: on terrain the road's
# own pitch leaks into the regression (mid-car pivots regressed to -5 to +3 m on hills, grades
# and all four terrains, and three of 93 rendered drives lost 0.03-0.09 % t_rel where it
# passed for learned). Flat: grade and cross-slope ahead under 1 %, curvatures under 0.002 /m,
# the remembered road turning the wheels less than 0.3 mrad over the pair.
_PIVOT_FLAT_GRADE = 0.01
_PIVOT_FLAT_CURVATURE = 0.002
_PIVOT_FLAT_TURN = 0.0003
# A long hump remembered as heights (road_heights): the tracks of the pairs near bumps found
# ahead (within _NEAR_BUMP m; elsewhere a hill's bend read as heights made runs of them), past
# the front wheels by _HEIGHTS_PAST_HINGE m, no more than _HEIGHT_EXCESS faster than the model
# (a car's, not the road), once the rates are learned (_HEIGHT_PAIRS). While heights are in
# use the surface's curvatures change at _CURVATURE_ON_HUMP of their rate: bending onto the hump
# it hid it from the heights (measured with every raised run taken, stop 66: a 3 m hump's read
# 29 mm low of 80, t_rel 0.25 %; at 0.1 of the rate 0.08 %). Before, from the first raised cell
# of a bump found ahead, at _CURVATURE_NEAR_HUMP (stop 67): waiting for the run to form, the
# surface had bent 0.03 /m onto a 3 m hump and the run never formed. 50 rendered drives 10.23
# -> 8.42 % summed at 0.3, 8.24 at 0.1; but on a flat road through a rolling shutter, where the
# noise of the far tracks made false bumps (and heights of 1-5 cm), 0.1 held the surface for
# nothing (1.6x a global shutter's t_rel). With bumps found only out of their tracks' noise
# (surface_bands._BAND_Z, stop 68), 0.1: 99 drives 15.70 -> 14.13. From the bump alone, no
# raised cell, hills' curves were held back for nothing.
_NEAR_BUMP = 2.0
_HEIGHTS_PAST_HINGE = 0.5
_HEIGHT_EXCESS = 0.15
_HEIGHT_PAIRS = 10
_CURVATURE_ON_HUMP = np.array([1.0, 1.0, 0.1, 0.1, 0.1])
_CURVATURE_NEAR_HUMP = np.array([1.0, 1.0, 0.1, 0.1, 0.1])


class LocalGroundFilter:
    """The road surface ahead and the vehicle's rotation, per frame pair.

    Its state is the attributes set in :meth:`reset` and the calibrator; each is replaced,
    never changed in place, so a shallow copy is a snapshot.
    """

    def __init__(self, mounting: Mounting, *, rates: np.ndarray, wheelbase: float,
                 self_calibrate: bool, half_width: float = np.inf, track: float = 0.0) -> None:
        self.rates = np.asarray(rates, dtype=float)  # upper bounds: roll, pitch, height rates
        self.wheelbase = wheelbase  # m ahead of base_link: the front axle, as configured
        self.hinge = wheelbase  # m: where the road ahead may bend from (see_ground)
        self.seen_from = 0.0  # m past the hinge where the camera's view begins (see_ground)
        self.track = track  # m between the front wheels
        self.half_width = half_width  # m either side of base_link: the surface's tracks
        self.self_calibrate = self_calibrate
        self.calibrator = MountingCalibrator(mounting)
        self.camera_height = float(mounting.position[2])  # m over the wheel plane (last pair)
        self.reset()

    @classmethod
    def from_params(cls, mounting: Mounting, params: Any) -> LocalGroundFilter:
        """From the parameters (rates, wheelbase, track_width, self_calibrate, half width)."""
        rates = np.array([params['attitude_rate'], params['attitude_rate'],
                          params['bounce_rate']])
        return cls(mounting, rates=rates, wheelbase=params['wheelbase'],
                   self_calibrate=params['self_calibrate'],
                   half_width=params['surface_half_width'], track=params['track_width'])

    def for_mounting(self, mounting: Mounting) -> LocalGroundFilter:
        """A filter of the same vehicle for a new mounting: nothing learned, the view unknown."""
        return LocalGroundFilter(mounting, rates=self.rates, wheelbase=self.wheelbase,
                                 self_calibrate=self.self_calibrate,
                                 half_width=self.half_width, track=self.track)

    def see_ground(self, view: tuple[float, float] | None) -> None:
        """The camera sees the ground from ``view`` = (near, far) m ahead of base_link.

        The road bends from the front wheels on, wherever the camera sees it from: a car whose
        camera sees the road from behind its front wheels (a wide lens, a low camera) has that
        road on the same surface, carried back under the car. Only front wheels set beyond the
        middle of the view are not there: a small robot left at a car's 2.7 m, seeing the
        ground from 0.4 to 1.8 m, took the road it saw as flat, 2.6 % off on hills (0.12 % with
        its own 0); bent from where its view begins, 0.23 %. (Until stop 46 wheels set 0.5 m
        inside the view were moved to its near edge: a car's wide lens on hills 0.27 % instead
        of 0.04.) None: the view is not known.
        """
        moved = view is not None and self.wheelbase > 0.5 * (view[0] + view[1])
        self.hinge = max(view[0], 0.0) if moved else self.wheelbase
        # A view that begins past the front wheels (a camera high or looking far: a van's, a
        # windshield's) has the road's history sampled on road it saw, from where it begins:
        # sampled from the hinge, the surface carried back there stood for the road under the
        # wheels (a windshield camera 1.3 m up, 6 deg down, the road from 0.6 m past the front
        # wheels: all four terrains sprung 0.550 -> 0.433 % t_rel, a van's camera 0.286 ->
        # 0.248, the camera unchanged: its view begins before the front wheels).
        self.seen_from = 0.0 if view is None else max(view[0] - self.hinge, 0.0)

    @property
    def samples_from(self) -> float:
        """Where the road's history samples each pair, m ahead of base_link (see_ground)."""
        return self.hinge + self.seen_from

    def wheels_inside_view(self) -> bool:
        """Whether the front wheels were set beyond the middle of the camera's view (see_ground).

        The road then bends from where the view begins, with advice in /diagnostics.
        """
        return self.hinge != self.wheelbase

    def reset(self) -> None:
        """Nothing seen yet: a flat road is only the prior's best guess."""
        self.rate2 = self.rates ** 2
        self.rate_samples = 0
        self.sprung = SprungBody.unknown()
        self.off_surface = 0.0  # share of the tracks the last pair weighed down
        self.irregular = False
        self.rough_ahead = np.zeros(len(SAMPLES_AHEAD), bool)  # the last pair's, per sample
        self.used_reach = np.inf  # m from the camera: the last pair's tracks (within_reach)
        self.side_drift = np.zeros(2)  # the road beyond the lane, left and right (_SIDE_SIGMAS)
        self.restart()

    def restart(self) -> None:
        """Tracking restarts: the surface ahead and the road's history are unknown again."""
        self.surface = np.zeros(5)
        self.surface_cov = np.diag(_SURFACE_SIGMA ** 2)
        self.profile = RoadProfile.empty()
        self.heights = RoadHeights()  # a long hump's, remembered
        self.heights_seen = None  # the last pair's (points, heights), taken on in advance()
        self.body = np.zeros(2)  # (roll, pitch) of the camera to its wheels, beyond the static
        self.last_fit: tuple | None = None  # what the last refinement saw, for advance()
        self.step_var = 0.0  # m^2: the last refinement's own variance of its step along x
        self.solution: tuple | None = None  # the last pair's (params, camera, hinge, weights)
        self.wheel_lift = 0.0  # m: how far the last pair's jolt lifted a wheel off the road
        self.ahead = RoadAhead()  # bumps and raised ground, until the wheels pass them
        self.history_reads = False  # the road's history has read the camera's tilt
        self.travel_unread = 0.0  # m driven since the restart while the history could not read
        self.seen_tilt: np.ndarray | None = None  # its last reading, if believable
        self.pivot_follows = False  # the last pair was a sample of the body's pivot

    @property
    def tilt_offset(self) -> np.ndarray:
        """The camera's learned static (roll, pitch) offset to the configured mounting, rad.

        The mean of the tilt samples (:meth:`_tilt_sample`), shrunk towards none by how well
        the drive knows it (correlated over ``_TERRAIN_CORRELATION_S``, the samples average
        out only slowly): a tilt learned wrong biases the scale as much as one not learned.
        """
        if not self.self_calibrate:
            return np.zeros(2)
        mean = self.calibrator.mean_tilt
        std = self.calibrator.tilt_std(_TERRAIN_CORRELATION_S)
        if not np.all(np.isfinite(std)):
            return np.zeros(2)
        return mean * mean ** 2 / (mean ** 2 + (_SHRINK_SIGMAS * std) ** 2 + 1e-30)

    def tilted(self, mounting: Mounting) -> Mounting:
        """``mounting`` with the learned static tilt and the body's tilt to the wheels.

        The body tilts about its pivot once that is learned (SprungBody.pivot_x), which moves
        the camera; until then the camera tilts in place.
        """
        tilted = tilted_mounting(mounting, np.r_[self.tilt_offset + self.body, 0.0])
        camera = mounting.position
        if not self.sprung.pivot_learned:
            return tilted
        arm = camera - np.array([self.sprung.pivot_x(float(camera[0])), 0.0, 0.5 * camera[2]])
        x, y, z = tilted.position + body_tilt(*self.body) @ arm - arm
        return dataclasses.replace(tilted, x=float(x), y=float(y), height=float(z))

    def reach(self) -> float:
        """How far from the camera (m, over the ground) the next pair's tracks may lie."""
        bound = np.maximum(_CALM_AHEAD, _CALM_SIGMAS * np.sqrt(np.diag(self.surface_cov)[2:]))
        calm = not self.irregular and np.all(np.abs(self.surface[2:]) < bound)
        return np.inf if calm else _UNEVEN_REACH

    def within_reach(self, distance: np.ndarray) -> np.ndarray:
        """Which tracks the next pair may use, (N,) bool, from their ground distance.

        ``distance``: (N,) from the camera over the ground, m (NaN: not on the ground).
        Never fewer than _KEPT_AT_LEAST of them: where most tracks lie far (a higher camera,
        reversing), they are the information.
        """
        reach = self.reach()
        if np.isfinite(reach) and np.any(np.isfinite(distance)):
            reach = max(reach, float(np.nanquantile(distance, _KEPT_AT_LEAST)))
        self.used_reach = reach
        return distance <= reach

    def hypothesis_threshold(self, inlier_threshold: float, focal_px: float,
                             dt: float) -> float:
        """Inlier threshold (px) of the planar hypotheses, ``dt`` s after the reference.

        The vehicle's rotation between the frames (a bump, a crest) moves every point off
        any planar motion by up to ``JOLT_SIGMAS`` of the learned rate; the refinement
        comes down from this threshold to the inlier threshold.
        """
        return jolt_threshold(self.rate2, inlier_threshold, focal_px, dt)

    def refine(self, est: RansacResult, rays1: np.ndarray, m2: np.ndarray,
               mounting: Mounting, model: TransferModel, *, dt: float,
               inlier_threshold: float, start_threshold: float,
               min_inliers: int) -> tuple[RansacResult, Mounting | None]:
        """Refine the motion over the local ground; learn the surface and the mounting.

        ``mounting``: the working mounting (self-calibrated yaw and camera_x); the learned
        static tilt is added here. Returns the refined result and the self-calibrated
        mounting to use from now on (None when it did not change). Raises
        PoseEstimationError, before anything changes, when fewer than ``min_inliers`` fit.
        """
        dt = max(dt, 1e-3)
        camera = self.tilted(mounting)
        hinge = self._surface_hinge()
        travel = step_length(est.motion)
        step = np.maximum(_SURFACE_PER_METRE * travel, _SURFACE_FLOOR)
        if self.heights.in_use:
            hinge = self._hinge_on_heights(hinge)
            step = step * _CURVATURE_ON_HUMP
        elif self.ahead.bumps.ahead and self.heights.any_raised:
            step = step * _CURVATURE_NEAR_HUMP
        prior = GroundPrior(np.diag(self.rate2 * dt * dt), self.surface,
                            self.surface_cov + np.diag(step ** 2))
        v1 = rays1 @ camera.base_from_optical.T
        distance = wheel_plane_distance(camera, v1)
        beyond, on_bumps = self._left_out(camera, v1, distance, 2 * min_inliers)
        pair = PairFit(camera=camera, focal_px=model.focal_px, dt=dt, travel=travel,
                       inlier_threshold=inlier_threshold, start_threshold=start_threshold,
                       min_inliers=min_inliers, rates=self.rates, rate2=self.rate2,
                       body_rate2=self.sprung.rate2,
                       road_turn=self.profile.pitch_change(self.hinge, HALF_TRACK, travel,
                                                           self._relief_turn(travel)),
                       front_axle=self.hinge, track=self.track,
                       samples_from=self.samples_from)
        try:
            shown = np.flatnonzero(~(beyond | on_bumps))
            fit, prior, hinge, rough = pair.on_tracks(est.motion, v1, m2, shown, prior, hinge)
        except PoseEstimationError:
            if not on_bumps.any():
                raise
            # A bump remembered over most of a low camera's view left too few tracks to hold
            # the pair (a car's camera 0.8 m up: 25 of 316, then tracking lost): with them.
            on_bumps = np.zeros_like(on_bumps)
            shown = np.flatnonzero(~beyond)
            fit, prior, hinge, rough = pair.on_tracks(est.motion, v1, m2, shown, prior, hinge)
        hidden = beyond | on_bumps
        if hidden.any():
            fit = _on_all_tracks(fit, shown, len(v1))
        if travel > 0.0:
            sides = side_offsets(fit, v1, m2, camera, hinge, model.focal_px,
                                 half_width=self.half_width, left_out=beyond,
                                 threshold_px=inlier_threshold)
            self.side_drift = self.side_drift + min(travel / _SIDE_MEMORY_M, 1.0) * (
                sides - self.side_drift)
        if on_bumps.any():
            rough = rough | samples_near(self.samples_from, np.array(self.ahead.bumps.ahead))
        lifted = pair.wheel_lift(fit.rotation)
        self.heights_seen = None
        if (lifted <= IRREGULAR_LIFT and self.rate_samples >= _HEIGHT_PAIRS
                and fit.motion[0] > 0.0):
            self.heights_seen = self._heights_seen(fit, rays1, v1, m2, camera, hinge)
        self.ahead = self.ahead.after_pair(
            fit, prior.surface, lifted=lifted > IRREGULAR_LIFT, rate_samples=self.rate_samples,
            rays1=rays1, v1=v1, m2=m2, camera=camera, hinge=hinge, distance=distance,
            focal_px=model.focal_px)
        self.surface, self.surface_cov = fit.surface, fit.surface_cov
        # Weight 0.1: a residual 3 sigma off the surface (1 % of Gaussian noise).
        self.off_surface = float(np.mean(fit.weights[fit.inliers] < 0.1))
        # The surface jumped further than the road can bend over the travel (a bump or a
        # kerb ahead, not a grade or a hill), or a wheel is off the road (a jolt, this pair
        # or the last).
        jump = np.abs(fit.surface - prior.surface) / np.sqrt(np.diag(prior.surface_cov))
        lift = max(lifted, self.wheel_lift)
        self.irregular = float(np.max(jump)) > _IRREGULAR_SIGMAS or lift > IRREGULAR_LIFT
        self.rough_ahead = rough
        self._learn_rate(fit, dt)
        calibrated = None
        motion_cov = fit.covariance * (_IRREGULAR_INFLATION if self.irregular else 1.0)
        motion_cov = motion_cov + self.sprung.covariance(camera, travel, dt, self.hinge)
        motion_cov[0, 0] += (lift * travel / camera.height) ** 2
        self.wheel_lift = lifted
        used = self.tilt_offset + self.body
        self.step_var = float(fit.covariance[0, 0])
        self.last_fit = (fit.measured_rotation, fit.surface, fit.surface_cov, used, dt,
                         model.focal_px, camera.position)
        self.solution = (np.concatenate([fit.motion, fit.rotation, fit.surface]), camera, hinge,
                         fit.weights)
        if self.self_calibrate:
            # Its slip fit takes many steps: their errors are correlated.
            slip_cov = correlated_covariance(fit.covariance, dt)
            calibrated, applied = self.calibrator.step(fit.motion, slip_cov,
                                                       self._tilt_sample(fit, used), dt)
            motion_cov = motion_cov + applied
        return RansacResult(fit.motion, motion_cov, fit.inliers, est.hypotheses,
                            fit.rms_px), calibrated

    def _hinge_on_heights(self, hinge: Hinge) -> Hinge:
        """The hinge over the remembered hump: the front wheels stand on it at its height.

        The road past them is the hump's heights less theirs; off the hump (the heights 0)
        the hinge keeps the height the bumps ahead gave it.
        """
        heights = self.heights
        wheels = np.array([[self.hinge, 0.5 * self.track], [self.hinge, -0.5 * self.track]])
        front = float(heights.at(wheels).mean())
        return Hinge(hinge.x, hinge.track, 0.0 if front != 0.0 else hinge.height,
                     relief=lambda points: heights.at(points) - front)

    def _relief_turn(self, travel: float) -> float:
        """How much the remembered hump raises the wheels' chord grade over ``travel`` m."""
        return (chord_grade(self.heights, self.hinge, HALF_TRACK, travel)
                - chord_grade(self.heights, self.hinge, HALF_TRACK))

    def _heights_seen(self, fit: LocalGroundResult, rays1: np.ndarray, v1: np.ndarray,
                      m2: np.ndarray, camera: Mounting,
                      hinge: Hinge) -> tuple[np.ndarray, np.ndarray]:
        """The road's heights the pair saw near the bumps ahead: (points (N, 2), heights (N,)).

        Each track's flow over the pair's model (its motion, rotation, surface and the heights
        already remembered) tells how much higher the road there is: a point ``dz`` higher is
        nearer, its flow ``h / (h - dz)`` times faster (``h`` the camera's height over it).
        Only tracks past the front wheels (+0.5 m), within _NEAR_BUMP of a bump found ahead,
        and no faster than a road hump's (_HEIGHT_EXCESS).
        """
        excess, ok, _ = flow_excess(fit.motion, fit.rotation, fit.surface, v1,
                                    rays1[:, :2] / rays1[:, 2:], m2, camera, hinge)
        c = camera.position
        off = np.zeros(len(v1))
        if hinge.relief is not None:
            off = relief_on_rays(c, v1.T, hinge.relief)
        points = c[:2] + ((c[2] - off) / np.maximum(-v1[:, 2], 1e-9))[:, None] * v1[:, :2]
        above = c[2] - off
        keep = ok & (points[:, 0] > self.hinge + _HEIGHTS_PAST_HINGE)
        keep &= np.abs(excess) < _HEIGHT_EXCESS
        near = np.zeros(len(v1), bool)
        for x in self.ahead.bumps.ahead:
            near |= np.abs(points[:, 0] - x) < _NEAR_BUMP
        keep &= near
        heights = self.heights.at(points) + height_from_excess(above, excess)
        return points[keep], heights[keep]

    def residuals_without_curvature(self, rays1: np.ndarray, m2: np.ndarray,
                                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The last pair's residuals (2, N) over its surface made flat, Jacobian, weights (N,).

        At the last refinement's motion, rotation, grade and cross-slope with the surface's
        curvatures and twist set to none, for the tracks it refined seen as ``rays1`` (N, 3)
        and ``m2`` (N, 2) (moved to their stamps with another readout); the Jacobian (8, 2, N)
        is over those 8. An unmodelled readout's shear bends the surface the pair fits (its
        curvatures take it up, whatever the readout): through them a pair says nothing
        of the readout, through a flat one it does (see readout_on_surface).
        """
        params, camera, hinge, weights = self.solution
        flat = np.concatenate([params[:8], np.zeros(len(params) - 8)])
        v1 = np.ascontiguousarray((rays1 @ camera.base_from_optical.T).T)
        r, J, front = surface_residuals(flat, v1, np.ascontiguousarray(m2.T), camera, hinge)
        return r, J[:8], np.where(front, weights, 0.0)

    def _left_out(self, camera: Mounting, v1: np.ndarray, distance: np.ndarray,
                  keep: int) -> tuple[np.ndarray, np.ndarray]:
        """Which tracks (N,) bool the pair's fit leaves out: beyond the lane, on a bump.

        Beyond ``half_width`` while the road bends away on a side (a crown), then on a bump
        remembered ahead or a band waiting for its confirmation; each only if ``keep`` tracks
        are left. A 10 Hz camera sees a bump in three pairs: the first showed a band where hills
        curved the road, its tracks bent the surface onto the bump, the second pair was then
        too curved to be searched, and the wheels crossed the bump with it in the fit (+80 mm).
        Not while a road hump's heights are in use: they are read from those tracks.
        """
        away = np.abs(self.side_drift) > _SIDE_SIGMAS
        beyond = away.any() & (np.abs(wheel_plane_lateral(camera, v1)) > self.half_width)
        if np.count_nonzero(~beyond) < keep:
            beyond[:] = False
        on_bumps = self.ahead.bumps.hides(distance, BAND_REACH,
                                          candidates=not self.heights.in_use) & ~beyond
        if np.count_nonzero(~(beyond | on_bumps)) < keep:
            on_bumps[:] = False
        return beyond, on_bumps

    def _tilt_sample(self, fit: LocalGroundResult, used: np.ndarray) -> np.ndarray | None:
        """The camera's (roll, pitch) beyond the configured mounting, for self-calibration.

        Once the road's history can read it, the camera's tilt to the road under its wheels:
        the grade ahead is not in it (read from the road ahead, a hill's trough at the start
        of a drive passed for a 1.7 deg pitch offset; over 42 rendered drives t_rel summed
        7.04 -> 6.18 %, a hills drive 0.29 -> 0.082 %, the mount 1 deg off 0.106 -> 0.045 %).
        Where it has not read after _UNREAD_TRAVEL m (a robot whose wheels stand where the
        camera cannot see, where it never can), the surface ahead on calm pairs. None: the
        pair says nothing about it.
        """
        if self.history_reads:
            forward = fit.motion[0] > _HISTORY_TRAVEL
            return self.seen_tilt if forward and not self.irregular else None
        if self.travel_unread < _UNREAD_TRAVEL:
            return None
        # Calm for sure: two sigmas of the curvatures inside the bound (a fit on the near
        # tracks alone, in a hill's trough, passed 0.0097 /m for calm and set a 0.57 deg pitch).
        spread = 2.0 * np.sqrt(np.diag(fit.surface_cov)[2:])
        calm = not self.irregular and np.all(np.abs(fit.surface[2:]) + spread < _CALM_CURVATURE)
        # The surface's grade and cross-slope, as the camera's tilt: (roll, pitch).
        return used - np.r_[fit.surface[1], -fit.surface[0]] if calm else None

    def _surface_hinge(self) -> Hinge:
        """Where the surface meets the front wheels, and how high (one on a bump ahead)."""
        return self.ahead.hinge(self.hinge, self.track, self.camera_height)

    def advance(self, motion: np.ndarray) -> None:
        """The last refined pair's motion was taken: remember its road, move on.

        The body's tilt at the new reference frame is the road's history's, shrunk towards
        none by how well that history is known; where the history cannot read it, the last
        one held (SprungBody.held).
        """
        if self.last_fit is None:
            return
        rotation, surface, surface_cov, used, dt, focal_px, camera = self.last_fit
        self.ahead = self.ahead.moved(motion, float(camera[0]), self.hinge)
        self.camera_height = float(camera[2])
        self.last_fit = self.solution = None
        # The pair's pitch (nose down) beyond the remembered road's curve: the body's turn, if
        # no wheel lifted (None until the history has the road under both axles).
        curve = self.profile.pitch_change(self.hinge, HALF_TRACK, float(motion[0]),
                                          self._relief_turn(float(motion[0])))
        if self.heights_seen is not None:
            self.heights = self.heights.seen(*self.heights_seen)
            self.heights_seen = None
        self.heights = self.heights.moved(np.asarray(motion, dtype=float))
        turn = None if curve is None else float(rotation[1]) - curve
        if (turn is not None and self.wheel_lift <= IRREGULAR_LIFT
                and float(motion[0]) > _HISTORY_TRAVEL and self._flat_pair(surface, curve)):
            # The reference camera's tilt error reads as the grade ahead on a flat road and
            # raises the pair's height change by the step times it (its grade's slope on the
            # renderer's tilt error 0.96-1.00, three flat sprung drives): summed into the
            # pivot's levels it follows the body's pitch. Taken out: 150 rendered drives
            # 26.863 -> 26.632 % t_rel summed (a sprung mounting 1 deg off 0.099 -> 0.198).
            rise = float(rotation[2]) - float(motion[0]) * float(surface[0])
            self.sprung = self.sprung.with_pivot_sample(turn, rise, dt,
                                                        self.calibrator.working.x,
                                                        follows=self.pivot_follows)
            self.pivot_follows = True
        else:
            self.pivot_follows = False
        if turn is None or self.wheel_lift > IRREGULAR_LIFT:
            turn = 0.0
        self.profile = self.profile.with_pair(np.asarray(motion, dtype=float), rotation[:2],
                                              surface, surface_cov, used, self.hinge,
                                              self.rough_ahead, seen_from=self.seen_from)
        seen = self.profile.camera_tilt(self.hinge, HALF_TRACK,
                                        chord_grade(self.heights, self.hinge, HALF_TRACK))
        self.history_reads = self.history_reads or seen is not None
        if not self.history_reads:
            self.travel_unread += abs(float(motion[0]))
        self.seen_tilt = None if seen is None or self.wheel_lift > IRREGULAR_LIFT else seen[0]
        if self.wheel_lift > IRREGULAR_LIFT:
            # A wheel on a bump tilts the wheels, not the body: the tilt to the road's chord
            # is not the body's, and the body's spread is not learned from it (learned, it
            # let the history's readings over the bump's ground through: +0.2-1.0 deg on a
            # rigid car with the bump between its axles).
            seen = None
        sprung, body = self.sprung.read_tilt(seen, self.tilt_offset, dt, focal_px)
        if not sprung.tilt_read:
            body = sprung.held(self.body, turn, focal_px)
            if curve is None:
                # No road under the wheels yet to tell the body's turn from the road's:
                # pulling away from rest, it is the body's squat (SprungBody.squat).
                road_turn = _SURFACE_SIGMA[2] * abs(float(motion[0]))
                body = body + np.array([0.0, sprung.squat(float(rotation[1]), road_turn, dt)])
        # The next pair's wheel plane is the camera tilted by the new body tilt: the
        # surface ahead, relative to it, tilts the other way (what the camera saw stays).
        change = body - self.body
        self.surface = self.surface + np.array([-change[1], change[0], 0.0, 0.0, 0.0])
        self.body = body
        self.sprung = sprung.moved(change, rotation[2], camera, dt,
                                   read_before=self.sprung.tilt_read, pair_turn=rotation[:2])

    def _flat_pair(self, surface: np.ndarray, curve: float) -> bool:
        """Whether the last pair drove on flat road: where its body's pivot is learned.

        Nothing irregular, the road ahead level with the wheels (_PIVOT_FLAT_GRADE) and
        straight (_PIVOT_FLAT_CURVATURE), and the remembered road under the wheels not
        turning them (``curve``, rad over the pair, under _PIVOT_FLAT_TURN).
        """
        if self.irregular or np.any(np.abs(surface[:2]) >= _PIVOT_FLAT_GRADE):
            return False
        if np.any(np.abs(surface[2:]) >= _PIVOT_FLAT_CURVATURE):
            return False
        return abs(curve) < _PIVOT_FLAT_TURN

    def on_surface(self, points: np.ndarray, camera: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Points (N, 2) on the wheels' plane moved along their rays onto the surface ahead.

        ``camera``: the camera's position in base_link (the rays go through it). Returns the
        points (N, 2) and their heights (N,) above the plane, m. A ray that misses the
        surface keeps its plane point.
        """
        # the ray camera + s d meets the plane at s = 1 (d's z is minus the camera's height)
        d = np.c_[points - camera[:2], np.full(len(points), -camera[2])].T
        dA, dB, dC = ray_coefficients(camera, d, self._surface_hinge())
        qa = self.surface @ dA
        qb = self.surface @ dB + camera[2]
        qc = self.surface @ dC - camera[2]
        disc = qb * qb - 4.0 * qa * qc
        hit = (disc > 0.0) & (qb > 0.0)
        scale = np.where(hit, -2.0 * qc / (qb + np.sqrt(np.where(hit, disc, 0.0))), 1.0)
        scale = np.where(scale > 0.0, scale, 1.0)
        xy = camera[:2] + scale[:, None] * (points - camera[:2])
        return xy, camera[2] * (1.0 - scale)

    def _learn_rate(self, fit: LocalGroundResult, dt: float) -> None:
        """How fast the vehicle really rotates, as the attitude filter learns its rate."""
        sample = fit.rotation ** 2 / (dt * dt)
        self.rate_samples += 1
        alpha = min(max(dt / _RATE_MEMORY_S, 1.0 / self.rate_samples), 1.0)
        self.rate2 = np.clip(self.rate2 + alpha * (sample - self.rate2), _MIN_RATE ** 2,
                             self.rates ** 2)

    def diagnostics(self) -> dict[str, str]:
        """What the ground model sees, as /diagnostics key/values."""
        ep, er, k, _, _ = self.surface
        return {
            'ground model': 'local surface',
            'grade ahead (%)': f'{100 * ep:.2f}',
            'cross-slope ahead (%)': f'{100 * er:.2f}',
            'curvature ahead (1/m)': f'{k:.4f}',
            'off-surface tracks (%)': f'{100 * self.off_surface:.1f}',
            'tracks used up to (m ahead)': (
                'all' if np.isinf(self.used_reach) else f'{self.used_reach:.1f}'),
            'ground ahead irregular': str(self.irregular),
            'bumps ahead (m)': ', '.join(f'{x:.1f}' for x in self.ahead.bumps.ahead) or 'none',
            'front wheels above the road ahead (cm)': f'{-100 * self._surface_hinge().height:.1f}',
            'road hump remembered': _hump_text(self.heights.extent()),
            'body pitches about (m ahead of base_link)': (
                f'{self.sprung.pivot_x(self.calibrator.working.x):.2f}'
                if self.sprung.pivot_learned else 'the camera (not learned)'),
            'road bends away beyond the lane': ', '.join(
                side for side, drift in zip(('left', 'right'), self.side_drift)
                if abs(drift) > _SIDE_SIGMAS) or 'neither side',
        }


def _hump_text(extent: tuple[float, float, float] | None) -> str:
    """A remembered hump (RoadHeights.extent) for /diagnostics."""
    if extent is None:
        return 'none'
    start, end, top = extent
    return f'{start:.1f} to {end:.1f} m ahead of base_link, {100 * top:.1f} cm high'


def _on_all_tracks(fit: LocalGroundResult, shown: np.ndarray, count: int) -> LocalGroundResult:
    """``fit`` of the tracks ``shown`` with its inliers and weights over all ``count``."""
    inliers = np.zeros(count, bool)
    inliers[shown] = fit.inliers
    weights = np.zeros(count)
    weights[shown] = fit.weights
    return dataclasses.replace(fit, inliers=inliers, weights=weights)
