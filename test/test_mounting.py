"""Real mountings end to end: a sprung body, a mounting configured wrong, planar_vo_calibrate.

Truth is the renderer's (planar_vo.synth builds the camera pose on its own path, not with
planar_vo.core.geometry.camera). Numbers measured when these tests were written are in the README.
"""

import dataclasses
import json
import re
import subprocess

import numpy as np
import pytest

from planar_vo import synth
from planar_vo.core import config
from planar_vo.core.metrics import metrics
from planar_vo.core.odometry import VisualOdometry
from planar_vo.io import resources
from test.conftest import run_scenario, sprung_body_params, synth_camera_model


def _params(truth_mounting, overrides):
    return config.validate({**config.mounting_params(truth_mounting), **overrides})


def _run(renderer, images, truth_mounting, overrides, rate=30.0):
    vo = VisualOdometry.from_params(synth_camera_model(renderer),
                                    _params(truth_mounting, overrides))
    return [vo.process(image, k / rate) for k, image in enumerate(images)]


def _metrics(results, traj):
    assert all(r.status in ('first', 'ok') for r in results)
    return metrics(np.array([r.pose for r in results]),
                   np.c_[traj.x, traj.y, traj.yaw])


@pytest.fixture(scope='module')
def sprung_car():
    """The ``car`` scenario (body pitch <= 1 deg, roll <= 0.6 deg, bounce <= 1.5 cm; camera
    rolled 0.5 deg and yawed -0.7 deg), rendered once for every pipeline variant."""
    renderer, traj = synth.render_scenario('car', 200, 0)
    return renderer, traj, [renderer.render_frame(traj, k) for k in range(200)]


@pytest.fixture(scope='module')
def sprung_car_as_advised(sprung_car):
    """The sprung car configured as the README advises (conftest.sprung_body_params: the
    attitude tracked, the body's pivot, 700 tracks, self-calibration on) on sprung_car's
    frames, run once: (params, results) for the two comparisons that score it."""
    renderer, _, images = sprung_car
    params = _params(renderer.mounting, sprung_body_params('car'))
    return params, _run(renderer, images, renderer.mounting, sprung_body_params('car'))


def test_sprung_body_attitude_tracking_beats_a_rigid_model(sprung_car):
    """Measured (200 frames, 31 m): rigid model t_rel 1.39 %, r_rel 9.8 deg/100 m; with the
    attitude tracked 0.21 %, 0.7 deg/100 m; with the body's pivot (its centre of mass, 0.7 m
    below and 0.15 m ahead of the camera) configured too 0.14 %; OpenCV's homography on the
    same tracks 0.14 %."""
    renderer, traj, images = sprung_car
    body = synth.SCENARIOS['car'].suspension
    rigid = _metrics(_run(renderer, images, renderer.mounting,
                          {'ground_model': 'plane', 'estimate_attitude': False}), traj)
    in_place = _metrics(_run(renderer, images, renderer.mounting,
                             {'ground_model': 'plane', 'estimate_attitude': True}), traj)
    pivoted = _metrics(_run(renderer, images, renderer.mounting, {
        'ground_model': 'plane', 'estimate_attitude': True,
        'body_pivot_below_camera': renderer.mounting.height - body.pivot_z,
        'body_pivot_behind_camera': renderer.mounting.x - body.pivot_x}), traj)
    # Measured now: rigid 1.56 % / 9.5 deg/100 m; in place 0.110 % / 0.25 / scale 1.00022;
    # pivoted 0.079 % / 0.30 / scale 1.00044.
    for tracked in (in_place, pivoted):
        assert tracked['t_rel_percent'] < rigid['t_rel_percent'] / 4, (tracked, rigid)
        assert tracked['r_rel_deg_per_100m'] < 0.75, tracked
        assert abs(tracked['scale_ratio'] - 1) < 0.0012, tracked
    assert pivoted['t_rel_percent'] < 0.2, pivoted
    assert pivoted['t_rel_percent'] < in_place['t_rel_percent'], (pivoted, in_place)


def test_the_shipped_defaults_hold_a_sprung_car_with_the_nominal_mounting(sprung_car):
    """Nothing configured but the nominal mounting (the camera's 0.5 deg roll and -0.7 deg
    yaw left out): the local ground model reads the body's tilt from the road's history.
    Measured (200 frames, 31 m, the history in use after ~8 m): 0.187 % / 0.23 deg/100 m;
    0.43 % before the history was kept."""
    renderer, traj, images = sprung_car
    nominal = dataclasses.replace(renderer.mounting, roll=0.0, yaw=0.0)
    ours = _metrics(_run(renderer, images, nominal, {}), traj)
    assert ours['t_rel_percent'] < 0.3, ours
    assert ours['r_rel_deg_per_100m'] < 0.6, ours
    assert abs(ours['scale_ratio'] - 1) < 0.002, ours


def test_sprung_body_stays_near_a_rigid_mount_and_beats_opencv(sprung_car,
                                                               sprung_car_as_advised):
    """The sprung `car` drive configured as the README advises (attitude, pivot, 700 tracks)
    against the rigid model on a rigid mount along the same path, and OpenCV's homography on
    the same tracks. Measured (200 frames, 31 m): rigid mount 0.034 %, sprung 0.047 % (1.4x;
    0.068 % with 400 tracks), OpenCV 0.109 % (2.3x ours: the issue's 3x is not reached)."""
    renderer, traj, images = sprung_car
    body = synth.SCENARIOS['car'].suspension
    m = renderer.mounting
    rigid_renderer, rigid_traj = synth.render_scenario('car', 200, 0, suspension=synth.RIGID)
    np.testing.assert_allclose(rigid_traj.x, traj.x)  # the same path
    rigid_images = [rigid_renderer.render_frame(rigid_traj, k) for k in range(200)]
    tracks = {'max_features': 700}
    rigid = _metrics(_run(rigid_renderer, rigid_images, m, {**tracks, 'ground_model': 'plane'}),
                     rigid_traj)
    advised, ours = sprung_car_as_advised  # the run below, shared with the next test
    assert advised == _params(m, {
        **tracks, 'ground_model': 'plane', 'estimate_attitude': True,
        'body_pivot_below_camera': m.height - body.pivot_z,
        'body_pivot_behind_camera': m.x - body.pivot_x})
    ours = _metrics(ours, traj)
    opencv = _metrics(_run(renderer, images, m,
                           {**tracks, 'ground_model': 'plane',
                            'ransac_method': 'opencv_homography'}), traj)
    # Measured: rigid mount 0.0323 %, sprung 0.0478 % / 0.157 deg/100 m, OpenCV 0.104 %.
    # Since stop 58 the vignetting is learned and divided out: the rigid model, which it had
    # biased, 0.0163 %, the sprung body (its attitude had absorbed it) 0.051 %. Since stop 61
    # (its symmetric part from 3 m) the rigid mount 0.0143 %, the sprung body 0.0516 (3.6x).
    assert ours['t_rel_percent'] < 4.0 * rigid['t_rel_percent'], (ours, rigid)
    assert ours['r_rel_deg_per_100m'] < 0.4, ours
    assert opencv['t_rel_percent'] > 1.8 * ours['t_rel_percent'], (opencv, ours)


def test_sprung_body_is_over_3x_better_than_a_plain_opencv_pipeline(sprung_car,
                                                                   sprung_car_as_advised):
    """The route the issue measured the product against on the same frames: OpenCV's own
    tracking on the ground region, then its homography (``OpenCVReference``), with the same
    700-feature budget and the true mounting. Measured (200 frames, 31 m): plain pipeline
    0.71 % / 1.4 deg/100 m (scale 0.994), ours 0.047 % / 0.15 (15x; with 400 features
    0.96 % against 0.068 %). Detecting over the whole image it was 0.74 % (1.25 % with 400)."""
    from planar_vo.tools.experiments.mounting_experiment import plain_opencv_path
    renderer, traj, images = sprung_car
    params, ours = sprung_car_as_advised  # sprung_body_params: 700 features for both
    plain = metrics(plain_opencv_path(synth_camera_model(renderer), params, images),
                    np.c_[traj.x, traj.y, traj.yaw])
    ours = _metrics(ours, traj)
    # Measured now: plain 0.706 % / 1.36 deg/100 m, ours 0.0478 % / 0.157 (15x and 8.7x).
    assert plain['t_rel_percent'] > 6.0 * ours['t_rel_percent'], (plain, ours)
    assert ours['r_rel_deg_per_100m'] < plain['r_rel_deg_per_100m'] / 4, (plain, ours)


def test_attitude_on_a_rigid_mount_costs_little():
    """`straight`, 150 frames, rigid mount, exactly configured: estimating the attitude (the
    mounting kept) as accurate as the rigid model. Measured: t_rel 0.024 against 0.032 %,
    r_rel 0.28 against 0.26 deg/100 m; with the learned tilt rate's old floor (3e-3 rad/s) the
    pairs' roll errors leaked into the yaw and t_rel was 0.045 %."""
    from test.conftest import run_scenario
    runs = {}
    for name, overrides in (('rigid', {'ground_model': 'plane', 'estimate_attitude': False}),
                            ('attitude', {'ground_model': 'plane', 'estimate_attitude': True,
                                          'self_calibrate': False})):
        results, truth = run_scenario('straight', 150, overrides=overrides)
        assert all(r.status in ('first', 'ok') for r in results)
        runs[name] = metrics(np.array([r.pose for r in results]), truth)
    rigid, attitude = runs['rigid'], runs['attitude']
    # Since stop 58 (the vignetting learned and divided out): 0.029 against 0.0215 %; since
    # stop 61 (its symmetric part from 3 m) 0.0213 against 0.0139 (1.53x).
    assert attitude['t_rel_percent'] < 1.8 * rigid['t_rel_percent'], runs
    assert attitude['r_rel_deg_per_100m'] < 1.5 * rigid['r_rel_deg_per_100m'] + 0.1, runs


@pytest.mark.parametrize('scenario', ['gentle', 'obstacles'])
def test_self_calibration_leaves_an_exact_rigid_mounting_alone(scenario):
    """A rigid mount configured exactly, 30 Hz, 600 tracks, the shipped defaults: the yaw and
    camera_x self-calibration applies stay the configured ones. Consecutive pairs share
    their tracks, and their slips' errors are correlated over about 0.15 s: taken as
    independent, the fit was three standard deviations sure of a 0.025 deg yaw after 15
    pairs on `gentle` and applied it (with 400 tracks 0.021 deg after 102 pairs), which slid
    the drive sideways 2.4 mm a second (the one-second pose NEES on `obstacles` 6.8)."""
    from test.conftest import rendered
    drawn = rendered(scenario, 150, 0, rate=30.0, camera=None, mounting=None, suspension=None,
                     exposure=0.0, supersample=1, rolling_shutter=None)  # as conftest.drive
    vo = VisualOdometry.from_params(synth_camera_model(drawn),
                                    _params(drawn.mounting, {'max_features': 600}))
    for k, image in enumerate(drawn.images):
        vo.process(image, k / 30.0)
    assert abs(np.degrees(vo.mounting.yaw - drawn.mounting.yaw)) < 0.01
    assert abs(vo.mounting.x - drawn.mounting.x) < 0.005


@pytest.fixture(scope='module')
def miscalibrated_drive(tmp_path_factory):
    """A 46 m sprung-car drive whose params file is 1.5 deg off in pitch, roll and yaw and
    0.2 m in camera_x (the bag's images use the true mounting)."""
    out = tmp_path_factory.mktemp('calibration')
    bag, params = out / 'bag', out / 'in.yaml'
    result = synth.generate_bag(bag, 'car', frames=300, params_out=params,
                                configured_error=synth.MountingError(
                                    pitch=1.5, roll=-1.5, yaw=1.5, x=0.2))
    return result, bag, params, out


def _cli(name, *args):
    exe = resources.executable(name)
    return subprocess.run([exe, *map(str, args)], capture_output=True, text=True, timeout=300)


def test_self_calibration_holds_accuracy_from_a_wrong_mounting(miscalibrated_drive):
    result, bag, params, out = miscalibrated_drive
    tracked = out / 'tracked.yaml'
    tracked.write_text(params.read_text().replace(
        'ros__parameters:',
            'ros__parameters:\n    ground_model: plane\n    estimate_attitude: true', 1))
    run = _cli('planar_vo_replay', bag, '--params', tracked, '--json')
    assert run.returncode == 0, run.stderr
    summary = json.loads(run.stdout)
    accuracy = summary['accuracy']
    assert accuracy['path_length_m'] > 40.0
    assert accuracy['t_rel_percent'] <= 0.25, accuracy  # measured 0.103 %
    assert accuracy['r_rel_deg_per_100m'] <= 0.35, accuracy  # measured 0.138
    # The online estimate at the end of the drive, against the renderer's mounting
    # (measured: pitch 0.030, roll 0.120, yaw 0.028 deg, camera_x 6.7 mm off). The reported
    # std is held to the earlier, wider bounds (0.2, 0.2, 0.3 deg, 5 cm).
    learned, truth = summary['mounting'], result.mounting
    assert learned['seconds'] > 9.0, learned
    for name, true, bound, std_bound in (
            ('camera_pitch', truth.pitch, np.radians(0.08), np.radians(0.2)),
            ('camera_roll', truth.roll, np.radians(0.2), np.radians(0.2)),
            ('camera_yaw', truth.yaw, np.radians(0.07), np.radians(0.3)),
            ('camera_x', truth.x, 0.017, 0.05)):
        assert abs(learned[name]['value'] - true) <= bound, (name, learned[name], true)
        assert learned[name]['std'] is not None and learned[name]['std'] < std_bound, learned
    text = _cli('planar_vo_replay', bag, '--params', tracked)
    line = [x for x in text.stdout.splitlines() if x.startswith('self-calibrated mounting')]
    assert len(line) == 1, text.stdout
    assert re.search(r'camera_pitch [0-9.]+ deg \(\+- [0-9.]+\)', line[0]), line
    assert re.search(r'camera_x [0-9.]+ m \(\+- [0-9.]+\)', line[0]), line


def test_calibrate_recovers_the_mounting_and_the_height(miscalibrated_drive):
    result, bag, params, out = miscalibrated_drive
    truth, length = result.mounting, result.trajectory.length
    run = _cli('planar_vo_calibrate', bag, '--params', params, '--output', out / 'out.yaml',
               '--known-distance', length, '--json')
    assert run.returncode == 0, run.stderr
    report = json.loads(run.stdout)
    calibrated = config.load_params_file(out / 'out.yaml')
    # Measured with the plane model and the attitude: pitch 0.030, roll 0.120, yaw 0.028 deg,
    # camera_x 6.7 mm, height 0.12 mm off; with the local ground (the default now) the height
    # is 0.072-0.12 % off (its reported std is 0.1 %), the pitch 0.080 deg (0.084 since stop
    # 53: the road's history sampled where this camera's view begins, past its front wheels),
    # the rest within the same bounds.
    assert abs(np.degrees(calibrated['camera_pitch'] - truth.pitch)) <= 0.1, report
    assert abs(np.degrees(calibrated['camera_roll'] - truth.roll)) <= 0.2, report
    assert abs(np.degrees(calibrated['camera_yaw'] - truth.yaw)) <= 0.07, report
    assert abs(calibrated['camera_x'] - truth.x) <= 0.017, report
    assert abs(calibrated['camera_height'] / truth.height - 1) <= 0.0018, report
    assert report['kept'] == [] and all(np.isfinite(v) for v in report['std'].values())
    # Everything else of IN is kept as it was.
    original = config.load_params_file(params)
    assert {k: v for k, v in calibrated.items() if not k.startswith('camera_')} == {
        k: v for k, v in original.items() if not k.startswith('camera_')}


def test_calibrate_bad_input_is_one_line_and_exit_2(miscalibrated_drive, tmp_path):
    _, bag, params, _ = miscalibrated_drive
    existing = tmp_path / 'exists.yaml'
    existing.write_text('x')
    cases = [
        (['missing_bag', '--params', params, '--output', tmp_path / 'a.yaml'], 'missing_bag'),
        ([bag, '--params', tmp_path / 'nope.yaml', '--output', tmp_path / 'b.yaml'],
         'cannot read params file'),
        ([bag, '--params', params, '--output', existing], 'exists'),
        ([bag, '--params', params, '--output', tmp_path / 'c.yaml', '--known-distance', '-3'],
         'known-distance'),
        ([bag, '--output', tmp_path / 'd.yaml'], '--params'),
    ]
    for args, expected in cases:
        run = _cli('planar_vo_calibrate', *args)
        assert run.returncode == 2, (args, run.stderr)
        lines = run.stderr.strip().splitlines()
        assert len(lines) == 1 and expected in lines[0], (args, run.stderr)
        assert 'Traceback' not in run.stderr


def test_a_frame_rejected_for_too_few_inliers_teaches_the_attitude_nothing(sprung_car):
    """Every frame refined and then rejected (min_inliers above any frame's count): the
    attitude, its learned rate and spread and the self-calibration stay as they started."""
    renderer, _, images = sprung_car
    m = renderer.mounting
    params = config.validate({**config.mounting_params(m), 'ground_model': 'plane',
                              'estimate_attitude': True,
                              'min_inliers': 1000})
    vo = VisualOdometry.from_params(synth_camera_model(renderer), params)
    att = vo.attitude_filter
    start = (att.attitude.copy(), att.rate2.copy(), vo.mounting_estimate().seconds)
    statuses = {vo.process(image, k / 30.0).status for k, image in enumerate(images[:6])}
    assert statuses == {'first', 'reinitialized'}, statuses  # refined, then rejected
    assert np.array_equal(vo.attitude_filter.attitude, start[0])
    assert np.array_equal(vo.attitude_filter.rate2, start[1])
    assert vo.mounting_estimate().seconds == start[2] == 0.0
    assert vo.attitude_filter.height.samples == 0 and vo.attitude_filter.height.walk == 0


def test_a_rough_road_at_20_hz_keeps_tracking_through_its_jolts():
    """`rough` seed 4 at 20 Hz (the rate of the issue's renderer), 120 frames (6 s, 28 m):
    at frame 69 the body pitches 0.35 deg in one frame. When the hypotheses saw both frames
    at the reference's attitude with the 0.5 px inlier threshold, they found 3-7 inliers of
    500 there, three frames went unestimated and tracking restarted: t_rel 0.82 %. Now every
    frame is estimated; measured 0.094 %."""
    renderer, traj = synth.render_scenario('rough', 120, 4, rate=20.0)
    images = [renderer.render_frame(traj, k) for k in range(120)]
    met = _metrics(_run(renderer, images, renderer.mounting, sprung_body_params('rough'),
                        rate=20.0), traj)  # every frame estimated
    assert met['t_rel_percent'] < 0.2, met  # measured 0.0973 % now
    assert met['r_rel_deg_per_100m'] < 0.4, met  # measured 0.143


def test_a_sprung_car_at_20_hz_with_auto_exposure_changes():
    """The issue's hardest row as rendered here: the sprung `car` body at 20 Hz with the gain
    drifting and stepping within +-20 % (seed 2, 200 frames, 46 m). Every frame estimated,
    and nearly as accurate as without the gain changes. Measured: t_rel 0.046 % (0.038 %
    without), r_rel 0.16 deg/100 m (the design's bar for such a drive: 0.3 % and 2)."""
    rows = {}
    for exposure in (0.0, 0.2):
        renderer, traj = synth.render_scenario('car', 200, 2, rate=20.0, exposure=exposure)
        images = [renderer.render_frame(traj, k) for k in range(200)]
        rows[exposure] = _metrics(_run(renderer, images, renderer.mounting,
                                       sprung_body_params('car'), rate=20.0), traj)
    gains = renderer.exposure
    assert gains.max() / gains.min() > 1.2  # the gain did change
    # Measured now: t_rel 0.0425 % (0.0366 % without), r_rel 0.147 deg/100 m.
    assert rows[0.2]['t_rel_percent'] < 0.11, rows
    assert rows[0.2]['t_rel_percent'] < 1.5 * rows[0.0]['t_rel_percent'], rows
    assert rows[0.2]['r_rel_deg_per_100m'] < 0.4, rows


@pytest.mark.parametrize(('ground_model', 'bar'), [('plane', 0.3), ('local', 1.2)])
def test_a_camera_looking_back_drives_on_without_losing_its_tracks(ground_model, bar):
    """A rear camera (behind the rear axle, turned 180 deg) sees the ground move away while
    the car drives on: its tracks drift up to the horizon margin and must give their budget
    to new ones near the car. They kept it: on this flat drive (376x240, 90 frames) tracking
    restarted 5 times, t_rel 0.44 % with the plane, 3.5 % with the local ground; now none,
    0.14 and 0.72 % (the local ground expects to see the road its wheels will drive on:
    README, Limits)."""
    rear = synth.CameraMount(x=-0.9, y=0.0, height=1.1, roll=0.0, pitch=np.radians(8.0),
                             yaw=np.pi)
    results, truth = run_scenario('default', 90, seed=3, rate=20.0, mounting=rear,
                                  camera=synth.SynthCamera.scaled(376, 240),
                                  overrides={'ground_model': ground_model})
    assert [r.status for r in results].count('reinitialized') == 0
    m = metrics(np.array([r.pose for r in results]), truth)
    assert m['t_rel_percent'] < bar, m
