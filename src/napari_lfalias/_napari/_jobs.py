"""Background jobs for the widgets: one slot per kind of job, latest request wins.

A job is a generator that yields ``(done, total)`` between steps and
returns its result. A request is a function that makes the job when the
slot is free, so a request that had to wait reads the controls as they are
when it starts, not as they were when it was made. It runs in a napari ``thread_worker``; while it
runs, the GUI thread keeps processing events. A new request for a busy
slot asks the running job to stop (``quit()``: it stops at its next yield)
and starts once the slot is free, so requests never pile up. Each request
is stamped with a generation number; a result whose generation is no
longer current is dropped.
"""

from __future__ import annotations

import time

from napari.qt.threading import GeneratorWorker, create_worker
from qtpy.QtCore import QCoreApplication

__all__ = ["JobRunner"]


class JobRunner:
    """Runs generator jobs in worker threads, one per slot.

    Parameters
    ----------
    on_progress : callable, optional
        ``on_progress(slot, done, total)`` on each yield of a job.
    on_error : callable, optional
        ``on_error(slot, exception)`` when a job raises.
    on_idle : callable, optional
        ``on_idle()`` when the last running job has finished.
    """

    def __init__(self, on_progress=None, on_error=None, on_idle=None):
        self.generation = 0
        self._workers = {}
        self._pending = {}
        self._on_progress = on_progress
        self._on_error = on_error
        self._on_idle = on_idle

    # -- state ---------------------------------------------------------------
    def bump(self):
        """Make every result in flight stale (parameters changed)."""
        self.generation += 1
        return self.generation

    def busy(self, slot=None):
        """True if a job runs (in ``slot``, or in any slot)."""
        if slot is not None:
            return slot in self._workers
        return bool(self._workers)

    def workers(self):
        """The workers running now."""
        return list(self._workers.values())

    # -- requests ---------------------------------------------------------------
    def submit(self, slot, make_job):
        """Run a job in ``slot``.

        Parameters
        ----------
        slot : str
            The kind of job (one job per slot at a time).
        make_job : callable
            ``make_job()`` returns ``(generator, on_result)`` or ``None``
            (nothing to do); it is called when the slot is free.
            ``on_result(result)`` is called only if no parameter changed and
            no newer request came for the slot while the job ran.

        If ``slot`` is busy, the running job is asked to stop and this
        request replaces any earlier one waiting for the slot.
        """
        if slot in self._workers:
            self._pending[slot] = make_job
            self._workers[slot].quit()
            return
        self._start(slot, make_job)

    def cancel(self):
        """Stop every job, drop waiting requests, and make results in flight stale."""
        self._pending.clear()
        self.bump()
        for worker in list(self._workers.values()):
            worker.quit()

    def shutdown(self, timeout_s=10.0):
        """Cancel everything and wait (processing events) for the jobs to end.

        Returns
        -------
        bool
            True if every job ended within ``timeout_s``.
        """
        self.cancel()
        deadline = time.monotonic() + timeout_s
        while self._workers and time.monotonic() < deadline:
            QCoreApplication.processEvents()
            time.sleep(0.005)
        return not self._workers

    # -- internals --------------------------------------------------------------
    def _start(self, slot, make_job):
        made = make_job()
        if made is None:
            self._finish(slot, None)
            return None
        generator, on_result = made
        generation = self.generation
        worker = create_worker(
            lambda: (yield from generator),
            _start_thread=False,
            _worker_class=GeneratorWorker,
            _ignore_errors=True,
        )
        self._workers[slot] = worker

        def returned(result):
            if generation == self.generation and slot not in self._pending:
                on_result(result)

        def yielded(step):
            if self._on_progress is not None and generation == self.generation:
                self._on_progress(slot, *step)

        def errored(error):
            if self._on_error is not None and generation == self.generation:
                self._on_error(slot, error)

        def finished():
            self._finish(slot, worker)

        worker.returned.connect(returned)
        worker.yielded.connect(yielded)
        worker.errored.connect(errored)
        worker.finished.connect(finished)
        worker.start()
        return worker

    def _finish(self, slot, worker):
        if worker is not None and self._workers.get(slot) is worker:
            del self._workers[slot]
        waiting = self._pending.pop(slot, None)
        if waiting is not None:
            self._start(slot, waiting)
        elif not self._workers and self._on_idle is not None:
            self._on_idle()
