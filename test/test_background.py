"""BackgroundSpin: the spinning thread has left the executor before anything is destroyed."""

import time

from planar_vo.ros.background import BackgroundSpin


def test_stop_returns_after_the_thread_left_the_executor_while_messages_flow(rclpy_context):
    """Stopped in the middle of a stream of messages, 20 times: each time the thread has
    ended when stop() returns, so destroying the node and the context cannot meet it inside
    a wait (executor.shutdown() alone does not wait for a thread in spin())."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from std_msgs.msg import String
    node = rclpy.create_node('background_spin_test', context=rclpy_context)
    got = []
    node.create_subscription(String, 'chatter', got.append, 10)
    pub = node.create_publisher(String, 'chatter', 10)
    for _ in range(20):
        executor = SingleThreadedExecutor(context=rclpy_context)
        executor.add_node(node)
        spin = BackgroundSpin(executor, node)
        before, end = len(got), time.monotonic() + 30.0
        while len(got) < before + 3 and time.monotonic() < end:  # it spins: messages come
            pub.publish(String(data='x'))
            time.sleep(0.002)
        assert len(got) >= before + 3
        assert spin.stop()
    node.destroy_node()
