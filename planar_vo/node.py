"""``planar_vo_node``: the rclpy adapter around :class:`planar_vo.odometry.VisualOdometry`.

Subscribes ``image`` (or ``<image>/compressed``) and ``camera_info``; publishes ``odom``
for every image (stamp = image stamp; when a frame gives no estimate the held pose is
published with an inflated covariance), optional ``~/path`` and ``~/debug_image``,
``/diagnostics`` about once a second and odom → base_link on /tf when tf2_ros is installed.
Service ``~/reset`` restarts at the origin.

Parameters come from :data:`planar_vo.config.SCHEMA`. An invalid start-up value (command
line or params file) is a one-line error and exit status 2; at run time invalid values are
refused with a reason. Mounting changes apply at once; other algorithm parameters rebuild
the odometry (tracking restarts, the pose is kept).
"""

from __future__ import annotations

import functools
import re
import sys
import time
from collections import OrderedDict

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry, Path
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, CompressedImage, Image
from std_srvs.srv import Trigger

from planar_vo import config, messages
from planar_vo.camera import CameraModelError
from planar_vo.odometry import VisualOdometry, mounting_from_params

_PARAMS = {p.name: p for p in config.SCHEMA}
_OUTPUT_PARAMS = {'odom_frame', 'base_frame', 'publish_tf', 'publish_path',
                  'publish_debug_image', 'image_transport', 'image_reliability'}
_WARN_EVERY = 10.0  # s: the same cause of a skipped frame is logged at most this often
_WARN_CAUSES = 64  # distinct causes remembered for throttling (oldest forgotten first)
# Numbers in a message (sizes like 640x480 too), but not digits inside names like mono16.
_NUMBER = re.compile(r'\d+x\d+|(?<![A-Za-z_\d.])[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?'
                     r'|\bnan\b|\binf\b')
_PATH_STEP = 0.05  # m or rad between poses appended to ~/path


class StartupError(Exception):
    """An invalid start-up parameter: reported as one line, exit status 2."""


def _guarded(where: str):
    """Run a callback so that an unexpected exception is one ERROR line, never a crash."""
    def wrap(callback):
        @functools.wraps(callback)
        def guarded(self, *args):
            try:
                return callback(self, *args)
            except Exception as err:  # noqa: BLE001 - a bug must not kill the node
                if self.context.ok():  # else shutting down: publishing fails, no bug
                    self._unexpected(where, err)
        return guarded
    return wrap


class PlanarVoNode(Node):
    """Planar monocular visual odometry node."""

    def __init__(self, **kwargs) -> None:
        super().__init__('planar_vo', **kwargs)
        self.vo: VisualOdometry | None = None
        self.camera = None
        self._calibration = None  # the last accepted CameraInfo's fields, to skip repeats
        self._warned: OrderedDict[str, tuple[float, int]] = OrderedDict()
        self._mounting_advised: set[str] = set()
        self._stats = {'frames': 0, 'estimated': 0, 'failed': 0, 'skipped': 0, 'errors': 0,
                       'last_status': 'waiting for images', 'tracks': 0, 'inliers': 0,
                       'ms': 0.0, 'ms_sum': 0.0}
        self.params = self._declare_parameters()
        self.add_post_set_parameters_callback(self._on_params_set)

        p = self.params
        image_qos = QoSProfile(
            history=HistoryPolicy.KEEP_LAST, depth=5,
            reliability=ReliabilityPolicy.RELIABLE if p['image_reliability'] == 'reliable'
            else ReliabilityPolicy.BEST_EFFORT)
        if p['image_transport'] == 'compressed':
            topic = self.resolve_topic_name('image') + '/compressed'
            self._image_sub = self.create_subscription(
                CompressedImage, topic, self._on_compressed, image_qos)
        else:
            topic = 'image'
            self._image_sub = self.create_subscription(Image, topic, self._on_image, image_qos)
        self._info_sub = self.create_subscription(
            CameraInfo, 'camera_info', self._on_camera_info, qos_profile_sensor_data)
        self._odom_pub = self.create_publisher(Odometry, 'odom', 10)
        self._path_pub = self.create_publisher(Path, '~/path', 1)
        self._debug_pub = self.create_publisher(Image, '~/debug_image', 1)
        self._diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self._path = Path()
        self._reset_srv = self.create_service(Trigger, '~/reset', self._on_reset)
        self._diag_timer = self.create_timer(1.0, self._publish_diagnostics)
        self._tf = None
        if p['publish_tf']:
            try:
                from tf2_ros import TransformBroadcaster
                self._tf = TransformBroadcaster(self)
            except ImportError:
                self.get_logger().info('tf2_ros is not installed: publishing nav_msgs/Odometry '
                                       'only, no odom -> base_link transform on /tf')
        self.get_logger().info(
            f'listening on {self._image_sub.topic_name} ({p["image_transport"]}, '
            f'{p["image_reliability"]}) and {self._info_sub.topic_name}; '
            f'publishing {self._odom_pub.topic_name}')

    # ---------------------------------------------------------------- parameters
    def _declare_parameters(self) -> dict:
        self.add_pre_set_parameters_callback(self._ints_to_floats)
        self.add_on_set_parameters_callback(self._validate)
        overrides = self._parameter_overrides  # start-up values: check them with our reasons
        for name, value in list(overrides.items()):
            spec = _PARAMS.get(name)
            if spec is None:
                if not name.startswith('qos_overrides.') and name != 'use_sim_time':
                    self.get_logger().warning(f'unknown parameter {name!r} ignored')
                continue
            try:
                checked = spec.check(value.value)
            except config.ConfigError as err:
                raise StartupError(f'invalid parameter: {err}') from None
            overrides[name] = Parameter(name, value=checked)
        for spec in config.SCHEMA:
            desc = ParameterDescriptor(description=spec.description, read_only=spec.read_only)
            if isinstance(spec.default, float):
                desc.floating_point_range = [FloatingPointRange(
                    from_value=float(spec.low), to_value=float(spec.high), step=0.0)]
            elif isinstance(spec.default, int) and not isinstance(spec.default, bool):
                desc.integer_range = [IntegerRange(
                    from_value=int(spec.low), to_value=int(spec.high), step=1)]
            elif spec.choices:
                desc.additional_constraints = 'one of: ' + ', '.join(spec.choices)
            self.declare_parameter(spec.name, spec.default, desc)
        return {s.name: self.get_parameter(s.name).value for s in config.SCHEMA}

    def _ints_to_floats(self, params: list[Parameter]) -> list[Parameter]:
        out = []
        for prm in params:
            spec = _PARAMS.get(prm.name)
            if (spec is not None and isinstance(spec.default, float)
                    and prm.type_ == Parameter.Type.INTEGER):
                prm = Parameter(prm.name, value=float(prm.value))
            out.append(prm)
        return out

    def _validate(self, params: list[Parameter]) -> SetParametersResult:
        for prm in params:
            spec = _PARAMS.get(prm.name)
            if spec is None:
                continue
            try:
                spec.check(prm.value)
            except config.ConfigError as err:
                return SetParametersResult(successful=False, reason=str(err))
        return SetParametersResult(successful=True)

    def _on_params_set(self, params: list[Parameter]) -> None:
        if not hasattr(self, 'params'):  # still declaring
            return
        names = {prm.name for prm in params if prm.name in _PARAMS}
        for prm in params:
            if prm.name in _PARAMS:
                self.params[prm.name] = _PARAMS[prm.name].check(prm.value)
        if self.vo is None or not names:
            return
        if names - set(config.MOUNTING_PARAMS) - _OUTPUT_PARAMS:
            self._rebuild()
            self.get_logger().info(f'{", ".join(sorted(names))} changed: tracking restarted')
        elif names & set(config.MOUNTING_PARAMS):
            self.vo.set_mounting(mounting_from_params(self.params))
            self.get_logger().info(f'camera mounting changed: {", ".join(sorted(names))}')

    def _rebuild(self) -> None:
        old, self.vo = self.vo, VisualOdometry.from_params(self.camera, self.params)
        if old is not None:
            self.vo.pose, self.vo.pose_covariance = old.pose, old.pose_covariance
            self.vo.counters = old.counters

    # ---------------------------------------------------------------- input
    def _warn(self, text: str, *, error: bool = False) -> None:
        """Log ``text`` at once, then the same cause at most every _WARN_EVERY s with a count.

        The cause is the text with its numbers stripped, so the same problem with other
        numbers is throttled and a different problem is always reported at once.
        """
        cause = _NUMBER.sub('#', text)
        now = time.monotonic()
        last, count = self._warned.pop(cause, (-1e9, 0))
        if now - last >= _WARN_EVERY:
            more = f' (and {count} more times)' if count else ''
            if error:  # rclpy ties a severity to each call site: two calls, not one
                self.get_logger().error(text + more)
            else:
                self.get_logger().warning(text + more)
            last, count = now, 0
        else:
            count += 1
        self._warned[cause] = (last, count)  # most recent last
        if len(self._warned) > _WARN_CAUSES:
            self._warned.popitem(last=False)

    def _unexpected(self, where: str, err: Exception) -> None:
        """A bug, not bad input: one ERROR line with the exception, and a counter."""
        self._stats['errors'] += 1
        self._warn(f'unexpected {type(err).__name__} while handling {where}: {err} '
                   '(state restored; please report this line)', error=True)

    @_guarded('camera_info')
    def _on_camera_info(self, msg: CameraInfo) -> None:
        calibration = (msg.width, msg.height, msg.distortion_model, msg.k.tobytes(),
                       msg.d.tobytes())
        if calibration == self._calibration:  # drivers repeat it with every image
            return
        self._calibration = None
        try:
            self._set_camera(messages.camera_info_to_model(msg))
            self._calibration = calibration
        except CameraModelError as err:
            self._warn(f'camera_info refused: {err}')

    def _set_camera(self, camera) -> None:
        if self.camera is not None and (
                camera.width, camera.height, camera.distortion_model) == (
                self.camera.width, self.camera.height, self.camera.distortion_model) and (
                (camera.K == self.camera.K).all() and camera.D.shape == self.camera.D.shape
                and (camera.D == self.camera.D).all()):
            return
        if self.vo is None:
            self.vo = VisualOdometry.from_params(camera, self.params)
            self.get_logger().info(f'camera: {camera.width}x{camera.height}, '
                                   f'fx {camera.K[0, 0]:.1f}, {camera.distortion_model}')
        else:
            self.vo.set_camera(camera)
            self.get_logger().info('camera_info changed: intrinsics updated')
        self.camera = camera

    @_guarded('an image')
    def _on_image(self, msg: Image) -> None:
        self._process(msg, messages.image_to_gray)

    @_guarded('a compressed image')
    def _on_compressed(self, msg: CompressedImage) -> None:
        self._process(msg, messages.compressed_to_gray)

    def _process(self, msg, decode) -> None:
        if self.vo is None:
            self._stats['skipped'] += 1
            self._warn(f'no valid camera_info on {self._info_sub.topic_name} yet: image '
                       'skipped')
            return
        try:
            gray = decode(msg)
        except messages.ImageError as err:
            self._stats['skipped'] += 1
            self._warn(f'image skipped: {err}')
            return
        # VisualOdometry.process restores its state itself when it raises.
        result = self.vo.process(gray, messages.stamp_to_seconds(msg.header.stamp))
        self._publish(msg.header, gray, result)

    # ---------------------------------------------------------------- output
    def _publish(self, header, gray, result) -> None:
        s, p = self._stats, self.params
        s['frames'] += 1
        s['estimated' if result.estimated else 'failed'] += result.status != 'first'
        s.update(last_status=result.status, tracks=result.tracks, inliers=result.inliers,
                 ms=result.timing_ms.get('total', 0.0))
        s['ms_sum'] += s['ms']
        if result.message and result.status not in ('ok', 'first'):
            self._warn(f'{result.status}: {result.message}')
        odom = messages.odometry_from_result(result, header.stamp, p['odom_frame'],
                                             p['base_frame'], Odometry)
        self._odom_pub.publish(odom)
        if self._tf is not None and p['publish_tf']:
            self._tf.sendTransform(messages.transform_from_result(
                result, header.stamp, p['odom_frame'], p['base_frame']))
        if p['publish_path']:
            self._append_path(odom)
        if p['publish_debug_image'] and self._debug_pub.get_subscription_count():
            self._debug_pub.publish(messages.debug_image(gray, result, header, Image))

    def _append_path(self, odom: Odometry) -> None:
        poses = self._path.poses
        pos = odom.pose.pose.position
        if poses:
            last = poses[-1].pose
            moved = abs(pos.x - last.position.x) + abs(pos.y - last.position.y)
            turned = abs(odom.pose.pose.orientation.z - last.orientation.z) * 2
            if moved < _PATH_STEP and turned < _PATH_STEP:
                return
        ps = PoseStamped(header=odom.header, pose=odom.pose.pose)
        poses.append(ps)
        self._path.header = odom.header
        self._path_pub.publish(self._path)

    def _on_reset(self, request, response):
        self._path = Path()
        try:
            if self.vo is not None:
                self.vo.reset()
        except Exception as err:  # noqa: BLE001 - a bug must not kill the node
            self._unexpected('~/reset', err)
            response.success, response.message = False, f'{type(err).__name__}: {err}'
            return response
        response.success = True
        response.message = 'odometry restarted at the origin'
        self.get_logger().info(response.message)
        return response

    @_guarded('diagnostics')
    def _publish_diagnostics(self) -> None:
        s = self._stats
        status = DiagnosticStatus(name='planar_vo: visual odometry', hardware_id='camera')
        if self.vo is None:
            status.level, status.message = DiagnosticStatus.WARN, 'waiting for camera_info'
        elif s['last_status'] in ('ok', 'first'):
            status.level, status.message = DiagnosticStatus.OK, 'tracking'
        else:
            status.level, status.message = DiagnosticStatus.WARN, s['last_status']
        values = {'state': s['last_status'], 'tracks': s['tracks'], 'inliers': s['inliers'],
                  'processing time (ms)': f'{s["ms"]:.2f}',
                  'mean processing time (ms)': f'{s["ms_sum"] / max(s["frames"], 1):.2f}',
                  'frames': s['frames'], 'frames estimated': s['estimated'],
                  'frames failed': s['failed'], 'frames skipped': s['skipped'],
                  'unexpected errors': s['errors']}
        if self.vo is not None:
            mounting, advice = self.vo.mounting_diagnostics()
            values.update(mounting)
            for name, line in advice.items():
                if name not in self._mounting_advised:  # once per parameter
                    self._mounting_advised.add(name)
                    self.get_logger().warning(line)
        status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        arr = DiagnosticArray(status=[status])
        arr.header.stamp = self.get_clock().now().to_msg()
        self._diag_pub.publish(arr)


def main(args=None) -> int:
    """Entry point of ``planar_vo_node``."""
    rclpy.init(args=args)
    node = None
    code = 0
    try:
        node = PlanarVoNode()
        rclpy.spin(node)
    except StartupError as err:
        print(f'[planar_vo] error: {err}', file=sys.stderr)
        code = 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return code


if __name__ == '__main__':
    sys.exit(main())
