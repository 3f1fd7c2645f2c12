"""The per-frame pipeline on rendered scenes: accuracy, and bad input that must not lose motion."""

import numpy as np
import pytest

from planar_vo.core import config
from planar_vo.core.frontend.tracker import Tracker
from planar_vo.core.geometry.camera import CameraModel, Mounting
from planar_vo.core.geometry.se2 import compose
from planar_vo.core.metrics import metrics
from planar_vo.core.odometry import VisualOdometry
from test.conftest import drive, run_scenario, sprung_body_params


def poses(results):
    return np.array([r.pose for r in results])


# Measured on 150 frames (5 s; deterministic, the same values in two runs), t_rel % /
# r_rel deg/100 m / scale: `straight` 0.0317 / 0.266 / 0.99974, `gentle` 0.0327 / 0.151 /
# 0.99973, `tight` 0.0376 / 0.363 / 0.99966, `obstacles` 0.0424 / 0.575 / 0.99974. Each bound
# is about 2.5x its own scenario's value (the design bar is 0.3 % and 2 deg/100 m). The
# covariances are checked against the true twist and poses in test_consistency (the same runs).
SCENARIO_BOUNDS = {'straight': (0.08, 0.7), 'gentle': (0.08, 0.4), 'tight': (0.09, 0.9),
                   'obstacles': (0.1, 1.4)}


@pytest.mark.parametrize('scenario', ['straight', 'gentle', 'tight', 'obstacles'])
def test_scenarios_within_bounds(scenario):
    results, truth, _ = drive(scenario, 150, 30.0)
    assert all(r.status in ('first', 'ok') for r in results)
    m = metrics(poses(results), truth)
    t_rel, r_rel = SCENARIO_BOUNDS[scenario]
    assert m['t_rel_percent'] < t_rel, m
    assert m['r_rel_deg_per_100m'] < r_rel, m
    assert abs(m['scale_ratio'] - 1) < 0.0008, m  # measured 0.99966-0.99974


@pytest.mark.parametrize('model, fx, t_rel, scale', [
    # Measured 0.0283 % / 0.99977 and 0.0174 % / 0.99987 when written; stop 43 0.0221 %,
    # 0.99988 and 0.0439 %, 0.99966; stop 44 (the road ahead no longer read as the camera's
    # tilt before the history can read it) 0.0182 %, 0.99993 and 0.0447 %, 0.99958.
    ('rational_polynomial', 460.0, 0.07, 0.0006),
    ('equidistant', 300.0, 0.06, 0.0006)])
def test_other_lens_models_end_to_end(model, fx, t_rel, scale):
    """Images rendered through each CameraInfo lens model (equidistant: a fisheye whose
    corners look 80 degrees off axis) give the same accuracy as the plumb_bob scenarios."""
    from planar_vo.synth import SynthCamera
    camera = SynthCamera.scaled(640, 480, fx=fx, fy=fx, distortion_model=model)
    results, truth = run_scenario('gentle', 90, camera=camera)
    assert all(r.status in ('first', 'ok') for r in results)
    m = metrics(poses(results), truth)
    assert m['t_rel_percent'] < t_rel, m
    assert abs(m['scale_ratio'] - 1) < scale, m


def test_blank_frames_are_skipped_without_losing_motion():
    blank = {40, 41, 42}

    def corrupt(k, image, stamp):
        return (np.full_like(image, 128) if k in blank else image), stamp

    results, truth = run_scenario('gentle', 90, corrupt=corrupt)
    statuses = [r.status for r in results]
    assert [statuses[k] for k in sorted(blank)] == ['blank'] * 3
    # At 6 m/s four frames apart (0.8 m) KLT follows from where the last twist predicts the
    # tracks, in the last good image warped by that motion (without the warp tracking
    # restarted and the gap was extrapolated): no frame is lost after the gap.
    assert statuses[43:] == ['ok'] * (90 - 43)
    m = metrics(poses(results), truth)
    assert m['final_drift_percent'] < 0.1, m  # measured 0.039 %
    # The held pose is distrusted while the vehicle moves unseen.
    assert results[42].pose_covariance[0, 0] > 10 * results[39].pose_covariance[0, 0]


def test_time_jump_backwards_restarts_tracking_and_keeps_the_pose():
    def corrupt(k, image, stamp):
        return image, (stamp - 5.0 if k >= 50 else stamp)

    results, _ = run_scenario('straight', 70, corrupt=corrupt)
    assert results[50].status == 'time_jump'
    assert 'time jumped' in results[50].message
    np.testing.assert_allclose(results[50].pose, results[49].pose)
    assert results[50].pose_covariance[0, 0] >= 1.0
    assert [r.status for r in results[51:]] == ['ok'] * 19


def test_frames_that_cannot_be_estimated_are_measured_later_against_the_reference():
    """Frames 30-31 are shifted: no ground motion fits them, but some tracks survive."""
    def corrupt(k, image, stamp):
        if k in (30, 31):
            image = np.roll(image, 60, axis=0)  # nothing matches the ground any more
        return image, stamp

    results, truth = run_scenario('straight', 60, corrupt=corrupt)
    assert [r.status for r in results[30:33]] == ['no_estimate', 'no_estimate', 'ok']
    # Frame 32 was matched against frame 29: its motion spans three frames, none lost.
    m = metrics(poses(results), truth)
    assert m['final_drift_percent'] < 0.12, m  # measured 0.045 %
    assert m['scale_ratio'] == pytest.approx(1.0, abs=0.0012)  # measured 0.99956


def test_lost_tracking_reinitialises_and_extrapolates_the_unseen_motion():
    lost = set(range(30, 40))

    def corrupt(k, image, stamp):
        if k in lost:  # sensor noise only: nothing can be tracked from frame to frame
            image = np.random.default_rng(k).integers(0, 256, image.shape, dtype=np.uint8)
        return image, stamp

    results, truth = run_scenario('straight', 60, corrupt=corrupt)
    assert any(r.status == 'reinitialized' for r in results[30:40])
    assert results[-1].status == 'ok'
    # Motion while lost is extrapolated from the last twist, not dropped: the straight path
    # at constant speed is recovered to a few hundredths of a percent.
    final = results[-1].pose
    assert final[0] == pytest.approx(truth[-1, 0], rel=0.001)  # measured -0.031 %
    assert results[-1].pose_covariance[0, 0] > 0.01


def test_compose_propagates_covariance():
    pose, cov = compose(np.array([1.0, 2.0, np.pi / 2]), np.diag([0.0, 0.0, 0.01]),
                        np.array([1.0, 0.0, 0.0]), np.zeros((3, 3)))
    np.testing.assert_allclose(pose, [1.0, 3.0, np.pi / 2], atol=1e-12)
    # A yaw uncertainty of 0.1 rad becomes 0.1 m sideways (along -x) after 1 m.
    assert cov[0, 0] == pytest.approx(0.01)
    assert cov[1, 1] == pytest.approx(0.0, abs=1e-15)


def test_duplicate_stamps_and_wrong_sizes_are_skipped_not_restarts():
    def corrupt(k, image, stamp):
        if k == 20:
            return image, 19 / 30.0  # the driver sent frame 19's stamp again
        if k == 25:
            return image[:240, :320].copy(), stamp  # binned image, full-size CameraInfo
        return image, stamp

    results, truth = run_scenario('gentle', 40, corrupt=corrupt)
    assert results[20].status == 'duplicate' and 'duplicate' in results[20].message
    assert results[25].status == 'skipped' and '320x240' in results[25].message
    assert [r.status for r in results[26:]] == ['ok'] * 14
    m = metrics(poses(results), truth)
    assert m['final_drift_percent'] < 0.06, m  # measured 0.024 %


def test_blank_frame_after_a_gap_does_not_become_the_reference():
    def corrupt(k, image, stamp):
        if k == 30:
            return np.zeros_like(image), stamp + 5.0
        return image, (stamp + 5.0 if k > 30 else stamp)

    results, _ = run_scenario('straight', 40, corrupt=corrupt)
    assert results[30].status == 'blank'
    assert results[31].status == 'time_jump'
    assert [r.status for r in results[32:]] == ['ok'] * 8


def test_an_exception_inside_process_leaves_the_state_as_it_was():
    """A frame OpenCV cannot track (float pixels: a caller's bug) raises, and changes nothing."""
    import cv2

    from planar_vo.core.odometry import VisualOdometry
    from test.test_properties import PARAMS, Frames
    frames = Frames(6)
    vo = VisualOdometry.from_params(frames.camera, PARAMS)
    for k in range(3):
        vo.process(frames.images[k], frames.stamps[k])
    before = (vo.pose.copy(), vo.tracker.points.copy(), vo.gate.last_stamp, dict(vo.counters))
    with pytest.raises(cv2.error):
        vo.process(frames.images[3].astype(np.float64), frames.stamps[3])
    np.testing.assert_array_equal(vo.pose, before[0])
    np.testing.assert_array_equal(vo.tracker.points, before[1])
    assert vo.gate.last_stamp == before[2] and vo.counters == before[3]
    # ... so the next frames go on as if the bad one had never come.
    assert [vo.process(frames.images[k], frames.stamps[k]).status for k in (3, 4, 5)] == [
        'ok', 'ok', 'ok']


def _relative(a, b):
    """Pose b in the frame of pose a (x, y, yaw)."""
    c, s = np.cos(a[2]), np.sin(a[2])
    dx, dy = b[:2] - a[:2]
    return np.array([c * dx + s * dy, -s * dx + c * dy, np.angle(np.exp(1j * (b[2] - a[2])))])


def _render(scenario, frames):
    from planar_vo import synth
    from planar_vo.core.odometry import VisualOdometry
    from test.conftest import synth_camera_model
    renderer, traj = synth.render_scenario(scenario, frames, 0)
    camera = synth_camera_model(renderer)
    images = [renderer.render(traj.x[k], traj.y[k], traj.yaw[k], k) for k in range(frames)]
    from planar_vo.core import config
    vo = VisualOdometry.from_params(camera, config.defaults())
    return vo, camera, images, np.c_[traj.x, traj.y, traj.yaw]


def test_set_pose_continues_from_the_given_pose_and_covariance():
    vo, _, images, truth = _render('gentle', 40)
    for k in range(20):
        assert vo.process(images[k], k / 30.0).status in ('first', 'ok')
    given = np.array([10.0, -3.0, 1.0])
    vo.set_pose(given, np.diag([0.04, 0.09, 0.01]))
    results = [vo.process(images[k], k / 30.0) for k in range(20, 40)]
    assert all(r.status == 'ok' for r in results)
    # The pose set applies to the last estimated frame (19); motion since then is composed on.
    expected, _ = compose(given, np.zeros((3, 3)), _relative(truth[19], truth[39]),
                          np.zeros((3, 3)))
    # Measured: 0.80 and 0.59 mm, 1.2e-4 rad.
    np.testing.assert_allclose(results[-1].pose[:2], expected[:2], atol=0.002)
    assert abs(results[-1].pose[2] - expected[2]) < 0.0003
    assert results[0].pose_covariance[0, 0] >= 0.04 and results[0].pose_covariance[1, 1] >= 0.09


def test_a_camera_briefly_of_another_size_keeps_the_tracks():
    """A wrong CameraInfo (another size) used for one frame, then the right one again: only
    that frame is lost; the next is measured from the tracks of the frame before it."""
    from planar_vo.core.geometry.camera import CameraModel
    vo, camera, images, truth = _render('gentle', 30)
    results = [vo.process(images[k], k / 30.0) for k in range(20)]
    vo.set_camera(CameraModel(camera.K, camera.D, camera.distortion_model, camera.width + 1,
                              camera.height))
    results.append(vo.process(images[20], 20 / 30.0))
    vo.set_camera(camera)
    results += [vo.process(images[k], k / 30.0) for k in range(21, 30)]
    assert results[20].status == 'skipped'
    assert [r.status for r in results[21:]] == ['ok'] * 9
    expected = _relative(truth[19], truth[29])
    got = _relative(results[19].pose, results[29].pose)
    # Measured: 0.53 mm, 6.9e-5 rad.
    assert np.hypot(*(got[:2] - expected[:2])) < 0.0015 and abs(got[2] - expected[2]) < 0.0002


def test_a_new_image_size_restarts_tracking_and_keeps_the_motion():
    """Binning switched on mid-run: a CameraInfo of the new size, tracking restarts."""
    import cv2

    from planar_vo.core.geometry.camera import CameraModel
    vo, camera, images, truth = _render('gentle', 40)
    binned = CameraModel(np.diag([0.5, 0.5, 1.0]) @ camera.K, camera.D,
                         camera.distortion_model, camera.width // 2, camera.height // 2)
    results = [vo.process(images[k], k / 30.0) for k in range(20)]
    vo.set_camera(binned)
    for k in range(20, 40):
        small = cv2.resize(images[k], (binned.width, binned.height),
                           interpolation=cv2.INTER_AREA)
        results.append(vo.process(small, k / 30.0))
    assert results[20].status == 'reinitialized' and 'size changed' in results[20].message
    assert [r.status for r in results[21:]] == ['ok'] * 19
    # Frame 20's motion is extrapolated, the rest measured at half resolution.
    m = metrics(poses(results), truth)
    assert m['final_drift_percent'] < 0.3, m  # measured 0.121 %


@pytest.mark.parametrize('scenario, frames, rate, r_rel', [
    ('gentle', 150, 30.0, 0.4), ('default', 90, 15.0, 0.75), ('obstacles', 150, 30.0, 1.0)])
def test_klt_prewarp_takes_out_the_bias_of_windows_that_deform(scenario, frames, rate, r_rel):
    """The default, KLT matched against the last image warped by the predicted motion and a
    0.5 px inlier threshold, against the earlier default (no warp, 1 px), on the renderer's
    truth. Measured t_rel % / r_rel (deg/100 m): `gentle` 0.048 / 0.65 -> 0.039 / 0.25,
    `default` at 15 Hz 0.072 / 0.79 -> 0.033 / 0.41, `obstacles` 0.045 / 0.88 -> 0.051 /
    0.87. Among many boxes the warp needs the tighter threshold: with 1 px, tracks on the
    boxes that fit the ground to under 1 px biased the yaw (0.086 / 1.96). Measured now
    (on / off): `gentle` 0.0327 / 0.151 against 0.0748 / 0.889, `default` 0.0267 / 0.293
    against 0.107 / 0.715, `obstacles` 0.0424 / 0.575 against 0.0664 / 1.32."""
    got = {}
    for prewarp, threshold in ((False, 1.0), (True, 0.5)):
        overrides = {'klt_prewarp': prewarp, 'inlier_threshold': threshold}
        if sprung_body_params(scenario) is None and all(
                config.defaults()[name] == value for name, value in overrides.items()):
            # The shipped defaults on a rigid body: the very run of drive() (the same frames,
            # the same params), shared with test_scenarios_within_bounds and test_consistency.
            results, truth, _ = drive(scenario, frames, rate)
        else:
            results, truth = run_scenario(scenario, frames, rate=rate, overrides=overrides)
        assert all(r.status in ('first', 'ok') for r in results)
        got[prewarp] = metrics(poses(results), truth)
    off, on = got[False], got[True]
    assert on['t_rel_percent'] < 0.06, on  # 1.4-2.2x the values measured
    assert on['r_rel_deg_per_100m'] < r_rel, on  # 1.7-2.7x
    if scenario != 'obstacles':  # there, as good, not better
        assert on['t_rel_percent'] < 0.85 * off['t_rel_percent'], (on, off)
        assert on['r_rel_deg_per_100m'] < 0.6 * off['r_rel_deg_per_100m'], (on, off)


def test_constructor_defaults_are_the_parameter_schemas():
    """Library users who build VisualOdometry directly get what the node runs by default."""
    K = np.array([[460.0, 0.0, 320.0], [0.0, 460.0, 240.0], [0.0, 0.0, 1.0]])
    camera = CameraModel(K, np.zeros(5), 'plumb_bob', 640, 480)
    mounting = Mounting(x=1.2, y=0.0, height=1.25, roll=0.0, pitch=np.radians(8.0), yaw=0.0)
    direct = VisualOdometry(camera, mounting)
    params = {**config.defaults(), 'camera_x': 1.2, 'camera_y': 0.0, 'camera_height': 1.25,
              'camera_roll': 0.0, 'camera_pitch': np.radians(8.0), 'camera_yaw': 0.0}
    schema = VisualOdometry.from_params(camera, params)
    for name in ('horizon_margin', 'ransac_method', 'inlier_threshold', 'ransac_confidence',
                 'circular_refine', 'min_inliers'):
        assert getattr(direct, name) == getattr(schema, name), name
    assert direct.gate.max_frame_gap == schema.gate.max_frame_gap
    for name in ('klt_prewarp', 'klt_first_search'):
        assert getattr(direct.front, name) == getattr(schema.front, name), name
    attitudes = (direct.attitude_filter, schema.attitude_filter)
    assert (attitudes[0] is None) == (attitudes[1] is None)
    if attitudes[0] is not None:
        assert attitudes[0].self_calibrate == attitudes[1].self_calibrate
        for name in ('tilt_sigma', 'tilt_rate', 'height_sigma', 'height_rate'):
            assert getattr(attitudes[0].noise, name) == getattr(attitudes[1].noise, name)
    for name in ('max_features', 'quality_level', 'min_distance', 'window', 'levels',
                 'fb_threshold'):
        assert getattr(direct.tracker, name) == getattr(schema.tracker, name), name
    tracker, d = Tracker(), config.defaults()  # the tracker's own defaults are the schema's
    assert (tracker.max_features, tracker.quality_level, tracker.min_distance, tracker.window,
            tracker.levels, tracker.fb_threshold) == (
        d['max_features'], d['quality_level'], schema.tracker.min_distance, d['klt_window'],
        d['klt_levels'], d['fb_threshold'])


@pytest.mark.parametrize(('size', 'configured', 'binning', 'spacing'), [
    ((640, 480), 0.0, 0, 8.0), ((752, 480), 0.0, 0, 8.0), ((376, 240), 0.0, 0, 8.0),
    ((1280, 720), 0.0, 0, 8.0 * np.sqrt(1280 * 720 / (752 * 480))),  # 13.1 px
    ((1920, 1080), 0.0, 1, 8.0 * np.sqrt(1920 * 1080 / (752 * 480))),  # 19.2 px
    ((1920, 1080), 0.0, 0, 8.0 * np.sqrt(960 * 540 / (752 * 480))),  # binned 2x2: 9.6 px
    ((1920, 1080), 5.0, 1, 5.0), ((376, 240), 12.0, 0, 12.0)])
def test_features_keep_their_spread_on_a_larger_image(size, configured, binning, spacing):
    """min_distance 0 (the default) is 8 px up to 752x480 and grows with the side of the
    image tracked beyond it (the same features 8 px apart crowd a 720p image: README, Camera
    input); a configured value is used as it is."""
    width, height = size
    K = np.array([[0.7 * width, 0.0, width / 2], [0.0, 0.7 * width, height / 2], [0, 0, 1.0]])
    camera = CameraModel(K, np.zeros(5), 'plumb_bob', width, height)
    params = {**config.defaults(), 'min_distance': configured, 'image_binning': binning,
              'camera_x': 1.2, 'camera_height': 1.25, 'camera_pitch': np.radians(8.0)}
    assert VisualOdometry.from_params(camera, params).tracker.min_distance == pytest.approx(
        spacing)


@pytest.mark.parametrize(('size', 'configured', 'binning'), [
    ((752, 480), 0, 1), ((1280, 720), 0, 1), ((1600, 900), 0, 1), ((1920, 1080), 0, 2),
    ((3840, 2160), 0, 3), ((752, 480), 2, 2), ((1920, 1080), 1, 1)])
def test_images_over_one_and_a_half_megapixels_are_binned(size, configured, binning):
    """image_binning 0 (the default): none up to 1.5 megapixels, above it the least factor
    that brings the image under them; the camera model is the binned image's: a ground
    point lands where the full camera puts it, in binned pixels (closed form: a binned pixel
    u' covers full pixels b u' .. b u' + b - 1, u' = (u - (b - 1) / 2) / b)."""
    width, height = size
    K = np.array([[0.6 * width, 0.0, width / 2 + 3.0], [0.0, 0.6 * width, height / 2 - 2.0],
                  [0, 0, 1.0]])
    D = np.array([-0.25, 0.07, 0.0005, -0.0005, 0.0])
    camera = CameraModel(K, D, 'plumb_bob', width, height)
    params = {**config.defaults(), 'image_binning': configured, 'camera_x': 1.2,
              'camera_height': 1.25, 'camera_pitch': np.radians(8.0)}
    vo = VisualOdometry.from_params(camera, params)
    assert vo.binning == binning
    assert (vo.camera.width, vo.camera.height) == (width // binning, height // binning)
    full = camera.distort(np.array([[0.1, 0.3], [-0.2, 0.25]]))
    binned = vo.camera.distort(np.array([[0.1, 0.3], [-0.2, 0.25]]))
    np.testing.assert_allclose(binned, (full - 0.5 * (binning - 1)) / binning, atol=1e-9)


def test_pose_covariance_holds_correlated_step_errors_and_a_persistent_scale_error():
    """Against simulation: steps whose errors are exponentially correlated over the model's
    time constant, and a scale error that persists over the second; the pose covariance
    accumulated step by step must carry both, at 15 and at 30 Hz."""
    from planar_vo.core.odometry import covariance
    rng = np.random.default_rng(7)
    tau, sigma = covariance.ERROR_CORRELATION_S, 1e-3
    for rate in (15.0, 30.0):
        dt, steps = 1.0 / rate, int(10 * rate)
        rho = np.exp(-dt / tau)
        errors = np.empty((4000, steps))
        errors[:, 0] = rng.normal(0.0, sigma, 4000)
        for k in range(1, steps):
            errors[:, k] = rho * errors[:, k - 1] + rng.normal(0.0, sigma * np.sqrt(1 - rho ** 2),
                                                                4000)
        simulated = errors.sum(axis=1).var()
        pose, cov = np.zeros(3), np.zeros((3, 3))
        for _ in range(steps):  # no motion: only the correlated part
            pose, cov = compose(pose, cov, np.zeros(3), covariance.shared_error_covariance(
                np.zeros(3), np.diag([sigma ** 2, 0.0, 0.0]), dt))
        assert 0.9 < cov[0, 0] / simulated < 1.1, (rate, cov[0, 0], simulated)
        # A scale error s held over 1 s at 5 m/s moves the pose by s * 5 m along the track.
        speed, scale = 5.0, rng.normal(0.0, covariance.SHARED_SCALE_ERROR, 4000)
        pose, cov = np.zeros(3), np.zeros((3, 3))
        for _ in range(int(rate)):
            pose, cov = compose(pose, cov, np.array([speed * dt, 0.0, 0.0]),
                                covariance.shared_error_covariance(
                                    np.array([speed * dt, 0.0, 0.0]), np.zeros((3, 3)), dt))
        assert 0.9 < cov[0, 0] / (scale * speed).var() < 1.1, (rate, cov[0, 0])


def test_a_binned_drive_holds_and_reports_its_tracks_in_the_image_given():
    """752x480 frames binned 2x2 (image_binning 2) against the renderer's truth (measured:
    t_rel 0.035 %, 0.021 unbinned); the debug image's tracks are in the pixels of the image
    the odometry was given, not of the binned one it tracked."""
    from planar_vo.synth import SynthCamera
    results, truth = run_scenario('gentle', 60, seed=0, rate=20.0,
                                  camera=SynthCamera.scaled(752, 480),
                                  overrides={'image_binning': 2})
    assert [r.status for r in results].count('ok') == 59
    m = metrics(np.array([r.pose for r in results]), truth)
    assert m['t_rel_percent'] < 0.1, m
    points = np.concatenate([r.inlier_points for r in results])
    assert points[:, 0].max() > 600 and points[:, 1].max() > 400  # beyond 376x240
    assert np.all((points >= 0) & (points < [752, 480]))
