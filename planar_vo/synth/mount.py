"""The synthetic camera's mounting, composed on its own (axis-angle rotations).

Never built with ``planar_vo.core.geometry.camera``: the renderer must not share the code it
tests, or a
wrong roll/pitch/yaw composition there would cancel out. The convention is DESIGN.md
section 2: the camera body frame (x forward, y left, z up) in base_link, rotated by
``Rz(yaw) Ry(pitch) Rx(roll)``; positive pitch looks down.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import cv2
import numpy as np

# Axes of the optical frame (x right, y down, z forward) in the camera body frame (x forward,
# y left, z up): the columns of the rotation body <- optical.
BODY_FROM_OPTICAL = np.column_stack([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])


def axis_rotation(axis: str, angle: float) -> np.ndarray:
    """Rotation by ``angle`` (rad, right-hand rule) about base axis ``'x'``, ``'y'`` or ``'z'``.

    Built from the axis-angle vector with OpenCV's Rodrigues formula: the renderer's own path,
    independent of ``planar_vo.core.geometry.camera``.
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

    Plain numbers; anything with these six attributes (e.g.
    ``planar_vo.core.geometry.camera.Mounting``)
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
