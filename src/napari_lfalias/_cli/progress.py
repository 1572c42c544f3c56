"""Small progress and timing helpers for the command line (stderr only)."""

from __future__ import annotations

import sys
import time
from contextlib import contextmanager

__all__ = ["Progress", "StepProgress", "Stages"]


class Progress:
    """A one-line counter on stderr: ``label: k/n``, redrawn in place on a terminal.

    Off a terminal (a log file, a pipe) only the final count is printed, so
    logs stay readable. ``quiet=True`` prints nothing.
    """

    def __init__(self, total, label, quiet=False, stream=None):
        self.total = int(total)
        self.label = label
        self.count = 0
        self.stream = stream or sys.stderr
        self.quiet = quiet
        self.live = not quiet and getattr(self.stream, "isatty", lambda: False)()
        self._draw()

    def _draw(self):
        if self.live:
            self.stream.write(f"\r{self.label}: {self.count}/{self.total}")
            self.stream.flush()

    def update(self, n=1):
        self.count += n
        self._draw()

    def close(self):
        if self.quiet:
            return
        prefix = "\r" if self.live else ""
        self.stream.write(f"{prefix}{self.label}: {self.count}/{self.total} finished\n")
        self.stream.flush()


class StepProgress:
    """The steps of a long decode on stderr: ``label: k/n step``, redrawn in place on a terminal.

    Called as ``progress(done, total, step)`` (the decoders' ``progress=``).
    Off a terminal only the final line is printed, and only if a step was
    reported; ``quiet=True`` prints nothing.

    Examples
    --------
    >>> import io
    >>> out = io.StringIO()
    >>> progress = StepProgress("decoding", stream=out)
    >>> progress(0, 2, "calibrating"); progress(2, 2, "done"); progress.close()
    >>> out.getvalue().strip()
    'decoding: 2/2 steps finished'
    """

    def __init__(self, label, quiet=False, stream=None):
        self.label = label
        self.stream = stream or sys.stderr
        self.quiet = quiet
        self.live = not quiet and getattr(self.stream, "isatty", lambda: False)()
        self.last = None

    def __call__(self, done, total, step):
        self.last = (done, total)
        if self.live:
            self.stream.write(f"\r{self.label}: {done}/{total} {step}\x1b[K")
            self.stream.flush()

    def close(self, failed=False):
        """End the display: the final line, or (``failed``) just clear the live one."""
        if self.quiet or self.last is None:
            return
        if failed:
            if self.live:
                self.stream.write("\r\x1b[K")
                self.stream.flush()
            return
        line = f"{self.label}: {self.last[0]}/{self.last[1]} steps finished"
        self.stream.write(f"\r{line}\x1b[K\n" if self.live else f"{line}\n")
        self.stream.flush()


class Stages:
    """Time named stages; print ``[k/n] stage ... 0.12 s`` as each ends.

    Examples
    --------
    >>> import io
    >>> out = io.StringIO()
    >>> stages = Stages(2, stream=out)
    >>> with stages("load"):
    ...     pass
    >>> out.getvalue().startswith("[1/2] load")
    True
    """

    def __init__(self, total, quiet=False, stream=None):
        self.total = total
        self.done = 0
        self.quiet = quiet
        self.stream = stream or sys.stdout
        self.seconds = {}

    @contextmanager
    def __call__(self, name):
        if not self.quiet and getattr(self.stream, "isatty", lambda: False)():
            self.stream.write(f"[{self.done + 1}/{self.total}] {name} ...\r")
            self.stream.flush()
        start = time.perf_counter()
        yield
        elapsed = time.perf_counter() - start
        self.seconds[name] = elapsed
        self.done += 1
        if not self.quiet:
            self.stream.write(f"[{self.done}/{self.total}] {name:<32s} {elapsed:8.3f} s\n")
            self.stream.flush()

    @property
    def total_seconds(self):
        return sum(self.seconds.values())
