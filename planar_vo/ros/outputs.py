"""What the node publishes for each frame.

``odom``, odom -> base_link on /tf, ``~/path`` and ``~/debug_image``.
"""

from __future__ import annotations

from collections import deque
from typing import Any

from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry, Path
from rclpy.node import Node
from sensor_msgs.msg import Image

from planar_vo.core import config
from planar_vo.core.odometry import FrameResult, FrameStatus
from planar_vo.ros import messages

__all__ = ['OdometryOutputs']

_PATH_STEP = 0.05  # m or rad between poses appended to ~/path


class OdometryOutputs:
    """The node's publishers of one frame's odometry, as the output parameters ask."""

    def __init__(self, node: Node, params: config.Params) -> None:
        self._node = node
        self.params = params  # the node's parameter values: it sets new ones on a change
        self.odom_pub = node.create_publisher(Odometry, 'odom', 10)
        self._path_pub = node.create_publisher(Path, '~/path', 1)
        self._debug_pub = node.create_publisher(Image, '~/debug_image', 1)
        self._path_poses: deque[PoseStamped] = deque(maxlen=params['path_max_poses'])
        self._tf = None
        self._tf_missing = False
        self.update()

    def update(self) -> None:
        """Follow changed output parameters: the /tf broadcaster, the path's length."""
        if self._path_poses.maxlen != self.params['path_max_poses']:
            self._path_poses = deque(self._path_poses, maxlen=self.params['path_max_poses'])
        if not self.params['publish_tf'] or self._tf is not None or self._tf_missing:
            return
        try:
            from tf2_ros import TransformBroadcaster
            self._tf = TransformBroadcaster(self._node)
        except ImportError:
            self._tf_missing = True
            self._node.get_logger().info(
                'tf2_ros is not installed: publishing nav_msgs/Odometry only, no odom -> '
                'base_link transform on /tf')

    def clear_path(self) -> None:
        """Forget the path (the pose was reset or set)."""
        self._path_poses.clear()

    def publish_odometry(self, header: Any, result: FrameResult) -> Odometry | None:
        """Publish ``odom`` for the frame (None for a repeated stamp: tf2 rejects those)."""
        if result.status == FrameStatus.DUPLICATE:
            return None
        p = self.params
        odom = messages.odometry_from_result(result, header.stamp, p['odom_frame'],
                                             p['base_frame'], Odometry)
        self.odom_pub.publish(odom)
        return odom

    def publish_extras(self, odom: Odometry, header: Any, gray: Any,
                       result: FrameResult) -> None:
        """/tf, ``~/path`` and ``~/debug_image``, as asked (after the odometry's latency)."""
        p = self.params
        if self._tf is not None and p['publish_tf']:
            self._tf.sendTransform(messages.transform_from_result(
                result, header.stamp, p['odom_frame'], p['base_frame']))
        if p['publish_path']:
            self._append_path(odom)
        if p['publish_debug_image'] and self._debug_pub.get_subscription_count():
            self._debug_pub.publish(messages.debug_image(gray, result, header, Image))

    def _append_path(self, odom: Odometry) -> None:
        """Keep a pose every ~5 cm or ~3 deg, at most path_max_poses; publish if listened to."""
        poses = self._path_poses
        pos = odom.pose.pose.position
        if poses:
            last = poses[-1].pose
            moved = abs(pos.x - last.position.x) + abs(pos.y - last.position.y)
            turned = abs(odom.pose.pose.orientation.z - last.orientation.z) * 2
            if moved < _PATH_STEP and turned < _PATH_STEP:
                return
        poses.append(PoseStamped(header=odom.header, pose=odom.pose.pose))
        if self._path_pub.get_subscription_count():
            self._path_pub.publish(Path(header=odom.header, poses=list(poses)))
