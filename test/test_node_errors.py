"""An unexpected exception inside a node callback: one ERROR line, a counter, no crash.

The node runs in this process (real rclpy, its own Context and domain): a callback is
handed something that is not an Image, as a bug elsewhere might, and the node must report
it as an error of its own (not as bad input) and keep working.
"""

import time

import pytest

from planar_vo.ros.background import BackgroundSpin


@pytest.fixture
def in_process_node(rclpy_context):
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    from planar_vo.ros.node import PlanarVoNode
    node = PlanarVoNode(context=rclpy_context)
    listener = rclpy.create_node('diagnostics_listener', context=rclpy_context)
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(node)
    executor.add_node(listener)
    spin = BackgroundSpin(executor, listener)
    yield node, listener
    spin.stop()
    node.destroy_node()
    listener.destroy_node()


def test_unexpected_exception_is_one_error_line_and_counted(in_process_node, capfd):
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import CameraInfo

    node, listener = in_process_node
    info = CameraInfo(width=640, height=480, distortion_model='plumb_bob')
    info.k = [460.0, 0.0, 320.0, 0.0, 460.0, 240.0, 0.0, 0.0, 1.0]
    got = []
    listener.create_subscription(DiagnosticArray, '/diagnostics', got.append, 10)
    node._on_camera_info(info)
    for _ in range(3):  # not an Image: AttributeError deep in the decoding
        assert node._on_image(object(), {}) is None  # returns: the node is not taken down
    end = time.monotonic() + 10
    while time.monotonic() < end and not any(
            kv.key == 'unexpected errors' and kv.value == '3'
            for arr in got for st in arr.status for kv in st.values):
        time.sleep(0.01)
    values = {kv.key: kv.value for st in got[-1].status for kv in st.values}
    assert values['unexpected errors'] == '3'
    err = capfd.readouterr().err
    lines = [line for line in err.splitlines() if 'unexpected' in line]
    assert len(lines) == 1, err  # the same cause, throttled
    assert '[ERROR]' in lines[0]
    assert 'AttributeError while handling an image' in lines[0]
    assert "'object' object has no attribute" in lines[0]  # the exception's own message
    assert 'Traceback' not in err


def test_warnings_are_throttled_per_cause_with_bounded_memory(in_process_node, capfd):
    node, _ = in_process_node
    node._warn('image data has 100 bytes, mono8 640x480 needs 307200')
    node._warn('image data has 7 bytes, mono8 320x240 needs 76800')  # same cause, numbers
    node._warn("image encoding 'mono16' is not supported")  # a different cause: at once
    node._warn("image encoding 'bgr8' is not supported")  # digits in names are not numbers
    lines = [line for line in capfd.readouterr().err.splitlines() if '[WARN]' in line]
    assert len(lines) == 3, lines
    assert 'mono16' in lines[1] and 'bgr8' in lines[2]
    letters = 'abcdefghij'
    for k in range(100):  # 100 distinct causes: only the most recent are remembered
        node._warn(f'cause {letters[k // 10]}{letters[k % 10]}')
    assert len(node._throttle._seen) == 64


def test_an_image_counts_as_arrived_when_the_middleware_received_it(monkeypatch):
    """A frame queued 0.3 s while the node was busy arrived 0.3 s ago, not now. The node's
    clocks are replaced by fixed ones: exact, whatever the machine's load."""
    from types import SimpleNamespace

    from planar_vo.ros import node as node_module
    from planar_vo.ros.node import _received_monotonic
    now, wall_ns = 1000.0, 1_700_000_000 * 10**9
    monkeypatch.setattr(node_module, 'time', SimpleNamespace(monotonic=lambda: now,
                                                             time_ns=lambda: wall_ns))
    assert _received_monotonic({'received_timestamp': wall_ns - 300_000_000}) == now - 0.3
    assert _received_monotonic({'received_timestamp': wall_ns}) == now
    assert _received_monotonic({'received_timestamp': 0}) == now  # not filled in: now
    assert _received_monotonic({}) == now
    assert _received_monotonic({'received_timestamp': wall_ns + 10**9}) == now  # clock step
    assert _received_monotonic({'received_timestamp': wall_ns - 10**12}) == now  # too old


def test_a_busy_node_drops_only_images_older_than_the_newest_by_stale_after():
    """The processing thread takes the oldest image that is not stale: a short hiccup is
    worked off, a long one costs frames instead of a growing delay."""
    from planar_vo.ros.node import STALE_AFTER, stale_images
    assert stale_images([5.0]) == 0
    assert stale_images([5.0, 5.0 + 0.5 * STALE_AFTER]) == 0  # a hiccup: both processed
    assert stale_images([5.0, 5.01, 5.0 + 1.5 * STALE_AFTER]) == 2
    assert stale_images([5.0, 5.0 + STALE_AFTER]) == 0  # exactly at the bound: kept
