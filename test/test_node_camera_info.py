"""The node skips CameraInfo messages that repeat the calibration it has, and only those."""

import numpy as np
import pytest

from test.test_node import ros_env  # noqa: F401 - fixture: local DDS, own domain id


def _info(fx, *, d=(-0.25, 0.07, 0.0005, -0.0005, 0.0)):
    from sensor_msgs.msg import CameraInfo
    msg = CameraInfo(width=640, height=480, distortion_model='plumb_bob')
    msg.k = [fx, 0.0, 320.0, 0.0, fx, 240.0, 0.0, 0.0, 1.0]
    msg.d = list(d)
    return msg


@pytest.fixture
def node(ros_env):  # noqa: F811
    import rclpy
    from rclpy.context import Context

    from planar_vo.node import PlanarVoNode
    ctx = Context()
    rclpy.init(context=ctx)
    node = PlanarVoNode(context=ctx)
    yield node
    node.destroy_node()
    rclpy.try_shutdown(context=ctx)


def test_a_changed_calibration_after_repeats_is_applied(node):
    node._on_camera_info(_info(460.0))
    vo = node.vo
    assert vo is not None and vo.camera.K[0, 0] == 460.0
    node._on_camera_info(_info(460.0))  # the same again: nothing rebuilt
    assert node.vo is vo and node.camera.K[0, 0] == 460.0
    node._on_camera_info(_info(470.0))
    assert node.vo is vo and vo.camera.K[0, 0] == 470.0
    node._on_camera_info(_info(470.0, d=(-0.2, 0.05, 0.0, 0.0, 0.0)))
    np.testing.assert_allclose(vo.camera.D, [-0.2, 0.05, 0.0, 0.0, 0.0])


def test_a_refused_calibration_is_checked_again_each_time(node):
    node._on_camera_info(_info(0.0))  # uncalibrated: refused
    assert node.vo is None
    node._on_camera_info(_info(0.0))
    assert node.vo is None
    node._on_camera_info(_info(460.0))
    assert node.vo is not None and node.vo.camera.K[0, 0] == 460.0
