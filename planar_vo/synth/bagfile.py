"""ROS messages of the synthetic camera and ground truth, and writing them to a bag."""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from planar_vo.synth.lens import SynthCamera
from planar_vo.synth.mount import CameraMount, MountingError, params_yaml
from planar_vo.synth.ride import CHASSIS, rotation_quaternion
from planar_vo.synth.scenarios import SCENARIOS, render_scenario
from planar_vo.synth.shutter import RollingShutter
from planar_vo.synth.terrain import Terrain, TerrainShape
from planar_vo.synth.vehicle import RIGID, Suspension, Trajectory

EPOCH_NS = 1_700_000_000 * 1_000_000_000
IMAGE_TOPIC = '/camera/image_raw'
COMPRESSED_TOPIC = '/camera/image_raw/compressed'
INFO_TOPIC = '/camera/camera_info'
ODOM_TOPIC = '/ground_truth/odom'
POSE3D_TOPIC = '/ground_truth/pose3d'
WORLD_FRAME = 'world'
OPTICAL_FRAME = 'camera_optical_frame'


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


def pose3d_msg(ts, traj: Trajectory, k: int, ns: int):
    """nav_msgs/Odometry of base_link's full 3D pose in ``world`` and its body twist."""
    t = ts.types
    p3 = traj.pose3d
    qx, qy, qz, qw = rotation_quaternion(p3.rotation[k])
    pose = t['geometry_msgs/msg/Pose'](
        position=t['geometry_msgs/msg/Point'](**dict(zip('xyz', map(float, p3.position[k])))),
        orientation=t['geometry_msgs/msg/Quaternion'](x=qx, y=qy, z=qz, w=qw))
    vec = t['geometry_msgs/msg/Vector3']
    twist = t['geometry_msgs/msg/Twist'](
        linear=vec(**dict(zip('xyz', map(float, p3.linear[k])))),
        angular=vec(**dict(zip('xyz', map(float, p3.angular[k])))))
    return t['nav_msgs/msg/Odometry'](
        header=_header(ts, ns, WORLD_FRAME), child_frame_id='base_link',
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
    terrain: Terrain | None = None
    vehicle: str = 'car'
    rolling_shutter: RollingShutter | None = None


def generate_bag(out_path, scenario: str = 'default', frames: int = 300, seed: int = 0, *,
                 rate: float = 30.0, camera: SynthCamera | None = None, mounting=None,
                 suspension: Suspension | None = None, compressed: bool = False,
                 jpeg_quality: int = 90, noise_sigma: float = 1.5, max_range: float = 60.0,
                 obstacles: bool = True, storage_compression: bool = True,
                 params_out=None, configured_error: MountingError | None = None,
                 exposure: float = 0.0, supersample: int = 1,
                 terrain: str | Terrain | None = None, vehicle: str = 'car',
                 rolling_shutter: RollingShutter | None = None,
                 terrain_shape: TerrainShape | None = None, texture_contrast: float = 1.0,
                 vignetting: float = 0.35, progress: bool = False) -> SynthResult:
    """Render a scenario and write the rosbag2 bag (MCAP, zstd chunks) at ``out_path``.

    ``mounting``, ``suspension``, ``exposure``, ``supersample``, ``terrain``, ``terrain_shape``,
    ``texture_contrast``, ``vignetting`` and ``vehicle`` as in :func:`render_scenario`. The
    images are rendered with ``mounting``;
    ``params_out`` gets it plus ``configured_error`` (the mounting a user would have
    configured, to test calibration). On terrain (not flat) the bag also has
    ``/ground_truth/pose3d`` and its metadata.yaml records the terrain and the vehicle
    (``custom_data``, key ``planar_vo_synth``, a JSON object); so does a comment in
    ``params_out``. A ``rolling_shutter`` with a readout over 0 renders each row at its own
    time (the stamp at its ``stamp`` convention) and is recorded the same way (key
    ``rolling_shutter``).
    """
    from planar_vo.io.bag import BagWriter, typestore

    t0 = time.monotonic()
    camera = camera or SynthCamera()
    renderer, traj = render_scenario(scenario, frames, seed, rate=rate, camera=camera,
                                     mounting=mounting, suspension=suspension,
                                     noise_sigma=noise_sigma, max_range=max_range,
                                     obstacles=obstacles, exposure=exposure,
                                     supersample=supersample, terrain=terrain,
                                     vehicle=vehicle, rolling_shutter=rolling_shutter,
                                     terrain_shape=terrain_shape,
                                     texture_contrast=texture_contrast, vignetting=vignetting)
    ground = renderer.terrain
    shutter = None if rolling_shutter is None or rolling_shutter.global_shutter \
        else rolling_shutter
    record = None if ground.flat else \
        {'scenario': scenario, 'vehicle': vehicle, 'terrain': ground.describe(),
         'seed': seed, 'truth': {ODOM_TOPIC: 'planar, distance along the surface',
                                 POSE3D_TOPIC: f'3D base_link pose in {WORLD_FRAME}'}}
    if shutter is not None:  # global-shutter bags stay byte for byte those of before
        record = (record or {'scenario': scenario, 'seed': seed}) | {
            'rolling_shutter': shutter.describe()}
    record = None if record is None else json.dumps(record)
    mounting = renderer.mounting
    configured = (configured_error or MountingError()).apply(mounting)
    suspension = SCENARIOS[scenario].suspension if suspension is None else suspension
    ts = typestore()
    img_topic = COMPRESSED_TOPIC if compressed else IMAGE_TOPIC
    img_type = 'sensor_msgs/msg/CompressedImage' if compressed else 'sensor_msgs/msg/Image'
    with BagWriter(out_path, compress=storage_compression) as bag, tqdm(
            total=frames, desc='planar_vo_synth', unit='frame', disable=not progress) as bar:
        bag.add_topic(img_topic, img_type)
        bag.add_topic(INFO_TOPIC, 'sensor_msgs/msg/CameraInfo')
        bag.add_topic(ODOM_TOPIC, 'nav_msgs/msg/Odometry')
        if record is not None:
            if not ground.flat:
                bag.add_topic(POSE3D_TOPIC, 'nav_msgs/msg/Odometry')
            # io.bag.BagWriter has no custom_data option yet: its rosbags Writer has
            bag._writer.set_custom_data('planar_vo_synth', record)
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
            if not ground.flat:
                bag.write(POSE3D_TOPIC, 'nav_msgs/msg/Odometry', ns, pose3d_msg(ts, traj, k, ns))
            bar.update()
    if params_out is not None:
        # The wheels are measured with the mounting: where the road may bend from.
        chassis = CHASSIS[vehicle]
        text = (params_yaml(configured) + f'    wheelbase: {chassis.front_x!r}\n'
                f'    track_width: {chassis.front_track!r}\n')
        if configured != mounting:
            text += (f'# rendered with camera_x {mounting.x!r}, camera_y {mounting.y!r}, '
                     f'camera_height {mounting.height!r},\n# camera_roll {mounting.roll!r}, '
                     f'camera_pitch {mounting.pitch!r}, camera_yaw {mounting.yaw!r}\n')
        if record is not None:
            text += f'# planar_vo_synth: {record}\n'
        Path(params_out).write_text(text)
    return SynthResult(Path(out_path), scenario, frames, rate, seed, camera, mounting, traj,
                       suspension, configured, exposure, len(renderer.boxes),
                       time.monotonic() - t0, ground, vehicle, shutter)
