"""Pair each image with the CameraInfo of the same stamp, as image_transport does.

Drivers publish both with one stamp (image_transport's camera subscriber matches them exactly).
Two plain subscriptions on a single-threaded executor can see an image before the CameraInfo
published just before it; used with the previous CameraInfo, a frame right after a change of
calibration or resolution would be wrong. So the last few CameraInfos are kept by stamp, and
an image newer than all of them waits for its own: until it comes, or the next image or a newer
CameraInfo does, or the caller gives up (:meth:`Pairing.flush`, the node does after 50 ms).
When stamps keep not matching (some drivers stamp CameraInfo differently) images use the
newest CameraInfo at once and :attr:`Pairing.unmatched` says so, until stamps match again a
few times in a row. A CameraInfo re-sent with an old stamp is never waited for. No ROS imports.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from typing import Any

__all__ = ['Pairing', 'Paired']

_IN_A_ROW = 3  # misses that stop images waiting; exact matches that make them wait again


@dataclass(frozen=True)
class Paired:
    """An image ready to process, with its CameraInfo (None: none received yet)."""

    image: Any
    info: Any | None
    exact: bool  # the CameraInfo has the image's stamp


class Pairing:
    """Stamp-keyed buffer of CameraInfos and at most one image waiting for its own."""

    def __init__(self, keep: int = 10) -> None:
        self.keep = keep
        self._infos: OrderedDict[int, Any] = OrderedDict()  # stamp (ns) -> info, last newest
        self._waiting: tuple[int, Any] | None = None
        self._latest_stamp: int | None = None  # of all CameraInfos so far
        self._resent = False  # the last CameraInfo was not newer: a driver re-sending one
        self._matches = self._misses = 0  # in a row
        self.unmatched = False  # stamps keep not matching: images use the newest at once

    @property
    def waiting(self) -> bool:
        """An image is waiting for its CameraInfo."""
        return self._waiting is not None

    def add_info(self, stamp_ns: int, info: Any) -> list[Paired]:
        """Store a CameraInfo; return the waiting image if it is done waiting."""
        self._resent = self._latest_stamp is not None and stamp_ns <= self._latest_stamp
        self._latest_stamp = max(stamp_ns, self._latest_stamp or stamp_ns)
        self._infos[stamp_ns] = info
        self._infos.move_to_end(stamp_ns)
        while len(self._infos) > self.keep:
            self._infos.popitem(last=False)
        if self._waiting is None:
            return []
        waiting_stamp, image = self._waiting
        if waiting_stamp == stamp_ns:
            self._waiting = None
            return [self._matched(image, info)]
        if stamp_ns > waiting_stamp or self._resent:  # its own CameraInfo is not coming
            return self.flush()
        return []

    def add_image(self, stamp_ns: int, image: Any) -> list[Paired]:
        """Queue an image; return the images ready to process, oldest first."""
        ready = self.flush()  # the next image came first: stop waiting
        if stamp_ns in self._infos:
            ready.append(self._matched(image, self._infos[stamp_ns]))
        elif not self.unmatched and not self._resent and self._infos and (
                next(reversed(self._infos)) < stamp_ns):
            self._waiting = (stamp_ns, image)  # its CameraInfo may be just behind it
        else:
            ready.append(self._unmatched(image))
        return ready

    def flush(self) -> list[Paired]:
        """The waiting image, if any, with the newest CameraInfo."""
        if self._waiting is None:
            return []
        image, self._waiting = self._waiting[1], None
        return [self._unmatched(image)]

    def _matched(self, image: Any, info: Any) -> Paired:
        self._matches, self._misses = self._matches + 1, 0
        if self._matches >= _IN_A_ROW:
            self.unmatched = False
        return Paired(image, info, True)

    def _unmatched(self, image: Any) -> Paired:
        newest = next(reversed(self._infos.values())) if self._infos else None
        if newest is not None:
            self._matches, self._misses = 0, self._misses + 1
            if self._misses >= _IN_A_ROW:
                self.unmatched = True
        return Paired(image, newest, False)
