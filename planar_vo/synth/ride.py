"""The vehicle riding a terrain through its wheel contacts; the 3D and the planar truth.

Chassis (:class:`Chassis`): base_link is the centre of the driven axle, on the surface:
- ``car``: rear axle (base_link) and front axle ``wheelbase`` (2.7 m) ahead, track 1.6 m;
- ``diff_drive``: two wheels on one axle (base_link), track 0.5 m, and a caster 0.35 m
  behind.
Pitch comes from the heights under the front and the rear contacts (``sin(pitch) =
(h_rear - h_front) / distance``; positive pitch = nose down), roll from the left and the
right wheels (``cos(pitch) sin(roll) = (h_left - h_right) / track``), base_link's height is
the mean of its axle's two wheel contacts. Contacts sit at body z = 0 (wheel radius and
tyre deflection ignored); the pose is solved by fixed-point iteration (contacts moved with
the attitude, 4 rounds).

Motion: the drive profile gives the wheel speed ``v`` (along the surface) and the yaw rate
``omega`` about base_link z (``v tan(steer) / 2.7`` for both chassis, so the diff-drive
robot drives the car's path). On a fine time grid (<= 2 ms, frames on grid points) the
horizontal state (x, y, heading) is integrated so that base_link moves along its heading at
``v`` along the surface, and the heading turns so that the body yaw rate is ``omega``;
solved by a few global fixed-point passes (trapezoid rule), all vectorised.

Truth:
- 3D: base_link's pose in the world frame at each frame and its body twist (central
  differences on the fine grid);
- planar (``/ground_truth/odom``): the SE(2) composition of the body-frame planar parts
  (dx, dy in base_link, dyaw about base_link z) of the 3D motion between consecutive fine
  steps, sampled at the frames: distance along the surface, as wheel odometry measures it,
  independent of the frame rate.
On flat ground none of this runs: the bicycle model's planar trajectory is the truth, as
before.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from planar_vo.synth.terrain import Terrain
from planar_vo.synth.vehicle import WHEELBASE, Pose3D, Trajectory, drive_functions

FINE_STEP = 0.002  # s, the largest internal step


@dataclass(frozen=True)
class Chassis:
    """Where the vehicle touches the ground, in base_link (x forward, y left; metres).

    ``front`` and ``rear``: the contacts (x, y) whose mean heights give the pitch;
    ``left`` and ``right``: those giving the roll; ``axle``: base_link's own two wheels.
    """

    name: str
    front: tuple
    rear: tuple
    left: tuple
    right: tuple
    axle: tuple

    @classmethod
    def car(cls, wheelbase: float = WHEELBASE, track: float = 1.6) -> Chassis:
        """Rear axle (base_link) and front axle ``wheelbase`` ahead."""
        w = track / 2
        rl, rr, fl, fr = (0.0, w), (0.0, -w), (wheelbase, w), (wheelbase, -w)
        return cls('car', (fl, fr), (rl, rr), (rl, fl), (rr, fr), (rl, rr))

    @classmethod
    def diff_drive(cls, track: float = 0.5, caster: float = 0.35) -> Chassis:
        """Two wheels on base_link's axle and a caster ``caster`` m behind."""
        w = track / 2
        left, right = (0.0, w), (0.0, -w)
        return cls('diff_drive', (left, right), ((-caster, 0.0),), (left,), (right,),
                   (left, right))

    @property
    def points(self) -> np.ndarray:
        """(K, 2) every contact once."""
        pts = []
        for p in self.front + self.rear + self.left + self.right + self.axle:
            if p not in pts:
                pts.append(p)
        return np.array(pts, np.float64)

    def _groups(self):
        pts = [tuple(p) for p in self.points]
        return [[pts.index(p) for p in g]
                for g in (self.front, self.rear, self.left, self.right, self.axle)]

    @property
    def front_x(self) -> float:
        """How far ahead of base_link the front contacts stand (m): the ``wheelbase`` param."""
        return float(np.mean([p[0] for p in self.front]))

    @property
    def front_track(self) -> float:
        """How far apart the front contacts stand (m): the ``track_width`` param."""
        ys = [p[1] for p in self.front]
        return float(max(ys) - min(ys))

    @property
    def length(self) -> float:
        """Distance between the front and the rear contacts' centres (m)."""
        return float(np.mean([p[0] for p in self.front]) - np.mean([p[0] for p in self.rear]))

    @property
    def track(self) -> float:
        """Distance between the left and the right contacts' centres (m)."""
        return float(np.mean([p[1] for p in self.left]) - np.mean([p[1] for p in self.right]))


CHASSIS = {'car': Chassis.car(), 'diff_drive': Chassis.diff_drive()}


def rotations(yaw, pitch, roll) -> np.ndarray:
    """(N, 3, 3) ``Rz(yaw) Ry(pitch) Rx(roll)`` (mount.rotation_rpy's convention), vectorised."""
    cy, sy, cp, sp, cr, sr = (np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch),
                              np.cos(roll), np.sin(roll))
    r = np.empty(np.shape(yaw) + (3, 3))
    r[..., 0, 0], r[..., 1, 0], r[..., 2, 0] = cy * cp, sy * cp, -sp
    r[..., 0, 1] = cy * sp * sr - sy * cr
    r[..., 1, 1] = sy * sp * sr + cy * cr
    r[..., 2, 1] = cp * sr
    r[..., 0, 2] = cy * sp * cr + sy * sr
    r[..., 1, 2] = sy * sp * cr - cy * sr
    r[..., 2, 2] = cp * cr
    return r


def rotation_quaternion(rotation: np.ndarray) -> tuple[float, float, float, float]:
    """(x, y, z, w) unit quaternion of a 3x3 rotation (w >= 0)."""
    r = np.asarray(rotation, np.float64)
    a, b, c = r[0, 0], r[1, 1], r[2, 2]

    def part(value, sign):
        return math.copysign(math.sqrt(max(0.0, value)) / 2, sign)

    return (part(1.0 + a - b - c, r[2, 1] - r[1, 2]), part(1.0 - a + b - c, r[0, 2] - r[2, 0]),
            part(1.0 - a - b + c, r[1, 0] - r[0, 1]), math.sqrt(max(0.0, 1.0 + a + b + c)) / 2)


def settle(terrain: Terrain, chassis: Chassis, x, y, heading, rounds: int = 4):
    """base_link's height, pitch and roll at horizontal (x, y) with ``heading`` (arrays).

    Returns (z, pitch, roll, contact heights (N, K)).
    """
    x, y, heading = (np.asarray(a, np.float64) for a in (x, y, heading))
    pts = chassis.points
    front, rear, left, right, axle = chassis._groups()
    length, track = chassis.length, chassis.track
    pitch = np.zeros_like(x)
    roll = np.zeros_like(x)
    z = terrain.height(x, y)
    for _ in range(rounds):
        r = rotations(heading, pitch, roll)
        # horizontal position of each contact (body z = 0)
        cx = x[:, None] + r[:, None, 0, 0] * pts[:, 0] + r[:, None, 0, 1] * pts[:, 1]
        cy = y[:, None] + r[:, None, 1, 0] * pts[:, 0] + r[:, None, 1, 1] * pts[:, 1]
        h = terrain.height(cx, cy)
        sp = (h[:, rear].mean(1) - h[:, front].mean(1)) / length
        pitch = np.arcsin(np.clip(sp, -0.9, 0.9))
        sr = (h[:, left].mean(1) - h[:, right].mean(1)) / (track * np.cos(pitch))
        roll = np.arcsin(np.clip(sr, -0.9, 0.9))
        z = h[:, axle].mean(1)
    return z, pitch, roll, h


def _cumtrapz(rate: np.ndarray, h: float) -> np.ndarray:
    return np.concatenate([[0.0], np.cumsum(0.5 * h * (rate[1:] + rate[:-1]))])


def _relative(rot: np.ndarray, pos: np.ndarray, a: np.ndarray, b: np.ndarray):
    """Motion from pose a to pose b (index arrays) in a's body frame: (dp (M, 3), dR)."""
    ra_t = np.swapaxes(rot[a], 1, 2)
    dp = np.einsum('nij,nj->ni', ra_t, pos[b] - pos[a])
    return dp, ra_t @ rot[b]


def _vee(dr: np.ndarray) -> np.ndarray:
    """Rotation vectors (M, 3) of small rotations (M, 3, 3) (log map)."""
    angle = np.arccos(np.clip((np.trace(dr, axis1=1, axis2=2) - 1) / 2, -1.0, 1.0))
    axis = np.stack([dr[:, 2, 1] - dr[:, 1, 2], dr[:, 0, 2] - dr[:, 2, 0],
                     dr[:, 1, 0] - dr[:, 0, 1]], 1)
    scale = np.where(angle > 1e-12, angle / (2 * np.sin(np.maximum(angle, 1e-12))), 0.5)
    return axis * scale[:, None]


@dataclass(frozen=True)
class RideGrid:
    """The ride on its fine time grid (step ``h``), as :func:`ride_over` solves it.

    ``t``, ``x``, ``y``, ``heading`` (n,): grid time (s) and horizontal state; ``rate_x``,
    ``rate_y``, ``rate_heading`` (n,): the rates the last pass integrated (trapezoid rule,
    so between grid points the state is the integral of their linear interpolant);
    ``position`` (n, 3) and ``rotation`` (n, 3, 3): base_link's world pose (the wheels
    settled on the terrain). Frame k is grid point ``first + k * sub``.
    """

    terrain: Terrain
    chassis: Chassis
    h: float
    first: int
    sub: int
    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    heading: np.ndarray
    rate_x: np.ndarray
    rate_y: np.ndarray
    rate_heading: np.ndarray
    position: np.ndarray
    rotation: np.ndarray

    def state_at(self, index: np.ndarray, offset: np.ndarray):
        """Horizontal (x, y, heading) at ``offset`` s (>= 0, < h) after grid points ``index``.

        The trapezoid rule's own interpolant: the state plus the integral of the linearly
        interpolated rate (exactly the grid's values at offset 0 and at h).
        """
        i, u = np.asarray(index), np.asarray(offset, np.float64)
        q = u * u / (2 * self.h)
        j = np.minimum(i + 1, len(self.t) - 1)  # the last point: offset 0 only
        return tuple(a[i] + u * r[i] + q * (r[j] - r[i]) for a, r in
                     ((self.x, self.rate_x), (self.y, self.rate_y),
                      (self.heading, self.rate_heading)))

    def pose_at(self, index: np.ndarray, offset: np.ndarray):
        """base_link's world pose ((N, 3), (N, 3, 3)) at ``offset`` s after grid points."""
        x, y, heading = self.state_at(index, offset)
        z, pitch, roll, _ = settle(self.terrain, self.chassis, x, y, heading)
        return np.stack([x, y, z], 1), rotations(heading, pitch, roll)


def ride_grid(drive, terrain: Terrain, frames: int, rate: float, seed: int,
              chassis: Chassis | str = 'car', *, passes: int = 4,
              margin: float = 0.0) -> RideGrid:
    """The ride of :func:`ride_over` on its fine grid, ``margin`` s longer at both ends.

    With ``margin`` 0 the grid is one step beyond the first and the last frame; a rolling
    shutter's rows before the first stamp and after the last need more.
    """
    chassis = CHASSIS[chassis] if isinstance(chassis, str) else chassis
    speed, steer = drive_functions(drive, frames, rate, seed)
    dt = 1.0 / rate
    sub = max(1, math.ceil(dt / FINE_STEP - 1e-9))
    h = dt / sub
    # the fine grid, one step beyond the first and the last frame (central differences there)
    # and `extra` steps more; frame k is grid point first + k * sub, the start (0, 0, heading
    # 0) is grid point first
    extra = math.ceil(margin / h - 1e-9) if margin > 0 else 0
    first = 1 + extra
    n = (frames - 1) * sub + 3 + 2 * extra
    t = (np.arange(n) - first) * h
    v = speed(t)
    omega = v * np.tan(steer(t)) / WHEELBASE

    def integrate(rate):
        out = _cumtrapz(rate, h)
        return out - out[first]

    # First guess: the flat bicycle path (trapezoid rule), then fixed-point passes.
    heading = integrate(omega)
    x = integrate(v * np.cos(heading))
    y = integrate(v * np.sin(heading))
    rate_heading, rate_x, rate_y = omega, v * np.cos(heading), v * np.sin(heading)
    axle = chassis._groups()[4]
    pts = chassis.points[axle]
    for _ in range(passes):
        z, pitch, roll, _ = settle(terrain, chassis, x, y, heading)
        # slope of the axle's height along the heading (mean of its wheels' gradients)
        c, s = np.cos(heading), np.sin(heading)
        slope = np.zeros_like(x)
        for px, py in pts:
            gx, gy = terrain.gradient(x + c * px - s * py, y + s * px + c * py)
            slope += (gx * c + gy * s) / len(pts)
        ground_speed = v / np.sqrt(1.0 + slope * slope)
        pitch_rate = np.gradient(pitch, h)
        # body yaw rate = heading_rate cos(pitch) cos(roll) - pitch_rate sin(roll)
        rate_heading = (omega + pitch_rate * np.sin(roll)) / (np.cos(pitch) * np.cos(roll))
        heading = integrate(rate_heading)
        rate_x, rate_y = ground_speed * np.cos(heading), ground_speed * np.sin(heading)
        x = integrate(rate_x)
        y = integrate(rate_y)
    z, pitch, roll, _ = settle(terrain, chassis, x, y, heading)
    pos = np.stack([x, y, z], 1)
    rot = rotations(heading, pitch, roll)
    return RideGrid(terrain, chassis, h, first, sub, t, x, y, heading, rate_x, rate_y,
                    rate_heading, pos, rot)


def body_twist(rot_a, pos_a, rot_k, rot_b, pos_b, span):
    """base_link's body twist at k from the poses a before it and b after it.

    Central differences over ``span`` s: (linear (N, 3) in k's frame, angular (N, 3)).
    """
    ra_t = np.swapaxes(rot_a, 1, 2)
    dpk = np.einsum('nij,nj->ni', ra_t, pos_b - pos_a)
    drk = ra_t @ rot_b
    # the velocity at k in k's frame: rotate the a-frame difference into k's frame
    linear = np.einsum('nji,nj->ni', ra_t @ rot_k, dpk) / span[:, None]
    return linear, _vee(drk) / span[:, None]


def ride_over(drive, terrain: Terrain, frames: int, rate: float, seed: int,
              chassis: Chassis | str = 'car', *, passes: int = 4,
              grid: RideGrid | None = None) -> Trajectory:
    """The trajectory of a drive over ``terrain``: 3D pose and planar truth at the frames.

    ``drive`` as for :func:`planar_vo.synth.vehicle.make_trajectory` (the same seeded speed
    and steering profiles). ``traj.pose3d`` holds the world pose; ``traj.x, y, yaw`` the
    planar truth (distance along the surface), ``traj.v, omega`` the body twist's forward
    speed and yaw rate at each stamp. ``grid``: the ride already solved by :func:`ride_grid`
    with these arguments (a longer one for a rolling shutter), else solved here.
    """
    if grid is None:
        grid = ride_grid(drive, terrain, frames, rate, seed, chassis, passes=passes)
    speed, steer = drive_functions(drive, frames, rate, seed)
    rot, pos, h, t, sub, first = grid.rotation, grid.position, grid.h, grid.t, grid.sub, \
        grid.first
    dt = 1.0 / rate
    # planar truth: SE(2) composition of the body-frame planar parts of each fine step
    idx = np.arange(first, first + (frames - 1) * sub)
    dp, dr = _relative(rot, pos, idx, idx + 1)
    dyaw = np.arctan2(dr[:, 1, 0], dr[:, 0, 0])
    yaw = np.concatenate([[0.0], np.cumsum(dyaw)])
    cy, sy = np.cos(yaw[:-1]), np.sin(yaw[:-1])
    px = np.concatenate([[0.0], np.cumsum(cy * dp[:, 0] - sy * dp[:, 1])])
    py = np.concatenate([[0.0], np.cumsum(sy * dp[:, 0] + cy * dp[:, 1])])
    j = np.arange(frames) * sub  # frames in the planar arrays
    px, py, yaw = px[j], py[j], yaw[j]
    # body twist at the frames: central differences on the fine grid
    k = j + first
    a, b = k - 1, k + 1
    span = (b - a) * h
    linear, angular = body_twist(rot[a], pos[a], rot[k], rot[b], pos[b], span)
    eps = 1e-5
    accel = (speed(t[k] + eps) - speed(t[k] - eps)) / (2 * eps)
    pose3d = Pose3D(pos[k], rot[k], linear, angular)
    return Trajectory(np.arange(frames) * dt, px, py, yaw, linear[:, 0], angular[:, 2],
                      steer(t[k]), WHEELBASE, accel, pose3d=pose3d)


def with_world_path(traj: Trajectory) -> Trajectory:
    """``traj`` with x, y, yaw the world-frame horizontal pose (where boxes are placed)."""
    if traj.pose3d is None:
        return traj
    rot = traj.pose3d.rotation
    return dataclasses.replace(traj, x=traj.pose3d.position[:, 0],
                               y=traj.pose3d.position[:, 1],
                               yaw=np.arctan2(rot[:, 1, 0], rot[:, 0, 0]))
