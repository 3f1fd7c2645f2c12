"""The vehicle: a kinematic bicycle model at the rear axle and a sprung body on it.

base_link (REP-103: x forward, y left, z up) is on the rear axle, on the ground; the
trajectory is its ground truth. The sprung body pitches, rolls and bounces under the
camera; that motion is kept apart (``Trajectory.body``, ``Trajectory.camera``).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from planar_vo.synth.mount import BODY_FROM_OPTICAL, CameraMount, rotation_rpy, rpy_of

WHEELBASE = 2.7


@dataclass(frozen=True)
class DriveProfile:
    """How the vehicle is driven: smooth (C1) speed and steering profiles through random knots.

    ``speed``: (lo, hi) m/s of the speed knots; ``steer``: largest |steering angle| of the
    knots (rad); ``knot_dt``: (lo, hi) seconds between knots. The yaw rate is
    ``v * tan(steer) / wheelbase``. ``schedule``: when set, a :class:`SpeedSchedule` gives the
    speed instead of the random knots (stops, creeping, reversing); the steering stays random.
    """

    speed: tuple = (3.0, 8.0)
    steer: float = 0.06
    knot_dt: tuple = (2.0, 3.5)
    schedule: SpeedSchedule | None = None

    @classmethod
    def of(cls, profile) -> DriveProfile:
        """The profile with the same fields as ``profile`` (e.g. a Scenario)."""
        return cls(tuple(profile.speed), float(profile.steer), tuple(profile.knot_dt),
                   getattr(profile, 'schedule', None))


@dataclass(frozen=True)
class SpeedSchedule:
    """A speed profile of phases: ``(duration s, speed m/s)`` each, in order.

    Each phase starts with a smoothstep ramp (C1) of ``ramp`` s from the previous phase's
    speed to its own (the first phase starts at its own speed), then holds it; past the last
    phase its speed is held. A phase of speed 0 is a full stop: once its ramp is over the
    speed is exactly 0.0, so the integrated pose does not change by a single bit (the truth
    holds the vehicle exactly still). Negative speeds reverse.
    """

    phases: tuple = ((5.0, 4.0),)
    ramp: float = 1.5

    @property
    def duration(self) -> float:
        """Seconds of all phases."""
        return float(sum(d for d, _ in self.phases))

    def speed(self, t):
        """Speed (m/s) at times ``t`` (s)."""
        t = np.asarray(t, np.float64)
        starts = np.cumsum([0.0] + [d for d, _ in self.phases])[:-1]
        targets = np.array([v for _, v in self.phases], np.float64)
        previous = np.r_[targets[0], targets[:-1]]
        i = np.clip(np.searchsorted(starts, t, side='right') - 1, 0, len(starts) - 1)
        ramp = np.minimum(self.ramp, np.array([d for d, _ in self.phases])[i])
        s = np.clip((t - starts[i]) / ramp, 0.0, 1.0)
        s = s * s * (3.0 - 2.0 * s)
        return np.where(s >= 1.0, targets[i], previous[i] + (targets[i] - previous[i]) * s)

    def stopped(self, t) -> np.ndarray:
        """(N,) True where the schedule holds the vehicle still at ``t``."""
        return self.speed(t) == 0.0


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


ROAD_EXCITED_SPEED = 1.0  # m/s: the road's vibration of the body is full from this speed on


def road_vibration(rng: np.random.Generator, t: np.ndarray) -> np.ndarray:
    """Road-excited body motion in [-1, 1]: three sines of 0.6-3 Hz with random phases."""
    bands, weights = ((0.6, 1.2), (1.2, 2.0), (2.0, 3.0)), (0.5, 0.3, 0.2)
    out = np.zeros_like(t)
    for (lo, hi), w in zip(bands, weights, strict=True):
        out += w * np.sin(2 * math.pi * rng.uniform(lo, hi) * t + rng.uniform(0, 2 * math.pi))
    return out


def body_motion(traj: Trajectory, suspension: Suspension, seed: int) -> BodyMotion:
    """Body pitch, roll and bounce at each frame of ``traj`` (see :class:`Suspension`).

    The road excites the body only while the wheels roll: its vibration fades out below
    ROAD_EXCITED_SPEED and is none standing (it rocked a stopped car 0.3 deg and 9 mm before).
    """
    rng = np.random.default_rng([seed, 5])
    share = suspension.inertial_share
    rolling = np.minimum(np.abs(traj.v) / ROAD_EXCITED_SPEED, 1.0)
    road = [rolling * road_vibration(rng, traj.t) for _ in range(3)]
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


@dataclass(frozen=True)
class Pose3D:
    """The full 3D base_link pose in the world frame at each frame, and its body twist.

    Set on terrain (``planar_vo.synth.ride``); None on flat ground, where world = odom and
    the planar pose is the whole pose.
    """

    position: np.ndarray  # (N, 3) m, world
    rotation: np.ndarray  # (N, 3, 3) world <- base_link
    linear: np.ndarray  # (N, 3) m/s, base_link velocity in base_link
    angular: np.ndarray  # (N, 3) rad/s, base_link angular velocity in base_link

    @property
    def rpy(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(roll, pitch, yaw) (N,) each, rad (:func:`rotation_rpy`; positive pitch = down)."""
        return rpy_of(self.rotation)


@dataclass
class Trajectory:
    """Ground truth at each frame: base_link pose in odom and twist in base_link.

    The twist (``v``, ``omega``) is the instantaneous one at each frame's stamp. ``body`` and
    ``camera`` (set by :func:`render_scenario`) are the sprung body's motion and the true
    camera pose in base_link at each frame; they are not part of the ground-truth odometry.
    On terrain, ``pose3d`` is base_link's 3D pose in the world frame and (x, y, yaw) is the
    planar truth: the SE(2) composition of the body-frame planar parts of the 3D motion
    (distance along the surface; see ``planar_vo.synth.ride``).
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
    pose3d: Pose3D | None = None

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


def drive_functions(drive, frames: int, rate: float, seed: int):
    """``(speed(t), steer(t))`` of a drive of ``frames`` frames at ``rate`` Hz (seeded)."""
    drive = DriveProfile.of(drive)
    rng = np.random.default_rng([seed, 1])
    duration = (frames - 1) * (1.0 / rate)  # as make_trajectory always computed it
    speed = _smooth_profile(rng, duration, *drive.speed, drive.knot_dt)
    steer = _smooth_profile(rng, duration, 0.0, drive.steer, drive.knot_dt, True)
    if drive.schedule is not None:
        speed = drive.schedule.speed
    return speed, steer


def make_trajectory(drive, frames: int, rate: float, seed: int,
                    wheelbase: float = WHEELBASE, substeps: int = 20) -> Trajectory:
    """Integrate the bicycle model (RK4 on fine sub-steps) and sample it at the frames.

    ``drive``: a :class:`DriveProfile` or anything with its fields (e.g. a Scenario).
    """
    dt = 1.0 / rate
    speed, steer = drive_functions(drive, frames, rate, seed)

    # Classic RK4 on sub-steps of h. The yaw rate depends on time only, so every stage is
    # evaluated at once; the sums accumulate in step order, as a loop would add them, and
    # math's tan/cos/sin (not numpy's SIMD ones) keep the bags byte-identical to that loop.
    h = dt / substeps
    steps = (np.arange(frames - 1)[:, None] * dt + np.arange(substeps)[None, :] * h).ravel()
    mid, end = steps + h / 2, steps + h

    def yaw_rate(t):
        return speed(t) * np.array([math.tan(s) for s in steer(t)]) / wheelbase

    w0, w_mid, w_end = yaw_rate(steps), yaw_rate(mid), yaw_rate(end)
    yaw_steps = np.concatenate([[0.0], np.cumsum(h / 6 * (w0 + 2 * w_mid + 2 * w_mid + w_end))])
    yaw0 = yaw_steps[:-1]  # yaw at the start of each sub-step
    v0, v_mid, v_end = speed(steps), speed(mid), speed(end)
    stages = (yaw0, yaw0 + h / 2 * w0, yaw0 + h / 2 * w_mid, yaw0 + h * w_mid)
    position = []
    for trig in (math.cos, math.sin):
        a, b, c, d = (np.array([trig(angle) for angle in stage]) for stage in stages)
        increments = h / 6 * (v0 * a + 2 * (v_mid * b) + 2 * (v_mid * c) + v_end * d)
        position.append(np.concatenate([[0.0], np.cumsum(increments)])[::substeps])
    x, y = position
    yaw = yaw_steps[::substeps]
    t = np.arange(frames) * dt
    v = speed(t)
    st = steer(t)
    eps = 1e-5  # the profiles are C1: a central difference gives the acceleration
    accel = (speed(t + eps) - speed(t - eps)) / (2 * eps)
    return Trajectory(t, x, y, yaw, v, v * np.tan(st) / wheelbase, st, wheelbase, accel)
