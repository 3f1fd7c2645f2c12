"""The world: a periodic asphalt texture with a mip-map, and boxes beside the road."""

from __future__ import annotations

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
        mapx[:m] = np.mod(x / s - 0.5, n)
        mapy[:m] = np.mod(y / s - 0.5, n)
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


def _blur_wrap(img: np.ndarray, sigma: float) -> np.ndarray:
    pad = int(math.ceil(4 * sigma)) + 1
    big = np.pad(img, pad, mode='wrap')
    return cv2.GaussianBlur(big, (0, 0), sigma)[pad:-pad, pad:-pad]


@functools.lru_cache(maxsize=2)
def make_ground_texture(seed: int = 0, size: int = 4096, texel: float = 0.005) -> Texture:
    """Asphalt-like periodic texture: pink noise + speckle + stones + stains + lane dashes."""
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
