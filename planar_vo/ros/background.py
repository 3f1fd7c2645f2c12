"""An rclpy executor spun on a thread of its own, and stopped before anything is destroyed.

``executor.shutdown()`` does not wait for a thread inside ``executor.spin()``: destroying the
nodes and the context right after it let that thread meet the shutdown inside its wait set,
where it spun holding the GIL while the main thread waited for it (a player that hung for
minutes after its node had exited, once in 12 runs with two busy processes). Here the thread is
woken by a guard condition and joined first; only then is the executor shut down.
"""

from __future__ import annotations

import threading
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from rclpy.executors import Executor
    from rclpy.node import Node

__all__ = ['BackgroundSpin']


class BackgroundSpin:
    """Spin ``executor`` on a daemon thread until :meth:`stop`."""

    def __init__(self, executor: Executor, node: Node) -> None:
        """``node``: one of the executor's nodes, which owns the guard condition that wakes it."""
        self.executor = executor
        self._stopping = threading.Event()
        self._wake = node.create_guard_condition(lambda: None)
        self._node = node
        self._thread = threading.Thread(target=self._run, name='rclpy spin', daemon=True)
        self._thread.start()

    def _run(self) -> None:
        context = self.executor.context
        while not self._stopping.is_set() and context.ok():
            self.executor.spin_once()

    def stop(self, timeout: float = 10.0) -> bool:
        """Wake the thread, wait for it to leave the executor, then shut the executor down.

        Call before destroying the nodes or shutting the context down. Returns whether the
        thread had left within ``timeout`` s (a callback that never returns keeps it).
        """
        self._stopping.set()
        self._wake.trigger()
        self._thread.join(timeout)
        self.executor.shutdown()
        self._node.destroy_guard_condition(self._wake)
        return not self._thread.is_alive()
