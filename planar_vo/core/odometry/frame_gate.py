"""Which images the odometry may track: the checks made before any tracking."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planar_vo.core.odometry.result import FrameStatus

__all__ = ['FrameGate', 'Refusal']

_BLANK_STD = 2.0  # grey levels: below this spread an image has nothing to track


@dataclass(frozen=True)
class Refusal:
    """Why a frame is not tracked as usual, and what follows from it."""

    status: FrameStatus
    message: str
    counter: str | None = None  # the odometry's counter that counts it
    restart: bool = False  # tracking restarts at this frame
    extrapolate: bool = False  # with restart: extrapolate the unseen motion (tracks lost)


class FrameGate:
    """Refuses frames of the wrong size, repeated stamps, blank images and time jumps.

    Its state is the stamp of the last frame let through (or restarted at).
    """

    def __init__(self, max_frame_gap: float) -> None:
        self.max_frame_gap = max_frame_gap
        self.last_stamp: float | None = None

    def check(self, gray: np.ndarray, stamp: float, camera_size: tuple[int, int],
              tracked_shape: tuple[int, int] | None) -> Refusal | None:
        """The reason ``gray`` (H, W) at ``stamp`` cannot be tracked, or None.

        ``camera_size``: (width, height) of the CameraInfo; ``tracked_shape``: (H, W) of
        the last image tracked, None before the first.
        """
        h, w = gray.shape
        if camera_size != (w, h):
            return Refusal(FrameStatus.SKIPPED, (
                f'image is {w}x{h} but CameraInfo says {camera_size[0]}x{camera_size[1]} '
                '(after its binning and ROI): frame skipped'), 'skipped')
        last = self.last_stamp
        if last is not None and stamp == last:
            return Refusal(FrameStatus.DUPLICATE,
                           'duplicate stamp: frame skipped, no odometry for it', 'skipped')
        if float(gray[::8, ::8].std()) < _BLANK_STD:  # lens cap, no exposure: keep the tracks
            return Refusal(FrameStatus.BLANK, 'blank image skipped', 'blank')
        if last is not None and (stamp < last or stamp - last > self.max_frame_gap):
            gap = stamp - last
            why = (f'stamp went backwards by {-gap:.3f} s' if gap < 0 else
                   f'stamps {gap:.3f} s apart, over max_frame_gap {self.max_frame_gap:g} s')
            return Refusal(FrameStatus.TIME_JUMP, f'time jumped ({why}): tracking restarted',
                           'time_jumps', restart=True)
        if tracked_shape is not None and tracked_shape != gray.shape and last is not None:
            return Refusal(FrameStatus.REINITIALIZED, 'image size changed: tracking restarted',
                           restart=True, extrapolate=True)
        return None
