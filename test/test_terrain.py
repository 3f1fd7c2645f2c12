"""The local ground model: the road ahead is not the plane under the wheels.

Closed-form cases (known surface, motion and rotation) and short rendered drives over the
renderer's own terrain (planar_vo.synth: its height fields, its vehicle on its wheels, its
planar truth along the surface). The long drives of the README's table: `make terrain`.
"""

import dataclasses
import functools

import numpy as np
import pytest

from planar_vo import synth
from planar_vo.core import config
from planar_vo.core.estimation.local_ground import (
    GroundPrior,
    Hinge,
    LocalGroundResult,
    refine_on_local_ground,
    surface_residuals,
)
from planar_vo.core.estimation.ransac import RansacResult, TransferModel
from planar_vo.core.geometry.camera import CameraModel, Mounting
from planar_vo.core.geometry.se2 import twist_motion
from planar_vo.core.metrics import metrics
from planar_vo.core.odometry import VisualOdometry
from planar_vo.core.odometry.bumps_ahead import BumpsAhead
from planar_vo.core.odometry.ground_filter import LocalGroundFilter
from planar_vo.core.odometry.road_ahead import RoadAhead
from planar_vo.core.odometry.surface_bands import BAND_REACH, off_surface_bands
from planar_vo.synth.terrain import TerrainShape
from planar_vo.tools.experiments.mounting_experiment import plain_opencv_path
from test.conftest import synth_camera_model

MOUNT = Mounting(x=1.2, y=0.0, height=1.1, roll=0.0, pitch=np.radians(8.0), yaw=0.0)
HINGE = 2.7


def _surface_z(surface, x, y):
    ep, er, k, kxy, kyy = surface
    u = x - HINGE
    return ep * u + er * y + 0.5 * k * u * u + kxy * u * y + 0.5 * kyy * y * y


def _observe(points, mount, motion, rotation, dh=0.0):
    """Normalized coordinates of base-1 points seen by camera 1, and by camera 2 after the
    planar motion and the rotation (roll, pitch) about base_link's origin: written out
    here, independently of the code under test."""
    o1 = (points - mount.position) @ mount.base_from_optical
    x, y, yaw = motion
    c, s = np.cos(yaw), np.sin(yaw)
    q = np.c_[c * (points[:, 0] - x) + s * (points[:, 1] - y),
              -s * (points[:, 0] - x) + c * (points[:, 1] - y), points[:, 2]]
    cr, sr, cp, sp = np.cos(rotation[0]), np.sin(rotation[0]), np.cos(rotation[1]), np.sin(
        rotation[1])
    tilt = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]]) @ np.array(
        [[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    centre = tilt @ mount.position + np.array([0.0, 0.0, dh])
    o2 = (q - centre) @ tilt @ mount.base_from_optical
    return o1[:, :2] / o1[:, 2:], o2[:, :2] / o2[:, 2:]


def test_the_local_ground_refinement_recovers_a_known_surface_motion_and_rotation():
    """A curved, twisted road ahead, a step with a pitch and roll jolt: all recovered from
    the two views (no noise), where the plane under the wheels is off by centimetres."""
    rng = np.random.default_rng(3)
    surface = np.array([0.03, -0.015, 0.02, 0.006, -0.01])
    x, y = rng.uniform(3.0, 7.0, 400), rng.uniform(-2.5, 2.5, 400)
    points = np.c_[x, y, _surface_z(surface, x, y)]
    motion, rotation = np.array([0.4, 0.01, 0.03]), np.array([0.004, -0.006])
    m1, m2 = _observe(points, MOUNT, motion, rotation, dh=0.002)
    v1 = np.c_[m1, np.ones(len(m1))] @ MOUNT.base_from_optical.T
    prior = GroundPrior(np.diag([0.02, 0.02, 0.01]) ** 2, np.zeros(5),
                        np.diag([0.05, 0.05, 0.03, 0.03, 0.03]) ** 2)
    fit = refine_on_local_ground(motion + [0.01, 0.0, 0.002], v1, m2, MOUNT, prior,
                                 focal_px=500.0, threshold_px=2.0, hinge=Hinge(HINGE),
                                 start_threshold_px=20.0, iterations=20)
    np.testing.assert_allclose(fit.motion, motion, atol=1e-6)
    np.testing.assert_allclose(fit.rotation, [*rotation, 0.002], atol=1e-6)
    np.testing.assert_allclose(fit.surface, surface, atol=1e-5)
    assert fit.inliers.all()



def test_the_surface_meets_the_front_wheels_not_the_centre_line():
    """A road curved across (a trough, 0.01 /m) under a car whose front wheels, 1.6 m apart,
    stand on it: the centre line lies 3.2 mm below their plane. The surface through the
    wheels' contacts recovers the step; the one through the centre line took that offset for
    the camera's height, and the step came out 1.2 mm short of 0.4 m (0.29 %)."""
    rng = np.random.default_rng(5)
    kyy, track = 0.01, 1.6
    x, y = rng.uniform(3.0, 7.0, 400), rng.uniform(-1.4, 1.4, 400)
    points = np.c_[x, y, 0.5 * kyy * (y * y - track * track / 4)]
    motion = np.array([0.4, 0.005, 0.01])
    m1, m2 = _observe(points, MOUNT, motion, np.zeros(2))
    v1 = np.c_[m1, np.ones(len(m1))] @ MOUNT.base_from_optical.T
    prior = GroundPrior(np.diag([0.02, 0.02, 0.01]) ** 2, np.zeros(5),
                        np.diag([0.05, 0.05, 0.03, 0.03, 0.03]) ** 2)

    def fit(hinge):
        return refine_on_local_ground(motion + [0.01, 0.0, 0.002], v1, m2, MOUNT, prior,
                                      focal_px=500.0, threshold_px=2.0, hinge=hinge,
                                      start_threshold_px=20.0, iterations=20)

    on_wheels = fit(Hinge(HINGE, track=track))
    np.testing.assert_allclose(on_wheels.motion, motion, atol=1e-6)
    np.testing.assert_allclose(on_wheels.surface[4], kyy, atol=1e-5)
    centre = fit(Hinge(HINGE))
    assert centre.motion[0] - motion[0] < -0.8e-3

def test_a_remembered_bump_that_leaves_too_few_tracks_is_fitted_with_its_tracks():
    """A low camera sees a short stretch of road: a bump remembered there hides nearly all of
    it, and what is left (here 30 tracks on something else, seen at random) cannot hold the
    pair. The pair is fitted with the bump's tracks instead (it once raised, and tracking was
    lost: a car's camera 0.8 m up kept 25 tracks of 316)."""
    rng = np.random.default_rng(13)
    x, y = rng.uniform(3.4, 4.4, 300), rng.uniform(-1.5, 1.5, 300)
    step = np.array([0.3, 0.0, 0.0])
    m1, m2 = _observe(np.c_[x, y, np.zeros_like(x)], MOUNT, step, np.zeros(2))
    xo, yo = rng.uniform(5.0, 6.0, 30), rng.uniform(-1.5, 1.5, 30)
    o1, _ = _observe(np.c_[xo, yo, np.zeros_like(xo)], MOUNT, step, np.zeros(2))
    o2 = o1 + rng.normal(0.0, 0.02, o1.shape)
    m1, m2 = np.r_[m1, o1], np.r_[m2, o2]
    ground = LocalGroundFilter(MOUNT, rates=np.array([0.5, 0.5, 0.3]), wheelbase=HINGE,
                               self_calibrate=False)
    ground.ahead = RoadAhead(BumpsAhead((3.9,)))
    assert np.count_nonzero(~ground.ahead.bumps.hides(x, BAND_REACH)) == 0
    model = TransferModel(*MOUNT.ground_to_optical(), 500.0, MOUNT)
    start = RansacResult(step + [0.01, 0.0, 0.0], np.eye(3) * 1e-4, np.ones(len(m1), bool), 1,
                         0.3)
    result, _ = ground.refine(start, np.c_[m1, np.ones(len(m1))], m2, MOUNT, model, dt=0.05,
                              inlier_threshold=2.0, start_threshold=8.0, min_inliers=12)
    assert abs(result.motion[0] - step[0]) < 0.001
    assert np.count_nonzero(result.inliers[:300]) > 250


def _crowned_road_drive(half_width, seed, crown=1.75, pairs=40):
    """A car in its lane on a crowned road (2 % either side of a crown ``crown`` m to its
    left, rounded over 0.5 m as the renderer's) drives straight at 10 m/s; 600 tracks where
    a 640x480 camera sees the ground, 0.15 px of noise. Returns the mean error of the
    refined steps (x, y, yaw) after the first ten, and which side the filter leaves out."""
    rng = np.random.default_rng(seed)
    pixels = np.c_[rng.uniform(0.0, 640.0, 600), rng.uniform(300.0, 480.0, 600)]
    rays = np.c_[(pixels - [320.0, 240.0]) / 500.0, np.ones(600)] @ MOUNT.base_from_optical.T
    reach = MOUNT.position[2] / -rays[:, 2]
    x, y = (MOUNT.position[:2, None] + reach * rays[:, :2].T)
    n, slope = y - crown, 0.02
    rho = np.where(np.abs(n) < 0.5, n * n + 0.25, np.abs(n))
    points = np.c_[x, y, -slope * (rho + n)]  # relative to the wheels' plane (slope * n)
    step = twist_motion(np.array([10.0, 0.0, 0.0]), 0.05)
    model = TransferModel(*MOUNT.ground_to_optical(), 500.0, MOUNT)
    ground = LocalGroundFilter(MOUNT, rates=np.array([0.5, 0.5, 0.3]), wheelbase=HINGE,
                               self_calibrate=False, half_width=half_width)
    errors = []
    for _ in range(pairs):
        m1, m2 = _observe(points, MOUNT, step, np.zeros(2))
        m2 = m2 + rng.normal(0.0, 0.15 / 500.0, m2.shape)
        start = RansacResult(step + [0.01, 0.0, 0.0], np.eye(3) * 1e-4, np.ones(600, bool),
                             1, 0.3)
        result, _ = ground.refine(start, np.c_[m1, np.ones(600)], m2, MOUNT, model,
                                  dt=0.05, inlier_threshold=0.5, start_threshold=8.0,
                                  min_inliers=10)
        ground.advance(result.motion)
        errors.append(result.motion - step)
    return np.mean(errors[10:], axis=0), ground.diagnostics()['road bends away beyond the lane']


def test_the_road_beyond_a_crown_is_left_out_of_the_surface():
    """The far side of the crown falls away from the surface under the wheels; fitted with
    it, the car turns steadily right (rendered crowned roads: 3-5 mdeg a metre). With the
    shipped surface_half_width that side is found and left out, and the steps come out
    straight; a road with no crown in sight keeps every track. Measured over four seeds,
    yaw a 0.5 m step: -3.3e-5 rad with every track, within +-1.6e-5 (one seed's noise)
    with the default."""
    half_width = config.defaults()['surface_half_width']
    default = [_crowned_road_drive(half_width, seed) for seed in range(4)]
    every = [_crowned_road_drive(np.inf, seed) for seed in range(4)]
    assert [side for _, side in default] == ['left'] * 4
    assert abs(np.mean([e[2] for e, _ in default])) < 1e-5, default
    assert np.mean([e[2] for e, _ in every]) < -2e-5, every  # the case the default mends
    _, side = _crowned_road_drive(half_width, 0, crown=100.0)
    assert side == 'neither side'


def _flat_road_with_a_bump(height, noise_px=0.0):
    """Tracks 3-9 m ahead on a flat road, those at 5.0-5.5 m on a bump ``height`` high; the
    fit the smooth surface would give (the true motion, no surface): (fit, v1, m2, on bump)."""
    rng = np.random.default_rng(5)
    x, y = rng.uniform(3.0, 9.0, 600), rng.uniform(-2.0, 2.0, 600)
    bump = (x >= 5.0) & (x < 5.5)
    points = np.c_[x, y, np.where(bump, height, 0.0)]
    motion = np.array([0.3, 0.0, 0.01])
    m1, m2 = _observe(points, MOUNT, motion, np.zeros(2))
    m2 = m2 + rng.normal(0.0, noise_px / 500.0, m2.shape)
    v1 = np.c_[m1, np.ones(len(m1))] @ MOUNT.base_from_optical.T
    fit = LocalGroundResult(motion, np.eye(3), np.zeros(3), np.zeros(3), np.zeros(5),
                            np.eye(5), np.ones(len(x), bool), np.ones(len(x)), 0.3)
    return fit, v1, m2, bump


def test_a_band_off_the_surface_together_is_left_out_and_noise_is_not():
    """An 8 cm speed bump 5 m ahead, tracks with 0.3 px of noise: every track on it goes,
    and few others (its rays meet the wheel plane up to 0.4 m further, in the next band).
    The same road without the bump: nothing goes."""
    fit, v1, m2, bump = _flat_road_with_a_bump(0.08, noise_px=0.3)
    keep = off_surface_bands(fit, v1, m2, MOUNT, Hinge(HINGE), 500.0)
    assert keep is not None
    assert not np.any(keep[bump])
    assert np.count_nonzero(~keep[~bump]) < 0.15 * np.count_nonzero(~bump)  # measured 63 of 543
    fit, v1, m2, _ = _flat_road_with_a_bump(0.0, noise_px=0.3)
    assert off_surface_bands(fit, v1, m2, MOUNT, Hinge(HINGE), 500.0) is None


def test_the_surface_jacobian_is_the_derivative_of_the_transfer():
    rng = np.random.default_rng(1)
    points = np.c_[rng.uniform(3, 7, 50), rng.uniform(-2, 2, 50), np.zeros(50)]
    v1 = (points - MOUNT.position).T
    params = np.array([0.3, 0.01, 0.02, 0.004, -0.006, 0.002, 0.02, -0.01, 0.01, 0.005, -0.008])
    axle = Hinge(HINGE, track=1.6)
    residual, jacobian, valid = surface_residuals(params, v1, np.zeros((2, 50)), MOUNT, axle)
    assert valid.all()
    for j in range(11):
        step = np.zeros(11)
        step[j] = 1e-6
        numeric = (surface_residuals(params + step, v1, np.zeros((2, 50)), MOUNT, axle)[0]
                   - surface_residuals(params - step, v1, np.zeros((2, 50)), MOUNT, axle)[0])
        np.testing.assert_allclose(jacobian[j], numeric / 2e-6, rtol=1e-5, atol=1e-9)


CAR_MOUNT = synth.CameraMount(x=1.2, y=0.0, height=1.1, roll=0.0, pitch=np.radians(8.0),
                              yaw=0.0)
# A small robot's camera: 0.35 m up, 20 deg down, 0.15 m ahead of its drive wheels.
ROBOT_MOUNT = synth.CameraMount(x=0.15, y=0.0, height=0.35, roll=0.0, pitch=np.radians(20.0),
                                yaw=0.0)


def _read_only(array: np.ndarray) -> np.ndarray:
    """``array``, which may no longer be written: it is shared between tests."""
    array.setflags(write=False)
    return array


def _render(terrain, frames=100, vehicle='car', mount=None):
    """A short 20 Hz drive over ``terrain`` (376x240, the default path; a car's camera 1.1 m
    up, 8 deg down, 1.2 m ahead of the rear axle, or ROBOT_MOUNT on a differential-drive
    robot, unless ``mount``): (camera model, mounting, images, planar truth, twist).

    Rendered once per module (several tests replay the same drive): the arrays are read-only.
    """
    return _rendered(terrain, frames, vehicle, mount or (CAR_MOUNT if vehicle == 'car'
                                                         else ROBOT_MOUNT))


@functools.cache
def _rendered(terrain, frames, vehicle, mount):
    camera = synth.SynthCamera.scaled(376, 240)
    renderer, traj = synth.render_scenario('default', frames, 0, rate=20.0, camera=camera,
                                           mounting=mount, terrain=terrain, vehicle=vehicle)
    images = tuple(_read_only(renderer.render_frame(traj, k)) for k in range(frames))
    twist = np.c_[traj.v, np.zeros_like(traj.v), traj.omega]  # the body's, at each stamp
    truth = np.c_[traj.x, traj.y, traj.yaw]
    return synth_camera_model(renderer), mount, images, _read_only(truth), _read_only(twist)


@functools.cache
def _drive(terrain, ground_model, vehicle='car', wheels_set=True, mount=None):
    """The shipped defaults, only the nominal mounting configured, on :func:`_render`'s
    drive: (metrics, results, whether each frame saw irregular ground). A robot's wheelbase
    is 0: its drive wheels, 0.5 m apart, are its front contacts (the caster trails); unless
    not ``wheels_set``: then a car's."""
    camera, mount, images, truth, _ = _render(terrain, vehicle=vehicle, mount=mount)
    wheels = {} if vehicle == 'car' or not wheels_set else {'wheelbase': 0.0, 'track_width': 0.5}
    params = config.validate({**config.mounting_params(mount), 'ground_model': ground_model,
                              **wheels})
    vo = VisualOdometry.from_params(camera, params)
    results, irregular = [], []
    for k, image in enumerate(images):
        results.append(vo.process(image, k / 20.0))
        irregular.append(vo.ground_irregular)
    return metrics(np.array([r.pose for r in results]), truth), results, irregular


# Measured (100 frames; stop 51): hills 0.18 %, grades 0.14 % (the plane model: 2.1 and 1.2 %).
@pytest.mark.parametrize('terrain, bound', [('hills', 0.45), ('grades', 0.3)])
def test_hills_and_grades_hold_with_the_shipped_defaults(terrain, bound):
    """Against the renderer's planar truth (distance along the surface); the paper's plane
    model on the same frames is several times worse."""
    local, results, _ = _drive(terrain, 'local')
    plane, _, _ = _drive(terrain, 'plane')
    assert all(r.status in ('first', 'ok') for r in results)
    assert local['t_rel_percent'] < bound, local
    assert local['t_rel_percent'] * 3 < plane['t_rel_percent'], (local, plane)



def test_a_crowned_road_holds_with_the_shipped_defaults():
    """A 2 % camber, the crown 1.75 m left of the path (the road beyond it bends away): within
    the issue's bars (t_rel 0.2 %, r_rel 1.5 deg/100 m) against the renderer's planar truth.
    Measured (100 frames, 376x240): 0.104 %, 0.97 deg/100 m (the plane model 0.30 %)."""
    local, results, _ = _drive('camber', 'local')
    assert all(r.status in ('first', 'ok') for r in results)
    assert local['t_rel_percent'] < 0.2, local
    assert local['r_rel_deg_per_100m'] < 1.5, local


# A car's camera 0.7 m up, 15 deg down: it sees the road from 0.5 m behind its front wheels.
LOW_CAR_MOUNT = synth.CameraMount(x=1.2, y=0.0, height=0.7, roll=0.0, pitch=np.radians(15.0),
                                  yaw=0.0)


# Measured (100 frames): 0.129 % (the plane model 1.19 %); bent from where the view begins
# (the wheels set 0.5 m inside it were taken not to be there, until stop 46), 0.367 %.
def test_a_car_whose_camera_sees_the_road_behind_its_front_wheels_holds_on_hills():
    """The road bends from the front wheels, also where the camera sees it from behind them:
    the road under the car is on the same surface."""
    local, results, _ = _drive('hills', 'local', mount=LOW_CAR_MOUNT)
    plane, _, _ = _drive('hills', 'plane', mount=LOW_CAR_MOUNT)
    assert all(r.status in ('first', 'ok') for r in results)
    assert local['t_rel_percent'] < 0.2, local
    assert local['t_rel_percent'] * 3 < plane['t_rel_percent'], (local, plane)


# Measured (100 frames, wheelbase 0, track 0.5 m; stop 51): hills 0.28 % (the plane model 2.4
# %); grades 0.26 % (0.96 %); with the surface through the axle's centre (before stop 36) 0.33 %
# and 0.31 %. 752x480, 300 frames at 30 Hz: flat 0.067, grades 0.10, hills 0.12 %.
def test_a_differential_drive_robot_holds_on_hills():
    """A low camera on a small robot: the local ground from its drive wheels on."""
    local, results, _ = _drive('hills', 'local', 'diff_drive')
    plane, _, _ = _drive('hills', 'plane', 'diff_drive')
    assert all(r.status in ('first', 'ok') for r in results)
    assert local['t_rel_percent'] < 0.5, local
    assert local['t_rel_percent'] * 3 < plane['t_rel_percent'], (local, plane)


# Measured (100 frames; stop 51): 0.38 % (its wheels set: 0.28 %, the plane model 2.4 %);
# before the road bent from where the camera sees it, 5.7 %. 752x480, 300 frames at 30 Hz:
# 0.23 %, 2.6 % before, its wheels set 0.12 %.
def test_a_robot_left_at_a_car_s_wheelbase_still_holds_on_hills():
    """The wheels configured 2.7 m ahead, beyond the camera's view of the ground (0.46-1.8 m
    ahead): the road is taken to bend from where it is seen, not from the wheels."""
    local, results, _ = _drive('hills', 'local', 'diff_drive', wheels_set=False)
    plane, _, _ = _drive('hills', 'plane', 'diff_drive')
    assert all(r.status in ('first', 'ok') for r in results)
    assert local['t_rel_percent'] < 0.8, local
    assert local['t_rel_percent'] * 3 < plane['t_rel_percent'], (local, plane)


@pytest.mark.parametrize('terrain', ['hills', 'grades', 'bumps', 'camber'])
def test_terrain_is_over_3x_better_than_the_plain_opencv_pipeline(terrain):
    """The same frames through the plain OpenCV pipeline (ground features, LK, homography,
    decomposition; ``plain_opencv_path``), both against the renderer's planar truth.
    Measured (100 frames, 376x240; stop 51): hills 0.18 vs 4.06 %, grades 0.14 vs 2.98 %,
    bumps 0.31 vs 4.05 %, camber 0.104 vs 1.82 %."""
    camera, mount, images, truth, _ = _render(terrain)
    ours, _, _ = _drive(terrain, 'local')
    params = config.validate(config.mounting_params(mount))
    opencv = metrics(plain_opencv_path(camera, params, images), truth)
    assert ours['t_rel_percent'] * 3 < opencv['t_rel_percent'], (ours, opencv)


def test_a_hill_s_trough_at_the_start_is_not_taken_for_the_camera_s_pitch():
    """Hills seed 2 starts in a trough: the road ahead rises as if the camera pitched down
    1.8 deg. The static pitch self-calibration learns must stay near the true mounting's
    (exact here) all along: it is read from the road under the wheels once the history
    holds it (measured in stop 51: at most 0.25 deg, t_rel 0.25 %; learned from the road ahead, as
    before: 1.84 deg, 0.50 %)."""
    camera = synth.SynthCamera.scaled(376, 240)
    renderer, traj = synth.render_scenario('default', 200, 2, rate=20.0, camera=camera,
                                           mounting=CAR_MOUNT, terrain='hills')
    params = config.validate(config.mounting_params(CAR_MOUNT))
    vo = VisualOdometry.from_params(synth_camera_model(renderer), params)
    poses, pitch = [], []
    for k in range(200):
        poses.append(vo.process(renderer.render_frame(traj, k), k / 20.0).pose)
        pitch.append(vo.ground.tilt_offset[1])
    assert np.degrees(np.max(np.abs(pitch))) < 0.5
    assert metrics(np.array(poses), np.c_[traj.x, traj.y, traj.yaw])['t_rel_percent'] < 0.3


def test_irregular_ground_is_reported_and_smooth_ground_is_not():
    """Speed bumps ahead make the surface jump (WARN, covariance inflated); a flat road and
    rolling hills (smooth, however curved) do not."""
    _, _, bumps = _drive('bumps', 'local')
    _, _, flat = _drive('flat', 'local')
    _, _, hills = _drive('hills', 'local')
    assert sum(bumps) >= 3  # measured 6 of 120 frames
    assert not any(flat) and not any(hills)


def test_long_low_bumps_hold_with_the_shipped_defaults():
    """Bumps 5 cm high and 1.5 m long (not the 8 cm x 0.7 m the defaults were tuned on): a
    wheel rises 2-4 cm a frame, less than a lift pitches the car. At 376x240 each drive is
    bimodal: a bump first seen at the far edge of the tracks is remembered by its near face,
    and the tracks past the window left out lie on the rest of it. Measured (150 frames,
    seeds 0-4, stop 51): 0.207, 0.232, 0.263, 0.213, 0.209 % (stop 39, 600 tracks: 0.425,
    0.183, 0.174, 0.153, 0.209; 400 tracks: 0.137, 0.185,
    0.628, 0.162, 0.329; 752x480, 300 frames, seeds 0-3: 0.116, 0.094, 0.099, 0.172, with 400
    tracks 0.192, 0.145, 0.172, 0.126). Since stop 58 (the vignetting divided out from 10 m):
    0.190, 0.283, 0.266, 0.329, 0.240 (from 3 m: mean 0.322; at 752x480 the bump drives
    gained)."""
    camera = synth.SynthCamera.scaled(376, 240)
    shape = TerrainShape.parse('bump_height=0.05,bump_length=1.5')
    t_rel = []
    for seed in range(5):
        renderer, traj = synth.render_scenario('default', 150, seed, rate=20.0, camera=camera,
                                               mounting=CAR_MOUNT, terrain='bumps',
                                               terrain_shape=shape)
        vo = VisualOdometry.from_params(synth_camera_model(renderer),
                                        config.validate(config.mounting_params(CAR_MOUNT)))
        poses = [vo.process(renderer.render_frame(traj, k), k / 20.0).pose
                 for k in range(150)]
        t_rel.append(metrics(np.array(poses), np.c_[traj.x, traj.y, traj.yaw])['t_rel_percent'])
    assert np.mean(t_rel) < 0.3 and max(t_rel) < 0.5, t_rel


def test_the_front_wheels_climb_of_a_bump_seen_ahead_is_read_as_it_happens():
    """On a short bumps drive (the issue's 752x480), while the renderer's front axle is on a
    bump the camera saw ahead, the front wheels' height comes out near the bump's 8 cm
    (measured: 57 and 69 mm on the two bumps climbed after the first 1.5 s). A bump is placed
    at its band's centre, past the bump: with the wheels on it only while it read up to 0.6 m
    ahead of the axle (before stop 37) the climb was missed (0 mm). At 376x240 the bump's band
    is found or missed as the image pipeline changes (stop 59): one bump decided the test."""
    camera = synth.SynthCamera.scaled(752, 480)
    renderer, traj = synth.render_scenario('default', 100, 0, rate=20.0, camera=camera,
                                           mounting=CAR_MOUNT, terrain='bumps')
    vo = VisualOdometry.from_params(synth_camera_model(renderer),
                                    config.validate(config.mounting_params(CAR_MOUNT)))
    heights = []
    for k in range(100):
        vo.process(renderer.render_frame(traj, k), k / 20.0)
        heights.append(vo.ground.ahead.bumps.front_height)
    pose = traj.pose3d
    front_x = (pose.position + pose.rotation @ np.array([vo.ground.wheelbase, 0.0, 0.0]))[:, 0]
    bumps = renderer.terrain
    on = [np.flatnonzero(np.abs(front_x - c) < bumps.length / 2) for c in bumps.centres]
    read = [max(heights[k] for k in frames) for frames in on if len(frames) and frames[0] > 30]
    assert len(read) == 2, read
    assert read == pytest.approx([bumps.amplitude] * len(read), rel=0.5), read


# Measured (the camera at 10 Hz, all four terrains, sprung, 150 frames): seed 551
# 0.458 -> 0.142 % t_rel since a band waiting for its confirmation is left out of the fit;
# seeds 536, 552, 553: 0.364 / 0.315 / 0.294 -> 0.167 / 0.281 / 0.248 (plain OpenCV on seed
# 536: 51 %). Here at 376x240 for its cost (the renderer's terrain is slow): the first 50
# frames of seed 551 +176 -> -22 mm of distance over 23.5 m (752x480: +99 -> +29 mm); of seed
# 536 +215 -> +200 mm (its error at this size lies elsewhere).
def test_a_10_hz_camera_leaves_a_bump_s_first_band_out_of_the_fit_where_hills_curve_the_road():
    """At 10 Hz a car moves 0.6 m a frame and its tracks see 2 m of road: a bump is in view
    for three pairs. Where hills curve the road its first band only waits for a later pair's
    to confirm it; fitted meanwhile, its tracks bent the surface onto the bump, the next pair
    was too curved to be searched, and the wheels crossed it in the fit (+20 to +40 mm a pair)."""
    frames = 50
    camera = synth.SynthCamera.scaled(376, 240, dist=(-0.28, 0.07, 0.0005, -0.0005, 0.0))
    renderer, traj = synth.render_scenario(
        'default', frames, 551, rate=10.0, camera=camera, mounting=CAR_MOUNT, terrain='all',
        suspension=synth.Suspension.degrees(1.0, 0.6, 0.015))
    vo = VisualOdometry.from_params(synth_camera_model(renderer),
                                    config.validate(config.mounting_params(CAR_MOUNT)))
    poses = np.array([vo.process(renderer.render_frame(traj, k), k / 10.0).pose
                      for k in range(frames)])

    def length(p):
        return np.hypot(*np.diff(p[:, :2], axis=0).T).sum()

    truth = length(np.c_[traj.x, traj.y])
    assert abs(length(poses) - truth) < 0.003 * truth, (length(poses), truth)


@pytest.mark.parametrize('terrain', ['hills', 'grades', 'bumps'])
def test_the_twist_covariance_holds_its_error_on_terrain(terrain):
    """NEES of the published twist against the renderer's twist at the stamp (measured in
    stop 51: hills 1.67, grades 2.06, bumps 2.7; bumps 12.2 before a lifted wheel entered the
    covariance; 3 is ideal)."""
    _, results, _ = _drive(terrain, 'local')
    twist = _render(terrain)[4]
    values = [float((r.twist - twist[k]) @ np.linalg.solve(r.twist_covariance,
                                                           r.twist - twist[k]))
              for k, r in enumerate(results) if r.estimated and k > 1]
    assert len(values) >= 95
    assert 1.0 <= np.mean(values) <= 6.0, np.mean(values)


@pytest.mark.parametrize('mount, wheelbase, advised', [
    (ROBOT_MOUNT, None, True), (ROBOT_MOUNT, 0.0, False), (CAR_MOUNT, None, False),
    (LOW_CAR_MOUNT, None, False)])
def test_wheels_set_inside_the_camera_view_get_advice(mount, wheelbase, advised):
    """A small robot left at a car's wheelbase is told what to set and the road bends from
    where its view begins; a car (a low camera too: it sees the road from 1.7 m ahead of
    base_link, to 4.5 m) or a robot set right is not, and the road bends from its wheels.
    The view's near edge computed here from the pinhole (no distortion)."""
    K = np.array([[300.0, 0.0, 320.0], [0.0, 300.0, 240.0], [0.0, 0.0, 1.0]])
    camera = CameraModel(K, np.zeros(5), 'plumb_bob', 640, 480)
    wheels = {} if wheelbase is None else {'wheelbase': wheelbase}
    vo = VisualOdometry.from_params(camera, config.validate(
        {**config.mounting_params(mount), **wheels}))
    advice = vo.mounting_diagnostics()[1]
    assert ('wheelbase' in advice) == advised, advice
    assert (vo.ground.hinge != vo.ground.wheelbase) == advised
    if advised:
        # The bottom row looks 20 + atan(240 / 300) = 58.7 deg down from 0.35 m: 0.21 m
        # ahead of the camera, 0.36 m ahead of base_link.
        assert 'from 0.36 m' in advice['wheelbase'], advice


@pytest.mark.parametrize('x, yaw, advised', [
    (-0.9, np.pi, 'turned 180 deg'), (1.0, -np.pi / 2, 'turned 90 deg'),
    (1.0, np.radians(30.0), 'turned 30 deg'), (1.2, np.radians(20.0), None)])
def test_a_camera_turned_away_from_ahead_is_told_what_the_local_ground_cannot_do(x, yaw,
                                                                                  advised):
    """Not the wheelbase (a camera looking back sees the ground from behind the rear axle,
    which moves the hinge there): the ground model, which expects the road the wheels will
    drive on (rendered flat drives: 20 deg as good as ahead, 30 deg worse than the plane)."""
    K = np.array([[460.0, 0.0, 376.0], [0.0, 460.0, 240.0], [0.0, 0.0, 1.0]])
    camera = CameraModel(K, np.zeros(5), 'plumb_bob', 752, 480)
    turned = dataclasses.replace(CAR_MOUNT, x=x, yaw=yaw)
    advice = VisualOdometry.from_params(camera, config.validate(
        config.mounting_params(turned))).mounting_diagnostics()[1]
    if advised is None:
        assert advice == {}, advice
    else:
        assert list(advice) == ['ground_model'] and advised in advice['ground_model'], advice
    plane = VisualOdometry.from_params(camera, config.validate(
        {**config.mounting_params(turned), 'ground_model': 'plane'}))
    assert plane.mounting_diagnostics()[1] == {}


def test_a_mounting_changed_at_run_time_keeps_the_vehicle_s_wheels():
    """The local ground is rebuilt for the new mounting with the configured wheels and lane
    (it once came back with no track and every track in the surface), and a robot's wheels
    set beyond the middle of the camera's view still bend the road from where it begins."""
    K = np.array([[300.0, 0.0, 320.0], [0.0, 300.0, 240.0], [0.0, 0.0, 1.0]])
    camera = CameraModel(K, np.zeros(5), 'plumb_bob', 640, 480)
    vo = VisualOdometry.from_params(camera, config.validate(
        {**config.mounting_params(ROBOT_MOUNT), 'track_width': 1.2, 'surface_half_width': 2.0}))
    before = vo.ground.hinge
    moved = {**config.mounting_params(ROBOT_MOUNT), 'camera_x': ROBOT_MOUNT.x + 0.1}
    vo.set_mounting(config.mounting_from_params(moved))
    ground = vo.ground
    assert (ground.wheelbase, ground.track, ground.half_width) == (2.7, 1.2, 2.0)
    # The view moved 0.1 m forward with the camera: 0.36 -> 0.46 m ahead of base_link.
    assert ground.hinge == pytest.approx(before + 0.1) and before == pytest.approx(0.36, abs=0.01)


def test_the_far_tracks_are_left_out_only_where_the_ground_ahead_bends():
    """The surface ahead is a quadratic: on hills it holds only so far, and the tracks past
    that reach are left out; on a flat road they stay (they hold the yaw best). Against the
    renderer's terrain (measured: flat 0 of 99 pairs cut, hills 88 of 99)."""
    share = {}
    for terrain in ('flat', 'hills'):
        camera, mount, images, _, _ = _render(terrain)
        vo = VisualOdometry.from_params(camera, config.validate(config.mounting_params(mount)))
        reach, said = [], set()
        for k, image in enumerate(images):
            reach.append(vo.ground.reach())  # what the pair about to be estimated may use
            vo.process(image, k / 20.0)
            said.add(vo.diagnostics()['tracks used up to (m ahead)'])
        share[terrain] = np.mean(np.isfinite(reach[1:]))
        if terrain == 'flat':
            assert said == {'all'}, said
        else:  # /diagnostics says so; at least three quarters of the tracks are kept
            assert min(float(x) for x in said - {'all'}) >= 4.1, said
    assert share['flat'] == 0.0, share
    assert share['hills'] > 0.6, share




def test_the_road_s_history_is_sampled_where_a_far_looking_view_begins():
    """A camera whose view begins 1.05 m past the front wheels (a windshield's): after a pair
    the road's history holds the road from 0.5 m into that view (moved back by the step), not
    from 0.5 m past the wheels, where it saw nothing; a view that begins before the wheels is
    sampled from 0.5 m past them."""
    rng = np.random.default_rng(3)
    x, y = rng.uniform(3.8, 6.0, 300), rng.uniform(-2.0, 2.0, 300)
    step = np.array([0.3, 0.0, 0.0])
    m1, m2 = _observe(np.c_[x, y, np.zeros_like(x)], MOUNT, step, np.zeros(2))
    model = TransferModel(*MOUNT.ground_to_optical(), 500.0, MOUNT)
    for near, first in ((HINGE + 1.05, HINGE + 1.55), (HINGE - 0.3, HINGE + 0.5)):
        ground = LocalGroundFilter(MOUNT, rates=np.array([0.5, 0.5, 0.3]), wheelbase=HINGE,
                                   self_calibrate=False)
        ground.see_ground((near, 12.0))
        start = RansacResult(step + [0.01, 0.0, 0.0], np.eye(3) * 1e-4,
                             np.ones(len(x), bool), 1, 0.3)
        result, _ = ground.refine(start, np.c_[m1, np.ones(len(m1))], m2, MOUNT, model,
                                  dt=0.05, inlier_threshold=2.0, start_threshold=8.0,
                                  min_inliers=10)
        ground.advance(result.motion)
        np.testing.assert_allclose(ground.profile.points[:, 0],
                                   first + np.arange(4.0) - result.motion[0], atol=1e-6)
