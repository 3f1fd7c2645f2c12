"""How the odometry is doing, as /diagnostics reports it: a level, why, and the numbers.

WARN when no image came for a second, the image rate fell below half of what it was, or images
were lost on the way (gaps in the publisher's sequence numbers); ERROR while tracking is lost
(a restart after failed frames, or more than a few frames in a row without an estimate), OK
otherwise. Several conditions at once: the worst level, every reason. No ROS imports: the node
feeds it receive times (monotonic s), sequence numbers and frame results.
"""

from __future__ import annotations

import bisect
import statistics
from collections import deque
from typing import Any

__all__ = ['Health', 'OK', 'WARN', 'ERROR']

OK, WARN, ERROR = 0, 1, 2  # the levels of diagnostic_msgs/DiagnosticStatus
_NEUTRAL = ('first', 'duplicate')  # statuses that say nothing about tracking
_LOST_AFTER = 3  # frames in a row without an estimate before tracking counts as lost
RECENT_FRAMES = 60  # the median processing time is over this many of the latest frames
# Images lost on the way over this share of those sent within the window make a warning.
_LOST_SHARE = 0.05
# Fast DDS loses best-effort messages larger than its shared-memory segment, sent at full rate
# (20-70 % of 1 MB images on this machine); smaller ones arrive whole (ROS notes).
LARGE_IMAGE_BYTES = 512 * 1024


class Health:
    """Image arrivals and frame results in; ``report(now)`` out."""

    def __init__(self, *, stale_after: float = 1.0, window: float = 2.0,
                 smoothing: float = 0.1, best_effort: bool = True) -> None:
        self.stale_after, self.window, self.smoothing = stale_after, window, smoothing
        self.best_effort = best_effort  # the image subscription's QoS: what a loss advises
        self._last_sequence: int | None = None
        self._lost: deque[tuple[float, int]] = deque()  # (receive time, images lost before it)
        self.lost_total = 0
        self.image_bytes = 0  # the last image's data
        self._arrivals: deque[float] = deque()  # receive times within the last window
        self._last_arrival: float | None = None
        self._usual_rate: float | None = None  # smoothed image rate, Hz
        self._failed_in_a_row = 0
        self._restarted = False  # tracking restarted since the last estimated frame
        self.last_failure = ''
        self.last_status = 'waiting for images'
        self.tracks = self.inliers = self.frames = 0
        self.rms_px = 0.0  # the last estimate's inlier rms error: inlier_threshold ~3x this
        self.processing_ms = self._ms_sum = 0.0
        # The median of the latest frames: a mean since start-up hides a slowdown, and one
        # busy moment of a shared machine moves a mean but not a median.
        self._recent_ms: deque[float] = deque(maxlen=RECENT_FRAMES)

    def image_received(self, now: float, sequence: int | None = None,
                       size_bytes: int = 0) -> None:
        """An image arrived at ``now`` (monotonic s), whether or not it could be used.

        Arrival times may come out of order (images queued while the node was busy are
        dated when they were received): they are kept sorted. ``sequence``: the publisher's
        sequence number of the message (its gaps are images lost on the way, in the
        middleware or the subscription's queue); a lower one starts over (another publisher,
        a restarted one). ``size_bytes``: the image's data.
        """
        bisect.insort(self._arrivals, now)
        self._last_arrival = max(now, self._last_arrival or now)
        if sequence is not None:
            if self._last_sequence is not None and sequence > self._last_sequence + 1:
                lost = sequence - self._last_sequence - 1
                self._lost.append((now, lost))
                self.lost_total += lost
            self._last_sequence = sequence
        self.image_bytes = size_bytes

    def frame_done(self, result: Any) -> None:
        """A FrameResult of the odometry."""
        self.frames += 1
        self.last_status = result.status
        self.tracks, self.inliers = result.tracks, result.inliers
        self.rms_px = float(result.rms_px)
        self.processing_ms = float(result.timing_ms.get('total', 0.0))
        self._ms_sum += self.processing_ms
        self._recent_ms.append(self.processing_ms)
        if result.status == 'ok':
            self._failed_in_a_row, self._restarted = 0, False
        elif result.status not in _NEUTRAL:
            self.frame_failed(f'{result.status}: {result.message}' if result.message
                              else result.status, restarted=result.status == 'reinitialized')

    def frame_failed(self, reason: str, *, restarted: bool = False) -> None:
        """A frame gave no estimate (or could not be used at all) for ``reason``."""
        self._failed_in_a_row += 1
        self._restarted |= restarted
        self.last_failure = reason

    def rate(self, now: float) -> float:
        """Images per second over the last ``window`` s (0 with fewer than two)."""
        span = self._span(now)
        return (len(self._arrivals) - 1) / span if span > 0 else 0.0

    def _span(self, now: float) -> float:
        """Seconds between the first and the last image of the last ``window`` s."""
        while self._arrivals and self._arrivals[0] < now - self.window:
            self._arrivals.popleft()
        return self._arrivals[-1] - self._arrivals[0] if self._arrivals else 0.0

    def _lost_share(self, now: float) -> float:
        """Of the images sent within the last ``window`` s, the share lost on the way."""
        while self._lost and self._lost[0][0] < now - self.window:
            self._lost.popleft()
        lost = sum(n for _, n in self._lost)
        received = sum(1 for t in self._arrivals if t >= now - self.window)
        return lost / (lost + received) if lost else 0.0

    def _lost_advice(self, share: float) -> str:
        """What the loss says, and what to do when the QoS and the images' size explain it."""
        text = f'{100 * share:.0f} % of the images lost on the way'
        if self.best_effort and self.image_bytes > LARGE_IMAGE_BYTES:
            text += (f' ({self.image_bytes / 1024:.0f} kB each, best-effort QoS: Fast DDS '
                     'loses those over 512 kB): set image_reliability to reliable (the camera '
                     'publishing reliable), or send smaller images (mono8, compressed)')
        return text

    def report(self, now: float, *, calibrated: bool,
               ground_irregular: bool = False) -> tuple[int, str, dict[str, str]]:
        """(level, message, values) at ``now``; call it about once a second.

        ``ground_irregular``: the odometry does not trust the ground ahead (WARN).
        """
        rate = self.rate(now)
        problems: list[tuple[int, str]] = []
        if self._last_arrival is None:
            problems.append((WARN, 'no image received yet'))
        elif now - self._last_arrival > self.stale_after:
            problems.append((WARN, f'no image for {now - self._last_arrival:.1f} s'))
        if not calibrated:
            problems.append((WARN, 'waiting for a valid camera_info'))
        elif self._restarted or self._failed_in_a_row > _LOST_AFTER:
            problems.append((ERROR, f'tracking lost ({self.last_failure})'))
        elif self._failed_in_a_row:
            problems.append((WARN, self.last_failure))
        if calibrated and ground_irregular:
            problems.append((WARN, 'the ground ahead is irregular: covariance inflated'))
        lost = self._lost_share(now)
        if lost > _LOST_SHARE:
            problems.append((WARN, self._lost_advice(lost)))
        if rate > 0 and self._usual_rate and rate < 0.5 * self._usual_rate:
            problems.append((WARN, f'image rate {rate:.1f} Hz, below half of the usual '
                                   f'{self._usual_rate:.1f} Hz'))
        # A lasting new rate becomes the usual one within ~15 reports; a rate over a short
        # span (the first images, two of a burst) is shown but not learned.
        if rate > 0 and self._span(now) >= 0.25 * self.window:
            self._usual_rate = rate if self._usual_rate is None else (
                (1 - self.smoothing) * self._usual_rate + self.smoothing * rate)
        level = max((lvl for lvl, _ in problems), default=OK)
        message = '; '.join(text for _, text in problems) or 'tracking'
        values = {
            'state': self.last_status,
            'image rate (Hz)': f'{rate:.2f}',
            'tracks': str(self.tracks), 'inliers': str(self.inliers),
            'inlier rms error (px)': f'{self.rms_px:.3f}',
            'processing time (ms)': f'{self.processing_ms:.2f}',
            'mean processing time (ms)': f'{self._ms_sum / max(self.frames, 1):.2f}',
            f'median processing time, last {RECENT_FRAMES} frames (ms)':
                f'{statistics.median(self._recent_ms) if self._recent_ms else 0.0:.2f}',
            'images lost on the way': str(self.lost_total),
            'frames without estimate in a row': str(self._failed_in_a_row),
            'last failure': self.last_failure or 'none',
        }
        return level, message, values
