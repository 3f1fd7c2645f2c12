"""Ground seen above the smooth road, remembered where it lies until the front wheels reach it.

While a front wheel stands on a speed bump the road past the front axle lies below the wheels'
plane, which a surface hinged there holds only with a height at the hinge (its step comes out
up to 8 % short). A bump found as a band square across the path (:mod:`bumps_ahead`) gives that
height; a bump crossed at an angle is never such a band (the renderer's bumps lie across world
x: after a turn the car meets them at 40-65 deg). Here every track of a calm pair is a sample of
the ground at its own place, as much higher than the road as it moved faster than the smooth
surface predicts: a point ``dz`` above the road at the same image position is nearer, and its
flow is ``h / (h - dz)`` times the road's (``h`` the camera's height), so a flow excess ``e``
is ``dz = h e / (1 + e)``, the point ``1 / (1 + e)`` of the way to where its ray meets the
wheels' plane. The samples move with the vehicle (2D, with its yaw); each front wheel reads the
samples in its own cell. On 34 rendered drives t_rel summed 3.47 -> 3.22 % (bumps crossed at
40-65 deg, seeds 4 / 7: 0.163 / 0.125 -> 0.094 / 0.075 %; docs/terrain-notes.md, stop 41). Numpy
only; no ROS.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ['CELL_M', 'KEY_OFFSET', 'RaisedGround', 'cell_keys', 'height_from_excess']

CELL_M = 0.25  # m: the cells samples are pooled in (a bump is 0.5-1.5 m long)
# A cell is raised when its samples' mean flow excess is over _EXCESS (3 cm under a camera
# 1.1 m up; 2 % read false heights past the bumps of rendered drives), from at least
# _SAMPLES samples of at least _PAIRS pairs (one pair's error, e.g. the rear wheels starting
# to climb at 10 Hz, read 2-3 cm under the front wheels 2-3 m past a bump).
_EXCESS = 0.03
_SAMPLES = 3
_PAIRS = 2
# Samples are taken this far ahead of the front axle (m): the ground that the wheels will
# reach, seen before they are near it.
AHEAD_OF_HINGE = 0.8
_KEEP_BEHIND = 1.5  # m behind the front axle: the wheels have passed it, the samples go
KEY_OFFSET = 100000  # cell indices are offset by this to be positive in the cell keys


@dataclass(frozen=True)
class RaisedGround:
    """Samples of the ground (x, y in base_link, m; their flow excess; the pair they came from)."""

    xy: np.ndarray = field(default_factory=lambda: np.empty((0, 2)))
    excess: np.ndarray = field(default_factory=lambda: np.empty(0))
    pair: np.ndarray = field(default_factory=lambda: np.empty(0, np.int64))
    pairs: int = 0  # how many pairs gave samples so far

    def seen(self, camera: np.ndarray, ground: np.ndarray, excess: np.ndarray,
             hinge: float) -> RaisedGround:
        """Self with one pair's samples added.

        ``camera``: its position (3,) in base_link; ``ground``: (N, 2) where each track's ray
        meets the wheels' plane; ``excess``: (N,) its flow over the smooth surface's, less one.
        Only those ``AHEAD_OF_HINGE`` past the front axle (``hinge``, m) are kept.
        """
        shrink = 1.0 - np.clip(excess, 0.0, None) / (1.0 + np.clip(excess, 0.0, None))
        xy = camera[:2] + (ground - camera[:2]) * shrink[:, None]
        ahead = xy[:, 0] > hinge + AHEAD_OF_HINGE
        return RaisedGround(np.concatenate([self.xy, xy[ahead]]),
                            np.concatenate([self.excess, excess[ahead]]),
                            np.concatenate([self.pair, np.full(np.count_nonzero(ahead),
                                                               self.pairs)]),
                            self.pairs + 1)

    def moved(self, motion: np.ndarray, hinge: float) -> RaisedGround:
        """Self in base_link after the planar ``motion`` (x, y, yaw); all of it when reversing."""
        if motion[0] < 0.0:
            return RaisedGround()
        if not len(self.xy):
            return self
        c, s = np.cos(motion[2]), np.sin(motion[2])
        d = self.xy - motion[:2]
        xy = np.c_[c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]]
        keep = xy[:, 0] > hinge - _KEEP_BEHIND
        return RaisedGround(xy[keep], self.excess[keep], self.pair[keep], self.pairs)

    def height_at(self, points: np.ndarray, camera_height: float) -> np.ndarray:
        """How far (m) the ground at ``points`` (N, 2) is above the road: 0 where not raised."""
        out = np.zeros(len(points))
        wanted = cell_keys(points)
        cells = cell_keys(self.xy)
        near = np.zeros(len(cells), bool)  # only the samples in the cells asked about (few)
        for key in wanted:
            near |= cells == key
        if not near.any():
            return out
        keys, inverse = np.unique(cells[near], return_inverse=True)
        count = np.bincount(inverse)
        mean = np.bincount(inverse, self.excess[near]) / count
        # Each (cell, pair) once: how many pairs saw the cell.
        seen_by = np.unique(np.c_[inverse, self.pair[near]], axis=0)[:, 0]
        pairs = np.bincount(seen_by, minlength=len(keys))
        i = np.clip(np.searchsorted(keys, wanted), 0, len(keys) - 1)
        found = (keys[i] == wanted) & (count[i] >= _SAMPLES) & (pairs[i] >= _PAIRS)
        excess = np.where(found, mean[i], 0.0)
        raised = excess > _EXCESS
        out[raised] = height_from_excess(camera_height, excess[raised])
        return out


def height_from_excess(above: float | np.ndarray, excess: np.ndarray) -> np.ndarray:
    """How far (m) ground is above the road when its flow is ``1 + excess`` times the road's.

    ``above``: the camera's height over the road there. A point ``dz`` higher is nearer: its
    flow is ``h / (h - dz)`` times the road's, so ``dz = h e / (1 + e)``.
    """
    return above * excess / (1.0 + excess)


def cell_keys(xy: np.ndarray, cell_x: float = CELL_M, cell_y: float = CELL_M) -> np.ndarray:
    """One integer per cell (``cell_x`` by ``cell_y`` m) of ``xy`` (N, 2), sorted as x, then y."""
    ix = np.floor(xy[:, 0] / cell_x).astype(np.int64) + KEY_OFFSET
    iy = np.floor(xy[:, 1] / cell_y).astype(np.int64) + KEY_OFFSET
    return ix * 2 * KEY_OFFSET + iy
