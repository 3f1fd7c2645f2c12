import numpy as np
import pytest

from planar_vo.core.geometry import solvers
from planar_vo.core.geometry.camera import CameraModel, CameraModelError, Mounting, level_to_base
from test.conftest import move_points, observe


@pytest.mark.parametrize('model, D', [
    ('plumb_bob', [-0.3, 0.09, 0.001, -0.001, -0.01]),
    ('rational_polynomial', [-0.3, 0.09, 0.001, -0.001, -0.01, 0.01, 0.002, 0.0]),
    ('equidistant', [-0.05, 0.01, -0.002, 0.0005]),
])
def test_undistortion_round_trip_under_strong_distortion(model, D):
    camera = CameraModel(K=np.array([[400.0, 0, 320], [0, 410.0, 240], [0, 0, 1]]), D=D,
                         distortion_model=model)
    rng = np.random.default_rng(0)
    normalized = rng.uniform(-0.7, 0.7, (200, 2))
    pixels = camera.distort(normalized)
    np.testing.assert_allclose(camera.normalize(pixels), normalized, atol=1e-7)


def test_uncalibrated_and_unknown_models_are_refused():
    with pytest.raises(CameraModelError, match='uncalibrated'):
        CameraModel(K=np.zeros((3, 3)))
    with pytest.raises(CameraModelError, match='not supported'):
        CameraModel(K=np.eye(3), D=[0.1, 0, 0, 0, 0], distortion_model='kannala')
    with pytest.raises(CameraModelError, match='coefficients'):
        CameraModel(K=np.eye(3), D=[0.1, 0, 0], distortion_model='plumb_bob')


def test_positive_pitch_looks_down():
    mounting = Mounting(height=1.0, pitch=np.deg2rad(10))
    optical_axis = mounting.base_from_optical @ [0.0, 0.0, 1.0]
    assert optical_axis[2] == pytest.approx(-np.sin(np.deg2rad(10)))
    assert optical_axis[0] > 0.98


def test_ground_points_round_trip_through_projection(car_camera):
    _, mounting = car_camera
    rng = np.random.default_rng(1)
    points = np.c_[rng.uniform(2.5, 15, 100), rng.uniform(-4, 4, 100)]
    rays = np.c_[observe(mounting, points), np.ones(100)]
    back, valid = mounting.ground_points(rays)
    assert valid.all()
    np.testing.assert_allclose(back, points, atol=1e-9)


def test_horizon_margin_rejects_rays_near_the_horizon():
    mounting = Mounting(height=1.0)
    depression = np.deg2rad([1.0, 5.0, 20.0])
    rays = np.c_[np.zeros(3), np.tan(depression), np.ones(3)]
    _, valid = mounting.ground_points(rays, min_depression=np.deg2rad(10))
    assert valid.tolist() == [False, False, True]
    _, above = mounting.ground_points(np.array([[0.0, -0.1, 1.0]]))
    assert not above.any()


def test_tilted_camera_gives_the_level_camera_answer():
    """A scene seen by a camera pitched 8 degrees down, rotated to level, gives the motion."""
    rng = np.random.default_rng(2)
    level = Mounting(height=1.5)
    tilted = Mounting(height=1.5, pitch=np.deg2rad(8.0))
    points = np.c_[rng.uniform(3, 12, 30), rng.uniform(-4, 4, 30)]
    motion = np.array([0.6, -0.2, -0.3])  # base motion; camera on the axle
    results = []
    for mounting in (level, tilted):
        m1 = observe(mounting, points)
        m2 = observe(mounting, move_points(points, motion))
        r1 = mounting.level_rays(np.c_[m1, np.ones(30)])
        r2 = mounting.level_rays(np.c_[m2, np.ones(30)])
        est = solvers.homography_npoint(r1, r2)
        results.append(solvers.paper_to_planar(est.theta, est.phi, est.rho * 1.5))
    np.testing.assert_allclose(results[0], motion, atol=1e-9)
    np.testing.assert_allclose(results[1], motion, atol=1e-9)
    # Without the rotation to level, the tilted camera's rays give a wrong motion.
    m1 = np.c_[observe(tilted, points), np.ones(30)]
    m2 = np.c_[observe(tilted, move_points(points, motion)), np.ones(30)]
    raw = solvers.homography_npoint(m1, m2)
    assert abs(raw.theta + motion[2]) > 1e-3 or abs(raw.rho * 1.5 - 0.6325) > 1e-3


def test_virtual_axle_camera_sees_ground_points_like_a_level_camera():
    rays = level_to_base(np.array([[4.0, 1.0]]), 1.2)
    assert rays.tolist() == [[-1.0, 1.2, 4.0]]  # left of the axle is -x in the optical frame


K640 = [[460.0, 0, 320], [0, 460.0, 240], [0, 0, 1]]


@pytest.mark.parametrize('K, D, size, reason', [
    ([[460.0, 0, 1e308], [0, 460, 240], [0, 0, 1]], [], (640, 480), 'principal point'),
    ([[1e-12, 0, 320], [0, 1e-12, 240], [0, 0, 1]], [], (640, 480), 'implausible'),
    ([[460.0, 0, 320], [0, 460, 240], [0, 0, 1]], [], (99999, 480), 'outside 1..16384'),
    ([[460.0, 0, 320], [0, 46, 240], [0, 0, 1]], [], (640, 480), 'aspect ratio'),
    ([[460.0, 200, 320], [0, 460, 240], [0, 0, 1]], [], (640, 480), 'skew'),
    ([[460.0, 0, 320], [0, 460, 240], [0, 0, 2]], [], (640, 480), 'last row'),
    ([[np.nan, 0, 320], [0, 460, 240], [0, 0, 1]], [], (640, 480), 'uncalibrated'),
    (K640, [np.nan, 0.0, 0.0, 0.0, 0.0], (640, 480), 'not all finite'),
])
def test_implausible_calibrations_are_refused_with_the_reason(K, D, size, reason):
    with pytest.raises(CameraModelError, match=reason):
        CameraModel(K=np.array(K), D=D, width=size[0], height=size[1])


def test_a_lens_model_that_cannot_be_inverted_over_the_ground_is_refused(car_camera):
    from planar_vo.core.odometry import VisualOdometry
    good, mounting = car_camera
    good = CameraModel(good.K, good.D, 'plumb_bob', 640, 480)
    vo = VisualOdometry(good, mounting)
    # Random 8-coefficient plumb_bob (a broken driver): the distortion folds over in the
    # image, so no undistortion can be trusted there. OpenCV's own projection says so:
    D = np.array([0.095, 0.054, -0.015, 0.108, -0.15, 0.136, -0.006, -0.054])
    bad = CameraModel(good.K, D, 'plumb_bob', 640, 480)
    error = bad.round_trip_px(np.array([[4.0, 464.0]]))
    assert error[0] > 100  # independent evidence: undistort/distort misses by far
    with pytest.raises(CameraModelError, match='cannot be inverted over the ground'):
        vo.set_camera(bad)
    assert vo.camera is good  # refused atomically: nothing of the bad model stays
    with pytest.raises(CameraModelError, match='cannot be inverted'):
        VisualOdometry(bad, mounting)
    # The strong but real distortion of the rendered bags passes the same check.
    assert good.round_trip_px(np.array([[4.0, 464.0], [636.0, 476.0]])).max() < 1e-3
