"""The camera front end: pairing, the odometry's camera, what to do with each image (no ROS)."""

import ast
from pathlib import Path

import numpy as np
import pytest

from planar_vo.core import config
from planar_vo.core.geometry.camera import CameraModel
from planar_vo.ros import camera_frontend
from planar_vo.ros.camera_frontend import (
    CHANGED,
    CREATED,
    INEXACT,
    NO_CAMERA_INFO,
    UNMATCHED,
    CameraFrontend,
)

K = np.array([[460.0, 0, 320], [0, 460.0, 240], [0, 0, 1]])
D = np.array([-0.25, 0.07, 0.0005, -0.0005, 0.0])
MS = 10**6


def camera(fx=460.0, width=640, height=480, dist=D):
    return CameraModel(np.array([[fx, 0, width / 2], [0, fx, height / 2], [0, 0, 1]]),
                       np.array(dist), 'plumb_bob', width, height)


# A broken driver's 8-coefficient plumb_bob: it folds over in the image (test_camera), so the
# odometry refuses it, as a first camera and as a new one.
FOLDED = [0.095, 0.054, -0.015, 0.108, -0.15, 0.136, -0.006, -0.054]


@pytest.fixture
def frontend():
    return CameraFrontend(config.defaults())


def test_images_before_any_camera_info_are_skipped(frontend):
    steps = frontend.add_image(1 * MS, 'image 1')
    assert [(s.image, s.process, s.skipped) for s in steps] == [
        ('image 1', False, NO_CAMERA_INFO)]
    assert steps[0].reasons == [NO_CAMERA_INFO]
    assert frontend.vo is None and frontend.camera is None


def test_the_first_good_camera_creates_the_odometry_and_a_repeat_changes_nothing(frontend):
    first = camera()
    assert frontend.add_info(1 * MS, first) == []
    (step,) = frontend.add_image(1 * MS, 'image 1')
    assert step.process and step.exact and step.camera == CREATED and step.reasons == []
    vo = frontend.vo
    assert vo is not None and vo.camera is first and frontend.camera is first
    # The driver repeats the calibration with every image: new objects, the same camera.
    frontend.add_info(2 * MS, camera())
    (step,) = frontend.add_image(2 * MS, 'image 2')
    assert step.process and step.camera is None
    assert frontend.vo is vo and frontend.camera is first


@pytest.mark.parametrize('changed', [camera(fx=500.0), camera(width=320, height=240),
                                     camera(dist=[-0.2, 0.05, 0, 0, 0])])
def test_a_new_calibration_goes_to_the_same_odometry(frontend, changed):
    frontend.add_info(1 * MS, camera())
    frontend.add_image(1 * MS, 'image 1')
    vo = frontend.vo
    frontend.add_info(2 * MS, changed)
    (step,) = frontend.add_image(2 * MS, 'image 2')
    assert step.process and step.camera == CHANGED
    assert frontend.vo is vo and vo.camera is changed and frontend.camera is changed


def test_a_refused_camera_keeps_the_previous_one(frontend):
    good = camera()
    frontend.add_info(1 * MS, good)
    frontend.add_image(1 * MS, 'image 1')
    frontend.add_info(2 * MS, camera(dist=FOLDED))
    (step,) = frontend.add_image(2 * MS, 'image 2')
    assert step.process and step.camera is None  # processed with the previous camera
    assert 'cannot be inverted' in step.refused
    assert step.reasons == [f'CameraInfo refused: {step.refused}']
    assert frontend.vo.camera is good and frontend.camera is good


def test_a_refused_first_camera_leaves_no_odometry(frontend):
    frontend.add_info(1 * MS, camera(dist=FOLDED))
    (step,) = frontend.add_image(1 * MS, 'image 1')
    assert not step.process and 'cannot be inverted' in step.skipped
    assert step.reasons == [f'CameraInfo refused: {step.refused}']
    assert frontend.vo is None and frontend.camera is None
    frontend.add_info(2 * MS, camera())  # then a good one
    (step,) = frontend.add_image(2 * MS, 'image 2')
    assert step.process and step.camera == CREATED


def test_an_image_waits_for_its_camera_info_then_uses_the_newest(frontend):
    frontend.add_info(1 * MS, camera())
    assert frontend.add_image(2 * MS, 'image 2') == []  # its CameraInfo may be just behind it
    assert frontend.waiting
    (step,) = frontend.add_info(2 * MS, camera())
    assert step.image == 'image 2' and step.exact and step.process
    assert frontend.add_image(3 * MS, 'image 3') == [] and frontend.waiting
    (step,) = frontend.flush()  # it did not come in time
    assert step.image == 'image 3' and not step.exact and step.process
    assert step.reasons == [INEXACT] and not frontend.waiting


def test_stamps_that_keep_not_matching_are_said_so():
    frontend = CameraFrontend(config.defaults())
    frontend.add_info(1 * MS, camera())
    reasons = []
    for k in range(2, 7):  # CameraInfo stamped 0.5 ms before its image, every time
        frontend.add_info(k * MS - MS // 2, camera())
        for step in frontend.add_image(k * MS, f'image {k}') + frontend.flush():
            reasons += step.reasons
    assert INEXACT in reasons and reasons[-1] == UNMATCHED


def test_rebuild_restarts_tracking_and_keeps_the_pose(frontend):
    frontend.rebuild()  # no camera yet: nothing to rebuild
    assert frontend.vo is None
    frontend.add_info(1 * MS, camera())
    frontend.add_image(1 * MS, 'image 1')
    old = frontend.vo
    old.set_pose(np.array([1.0, 2.0, 0.3]), np.eye(3) * 0.01)
    old.counters['estimated'] = 7
    frontend.rebuild(dict(config.defaults(), max_features=200))
    new = frontend.vo
    assert new is not old and new.camera is frontend.camera
    assert frontend.params['max_features'] == 200
    np.testing.assert_array_equal(new.pose, old.pose)
    np.testing.assert_array_equal(new.pose_covariance, old.pose_covariance)
    assert new.counters['estimated'] == 7


def test_imports_only_the_core_and_the_pairing():
    """No rclpy, no message package: the core is ROS-free (test_config), so is the pairing."""
    tree = ast.parse(Path(camera_frontend.__file__).read_text())
    imported = {node.module for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)}
    imported |= {alias.name for node in ast.walk(tree) if isinstance(node, ast.Import)
                 for alias in node.names}
    local = {m for m in imported if m.startswith('planar_vo.')}
    assert all(m.startswith('planar_vo.core') for m in local - {'planar_vo.ros.pairing'})
    assert imported - local <= {'__future__', 'collections.abc', 'dataclasses', 'typing',
                                'numpy'}, imported
