"""Small helpers over ``rosbags`` for rosbag2 bags (MCAP storage, Jazzy messages).

Writing::

    with BagWriter(out_dir) as bag:            # out_dir must not exist
        bag.write('/odom', 'nav_msgs/msg/Odometry', stamp_ns, msg)

Messages are built with ``typestore().types[...]`` (every field is required; ``uint8[]``
fields are numpy ``uint8`` arrays). Connections are added on first use of a topic.
MCAP chunks are zstd-compressed by default (``compress=True``): the bag's metadata.yaml
then says ``compression_mode: ''`` as ``ros2 bag record --storage-preset-profile`` bags do,
and every MCAP reader (rosbags, ``ros2 bag``, the ``mcap`` library, Foxglove) reads it.

Reading::

    with open_reader(path) as reader:          # rosbag2 directory or a bare .mcap file
        for conn, raw, msg in read_messages(reader, path):
            ...                                # msg: the deserialized message

Missing paths, directories that are not bags and corrupt bags raise
:class:`planar_vo.io.errors.BagError`.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.interfaces import Connection
from rosbags.rosbag2 import StoragePlugin, Writer, WriterError
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode
from rosbags.typesys import Stores, get_typestore

from planar_vo.io.errors import BagError

__all__ = ['BagWriter', 'open_reader', 'read_messages', 'truth_connection', 'typestore',
           'write_bag', 'IMAGE_TYPES', 'INFO_TYPE', 'ODOM_TYPE', 'PLANAR_TRUTH_TOPIC']

# The message types the tools read: camera images, calibration, ground truth.
IMAGE_TYPES = ('sensor_msgs/msg/Image', 'sensor_msgs/msg/CompressedImage')
INFO_TYPE = 'sensor_msgs/msg/CameraInfo'
ODOM_TYPE = 'nav_msgs/msg/Odometry'
# The planar truth of planar_vo_synth's bags (distance along the surface); on terrain they
# also hold the 3D pose, another Odometry topic whose horizontal projection is not the truth.
PLANAR_TRUTH_TOPIC = '/ground_truth/odom'


@functools.cache
def typestore():
    """Return the ROS 2 Jazzy typestore (cached)."""
    return get_typestore(Stores.ROS2_JAZZY)


class BagWriter:
    """Context manager that writes a rosbag2 bag (MCAP storage, metadata version 9).

    Args:
        path: Output bag directory; must not exist yet.
        compress: zstd-compress the MCAP chunks (storage-level compression).
        version: rosbag2 metadata version (9 for Jazzy, 8 for Humble).

    """

    def __init__(self, path, *, compress: bool = True, version: int = 9) -> None:
        self.path = Path(path)
        if self.path.exists():
            raise BagError(f'output bag {self.path} already exists')
        if not self.path.parent.is_dir():
            raise BagError(f'parent directory of {self.path} does not exist')
        self._writer = Writer(self.path, version=version, storage_plugin=StoragePlugin.MCAP)
        if compress:
            self._writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        self._connections: dict[str, Connection] = {}
        self._open = False

    def __enter__(self) -> BagWriter:
        """Open the bag."""
        self.open()
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        """Close the bag (also after an error, so that what was written stays readable)."""
        self.close()

    def open(self) -> None:
        """Create the bag directory and start writing."""
        try:
            self._writer.open()
        except (WriterError, OSError) as err:
            raise BagError(f'cannot create bag {self.path}: {err}') from None
        self._open = True

    def close(self) -> None:
        """Finish the bag: write the MCAP summary and metadata.yaml."""
        if self._open:
            self._open = False
            self._writer.close()

    def add_topic(self, topic: str, msgtype: str, qos=()) -> Connection:
        """Add a connection for ``topic`` (idempotent); return it."""
        conn = self._connections.get(topic)
        if conn is None:
            conn = self._writer.add_connection(
                topic, msgtype, typestore=typestore(), offered_qos_profiles=qos
            )
            self._connections[topic] = conn
        elif conn.msgtype != msgtype:
            raise BagError(f'topic {topic} already has type {conn.msgtype}, not {msgtype}')
        return conn

    def write(self, topic: str, msgtype: str, stamp_ns: int, msg) -> None:
        """Serialize ``msg`` (CDR) and write it with receive time ``stamp_ns``."""
        conn = self.add_topic(topic, msgtype)
        self._writer.write(conn, int(stamp_ns), typestore().serialize_cdr(msg, msgtype))

    def write_raw(self, topic: str, msgtype: str, stamp_ns: int, data: bytes) -> None:
        """Write already CDR-serialized bytes."""
        conn = self.add_topic(topic, msgtype)
        self._writer.write(conn, int(stamp_ns), data)


def write_bag(path, messages: Iterable[tuple[str, str, int, object]], *, compress=True) -> None:
    """Write ``(topic, msgtype, stamp_ns, msg)`` tuples to a new bag at ``path``."""
    with BagWriter(path, compress=compress) as bag:
        for topic, msgtype, stamp_ns, msg in messages:
            bag.write(topic, msgtype, stamp_ns, msg)


def truth_connection(connections: Iterable[Connection]) -> Connection | None:
    """The ground truth's connection: the bag's one Odometry topic, or the planar truth's.

    None when the bag has none, or several and no planar truth among them.
    """
    found = [c for c in connections if c.msgtype == ODOM_TYPE]
    if len({c.topic for c in found}) == 1:
        return found[0]
    return next((c for c in found if c.topic == PLANAR_TRUTH_TOPIC), None)


class _Reader(AnyReader):
    """AnyReader that is already open; ``with`` does not reopen it but closes it."""

    def __enter__(self):
        if not self.stack:
            self.open()
        return self


def open_reader(path) -> AnyReader:
    """Open a rosbag2 directory or a bare ``.mcap`` file; return an open ``AnyReader``.

    Use it as ``with open_reader(p) as reader:`` or call ``reader.close()`` when done.
    Raises :class:`BagError` for a missing path, something that is not a bag or a corrupt bag.
    """
    p = Path(path)
    if not p.exists():
        raise BagError(f'bag not found: {p}')
    if p.is_dir() and not (p / 'metadata.yaml').is_file():
        raise BagError(f'{p} is not a rosbag2 bag (no metadata.yaml)')
    if p.is_file() and p.suffix != '.mcap':
        raise BagError(f'{p} is not a rosbag2 directory or .mcap file')
    try:
        reader = _Reader([p], default_typestore=typestore())
        reader.open()
    except (AnyReaderError, OSError, ValueError, KeyError) as err:
        raise BagError(f'cannot read bag {p}: {err}') from None
    return reader


def read_messages(reader: AnyReader, path, connections: list[Connection] | None = None, *,
                  decode: Callable[[Connection], bool] = lambda conn: True
                  ) -> Iterator[tuple[Connection, bytes, Any]]:
    """``(connection, CDR bytes, message)`` of each message of ``connections`` (default: all).

    The message is deserialized where ``decode(connection)`` is true, else None (kept as
    bytes, e.g. images to decode later). A bag that turns out truncated or corrupt part way
    raises :class:`BagError` (rosbags raises many kinds of exception for it).
    """
    messages, count = reader.messages(connections=connections), 0
    while True:
        try:
            conn, _, raw = next(messages)
            msg = reader.deserialize(raw, conn.msgtype) if decode(conn) else None
        except StopIteration:
            return
        except Exception as err:  # noqa: BLE001 - whatever rosbags raises on a broken file
            raise BagError(f'bag {path} is corrupt after {count} messages '
                           f'({type(err).__name__}: {err})') from None
        count += 1
        yield conn, raw, msg
