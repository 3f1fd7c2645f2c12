"""A one-line progress bar on stderr for long CLI work (no dependency needed for this)."""

from __future__ import annotations

import sys
import time

__all__ = ['Progress']


class Progress:
    """``Progress(total, 'label')``; ``update(done)``; ``close()``. Redraws at most 10 Hz."""

    def __init__(self, total: int, label: str, *, enabled: bool = True) -> None:
        self.total, self.label, self.enabled = max(int(total), 1), label, enabled
        self._start = self._last = time.monotonic()
        self._done = 0

    def update(self, done: int) -> None:
        """Report ``done`` items finished."""
        self._done = done
        now = time.monotonic()
        if self.enabled and (now - self._last > 0.1 or done >= self.total):
            self._last = now
            self._draw(now)

    def _draw(self, now: float) -> None:
        frac = min(self._done / self.total, 1.0)
        rate = self._done / max(now - self._start, 1e-9)
        eta = (self.total - self._done) / rate if rate > 0 else 0.0
        bar = '#' * int(30 * frac)
        sys.stderr.write(f'\r{self.label} [{bar:<30}] {self._done}/{self.total} '
                         f'{rate:5.1f}/s eta {eta:4.0f}s')
        sys.stderr.flush()

    def close(self) -> None:
        """Finish the line."""
        if self.enabled:
            self._draw(time.monotonic())
            sys.stderr.write('\n')
            sys.stderr.flush()
