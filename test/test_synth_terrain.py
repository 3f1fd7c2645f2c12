"""Terrain in the synthetic bags: height fields, the vehicle on its wheels, the ray caster,
the 3D and planar truth, and the command line. Closed forms wherever there is one."""

import ast
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from planar_vo import synth
from planar_vo.io.bag import open_reader
from planar_vo.synth import terrain as terrain_mod
from planar_vo.synth.terrain import TerrainShape

PINHOLE = synth.SynthCamera(width=320, height=240, fx=230.0, fy=230.0, cx=160.0, cy=120.0,
                            dist=(0.0, 0.0, 0.0, 0.0, 0.0))
SMALL = synth.SynthCamera.scaled(160, 120)


def default_path(frames=300, rate=20.0):
    traj = synth.make_trajectory(synth.SCENARIOS['default'], frames, rate, 0)
    return traj.x, traj.y


# --------------------------------------------------------------------------------------------
# Height fields
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize('kind', sorted(synth.TERRAIN_KINDS))
def test_gradient_is_the_derivative_of_the_height_and_bounds_hold(kind):
    ground = synth.make_terrain(kind, 0, *default_path())
    rng = np.random.default_rng(0)
    x, y = rng.uniform(-5, 90, 4000), rng.uniform(-25, 20, 4000)
    e = 1e-6
    gx, gy = ground.gradient(x, y)
    np.testing.assert_allclose(gx, (ground.height(x + e, y) - ground.height(x - e, y)) / (2 * e),
                               atol=1e-7)
    np.testing.assert_allclose(gy, (ground.height(x, y + e) - ground.height(x, y - e)) / (2 * e),
                               atol=1e-7)
    for cx, cy in ((0.0, 0.0), (40.0, -5.0)):
        lo, hi = ground.bounds(cx, cy, 30.0)
        inside = np.hypot(x - cx, y - cy) < 30.0
        h = ground.height(x[inside], y[inside])
        assert lo <= h.min() and h.max() <= hi
    assert ground.flat == (kind == 'flat')


def test_terrain_features_have_the_documented_sizes():
    grades = synth.Grades.random(0)
    g = grades.grade(np.linspace(0, 300, 30001))
    assert np.abs(g).max() <= 0.04 and np.abs(g).max() > 0.03
    assert np.all(g[:800] == 0)  # flat for the first 8 m
    changes = np.array(grades.knots_x[1::2])  # starts of the vertical curves
    assert 12.0 <= np.diff(changes).min() and np.diff(changes).max() <= 18.0
    bumps = synth.Bumps.random(0)
    assert bumps.amplitude == 0.08 and 0.5 <= bumps.length <= 1.0
    assert 10.0 <= np.diff(bumps.centres).min() and np.diff(bumps.centres).max() <= 14.0
    assert float(bumps.height(bumps.centres[2], 3.0)) == pytest.approx(0.08)
    hills = synth.Hills.random(0)
    h = hills.height(*np.meshgrid(np.linspace(0, 40, 200), np.linspace(-20, 20, 200)))
    assert 0.25 < h.max() <= 0.3 and -0.3 <= h.min() < -0.25
    camber = synth.Camber.along(*default_path())
    # on the path (1.75 m right of the crown) the road falls off to the right at 2 %
    x, y = default_path()
    gx, gy = camber.gradient(x, y)
    yaw = synth.make_trajectory(synth.SCENARIOS['default'], 300, 20.0, 0).yaw
    across = -gx * np.sin(yaw) + gy * np.cos(yaw)  # the slope towards base_link's left
    np.testing.assert_allclose(across, 0.02, atol=5e-4)
    np.testing.assert_allclose(camber.height(x, y), -0.02 * 1.75, atol=2e-3)


def test_other_shapes_have_their_sizes():
    shape = TerrainShape.parse('bump_height=0.1,bump_length=0.5,max_grade=0.06,camber=0.03,'
                               'hill_amplitude=0.5,hill_wavelength=30')
    grades, bumps, camber, hills = synth.make_terrain('all', 0, *default_path(),
                                                      shape=shape).parts
    g = grades.grade(np.linspace(0, 300, 30001))
    assert np.abs(g).max() <= 0.06 and np.abs(g).max() > 0.045
    centre = bumps.centres[2]
    assert float(bumps.height(centre, 3.0)) == pytest.approx(0.1)
    assert float(bumps.height(centre + 0.26, 3.0)) < 1e-12  # 0.5 m long
    assert float(bumps.height(centre + 0.24, 3.0)) > 0.0
    x = np.linspace(0, 60, 600)
    h = hills.height(*np.meshgrid(x, x - 30))
    assert 0.45 < h.max() <= 0.5
    spectrum = np.abs(np.fft.rfft(hills.height(x, 0 * x) - hills.height(x, 0 * x).mean()))
    # the waves cross x at +-30 deg: along x their period is 30 m / cos(30 deg)
    assert np.fft.rfftfreq(x.size, x[1] - x[0])[spectrum.argmax()] == pytest.approx(
        np.cos(np.radians(30)) / 30, abs=1 / 60)
    px, py = default_path()
    gx, gy = camber.gradient(px, py)
    yaw = synth.make_trajectory(synth.SCENARIOS['default'], 300, 20.0, 0).yaw
    np.testing.assert_allclose(-gx * np.sin(yaw) + gy * np.cos(yaw), 0.03, atol=7e-4)
    # the defaults are the documented kinds, bit for bit
    assert synth.make_terrain('all', 0, px, py, shape=TerrainShape()) == \
        synth.make_terrain('all', 0, px, py)


def test_a_scene_rides_the_terrain_of_its_shape():
    renderer, traj = synth.render_scenario(
        'straight', 40, 0, rate=10.0, camera=synth.SynthCamera.scaled(160, 120),
        terrain='bumps', obstacles=False,
        terrain_shape=TerrainShape(bump_height=0.12, bump_length=0.5))
    assert renderer.terrain.amplitude == 0.12 and renderer.terrain.length == 0.5
    # the rear axle rides up to the bump's top (10 m, where the first one is)
    over = np.abs(traj.pose3d.position[:, 0] - 10.0) < 0.3
    assert np.any(over) and traj.pose3d.position[over, 2].max() > 0.08


@pytest.mark.parametrize('text, message', [
    ('bump_height=0.5', 'outside [0, 0.2]'), ('kerb=1', 'NAME one of bump_height'),
    ('camber=x', 'not a number'), ('', 'at least one')])
def test_terrain_shape_errors_say_what_is_wrong(text, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        TerrainShape.parse(text)


def test_camber_needs_a_path_along_x():
    t = np.linspace(0, math.pi, 100)
    with pytest.raises(synth.TerrainError, match='turns'):
        synth.Camber.along(10 * np.sin(t), 10 - 10 * np.cos(t))
    with pytest.raises(synth.TerrainError, match='unknown terrain'):
        synth.make_terrain('moon')


# --------------------------------------------------------------------------------------------
# The ray caster: closed forms
# --------------------------------------------------------------------------------------------


def random_rays(n, seed=1):
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(3, n))
    d[2] = -np.abs(d[2]) * 0.3 + 0.02  # mostly down, some slightly up
    return d / np.linalg.norm(d, axis=0)


@pytest.mark.parametrize('plane', [synth.Plane(0.04, 0.0), synth.Plane(-0.03, 0.02, 0.1),
                                   synth.Plane(0.0, 0.0, 0.0)])
def test_rays_hit_a_constant_grade_where_the_ray_plane_intersection_says(plane):
    origin = np.array([3.0, -2.0, 1.1 + float(plane.height(3.0, -2.0))])
    d = random_rays(20000)
    t, hit = synth.intersect(plane, origin, d, 60.0)
    # ray-plane intersection: oz + t dz = z0 + gx (ox + t dx) + gy (oy + t dy)
    tc = ((origin[2] - plane.z0 - plane.gx * origin[0] - plane.gy * origin[1])
          / (plane.gx * d[0] + plane.gy * d[1] - d[2]))
    expected = (tc > 0) & (tc * np.hypot(d[0], d[1]) < 60.0)
    assert expected.sum() > 10000 and (~expected).sum() > 1000
    np.testing.assert_array_equal(hit, expected)
    np.testing.assert_allclose(t[hit], tc[hit], rtol=0, atol=1e-6)
    assert np.all(np.isinf(t[~hit]))


def test_a_level_ray_below_the_top_of_a_bump_hits_its_front_face():
    """A level ray at height z < A hits A cos^2(pi u / L) = z at u = -(L / pi) acos(sqrt(z/A))
    before the crest; above the crest it misses (no other ground in range)."""
    bump = synth.Bumps((5.0,), amplitude=0.08, length=0.7)
    for z in (0.01, 0.04, 0.07):
        t, hit = synth.intersect(bump, (0.0, 0.0, z), np.array([[1.0], [0.0], [0.0]]), 20.0)
        expected = 5.0 - 0.7 / math.pi * math.acos(math.sqrt(z / 0.08))
        assert hit[0] and t[0] == pytest.approx(expected, abs=1e-6)
    _, hit = synth.intersect(bump, (0.0, 0.0, 0.09), np.array([[1.0], [0.0], [0.0]]), 20.0)
    assert not hit[0]


def test_the_first_hit_is_found_when_a_ray_crosses_the_surface_several_times():
    """Descending rays over bumps on a grade and hills: the hit is a root of f, and a brute
    force march in 1 mm steps finds no earlier one."""
    ground = synth.Composite((synth.Bumps((4.0, 6.5, 9.0), length=0.6), synth.Plane(0.02, 0.0),
                              synth.Hills(amplitude=0.3, wavelength=8.0)))
    origin = np.array([0.0, 0.3, 0.6])
    pitch = np.radians(np.linspace(1.0, 12.0, 60))
    d = np.stack([np.cos(pitch), np.zeros_like(pitch), -np.sin(pitch)])
    t, hit = synth.intersect(ground, origin, d, 30.0)
    assert hit.all()
    p = origin[:, None] + t * d
    np.testing.assert_allclose(p[2], ground.height(p[0], p[1]), atol=2e-5)
    for k in range(d.shape[1]):
        s = np.arange(0.0, t[k] - 2e-3, 1e-3)
        q = origin[:, None] + s * d[:, k:k + 1]
        assert np.all(q[2] > ground.height(q[0], q[1])), k


def test_a_dot_on_a_grade_is_rendered_where_the_pinhole_projects_it():
    """render_world: a bright dot on a 4 % grade (and a 2 % cross-slope), seen from a tilted
    camera, lands at K R^T (P - C) (within 0.2 px)."""
    texel, size, centre = 0.01, 1024, 300
    yy, xx = np.mgrid[0:size, 0:size]
    dot = 250 * np.exp(-((xx - centre) ** 2 + (yy - centre) ** 2) / (2 * 6.0 ** 2))
    textures = synth.Texture(dot, texel), synth.Texture(np.zeros_like(dot), texel)
    plane = synth.Plane(0.04, -0.02, 0.3)
    world = np.array([(centre + 0.5) * texel] * 2)
    point = np.array([*world, float(plane.height(*world))])
    position = point + np.array([-4.0, 0.8, 1.2])
    rotation = synth.rotation_rpy(0.03, math.radians(12.0), -0.1) @ synth.BODY_FROM_OPTICAL
    images = []
    for tex in textures:
        r = synth.Renderer(PINHOLE, synth.CameraMount(height=1.0), tex, noise_sigma=0,
                           illumination=False, haze=False, max_range=15, terrain=plane)
        r.vignette[:] = 1
        images.append(r.render_world(0, position, rotation).astype(float))
    w = np.clip(images[0] - images[1], 0, None)
    w[w < 20] = 0
    vs, us = np.mgrid[0:w.shape[0], 0:w.shape[1]]
    got = np.array([(w * us).sum() / w.sum(), (w * vs).sum() / w.sum()])
    expected = PINHOLE.project((rotation.T @ (point - position))[None])[0]
    np.testing.assert_allclose(got, expected, atol=0.2)


# --------------------------------------------------------------------------------------------
# The vehicle on its wheels, the 3D and the planar truth
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize('vehicle', ['car', 'diff_drive'])
def test_wheels_on_a_plane_give_its_pitch_and_roll(vehicle):
    chassis = synth.CHASSIS[vehicle]
    heading = np.array([0.0, 0.0, math.pi / 2])
    plane = synth.Plane(0.04, 0.02, 0.5)
    z, pitch, roll, _ = synth.settle(plane, chassis, np.array([1.0, 2.0, 3.0]),
                                        np.array([0.0, -1.0, 4.0]), heading)
    np.testing.assert_allclose(z, plane.height([1.0, 2.0, 3.0], [0.0, -1.0, 4.0]), atol=1e-12)
    # heading +x: uphill ahead (nose up: pitch < 0), left side up (roll > 0)
    np.testing.assert_allclose(pitch[:2], -math.atan(0.04), atol=1e-9)
    r = synth.rotation_rpy(roll[0], pitch[0], 0.0)
    normal = np.array([-0.04, -0.02, 1.0]) / math.sqrt(1 + 0.04 ** 2 + 0.02 ** 2)
    np.testing.assert_allclose(r[:, 2], normal, atol=1e-9)  # base_link z is the plane normal
    # heading +y: the 2 % is uphill ahead, the 4 % rises to the right (roll < 0)
    r = synth.rotation_rpy(roll[2], pitch[2], heading[2])
    np.testing.assert_allclose(r[:, 2], normal, atol=1e-9)
    assert pitch[2] < 0 and roll[2] < 0


def test_a_bump_under_the_front_wheels_lifts_the_nose_and_one_under_the_left_rolls_right():
    car = synth.CHASSIS['car']
    bump = synth.Bumps((2.7,), amplitude=0.08, length=0.7)  # under the front axle at x = 0
    z, pitch, roll, _ = synth.settle(bump, car, np.array([0.0]), np.array([0.0]),
                                        np.array([0.0]))
    assert z[0] == pytest.approx(0.0, abs=1e-12) and roll[0] == pytest.approx(0.0, abs=1e-12)
    assert pitch[0] == pytest.approx(-math.asin(0.08 / 2.7), abs=1e-4)
    side = synth.Bumps((0.8,), amplitude=0.08, length=0.7)  # along world x: heading +y
    _, pitch, roll, _ = synth.settle(side, car, np.array([0.0]), np.array([0.0]),
                                        np.array([-math.pi / 2]))
    # heading -y: the left wheels are at x = +0.8, on the bump's crest
    assert roll[0] == pytest.approx(math.asin(0.04 * 2 / 1.6), abs=2e-3)


def straight_on(ground, frames=60, rate=20.0, vehicle='car'):
    return synth.ride_over(synth.SCENARIOS['straight'], ground, frames, rate, 0, vehicle)


@pytest.mark.parametrize('grade', [0.04, -0.03, 0.08])
def test_planar_truth_on_a_constant_grade_is_the_distance_along_the_surface(grade):
    """Straight up a constant grade at 5 m/s: the planar truth advances 5 m/s (along the
    surface) while the world position advances 5 / sqrt(1 + g^2) m/s horizontally."""
    traj = straight_on(synth.Plane(grade, 0.0))
    flat = synth.make_trajectory(synth.SCENARIOS['straight'], 60, 20.0, 0)
    np.testing.assert_allclose(traj.x, flat.x, atol=1e-9)
    np.testing.assert_allclose(traj.x, 5.0 * traj.t, atol=1e-9)
    assert np.all(traj.y == 0) and np.all(traj.yaw == 0)
    p = traj.pose3d.position
    np.testing.assert_allclose(p[:, 0], 5.0 * traj.t / math.sqrt(1 + grade ** 2), atol=1e-9)
    np.testing.assert_allclose(p[:, 2], grade * p[:, 0], atol=1e-12)
    np.testing.assert_allclose(traj.pose3d.rpy[1], -math.atan(grade), atol=1e-12)
    np.testing.assert_allclose(traj.v, 5.0, atol=1e-9)
    np.testing.assert_allclose(traj.pose3d.linear[:, 1:], 0.0, atol=1e-9)


def test_planar_truth_on_a_tilted_plane_follows_the_drive_profile():
    """On any plane the body's planar motion is the bicycle model's (speed along the surface,
    yaw rate about base_link z): the planar truth is the flat one, turns included."""
    traj = synth.ride_over(synth.SCENARIOS['car'], synth.Plane(0.03, -0.04), 200, 20.0, 1)
    flat = synth.make_trajectory(synth.SCENARIOS['car'], 200, 20.0, 1)
    assert np.ptp(flat.yaw) > 0.3
    np.testing.assert_allclose(np.c_[traj.x, traj.y], np.c_[flat.x, flat.y], atol=1e-3)
    np.testing.assert_allclose(traj.yaw, flat.yaw, atol=2e-5)
    np.testing.assert_allclose(traj.v, flat.v, atol=1e-4)
    np.testing.assert_allclose(traj.omega, flat.omega, atol=1e-4)


def test_planar_truth_does_not_depend_on_the_frame_rate():
    ground = synth.make_terrain('all', 0, *default_path())
    a = synth.ride_over(synth.SCENARIOS['default'], ground, 61, 15.0, 0)
    b = synth.ride_over(synth.SCENARIOS['default'], ground, 81, 20.0, 0)
    # the same instants (every second): the fine grids differ (1.96 ms and 2 ms)
    pa, pb = np.c_[a.x, a.y, a.yaw][::15], np.c_[b.x, b.y, b.yaw][::20]
    np.testing.assert_allclose(pa, pb, atol=2e-4)
    np.testing.assert_allclose(a.pose3d.position[::15], b.pose3d.position[::20], atol=2e-4)


def test_truth_over_bumps_is_shorter_than_the_wheel_distance():
    """Over a bump the axle moves along base_link z too: the planar truth (base_link's x, y)
    loses that, the wheel distance does not; between bumps the two advance alike."""
    traj = straight_on(synth.Bumps.random(0), frames=120)
    wheel = 5.0 * traj.t
    assert np.all(traj.x <= wheel + 1e-9)
    loss = wheel[-1] - traj.x[-1]
    assert 0.002 < loss < 0.1, loss
    z = traj.pose3d.position[:, 2]
    assert z.max() > 0.07 and np.abs(traj.pose3d.rpy[1]).max() > math.radians(1.0)


def test_a_diff_drive_robot_pitches_more_than_a_car_over_the_same_bumps():
    ground = synth.Bumps.random(0)
    car, robot = (straight_on(ground, 120, 20.0, v) for v in ('car', 'diff_drive'))
    assert np.abs(robot.pose3d.rpy[1]).max() > 3 * np.abs(car.pose3d.rpy[1]).max()


def test_flat_terrain_and_either_vehicle_give_todays_trajectory_and_images():
    plain, traj = synth.render_scenario('car', 4, seed=2, camera=SMALL)
    for vehicle in ('car', 'diff_drive'):
        r, t = synth.render_scenario('car', 4, seed=2, camera=SMALL, terrain='flat',
                                     vehicle=vehicle)
        assert t.pose3d is None and r.terrain.flat
        for name in ('t', 'x', 'y', 'yaw', 'v', 'omega', 'steer', 'accel'):
            np.testing.assert_array_equal(getattr(t, name), getattr(traj, name))
        np.testing.assert_array_equal(t.camera.position, traj.camera.position)
        for k in range(4):
            np.testing.assert_array_equal(r.render_frame(t, k), plain.render_frame(traj, k))


def test_the_camera_rides_the_terrain_and_the_body():
    """On terrain the camera pose of each frame is base_link's 3D pose composed with the
    sprung body's camera pose; the renderer sees exactly that."""
    renderer, traj = synth.render_scenario('road', 30, seed=0, camera=SMALL, noise_sigma=0.0)
    assert traj.pose3d is not None and traj.body is not None
    k = 17
    rot, pos = traj.pose3d.rotation[k], traj.pose3d.position[k]
    expected = renderer.render_world(k, pos + rot @ traj.camera.position[k],
                                     rot @ traj.camera.base_from_optical(k))
    np.testing.assert_array_equal(renderer.render_frame(traj, k), expected)
    height = traj.camera.position[:, 2]
    ground = renderer.terrain.height(traj.pose3d.position[:, 0], traj.pose3d.position[:, 1])
    assert np.all(traj.pose3d.position[:, 2] - ground < 0.1)  # on the surface, roughly
    assert np.ptp(height) > 0.005  # the body bounces


# --------------------------------------------------------------------------------------------
# Bags and the command line
# --------------------------------------------------------------------------------------------


def read(path):
    with open_reader(path) as reader:
        return [(c.topic, reader.deserialize(raw, c.msgtype)) for c, _, raw in reader.messages()]


def test_terrain_bag_has_the_3d_truth_and_records_the_terrain(tmp_path):
    rc = synth.main([str(tmp_path / 'b'), '--terrain', 'hills', '--vehicle', 'diff_drive',
                     '--frames', '3', '--width', '160', '--height', '120', '--quiet',
                     '--params-out', str(tmp_path / 'p.yaml'), '--rate', '2'])
    assert rc == 0
    msgs = read(tmp_path / 'b')
    pose3d = [m for t, m in msgs if t == synth.POSE3D_TOPIC]
    odom = [m for t, m in msgs if t == synth.ODOM_TOPIC]
    assert len(pose3d) == len(odom) == 3
    assert (pose3d[0].header.frame_id, pose3d[0].child_frame_id) == ('world', 'base_link')
    assert all(m.pose.pose.position.z == 0.0 for m in odom)
    _, traj = synth.render_scenario('default', 3, 0, rate=2.0, camera=SMALL, terrain='hills',
                                    vehicle='diff_drive')
    last = pose3d[-1].pose.pose
    np.testing.assert_allclose([last.position.x, last.position.y, last.position.z],
                               traj.pose3d.position[-1])
    assert last.position.z != 0.0 and last.orientation.y != 0.0  # on a hill
    q = last.orientation
    np.testing.assert_allclose(math.hypot(math.hypot(q.x, q.y), math.hypot(q.z, q.w)), 1.0)
    meta = yaml.safe_load((tmp_path / 'b' / 'metadata.yaml').read_text())
    record = json.loads(meta['rosbag2_bagfile_information']['custom_data']['planar_vo_synth'])
    assert record['terrain']['kind'] == 'hills' and record['vehicle'] == 'diff_drive'
    text = (tmp_path / 'p.yaml').read_text()
    assert '"hills"' in text and yaml.safe_load(text)['planar_vo']['ros__parameters']


def test_flat_bags_have_no_3d_topic(tmp_path):
    synth.generate_bag(tmp_path / 'f', 'default', 2, camera=SMALL)
    assert synth.POSE3D_TOPIC not in {t for t, _ in read(tmp_path / 'f')}


@pytest.mark.parametrize('args, message', [
    (['--terrain', 'moon'], "invalid choice: 'moon'"),
    (['--vehicle', 'bike'], "invalid choice: 'bike'"),
    (['--terrain-shape', 'bump_height=0.5'], 'bump_height=0.5 is outside [0, 0.2]'),
])
def test_cli_terrain_errors_are_one_line(tmp_path, args, message, capsys):
    with pytest.raises(SystemExit) as exc:
        synth.main([str(tmp_path / 'x'), *args])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]


def test_cli_help_lists_terrains_and_vehicles(capsys):
    with pytest.raises(SystemExit):
        synth.main(['--help'])
    out = capsys.readouterr().out
    for word in ('--terrain', '--vehicle', 'grades', 'bumps', 'camber', 'hills', 'all',
                 'diff_drive', 'pose3d', '--terrain-shape', 'bump_height'):
        assert word in out


def test_profiles_belong_to_their_modules_and_scenarios_import_them():
    """No import cycle: vehicle, scene, terrain, ride and render never import scenarios."""
    root = Path(synth.__file__).parent
    for name in ('vehicle', 'scene', 'terrain', 'ride', 'render', 'raycast', 'mount', 'lens'):
        tree = ast.parse((root / f'{name}.py').read_text())
        imported = {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
        imported |= {a.name for n in ast.walk(tree) if isinstance(n, ast.Import)
                     for a in n.names}
        assert 'planar_vo.synth.scenarios' not in imported, name
        assert not any(m and m.startswith('planar_vo.core') for m in imported), name
    sc = synth.SCENARIOS['tight']
    assert isinstance(sc.drive, synth.DriveProfile) and sc.steer == sc.drive.steer == 0.35
    assert isinstance(sc.obstacles, synth.ObstacleProfile) and sc.obstacles_per_100m == 4.0
    assert terrain_mod.TERRAIN_KINDS.keys() == {'flat', 'grades', 'bumps', 'camber', 'hills',
                                                'all'}
