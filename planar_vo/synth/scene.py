"""The world: a periodic asphalt texture with a mip-map, and boxes beside the road."""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import cv2
import numpy as np

from planar_vo.synth.mount import DEFAULT_MOUNTING

if TYPE_CHECKING:
    from planar_vo.synth.vehicle import Trajectory


@dataclass(frozen=True)
class ObstacleProfile:
    """How many boxes stand beside the road, and how many of them close to the path."""

    per_100m: float = 6.0  # boxes per 100 m of path
    ahead_fraction: float = 0.2  # fraction of boxes close to the path (seen ahead)

    @classmethod
    def of(cls, profile) -> ObstacleProfile:
        """The profile of anything with ``obstacles_per_100m`` and ``ahead_fraction``.

        An ObstacleProfile is returned as it is; a Scenario gives its own.
        """
        if isinstance(profile, ObstacleProfile):
            return profile
        return cls(float(profile.obstacles_per_100m), float(profile.ahead_fraction))


class Texture:
    """Periodic greyscale texture with a mip-map; world (X, Y) in metres → grey value.

    Texel (row i, column j) of level 0 covers X in [j, j+1) * texel, Y in [i, i+1) * texel.
    """

    def __init__(self, image: np.ndarray, texel: float, min_size: int = 8) -> None:
        img = np.asarray(image, np.float32)
        if img.shape[0] != img.shape[1] or img.shape[0] & (img.shape[0] - 1):
            raise ValueError('texture must be square with a power-of-two size')
        self.texel = float(texel)
        self.levels: list[np.ndarray] = []
        self.sizes: list[int] = []
        while True:
            self.sizes.append(img.shape[0])
            self.levels.append(np.pad(img, ((0, 2), (0, 2)), mode='wrap'))
            if img.shape[0] // 2 < min_size:
                break
            img = 0.25 * (img[0::2, 0::2] + img[1::2, 0::2] + img[0::2, 1::2] + img[1::2, 1::2])
        self.nlevels = len(self.levels)

    def _sample_level(self, lev: int, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        s = self.texel * (1 << lev)
        n = self.sizes[lev]
        m = x.shape[0]
        cols = 4096
        rows = max(1, -(-m // cols))
        mapx = np.zeros(rows * cols, np.float32)
        mapy = np.zeros(rows * cols, np.float32)
        mapx[:m] = _wrap(x / s - 0.5, n)
        mapy[:m] = _wrap(y / s - 0.5, n)
        out = cv2.remap(self.levels[lev], mapx.reshape(rows, cols), mapy.reshape(rows, cols),
                        cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        return out.ravel()[:m]

    def sample(self, x: np.ndarray, y: np.ndarray, level: np.ndarray) -> np.ndarray:
        """Trilinear sample at world points (x, y) with fractional mip ``level`` (1-D arrays)."""
        level = np.clip(level, 0.0, self.nlevels - 1.0)
        l0 = np.floor(level).astype(np.int64)
        order = np.argsort(l0, kind='stable')
        out = np.empty(x.shape[0], np.float32)
        out[order] = self.sample_sorted(x[order], y[order], l0[order], level[order] - l0[order])
        return out

    def sample_sorted(self, x, y, l0, frac) -> np.ndarray:
        """Like :meth:`sample` for points already sorted by integer level ``l0``."""
        out = np.empty(x.shape[0], np.float32)
        if x.shape[0] == 0:
            return out
        bounds = np.flatnonzero(np.diff(l0)) + 1
        starts = np.concatenate([[0], bounds])
        ends = np.concatenate([bounds, [x.shape[0]]])
        for a, b in zip(starts, ends, strict=True):
            lev = int(l0[a])
            va = self._sample_level(lev, x[a:b], y[a:b])
            if lev + 1 < self.nlevels:
                vb = self._sample_level(lev + 1, x[a:b], y[a:b])
                va += (vb - va) * frac[a:b]
            out[a:b] = va
        return out


def _wrap(v: np.ndarray, n: int) -> np.ndarray:
    """``np.mod(v, n)`` for a power of two ``n``, bit for bit, an order of magnitude faster.

    ``n * floor(v / n)`` is exact, so the result is the exact remainder rounded once, as
    np.mod's (fmod, then + n when negative).
    """
    return v - n * np.floor(v / n)


def _blur_wrap(img: np.ndarray, sigma: float) -> np.ndarray:
    pad = int(math.ceil(4 * sigma)) + 1
    big = np.pad(img, pad, mode='wrap')
    return cv2.GaussianBlur(big, (0, 0), sigma)[pad:-pad, pad:-pad]


@functools.lru_cache(maxsize=5)  # ~64 MB each: the tests' five seeds built once
def make_ground_texture(seed: int = 0, size: int = 4096, texel: float = 0.005,
                        contrast: float = 1.0) -> Texture:
    """Asphalt-like periodic texture: pink noise + speckle + stones + stains + lane dashes.

    ``contrast`` scales every grey level's distance from 120 (a worn, even road: 0.3).
    """
    rng = np.random.default_rng([seed, 2])
    fy = np.fft.fftfreq(size)[:, None]
    fx = np.fft.rfftfreq(size)[None, :]
    f = np.sqrt(fx * fx + fy * fy)
    f[0, 0] = 1.0
    shape = (size, size // 2 + 1)
    spec = (rng.standard_normal(shape, np.float32) + 1j * rng.standard_normal(shape, np.float32))
    amp = f ** -0.85
    amp[0, 0] = 0.0
    amp *= np.exp(-(f / 0.35) ** 2)  # roll off right at the texel scale
    pink = np.fft.irfft2(spec * amp, s=(size, size)).astype(np.float32)
    pink /= pink.std()
    # Large stains: the low-frequency part of another field, soft-thresholded.
    low = np.fft.irfft2(
        (rng.standard_normal(shape) + 1j * rng.standard_normal(shape)) * (f < 0.004) / f,
        s=(size, size)).astype(np.float32)
    low /= low.std()
    stains = 1.0 / (1.0 + np.exp(-(low - 1.3) * 6.0))
    # Asphalt grain: blurred white noise and sparse stones (bright and dark).
    grain = _blur_wrap(rng.standard_normal((size, size), np.float32), 0.8)
    grain /= grain.std()
    stones = np.zeros((size, size), np.float32)
    mask = rng.random((size, size), np.float32) < 0.004
    stones[mask] = rng.choice(np.array([-1.0, 1.0, 1.5], np.float32), int(mask.sum()))
    stones = _blur_wrap(stones, 1.3)
    stones /= max(float(np.abs(stones).max()), 1e-6)
    img = 110.0 + 22.0 * pink + 9.0 * grain + 45.0 * stones - 35.0 * stains
    # Dashed lane markings along X (two per tile period), slightly worn.
    lane_w = int(round(0.12 / texel))
    dash = int(round(3.0 / texel))
    period = size // 2
    for row0 in (int(size * 0.18), int(size * 0.68)):
        for start in range(0, size, period):
            wear = 0.75 + 0.25 * rng.random((lane_w, dash), np.float32)
            img[row0:row0 + lane_w, start:start + dash] = (
                0.3 * img[row0:row0 + lane_w, start:start + dash] + 150.0 * wear)
    img = np.clip(img, 5.0, 250.0)
    if contrast != 1.0:
        img = 120.0 + contrast * (img - 120.0)
    return Texture(img, texel)


@dataclass(frozen=True)
class Box:
    """Vertical box standing on the ground (world/odom frame)."""

    x: float
    y: float
    yaw: float
    half_x: float
    half_y: float
    height: float
    tex_x: float = 0.0  # texture offset (m)
    tex_y: float = 0.0
    albedo: float = 1.0
    offset: float = 0.0


@dataclass(frozen=True)
class TrafficProfile:
    """Other road users crossing in front of the vehicle while it stands still.

    At every stop of at least ``min_stop`` s, cars cross the road ahead (one every
    ``car_every`` s, alternating directions), ``ahead`` (lo, hi) m in front of the camera at
    ``car_speed`` (lo, hi) m/s; with ``pedestrians`` one person also walks across
    ``walk_ahead`` m in front at about 1.3 m/s. They are boxes (cars 4.4 x 1.8 x 1.5 m,
    people 0.5 x 0.5 x 1.7 m) moving in straight lines; the ground under them is the same.
    """

    car_every: float = 3.0
    ahead: tuple = (7.0, 14.0)
    car_speed: tuple = (4.0, 9.0)
    pedestrians: bool = True
    walk_ahead: tuple = (4.0, 6.0)
    min_stop: float = 1.0


@dataclass(frozen=True)
class MovingBox:
    """A :class:`Box` moving at (``vx``, ``vy``) m/s in odom; ``box`` is where it is at ``t0``.

    It is in the scene only between ``t_on`` and ``t_off`` (s), when it is far to the side.
    """

    box: Box
    vx: float
    vy: float
    t0: float
    t_on: float
    t_off: float

    def at(self, t: float) -> Box | None:
        """The box at time ``t`` (s), None when it is not in the scene."""
        if not self.t_on <= t <= self.t_off:
            return None
        return dataclasses.replace(self.box, x=self.box.x + self.vx * (t - self.t0),
                                   y=self.box.y + self.vy * (t - self.t0))


def stops_of(traj: Trajectory) -> list[tuple[int, int]]:
    """(first, last) frame of every run of frames where the vehicle stands exactly still."""
    still = np.r_[False, (np.diff(traj.x) == 0) & (np.diff(traj.y) == 0)
                  & (np.diff(traj.yaw) == 0)]
    # frame k is still when it did not move since k - 1; the stop starts one frame earlier
    runs, k = [], 1
    while k < still.size:
        if still[k]:
            j = k
            while j + 1 < still.size and still[j + 1]:
                j += 1
            runs.append((k - 1, j))
            k = j + 1
        else:
            k += 1
    return runs


def make_traffic(traj: Trajectory, profile: TrafficProfile | None, seed: int,
                 camera_x: float = DEFAULT_MOUNTING.x) -> list[MovingBox]:
    """Cars (and people) crossing ahead during every stop of ``traj`` (see TrafficProfile)."""
    if profile is None:
        return []
    rng = np.random.default_rng([seed, 7])
    movers: list[MovingBox] = []
    for first, last in stops_of(traj):
        t0, t1 = float(traj.t[first]), float(traj.t[last])
        if t1 - t0 < profile.min_stop:
            continue
        x, y, yaw = float(traj.x[first]), float(traj.y[first]), float(traj.yaw[first])
        fwd = np.array([math.cos(yaw), math.sin(yaw)])
        left = np.array([-fwd[1], fwd[0]])
        n_cars = max(1, int((t1 - t0) // profile.car_every))
        crossings = [('car', t0 + (i + rng.uniform(0.3, 0.7)) * (t1 - t0) / n_cars)
                     for i in range(n_cars)]
        if profile.pedestrians and t1 - t0 >= 2.0:
            crossings.append(('person', rng.uniform(t0 + 0.3 * (t1 - t0), t0 + 0.7 * (t1 - t0))))
        for i, (kind, tc) in enumerate(crossings):
            if kind == 'car':
                ahead, speed = rng.uniform(*profile.ahead), rng.uniform(*profile.car_speed)
                half_x, half_y, height = 2.2, 0.9, 1.5
            else:
                ahead, speed = rng.uniform(*profile.walk_ahead), rng.uniform(1.1, 1.5)
                half_x, half_y, height = 0.25, 0.25, 1.7
            sign = 1.0 if i % 2 == 0 else -1.0
            centre = np.array([x, y]) + (camera_x + ahead) * fwd
            velocity = sign * speed * left
            box = Box(float(centre[0]), float(centre[1]), yaw + math.pi / 2, half_x, half_y,
                      height, rng.uniform(0, 20), rng.uniform(0, 20), rng.uniform(0.6, 1.2),
                      rng.uniform(-30, 40))
            span = 40.0 / speed  # seconds from 40 m to the side to the path
            movers.append(MovingBox(box, float(velocity[0]), float(velocity[1]), tc,
                                    tc - span, tc + span))
    return movers


def make_obstacles(traj: Trajectory, profile, seed: int, mounting=None) -> list[Box]:
    """Random boxes beside (and sometimes just off, ahead on) the path, never on it.

    ``profile``: an :class:`ObstacleProfile` (or a Scenario); the path is ``traj``'s x, y, yaw
    (in the world frame the boxes stand in).
    """
    profile = ObstacleProfile.of(profile)
    rng = np.random.default_rng([seed, 3])
    # Path samples, extended 40 m beyond the last pose along its heading.
    ext = np.linspace(0.5, 40.0, 80)
    px = np.concatenate([traj.x, traj.x[-1] + ext * math.cos(traj.yaw[-1])])
    py = np.concatenate([traj.y, traj.y[-1] + ext * math.sin(traj.yaw[-1])])
    pyaw = np.concatenate([traj.yaw, np.full(ext.size, traj.yaw[-1])])
    s = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(px), np.diff(py)))])
    total = s[-1]
    n = int(round(profile.per_100m * total / 100.0))
    # Vehicle body points (rear axle frame) that must stay clear of every box.
    cam_x = DEFAULT_MOUNTING.x if mounting is None else mounting.x
    body = np.array([-0.9, 0.0, 1.35, 2.7, 3.6, cam_x])
    vx = (traj.x[:, None] + body[None, :] * np.cos(traj.yaw)[:, None]).ravel()
    vy = (traj.y[:, None] + body[None, :] * np.sin(traj.yaw)[:, None]).ravel()
    boxes: list[Box] = []
    tries = 0
    while len(boxes) < n and tries < 50 * max(n, 1):
        tries += 1
        si = rng.uniform(4.0, total)
        i = int(np.searchsorted(s, si))
        i = min(i, px.size - 1)
        side = rng.choice([-1.0, 1.0])
        if rng.random() < profile.ahead_fraction:
            lat = side * rng.uniform(2.0, 3.2)
        else:
            lat = side * rng.uniform(3.2, 9.0)
        bx = px[i] - lat * math.sin(pyaw[i])
        by = py[i] + lat * math.cos(pyaw[i])
        hx, hy = rng.uniform(0.25, 1.0), rng.uniform(0.25, 1.0)
        radius = math.hypot(hx, hy)
        if np.min(np.hypot(vx - bx, vy - by)) < radius + 1.1:
            continue
        if any(math.hypot(b.x - bx, b.y - by) < radius + math.hypot(b.half_x, b.half_y)
               for b in boxes):
            continue
        boxes.append(Box(bx, by, rng.uniform(-math.pi, math.pi), hx, hy,
                         rng.uniform(0.5, 2.0), rng.uniform(0, 20), rng.uniform(0, 20),
                         rng.uniform(0.6, 1.2), rng.uniform(-30, 40)))
    return boxes
