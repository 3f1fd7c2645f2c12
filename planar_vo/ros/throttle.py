"""One log line per distinct cause: the same problem again is counted, not repeated.

No ROS: the node passes the log call in.
"""

from __future__ import annotations

import re
from collections import OrderedDict
from collections.abc import Callable

__all__ = ['WarningThrottle']

# Numbers in a message (sizes like 640x480 too), but not digits inside names like mono16.
_NUMBER = re.compile(r'\d+x\d+|(?<![A-Za-z_\d.])[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?'
                     r'|\bnan\b|\binf\b')


class WarningThrottle:
    """Logs a message at once, then the same cause at most every ``every`` s with a count.

    The cause is the text with its numbers stripped, so the same problem with other numbers
    is throttled and a different problem is always reported at once. At most ``causes``
    are remembered (the oldest forgotten first).
    """

    def __init__(self, every: float = 10.0, causes: int = 64) -> None:
        self.every = every
        self.causes = causes
        self._seen: OrderedDict[str, tuple[float, int]] = OrderedDict()

    def __call__(self, text: str, now: float, log: Callable[[str], None]) -> bool:
        """Log ``text`` through ``log`` unless its cause was logged under ``every`` s ago.

        Returns True when it was logged. ``now``: a monotonic time, s.
        """
        cause = _NUMBER.sub('#', text)
        last, count = self._seen.pop(cause, (-1e9, 0))
        logged = now - last >= self.every
        if logged:
            log(text + (f' (and {count} more times)' if count else ''))
            last, count = now, 0
        else:
            count += 1
        self._seen[cause] = (last, count)  # most recent last
        if len(self._seen) > self.causes:
            self._seen.popitem(last=False)
        return logged
