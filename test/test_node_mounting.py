"""The node's self-calibration over real DDS: the estimated mounting in /diagnostics next to
the configured one, and one warning per parameter that is off, naming the value to set."""

import re

import numpy as np
import pytest

from test import test_node
from test.test_node import BagFrames, NodeProcess, Ros, send_lockstep, wait_for, warm_up

ros_env = test_node.ros_env  # the same fixture: LOCALHOST, a domain id of its own


@pytest.fixture(scope='module')
def miscalibrated(tmp_path_factory):
    """A sprung-car drive whose params file says pitch 1.5 deg more and roll 1 deg less."""
    from planar_vo import synth
    out = tmp_path_factory.mktemp('node_mounting')
    result = synth.generate_bag(out / 'bag', 'car', frames=150, params_out=out / 'in.yaml',
                                configured_error=synth.MountingError(pitch=1.5, roll=-1.0))
    return result, BagFrames(out / 'bag'), out / 'in.yaml'


def test_diagnostics_show_the_learned_mounting_and_the_node_says_what_to_set(
        ros_env, miscalibrated):
    from diagnostic_msgs.msg import DiagnosticArray
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import CameraInfo, Image
    result, bag, params = miscalibrated
    node = NodeProcess(ros_env, '--params-file', str(params), '-p', 'ground_model:=plane', '-p',
                       'estimate_attitude:=true',
                       '-p', 'image_reliability:=reliable')
    ros = Ros()
    try:
        image_pub = ros.publisher(Image, 'image')
        info_pub = ros.publisher(CameraInfo, 'camera_info')
        _, odoms = ros.collector(Odometry, 'odom')
        _, diagnostics = ros.collector(DiagnosticArray, '/diagnostics')
        info = bag.info_msg()
        warm_up(ros, image_pub, info_pub, info, bag.image_msg(0), odoms)
        for k in range(1, len(bag.images)):
            send_lockstep(image_pub, info_pub, info, bag.image_msg(k), odoms)
        n = len(diagnostics)
        wait_for(lambda: len(diagnostics) > n + 1, 5.0, 'diagnostics after the drive')
        values = {kv.key: kv.value for kv in diagnostics[-1].status[0].values}
        estimated = float(values['camera_pitch estimated (deg)'].split('+-')[0])
        assert abs(estimated - np.degrees(result.mounting.pitch)) < 0.3, values
        configured = float(values['camera_pitch configured (deg)'])
        assert abs(configured - np.degrees(result.mounting.pitch) - 1.5) < 1e-3, values
        assert 'camera_x estimated (m)' in values and 'camera_yaw configured (deg)' in values
        warnings = [line for line in node.lines if 'the drive says' in line]
        pitch = [line for line in warnings if 'camera_pitch is configured' in line]
        assert len(pitch) == 1, warnings
        value = float(re.search(r'set camera_pitch: ([-0-9.]+)', pitch[0]).group(1))
        assert abs(np.degrees(value - result.mounting.pitch)) < 0.3, pitch
        assert len(warnings) == len({line.split(' is configured')[0] for line in warnings})
        assert node.alive()
    finally:
        ros.close()
        assert node.stop() == 0
        assert 'Traceback' not in node.output, node.output
