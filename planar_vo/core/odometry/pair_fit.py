"""One frame pair refined over the local ground: smooth, through a jolt, held to its arc.

The pair is refined as :mod:`planar_vo.core.estimation.local_ground` fits it, tried in the
order a wheeled vehicle calls for: the body's learned turn rate as the rotation's prior, the
height's upper bound when a wheel climbs, the rate's upper bound when a wheel hits a bump (a
jolt), held to the arc of rolling wheels when a fit slides sideways, once more from the front
wheels' height when they came down off a bump, and without the bands off the surface (a speed
bump's faces). A :class:`PairFit` holds what one pair knows and nothing between pairs: what
the fit learns is kept by :class:`~planar_vo.core.odometry.ground_filter.LocalGroundFilter`.
Numpy only; no ROS.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from planar_vo.core.errors import PoseEstimationError
from planar_vo.core.estimation.local_ground import (
    GroundPrior,
    Hinge,
    LocalGroundResult,
    refine_on_local_ground,
)
from planar_vo.core.geometry.camera import Mounting
from planar_vo.core.geometry.se2 import off_arc
from planar_vo.core.odometry.attitude_filter import JOLT_SIGMAS, jolt_threshold
from planar_vo.core.odometry.road_profile import SAMPLES_AHEAD
from planar_vo.core.odometry.surface_bands import (
    BAND_REACH,
    off_surface_bands,
    refit_consistent,
    wheel_plane_distance,
)

__all__ = ['HALF_TRACK', 'IRREGULAR_LIFT', 'PairFit', 'samples_near']

# Cauchy scale, in the inliers' own noise: tracks off the smooth surface (a bump's faces,
# past a road's crown) weigh less. On the rendered camber drive 1 took t_rel from 0.25 to
# 0.08 %; 2: 0.12 %.
_CAUCHY = 1.0
HALF_TRACK = 1.0  # m either side of base_link whose remembered road the wheels stand on
# A wheel hitting a bump lifts its end of the wheels' plane off the road; the road past the
# front axle is then below that plane, which the surface cannot hold (on a rendered 8 cm bump
# the step came out 8 % short, 12 times its standard deviation). The pair's rotation beyond
# this many of the body's learned turn rates is taken for such a lift, and its scale error
# enters the covariance of this pair and the next (the wheel comes down a frame later).
_WHEEL_LIFT_SIGMAS = 3.0
IRREGULAR_LIFT = 0.01  # m: a wheel lifted this far makes the ground irregular
# A wheel climbing a long, low bump (5 cm over 1.5 m) rises 2-4 cm a frame and pitches the car
# less than a lift (4-10 mm of it): the height change's prior, the rate learned on the road
# before (0.5 mm a frame at 20 Hz), held the rise back and the steps came out 5-10 mm short for
# five frames at each axle. When the pair's own reading of the height change is beyond
# _RISE_SIGMAS of that rate and _RISE_FLOOR, the pair is refitted as for a lift. Stop 37:
# that drive 0.235 -> 0.126 %, 34 drives (docs/terrain-notes.md) 4.533 -> 4.516 (none by 0.02);
# 3 or 5 sigmas: 0.115 / 0.114, 8: 0.239 again.
_RISE_SIGMAS = 4.0
_RISE_FLOOR = 0.01  # m (0.005: the same)
# A front wheel coming down off a bump: at the pair's first frame it stood on the bump, so the
# road past the front axle lay below the wheels' plane by its height, which the raised ground
# or a band gives only where they saw the bump (a bump crossed at an angle, one wheel on it:
# none of its 37 mm known, the step 15.7 mm short). The pair's own rotation tells it: its
# pitch beyond the road's curve (nose down) times the hinge is the drop, when the pair lifted
# a wheel and base_link did not rise with it (a rear wheel climbing pitches the same way and
# lifts base_link by _DROP_RISE_SHARE of it or more). When the drop is over the known height by
# _DROP_MARGIN (m) the pair is refitted with the front wheels that high. Stop 44, per pair on
# three all-four sprung drives: the steps of front descents -3.4 -> -1.4 mm in mean.
_DROP_MARGIN = 0.01
_DROP_RISE_SHARE = 0.3
# Wheels roll, they do not slide: base_link (between the rear or drive wheels) moves along a
# circular arc, the paper's motion model. A refined motion this far off its arc (a share of
# the step, with a floor for slow steps) is a fit gone astray on a jolt, not the vehicle's:
# the jolt's fit replaces it when that one keeps to an arc. Over 50 rendered drives the
# fits' largest slide was 3 % of the step, but for six of 6-12 % on bumps (one kept 7 of 148
# tracks; one a 1.05 deg yaw error at 10 Hz). That drive 0.51 -> 0.46 %, r_rel 1.02 -> 0.29
# deg/100 m; a bumps drive 0.20 -> 0.15 %; 42 drives (terrain-notes.md) 5.04 -> 5.05 in sum.
# When the jolt's fit slides too, through a jolt (a wheel lifted), the pair is refined again
# held to its arc within _HELD_SHARE of the bound: the paper's circular motion, where the
# tracks cannot tell a sideways slide from a roll and a turn (45 of 233 tracks left as a
# wheel climbed a bump crossed at 23 deg: three frames 0.2-0.29 deg of yaw off, that drive
# 0.378 -> 0.158 %).
# Stop 34, 24 rendered drives: a share of 0.05 -> 0.03 took another of them 0.253 -> 0.216 %
# (0.02: 3.93 in sum against 3.92; the held fit within 0.3 or 0.03 of the bound: 3.93).
# Held always, within 1 or 2 % of the step: 3.95-3.98 in sum, and the sideways slip that
# self-calibration learns the camera's yaw and camera_x from would be held too.
_SLIDE_SHARE = 0.03
_SLIDE_FLOOR = 0.005  # m
_HELD_SHARE = 0.1


def samples_near(samples_from: float, xs: np.ndarray) -> np.ndarray:
    """Which of the road history's samples ahead (SAMPLES_AHEAD) lie near a band or bump.

    ``samples_from``: where they are taken from (m ahead of base_link: the front axle, or
    where the view begins past it); ``xs``: where the bands or bumps are (m, base_link);
    near: within BAND_REACH.
    """
    ahead = samples_from + SAMPLES_AHEAD
    return np.any(np.abs(ahead[:, None] - xs[None, :]) < BAND_REACH, axis=1)


@dataclass(frozen=True)
class PairFit:
    """What one frame pair's refinement knows besides its tracks.

    ``rates``: the rotation's and height's upper bounds (roll, pitch in rad/s, height m/s);
    ``rate2``: their learned squares; ``body_rate2``: the sprung body's learned turn rate,
    squared (roll, pitch); ``road_turn``: the remembered road's pitch change under the wheels
    over the travel (rad, nose down; None while the history has not seen it);
    ``front_axle``: m ahead of base_link, where the road bends from; ``track``: m between the
    front wheels; ``samples_from``: m ahead of base_link, where the road history's samples
    are taken from (see samples_near).
    """

    camera: Mounting
    focal_px: float
    dt: float
    travel: float
    inlier_threshold: float
    start_threshold: float
    min_inliers: int
    rates: np.ndarray
    rate2: np.ndarray
    body_rate2: np.ndarray
    road_turn: float | None
    front_axle: float
    track: float
    samples_from: float

    def on_tracks(self, motion: np.ndarray, v1: np.ndarray, m2: np.ndarray, shown: np.ndarray,
                  prior: GroundPrior, hinge: Hinge,
                  ) -> tuple[LocalGroundResult, GroundPrior, Hinge, np.ndarray]:
        """The pair refined on the ``shown`` tracks (indices into v1 and m2).

        Its fit, the prior and the hinge it used, and the road history's samples a band covers
        (see _without_bands). Once more from the front wheels' height if they came down. Raises
        PoseEstimationError when fewer than ``min_inliers`` fit.
        """
        v1, m2 = v1[shown], m2[shown]
        fit, used_prior = self._refined(motion, v1, m2, prior, hinge)
        drop = self._front_drop(fit)
        if drop > -hinge.height + _DROP_MARGIN:
            hinge = dataclasses.replace(hinge, height=-drop)
            fit, used_prior = self._refined(motion, v1, m2, prior, hinge)
        fit, rough = self._without_bands(fit, motion, v1, m2, used_prior, hinge)
        count = int(np.count_nonzero(fit.inliers))
        if count < self.min_inliers:
            raise PoseEstimationError(f'{count} inliers, fewer than {self.min_inliers}')
        return fit, used_prior, hinge, rough

    def wheel_lift(self, rotation: np.ndarray) -> float:
        """How far a wheel was lifted (m): the rotation beyond what the body turns.

        A pitch the remembered road explains (a hill's curve under the wheels) lifts no wheel
        (on a rendered drive over hills, grades, camber and bumps, 20 of 59 lifts were such,
        and t_rel was 0.57 % with them, 0.29 without). Near a bump the road's history is
        unsure, so the smaller of the pitch and its excess over the road's counts.
        """
        excess = self._pitch_beyond_road(rotation)
        turn = np.abs(rotation[:2])
        if excess is not None:
            turn[1] = min(turn[1], abs(excess))
        beyond = np.maximum(turn
                            - _WHEEL_LIFT_SIGMAS * np.sqrt(self.body_rate2) * self.dt, 0.0)
        return float(HALF_TRACK * beyond[0] + self.front_axle * beyond[1])

    def _pitch_beyond_road(self, rotation: np.ndarray) -> float | None:
        """The pair's pitch (rad, nose down) beyond the remembered road's curve, if known."""
        return None if self.road_turn is None else float(rotation[1]) - self.road_turn

    def _front_drop(self, fit: LocalGroundResult) -> float:
        """How far (m) the front wheels came down in the pair, 0 if they did not.

        0 also when it lifted no wheel, or base_link rose with it (a rear wheel climbing).
        """
        if self.wheel_lift(fit.rotation) <= IRREGULAR_LIFT:
            return 0.0
        beyond = self._pitch_beyond_road(fit.rotation)
        drop = self.front_axle * (float(fit.rotation[1]) if beyond is None else beyond)
        return drop if float(fit.rotation[2]) < _DROP_RISE_SHARE * drop else 0.0

    def _refined(self, motion: np.ndarray, v1: np.ndarray, m2: np.ndarray, prior: GroundPrior,
                 hinge: Hinge) -> tuple[LocalGroundResult, GroundPrior]:
        """The pair refined over the local ground, and the prior it used.

        Once more through a jolt if it is lost. A fit that slides sideways off its arc gives
        way to the jolt's fit if that one keeps to an arc; if that one slides through a jolt,
        to the fit held to its arc (see _SLIDE_SHARE).
        """
        args = (motion, v1, m2, prior, hinge)
        bound = max(_SLIDE_SHARE * self.travel, _SLIDE_FLOOR)
        held = _HELD_SHARE * bound

        def astray(jolted: LocalGroundResult) -> bool:
            # Sliding through a jolt: a vehicle that really moves sideways (mecanum wheels)
            # keeps its own fit on smooth ground.
            return (off_arc(jolted.motion) > bound
                    and self.wheel_lift(jolted.rotation) > IRREGULAR_LIFT)

        try:
            fit, used = self._smooth(*args)
        except PoseEstimationError:
            jolted = self._jolt(*args)
            if not astray(jolted[0]):
                return jolted
            try:
                return self._jolt(*args, arc_sigma=held)
            except PoseEstimationError:
                return jolted
        if off_arc(fit.motion) <= bound:
            return fit, used
        try:
            jolted = self._jolt(*args)
        except PoseEstimationError:
            return fit, used
        if off_arc(jolted[0].motion) <= bound:
            return jolted
        if not astray(jolted[0]):
            return fit, used
        try:
            return self._smooth(*args, arc_sigma=held)
        except PoseEstimationError:
            return fit, used

    def _refine(self, motion: np.ndarray, v1: np.ndarray, m2: np.ndarray, prior: GroundPrior,
                hinge: Hinge, *, start_threshold: float | None = None,
                arc_sigma: float | None = None) -> LocalGroundResult:
        """refine_on_local_ground with this pair's camera, thresholds and Cauchy scale."""
        return refine_on_local_ground(
            motion, v1, m2, self.camera, prior, focal_px=self.focal_px,
            threshold_px=self.inlier_threshold,
            start_threshold_px=self.start_threshold if start_threshold is None
            else start_threshold,
            hinge=hinge, cauchy=_CAUCHY, arc_sigma=arc_sigma)

    def _smooth(self, motion: np.ndarray, v1: np.ndarray, m2: np.ndarray, prior: GroundPrior,
                hinge: Hinge, *, arc_sigma: float | None = None,
                ) -> tuple[LocalGroundResult, GroundPrior]:
        """The pair refined with the body's learned rate as the rotation's prior.

        Once more with the height change's upper bound if a wheel lifted. Raises
        PoseEstimationError when it is lost.
        """
        fit = self._refine(motion, v1, m2, prior, hinge, arc_sigma=arc_sigma)
        if self.wheel_lift(fit.rotation) <= IRREGULAR_LIFT and not self._height_held_down(fit):
            return fit, prior
        # A rear wheel climbing a bump lifts base_link 5-8 cm within a frame, far past
        # the height's rate learned on the road before: that prior held the lift to 80 %
        # and the step took the rest (+10-24 mm a bump on a rendered 8 cm bump).
        dt = self.dt
        rates2 = np.r_[self.rate2[:2], self.rates[2] ** 2]
        lifted = GroundPrior(np.diag(rates2 * dt * dt), prior.surface, prior.surface_cov)
        return self._refine(motion, v1, m2, lifted, hinge, arc_sigma=arc_sigma), lifted

    def _height_held_down(self, fit: LocalGroundResult) -> bool:
        """Whether the height change's prior held the camera down against the tracks.

        The pair's reading of the height change without its prior (``measured_rotation``)
        beyond _RISE_SIGMAS of the learned rate and _RISE_FLOOR: a wheel climbing a long, low
        bump, whose rise a frame is below what the pitch flags as a lift.
        """
        bound = max(_RISE_SIGMAS * float(np.sqrt(self.rate2[2])) * self.dt, _RISE_FLOOR)
        return abs(float(fit.measured_rotation[2])) > bound

    def _jolt(self, motion: np.ndarray, v1: np.ndarray, m2: np.ndarray, prior: GroundPrior,
              hinge: Hinge, *, arc_sigma: float | None = None,
              ) -> tuple[LocalGroundResult, GroundPrior]:
        """The pair refined as a jolt beyond the learned rate, and the prior it used.

        A wheel hitting a bump turns the car 1-2 deg in a frame: the rotation's prior is the
        rate's upper bound, from a wider threshold.
        """
        dt = self.dt
        jolt = GroundPrior(np.diag(self.rates ** 2 * dt * dt), prior.surface, prior.surface_cov)
        wide = jolt_threshold(self.rates ** 2, self.inlier_threshold, self.focal_px, dt)
        fit = self._refine(motion, v1, m2, jolt, hinge,
                           start_threshold=max(wide, self.start_threshold), arc_sigma=arc_sigma)
        if np.any(np.abs(fit.rotation[:2]) > JOLT_SIGMAS * self.rates[:2] * dt):
            # No vehicle turns that fast: an image that matches nothing (a shifted or corrupt
            # frame) fitted by a rotation.
            raise PoseEstimationError('no motion fits the local ground, even as a jolt')
        return fit, jolt

    def _without_bands(self, fit: LocalGroundResult, motion: np.ndarray, v1: np.ndarray,
                       m2: np.ndarray, prior: GroundPrior, hinge: Hinge,
                       ) -> tuple[LocalGroundResult, np.ndarray]:
        """``fit`` refined again without the bands off its surface (when that holds).

        Also returns which of the road history's samples ahead (SAMPLES_AHEAD) a band covers.
        """
        keep = off_surface_bands(fit, v1, m2, self.camera, hinge, self.focal_px)
        # The road's history is not kept where a band went: the smooth surface is not the
        # road there (all four terrains with a sprung body: 0.50 -> 0.44 %; marking every
        # sample of a pair whose surface jumped kept the body's tilt unread on 2/3 of it).
        rough = np.zeros(len(SAMPLES_AHEAD), bool)
        if keep is None:
            return fit, rough
        went = wheel_plane_distance(self.camera, v1[~keep])
        rough = samples_near(self.samples_from, went)
        if np.count_nonzero(keep) < self.min_inliers:
            return fit, rough
        try:
            again = self._refine(motion, v1[keep], m2[keep], prior, hinge)
        except PoseEstimationError:
            return fit, rough
        if (np.count_nonzero(again.inliers) < self.min_inliers
                or not refit_consistent(again, fit)):
            return fit, rough
        inliers = np.zeros(len(v1), bool)
        inliers[np.flatnonzero(keep)[again.inliers]] = True
        weights = np.zeros(len(v1))
        weights[keep] = again.weights
        return dataclasses.replace(again, inliers=inliers, weights=weights), rough
