"""What a sprung body does that its wheels do not: its tilt to them, its turn and its lift.

The local ground model (:mod:`.ground_filter`) rotates each frame pair about the wheel
contacts and takes the camera's height above the wheels as known. A car's body pitches,
rolls and bounces on its springs: the camera tilts to its wheels (read from the road's
history, :class:`~planar_vo.core.odometry.road_profile.RoadProfile`), turns about a pivot
nobody configured and rises and sinks. This learns how much of each the body does, so the
tilt is applied only as far as it is believed and the rest enters the motion's covariance.
Numpy only; no ROS.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from planar_vo.core.geometry.camera import Mounting

__all__ = ['SprungBody']

# The camera's tilt to its wheels from the road's history. Its error, measured on rigid cars
# (752x480, f 540 px): 0.038 deg on a flat road, 0.08 deg over grade changes (the rotations
# integrated about 5 % short, wandering with the grade), so a floor of 0.095 deg, this many
# pixels over the focal. How much a body really tilts is learned (its variance over
# _TILT_MEMORY_S, less that floor): rigid cars on every rendered terrain keep none of it
# (their results unchanged), a sprung car nearly all (0.31 -> 0.089 %).
_TILT_NOISE_PX = 0.9
# Where the history reads the road as flat (its reading's variance under _FLAT_READING_VAR,
# rad^2), the reading is as good as on a rigid car's flat road, and the body is believed
# against _FLAT_TILT_NOISE_PX instead: the floor held a sprung car's sustained dive back to
# 55-87 % of its reading (335 mdeg read of 374) while the reading was 30-60 mdeg off. Stop 55,
# 80 rendered drives 19.363 -> 19.143 % t_rel summed (flat sprung bodies about base_link
# 0.01-0.04 better each, a sprung mounting 1 deg off 0.272 -> 0.248; bumps sprung seed 32
# 0.079 -> 0.096), held out after the choice 12 more 1.845 -> 1.698 (one 0.064 -> 0.072).
_FLAT_READING_VAR = 5e-7
_FLAT_TILT_NOISE_PX = 0.5
_TILT_MEMORY_S = 5.0
_TILT_GATE = 4.0
_TILT_WARMUP = 20  # tilts learned before the gate applies
# What a sprung body moves that the pair does not model, for the motion's covariance: the
# body turns about its centre of mass, not the wheel contacts (the step's error is the
# pivot's height times the turn: RMS over a pivot anywhere from the ground to the camera,
# 0.58 of the camera's height), and its springs lift the camera (an error of the lift over
# the height, of the step). Measured on the rendered `car` (twist error regressed on the
# true body motion): 0.48 m per rad of pitch turn (pivot 0.55 m up), 0.62 per rad of roll,
# 0.79 of the bounce over the height. The lift is integrated from each pair's height change
# over _LIFT_MEMORY_S; its spread on rigid mounts was 1-2.2 mm, under _LIFT_FLOOR.
_PIVOT_SPREAD = 0.58
# A roll is read from the road's history less well than a pitch (0.9 px of noise over a 460 px
# focal length, 0.002 rad; the rendered `car` rolls 0.004 RMS), and shrunk to none under the
# noise: the rate learned from the rolls applied was 0.003-0.007 rad/s where the body rolled
# 0.013 RMS (pitch: 0.019 learned, 0.024 true), and the sideways twist error (0.55 m per rad
# of roll, up to 0.017 m/s) ran 6 sigma past what the covariance allowed. The roll is taken to
# turn as fast as the pitch where its own rate is less (both rendered bodies: roll 0.56x the
# pitch's rate).
_LIFT_MEMORY_S = 3.0
_LIFT_FLOOR = 0.003  # m
# The step's along error per unit of the lift over the height. Measured again in stop 61
# (the step's error regressed on the renderer's camera height about its median, over the
# height, times the step): 0.83 on the `car` and 0.86 on `rough`; and the lift learned runs
# above the true one (its spread over the floor 9.0 mm where the camera's height spreads 6.4;
# `rough` 15.7 and 12.7). Counted whole, the speed's NEES was 0.33 / 0.45 (the twist's 1.73 /
# 1.65); at 0.6, 0.75 / 0.96 (2.15 / 2.16; the 1 s pose 0.59 -> 0.62).
_LIFT_LEAK = 0.6
# Before they are learned: a body turning 0.05 rad/s (until the road's history first reads
# it) and lifting 5 mm (weighed as this many pairs): a car's. The first second of a sprung
# drive was otherwise overconfident (the rendered `car`'s twist NEES 5.6 instead of 1.6).
_PRIOR_RATE = 0.05
_PRIOR_LIFT = 0.005
_PRIOR_PAIRS = 5
# A pair's pitch turn is taken as the body's (squatting as it pulls away) only where the
# body's share of it is at least this: under 1.67 m/s, whatever the frame rate (the road's
# share grows with the speed; taken at any share, the 99 rendered drives of stop 68 lost
# 14.13 -> 14.42 % t_rel summed, from a quarter or less of each turn over hills).
_SQUAT_SHARE = 0.5
# Where the body pitches about (its x in base_link; its height made no difference on rendered
# drives). The pair turns about base_link, so its height change is the pivot's x times the
# body's pitch turn: regressed over pairs on flat road (the ground filter's _flat_pair), it
# finds the renderer's pivot on flat sprung drives (1.36 m for 1.35, 0.01 for 0). A 12 s
# drive's bounce and pitch correlate by chance (mid-car pivots regressed to 0.33-1.0 m for a
# while), so each sample weighs as a sample every _PIVOT_CORRELATION_S, nothing is learned
# before _PIVOT_WARMUP_S of them, the camera's own x (the tilt in place, as before) is the
# prior, _PIVOT_SPREAD_M wide, and the pivot is taken as learned only once its estimate leaves
# the prior by _PIVOT_APART_M. A body that pitches about base_link (flat, 12 s) 0.307 -> 0.149
# % t_rel, over 60 s 0.111 -> 0.066; mid-car bodies unchanged (with the truth given they gain
# nothing: 0.066 -> 0.073, 0.131 -> 0.123). Without the threshold they lost up to 0.02; with a
# sample every 0.25 s, 0.022.
# Once learned, its value is held towards the camera's x only as a pivot anywhere on a car
# is (_PIVOT_LEARNED_SPREAD_M): held 0.7 m wide, a body about base_link came to 0.3 m on a
# rendered flat drive whose pairs regressed to 0.0 +- 0.3. Stop 55, flat sprung drives: about
# base_link seven seeds 1.301 -> 1.109 % t_rel summed (one worse, 0.170 -> 0.190); held out
# after the choice, five more 0.878 -> 0.752, about the front axle 0.250 / 0.151 -> 0.205 /
# 0.102, mid-car and about the camera unchanged (not learned), none worse.
# Regressed on the levels since stop 62: the turns and height changes summed, each less its
# mean over _PIVOT_LEVEL_MEMORY_S (a drift in either left out), not pair by pair. A pair's
# change is mostly the body's 0.6-3 Hz bounce, which follows its pitch by chance for seconds;
# a level is mostly the slow dive and squat, which the bounce does not follow. Flat sprung
# drives, the pairs' turns and height changes 4 s in: about base_link 0.16 / -0.29 / 0.01
# (pair by pair 0.37 / 0.65 / -0.21), mid-car 1.51 / 0.95 / 1.19 (1.70 / 2.04 / 1.10) for 0
# and 1.35; a body about base_link braking at 1.5 m/s^2 4 s in had its pivot learned at 3 s,
# not 5. 150 rendered drives 26.918 -> 26.632 % t_rel summed (17 flat bodies about base_link
# 2.704 -> 2.477, 22 mid-car 1.378 -> 1.339; worse: a sprung mounting 1 deg off seed 49
# 0.137 -> 0.198, about base_link seed 72 0.156 -> 0.251).
_PIVOT_LEVEL_MEMORY_S = 4.0
_PIVOT_LEARNED_SPREAD_M = 2.0
_PIVOT_CORRELATION_S = 0.5
_PIVOT_WARMUP_S = 2.5
_PIVOT_SPREAD_M = 0.7
_PIVOT_APART_M = 0.5


@dataclass(frozen=True)
class SprungBody:
    """The body's learned motion on its springs. Replaced, never changed in place."""

    tilt_mean: np.ndarray  # (2,) (roll, pitch) of the camera to its wheels: its mean, rad
    tilt_var: np.ndarray  # (2,) and its variance, rad^2
    tilt_samples: int
    tilt_read: bool  # the last tilt came from the road's history
    unknown_tilt_var: np.ndarray  # (2,) what is not known of the tilt applied, rad^2
    rate2: np.ndarray  # (2,) mean square of the (roll, pitch) rate, rad^2/s^2
    rate_pairs: int
    lift: float  # m: the camera's height above its wheels, from the pairs' changes
    lift2: float  # its mean square, m^2
    lift_pairs: int
    # The pivot's regression: sums of w turn^2, w turn dh, w dh^2 and w (w = dt / s) over
    # the levels (turn and dh: the summed turns and height changes less their means), and
    # whether it is learned (see _PIVOT_APART_M).
    pivot_sums: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(4))
    pivot_learned: bool = False
    # The levels: summed turn (rad) and height change (m), their means, the samples.
    pivot_levels: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(5))
    # (2,) mean square of the pairs' own (roll, pitch) turn rate, rad^2/s^2: the body's turn
    # and the road's curve together, so never less than the body's.
    pair_rate2: np.ndarray = dataclasses.field(
        default_factory=lambda: np.full(2, _PRIOR_RATE ** 2))

    @classmethod
    def unknown(cls) -> SprungBody:
        """Nothing learned yet: a car's body is assumed (the priors above)."""
        return cls(np.zeros(2), np.zeros(2), 0, False, np.zeros(2),
                   np.full(2, _PRIOR_RATE ** 2), 0, 0.0, _PRIOR_LIFT ** 2, 0)

    def read_tilt(self, seen: tuple[np.ndarray, float] | None, static_tilt: np.ndarray,
                  dt: float, focal_px: float) -> tuple[SprungBody, np.ndarray]:
        """Self having learned the tilt, and the tilt: (roll, pitch) beyond ``static_tilt``.

        The camera's tilt to its wheels, rad, believed as far as the body tilts. ``seen``:
        the road's history's reading of the camera's tilt to the chord of its wheels and its
        variance, None when it cannot tell (then no tilt: see :meth:`held`). A reading
        further than _TILT_GATE sigmas from what the body does (a wheel on a bump) is not
        believed.
        """
        unknown = np.maximum(self.tilt_var - (_TILT_NOISE_PX / focal_px) ** 2, 0.0)
        body = dataclasses.replace(self, tilt_read=False, unknown_tilt_var=unknown)
        if seen is None:
            return body, np.zeros(2)
        tilt, variance = seen
        noise2 = (_TILT_NOISE_PX / focal_px) ** 2 + variance
        deviation = tilt - self.tilt_mean
        if (self.tilt_samples >= _TILT_WARMUP
                and np.any(deviation ** 2 > _TILT_GATE ** 2 * (self.tilt_var + noise2))):
            return body, np.zeros(2)
        samples = self.tilt_samples + 1
        alpha = min(max(dt / _TILT_MEMORY_S, 1.0 / samples), 1.0)
        tilt_var = (1.0 - alpha) * (self.tilt_var + alpha * deviation * deviation)
        body2 = np.maximum(tilt_var - noise2, 0.0)
        body = dataclasses.replace(body, tilt_mean=self.tilt_mean + alpha * deviation,
                                   tilt_var=tilt_var, tilt_samples=samples, tilt_read=True,
                                   unknown_tilt_var=body2 * noise2 / (body2 + noise2))
        floor_px = _FLAT_TILT_NOISE_PX if np.all(variance < _FLAT_READING_VAR) else _TILT_NOISE_PX
        believed = (floor_px / focal_px) ** 2 + variance
        return body, (tilt - static_tilt) * body2 / (body2 + believed)

    def held(self, tilt: np.ndarray, pitch_turn: float, focal_px: float) -> np.ndarray:
        """The tilt (roll, pitch) where the road's history did not read it (:meth:`read_tilt`).

        A body on its springs does not come level because a wheel is on a bump: its last
        ``tilt`` is held, its pitch turned by the pair's ``pitch_turn`` beyond the road's
        curve (rad; 0 when a wheel lifted) as far as the body is believed to tilt (a rigid
        car: not). Taken for none before: 15 rendered sprung drives over all four terrains
        summed 2.42 -> 2.19 % t_rel (held only: 2.25); the tilt jumped to none and back.
        """
        floor = (_TILT_NOISE_PX / focal_px) ** 2
        body2 = max(float(self.tilt_var[1]) - floor, 0.0)
        return tilt + np.array([0.0, pitch_turn * body2 / (body2 + floor)])

    def squat(self, pitch_turn: float, road_turn_sigma: float, dt: float) -> float:
        """The body's share (rad) of a pair's ``pitch_turn`` where the road's history is short.

        Before the wheels have driven over road the camera saw, a pair's turn is the body's
        and the road's together: the road turns the wheels by ``road_turn_sigma`` at most (its
        curvature's bound times the travel), the body by its rate before it is learned. Pulling
        away from rest the road's few centimetres hardly turn the wheels, and the squat is the
        body's (taken as none, the camera looked up 0.8 deg at the road ahead and the steps came
        out 1-4 % short).
        """
        body2 = (_PRIOR_RATE * dt) ** 2
        share = body2 / (body2 + road_turn_sigma ** 2)
        return pitch_turn * share if share >= _SQUAT_SHARE else 0.0

    def moved(self, change: np.ndarray, height_change: float, camera: np.ndarray, dt: float,
              *, read_before: bool, pair_turn: np.ndarray | None = None) -> SprungBody:
        """Self after a pair: body tilt changed by ``change`` (rad), wheel plane lifted.

        ``pair_turn``: the pair's own (roll, pitch) turn (rad), learned as :attr:`pair_rate2`.

        ``height_change``: the pair's (m); ``camera``: its position in base_link. The lift is
        the pair's height change, plus what its rotation about the wheel contacts moved the
        camera where the body turned (the wheels did not), fading. The turn rate is learned
        between two tilts read from the road's history.
        """
        turned = -camera[0] * change[1] + camera[1] * change[0]
        lift = float(np.exp(-dt / _LIFT_MEMORY_S) * (self.lift + height_change + turned))
        lift_pairs = self.lift_pairs + 1
        alpha = min(max(dt / _TILT_MEMORY_S, 1.0 / (lift_pairs + _PRIOR_PAIRS)), 1.0)
        pair_rate2 = self.pair_rate2 if pair_turn is None else (
            self.pair_rate2 + alpha * ((np.asarray(pair_turn) / dt) ** 2 - self.pair_rate2))
        body = dataclasses.replace(self, lift=lift, lift_pairs=lift_pairs,
                                   lift2=self.lift2 + alpha * (lift ** 2 - self.lift2),
                                   pair_rate2=pair_rate2)
        if not (read_before and self.tilt_read):
            return body
        rate_pairs = self.rate_pairs + 1
        alpha = min(max(dt / _TILT_MEMORY_S, 1.0 / rate_pairs), 1.0)
        return dataclasses.replace(body, rate_pairs=rate_pairs,
                                   rate2=self.rate2 + alpha * ((change / dt) ** 2 - self.rate2))

    def with_pivot_sample(self, turn: float, height_change: float, dt: float,
                          prior: float, *, follows: bool = True) -> SprungBody:
        """Self with a calm pair's pitch turn (rad, beyond the road) and height change (m).

        ``prior``: the pivot's x before it is learned (the camera's), m. ``follows``: the
        last pair was a sample too; else the levels start again (summed over a gap's missing
        pairs they are no level: a grades drive at 8-14 m/s sampling a third of its pairs
        took a mid-car body's pivot for 3.4 m, t_rel 0.076 -> 0.353 %).
        """
        start = self.pivot_levels if follows else np.zeros(5)
        levels = start + np.array([turn, height_change, 0.0, 0.0, 1.0])
        alpha = max(dt / _PIVOT_LEVEL_MEMORY_S, 1.0 / levels[4])
        levels[2:4] += alpha * (levels[:2] - levels[2:4])
        turned, lifted = levels[:2] - levels[2:4]
        w = dt / _PIVOT_CORRELATION_S
        sums = self.pivot_sums + w * np.array([turned * turned, turned * lifted,
                                               lifted * lifted, 1.0])
        learned = (self.pivot_learned
                   or abs(_pivot_estimate(sums, prior) - prior) > _PIVOT_APART_M)
        return dataclasses.replace(self, pivot_sums=sums, pivot_learned=learned,
                                   pivot_levels=levels)

    def pivot_x(self, prior: float) -> float:
        """Where the body pitches about (x in base_link, m): ``prior`` until learned."""
        if not self.pivot_learned:
            return prior
        return _pivot_estimate(self.pivot_sums, prior, _PIVOT_LEARNED_SPREAD_M)

    def covariance(self, camera: Mounting, travel: float, dt: float,
                   hinge: float) -> np.ndarray:
        """(3, 3) covariance of the step's error from the body's unmodelled motion.

        Its turn about an unknown pivot, its lift, and what is not known of its tilt (a
        pitch error hinges the ground at the front axle, ``hinge`` m ahead of base_link: the
        scale's error is the hinge's distance ahead of the camera over its height, per
        radian).
        """
        height = camera.height
        pivot2 = (_PIVOT_SPREAD * height * dt) ** 2
        lift2 = max(self.lift2 - _LIFT_FLOOR ** 2, 0.0) * (_LIFT_LEAK * travel / height) ** 2
        hinge2 = (travel * (hinge - camera.position[0]) / height) ** 2
        # The body turns no faster than the pairs see the camera turn: where the road's
        # history never reads (a robot, wheelbase 0) the prior's 0.05 rad/s stayed, and the
        # sideways speed's NEES was 0.01 (twist 1.04 flat, 0.84 on tight turns).
        rate2 = np.minimum(self.rate2, self.pair_rate2)
        # A roll under the readings' noise is not applied, nor its rate learned (above).
        roll_rate2 = max(rate2[0], rate2[1])
        return np.diag([pivot2 * rate2[1] + lift2 + hinge2 * self.unknown_tilt_var[1],
                        pivot2 * roll_rate2, 0.0])


def _pivot_estimate(sums: np.ndarray, prior: float, spread: float = _PIVOT_SPREAD_M) -> float:
    """The pivot's x (m) from its regression ``sums`` (SprungBody.pivot_sums) and ``prior``.

    The prior is ``spread`` m wide.
    """
    sxx, sxy, syy, samples = sums
    if samples * _PIVOT_CORRELATION_S < _PIVOT_WARMUP_S or sxx <= 0.0:
        return prior
    slope = sxy / sxx
    information = sxx * samples / (max(syy - sxy * slope, 0.0) + 1e-12)
    return float((prior / spread ** 2 + slope * information)
                 / (1.0 / spread ** 2 + information))
