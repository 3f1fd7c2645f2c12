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
  The renderer composes these rotations itself (axis-angle, :func:`rotation_rpy`), never with
  the pipeline's ``camera.Mounting``, so a wrong composition there cannot cancel out.
- A sprung body (:class:`Suspension`) may carry the camera: it pitches with the longitudinal
  acceleration (dive, squat), rolls with the lateral one (lean out of turns), both plus road
  vibration, and bounces; it rotates about a pivot at the body's centre of mass, so the camera
  also moves. The ground truth stays base_link on the ground; the true camera pose of every
  frame is ``Trajectory.camera``.
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
import dataclasses
import functools
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

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

# Axes of the optical frame (x right, y down, z forward) in the camera body frame (x forward,
# y left, z up): the columns of the rotation body <- optical.
BODY_FROM_OPTICAL = np.column_stack([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])


def axis_rotation(axis: str, angle: float) -> np.ndarray:
    """Rotation by ``angle`` (rad, right-hand rule) about base axis ``'x'``, ``'y'`` or ``'z'``.

    Built from the axis-angle vector with OpenCV's Rodrigues formula: the renderer's own path,
    independent of ``planar_vo.camera``.
    """
    rvec = np.zeros((3, 1))
    rvec['xyz'.index(axis), 0] = angle
    return cv2.Rodrigues(rvec)[0]


def rotation_rpy(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Attitude ``Rz(yaw) Ry(pitch) Rx(roll)`` (DESIGN.md section 2; positive pitch = down)."""
    return axis_rotation('z', yaw) @ axis_rotation('y', pitch) @ axis_rotation('x', roll)


def rpy_of(rotation: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Inverse of :func:`rotation_rpy` for (..., 3, 3) rotations: (roll, pitch, yaw) arrays."""
    r = np.asarray(rotation)
    pitch = np.arcsin(np.clip(-r[..., 2, 0], -1.0, 1.0))
    return np.arctan2(r[..., 2, 1], r[..., 2, 2]), pitch, np.arctan2(r[..., 1, 0], r[..., 0, 0])


@dataclass(frozen=True)
class CameraMount:
    """Where the camera sits on the vehicle: camera body frame in base_link (m and rad).

    Plain numbers; anything with these six attributes (e.g. ``planar_vo.camera.Mounting``)
    converts with :meth:`of`.
    """

    x: float = 0.0
    y: float = 0.0
    height: float = 1.0
    roll: float = 0.0
    pitch: float = 0.0
    yaw: float = 0.0

    @classmethod
    def of(cls, mounting) -> CameraMount:
        """The mount with the same six numbers as ``mounting``."""
        return cls(*(float(getattr(mounting, f.name)) for f in dataclasses.fields(cls)))

    @property
    def position(self) -> np.ndarray:
        """Camera position in base_link, (3,)."""
        return np.array([self.x, self.y, self.height])

    @property
    def rotation(self) -> np.ndarray:
        """Rotation base_link <- camera body frame, 3x3."""
        return rotation_rpy(self.roll, self.pitch, self.yaw)


# The realistic set-up: 1.2 m ahead of the rear axle, 1.25 m up, pitched 8 degrees down.
DEFAULT_MOUNTING = CameraMount(x=1.2, y=0.0, height=1.25, pitch=math.radians(8.0))


@dataclass(frozen=True)
class MountingError:
    """How far a configured mounting is off the true one: angles in degrees, offsets in m."""

    roll: float = 0.0
    pitch: float = 0.0
    yaw: float = 0.0
    x: float = 0.0
    y: float = 0.0
    height: float = 0.0

    @classmethod
    def parse(cls, text: str) -> MountingError:
        """``'pitch=1.0,roll=-1.0,yaw=1.0,x=0.15'`` (degrees and metres); ValueError if bad."""
        names = [f.name for f in dataclasses.fields(cls)]
        values: dict[str, float] = {}
        for item in filter(None, (part.strip() for part in text.split(','))):
            name, sep, value = item.partition('=')
            name = name.strip()
            if not sep or name not in names:
                raise ValueError(f'{item!r} is not NAME=VALUE with NAME one of '
                                 f'{", ".join(names)}')
            if name in values:
                raise ValueError(f'{name} is given twice')
            try:
                values[name] = float(value)
            except ValueError:
                raise ValueError(f'{name}={value.strip()!r} is not a number') from None
            if not math.isfinite(values[name]):
                raise ValueError(f'{name} must be finite')
        if not values:
            raise ValueError(f'give at least one NAME=VALUE with NAME one of {", ".join(names)}')
        return cls(**values)

    def apply(self, mount) -> CameraMount:
        """The configured mounting: ``mount`` with this error added."""
        m = CameraMount.of(mount)
        return CameraMount(m.x + self.x, m.y + self.y, m.height + self.height,
                           m.roll + math.radians(self.roll), m.pitch + math.radians(self.pitch),
                           m.yaw + math.radians(self.yaw))


def params_yaml(mounting) -> str:
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
class Suspension:
    """A sprung body carrying the camera: peak body motion and where the body rotates.

    ``pitch`` and ``roll`` (rad) bound |body pitch| and |body roll|: a share
    ``inertial_share`` of each follows the acceleration as ``tanh(a / reference)`` (pitch
    the longitudinal one over ``accel_ref``: dive when braking, squat when accelerating;
    roll the lateral one ``v * omega`` over ``lateral_ref``: lean out of turns), the rest is
    road vibration (three sines of 0.6-3 Hz). ``bounce`` (m) bounds the body's height change
    (road only). A drive of the ``car`` scenario reaches 60-90 % of the bounds. The body
    rotates about its centre of mass at (``pivot_x``, 0, ``pivot_z``) in base_link.
    """

    pitch: float = 0.0
    roll: float = 0.0
    bounce: float = 0.0
    pivot_x: float = 1.35
    pivot_z: float = 0.55
    inertial_share: float = 0.6
    accel_ref: float = 1.5  # m/s^2: longitudinal acceleration giving tanh(1) of the share
    lateral_ref: float = 1.0  # m/s^2: the same for the lateral acceleration

    @classmethod
    def degrees(cls, pitch: float, roll: float, bounce: float, **kw) -> Suspension:
        """Suspension with pitch and roll amplitudes in degrees, bounce in metres."""
        return cls(math.radians(pitch), math.radians(roll), bounce, **kw)

    @property
    def rigid(self) -> bool:
        """True when the body does not move on its springs."""
        return self.pitch == 0.0 and self.roll == 0.0 and self.bounce == 0.0


RIGID = Suspension()


def exposure_gains(t: np.ndarray, fraction: float, seed: int) -> np.ndarray:
    """Auto-exposure gain at times ``t`` (s), within 1 +- ``fraction``.

    Half the range is a smooth drift (two slow sines, 0.05-0.3 Hz), half are steps, as an
    auto-exposure loop makes: a new level every 1.5-4 s, reached from one frame to the next.
    """
    t = np.asarray(t, np.float64)
    if fraction == 0:
        return np.ones_like(t)
    rng = np.random.default_rng([seed, 6])
    smooth = (0.6 * np.sin(2 * math.pi * rng.uniform(0.05, 0.12) * t + rng.uniform(0, 7))
              + 0.4 * np.sin(2 * math.pi * rng.uniform(0.12, 0.3) * t + rng.uniform(0, 7)))
    switch = np.cumsum(rng.uniform(1.5, 4.0, int(t.max(initial=0) / 1.5) + 2))
    levels = rng.uniform(-1.0, 1.0, switch.size + 1)
    levels[0] = 0.0
    steps = levels[np.searchsorted(switch, t, side='right')]
    return 1.0 + 0.5 * fraction * (smooth + steps)


@dataclass(frozen=True)
class Scenario:
    """Driving profile, obstacle density, body motion and the scenario's camera attitude."""

    name: str
    speed: tuple = (3.0, 8.0)  # m/s range of the speed knots
    steer: float = 0.06  # max |steering angle| of the knots (rad)
    knot_dt: tuple = (2.0, 3.5)  # seconds between knots
    obstacles_per_100m: float = 6.0
    ahead_fraction: float = 0.2  # fraction of obstacles close to the path (seen ahead)
    description: str = ''
    suspension: Suspension = RIGID
    camera_roll: float = 0.0  # rad, the scenario's mounting (else DEFAULT_MOUNTING's)
    camera_yaw: float = 0.0

    @property
    def mounting(self) -> CameraMount:
        """The scenario's camera mounting: the default one with its roll and yaw."""
        return dataclasses.replace(DEFAULT_MOUNTING, roll=self.camera_roll,
                                   yaw=self.camera_yaw)


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
    'car': Scenario('car', speed=(3.0, 8.0), steer=0.14, obstacles_per_100m=6.0,
                    suspension=Suspension.degrees(1.0, 0.6, 0.015),
                    camera_roll=math.radians(0.5), camera_yaw=math.radians(-0.7),
                    description='a sprung car body (pitch <= 1 deg, roll <= 0.6 deg, '
                                'bounce <= 1.5 cm), curves, speed changes 3-8 m/s, camera '
                                'rolled 0.5 deg and yawed -0.7 deg'),
    'rough': Scenario('rough', speed=(3.0, 7.0), steer=0.16, obstacles_per_100m=6.0,
                      suspension=Suspension.degrees(2.0, 1.2, 0.03),
                      camera_roll=math.radians(-0.6), camera_yaw=math.radians(0.8),
                      description='rough road, twice the car body motion (pitch <= 2 deg, '
                                  'roll <= 1.2 deg, bounce <= 3 cm), camera rolled -0.6 deg '
                                  'and yawed 0.8 deg'),
}


@dataclass(frozen=True)
class BodyMotion:
    """The sprung body's attitude and height change at each frame, relative to the ground."""

    roll: np.ndarray  # rad, positive = right side down (lean to the right)
    pitch: np.ndarray  # rad, positive = nose down (dive)
    bounce: np.ndarray  # m, positive = body up


@dataclass(frozen=True)
class CameraPoses:
    """True pose of the camera body frame (x forward, y left, z up) in base_link per frame.

    base_link is on the ground, so these are the camera's attitude and height to the ground.
    """

    position: np.ndarray  # (N, 3) m; position[:, 2] is the height above the ground
    rotation: np.ndarray  # (N, 3, 3) base_link <- camera body frame

    @property
    def height(self) -> np.ndarray:
        """(N,) camera height above the ground, m."""
        return self.position[:, 2]

    @property
    def rpy(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(roll, pitch, yaw) (N,) each, rad, in the convention of :func:`rotation_rpy`."""
        return rpy_of(self.rotation)

    def base_from_optical(self, k: int) -> np.ndarray:
        """Rotation base_link <- optical frame at frame k, 3x3."""
        return self.rotation[k] @ BODY_FROM_OPTICAL


def road_vibration(rng: np.random.Generator, t: np.ndarray) -> np.ndarray:
    """Road-excited body motion in [-1, 1]: three sines of 0.6-3 Hz with random phases."""
    bands, weights = ((0.6, 1.2), (1.2, 2.0), (2.0, 3.0)), (0.5, 0.3, 0.2)
    out = np.zeros_like(t)
    for (lo, hi), w in zip(bands, weights, strict=True):
        out += w * np.sin(2 * math.pi * rng.uniform(lo, hi) * t + rng.uniform(0, 2 * math.pi))
    return out


def body_motion(traj: Trajectory, suspension: Suspension, seed: int) -> BodyMotion:
    """Body pitch, roll and bounce at each frame of ``traj`` (see :class:`Suspension`)."""
    rng = np.random.default_rng([seed, 5])
    share = suspension.inertial_share
    road = [road_vibration(rng, traj.t) for _ in range(3)]
    a_long = traj.accel
    a_lat = traj.v * traj.omega  # centripetal, towards the centre of the turn
    pitch = suspension.pitch * (-share * np.tanh(a_long / suspension.accel_ref)
                                + (1.0 - share) * road[0])
    roll = suspension.roll * (share * np.tanh(a_lat / suspension.lateral_ref)
                              + (1.0 - share) * road[1])
    return BodyMotion(roll, pitch, suspension.bounce * road[2])


def camera_poses(mount: CameraMount, body: BodyMotion, suspension: Suspension) -> CameraPoses:
    """The camera pose of every frame: the mount carried by the body about its pivot."""
    n = body.pitch.shape[0]
    pivot = np.array([suspension.pivot_x, 0.0, suspension.pivot_z])
    lever = mount.position - pivot
    position = np.empty((n, 3))
    rotation = np.empty((n, 3, 3))
    mount_rotation = mount.rotation
    for k in range(n):
        body_rotation = rotation_rpy(body.roll[k], body.pitch[k], 0.0)
        # mount + (R - I) lever: exactly the mount when the body is at rest
        position[k] = mount.position + (body_rotation - np.eye(3)) @ lever
        position[k, 2] += body.bounce[k]
        rotation[k] = body_rotation @ mount_rotation
    return CameraPoses(position, rotation)


@dataclass
class Trajectory:
    """Ground truth at each frame: base_link pose in odom and twist in base_link.

    The twist (``v``, ``omega``) is the instantaneous one at each frame's stamp. ``body`` and
    ``camera`` (set by :func:`render_scenario`) are the sprung body's motion and the true
    camera pose in base_link at each frame; they are not part of the ground-truth odometry.
    """

    t: np.ndarray  # s since the first frame
    x: np.ndarray
    y: np.ndarray
    yaw: np.ndarray
    v: np.ndarray  # forward speed (m/s)
    omega: np.ndarray  # yaw rate (rad/s)
    steer: np.ndarray
    wheelbase: float = WHEELBASE
    accel: np.ndarray | None = None  # dv/dt (m/s^2)
    body: BodyMotion | None = None
    camera: CameraPoses | None = None

    @property
    def length(self) -> float:
        """Path length (m) from the first to the last frame."""
        return float(np.hypot(np.diff(self.x), np.diff(self.y)).sum())


def mount_camera(traj: Trajectory, mount, suspension: Suspension = RIGID,
                 seed: int = 0) -> Trajectory:
    """``traj`` with the body motion and the true camera pose of every frame filled in."""
    body = body_motion(traj, suspension, seed)
    return dataclasses.replace(traj, body=body,
                               camera=camera_poses(CameraMount.of(mount), body, suspension))


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
    h = 1e-5  # the profiles are C1: a central difference gives the acceleration
    accel = (speed(t + h) - speed(t - h)) / (2 * h)
    return Trajectory(t, x, y, yaw, v, v * np.tan(st) / wheelbase, st, wheelbase, accel)


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
                   mounting=None) -> list[Box]:
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


def _rotate(rotation: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    """``rotation @ vectors`` for (3, N) float32 vectors.

    Written out: BLAS threads stall such thin products on a busy machine.
    """
    return np.stack([rotation[i, 0] * vectors[0] + rotation[i, 1] * vectors[1]
                     + rotation[i, 2] * vectors[2] for i in range(3)])


class Renderer:
    """Render mono8 images of the ground (and boxes) for base_link poses in odom.

    For the nominal (rigid) mount all per-pixel ground geometry is fixed in base_link (planar
    motion), so it is computed once: ground hit points, mip levels, haze; per frame only a 2-D
    rigid transform, the texture look-ups, the boxes and the noise. A camera moving on a
    sprung body (:meth:`render_frame`, :meth:`render_pose`) gets its ground intersection per
    frame, for every pixel whose nominal ray is less than ``max_tilt`` above the horizon;
    the mip levels stay those of the nominal pose (the body moves by a degree or two).
    """

    def __init__(self, camera: SynthCamera | None = None, mounting=None,
                 texture: Texture | None = None, boxes=(), *, max_range: float = 60.0,
                 noise_sigma: float = 1.5, seed: int = 0, illumination: bool = True,
                 haze: bool = True, max_tilt: float = math.radians(4.0),
                 exposure: np.ndarray | None = None) -> None:
        self.camera = camera or SynthCamera()
        self.exposure = None if exposure is None else np.asarray(exposure, np.float64)
        self.mounting = CameraMount.of(mounting or DEFAULT_MOUNTING)
        self.texture = texture if texture is not None else make_ground_texture(seed)
        self.boxes = list(boxes)
        self.max_range = float(max_range)
        self.noise_sigma = float(noise_sigma)
        self.seed = seed
        self.illumination = illumination
        self.haze = haze
        cam, mnt = self.camera, self.mounting
        h, w = cam.height, cam.width
        rays = cam.rays().reshape(-1, 3)
        self.base_from_optical = mnt.rotation @ BODY_FROM_OPTICAL
        d = rays @ self.base_from_optical.T
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        self.dirs = np.ascontiguousarray(d.T, np.float32)  # (3, N) unit rays in base_link
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
        self.sky = self._sky(d[:, 2])
        self.g_fog = self._haze(dist[self.g_idx])
        # Vignetting (fixed per pixel).
        uu, vv = np.meshgrid((np.arange(w) - cam.cx) / w, (np.arange(h) - cam.cy) / h)
        self.vignette = (1.0 - 0.35 * (uu * uu + vv * vv)).ravel().astype(np.float32)
        self.ground_mask = ground.reshape(h, w)
        # Pixels a tilted camera may see the ground through, sorted by their nominal level.
        unit_rays = rays / np.linalg.norm(rays, axis=1, keepdims=True)
        self._unit_rays = np.ascontiguousarray(unit_rays.T, np.float32)  # (3, N)
        cand = np.flatnonzero(d[:, 2] < math.sin(max_tilt))
        cand_level = np.where(ground[cand], level[cand], self.texture.nlevels - 1.0)
        c0 = np.floor(cand_level).astype(np.int64)
        order = np.argsort(c0, kind='stable')
        self._c_idx = cand[order]
        self._c_l0 = c0[order]
        self._c_frac = (cand_level[order] - c0[order]).astype(np.float32)
        self._c_rays = np.ascontiguousarray(self._unit_rays[:, self._c_idx])

    @staticmethod
    def _sky(up: np.ndarray) -> np.ndarray:
        """Sky grey level from each unit ray's upward component (its elevation only)."""
        elev = np.arcsin(np.clip(up, -1, 1))
        return (196.0 + 45.0 * np.sin(np.clip(elev, 0, None)) ** 0.7
                - 12.0 * np.clip(-elev, 0, 0.2) / 0.2).astype(np.float32)

    def _haze(self, dist: np.ndarray) -> np.ndarray:
        """Blend factor towards the sky for ground at ``dist`` m (1 = all sky)."""
        if not self.haze:
            return np.zeros(dist.shape, np.float32)
        s = np.clip((dist - 0.5 * self.max_range) / (0.5 * self.max_range), 0, 1)
        fog = 0.12 * (1 - np.exp(-dist / 30.0)) + 0.88 * s * s * (3 - 2 * s)
        return np.clip(fog, 0, 1).astype(np.float32)

    def ground_points_base(self) -> np.ndarray:
        """(H, W, 2) ground hit point of every pixel in base_link (NaN = no ground)."""
        out = np.full((self.camera.height * self.camera.width, 2), np.nan)
        out[self.g_idx] = self.g_pts
        return out.reshape(self.camera.height, self.camera.width, 2)

    def gain(self, k: int) -> float:
        """Global gain of frame k: slow, smooth illumination times the auto-exposure gain."""
        exposure = 1.0 if self.exposure is None else float(self.exposure[k])
        if not self.illumination:
            return exposure
        ph = (self.seed % 97) * 0.37
        return (1.0 + 0.05 * math.sin(0.21 * k / 30.0 * 2 * math.pi + ph)
                + 0.02 * math.sin(0.9 * k / 30.0 * 2 * math.pi + 2 * ph)) * exposure

    def render(self, x: float, y: float, yaw: float, k: int = 0) -> np.ndarray:
        """Render the image seen from base_link pose (x, y, yaw) in odom; frame index k."""
        img = self.sky.copy()
        c, s = math.cos(yaw), math.sin(yaw)
        gx = x + c * self.g_pts[:, 0] - s * self.g_pts[:, 1]
        gy = y + s * self.g_pts[:, 0] + c * self.g_pts[:, 1]
        val = self.texture.sample_sorted(gx, gy, self.g_l0, self.g_frac)
        sky = img[self.g_idx]
        img[self.g_idx] = val + (sky - val) * self.g_fog
        if self.boxes:
            self._render_boxes(img, x, y, yaw, self.origin, self.dirs, self.t_ground.copy(),
                               self.sky)
        return self._finish(img, k)

    def render_frame(self, traj: Trajectory, k: int) -> np.ndarray:
        """Frame k of ``traj``: its base_link pose and, when set, its true camera pose."""
        if traj.camera is None:
            return self.render(traj.x[k], traj.y[k], traj.yaw[k], k)
        return self.render_pose(traj.x[k], traj.y[k], traj.yaw[k], k,
                                traj.camera.position[k], traj.camera.base_from_optical(k))

    def render_pose(self, x: float, y: float, yaw: float, k: int, position: np.ndarray,
                    base_from_optical: np.ndarray) -> np.ndarray:
        """Render from base_link pose (x, y, yaw) with the camera moved on the body.

        ``position`` (3,) and ``base_from_optical`` (3x3) are the camera's pose in base_link
        at this frame.
        """
        if (np.array_equal(position, self.origin)
                and np.array_equal(base_from_optical, self.base_from_optical)):
            return self.render(x, y, yaw, k)  # the nominal pose: geometry precomputed
        position = np.asarray(position, np.float64)
        if position[2] <= 0:
            raise ValueError('the camera must stay above the ground')
        # float32 throughout: ground points within max_range of the camera, and the odom
        # position wrapped to the texture's period (the texture repeats exactly).
        rotation = np.asarray(base_from_optical, np.float32)
        dirs = _rotate(rotation, self._unit_rays)
        sky = self._sky_fast(dirs[2])
        img = sky.copy()
        d = _rotate(rotation, self._c_rays)
        depression = -d[2]
        down = depression > 1e-6
        t = np.float32(position[2]) / np.where(down, depression, np.float32(1.0))
        dist = t * np.hypot(d[0], d[1])
        ground = down & (dist < self.max_range)
        t[~ground] = 0.0  # no ground within range: sampled at the camera's foot, fog hides it
        bx = np.float32(position[0]) + t * d[0]
        by = np.float32(position[1]) + t * d[1]
        c, s = np.float32(math.cos(yaw)), np.float32(math.sin(yaw))
        period = self.texture.texel * self.texture.sizes[0]
        val = self.texture.sample_sorted(np.float32(x % period) + c * bx - s * by,
                                         np.float32(y % period) + s * bx + c * by,
                                         self._c_l0, self._c_frac)
        fog = np.where(ground, self._haze(dist), np.float32(1.0))
        behind = img[self._c_idx]
        img[self._c_idx] = val + (behind - val) * fog
        if self.boxes:
            depth = np.full(img.shape[0], np.inf)
            depth[self._c_idx[ground]] = t[ground]
            self._render_boxes(img, x, y, yaw, position, dirs, depth, sky)
        return self._finish(img, k)

    @staticmethod
    def _sky_fast(up: np.ndarray) -> np.ndarray:
        """:meth:`_sky` in float32 arithmetic (``sin(arcsin(up)) = up``)."""
        return (np.float32(196.0) + np.float32(45.0) * np.maximum(up, 0) ** np.float32(0.7)
                - np.float32(60.0) * np.clip(-np.arcsin(np.clip(up, -1, 1)), 0, 0.2))

    def _finish(self, img: np.ndarray, k: int) -> np.ndarray:
        """Vignetting, illumination and sensor noise; mono8 (H, W)."""
        img *= self.vignette * self.gain(k)
        if self.noise_sigma > 0:
            rng = np.random.default_rng([self.seed, 4, k])
            img += rng.standard_normal(img.shape[0], np.float32) * np.float32(self.noise_sigma)
        cam = self.camera
        return np.clip(img + 0.5, 0, 255).astype(np.uint8).reshape(cam.height, cam.width)

    def _render_boxes(self, img: np.ndarray, x: float, y: float, yaw: float,
                      origin: np.ndarray, dirs: np.ndarray, depth: np.ndarray,
                      sky: np.ndarray) -> None:
        """Draw the boxes over ``img`` seen from base_link pose (x, y, yaw).

        ``origin`` and the unit pixel rays ``dirs`` (3, N) are in base_link; ``depth`` is the
        ground's ray length per pixel, ``sky`` the sky behind the haze.
        """
        c, s = math.cos(yaw), math.sin(yaw)
        ox, oy, oz = origin
        cwx, cwy = x + c * ox - s * oy, y + s * ox + c * oy  # camera centre in odom
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
                vb32 = vb.astype(np.float32)
                sel = np.flatnonzero(dirs[0] * vb32[0] + dirs[1] * vb32[1] + dirs[2] * vb32[2]
                                     > cos_th)
            else:
                sel = np.arange(dirs.shape[1])
            if sel.size == 0:
                continue
            d = dirs[:, sel].T.astype(np.float64)
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
            img[idx] = val + (img[idx] * 0 + sky[idx] - val) * fog
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
    mounting: CameraMount
    trajectory: Trajectory = field(repr=False)
    suspension: Suspension = RIGID
    configured: CameraMount | None = None  # the mounting written to params_out
    exposure: float = 0.0
    obstacles: int = 0
    seconds: float = 0.0


def render_scenario(scenario: str = 'default', frames: int = 300, seed: int = 0, *,
                    rate: float = 30.0, camera: SynthCamera | None = None, mounting=None,
                    suspension: Suspension | None = None, noise_sigma: float = 1.5,
                    max_range: float = 60.0, obstacles: bool = True, exposure: float = 0.0):
    """Build the scene; return ``(renderer, trajectory)``.

    ``mounting`` (a :class:`CameraMount` or anything with its six numbers) and ``suspension``
    default to the scenario's. ``exposure`` is the auto-exposure range (0.2: gain within
    +-20 %, see :func:`exposure_gains`; ``renderer.exposure`` holds the gain of every frame).
    ``renderer.render_frame(traj, k)`` is frame k of the bag; ``traj.camera`` holds the true
    camera pose of every frame.
    """
    if not 0.0 <= exposure < 1.0:
        raise ValueError(f'exposure must be in [0, 1), got {exposure}')
    if scenario not in SCENARIOS:
        raise ValueError(f'unknown scenario {scenario!r} (choose from {", ".join(SCENARIOS)})')
    sc = SCENARIOS[scenario]
    mounting = CameraMount.of(mounting or sc.mounting)
    suspension = sc.suspension if suspension is None else suspension
    traj = mount_camera(make_trajectory(sc, frames, rate, seed), mounting, suspension, seed)
    boxes = make_obstacles(traj, sc, seed, mounting) if obstacles else []
    renderer = Renderer(camera, mounting, make_ground_texture(seed), boxes,
                        max_range=max_range, noise_sigma=noise_sigma, seed=seed,
                        max_tilt=suspension.pitch + suspension.roll + math.radians(1.0),
                        exposure=exposure_gains(traj.t, exposure, seed) if exposure else None)
    return renderer, traj


def generate_bag(out_path, scenario: str = 'default', frames: int = 300, seed: int = 0, *,
                 rate: float = 30.0, camera: SynthCamera | None = None, mounting=None,
                 suspension: Suspension | None = None, compressed: bool = False,
                 jpeg_quality: int = 90, noise_sigma: float = 1.5, max_range: float = 60.0,
                 obstacles: bool = True, storage_compression: bool = True,
                 params_out=None, configured_error: MountingError | None = None,
                 exposure: float = 0.0, progress: bool = False) -> SynthResult:
    """Render a scenario and write the rosbag2 bag (MCAP, zstd chunks) at ``out_path``.

    ``mounting``, ``suspension`` and ``exposure`` as in :func:`render_scenario`. The images
    are rendered with ``mounting``; ``params_out`` gets it plus ``configured_error`` (the
    mounting a user would have configured, to test calibration).
    """
    from planar_vo.bag import BagWriter, typestore

    t0 = time.monotonic()
    camera = camera or SynthCamera()
    renderer, traj = render_scenario(scenario, frames, seed, rate=rate, camera=camera,
                                     mounting=mounting, suspension=suspension,
                                     noise_sigma=noise_sigma, max_range=max_range,
                                     obstacles=obstacles, exposure=exposure)
    mounting = renderer.mounting
    configured = (configured_error or MountingError()).apply(mounting)
    suspension = SCENARIOS[scenario].suspension if suspension is None else suspension
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
            img = renderer.render_frame(traj, k)
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
        text = params_yaml(configured)
        if configured != mounting:
            text += (f'# rendered with camera_x {mounting.x!r}, camera_y {mounting.y!r}, '
                     f'camera_height {mounting.height!r},\n# camera_roll {mounting.roll!r}, '
                     f'camera_pitch {mounting.pitch!r}, camera_yaw {mounting.yaw!r}\n')
        Path(params_out).write_text(text)
    return SynthResult(Path(out_path), scenario, frames, rate, seed, camera, mounting, traj,
                       suspension, configured, exposure, len(renderer.boxes),
                       time.monotonic() - t0)


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


def _mounting_error(s):
    try:
        return MountingError.parse(s)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


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
    p.add_argument('--camera-x', type=_finite,
                   help='camera x ahead of the rear axle, m (default 1.2)')
    p.add_argument('--camera-y', type=_finite, help='camera y (left), m (default 0)')
    p.add_argument('--camera-height', type=_positive_float,
                   help='camera height above the ground, m (default 1.25)')
    p.add_argument('--camera-roll', type=_finite,
                   help="rad (default: the scenario's, 0 except car 0.5 deg, rough -0.6 deg)")
    p.add_argument('--camera-pitch', type=_finite,
                   help='rad, positive looks down (default 0.13963 = 8 deg)')
    p.add_argument('--camera-yaw', type=_finite,
                   help="rad, positive looks left (default: the scenario's, 0 except "
                        'car -0.7 deg, rough 0.8 deg)')
    p.add_argument('--body-pitch', type=_nonneg, metavar='DEG',
                   help='sprung body: peak |pitch|, degrees; 60 %% follows the longitudinal '
                        'acceleration (dive when braking, squat when accelerating), 40 %% is '
                        "road vibration up to 3 Hz (default: the scenario's, 0 except car 1, "
                        'rough 2)')
    p.add_argument('--body-roll', type=_nonneg, metavar='DEG',
                   help='sprung body: peak |roll|, degrees; 60 %% follows the lateral '
                        'acceleration v*omega (lean out of turns), 40 %% is road vibration '
                        "(default: the scenario's, 0 except car 0.6, rough 1.2)")
    p.add_argument('--bounce', type=_nonneg, metavar='M',
                   help="sprung body: peak height change, m (default: the scenario's, 0 "
                        'except car 0.015, rough 0.03)')
    p.add_argument('--configured-error', type=_mounting_error, metavar='NAME=VALUE,...',
                   help='write to --params-out a mounting that is off the rendered one by '
                        'this much, to test calibration: roll, pitch, yaw in degrees, x, y, '
                        'height in metres, e.g. pitch=1.0,roll=-1.0,yaw=1.0,x=0.15 (the '
                        'images still use the true mounting, noted in a comment)')
    p.add_argument('--exposure', type=_nonneg, default=0.0, metavar='FRACTION',
                   help='auto-exposure gain changes within +-FRACTION (e.g. 0.2): half a '
                        'smooth drift, half steps every 1.5-4 s (default 0: off)')
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
    scenario = SCENARIOS[args.scenario]
    mounting = scenario.mounting
    given = {name: getattr(args, f'camera_{name}') for name in
             ('x', 'y', 'height', 'roll', 'pitch', 'yaw')}
    mounting = dataclasses.replace(mounting, **{k: v for k, v in given.items() if v is not None})
    if not -1.2 < mounting.pitch < 1.5 or abs(mounting.roll) > 0.5:
        parser.error('camera pitch/roll out of range: the camera must see the ground')
    body = scenario.suspension
    suspension = Suspension.degrees(
        math.degrees(body.pitch) if args.body_pitch is None else args.body_pitch,
        math.degrees(body.roll) if args.body_roll is None else args.body_roll,
        body.bounce if args.bounce is None else args.bounce)
    if max(suspension.pitch, suspension.roll) > math.radians(5.0):
        parser.error('--body-pitch/--body-roll must be at most 5 degrees')
    if suspension.bounce > 0.5 * mounting.height:
        parser.error('--bounce must be at most half the camera height')
    if args.exposure > 0.5:
        parser.error('--exposure must be at most 0.5 (a gain within +-50 %)')
    if args.configured_error and not args.params_out:
        parser.error('--configured-error needs --params-out (it only changes that file)')
    if args.configured_error and args.configured_error.apply(mounting).height <= 0:
        parser.error('--configured-error: the configured camera height must stay > 0')
    expected = len(DISTORTION_DEFAULTS[args.distortion_model])
    if args.dist and len(args.dist) != expected:
        parser.error(f'--dist: {args.distortion_model} takes {expected} coefficients, '
                     f'not {len(args.dist)}')
    camera = SynthCamera.scaled(args.width, args.height, fx=args.fx,
                                fy=args.fy if args.fy is not None else args.fx,
                                cx=args.cx, cy=args.cy,
                                dist=tuple(args.dist) if args.dist else None,
                                distortion_model=args.distortion_model)
    from planar_vo.bag import BagError

    try:
        res = generate_bag(out, args.scenario, args.frames, args.seed, rate=args.rate,
                           camera=camera, mounting=mounting, suspension=suspension,
                           compressed=args.compressed,
                           jpeg_quality=args.jpeg_quality, noise_sigma=args.noise,
                           max_range=args.max_range, obstacles=not args.no_obstacles,
                           storage_compression=not args.no_storage_compression,
                           params_out=args.params_out, configured_error=args.configured_error,
                           exposure=args.exposure, progress=not args.quiet)
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
