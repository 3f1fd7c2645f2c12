"""How the odometry is doing, as /diagnostics reports it: a level, why, and the numbers.

WARN when no image came for a second or the image rate fell below half of what it was, ERROR
while tracking is lost (a restart after failed frames, or more than a few frames in a row
without an estimate), OK otherwise. Several conditions at once: the worst level, every reason.
No ROS imports: the node feeds it receive times (monotonic s) and frame results.
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


class Health:
    """Image arrivals and frame results in; ``report(now)`` out."""

    def __init__(self, *, stale_after: float = 1.0, window: float = 2.0,
                 smoothing: float = 0.1) -> None:
        self.stale_after, self.window, self.smoothing = stale_after, window, smoothing
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

    def image_received(self, now: float) -> None:
        """An image arrived at ``now`` (monotonic s), whether or not it could be used.

        Arrival times may come out of order (images queued while the node was busy are
        dated when they were received): they are kept sorted.
        """
        bisect.insort(self._arrivals, now)
        self._last_arrival = max(now, self._last_arrival or now)

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
            'frames without estimate in a row': str(self._failed_in_a_row),
            'last failure': self.last_failure or 'none',
        }
        return level, message, values
