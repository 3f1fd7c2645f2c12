"""What the ROS adapters raise besides the core's errors."""

from __future__ import annotations

__all__ = ['ImageError', 'StartupError']


class ImageError(ValueError):
    """An image message that cannot be turned into a grey image (with the reason)."""


class StartupError(Exception):
    """An invalid start-up parameter: the node reports it as one line, exit status 2."""
