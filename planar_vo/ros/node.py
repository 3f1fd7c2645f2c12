"""``planar_vo_node``: the rclpy adapter around :class:`planar_vo.core.odometry.VisualOdometry`.

Subscribes ``image`` (or ``<image>/compressed``) and ``camera_info``, paired by stamp
(:mod:`planar_vo.ros.pairing`), and ``set_pose`` (geometry_msgs/PoseWithCovarianceStamped, as
robot_localization): odometry continues from that pose. Publishes ``odom`` for every image it
processes (stamp = image stamp; when a frame gives no estimate the held pose is published with
an inflated covariance; a repeated stamp publishes nothing), optional ``~/path`` and
``~/debug_image``, ``/diagnostics`` about once a second (:mod:`planar_vo.ros.health`) and
odom → base_link on /tf when tf2_ros is installed. Service ``~/reset`` restarts at the origin.

The odometry runs on a thread of its own: the executor's callbacks only pair images with
their CameraInfo and hand them over. When images come faster than they are processed, the
ones that came more than :data:`STALE_AFTER` before the newest are dropped (counted in
/diagnostics), so the odometry never falls further behind than that; a shorter hiccup is
worked off (dropping at once cost more frames than it saved: a frame after a dropped one
moved twice as far, and is the dearer to track).

Parameters come from :data:`planar_vo.core.config.SCHEMA`. An invalid start-up value (command
line or params file) is a one-line error and exit status 2; at run time invalid values are
refused with a reason. Mounting changes apply at once; other algorithm parameters rebuild
the odometry (tracking restarts, the pose is kept).
"""

from __future__ import annotations

import functools
import sys
import threading
import time

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseWithCovarianceStamped
from rclpy.clock import Clock, ClockType
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, CompressedImage, Image
from std_srvs.srv import Trigger

from planar_vo.core import config
from planar_vo.core.config import mounting_from_params
from planar_vo.core.geometry.camera import CameraModelError
from planar_vo.core.odometry import VisualOdometry
from planar_vo.ros import messages
from planar_vo.ros.camera_frontend import CHANGED, CREATED, CameraFrontend, Step
from planar_vo.ros.health import LARGE_IMAGE_BYTES, Health
from planar_vo.ros.outputs import OdometryOutputs
from planar_vo.ros.pairing import Paired
from planar_vo.ros.parameters import SCHEMA_BY_NAME, StartupError, declare_schema
from planar_vo.ros.throttle import WarningThrottle

_OUTPUT_PARAMS = {'odom_frame', 'base_frame', 'publish_tf', 'publish_path', 'path_max_poses',
                  'publish_debug_image', 'image_transport', 'image_reliability',
                  'rectified_input'}
_PLANAR = (0, 1, 5)  # x, y, yaw within a 6x6 covariance over (x, y, z, roll, pitch, yaw)
_WARN_EVERY = 10.0  # s: the same cause of a skipped frame is logged at most this often
_WARN_CAUSES = 64  # distinct causes remembered for throttling (oldest forgotten first)
_PAIRING_WAIT = 0.05  # s an image waits at most for the CameraInfo of its stamp
# s: a subscription replaced by one of other QoS goes once the new one met every publisher,
# or after this long.
_RETIRE_AFTER = 5.0
STALE_AFTER = 0.1  # s: an image waiting this much longer than the newest one is dropped


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


_MAX_QUEUED_NS = 60 * 10**9  # older than this, the system clock has stepped


def _received_monotonic(info: dict) -> float:
    """When the middleware received the message, on the monotonic clock.

    Not when the callback runs: frames queued while the node was busy (at start-up, say) would
    otherwise arrive in a burst and make the usual image rate look several times too high.
    """
    now = time.monotonic()
    received_ns = info.get('received_timestamp', 0) if isinstance(info, dict) else 0
    age = time.time_ns() - received_ns
    if not received_ns or not 0 <= age < _MAX_QUEUED_NS:  # not filled in, or a clock step
        return now
    return now - age / 1e9


class PlanarVoNode(Node):
    """Planar monocular visual odometry node."""

    def __init__(self, **kwargs) -> None:
        super().__init__('planar_vo', **kwargs)
        # The odometry, its outputs and camera: used by the processing thread frame by frame,
        # by the executor's callbacks (parameters, set_pose, reset, diagnostics) in between.
        self._lock = threading.RLock()
        self._small_lock = threading.Lock()  # health and warning throttle, held briefly
        self._inbox = threading.Condition()  # paired images not yet processed, newest last
        self._pending: list[tuple[float, Paired]] = []  # (when handed over, image)
        self._dropped = 0  # images dropped for a newer one while the odometry was busy
        self._stopping = False
        self._calibration = None  # (the last accepted CameraInfo's fields, its CameraModel)
        self._throttle = WarningThrottle(_WARN_EVERY, _WARN_CAUSES)
        self._errors = 0  # unexpected exceptions (bugs) caught in callbacks
        self._mounting_advised: set[str] = set()
        self._health = Health()
        self._camera_frame = ''
        self.params = self._declare_parameters()
        self._frontend = CameraFrontend(self.params)
        self.add_post_set_parameters_callback(self._on_params_set)

        p = self.params
        # CameraInfo first: when it and its image are both waiting, the executor takes them in
        # this order, and the image is processed in its own callback instead of waiting for
        # the CameraInfo's turn.
        self._info_sub = self.create_subscription(
            CameraInfo, 'camera_info', self._on_camera_info, qos_profile_sensor_data)
        self._image_topic = self.resolve_topic_name('image') + (
            '/compressed' if p['image_transport'] == 'compressed' else '')
        self._image_sub, self._retiring = None, None
        self._last_image_stamp = None
        self._subscribe_images(self._image_reliability())
        self._set_pose_sub = self.create_subscription(
            PoseWithCovarianceStamped, 'set_pose', self._on_set_pose, 10)
        self._outputs = OdometryOutputs(self, self.params)
        self._diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self._reset_srv = self.create_service(Trigger, '~/reset', self._on_reset)
        steady = Clock(clock_type=ClockType.STEADY_TIME)  # also with use_sim_time, no /clock
        self._diag_timer = self.create_timer(1.0, self._publish_diagnostics, clock=steady)
        if p['image_reliability'] == 'auto':
            self._qos_timer = self.create_timer(1.0, self._match_image_publishers, clock=steady)
        self._pairing_timer = self.create_timer(_PAIRING_WAIT, self._stop_waiting, clock=steady,
                                                autostart=False)
        self.get_logger().info(
            f'listening on {self._image_sub.topic_name} ({p["image_transport"]}, '
            f'{p["image_reliability"]}) and {self._info_sub.topic_name}; '
            f'publishing {self._outputs.odom_pub.topic_name}')
        self._worker = threading.Thread(target=self._work, name='planar_vo odometry',
                                        daemon=True)
        self._worker.start()

    def destroy_node(self) -> None:
        """Stop the processing thread (after the frame in hand), then the node."""
        with self._inbox:
            self._stopping = True
            self._inbox.notify()
        if self._worker.is_alive() and self._worker is not threading.current_thread():
            self._worker.join(10.0)
        super().destroy_node()

    # ---------------------------------------------------------------- parameters
    def _declare_parameters(self) -> config.Params:
        params = declare_schema(self)
        unknown = sorted(set(self._parameter_overrides) - set(SCHEMA_BY_NAME))  # read only
        for name in unknown:
            if not name.startswith('qos_overrides.') and name != 'use_sim_time':
                self.get_logger().warning(f'unknown parameter {name!r} ignored')
        return params

    def _on_params_set(self, params: list[Parameter]) -> None:
        if not hasattr(self, 'params'):  # still declaring
            return
        names = {prm.name for prm in params if prm.name in SCHEMA_BY_NAME}
        self.params = self.params.replace(
            **{prm.name: prm.value for prm in params if prm.name in SCHEMA_BY_NAME})
        with self._lock:
            self._outputs.params = self.params
            if names & _OUTPUT_PARAMS:
                self._outputs.update()
            if self.vo is None or not names:
                return
            if names - set(config.MOUNTING_PARAMS) - _OUTPUT_PARAMS:
                self._rebuild()
                self.get_logger().info(
                    f'{", ".join(sorted(names))} changed: tracking restarted')
            elif names & set(config.MOUNTING_PARAMS):
                self.vo.set_mounting(mounting_from_params(self.params))
                self.get_logger().info(f'camera mounting changed: {", ".join(sorted(names))}')

    @property
    def vo(self) -> VisualOdometry | None:
        """The odometry, once a CameraInfo was accepted."""
        return self._frontend.vo

    def _rebuild(self) -> None:
        self._frontend.rebuild(self.params)

    # ---------------------------------------------------------------- input
    def _image_reliability(self) -> ReliabilityPolicy:
        """The image subscription's QoS at start-up: as configured; best effort with 'auto'.

        Best effort connects to every publisher; _match_image_publishers changes it later.
        """
        return (ReliabilityPolicy.RELIABLE if self.params['image_reliability'] == 'reliable'
                else ReliabilityPolicy.BEST_EFFORT)

    def _subscribe_images(self, reliability: ReliabilityPolicy) -> None:
        """(Re)subscribe the images with ``reliability``.

        The old subscription stays until the new one has met every publisher (or for
        _RETIRE_AFTER s), so no image falls between them; an image both bring is taken once.
        """
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5, reliability=reliability)
        compressed = self.params['image_transport'] == 'compressed'
        if self._image_sub is not None:
            self._retiring = (self._image_sub, time.monotonic() + _RETIRE_AFTER)
        self._image_sub = self.create_subscription(
            CompressedImage if compressed else Image, self._image_topic,
            self._on_compressed if compressed else self._on_image, qos)
        self._image_qos = reliability
        self._health.best_effort = reliability == ReliabilityPolicy.BEST_EFFORT

    @_guarded('the image publishers')
    def _match_image_publishers(self) -> None:
        """With image_reliability 'auto': follow the images' size and the publishers' QoS.

        Reliable once the images are over 512 kB and every publisher of the topic is reliable
        (Fast DDS loses best-effort messages that large: half of 1280x720 mono8 images sent
        in a burst), best effort again once one is not.
        """
        publishers = self.get_publishers_info_by_topic(self._image_topic)
        if self._retiring is not None and (
                self._image_sub.get_publisher_count() >= len(publishers)
                or time.monotonic() > self._retiring[1]):
            self.destroy_subscription(self._retiring[0])
            self._retiring = None
        reliable = [info.qos_profile.reliability == ReliabilityPolicy.RELIABLE
                    for info in publishers]
        if self._image_qos == ReliabilityPolicy.RELIABLE and not all(reliable):
            wanted = ReliabilityPolicy.BEST_EFFORT
        elif (self._image_qos == ReliabilityPolicy.BEST_EFFORT and reliable and all(reliable)
              and self._health.image_bytes > LARGE_IMAGE_BYTES):
            wanted = ReliabilityPolicy.RELIABLE
        else:
            return
        if self._retiring is not None:  # still switching: the next tick
            return
        self._subscribe_images(wanted)
        how = ('reliable: the images are large and every publisher is reliable'
               if wanted == ReliabilityPolicy.RELIABLE else 'best effort: a publisher is')
        self.get_logger().info(f'{self._image_topic} subscribed {how}')


    def _warn(self, text: str, *, error: bool = False) -> None:
        """Log ``text``, throttled per cause (see :class:`WarningThrottle`)."""
        # rclpy ties a severity to each call site: two calls, not one
        log = self.get_logger().error if error else self.get_logger().warning
        with self._small_lock:
            self._throttle(text, time.monotonic(), log)

    def _unexpected(self, where: str, err: Exception) -> None:
        """A bug, not bad input: one ERROR line with the exception, and a counter."""
        with self._small_lock:
            self._errors += 1
        self._warn(f'unexpected {type(err).__name__} while handling {where}: {err} '
                   '(state restored; please report this line)', error=True)

    @_guarded('camera_info')
    def _on_camera_info(self, msg: CameraInfo) -> None:
        try:
            camera = self._camera_model(msg)
        except CameraModelError as err:
            self._warn(f'camera_info refused: {err}')
            return
        self._hand_over(self._frontend.pairing.add_info(_stamp_ns(msg.header.stamp), camera))

    def _camera_model(self, msg: CameraInfo):
        """The CameraModel of ``msg``; the same object again when the calibration repeats.

        Drivers repeat one CameraInfo with every image: it is converted (and checked) once.
        A refused calibration is checked again each time. Raises CameraModelError.
        """
        roi = msg.roi
        calibration = (msg.width, msg.height, msg.distortion_model, msg.k.tobytes(),
                       msg.d.tobytes(), msg.p.tobytes(), msg.binning_x, msg.binning_y,
                       roi.x_offset, roi.y_offset, roi.width, roi.height)
        if self._calibration is not None and calibration == self._calibration[0]:
            return self._calibration[1]
        camera = messages.camera_info_to_model(msg, rectified=self.params['rectified_input'])
        self._calibration = (calibration, camera)
        return camera

    @_guarded('an image')
    def _on_image(self, msg: Image, info: dict) -> None:
        self._receive(msg, messages.image_to_gray, info)

    @_guarded('a compressed image')
    def _on_compressed(self, msg: CompressedImage, info: dict) -> None:
        self._receive(msg, messages.compressed_to_gray, info)

    def _receive(self, msg, decode, info: dict) -> None:
        stamp = _stamp_ns(msg.header.stamp)
        with self._small_lock:
            if self._retiring is not None and stamp == self._last_image_stamp:
                return  # brought by both subscriptions while they change over
            self._last_image_stamp = stamp
            self._health.image_received(
                _received_monotonic(info), size_bytes=len(msg.data),
                sequence=info.get('publication_sequence_number') if isinstance(info, dict)
                else None)
        self._hand_over(self._frontend.pairing.add_image(stamp, (msg, decode)))
        if self._frontend.waiting:
            self._pairing_timer.reset()

    @_guarded('an image')
    def _stop_waiting(self) -> None:
        """The CameraInfo of the waiting image did not come in time: use the newest."""
        self._pairing_timer.cancel()
        self._hand_over(self._frontend.pairing.flush())

    def _hand_over(self, ready: list[Paired]) -> None:
        """Give images the pairing released (oldest first) to the processing thread."""
        if ready:
            now = time.monotonic()
            with self._inbox:
                self._pending.extend((now, paired) for paired in ready)
                self._inbox.notify()

    def _work(self) -> None:
        """The processing thread: the oldest image that is not stale, again and again.

        Images that came more than :data:`STALE_AFTER` before the newest are dropped, not
        queued: a busy machine costs frames, never a growing delay.
        """
        while True:
            with self._inbox:
                while not self._pending and not self._stopping:
                    self._inbox.wait()
                if self._stopping:
                    return
                stale = stale_images([when for when, _ in self._pending])
                paired = self._pending[stale][1]
                del self._pending[:stale + 1]
                self._dropped += stale
            try:
                with self._lock:
                    for step in self._frontend.steps([paired]):
                        self._process(step)
            except Exception as err:  # noqa: BLE001 - a bug must not kill the thread
                if self.context.ok():  # else shutting down: publishing fails, no bug
                    self._unexpected('an image', err)

    def _process(self, step: Step) -> None:
        """One image with the CameraInfo it was paired with (see CameraFrontend)."""
        msg, decode = step.image
        if step.refused is not None:
            self._warn(f'camera_info refused: {step.refused}')
        if not step.process:
            if step.refused is None:  # no CameraInfo yet
                with self._small_lock:
                    self._health.frame_failed('no camera_info')
                self._warn(f'no valid camera_info on {self._info_sub.topic_name} yet: image '
                           'skipped')
            return
        if not step.exact and step.unmatched:
            self._warn('no camera_info with the image\'s stamp (the driver stamps them '
                       'differently?): using the newest camera_info')
        camera = self._frontend.camera
        if step.camera == CREATED:
            self.get_logger().info(f'camera: {camera.width}x{camera.height}, '
                                   f'fx {camera.K[0, 0]:.1f}, {camera.distortion_model}')
        elif step.camera == CHANGED:
            self.get_logger().info(f'camera_info changed: {camera.width}x{camera.height}, '
                                   f'fx {camera.K[0, 0]:.1f}')
        self._camera_frame = msg.header.frame_id
        try:
            gray = decode(msg)
        except messages.ImageError as err:
            with self._small_lock:
                self._health.frame_failed(f'image skipped: {err}')
            self._warn(f'image skipped: {err}')
            return
        # VisualOdometry.process restores its state itself when it raises.
        result = self.vo.process(gray, messages.stamp_to_seconds(msg.header.stamp))
        self._publish(msg.header, gray, result)

    @_guarded('set_pose')
    def _on_set_pose(self, msg: PoseWithCovarianceStamped) -> None:
        """Continue from the given pose (robot_localization's set_pose convention)."""
        frame = msg.header.frame_id
        if frame and frame.lstrip('/') != self.params['odom_frame']:
            self._warn(f'set_pose in frame {frame!r} ignored: it must be '
                       f'in {self.params["odom_frame"]!r} (odom_frame)')
            return
        pose = messages.planar_pose(msg.pose.pose)
        cov = np.asarray(msg.pose.covariance, dtype=float).reshape(6, 6)[np.ix_(_PLANAR, _PLANAR)]
        if not (np.all(np.isfinite(pose)) and np.all(np.isfinite(cov))
                and np.all(np.diag(cov) >= 0)):
            self._warn('set_pose ignored: its pose or covariance is not '
                       'finite, or a variance is negative')
            return
        with self._lock:
            if self.vo is None:
                self._warn('set_pose ignored: no camera_info yet')
                return
            self._outputs.clear_path()
            self.vo.set_pose(pose, cov)
        self.get_logger().info(f'pose set to x {pose[0]:.3f} m, y {pose[1]:.3f} m, '
                               f'yaw {pose[2]:.4f} rad')

    # ---------------------------------------------------------------- output
    def _publish(self, header, gray, result) -> None:
        # Odometry first: the bookkeeping below is not part of its latency.
        odom = self._outputs.publish_odometry(header, result)
        with self._small_lock:
            self._health.frame_done(result)
        if result.message and result.status not in ('ok', 'first'):
            self._warn(f'{result.status}: {result.message}')
        if odom is not None:
            self._outputs.publish_extras(odom, header, gray, result)

    def _on_reset(self, request, response):
        try:
            with self._lock:
                self._outputs.clear_path()
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
        with self._small_lock:
            level, message, values = self._health.report(
                time.monotonic(), calibrated=self.vo is not None,
                ground_irregular=self.vo is not None and self.vo.ground_irregular)
            values['unexpected errors'] = str(self._errors)
            values['image subscription'] = (
                'reliable' if self._image_qos == ReliabilityPolicy.RELIABLE else 'best effort')
        with self._inbox:
            values['frames dropped for a newer one (busy)'] = str(self._dropped)
        advice = {}
        with self._lock:
            if self.vo is not None:
                values.update(self.vo.diagnostics())
                mounting, advice = self.vo.mounting_diagnostics()
                values.update(mounting)
        for name, line in advice.items():
            if name not in self._mounting_advised:  # once per parameter
                self._mounting_advised.add(name)
                self.get_logger().warning(line)
        status = DiagnosticStatus(
            level=bytes([level]), name=f'{self.get_fully_qualified_name()}: visual odometry',
            message=message, hardware_id=self._camera_frame,
            values=[KeyValue(key=k, value=str(v)) for k, v in values.items()])
        arr = DiagnosticArray(status=[status])
        arr.header.stamp = self.get_clock().now().to_msg()
        self._diag_pub.publish(arr)


def stale_images(handed_over: list[float]) -> int:
    """How many of the waiting images (hand-over times, s, oldest first) are stale.

    Those that came more than :data:`STALE_AFTER` before the newest; never the newest.
    """
    newest = handed_over[-1]
    return sum(1 for when in handed_over if when < newest - STALE_AFTER)


def _stamp_ns(stamp) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


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
    except Exception:
        if rclpy.ok():  # not stopping: a real failure
            raise
        # Ctrl-C shut the context down while the executor was waiting: rclpy may raise from
        # the wait instead of ExternalShutdownException. A clean stop all the same.
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return code


if __name__ == '__main__':
    sys.exit(main())
