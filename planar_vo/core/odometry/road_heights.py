"""A road hump's heights, remembered where the camera saw them until the rear wheels pass.

The local surface is a quadratic hinged at the front axle. A speed hump as long as the
wheelbase (3 m, 8 cm) is not: with the front wheels on it the road ahead falls over its far
face and then runs flat, and the steps came out 14-24 % long (0.52-1.6 % t_rel on rendered
3 m humps). Given the renderer's road height at each track (as a height above the surface
hinged at the front wheels) and the wheels' chord through it in the road's history, that
drive was 0.037 % (0.52 before); so the hump is remembered as heights.

Each pair measures, for every track seen near a bump found ahead (:mod:`bumps_ahead`), how
much higher the road there is than the model of the pair holds (its flow's excess, as
:mod:`raised_ground` reads it), and adds that to the height remembered in its cell (0.25 m
along, 0.5 m across, fixed to the road). A cell counts once it has samples from several
tracks and lies in a raised run (over 1 cm) ``LONG_M`` long or more: shorter bumps are left
to the bands and lifts that hold them (:mod:`bumps_ahead`). Runs of 1.0 m held the humps
better (14 held-out drives 5.54 -> 3.54 % t_rel summed, a 3 m hump 0.79 -> 0.48) but took
0.7 m bumps smeared over a metre for humps (all four terrains, sprung, 0.176 / 0.169 -> 0.214
/ 0.216; with 3 m humps 0.62 -> 1.29); at 1.25 m, 68 drives 9.40 -> 8.62 (none worse by over
0.033), the 14 held out 5.54 -> 3.94 (a 3 m hump 1.63 -> 0.43, another 0.79 -> 0.81).
Numpy only; no ROS.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from planar_vo.core.odometry.raised_ground import KEY_OFFSET, cell_keys

__all__ = ['RoadHeights', 'chord_grade']

CELL_X = 0.25  # m along the road
CELL_Y = 0.5  # m across it
_MIN_SAMPLES = 3  # tracks a cell needs before it counts
RAISED = 0.01  # m: a cell this high is part of a raised run
LONG_M = 1.25  # m: a raised run counts when it is this long
_MEMORY = 8  # samples: a cell's height moves towards new ones at least 1 / (this + new)
_KEEP_BEHIND = 1.0  # m behind base_link: the rear wheels have passed, the cell goes


def _keys(xy: np.ndarray) -> np.ndarray:
    """One integer per cell of road-fixed ``xy`` (N, 2)."""
    return cell_keys(xy, CELL_X, CELL_Y)


def _centres(keys: np.ndarray) -> np.ndarray:
    """Road-fixed centres (N, 2) of the cells ``keys``."""
    ix = keys // (2 * KEY_OFFSET) - KEY_OFFSET
    iy = keys % (2 * KEY_OFFSET) - KEY_OFFSET
    return np.c_[(ix + 0.5) * CELL_X, (iy + 0.5) * CELL_Y]


@dataclass(frozen=True)
class RoadHeights:
    """Heights (m) of the road above its smooth surface, in cells fixed to the road.

    ``pose``: base_link (x, y, yaw) in the road-fixed frame, integrated from the pairs'
    motions (only the metre or two between seeing a cell and driving over it matters).
    Replaced, never changed in place.
    """

    pose: np.ndarray = field(default_factory=lambda: np.zeros(3))
    keys: np.ndarray = field(default_factory=lambda: np.empty(0, np.int64))
    height: np.ndarray = field(default_factory=lambda: np.empty(0))
    count: np.ndarray = field(default_factory=lambda: np.empty(0))

    def __post_init__(self) -> None:
        object.__setattr__(self, '_long', _long_runs(self.keys, self.height, self.count))

    @property
    def any_raised(self) -> bool:
        """Whether any cell is raised (over RAISED, from _MIN_SAMPLES tracks): a hump forming."""
        return bool(_raised_cells(self.count, self.height).any())

    @property
    def in_use(self) -> bool:
        """Whether any cell counts (part of a long hump)."""
        return bool(self._long.any())

    def at(self, points: np.ndarray) -> np.ndarray:
        """Heights (N,) at base_link ``points`` (N, 2): 0 off a long hump."""
        out = np.zeros(len(points))
        if not self.in_use or not len(points):
            return out
        wanted = _keys(self._to_road(points))
        i = np.clip(np.searchsorted(self.keys, wanted), 0, len(self.keys) - 1)
        found = (self.keys[i] == wanted) & self._long[i]
        out[found] = self.height[i[found]]
        return out

    def extent(self) -> tuple[float, float, float] | None:
        """Where the remembered hump lies (x from, x to in base_link, m) and its top (m)."""
        if not self.in_use:
            return None
        c, s = np.cos(self.pose[2]), np.sin(self.pose[2])
        d = _centres(self.keys[self._long]) - self.pose[:2]
        x = c * d[:, 0] + s * d[:, 1]
        return float(x.min() - 0.5 * CELL_X), float(x.max() + 0.5 * CELL_X), float(
            self.height[self._long].max())

    def seen(self, points: np.ndarray, heights: np.ndarray) -> RoadHeights:
        """Self with the road's ``heights`` (N,) measured at base_link ``points`` (N, 2)."""
        if not len(points):
            return self
        new, inverse = np.unique(_keys(self._to_road(points)), return_inverse=True)
        samples = np.bincount(inverse).astype(float)
        mean = np.bincount(inverse, heights) / samples
        keys = np.union1d(self.keys, new)
        height, count = np.zeros(len(keys)), np.zeros(len(keys))
        old = np.searchsorted(keys, self.keys)
        height[old], count[old] = self.height, self.count
        i = np.searchsorted(keys, new)
        gain = samples / (np.minimum(count[i], _MEMORY) + samples)
        height[i] += gain * (mean - height[i])
        count[i] += samples
        return RoadHeights(self.pose, keys, height, count)

    def moved(self, motion: np.ndarray) -> RoadHeights:
        """Self after base_link moved by ``motion`` (x, y, yaw); none when reversing."""
        if motion[0] < 0.0:
            return RoadHeights()
        c, s = np.cos(self.pose[2]), np.sin(self.pose[2])
        pose = self.pose + np.array([c * motion[0] - s * motion[1],
                                     s * motion[0] + c * motion[1], motion[2]])
        if not len(self.keys):
            return RoadHeights(pose)
        d = _centres(self.keys) - pose[:2]
        keep = np.cos(pose[2]) * d[:, 0] + np.sin(pose[2]) * d[:, 1] > -_KEEP_BEHIND
        return RoadHeights(pose, self.keys[keep], self.height[keep], self.count[keep])

    def _to_road(self, points: np.ndarray) -> np.ndarray:
        """Base_link ``points`` (N, 2) in the road-fixed frame."""
        c, s = np.cos(self.pose[2]), np.sin(self.pose[2])
        return np.c_[c * points[:, 0] - s * points[:, 1] + self.pose[0],
                     s * points[:, 0] + c * points[:, 1] + self.pose[1]]


def _raised_cells(count: np.ndarray, height: np.ndarray) -> np.ndarray:
    """Which cells (bool) are raised: over RAISED, from _MIN_SAMPLES tracks or more."""
    return (count >= _MIN_SAMPLES) & (height > RAISED)


def _long_runs(keys: np.ndarray, height: np.ndarray, count: np.ndarray) -> np.ndarray:
    """Which cells (bool per key) lie in a raised run along x LONG_M long or more."""
    raised = _raised_cells(count, height)
    out = np.zeros(len(keys), bool)
    if not raised.any():
        return out
    ix, iy = keys // (2 * KEY_OFFSET), keys % (2 * KEY_OFFSET)
    for column in np.unique(iy[raised]):
        cells = np.flatnonzero(raised & (iy == column))  # keys are sorted: x ascending
        for run in np.split(cells, np.flatnonzero(np.diff(ix[cells]) != 1) + 1):
            if len(run) * CELL_X >= LONG_M - 1e-9:
                out[run] = True
    return out


def chord_grade(heights: RoadHeights, wheelbase: float, half_track: float,
                travel: float = 0.0) -> float:
    """The remembered heights' share of the wheels' chord grade, ``travel`` m further on.

    The mean front wheels' height less the rear's, over the wheelbase (none without one: a
    robot's drive wheels share an axle).
    """
    if wheelbase <= 0.0 or not heights.in_use:
        return 0.0
    wheels = np.array([[travel, half_track], [travel, -half_track],
                       [wheelbase + travel, half_track], [wheelbase + travel, -half_track]])
    h = heights.at(wheels)
    return float((h[2:].mean() - h[:2].mean()) / wheelbase)
