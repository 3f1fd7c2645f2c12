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

    from planar_vo.ros.node import PlanarVoNode
    ctx = Context()
    rclpy.init(context=ctx)
    node = PlanarVoNode(context=ctx)
    yield node
    node.destroy_node()
    rclpy.try_shutdown(context=ctx)


def test_a_changed_calibration_after_repeats_is_applied(node):
    """Repeats give the same CameraModel (not converted again); any change a new one.

    (CameraInfo is applied when the image of its stamp comes, see test_node_io.py.)
    """
    first = node._camera_model(_info(460.0))
    assert first.K[0, 0] == 460.0
    assert node._camera_model(_info(460.0)) is first  # the same again: nothing converted
    second = node._camera_model(_info(470.0))
    assert second is not first and second.K[0, 0] == 470.0
    third = node._camera_model(_info(470.0, d=(-0.2, 0.05, 0.0, 0.0, 0.0)))
    np.testing.assert_allclose(third.D, [-0.2, 0.05, 0.0, 0.0, 0.0])
    binned = _info(470.0, d=(-0.2, 0.05, 0.0, 0.0, 0.0))
    binned.binning_x = binned.binning_y = 2
    assert node._camera_model(binned).K[0, 0] == 235.0  # binning is part of the calibration


def test_a_refused_calibration_is_checked_again_each_time(node):
    from planar_vo.core.geometry.camera import CameraModelError
    for _ in range(2):  # uncalibrated: refused, every time
        with pytest.raises(CameraModelError):
            node._camera_model(_info(0.0))
    assert node._camera_model(_info(460.0)).K[0, 0] == 460.0
