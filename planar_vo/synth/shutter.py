"""A rolling shutter: each image row exposed at its own time, from the pose at that time.

Row ``r`` of an ``H``-row image with readout ``T`` is exposed at ``t + (r / H - c) T``, where
``t`` is the image stamp and ``c`` is 0, 0.5 or 1 for a stamp at the start, the middle or the
end of the readout (:data:`STAMPS`). For every frame and every row this module gives the
vehicle's pose at that row's time, integrated from the frame's own pose with the drive's
speed and steering profiles (the bicycle model, RK4, one step per row), and the sprung body's
motion at that time (the same body functions evaluated at the row times). The renderer then
draws each row from its own pose. Independent of ``planar_vo.core``.

On a terrain (:func:`world_row_poses`) the rows are base_link's 3D world pose at their times
on the ride's own fine grid (:class:`planar_vo.synth.ride.RideGrid`, extended by the readout
at both ends): the horizontal state between grid points is the trapezoid rule's interpolant
(the integral of the linearly interpolated rates), the wheels settled on the terrain there
(:func:`planar_vo.synth.ride.settle`), the body twist by central differences one grid step
either side (as at the stamps); a sprung body's motion follows from that twist. A row at the
stamp is the frame's pose, bit for bit.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from planar_vo.synth.vehicle import (
    Suspension,
    Trajectory,
    body_motion,
    camera_poses,
    drive_functions,
)

__all__ = ['STAMPS', 'RollingShutter', 'RowPoses', 'WorldRowPoses', 'row_poses',
           'world_row_poses']

#: Where in the readout the image stamp is: the fraction c of the readout before it.
STAMPS = {'start': 0.0, 'middle': 0.5, 'end': 1.0}


@dataclass(frozen=True)
class RollingShutter:
    """``readout`` seconds from the first row to the last; the stamp at ``stamp``."""

    readout: float = 0.0
    stamp: str = 'middle'

    def __post_init__(self) -> None:
        if not (math.isfinite(self.readout) and self.readout >= 0.0):
            raise ValueError(f'rolling-shutter readout must be >= 0 s, got {self.readout}')
        if self.stamp not in STAMPS:
            raise ValueError(f'rolling-shutter stamp must be one of {", ".join(STAMPS)}, '
                             f'got {self.stamp!r}')

    @property
    def global_shutter(self) -> bool:
        return self.readout == 0.0

    def row_offsets(self, height: int) -> np.ndarray:
        """(H,) time of each row relative to the stamp, s."""
        return (np.arange(height) / height - STAMPS[self.stamp]) * self.readout

    def describe(self) -> dict:
        return {'readout_s': self.readout, 'stamp': self.stamp}


@dataclass(frozen=True)
class RowPoses:
    """base_link pose in odom at each row's time of each frame, and the camera on the body.

    ``x``, ``y``, ``yaw``: (frames, H). ``camera_position`` (frames, H, 3) and
    ``camera_rotation`` (frames, H, 3, 3) (base_link <- camera body frame), or None for a
    rigid mount (the mount's pose at every row).
    """

    x: np.ndarray
    y: np.ndarray
    yaw: np.ndarray
    camera_position: np.ndarray | None = None
    camera_rotation: np.ndarray | None = None


def _derivative(t, yaw, speed, steer, wheelbase):
    v = speed(t)
    return v * np.cos(yaw), v * np.sin(yaw), v * np.tan(steer(t)) / wheelbase


def _rk4_chain(times, x, y, yaw, t0, speed, steer, wheelbase):
    """Integrate from (x, y, yaw) at ``t0`` (F,) through offsets ``times`` (J,) in order."""
    out = np.empty((3, len(t0), len(times)))
    t_prev = np.zeros(1)
    state = np.stack([x, y, yaw])
    for j, tau in enumerate(times):
        h = tau - t_prev[0]
        t = t0 + t_prev[0]
        k1 = np.stack(_derivative(t, state[2], speed, steer, wheelbase))
        k2 = np.stack(_derivative(t + h / 2, state[2] + h / 2 * k1[2], speed, steer, wheelbase))
        k3 = np.stack(_derivative(t + h / 2, state[2] + h / 2 * k2[2], speed, steer, wheelbase))
        k4 = np.stack(_derivative(t + h, state[2] + h * k3[2], speed, steer, wheelbase))
        state = state + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        out[:, :, j] = state
        t_prev = np.array([tau])
    return out


def row_poses(drive, traj: Trajectory, rate: float, seed: int, shutter: RollingShutter,
              height: int, mount=None, suspension: Suspension | None = None) -> RowPoses:
    """The pose of every row of every frame of ``traj`` (flat ground, see :class:`RowPoses`).

    ``drive``, ``rate`` and ``seed`` are those ``traj`` was made with (its speed and steering
    profiles); ``mount`` and ``suspension`` those of ``traj.camera`` (None: a rigid mount).
    """
    frames = len(traj.t)
    speed, steer = drive_functions(drive, frames, rate, seed)
    offsets = shutter.row_offsets(height)
    poses = np.empty((3, frames, height))
    after, before = offsets >= 0, offsets < 0
    args = (traj.x, traj.y, traj.yaw, traj.t, speed, steer, traj.wheelbase)
    if after.any():
        poses[:, :, after] = _rk4_chain(offsets[after], *args)
    if before.any():  # backwards from the stamp: the rows before it, latest first
        idx = np.flatnonzero(before)[::-1]
        poses[:, :, idx] = _rk4_chain(offsets[idx], *args)
    exact = offsets == 0  # the stamp's own row is the frame's pose, bit for bit
    poses[0][:, exact], poses[1][:, exact] = traj.x[:, None], traj.y[:, None]
    poses[2][:, exact] = traj.yaw[:, None]
    if suspension is None or suspension.rigid:
        return RowPoses(*poses)
    # The body's motion at the row times: the same functions of time, speed and turn rate.
    t = (traj.t[:, None] + offsets[None, :]).ravel()
    eps = 1e-5
    v = speed(t)
    rows = dataclasses.replace(
        traj, t=t, x=poses[0].ravel(), y=poses[1].ravel(), yaw=poses[2].ravel(), v=v,
        omega=v * np.tan(steer(t)) / traj.wheelbase, steer=steer(t),
        accel=(speed(t + eps) - speed(t - eps)) / (2 * eps), body=None, camera=None)
    cam = camera_poses(_mount_of(mount), body_motion(rows, suspension, seed), suspension)
    return RowPoses(*poses, cam.position.reshape(frames, height, 3),
                    cam.rotation.reshape(frames, height, 3, 3))


@dataclass(frozen=True)
class WorldRowPoses:
    """base_link's 3D world pose at each row's time of each frame (on terrain).

    ``position`` (frames, H, 3) and ``rotation`` (frames, H, 3, 3) (world <- base_link);
    ``camera_position`` (frames, H, 3) and ``camera_rotation`` (frames, H, 3, 3) (base_link
    <- camera body frame) the camera on a sprung body, or None for a rigid mount.
    """

    position: np.ndarray
    rotation: np.ndarray
    camera_position: np.ndarray | None = None
    camera_rotation: np.ndarray | None = None


def world_row_poses(grid, traj: Trajectory, drive, rate: float, seed: int,
                    shutter: RollingShutter, height: int, mount=None,
                    suspension: Suspension | None = None) -> WorldRowPoses:
    """The 3D pose of every row of every frame of ``traj``, ridden over a terrain.

    ``grid``: the :class:`~planar_vo.synth.ride.RideGrid` ``traj`` was made from
    (:func:`~planar_vo.synth.ride.ride_over` with ``grid``), at least ``shutter.readout``
    longer at both ends; ``drive``, ``rate``, ``seed`` those of ``traj``; ``mount`` and
    ``suspension`` those of ``traj.camera`` (None: a rigid mount).
    """
    from planar_vo.synth.ride import body_twist

    frames = len(traj.t)
    offsets = shutter.row_offsets(height)
    steps = np.floor(offsets / grid.h)
    # each row's time: grid point `index`, then `u` s more (0 at the stamp: the grid point)
    u = np.clip(offsets - steps * grid.h, 0.0, grid.h)
    index = grid.first + np.arange(frames)[:, None] * grid.sub + steps.astype(np.int64)[None]
    rigid = suspension is None or suspension.rigid
    reach = 0 if rigid else 1  # a sprung body's twist: one grid step either side too
    if (index.min() - reach < 0
            or (index + reach + (u > 0)[None]).max() > len(grid.t) - 1):
        raise ValueError('the ride grid is shorter than the readout')
    index, u = index.ravel(), np.broadcast_to(u, (frames, height)).ravel()
    position, rotation = grid.pose_at(index, u)
    shape = (frames, height)
    if rigid:
        return WorldRowPoses(position.reshape(*shape, 3), rotation.reshape(*shape, 3, 3))
    # The body's motion at the row times: the same functions of time, speed, turn rate and
    # acceleration as at the stamps, the twist from the poses one grid step either side.
    pos_a, rot_a = grid.pose_at(index - 1, u)
    pos_b, rot_b = grid.pose_at(index + 1, u)
    linear, angular = body_twist(rot_a, pos_a, rotation, rot_b, pos_b,
                                 np.full(index.size, 2 * grid.h))
    speed, steer = drive_functions(drive, frames, rate, seed)
    t = (traj.t[:, None] + offsets[None, :]).ravel()
    t_grid = (grid.t[grid.first + np.arange(frames) * grid.sub][:, None]
              + offsets[None, :]).ravel()
    eps = 1e-5
    rows = dataclasses.replace(
        traj, t=t, x=position[:, 0], y=position[:, 1], yaw=np.zeros(index.size),
        v=linear[:, 0], omega=angular[:, 2], steer=steer(t_grid),
        accel=(speed(t_grid + eps) - speed(t_grid - eps)) / (2 * eps), body=None, camera=None,
        pose3d=None)
    cam = camera_poses(_mount_of(mount), body_motion(rows, suspension, seed), suspension)
    return WorldRowPoses(position.reshape(*shape, 3), rotation.reshape(*shape, 3, 3),
                         cam.position.reshape(*shape, 3), cam.rotation.reshape(*shape, 3, 3))


def _mount_of(mount):
    from planar_vo.synth.mount import CameraMount
    return CameraMount.of(mount)
