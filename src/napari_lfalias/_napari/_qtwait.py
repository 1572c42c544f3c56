"""Waiting on the Qt event loop (for scripts and benchmarks that drive the widgets)."""

from __future__ import annotations

import time

__all__ = ["run_event_loop_until"]


def run_event_loop_until(condition, timeout_s=30.0, interval_ms=1):
    """Run the Qt event loop (a ``QEventLoop``, not a busy wait) until ``condition()`` holds.

    Parameters
    ----------
    condition : callable
        Checked every ``interval_ms`` while events are processed.
    timeout_s : float
        Give up after this long.
    interval_ms : int
        How often ``condition`` is checked.

    Raises
    ------
    TimeoutError
        If ``condition()`` still fails after ``timeout_s``.
    """
    from qtpy.QtCore import QEventLoop, QTimer

    if condition():
        return
    loop = QEventLoop()
    timer = QTimer()
    timer.setInterval(interval_ms)
    deadline = time.perf_counter() + timeout_s

    def check():
        if condition() or time.perf_counter() > deadline:
            loop.quit()

    timer.timeout.connect(check)
    timer.start()
    loop.exec()
    timer.stop()
    if not condition():
        raise TimeoutError(f"condition not met within {timeout_s} s")
