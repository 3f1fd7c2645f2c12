"""The road the wheels stand on, remembered from when the camera saw it ahead.

From one frame pair a camera pitched by its sprung body and a road tilted ahead of the wheels
give the same images; they differ in where the tilt is hinged, 1.5 m ahead of a car's camera,
which is 2 % of the scale per degree (measured on a rendered sprung car: +1.2 of the step per
radian of the body's pitch). The road's history tells them apart: the ground the camera sees
2-6 m ahead is the ground the wheels stand on a second later, while a body's tilt is not
there when the wheels arrive.

So the gradient of the road is kept where it was seen, in a level frame that moves with the
vehicle: the camera's own level (its configured base plane) is integrated from the rotations
between frames, and each pair adds the surface's gradient ahead relative to it. When the
wheels stand on remembered ground, the chord between the axles is the mean gradient over
the wheelbase, and the camera's tilt to the wheels is its level minus that chord: no grade
ahead can pass for it. The integration's drift matters only over the second between seeing
the road and driving on it. Numpy only; no ROS.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ['SAMPLES_AHEAD', 'RoadProfile']

SAMPLES_AHEAD = np.array([0.5, 1.5, 2.5, 3.5])  # m past the hinge (or the view's start) sampled
_BINS = 3  # the wheelbase in this many parts, each needs a sample: the chord's mean gradient
_KEEP_BEHIND = 1.0  # m behind the rear axle a sample is still kept
_MAX_SAMPLES = 400
# The integrated level's error per radian it turned since a sample was seen: the rotations
# between frames are measured 3-5 % short on rendered grade changes (752x480), which a hill
# of a few degrees makes larger than a body's tilt.
_LEVEL_ERROR = 0.05


def _rotation(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s], [s, c]])


@dataclass(frozen=True)
class RoadProfile:
    """Gradients of the road seen ahead, and the camera's level, in the current base_link.

    Gradients are (dz/dx, dz/dy) relative to a level plane that is only defined up to a
    constant tilt (it drifts slowly); positions are base_link x, y. Replaced, never changed.
    """

    points: np.ndarray  # (N, 2) m
    gradients: np.ndarray  # (N, 2)
    variances: np.ndarray  # (N,)
    rough: np.ndarray  # (N,) bool: seen from a pair whose ground ahead was irregular
    seen_level: np.ndarray  # (N, 2) the level when each was seen
    level: np.ndarray  # (2,) the configured camera's base plane, as a gradient

    @classmethod
    def empty(cls) -> RoadProfile:
        """Nothing seen yet."""
        return cls(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), np.zeros(0, bool),
                   np.zeros((0, 2)), np.zeros(2))

    def with_pair(self, motion: np.ndarray, rotation: np.ndarray, surface: np.ndarray,
                  surface_cov: np.ndarray, tilt: np.ndarray, hinge: float,
                  rough: bool | np.ndarray, *, seen_from: float = 0.0) -> RoadProfile:
        """Add what a frame pair saw and move on to base_link of its second frame.

        Args:
            motion: (3,) x, y, yaw of base_link 2 in base_link 1.
            rotation: (2,) roll, pitch of frame 2 relative to frame 1 (rad, pitch nose down).
            surface: the local ground model's (grade, cross-slope, curvature, twist, ...) of
                the road past ``hinge`` relative to the pair's wheel plane.
            surface_cov: (5, 5) its covariance.
            tilt: (2,) roll, pitch of the camera to that wheel plane beyond the configured
                mounting (the learned static tilt and the body's) the pair used.
            seen_from: m past ``hinge`` where the camera's view of the road begins (0 when
                it begins before the hinge): the samples (SAMPLES_AHEAD) are taken from there,
                on road the pair saw, not on the surface carried back to the hinge.
        """
        ep, er, k, kxy, _ = surface
        offsets = seen_from + SAMPLES_AHEAD
        # The road's gradient relative to the configured camera's base plane: the pair's
        # wheel plane is that plane tilted by -tilt (nose down lowers the gradient ahead).
        along = ep + tilt[1] + k * offsets
        across = er - tilt[0] + kxy * offsets
        basis = np.stack([np.ones_like(offsets), offsets])
        var_along = np.einsum('in,ij,jn->n', basis, surface_cov[np.ix_([0, 2], [0, 2])], basis)
        var_across = np.einsum('in,ij,jn->n', basis, surface_cov[np.ix_([1, 3], [1, 3])], basis)
        ahead = np.c_[hinge + offsets, np.zeros_like(offsets)]
        points = np.vstack([self.points, ahead])
        gradients = np.vstack([self.gradients, self.level + np.c_[along, across]])
        variances = np.r_[self.variances, 0.5 * (var_along + var_across)]
        rough_ = np.r_[self.rough, np.broadcast_to(rough, SAMPLES_AHEAD.shape)]
        seen_level = np.vstack([self.seen_level, np.tile(self.level, (len(SAMPLES_AHEAD), 1))])
        level = self.level + np.array([-rotation[1], rotation[0]])
        # Into base_link 2.
        turn = _rotation(float(motion[2])).T
        points = (points - motion[:2]) @ turn.T
        keep = points[:, 0] > -_KEEP_BEHIND
        keep[:-_MAX_SAMPLES] = False
        return RoadProfile(points[keep], gradients[keep] @ turn.T, variances[keep],
                           rough_[keep], seen_level[keep] @ turn.T, turn @ level)

    def pitch_change(self, wheelbase: float, half_track: float, travel: float,
                     relief: float = 0.0) -> float | None:
        """The pitch change (rad, nose down) of the wheels' chord over ``travel`` forward.

        The chord turns by the gradient the front wheels meet less the one the rear wheels
        leave, times the travel over the wheelbase (on the rendered hills this explains the
        pitch between frames to 0.01-0.02 deg, of 0.05-0.17 deg rms). None until the road
        under both has been seen (never for a robot whose wheels share an axle, wheelbase 0);
        ground seen irregular is left out. ``relief``: how much a remembered hump's heights
        (not in the gradients) raise the chord's grade over the travel.
        """
        if wheelbase <= 0.0:
            return None
        x, y = self.points[:, 0], self.points[:, 1]
        smooth = (np.abs(y) <= half_track) & ~self.rough
        reach = max(travel, wheelbase / _BINS)
        front = smooth & (x >= wheelbase) & (x <= wheelbase + reach)
        rear = smooth & (x >= 0.0) & (x <= reach)
        if not (np.any(front) and np.any(rear)):
            return None
        rise = self.gradients[front, 0].mean() - self.gradients[rear, 0].mean()
        return float(-rise * travel / wheelbase - relief)

    def camera_tilt(self, wheelbase: float, half_track: float,
                    relief: float = 0.0) -> tuple[np.ndarray, float] | None:
        """(roll, pitch) of the camera to the chord of its wheels, rad, and its variance.

        Beyond the configured mounting. None until the ground under every part of the
        wheelbase has been seen. Ground seen irregular (a bump's band) is left out: the chord
        is the smooth road's, and a vehicle tilted by a bump under a wheel reads as a tilt to
        it (the caller's gate decides whether to believe it). ``relief``: a remembered hump's
        share of the chord's grade (rear wheels to front), which the gradients do not hold.
        """
        x, y = self.points[:, 0], self.points[:, 1]
        under = (x >= 0.0) & (x <= wheelbase) & (np.abs(y) <= half_track)
        under &= ~self.rough
        drift = np.linalg.norm(self.level - self.seen_level, axis=1)
        variances = self.variances + (_LEVEL_ERROR * drift) ** 2
        edges = np.linspace(0.0, wheelbase, _BINS + 1)
        means, bin_variances = [], []
        for lo, hi in zip(edges[:-1], edges[1:], strict=True):
            inside = under & (x >= lo) & (x <= hi)
            if not np.any(inside):
                return None
            w = 1.0 / np.maximum(variances[inside], 1e-12)
            means.append(w @ self.gradients[inside] / w.sum())
            # The samples of a bin share the level's drift: their mean is no better than
            # their best one.
            bin_variances.append(float(variances[inside].min()))
        chord = np.mean(means, axis=0) + np.array([relief, 0.0])
        relative = self.level - chord
        return np.array([relative[1], -relative[0]]), float(np.mean(bin_variances))
