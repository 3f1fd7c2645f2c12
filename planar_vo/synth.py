"""Synthetic rosbag2 bags with ground truth: a camera on a car driving over textured ground.

Geometry (all exact, the odometry is tested against it):

- base_link (REP-103: x forward, y left, z up) is on the rear axle, on the ground (z = 0 is
  the ground plane); odom is the base_link pose at the first frame.
- The vehicle follows a kinematic bicycle model at the rear axle (wheelbase 2.7 m) with
  smooth (C1) speed and steering profiles: ``yaw_rate = v * tan(steer) / wheelbase``.
- The camera body frame (x forward, y left, z up) sits at (camera_x, camera_y,
  camera_height) in base_link, rotated by ``Rz(yaw) @ Ry(pitch) @ Rx(roll)``; positive pitch
  tilts the camera down. The optical frame (x right, y down, z forward) is
  ``R_body_optical = [[0, 0, 1], [-1, 0, 0], [0, -1, 0]]`` relative to the body frame.
- Images are rendered *with* the plumb_bob distortion that CameraInfo describes: every pixel
  (u, v) (OpenCV convention, pixel centres at integer coordinates) is undistorted to a ray.

Rendering: a periodic pink-noise asphalt texture (20.48 m tile, 5 mm texels) sampled through
a mip-map with trilinear filtering, level chosen from each pixel's ground footprint; haze and a
smooth sky gradient beyond ``max_range``; textured vertical boxes as outliers (ray/box slab
intersection); vignetting, slow global illumination change and Gaussian noise. Deterministic
for a seed.
"""

from __future__ import annotations

import argparse
import functools
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from planar_vo.camera import Mounting
from planar_vo.progress import Progress

WHEELBASE = 2.7
EPOCH_NS = 1_700_000_000 * 1_000_000_000
IMAGE_TOPIC = '/camera/image_raw'
COMPRESSED_TOPIC = '/camera/image_raw/compressed'
INFO_TOPIC = '/camera/camera_info'
ODOM_TOPIC = '/ground_truth/odom'
OPTICAL_FRAME = 'camera_optical_frame'


# --------------------------------------------------------------------------------------------
# Set-up: mounting and camera
# --------------------------------------------------------------------------------------------


# The realistic set-up: 1.2 m ahead of the rear axle, 1.25 m up, pitched 8 degrees down.
DEFAULT_MOUNTING = Mounting(x=1.2, y=0.0, height=1.25, pitch=math.radians(8.0))


def params_yaml(mounting: Mounting) -> str:
    """Node/replay parameter file (``planar_vo: ros__parameters:``) for this mounting."""
    values = {'camera_x': mounting.x, 'camera_y': mounting.y,
              'camera_height': mounting.height, 'camera_roll': mounting.roll,
              'camera_pitch': mounting.pitch, 'camera_yaw': mounting.yaw}
    lines = ['planar_vo:', '  ros__parameters:']
    lines += [f'    {k}: {float(v)!r}' for k, v in values.items()]
    return '\n'.join(lines) + '\n'


# Lens models the renderer can simulate, as CameraInfo names them, with default coefficients.
DISTORTION_DEFAULTS = {
    'plumb_bob': (-0.25, 0.07, 0.0005, -0.0005, 0.0),
    'rational_polynomial': (-0.3, 0.09, 0.0005, -0.0005, -0.01, 0.01, 0.002, 0.0),
    'equidistant': (-0.03, 0.004, -0.001, 0.0002),
}


@dataclass(frozen=True)
class SynthCamera:
    """Camera with lens distortion, OpenCV conventions (``equidistant`` is cv2.fisheye)."""

    width: int = 640
    height: int = 480
    fx: float = 460.0
    fy: float = 460.0
    cx: float = 320.0
    cy: float = 240.0
    dist: tuple = DISTORTION_DEFAULTS['plumb_bob']
    distortion_model: str = 'plumb_bob'

    def __post_init__(self) -> None:
        expected = len(DISTORTION_DEFAULTS[self.distortion_model])
        if len(self.dist) != expected:
            raise ValueError(f'{self.distortion_model} takes {expected} coefficients, '
                             f'not {len(self.dist)}')

    @classmethod
    def scaled(cls, width: int, height: int, **kw) -> SynthCamera:
        """Default camera scaled to another image size (same field of view)."""
        s = width / 640.0
        base = dict(width=width, height=height, fx=460.0 * s, fy=460.0 * s,
                    cx=width / 2.0, cy=height / 2.0)
        base.update({k: v for k, v in kw.items() if v is not None})
        if 'dist' not in base:
            base['dist'] = DISTORTION_DEFAULTS[base.get('distortion_model', 'plumb_bob')]
        return cls(**base)

    def k_matrix(self) -> np.ndarray:
        """3x3 intrinsic matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def project(self, points_optical: np.ndarray) -> np.ndarray:
        """Project (N, 3) points in the optical frame to distorted pixels (N, 2)."""
        pts = np.asarray(points_optical, np.float64).reshape(-1, 1, 3)
        d = np.asarray(self.dist, np.float64)
        if self.distortion_model == 'equidistant':
            px, _ = cv2.fisheye.projectPoints(pts, np.zeros((3, 1)), np.zeros((3, 1)),
                                              self.k_matrix(), d)
        else:
            px, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), self.k_matrix(), d)
        return px.reshape(-1, 2)

    def rays(self) -> np.ndarray:
        """Rays ``(x, y, 1)`` in the optical frame for every pixel, shape (H, W, 3); cached."""
        return _camera_rays(self)


def undistort_pixels(pixels: np.ndarray, k: np.ndarray, dist,
                     model: str = 'plumb_bob') -> np.ndarray:
    """Undistort (N, 2) pixels to normalised image coordinates with tight convergence."""
    pts = np.asarray(pixels, np.float64).reshape(-1, 1, 2)
    d = np.asarray(dist, np.float64)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    if model == 'equidistant':
        out = cv2.fisheye.undistortPoints(pts, k, d, criteria=crit)
    elif hasattr(cv2, 'undistortPointsIter'):  # OpenCV 4.x
        out = cv2.undistortPointsIter(pts, k, d, None, None, crit)
    else:  # OpenCV 5.x
        out = cv2.undistortPoints(pts, k, d, criteria=crit)
    return out.reshape(-1, 2)


@functools.lru_cache(maxsize=8)
def _camera_rays(cam: SynthCamera) -> np.ndarray:
    u, v = np.meshgrid(np.arange(cam.width, dtype=np.float64),
                       np.arange(cam.height, dtype=np.float64))
    xy = undistort_pixels(np.stack([u.ravel(), v.ravel()], 1), cam.k_matrix(), cam.dist,
                          cam.distortion_model)
    rays = np.concatenate([xy, np.ones((xy.shape[0], 1))], 1).reshape(cam.height, cam.width, 3)
    rays.setflags(write=False)
    return rays


# --------------------------------------------------------------------------------------------
# Texture
# --------------------------------------------------------------------------------------------


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


# --------------------------------------------------------------------------------------------
# Scenarios and trajectory
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Scenario:
    """Driving profile and obstacle density."""

    name: str
    speed: tuple = (3.0, 8.0)  # m/s range of the speed knots
    steer: float = 0.06  # max |steering angle| of the knots (rad)
    knot_dt: tuple = (2.0, 3.5)  # seconds between knots
    obstacles_per_100m: float = 6.0
    ahead_fraction: float = 0.2  # fraction of obstacles close to the path (seen ahead)
    description: str = ''


SCENARIOS = {
    'straight': Scenario('straight', speed=(5.0, 5.0), steer=0.0, obstacles_per_100m=4.0,
                         description='straight line at a constant 5 m/s, few obstacles'),
    'gentle': Scenario('gentle', speed=(4.0, 7.0), steer=0.04, obstacles_per_100m=4.0,
                       description='gentle curves (radius >= ~65 m), 4-7 m/s'),
    'tight': Scenario('tight', speed=(2.0, 3.0), steer=0.35, knot_dt=(1.5, 2.5),
                      obstacles_per_100m=4.0,
                      description='tight turns (radius down to ~7.5 m), 2-3 m/s'),
    'obstacles': Scenario('obstacles', speed=(3.0, 6.0), steer=0.05, obstacles_per_100m=30.0,
                          ahead_fraction=0.35,
                          description='gentle curves among many boxes (30 per 100 m)'),
    'default': Scenario('default', speed=(3.0, 8.0), steer=0.08, obstacles_per_100m=8.0,
                        description='realistic mix: curves, speed changes 3-8 m/s, boxes'),
}


@dataclass
class Trajectory:
    """Ground truth at each frame: base_link pose in odom and twist in base_link."""

    t: np.ndarray  # s since the first frame
    x: np.ndarray
    y: np.ndarray
    yaw: np.ndarray
    v: np.ndarray  # forward speed (m/s)
    omega: np.ndarray  # yaw rate (rad/s)
    steer: np.ndarray
    wheelbase: float = WHEELBASE

    @property
    def length(self) -> float:
        """Path length (m) from the first to the last frame."""
        return float(np.hypot(np.diff(self.x), np.diff(self.y)).sum())


def _smooth_profile(rng, duration, lo, hi, knot_dt, symmetric=False):
    """C1 profile: random knots joined by smoothstep; returns f(t)."""
    times = [0.0]
    while times[-1] < duration + 1.0:
        times.append(times[-1] + rng.uniform(*knot_dt))
    n = len(times)
    if symmetric:
        vals = rng.uniform(-hi, hi, n)
        vals[0] = 0.0
    else:
        vals = rng.uniform(lo, hi, n)
    times_a = np.asarray(times)

    def f(t):
        t = np.asarray(t, np.float64)
        i = np.clip(np.searchsorted(times_a, t, side='right') - 1, 0, n - 2)
        s = np.clip((t - times_a[i]) / (times_a[i + 1] - times_a[i]), 0.0, 1.0)
        s = s * s * (3.0 - 2.0 * s)
        return vals[i] + (vals[i + 1] - vals[i]) * s

    return f


def make_trajectory(scenario: Scenario, frames: int, rate: float, seed: int,
                    wheelbase: float = WHEELBASE, substeps: int = 20) -> Trajectory:
    """Integrate the bicycle model (RK4 on fine sub-steps) and sample it at the frames."""
    rng = np.random.default_rng([seed, 1])
    dt = 1.0 / rate
    duration = (frames - 1) * dt
    speed = _smooth_profile(rng, duration, *scenario.speed, scenario.knot_dt)
    steer = _smooth_profile(rng, duration, 0.0, scenario.steer, scenario.knot_dt, True)

    def deriv(t, yaw):
        v = speed(t)
        return v * math.cos(yaw), v * math.sin(yaw), v * math.tan(steer(t)) / wheelbase

    x = np.zeros(frames)
    y = np.zeros(frames)
    yaw = np.zeros(frames)
    h = dt / substeps
    cx = cy = cyaw = 0.0
    for k in range(1, frames):
        t0 = (k - 1) * dt
        for j in range(substeps):
            t = t0 + j * h
            a = deriv(t, cyaw)
            b = deriv(t + h / 2, cyaw + h / 2 * a[2])
            c = deriv(t + h / 2, cyaw + h / 2 * b[2])
            d = deriv(t + h, cyaw + h * c[2])
            cx += h / 6 * (a[0] + 2 * b[0] + 2 * c[0] + d[0])
            cy += h / 6 * (a[1] + 2 * b[1] + 2 * c[1] + d[1])
            cyaw += h / 6 * (a[2] + 2 * b[2] + 2 * c[2] + d[2])
        x[k], y[k], yaw[k] = cx, cy, cyaw
    t = np.arange(frames) * dt
    v = speed(t)
    st = steer(t)
    return Trajectory(t, x, y, yaw, v, v * np.tan(st) / wheelbase, st, wheelbase)


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


def make_obstacles(traj: Trajectory, scenario: Scenario, seed: int,
                   mounting: Mounting | None = None) -> list[Box]:
    """Random boxes beside (and sometimes just off, ahead on) the path, never on it."""
    rng = np.random.default_rng([seed, 3])
    # Path samples, extended 40 m beyond the last pose along its heading.
    ext = np.linspace(0.5, 40.0, 80)
    px = np.concatenate([traj.x, traj.x[-1] + ext * math.cos(traj.yaw[-1])])
    py = np.concatenate([traj.y, traj.y[-1] + ext * math.sin(traj.yaw[-1])])
    pyaw = np.concatenate([traj.yaw, np.full(ext.size, traj.yaw[-1])])
    s = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(px), np.diff(py)))])
    total = s[-1]
    n = int(round(scenario.obstacles_per_100m * total / 100.0))
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
        if rng.random() < scenario.ahead_fraction:
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


# --------------------------------------------------------------------------------------------
# Renderer
# --------------------------------------------------------------------------------------------


class Renderer:
    """Render mono8 images of the ground (and boxes) for base_link poses in odom.

    All per-pixel ground geometry is fixed in base_link (planar motion), so it is computed
    once: ground hit points, mip levels, haze. Per frame only a 2-D rigid transform, the
    texture look-ups, the boxes and the noise are computed.
    """

    def __init__(self, camera: SynthCamera | None = None, mounting: Mounting | None = None,
                 texture: Texture | None = None, boxes=(), *, max_range: float = 60.0,
                 noise_sigma: float = 1.5, seed: int = 0, illumination: bool = True,
                 haze: bool = True) -> None:
        self.camera = camera or SynthCamera()
        self.mounting = mounting or DEFAULT_MOUNTING
        self.texture = texture if texture is not None else make_ground_texture(seed)
        self.boxes = list(boxes)
        self.max_range = float(max_range)
        self.noise_sigma = float(noise_sigma)
        self.seed = seed
        self.illumination = illumination
        cam, mnt = self.camera, self.mounting
        h, w = cam.height, cam.width
        rays = cam.rays().reshape(-1, 3)
        d = rays @ mnt.base_from_optical.T
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        self.dirs = d.astype(np.float32)  # unit rays in base_link
        self.origin = mnt.position
        cz = self.origin[2]
        if cz <= 0:
            raise ValueError('camera_height must be > 0')
        with np.errstate(divide='ignore', invalid='ignore'):  # sky rays: t = inf, masked below
            t = np.where(d[:, 2] < -1e-9, cz / -d[:, 2], np.inf)
            gp = self.origin[None, :2] + t[:, None] * d[:, :2]
        dist = np.hypot(gp[:, 0] - self.origin[0], gp[:, 1] - self.origin[1])
        ground = np.isfinite(t) & (dist < max_range)
        self.t_ground = np.where(ground, t, np.inf)
        # Footprint of each pixel on the ground (finite differences of hit points).
        g = np.where(ground[:, None], gp, np.nan).reshape(h, w, 2)
        du = np.linalg.norm(np.gradient(g, axis=1), axis=2)
        dv = np.linalg.norm(np.gradient(g, axis=0), axis=2)
        foot = np.fmax(du, dv).ravel()
        level = np.log2(np.maximum(np.nan_to_num(foot, nan=1e3) / self.texture.texel, 1e-9))
        level = np.clip(level, 0.0, self.texture.nlevels - 1.0)
        idx = np.flatnonzero(ground)
        l0 = np.floor(level[idx]).astype(np.int64)
        order = np.argsort(l0, kind='stable')
        self.g_idx = idx[order]
        self.g_l0 = l0[order]
        self.g_frac = (level[idx] - l0)[order].astype(np.float32)
        self.g_pts = gp[self.g_idx]
        # Sky gradient (depends on the ray's elevation only) and haze over distance.
        elev = np.arcsin(np.clip(d[:, 2], -1, 1))
        self.sky = (196.0 + 45.0 * np.sin(np.clip(elev, 0, None)) ** 0.7
                    - 12.0 * np.clip(-elev, 0, 0.2) / 0.2).astype(np.float32)
        rr = dist[self.g_idx]
        if haze:
            s = np.clip((rr - 0.5 * max_range) / (0.5 * max_range), 0, 1)
            fog = 0.12 * (1 - np.exp(-rr / 30.0)) + 0.88 * s * s * (3 - 2 * s)
        else:
            fog = np.zeros_like(rr)
        self.g_fog = np.clip(fog, 0, 1).astype(np.float32)
        # Vignetting (fixed per pixel).
        uu, vv = np.meshgrid((np.arange(w) - cam.cx) / w, (np.arange(h) - cam.cy) / h)
        self.vignette = (1.0 - 0.35 * (uu * uu + vv * vv)).ravel().astype(np.float32)
        self.ground_mask = ground.reshape(h, w)

    def ground_points_base(self) -> np.ndarray:
        """(H, W, 2) ground hit point of every pixel in base_link (NaN = no ground)."""
        out = np.full((self.camera.height * self.camera.width, 2), np.nan)
        out[self.g_idx] = self.g_pts
        return out.reshape(self.camera.height, self.camera.width, 2)

    def gain(self, k: int) -> float:
        """Global illumination gain of frame k (slow, smooth)."""
        if not self.illumination:
            return 1.0
        ph = (self.seed % 97) * 0.37
        return 1.0 + 0.05 * math.sin(0.21 * k / 30.0 * 2 * math.pi + ph) \
            + 0.02 * math.sin(0.9 * k / 30.0 * 2 * math.pi + 2 * ph)

    def render(self, x: float, y: float, yaw: float, k: int = 0) -> np.ndarray:
        """Render the image seen from base_link pose (x, y, yaw) in odom; frame index k."""
        cam = self.camera
        img = self.sky.copy()
        c, s = math.cos(yaw), math.sin(yaw)
        gx = x + c * self.g_pts[:, 0] - s * self.g_pts[:, 1]
        gy = y + s * self.g_pts[:, 0] + c * self.g_pts[:, 1]
        val = self.texture.sample_sorted(gx, gy, self.g_l0, self.g_frac)
        sky = img[self.g_idx]
        img[self.g_idx] = val + (sky - val) * self.g_fog
        if self.boxes:
            self._render_boxes(img, x, y, yaw)
        img *= self.vignette * self.gain(k)
        if self.noise_sigma > 0:
            rng = np.random.default_rng([self.seed, 4, k])
            img += rng.standard_normal(img.shape[0], np.float32) * np.float32(self.noise_sigma)
        return np.clip(img + 0.5, 0, 255).astype(np.uint8).reshape(cam.height, cam.width)

    def _render_boxes(self, img: np.ndarray, x: float, y: float, yaw: float) -> None:
        c, s = math.cos(yaw), math.sin(yaw)
        ox, oy, oz = self.origin
        cwx, cwy = x + c * ox - s * oy, y + s * ox + c * oy  # camera centre in odom
        depth = self.t_ground.copy()
        cands = []
        for b in self.boxes:
            dx, dy = b.x - cwx, b.y - cwy
            r = math.sqrt(b.half_x ** 2 + b.half_y ** 2 + (b.height / 2) ** 2)
            dist = math.sqrt(dx * dx + dy * dy + (b.height / 2 - oz) ** 2)
            if dist - r > self.max_range:
                continue
            # Direction to the centre in base_link.
            vb = np.array([c * dx + s * dy, -s * dx + c * dy, b.height / 2 - oz]) / dist
            cands.append((dist, b, vb, r))
        cands.sort(key=lambda e: e[0])
        for dist, b, vb, r in cands:
            if dist > r * 1.001:
                cos_th = math.cos(math.asin(r / dist))
                sel = np.flatnonzero(self.dirs @ vb.astype(np.float32) > cos_th)
            else:
                sel = np.arange(self.dirs.shape[0])
            if sel.size == 0:
                continue
            d = self.dirs[sel].astype(np.float64)
            a = yaw - b.yaw  # base → box rotation
            ca, sa = math.cos(a), math.sin(a)
            dlx = ca * d[:, 0] - sa * d[:, 1]
            dly = sa * d[:, 0] + ca * d[:, 1]
            dlz = d[:, 2]
            cb, sb = math.cos(b.yaw), math.sin(b.yaw)
            olx = cb * (cwx - b.x) + sb * (cwy - b.y)
            oly = -sb * (cwx - b.x) + cb * (cwy - b.y)
            olz = oz
            with np.errstate(divide='ignore', invalid='ignore'):
                tx1, tx2 = (-b.half_x - olx) / dlx, (b.half_x - olx) / dlx
                ty1, ty2 = (-b.half_y - oly) / dly, (b.half_y - oly) / dly
                tz1, tz2 = (0.0 - olz) / dlz, (b.height - olz) / dlz
            tnx, tfx = np.fmin(tx1, tx2), np.fmax(tx1, tx2)
            tny, tfy = np.fmin(ty1, ty2), np.fmax(ty1, ty2)
            tnz, tfz = np.fmin(tz1, tz2), np.fmax(tz1, tz2)
            tnear = np.fmax(np.fmax(tnx, tny), tnz)
            tfar = np.fmin(np.fmin(tfx, tfy), tfz)
            hit = (tnear <= tfar) & (tnear > 1e-6) & (tnear < depth[sel])
            if not hit.any():
                continue
            tn = tnear[hit]
            px = olx + tn * dlx[hit]
            py = oly + tn * dly[hit]
            pz = olz + tn * dlz[hit]
            face_x = tnx[hit] >= np.fmax(tny[hit], tnz[hit])
            face_z = ~face_x & (tnz[hit] >= tny[hit])
            tu = np.where(face_x, py, px)
            tv = np.where(face_z, py, pz)
            shade = np.where(face_x, np.where(px > 0, 0.85, 1.1),
                             np.where(face_z, 1.2, np.where(py > 0, 0.95, 0.75)))
            level = np.log2(np.maximum(tn / self.camera.fx / self.texture.texel, 1e-9))
            tex = self.texture.sample(tu + b.tex_x, tv + b.tex_y, level)
            idx = sel[hit]
            val = (b.albedo * shade * (tex - 110.0) * 1.3 + 100.0 + b.offset) * shade
            rr = tn
            fs = np.clip((rr - 0.5 * self.max_range) / (0.5 * self.max_range), 0, 1)
            fog = 0.12 * (1 - np.exp(-rr / 30.0)) + 0.88 * fs * fs * (3 - 2 * fs)
            img[idx] = val + (img[idx] * 0 + self.sky[idx] - val) * fog
            depth[idx] = tn


# --------------------------------------------------------------------------------------------
# Messages and bag
# --------------------------------------------------------------------------------------------


def _stamp(ts, ns: int):
    return ts.types['builtin_interfaces/msg/Time'](sec=ns // 1_000_000_000,
                                                   nanosec=ns % 1_000_000_000)


def _header(ts, ns: int, frame: str):
    return ts.types['std_msgs/msg/Header'](stamp=_stamp(ts, ns), frame_id=frame)


def camera_info_msg(ts, cam: SynthCamera, ns: int):
    """sensor_msgs/CameraInfo for ``cam`` (its distortion model, R = I, P = [K|0])."""
    t = ts.types
    k = cam.k_matrix()
    p = np.zeros((3, 4))
    p[:, :3] = k
    roi = t['sensor_msgs/msg/RegionOfInterest'](x_offset=0, y_offset=0, height=0, width=0,
                                                  do_rectify=False)
    return t['sensor_msgs/msg/CameraInfo'](
        header=_header(ts, ns, OPTICAL_FRAME), height=cam.height, width=cam.width,
        distortion_model=cam.distortion_model, d=np.asarray(cam.dist, np.float64),
        k=k.ravel(), r=np.eye(3).ravel(), p=p.ravel(), binning_x=0, binning_y=0, roi=roi)


def image_msg(ts, img: np.ndarray, ns: int):
    """sensor_msgs/Image mono8."""
    h, w = img.shape
    return ts.types['sensor_msgs/msg/Image'](
        header=_header(ts, ns, OPTICAL_FRAME), height=h, width=w, encoding='mono8',
        is_bigendian=0, step=w, data=np.ascontiguousarray(img).reshape(-1))


def compressed_msg(ts, img: np.ndarray, ns: int, quality: int = 90):
    """sensor_msgs/CompressedImage (JPEG, mono8)."""
    ok, buf = cv2.imencode('.jpg', img, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise RuntimeError('JPEG encoding failed')
    return ts.types['sensor_msgs/msg/CompressedImage'](
        header=_header(ts, ns, OPTICAL_FRAME), format='mono8; jpeg compressed mono8',
        data=buf.reshape(-1).astype(np.uint8))


def odometry_msg(ts, traj: Trajectory, k: int, ns: int):
    """nav_msgs/Odometry of base_link in odom (twist in base_link), zero covariance."""
    t = ts.types
    yaw = float(traj.yaw[k])
    pose = t['geometry_msgs/msg/Pose'](
        position=t['geometry_msgs/msg/Point'](x=float(traj.x[k]), y=float(traj.y[k]), z=0.0),
        orientation=t['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=math.sin(yaw / 2),
                                                      w=math.cos(yaw / 2)))
    vec = t['geometry_msgs/msg/Vector3']
    twist = t['geometry_msgs/msg/Twist'](linear=vec(x=float(traj.v[k]), y=0.0, z=0.0),
                                         angular=vec(x=0.0, y=0.0, z=float(traj.omega[k])))
    return t['nav_msgs/msg/Odometry'](
        header=_header(ts, ns, 'odom'), child_frame_id='base_link',
        pose=t['geometry_msgs/msg/PoseWithCovariance'](pose=pose, covariance=np.zeros(36)),
        twist=t['geometry_msgs/msg/TwistWithCovariance'](twist=twist, covariance=np.zeros(36)))


@dataclass
class SynthResult:
    """What :func:`generate_bag` wrote."""

    path: Path
    scenario: str
    frames: int
    rate: float
    seed: int
    camera: SynthCamera
    mounting: Mounting
    trajectory: Trajectory = field(repr=False)
    obstacles: int = 0
    seconds: float = 0.0


def render_scenario(scenario: str = 'default', frames: int = 300, seed: int = 0, *,
                    rate: float = 30.0, camera: SynthCamera | None = None,
                    mounting: Mounting | None = None, noise_sigma: float = 1.5,
                    max_range: float = 60.0, obstacles: bool = True):
    """Build the scene; return ``(renderer, trajectory)``.

    ``renderer.render(traj.x[k], traj.y[k], traj.yaw[k], k)`` is frame k of the bag.
    """
    if scenario not in SCENARIOS:
        raise ValueError(f'unknown scenario {scenario!r} (choose from {", ".join(SCENARIOS)})')
    sc = SCENARIOS[scenario]
    mounting = mounting or DEFAULT_MOUNTING
    traj = make_trajectory(sc, frames, rate, seed)
    boxes = make_obstacles(traj, sc, seed, mounting) if obstacles else []
    renderer = Renderer(camera, mounting, make_ground_texture(seed), boxes,
                        max_range=max_range, noise_sigma=noise_sigma, seed=seed)
    return renderer, traj


def generate_bag(out_path, scenario: str = 'default', frames: int = 300, seed: int = 0, *,
                 rate: float = 30.0, camera: SynthCamera | None = None,
                 mounting: Mounting | None = None, compressed: bool = False,
                 jpeg_quality: int = 90, noise_sigma: float = 1.5, max_range: float = 60.0,
                 obstacles: bool = True, storage_compression: bool = True,
                 params_out=None, progress: bool = False) -> SynthResult:
    """Render a scenario and write the rosbag2 bag (MCAP, zstd chunks) at ``out_path``."""
    from planar_vo.bag import BagWriter, typestore

    t0 = time.monotonic()
    camera = camera or SynthCamera()
    mounting = mounting or DEFAULT_MOUNTING
    renderer, traj = render_scenario(scenario, frames, seed, rate=rate, camera=camera,
                                     mounting=mounting, noise_sigma=noise_sigma,
                                     max_range=max_range, obstacles=obstacles)
    ts = typestore()
    img_topic = COMPRESSED_TOPIC if compressed else IMAGE_TOPIC
    img_type = 'sensor_msgs/msg/CompressedImage' if compressed else 'sensor_msgs/msg/Image'
    bar = Progress(frames, 'planar_vo_synth', enabled=progress)
    with BagWriter(out_path, compress=storage_compression) as bag:
        bag.add_topic(img_topic, img_type)
        bag.add_topic(INFO_TOPIC, 'sensor_msgs/msg/CameraInfo')
        bag.add_topic(ODOM_TOPIC, 'nav_msgs/msg/Odometry')
        for k in range(frames):
            ns = EPOCH_NS + int(round(k * 1e9 / rate))
            img = renderer.render(traj.x[k], traj.y[k], traj.yaw[k], k)
            msg = compressed_msg(ts, img, ns, jpeg_quality) if compressed \
                else image_msg(ts, img, ns)
            # CameraInfo first, as camera drivers do: a reader has the calibration in time.
            bag.write(INFO_TOPIC, 'sensor_msgs/msg/CameraInfo', ns,
                      camera_info_msg(ts, camera, ns))
            bag.write(img_topic, img_type, ns, msg)
            bag.write(ODOM_TOPIC, 'nav_msgs/msg/Odometry', ns, odometry_msg(ts, traj, k, ns))
            bar.update(k + 1)
    bar.close()
    if params_out is not None:
        Path(params_out).write_text(params_yaml(mounting))
    return SynthResult(Path(out_path), scenario, frames, rate, seed, camera, mounting, traj,
                       len(renderer.boxes), time.monotonic() - t0)


# --------------------------------------------------------------------------------------------
# CLI
# --------------------------------------------------------------------------------------------


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, exit code 2
        self.exit(2, f'planar_vo_synth: error: {message}\n')


def _positive_int(s):
    v = int(s)
    if v <= 0:
        raise argparse.ArgumentTypeError(f'must be > 0, got {s}')
    return v


def _positive_float(s):
    v = float(s)
    if not math.isfinite(v) or v <= 0:
        raise argparse.ArgumentTypeError(f'must be a finite number > 0, got {s}')
    return v


def _finite(s):
    v = float(s)
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f'must be finite, got {s}')
    return v


def _nonneg(s):
    v = float(s)
    if not math.isfinite(v) or v < 0:
        raise argparse.ArgumentTypeError(f'must be a finite number >= 0, got {s}')
    return v


def build_parser() -> argparse.ArgumentParser:
    """Command-line interface of ``planar_vo_synth``."""
    scen = '; '.join(f'{k}: {v.description}' for k, v in SCENARIOS.items())
    p = _Parser(
        prog='planar_vo_synth',
        description='Render a monocular camera on a car driving over textured ground and write '
                    'a rosbag2 bag (MCAP, Jazzy) with /camera/image_raw, /camera/camera_info '
                    'and /ground_truth/odom (base_link on the rear axle, in odom).')
    p.add_argument('out_bag', metavar='OUT_BAG', help='output bag directory (must not exist)')
    p.add_argument('--scenario', default='default', metavar='NAME',
                   help=f'driving scenario (default: default). {scen}')
    p.add_argument('--frames', type=_positive_int, default=300,
                   help='number of frames (default: 300)')
    p.add_argument('--seed', type=int, default=0, help='random seed (default: 0)')
    p.add_argument('--rate', type=_positive_float, default=30.0,
                   help='frame rate in Hz (default: 30)')
    p.add_argument('--width', type=_positive_int, default=640, help='image width (default 640)')
    p.add_argument('--height', type=_positive_int, default=480,
                   help='image height (default 480)')
    p.add_argument('--fx', type=_positive_float, help='focal length x in px (default 460*W/640)')
    p.add_argument('--fy', type=_positive_float, help='focal length y in px (default = fx)')
    p.add_argument('--cx', type=_finite, help='principal point x (default W/2)')
    p.add_argument('--cy', type=_finite, help='principal point y (default H/2)')
    p.add_argument('--distortion-model', choices=sorted(DISTORTION_DEFAULTS),
                   default='plumb_bob', help='lens model, as CameraInfo names it '
                   '(default plumb_bob; equidistant is the OpenCV fisheye model)')
    p.add_argument('--dist', type=_finite, nargs='+', metavar='D',
                   help='distortion coefficients in CameraInfo order: 5 for plumb_bob '
                        '(default -0.25 0.07 0.0005 -0.0005 0), 8 for rational_polynomial, '
                        '4 for equidistant')
    p.add_argument('--camera-x', type=_finite, default=1.2,
                   help='camera x ahead of the rear axle, m (default 1.2)')
    p.add_argument('--camera-y', type=_finite, default=0.0,
                   help='camera y (left), m (default 0)')
    p.add_argument('--camera-height', type=_positive_float, default=1.25,
                   help='camera height above the ground, m (default 1.25)')
    p.add_argument('--camera-roll', type=_finite, default=0.0, help='rad (default 0)')
    p.add_argument('--camera-pitch', type=_finite, default=math.radians(8.0),
                   help='rad, positive looks down (default 0.13963 = 8 deg)')
    p.add_argument('--camera-yaw', type=_finite, default=0.0, help='rad (default 0)')
    p.add_argument('--noise', type=_nonneg, default=1.5,
                   help='Gaussian image noise sigma, grey levels (default 1.5)')
    p.add_argument('--max-range', type=_positive_float, default=60.0,
                   help='ground beyond this distance (m) is haze/sky (default 60)')
    p.add_argument('--no-obstacles', action='store_true', help='no boxes')
    p.add_argument('--compressed', action='store_true',
                   help='write JPEG sensor_msgs/CompressedImage on /camera/image_raw/compressed '
                        'instead of raw Image')
    p.add_argument('--jpeg-quality', type=_positive_int, default=90,
                   help='JPEG quality with --compressed (default 90)')
    p.add_argument('--no-storage-compression', action='store_true',
                   help='do not zstd-compress the MCAP chunks')
    p.add_argument('--params-out', metavar='YAML',
                   help='also write a planar_vo params file with this mounting')
    p.add_argument('--quiet', action='store_true', help='no progress output')
    return p


def main(argv=None) -> int:
    """Entry point of ``planar_vo_synth``."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.scenario not in SCENARIOS:
        parser.error(f'unknown scenario {args.scenario!r} (choose from {", ".join(SCENARIOS)})')
    out = Path(args.out_bag)
    if out.exists():
        parser.error(f'output {out} already exists')
    if not out.parent.is_dir():
        parser.error(f'directory {out.parent} does not exist')
    if args.params_out and not Path(args.params_out).parent.is_dir():
        parser.error(f'directory of --params-out {args.params_out} does not exist')
    if args.jpeg_quality > 100:
        parser.error('--jpeg-quality must be in 1..100')
    if not -1.2 < args.camera_pitch < 1.5 or abs(args.camera_roll) > 0.5:
        parser.error('camera pitch/roll out of range: the camera must see the ground')
    expected = len(DISTORTION_DEFAULTS[args.distortion_model])
    if args.dist and len(args.dist) != expected:
        parser.error(f'--dist: {args.distortion_model} takes {expected} coefficients, '
                     f'not {len(args.dist)}')
    camera = SynthCamera.scaled(args.width, args.height, fx=args.fx,
                                fy=args.fy if args.fy is not None else args.fx,
                                cx=args.cx, cy=args.cy,
                                dist=tuple(args.dist) if args.dist else None,
                                distortion_model=args.distortion_model)
    mounting = Mounting(x=args.camera_x, y=args.camera_y, height=args.camera_height,
                        roll=args.camera_roll, pitch=args.camera_pitch, yaw=args.camera_yaw)
    from planar_vo.bag import BagError

    try:
        res = generate_bag(out, args.scenario, args.frames, args.seed, rate=args.rate,
                           camera=camera, mounting=mounting, compressed=args.compressed,
                           jpeg_quality=args.jpeg_quality, noise_sigma=args.noise,
                           max_range=args.max_range, obstacles=not args.no_obstacles,
                           storage_compression=not args.no_storage_compression,
                           params_out=args.params_out, progress=not args.quiet)
    except (BagError, OSError, ValueError) as err:
        print(f'planar_vo_synth: error: {err}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print('planar_vo_synth: interrupted', file=sys.stderr)
        return 130
    if not args.quiet:
        print(f'planar_vo_synth: wrote {res.path} ({res.frames} frames, scenario {res.scenario}, '
              f'path {res.trajectory.length:.1f} m, {res.obstacles} boxes, '
              f'{res.seconds:.1f} s)', file=sys.stderr)
    return 0


if __name__ == '__main__':
    sys.exit(main())
