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
- Terrain (``terrain``, ``ride``, ``raycast``): off flat ground the world has a height field
  ``z = h(x, y)`` laid out in world x, y (the drive starts at the origin heading +x; a road
  crown follows the planar path). The vehicle (car or differential-drive robot) stands on it
  through its wheel contacts: base_link's 3D pose in the world (``Trajectory.pose3d``) has the
  pitch of its front vs rear contacts and the roll of its left vs right wheels; the sprung
  body rides on that pose. The planar truth is then the SE(2) composition of the body-frame
  planar parts of the 3D motion on a <= 2 ms grid: distance along the surface. Every pixel's
  ray is intersected with the height field (the first hit). On flat ground none of it runs:
  bags are byte for byte those of before.
- A rolling shutter (``shutter``) exposes row r of H at stamp + (r/H - c) * readout and
  renders each row from the pose at its own time: on flat ground the bicycle model's, on
  terrain the vehicle's 3D pose riding the height field then (and the sprung body's), each
  row's rays cast from there. The ground truth stays at the stamps.

Rendering: a periodic pink-noise asphalt texture (20.48 m tile, 5 mm texels) sampled through
a mip-map with trilinear filtering, level chosen from each pixel's ground footprint; haze and a
smooth sky gradient beyond ``max_range``; textured vertical boxes as outliers (ray/box slab
intersection); vignetting, slow global illumination change and Gaussian noise. Deterministic
for a seed.

Modules: ``mount`` (the camera's mounting, own rotations), ``lens`` (intrinsics, distortion),
``scene`` (texture, boxes, the obstacle profile), ``vehicle`` (drive profile, bicycle model,
sprung body, true camera poses), ``terrain`` (height fields), ``ride`` (the vehicle on a
terrain, 3D and planar truth), ``raycast`` (rays against a height field), ``render`` (images,
auto-exposure), ``scenarios`` (named scenarios composing the profiles, building one; nothing
imports it but bagfile and cli), ``bagfile`` (messages, writing the bag), ``cli``
(``planar_vo_synth``).
"""

from planar_vo.synth.bagfile import (
    COMPRESSED_TOPIC,
    EPOCH_NS,
    IMAGE_TOPIC,
    INFO_TOPIC,
    ODOM_TOPIC,
    OPTICAL_FRAME,
    POSE3D_TOPIC,
    WORLD_FRAME,
    SynthResult,
    camera_info_msg,
    compressed_msg,
    generate_bag,
    image_msg,
    odometry_msg,
    pose3d_msg,
)
from planar_vo.synth.cli import build_parser, main
from planar_vo.synth.lens import DISTORTION_DEFAULTS, SynthCamera, undistort_pixels
from planar_vo.synth.mount import (
    BODY_FROM_OPTICAL,
    DEFAULT_MOUNTING,
    CameraMount,
    MountingError,
    axis_rotation,
    params_yaml,
    rotation_rpy,
    rpy_of,
)
from planar_vo.synth.raycast import intersect
from planar_vo.synth.render import Renderer, exposure_gains
from planar_vo.synth.ride import CHASSIS, Chassis, ride_over, settle
from planar_vo.synth.scenarios import SCENARIOS, VEHICLES, Scenario, render_scenario
from planar_vo.synth.scene import (
    Box,
    ObstacleProfile,
    Texture,
    make_ground_texture,
    make_obstacles,
)
from planar_vo.synth.terrain import (
    FLAT,
    TERRAIN_KINDS,
    Bumps,
    Camber,
    Composite,
    Flat,
    Grades,
    Hills,
    Plane,
    Terrain,
    TerrainError,
    make_terrain,
)
from planar_vo.synth.vehicle import (
    RIGID,
    WHEELBASE,
    BodyMotion,
    CameraPoses,
    DriveProfile,
    Pose3D,
    Suspension,
    Trajectory,
    body_motion,
    camera_poses,
    drive_functions,
    make_trajectory,
    mount_camera,
    road_vibration,
)

__all__ = [
    'BODY_FROM_OPTICAL', 'CHASSIS', 'COMPRESSED_TOPIC', 'DEFAULT_MOUNTING', 'DISTORTION_DEFAULTS',
    'EPOCH_NS', 'FLAT', 'IMAGE_TOPIC', 'INFO_TOPIC', 'ODOM_TOPIC', 'OPTICAL_FRAME',
    'POSE3D_TOPIC', 'RIGID', 'SCENARIOS', 'TERRAIN_KINDS', 'VEHICLES', 'WHEELBASE', 'WORLD_FRAME',
    'BodyMotion', 'Box', 'Bumps', 'Camber', 'CameraMount', 'CameraPoses', 'Chassis', 'Composite',
    'DriveProfile', 'Flat', 'Grades', 'Hills', 'MountingError', 'ObstacleProfile', 'Plane',
    'Pose3D', 'Renderer', 'Scenario', 'Suspension', 'SynthCamera', 'SynthResult', 'Terrain',
    'TerrainError', 'Texture', 'Trajectory', 'axis_rotation', 'body_motion', 'build_parser',
    'camera_info_msg', 'camera_poses', 'compressed_msg', 'drive_functions', 'exposure_gains',
    'generate_bag', 'image_msg', 'intersect', 'main', 'make_ground_texture', 'make_obstacles',
    'make_terrain', 'make_trajectory', 'mount_camera', 'odometry_msg', 'params_yaml',
    'pose3d_msg', 'render_scenario', 'ride_over', 'road_vibration',
    'settle', 'rotation_rpy', 'rpy_of',
    'undistort_pixels',
]
