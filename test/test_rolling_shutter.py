"""Rolling-shutter cameras: the renderer's per-row poses, the model, and the learned readout."""

import csv
import json
import subprocess
from pathlib import Path

import numpy as np
import pytest

from planar_vo import synth
from planar_vo.core import config
from planar_vo.core.estimation import rolling_shutter
from planar_vo.core.estimation.ransac import TransferModel, estimate_motion, transfer_errors
from planar_vo.core.estimation.rolling_shutter import ShutterModel, accelerated, at_stamp
from planar_vo.core.geometry.camera import Mounting, rays_through
from planar_vo.core.geometry.se2 import circular_motion, power, twist_motion
from planar_vo.core.metrics import metrics
from planar_vo.core.odometry.deskew import Deskew
from planar_vo.core.odometry.ground_filter import LocalGroundFilter
from planar_vo.core.odometry.shutter_learning import ShutterLearning
from planar_vo.io import resources
from planar_vo.synth.shutter import RollingShutter, RowPoses
from planar_vo.tools import replay

from .conftest import move_points, observe, run_scenario


def test_power_is_the_twist_held_longer():
    motion = circular_motion(0.1, 0.4)
    twist = np.array([0.4 * 0.05 / np.sin(0.05), 0.0, 0.1])  # the arc's speed over 1 s
    for s in (0.0, 0.7, 1.0, 1.3):
        np.testing.assert_allclose(power(motion, s), twist_motion(twist, s), atol=1e-12)


def test_readout_on_surface_is_the_least_squares_readout_with_the_rest_free():
    """Residuals linear in K parameters and the readout, offset from a solution at T = 12 ms
    and parameters a: one step from T = 0 lands on the least-squares readout whatever a (they
    are marginalised); from the solution itself, the variance is a least-squares fit's of the
    known noise."""
    rng = np.random.default_rng(3)
    k, n, truth, sigma = 4, 300, 0.012, 1e-3
    J = rng.normal(size=(k, 2, n))
    column = rng.normal(size=(2, n))
    noise = rng.normal(scale=sigma, size=(2, n))
    design = np.concatenate([J, column[None]]).reshape(k + 1, -1).T

    def residuals_from(a):
        def residuals(readout):
            r = np.tensordot(a, J, axes=1) + column * (readout - truth) + noise
            return r, J, np.ones(n)
        return residuals

    a = rng.normal(size=k)
    readout, _ = rolling_shutter.readout_on_surface(residuals_from(a), 0.0)
    start = np.tensordot(a, J, axes=1) - column * truth + noise
    exact = np.linalg.lstsq(design, -start.reshape(-1), rcond=None)[0][-1]
    assert readout == pytest.approx(exact, abs=1e-9)
    assert abs(readout - truth) < 1e-4
    readout, variance = rolling_shutter.readout_on_surface(residuals_from(np.zeros(k)), truth)
    expected = sigma ** 2 * np.linalg.inv(design.T @ design)[-1, -1]
    assert variance == pytest.approx(expected, rel=0.2)
    assert abs(readout - truth) < 4 * np.sqrt(variance)


def test_hypotheses_and_refinement_use_each_tracks_rows():
    """Tracks whose motion is the frame's stretched by their rows' times: exact with the
    model; the global-shutter model keeps about a quarter of them and is 2 cm off."""
    mounting = Mounting(x=1.2, y=0.0, height=1.25, pitch=np.radians(8.0))
    A, b = mounting.ground_to_optical()
    model = TransferModel(A, b, 460.0, mounting)
    rng = np.random.default_rng(1)
    p1 = np.c_[rng.uniform(4, 15, 200), rng.uniform(-3, 3, 200)]
    motion = circular_motion(0.03, 0.2)
    stretch = rng.uniform(0.8, 1.2, 200)
    p2 = np.array([move_points(p[None], m)[0] for p, m in zip(p1, power(motion, stretch))])
    m2 = observe(mounting, p2)
    for method in ('1point', '2point', 'histogram'):
        est = estimate_motion(p1, p2, m2, model, method=method, stretch=stretch)
        np.testing.assert_allclose(est.motion, motion, atol=1e-9)
        assert est.inliers.all()
    assert transfer_errors(motion, p1, m2, model, stretch).max() < 1e-9
    plain = estimate_motion(p1, p2, m2, model)
    assert np.linalg.norm(plain.motion[:2] - motion[:2]) > 0.01
    assert ShutterModel(0.0).stretch(p1[:, 0], p1[:, 1], 240, 0.05) is None


def _pose_at(times, twist, rate, t_mid, step=2e-5):
    """base_link poses (N, 3) at ``times`` relative to time 0, the body twist
    ``twist + rate (t - t_mid)``: integrated in small steps (midpoint rule), interpolated."""
    grid = np.arange(min(times.min(), 0.0) - step, max(times.max(), 0.0) + 2 * step, step)
    poses = np.zeros((len(grid), 3))
    for i in range(1, len(grid)):
        held = twist_motion(twist + rate * (0.5 * (grid[i - 1] + grid[i]) - t_mid), step)
        x, y, yaw = poses[i - 1]
        c, s = np.cos(yaw), np.sin(yaw)
        poses[i] = [x + c * held[0] - s * held[1], y + s * held[0] + c * held[1], yaw + held[2]]
    zero = np.array([np.interp(0.0, grid, poses[:, j]) for j in range(3)])
    at = np.stack([np.interp(times, grid, poses[:, j]) for j in range(3)], axis=1)
    c, s = np.cos(zero[2]), np.sin(zero[2])
    d = at[:, :2] - zero[:2]
    return np.c_[c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], at[:, 2] - zero[2]]


def test_a_changing_twist_is_carried_into_each_tracks_motion_and_the_de_skew():
    """Tracks of a car changing speed and yaw rate within the pair (integrated, not the
    model's algebra): with the twist's rate of change the 3-DoF estimate is the motion
    between the stamps and the de-skew puts both observations at their stamps; without it
    the estimate is the motion of an interval shifted by the tracks' mean row time."""
    mounting = Mounting(x=1.2, y=0.0, height=1.25, pitch=np.radians(8.0))
    model = TransferModel(*mounting.ground_to_optical(), 460.0, mounting)
    shutter, height, dt = ShutterModel(0.033), 480, 0.05
    twist, rate = np.array([8.0, 0.0, 0.3]), np.array([3.0, 0.0, 1.0])  # m/s, rad/s; per s
    rng = np.random.default_rng(3)
    n = 300
    world = np.c_[rng.uniform(4, 15, n), rng.uniform(-3, 3, n)]  # base_link at the 1st stamp
    v1, v2 = rng.uniform(250, 479, n), rng.uniform(250, 479, n)
    tau1, tau2 = shutter.row_time(v1, height), shutter.row_time(v2, height)
    poses = _pose_at(np.r_[tau1, dt + tau2, dt], twist, rate, dt / 2)
    seen1, seen2, motion = poses[:n], poses[n:2 * n], poses[-1]
    p1 = np.array([move_points(w[None], m)[0] for w, m in zip(world, seen1)])
    p2 = np.array([move_points(w[None], m)[0] for w, m in zip(world, seen2)])
    m2 = observe(mounting, p2)
    stretch = shutter.stretch(v1, v2, height, dt)
    fixed = accelerated(p1, (tau1, tau2), dt, rate, twist)
    est = estimate_motion(fixed, p2, m2, model, stretch=stretch)
    plain = estimate_motion(p1, p2, m2, model, stretch=stretch)
    err, err_plain = (np.abs(e.motion - motion) for e in (est, plain))
    # Measured: 13 um and 0.4 urad off (1.2 mm and 0.4 mrad without it) for a pair of 40 cm.
    assert err[:2].max() < 3e-5 and err[2] < 1e-6, err
    assert err_plain[:2].max() > 20 * err[:2].max() and err_plain[2] > 100 * err[2], err_plain
    # The de-skew: each observation where a global shutter at its frame's stamp sees it.
    at1 = at_stamp(p1, tau1, motion, dt, model, rate, -dt / 2)
    at2 = at_stamp(p2, tau2, motion, dt, model, rate, dt / 2)
    for got, want in ((at1, observe(mounting, world)),
                      (at2, observe(mounting, move_points(world, motion)))):
        assert 460.0 * np.abs(got - want).max() < 5e-3  # px
    assert 460.0 * np.abs(at_stamp(p1, tau1, motion, dt, model)
                          - observe(mounting, world)).max() > 0.02


def test_a_pairs_tracks_are_carried_to_their_stamps_by_their_rows_times():
    """Driving straight at 8 m/s, a ground point read ``tau`` after a frame's stamp was seen
    from base_link ``8 tau`` further on: carried back by that, both frames' observations are a
    global shutter's at the stamps (closed form); a global shutter's are left as seen."""
    mounting = Mounting(x=1.2, y=0.0, height=1.1, pitch=np.radians(8.0))
    model = TransferModel(*mounting.ground_to_optical(), 460.0, mounting)
    height, dt, motion = 480, 0.05, np.array([0.4, 0.0, 0.0])
    rng = np.random.default_rng(5)
    world = np.c_[rng.uniform(3, 12, 50), rng.uniform(-2, 2, 50)]  # base_link at the 1st stamp
    rows = rng.uniform(250, 479, 50), rng.uniform(250, 479, 50)
    rolling = ShutterModel(0.03)
    tau1, tau2 = (rolling.row_time(v, height) for v in rows)
    p1 = world - np.c_[8.0 * tau1, 0 * tau1]
    p2 = world - np.c_[0.4 + 8.0 * tau2, 0 * tau2]
    pair = Deskew((p1, p2), rows, dt, model, None)
    rays1, m2 = pair.at_stamps(motion, rolling, height, ground=None)
    np.testing.assert_allclose(rays1, rays_through(observe(mounting, world)), atol=1e-12)
    np.testing.assert_allclose(m2, observe(mounting, world - [0.4, 0.0]), atol=1e-12)
    assert 460.0 * np.abs(observe(mounting, p2) - m2).max() > 1.0  # px: what it carried
    rays1, m2 = pair.at_stamps(motion, ShutterModel(0.0), height, ground=None)
    np.testing.assert_allclose(rays1, rays_through(observe(mounting, p1)), atol=1e-12)
    np.testing.assert_allclose(m2, observe(mounting, p2), atol=1e-12)


def test_the_prewarp_and_prediction_follow_each_rows_time():
    """The KLT prewarp's map and the track prediction with a rolling shutter, against the
    renderer's own row poses (376x240, 33 ms, a frame pair of the default drive, the true
    motion between the stamps): the map's samples and the prediction within 0.02 px of where
    the renderer has the ground (0.011: the twist changes within the pair), the map within
    0.06 px (its 16 px grid); the global shutter's map is off by up to 0.7 px."""
    from planar_vo.core.config import mounting_from_params, mounting_params
    from planar_vo.core.frontend.warp import GroundWarp
    from planar_vo.core.geometry.camera import rays_through

    from .conftest import synth_camera_model
    rs = RollingShutter(0.033)
    renderer, traj = synth.render_scenario('default', 6, 0, rate=20.0, suspension=synth.RIGID,
                                           camera=synth.SynthCamera.scaled(376, 240),
                                           rolling_shutter=rs)
    camera = synth_camera_model(renderer)
    mounting = mounting_from_params(mounting_params(renderer.mounting))
    model = TransferModel.from_camera(mounting, camera)
    height, rows, k = camera.height, renderer.rows, 4
    pose = np.c_[traj.x, traj.y, traj.yaw]
    c, s = np.cos(pose[k - 1, 2]), np.sin(pose[k - 1, 2])
    d = pose[k, :2] - pose[k - 1, :2]
    motion = np.r_[c * d[0] + s * d[1], -s * d[0] + c * d[1], pose[k, 2] - pose[k - 1, 2]]

    def row_pose(frame, v):
        return np.stack([np.interp(v, np.arange(height), a[frame])
                         for a in (rows.x, rows.y, rows.yaw)], axis=1)

    def seen(frame_from, pixels, frame_to):
        """Where the renderer sees the ground at ``pixels`` of one frame in the other."""
        ground = mounting.ground_points(rays_through(camera.normalize(pixels)))[0]
        at = row_pose(frame_from, pixels[:, 1])
        c, s = np.cos(at[:, 2]), np.sin(at[:, 2])
        w = np.c_[at[:, 0] + c * ground[:, 0] - s * ground[:, 1],
                  at[:, 1] + s * ground[:, 0] + c * ground[:, 1]]
        v = pixels[:, 1].astype(float)
        for _ in range(8):
            to = row_pose(frame_to, v)
            c, s = np.cos(to[:, 2]), np.sin(to[:, 2])
            dx, dy = w[:, 0] - to[:, 0], w[:, 1] - to[:, 1]
            out = camera.distort(model.project(np.c_[c * dx + s * dy, -s * dx + c * dy]))
            v = out[:, 1]
        return out

    uu, vv = np.meshgrid(np.arange(20.0, 356.0, 7.0), np.arange(150.0, 228.0, 7.0))
    pixels = np.c_[uu.ravel(), vv.ravel()]
    want = seen(k, pixels, k - 1)
    shutter = ShutterModel(0.033)
    warp = GroundWarp(camera)
    got = _bilinear_map(warp.rows_map(model, motion, 0, shutter, 0.05).copy(), pixels)
    plain = _bilinear_map(warp.pixel_map(model, motion), pixels)
    inside = np.all((want > 10) & (want < [366, 230]), axis=1)
    assert inside.sum() > 300
    error = np.linalg.norm(got - want, axis=1)[inside]
    assert error.max() < 0.06, error.max()
    assert np.linalg.norm(plain - want, axis=1)[inside].max() > 0.5
    # The map's samples themselves (no grid): the motion stretched by each pixel's rows.
    def pixels_of(q):
        return camera.distort(model.transfer(np.zeros(3), q))
    ground = mounting.ground_points(rays_through(camera.normalize(pixels[inside])))[0]
    back = shutter.seen_in_other(ground, pixels[inside, 1], motion, 0.05, pixels_of, height,
                                 forward=False)
    assert np.linalg.norm(back - want[inside], axis=1).max() < 0.02
    # The prediction: reference pixels forward into the next frame.
    ahead = seen(k - 1, pixels[inside], k)
    predicted = shutter.seen_in_other(ground, pixels[inside, 1], motion, 0.05, pixels_of,
                                      height, forward=True)
    kept = ahead[:, 1] < height - 10  # still in the image (the renderer's rows end there)
    assert kept.sum() > 300
    assert np.linalg.norm(predicted - ahead, axis=1)[kept].max() < 0.02  # 0.011


def _bilinear_map(grid, pixels):
    from planar_vo.core.frontend.tracker import _bilinear
    return _bilinear(grid, pixels.astype(np.float32))


def test_rows_at_the_frame_pose_render_the_global_shutter_frame():
    """The per-row renderer with every row at the frame's pose is the frame (rigid: exact;
    sprung: within a grey level, float32 geometry); with a readout rows differ from it."""
    camera = synth.SynthCamera.scaled(160, 120)
    for scenario in ('default', 'car'):
        renderer, traj = synth.render_scenario(scenario, 4, 0, rate=20.0, camera=camera)
        want = renderer.render_frame(traj, 2)
        h, n = camera.height, len(traj.t)
        rows = RowPoses(*(np.repeat(a[:, None], h, axis=1) for a in (traj.x, traj.y, traj.yaw)))
        if scenario == 'car':
            rows = RowPoses(rows.x, rows.y, rows.yaw,
                            np.repeat(traj.camera.position[:, None], h, axis=1),
                            np.repeat(traj.camera.rotation[:, None], h, axis=1))
        renderer.rows = rows
        got = renderer.render_frame(traj, 2).astype(int)
        assert np.abs(got - want).max() <= (0 if scenario == 'default' else 2), scenario
        assert np.abs(got - want).mean() < 0.05, scenario
        assert n == 4
    rs, traj = synth.render_scenario('default', 4, 0, rate=20.0, camera=camera,
                                     rolling_shutter=RollingShutter(0.03, 'start'))
    assert rs.rows.x[2, 0] == traj.x[2]  # the stamp is the first row's time
    assert rs.rows.x[2, -1] > traj.x[2] + 0.9 * 0.03 * traj.v[2] * (h - 1) / h


def test_synth_cli_records_the_rolling_shutter(tmp_path):
    from planar_vo.synth.cli import main
    with pytest.raises(SystemExit):  # (on terrain it renders: test_synth_rolling_terrain)
        main([str(tmp_path / 'x'), '--rolling-shutter', '0.5'])
    out = tmp_path / 'rs'
    assert main([str(out), '--frames', '2', '--width', '96', '--height', '64', '--quiet',
                 '--rolling-shutter', '0.02', '--rolling-shutter-stamp', 'end']) == 0
    meta = (out / 'metadata.yaml').read_text()
    assert 'rolling_shutter' in meta and '0.02' in meta and 'end' in meta


# (scenario, rate Hz, readout s, frames, sprung): the default, tight and car paths at 15-30 Hz,
# with the shipped defaults (the local ground, refined on the de-skewed tracks). The car on its
# springs (body pitch <= 1 deg, roll <= 0.6 deg, bounce <= 1.5 cm) rolls and pitches within
# a readout too, which neither model holds.
# Measured at 376x240 (t_rel %, GS / RS without the model / RS with it; stop 69):
#   default 30 Hz 20 ms: 0.085 / 6.56 / 0.085, scale 1.0004 with the model
#   tight 20 Hz 33 ms: 0.070 / 3.58 / 0.050, scale 1.0002 (r_rel 0.58 deg/100 m)
#   car path (rigid body) 15 Hz 10 ms: 0.111 / 2.32 / 0.121, scale 1.0003
#   sprung car 15 Hz 33 ms: 0.250 / 6.26 / 0.264, scale 1.0004
DRIVES = [('default', 30.0, 0.020, 150, False), ('tight', 20.0, 0.033, 200, False),
          ('car', 15.0, 0.010, 150, False), ('car', 15.0, 0.033, 120, True)]


@pytest.mark.parametrize('scenario,rate,readout,frames,sprung', DRIVES)
def test_a_rolling_shutter_drive_is_as_accurate_as_a_global_shutter(scenario, rate, readout,
                                                                     frames, sprung):
    camera = synth.SynthCamera.scaled(376, 240)
    runs, kept = {}, []
    for name, shutter, over in (('global', None, {}),
                                ('plain', RollingShutter(readout),
                                 {'detect_rolling_shutter': False}),
                                ('model', RollingShutter(readout),
                                 {'rolling_shutter_readout': readout})):
        results, truth = run_scenario(scenario, frames, rate=rate, camera=camera,
                                      suspension=None if sprung else synth.RIGID,
                                      overrides=over, rolling_shutter=shutter, keep=kept)
        assert all(r.status in ('first', 'ok') for r in results), name
        runs[name] = metrics(np.array([r.pose for r in results]), truth)
    # The global shutter, watched with the shipped defaults, was not taken for a rolling one.
    assert kept[0].shutter_learning.calibrator is None and kept[0].shutter.global_shutter
    ours, gs, plain = runs['model'], runs['global'], runs['plain']
    assert ours['t_rel_percent'] < 1.5 * gs['t_rel_percent'], runs
    assert abs(ours['scale_ratio'] - 1) < 0.002, runs
    assert ours['r_rel_deg_per_100m'] <= 1.5, runs
    assert plain['t_rel_percent'] > 2 * ours['t_rel_percent'], runs


@pytest.fixture(scope='module')
def sprung_rolling_shutter_drive(tmp_path_factory):
    """752x480 (at 376x240 KLT's aliasing biases the readout about 12 % low), the car path
    (curves, 3-8 m/s) on its springs (body pitch <= 1 deg, roll <= 0.6 deg), 20 Hz, a 30 ms
    readout, rendered once into a bag (raw mono8 images: the rendered frames byte for byte)
    whose params file is a global shutter and 0.5 deg off in pitch and roll.
    (bag, params file, SynthResult: the true mounting and the trajectory)."""
    out = tmp_path_factory.mktemp('rolling_shutter')
    bag, params = out / 'bag', out / 'in.yaml'
    result = synth.generate_bag(bag, 'car', frames=240, rate=20.0,
                                camera=synth.SynthCamera.scaled(752, 480), params_out=params,
                                configured_error=synth.MountingError(pitch=0.5, roll=-0.5),
                                rolling_shutter=RollingShutter(0.03))
    return bag, params, result


def test_the_readout_is_learned_from_a_drive_with_turns(sprung_rolling_shutter_drive):
    """sprung_rolling_shutter_drive's frames with the true mounting, configured as a global
    shutter, the shipped ground model (local).
    Measured: 31.3 ms over 61 m, t_rel 0.294 % (the readout 0: 7.9 %). Measured through the
    plane under the wheels, as before stop 43, the body's roll and pitch put it 5.9 ms off:
    t_rel 5.887 %."""
    from planar_vo.core.odometry import VisualOdometry
    from planar_vo.io.bag import open_reader

    from .conftest import synth_camera_model
    bag, _, result = sprung_rolling_shutter_drive
    traj = result.trajectory
    params = config.validate({**config.mounting_params(result.mounting),
                              'learn_rolling_shutter': True})
    vo = VisualOdometry.from_params(synth_camera_model(result), params)
    poses = []
    with open_reader(bag) as reader:
        connections = [c for c in reader.connections if c.topic == synth.IMAGE_TOPIC]
        for k, (c, _, raw) in enumerate(reader.messages(connections)):
            msg = reader.deserialize(raw, c.msgtype)
            assert msg.encoding == 'mono8' and msg.step == msg.width
            poses.append(vo.process(
                np.frombuffer(msg.data, np.uint8).reshape(msg.height, msg.width), k / 20.0).pose)
    assert k + 1 == len(traj.t) == 240
    learned = vo.readout_estimate()
    assert traj.length > 25.0
    assert abs(learned.readout - 0.03) < 0.003, learned
    assert vo.shutter.readout == learned.readout  # in use once known
    accuracy = metrics(np.array(poses), np.c_[traj.x, traj.y, traj.yaw])
    assert accuracy['t_rel_percent'] < 0.6, accuracy
    said = replay.report(replay.ReplayResult(replay.Trajectory(), replay.Trajectory(), {}, [],
                                             240, readout=learned))  # planar_vo_replay --json
    assert said['rolling_shutter_readout']['value'] == learned.readout
    assert said['rolling_shutter_readout']['pairs'] == learned.pairs > 200
    values, advice = vo.mounting_diagnostics()
    assert 'rolling_shutter_readout' in advice  # configured 0: warned
    assert 'estimated' in ' '.join(values)
    assert vo.diagnostics()['shutter'].startswith(
        f'rolling shutter, readout {1e3 * learned.readout:.2f} ms')


def test_a_rolling_shutter_is_found_with_the_shipped_defaults(sprung_rolling_shutter_drive):
    """sprung_rolling_shutter_drive replayed as a user runs it: a global shutter configured
    (the default), only the mounting set. The watch finds the rolling shutter and learns its
    readout; the drive before it was found stays as far off as it was.
    Measured: found after 54 pairs (15 m), 31.4 ms, t_rel 1.465 % (found after 40 pairs
    before stop 48: 0.808 %; detect_rolling_shutter off, as before stop 43: 7.91 %)."""
    _, _, result = sprung_rolling_shutter_drive
    bag = sprung_rolling_shutter_drive[0]
    params = {**config.defaults(), **config.mounting_params(result.mounting)}
    found = replay.report(replay.replay(bag, params))
    assert abs(found['rolling_shutter_readout']['value'] - 0.03) < 0.003, found
    assert found['accuracy']['t_rel_percent'] < 1.6, found


def test_a_rolling_shutter_found_is_used_once_its_readout_is_known_to_a_millisecond():
    """Readings of 38 and 18 ms in turn, 4 ms each, 0.35 m a pair: after 43 pairs (15 m) both
    are over 8 ms by three sigmas, so a rolling shutter is found, but their mean is known only
    to 1.5 ms: the global shutter stays in use until the learner knows it to 1 ms (a global
    shutter found for one, used at once in stop 54, went 0.40 -> 2.88 % t_rel)."""
    learning = ShutterLearning(0.0, 'middle', learn=False, watch=True)
    readings = []
    while learning.watch is not None and len(readings) < 100:
        readings.append(0.018 if len(readings) % 2 else 0.038)
        found = learning.add_watched(*[(readings[-1], 0.004 ** 2)] * 2, 0.05, 0.35)
    assert found and len(readings) == 43, readings
    estimate = learning.estimate()
    assert 1e-3 < estimate.std < 2e-3 and learning.calibrator.usable() is None, estimate
    assert learning.shutter.readout == 0.0
    assert learning.diagnostics()[0]['rolling_shutter_readout in use (ms)'] == '0.00'


def _found_at(readout: float) -> ShutterLearning:
    """A watch that found a rolling shutter from readings of ``readout`` (s), 2 ms each."""
    learning = ShutterLearning(0.0, 'middle', learn=False, watch=True)
    for _ in range(100):
        if learning.add_watched(*[(readout, 0.002 ** 2)] * 2, 0.05, 0.35):
            return learning
    raise AssertionError('not found')


def test_a_rolling_shutter_found_is_taken_back_when_the_readings_since_contradict_it():
    """A global shutter found for a rolling one by what its first metres did (a body pitching
    about its rear axle over all four terrains: found at 18 ms, then read 0): once the pairs
    since read under the readout that found it by more than the 8 ms bar, surely, the global
    shutter is back and nothing is learned. A rolling shutter read 0.9 of it stays found."""
    learning = _found_at(0.018)
    rng = np.random.default_rng(0)
    for _ in range(39):
        learning.add_reading(rng.normal(0.001, 0.002), 0.002 ** 2, 0.05)
    assert learning.calibrator is not None and learning.found is not None  # 40 pairs first
    learning.add_reading(0.001, 0.002 ** 2, 0.05)
    assert learning.shutter.global_shutter and learning.shutter == learning.configured
    assert learning.estimate() is None and not learning.wants(refined=True)
    assert learning.diagnostics() == ({}, {})

    learning = _found_at(0.030)
    for _ in range(200):
        learning.add_reading(rng.normal(0.027, 0.002), 0.002 ** 2, 0.05)
    assert learning.found is not None
    assert learning.shutter.readout == pytest.approx(0.027, abs=0.001)


def _watch_verdicts(drive: str) -> tuple[str, int, float]:
    """ShutterWatch over a drive's recorded readings: (found / ruled out / watching, at pair,
    the lower of the two readings' lower bounds at pair 40, s)."""
    path = Path(__file__).parent / 'data' / 'shutter_watch_readings.csv'
    with path.open() as f:
        rows = [r for r in csv.DictReader(line for line in f if not line.startswith('#'))
                if r['drive'] == drive]
    watch, lower_at_40 = rolling_shutter.ShutterWatch(), None
    for pair, row in enumerate(rows, start=1):
        value = {k: float(v) for k, v in row.items() if k != 'drive'}
        watch = watch.add((1e-3 * value['plane_ms'], (1e-3 * value['plane_sd_ms']) ** 2),
                          (1e-3 * value['surface_ms'], (1e-3 * value['surface_sd_ms']) ** 2),
                          value['dt'], value['metres'])
        if pair == 40:
            lower_at_40 = min(e.readout - 3 * e.std
                              for e in (watch.plane.estimate(), watch.surface.estimate()))
        if watch.found() or watch.ruled_out():
            return ('found' if watch.found() else 'ruled out'), pair, lower_at_40
    return 'watching', pair, lower_at_40


@pytest.mark.parametrize('drive,shutter', [('global_bend', 'global'), ('global_bend2', 'global'),
                                           ('rolling_20ms', 'rolling'),
                                           ('rolling_33ms', 'rolling')])
def test_a_bend_in_the_road_is_not_taken_for_a_rolling_shutter(drive, shutter):
    """The readings the shipped defaults gave the watch on four rendered drives (recorded in
    test/data). The issue's camera over all four terrains, sprung, a global shutter (seeds 22
    and 26): through the local ground 22 and 18 ms +- 1-2 over the first 40 pairs (7-9 m of
    road: a vertical curve ahead), both readings over 8 ms by 3 standard deviations there, and
    found there until stop 48 (t_rel 0.302 and 0.620 %; since 0.189 and 0.110). Now the watch
    waits for 15 m of road or 3 s. Rolling shutters of 20 ms (20 Hz) and 33 ms (15 Hz): found
    at pairs 46 (15 m) and 45 (3 s); 40 before."""
    verdict, pair, lower_at_40 = _watch_verdicts(drive)
    if shutter == 'global':
        assert lower_at_40 > 8e-3  # what the watch took for a rolling shutter until stop 48
        assert verdict != 'found', pair
    else:
        assert verdict == 'found' and pair <= 60, pair


def test_calibrate_learns_the_readout(sprung_rolling_shutter_drive, tmp_path):
    """``planar_vo_calibrate --rolling-shutter`` on a recorded drive (the learned test's:
    752x480, a sprung car, 20 Hz, 30 ms) whose params file is a global shutter and 0.5 deg
    off in pitch and roll.
    Measured: 31.3 ms (std 0.13), camera_pitch 0.034 deg and camera_roll 0.17 deg off the
    truth."""
    bag, params, _ = sprung_rolling_shutter_drive
    out = tmp_path / 'out.yaml'
    assert config.load_params_file(params)['rolling_shutter_readout'] == 0.0
    run = subprocess.run([resources.executable('planar_vo_calibrate'), str(bag), '--params',
                          str(params), '--output', str(out), '--rolling-shutter', '--json'],
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr
    report = json.loads(run.stdout)
    calibrated = config.load_params_file(out)
    assert abs(calibrated['rolling_shutter_readout'] - 0.03) < 0.003, report
    assert 'rolling_shutter_readout' not in report['kept'], report


def test_a_rolling_shutter_draws_the_traffic_a_global_one_does():
    # A readout of 1 us is a global shutter: the frames must agree, crossing traffic included
    # (it once drew the parked boxes only: 120-180 grey levels off where a car crossed).
    camera = synth.SynthCamera.scaled(160, 120)
    still, traj = synth.render_scenario('stop_and_go', 200, 0, rate=10.0, camera=camera)
    rolling, _ = synth.render_scenario('stop_and_go', 200, 0, rate=10.0, camera=camera,
                                       rolling_shutter=RollingShutter(1e-6, 'middle'))
    for k in (0, 10, 90):
        assert len(still.boxes_at(k)) > len(still.boxes)  # traffic in the scene
        diff = np.abs(still.render_frame(traj, k).astype(int)
                      - rolling.render_frame(traj, k).astype(int))
        assert diff.max() <= 1, k


def test_a_track_on_a_grade_is_moved_to_its_stamp_as_a_point_on_the_grade():
    # The de-skew moves each track by the motion over its row's time offset: a point off the
    # wheels' plane (the road ahead's surface) moves in the image as a point at its own
    # depth, not as the plane point on its ray. Checked against the pinhole's closed form.
    mounting = Mounting(x=1.2, y=0.0, height=1.1, roll=0.0, pitch=0.14, yaw=0.0)
    A, b = mounting.ground_to_optical()
    model = TransferModel(A, b, 500.0, mounting)
    ground = LocalGroundFilter(mounting, rates=np.array([0.3, 0.3, 0.1]), wheelbase=2.7,
                               self_calibrate=False)
    ground.surface = np.array([0.05, 0.01, 0.03, 0.01, 0.02])  # grade, crown, a crest...
    x, y = np.meshgrid(np.linspace(3.5, 6.0, 6), np.linspace(-1.5, 1.5, 5))
    u, y = x.ravel() - 2.7, y.ravel()
    points = np.c_[x.ravel(), y, 0.05 * u + 0.01 * y + 0.015 * u * u + 0.01 * u * y
                   + 0.01 * y * y]  # on that surface
    c = mounting.position
    on_plane = c[:2] + (c[2] / (c[2] - points[:, 2]))[:, None] * (points[:, :2] - c[:2])
    xy, height = ground.on_surface(on_plane, c)
    np.testing.assert_allclose(np.c_[xy, height], points, atol=1e-12)
    motion, dt = np.array([0.4, 0.01, 0.02]), 0.05
    offset = np.linspace(-0.015, 0.015, len(points))
    moved = power(motion, offset / dt)
    c_, s_ = np.cos(moved[:, 2]), np.sin(moved[:, 2])
    carried = np.c_[moved[:, 0] + c_ * points[:, 0] - s_ * points[:, 1],
                    moved[:, 1] + s_ * points[:, 0] + c_ * points[:, 1], points[:, 2]]
    optical = (carried - c) @ mounting.base_from_optical
    want = optical[:, :2] / optical[:, 2:]
    got = at_stamp(points[:, :2], offset, motion, dt, model, height=points[:, 2])
    np.testing.assert_allclose(got, want, atol=1e-12)
    plane = at_stamp(on_plane, offset, motion, dt, model)
    assert 500 * np.abs(plane - want).max() > 0.1  # px: the plane's de-skew is off by this
