"""Play a bag into a running ``planar_vo_node`` over DDS and measure what comes back.

Used by ``planar_vo_demo`` (accuracy and latency at the bag's real rate) and by
``planar_vo_bench --live`` (the highest rate the node sustains without dropping frames).
DDS stays on this machine: ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` and a domain id of
its own are set before rclpy starts, unless the caller set them already.
"""

from __future__ import annotations

import os
import signal
import struct
import subprocess
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from planar_vo.io.bag import (
    IMAGE_TYPES,
    INFO_TYPE,
    open_reader,
    read_messages,
    truth_connection,
)
from planar_vo.io.errors import BagError
from planar_vo.io.resources import executable
from planar_vo.ros.background import BackgroundSpin
from planar_vo.ros.messages import planar_pose, stamp_to_seconds
from planar_vo.tools.errors import LiveError

__all__ = ['BagStream', 'LiveSession', 'STALLED_AFTER', 'local_dds_env']

# Frames in a row without an answer after which a player with a window gives up: one is
# a frame dropped under load, this many a node that is stuck.
STALLED_AFTER = 5


def local_dds_env() -> dict[str, str]:
    """Return the environment with DDS kept on loopback and a domain id of its own.

    The id is within 1-101, where DDS's ports stay below Linux's ephemeral range.
    """
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ.pop('ROS_LOCALHOST_ONLY', None)  # deprecated in Jazzy; do not let it interfere
    os.environ.setdefault('ROS_DOMAIN_ID', str(1 + os.getpid() % 101))
    return dict(os.environ)


def _cdr_stamp(cdr: bytes) -> float:
    """header.stamp (s) of a serialized message that starts with a std_msgs/Header.

    After the 4-byte CDR encapsulation (its second byte: 1 little-endian, 0 big-endian)
    come stamp.sec (int32) and stamp.nanosec (uint32).
    """
    sec, nanosec = struct.unpack_from('<iI' if cdr[1] == 1 else '>iI', cdr, 4)
    return float(sec) + 1e-9 * float(nanosec)  # as stamp_to_seconds: the same float


@dataclass
class BagStream:
    """A bag's camera messages, kept as CDR bytes so they are published as they were."""

    frames: list[tuple[float, bytes, bytes]]  # (image stamp, image CDR, camera_info CDR)
    image_type: str
    truth: dict[float, np.ndarray] = field(default_factory=dict)  # stamp → (x, y, yaw)

    @classmethod
    def read(cls, path: str | Path, limit: int | None = None) -> BagStream:
        """Pair every image with the CameraInfo of the same stamp (or the latest one)."""
        images, infos, truth, image_type = [], {}, {}, None
        with open_reader(path) as reader:
            truth_conn = truth_connection(reader.connections)
            wanted = [c for c in reader.connections if c.msgtype in (*IMAGE_TYPES, INFO_TYPE)]
            wanted += [truth_conn] if truth_conn is not None else []
            for conn, raw, msg in read_messages(reader, path, wanted):
                stamp = stamp_to_seconds(msg.header.stamp)
                if conn.msgtype in IMAGE_TYPES:
                    image_type = conn.msgtype
                    images.append((stamp, bytes(raw)))
                elif conn.msgtype == INFO_TYPE:
                    infos[stamp] = bytes(raw)
                else:
                    truth[stamp] = planar_pose(msg.pose.pose)
        if not images or not infos:
            raise BagError(f'{path} needs images and CameraInfo to be played into the node')
        latest = next(iter(infos.values()))
        frames = []
        for stamp, raw in images[:limit]:
            latest = infos.get(stamp, latest)
            frames.append((stamp, raw, latest))
        return cls(frames, image_type, truth)


class LiveSession:
    """A planar_vo_node subprocess and an rclpy node that feeds it and listens to it."""

    def __init__(self, params_file: str | Path, *, extra_args: tuple[str, ...] = (),
                 image_type: str = IMAGE_TYPES[0], log: Path | None = None) -> None:
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import CameraInfo, CompressedImage, Image

        env = local_dds_env()
        compressed = image_type.endswith('CompressedImage')
        exe = executable('planar_vo_node')
        self._log = open(log, 'w') if log else subprocess.DEVNULL  # noqa: SIM115
        self.proc = subprocess.Popen(
            [exe, '--ros-args', '--params-file', str(params_file),
             '-p', 'image_reliability:=reliable',
             '-p', f'image_transport:={"compressed" if compressed else "raw"}',
             '-r', 'image:=/camera/image_raw', '-r', 'camera_info:=/camera/camera_info',
             *extra_args],
            stdout=self._log, stderr=subprocess.STDOUT, env=env)
        self.ctx = Context()
        rclpy.init(context=self.ctx)
        # The player is the instrument: no parameter services to wait on, odometry kept as
        # the CDR bytes that came (decoded on demand), so its own Python costs little latency.
        self.node = rclpy.create_node('planar_vo_player', context=self.ctx,
                                      start_parameter_services=False)
        reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        topic = '/camera/image_raw' + ('/compressed' if compressed else '')
        self.image_pub = self.node.create_publisher(
            CompressedImage if compressed else Image, topic, reliable)
        self.info_pub = self.node.create_publisher(CameraInfo, '/camera/camera_info', reliable)
        self.received: dict[float, tuple[float, bytes]] = {}  # stamp → (receive time, CDR)
        self.sent: dict[float, float] = {}  # stamp → send time
        self._newest = -np.inf  # the latest stamp whose odometry came
        self._lock = threading.Lock()
        from nav_msgs.msg import Odometry
        self.node.create_subscription(Odometry, '/odom', self._on_odom, 100, raw=True)
        executor = SingleThreadedExecutor(context=self.ctx)
        executor.add_node(self.node)
        self._spin = BackgroundSpin(executor, self.node)

    def _on_odom(self, cdr: bytes) -> None:
        now = time.perf_counter()
        with self._lock:
            stamp = _cdr_stamp(cdr)
            self.received.setdefault(stamp, (now, cdr))
            self._newest = max(self._newest, stamp)

    def odometry(self, stamp: float) -> Any:
        """The nav_msgs/Odometry received for ``stamp``."""
        from nav_msgs.msg import Odometry
        from rclpy.serialization import deserialize_message
        with self._lock:
            cdr = self.received[stamp][1]
        return deserialize_message(cdr, Odometry)

    def _check_alive(self) -> None:
        """Raise LiveError if the node's process has ended: nothing more will come."""
        if self.proc.poll() is not None:
            raise LiveError(f'planar_vo_node exited with status {self.proc.returncode}')

    def wait_connected(self, timeout: float = 30.0) -> None:
        """Wait for discovery both ways (matched counts, not a fixed sleep)."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            self._check_alive()
            if (self.image_pub.get_subscription_count() and self.info_pub.get_subscription_count()
                    and self.node.count_publishers('/odom')):
                return
            time.sleep(0.01)
        raise LiveError(f'planar_vo_node did not connect within {timeout:.0f} s')

    def send(self, frame: tuple[float, bytes, bytes]) -> None:
        """Publish one frame's CameraInfo then its image, as CDR bytes."""
        stamp, image, info = frame
        self.info_pub.publish(info)
        with self._lock:
            self.sent.setdefault(stamp, time.perf_counter())
        self.image_pub.publish(image)

    def handshake(self, frame: tuple[float, bytes, bytes], timeout: float = 30.0) -> None:
        """Send the first frame until its odom comes back: the node is then calibrated."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            self.send(frame)
            if self.wait_for(frame[0], 0.2):
                return
        raise LiveError('planar_vo_node never answered the first frame')

    def wait_for(self, stamp: float, timeout: float) -> bool:
        """True once odom for ``stamp`` has arrived; LiveError if the node has died."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if stamp in self.received:
                return True
            self._check_alive()
            time.sleep(0.002)
        return False

    def play(self, frames: list[tuple[float, bytes, bytes]], rate: float | None = None,
             settle: float = 2.0, window: int | None = None) -> float:
        """Publish frames at their own stamps' pace (``rate=None``) or at ``rate`` Hz.

        ``window``: never more than this many frames ahead of the odometry that came back
        (each waited for up to ``settle`` s): on a loaded machine the player slows down
        instead of the node dropping the frames it cannot keep up with, so what is compared
        does not depend on the machine's load. None: the pace alone (what the node keeps up
        with is then the measurement). With a window, :data:`STALLED_AFTER` frames in a row
        unanswered raise LiveError: the node is alive but stuck, and waiting on would only
        hide it. Returns the seconds the playback took.
        """
        start = time.perf_counter()
        first = frames[0][0]
        unanswered = 0  # frames in a row whose odometry did not come within ``settle``
        for i, frame in enumerate(frames):
            if window is not None and i >= window:
                answered = self.wait_for_any(frames[i - window][0], settle)
                unanswered = 0 if answered else unanswered + 1
                if unanswered >= STALLED_AFTER:
                    raise LiveError(f'planar_vo_node stopped answering: no odometry for '
                                    f'{unanswered} frames in a row ({settle:g} s each)')
            due = start + ((frame[0] - first) if rate is None else i / rate)
            while time.perf_counter() < due:
                time.sleep(min(0.001, max(due - time.perf_counter(), 0)))
            self.send(frame)
        self.wait_for(frames[-1][0], settle)
        return time.perf_counter() - start

    def wait_for_any(self, stamp: float, timeout: float) -> bool:
        """True once odom for ``stamp`` or a later one has arrived.

        The node answers in order: a later answer means ``stamp`` will not come. LiveError
        if the node has died.
        """
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            with self._lock:
                if stamp in self.received or self._newest > stamp:
                    return True
            self._check_alive()
            time.sleep(0.002)
        return False

    def reset(self, timeout: float = 10.0) -> None:
        """Call ~/reset and forget what was sent and received."""
        from std_srvs.srv import Trigger
        self._check_alive()
        client = self.node.create_client(Trigger, '/planar_vo/reset')
        if not client.wait_for_service(timeout_sec=timeout):
            raise LiveError('~/reset service not available')
        future = client.call_async(Trigger.Request())
        end = time.monotonic() + timeout
        while not future.done() and time.monotonic() < end:
            time.sleep(0.005)
        self.node.destroy_client(client)
        with self._lock:
            self.received.clear()
            self.sent.clear()
            self._newest = -np.inf

    def latencies_ms(self, stamps: list[float]) -> np.ndarray:
        """Send → odom-received time of each stamp that came back, ms."""
        with self._lock:
            return np.array([1e3 * (self.received[s][0] - self.sent[s]) for s in stamps
                             if s in self.received and s in self.sent])

    def close(self) -> int:
        """Stop the node like Ctrl-C; return its exit status."""
        import rclpy
        self._spin.stop()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.ctx)
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self._log is not subprocess.DEVNULL:
            self._log.close()
        return self.proc.returncode
