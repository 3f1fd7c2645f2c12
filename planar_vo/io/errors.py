"""The exceptions of the I/O layer (bags and the package's files), in one place.

Each carries a message for a person: the CLIs print it as one ``error:`` line (exit 2).
"""

from __future__ import annotations

__all__ = ['BagError', 'ResourceError']


class BagError(Exception):
    """A bag cannot be read or written.

    Raised by :mod:`planar_vo.io.bag` for a missing path, a directory that is not a rosbag2
    bag, a corrupt or truncated bag (also part way through reading it), an output bag that
    already exists, and by the tools for a bag that lacks what they need (no images, no
    CameraInfo).
    """


class ResourceError(FileNotFoundError):
    """A file or an executable of the package cannot be found (the message says how to fix it).

    Raised by :mod:`planar_vo.io.resources` when neither the source tree nor an install (colcon
    or pip) has the share directory, or ``planar_vo_node`` is neither on PATH nor in a sourced
    workspace's ``lib/planar_vo``.
    """
