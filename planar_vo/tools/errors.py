"""The exceptions of the command-line tools, in one place.

Each carries a message for a person: the CLIs print it as one ``error:`` line (exit 2).
The I/O layer's are in :mod:`planar_vo.io.errors`.
"""

from __future__ import annotations

__all__ = ['ReplayError', 'LiveError', 'CalibrationError']


class ReplayError(RuntimeError):
    """The bag cannot be replayed as asked.

    Raised by :func:`planar_vo.tools.replay.replay` for a topic that is not in the bag or has
    the wrong type, several candidate topics and no choice among them, no image or CameraInfo
    topic, no usable CameraInfo at all, or an output path that exists.
    """


class LiveError(RuntimeError):
    """The node over DDS did not start, connect or answer in time, or it died.

    Raised by :class:`planar_vo.tools.live_session.LiveSession` (demo, bench ``--live``, soak):
    ``planar_vo_node`` exited, discovery did not complete, the first frame was never answered,
    ``~/reset`` was not available, or (soak) its resident memory could not be read.
    """


class CalibrationError(RuntimeError):
    """The drive cannot calibrate the mounting.

    Raised by :func:`planar_vo.tools.calibrate.calibrate` when too few frames could be
    estimated (too short a drive, no texture) or, with ``--known-distance``, the drive is too
    short to scale the camera height.
    """
