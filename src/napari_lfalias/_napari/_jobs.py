"""Background jobs for the widgets: one slot per kind of job, latest request wins.

A job is a generator that yields ``(done, total)`` between steps and
returns its result; it may also yield a :class:`Partial` (an early result,
such as the refocused image before its Cv), handed to the request's
``on_partial`` under the same staleness rule as the final result.

A request is a function that makes the job when the slot is free, so a
request that had to wait reads the controls as they are when it starts,
not as they were when it was made. The job runs in a napari
``thread_worker``; while it runs, the GUI thread keeps processing events. A
new request for a busy slot asks the running job to stop (``quit()``: it
stops at its next yield) and starts once the slot is free, so requests
never pile up. Each request is stamped with a generation number; a result
whose generation is no longer current is dropped, unless the job was
submitted as ``lasting`` (its result depends on none of the parameters,
e.g. a light field's disparity): then only :meth:`JobRunner.cancel`, a
newer request for its slot or the owner's deletion stop it. Errors are
always reported, stale or not. A job may yield ``(done, total, stage)``:
the stage's name goes to ``on_progress`` too.

A stopped job is closed in its own worker thread as soon as it stops
(:class:`_ClosingWorker`): its ``finally`` blocks run then (a lock it
holds is released), not whenever the garbage collector gets to it.
superqt's ``GeneratorWorker.quit()`` alone only stops iterating.

The runner may belong to a widget (``owner``): once the widget is deleted
(its viewer closed), running jobs are asked to stop and nothing is
delivered to it any more, so no callback touches a deleted Qt object.

napari and Qt are imported when a job starts, so :class:`Partial` can be
used by code that runs without them (the session).
"""

from __future__ import annotations

import time

__all__ = ["JobRunner", "Partial"]


class Partial:
    """An early result a job yields before its final one.

    Parameters
    ----------
    value : object
        Handed to the request's ``on_partial(value)`` in the GUI thread.
    """

    __slots__ = ("value",)

    def __init__(self, value):
        self.value = value


class _Failed:
    """What a guarded job yields when it raised (see :func:`_guarded`)."""

    __slots__ = ("error",)

    def __init__(self, error):
        self.error = error


_FAILED = object()


def _guarded(generator):
    """Run ``generator``, turning an exception into a yielded :class:`_Failed`.

    superqt's workers treat a ``RuntimeError`` (and its subclasses, such as
    ``NotImplementedError``) raised by the job as "the worker was deleted":
    they warn and return without emitting ``errored`` or ``finished``, so
    the error would be lost and the slot stay busy. Errors therefore never
    leave the job; a yielded value is delivered even when the worker was
    asked to quit meanwhile.
    """
    try:
        return (yield from generator)
    except Exception as error:  # every error is reported through the yield, none is raised
        yield _Failed(error)
        return _FAILED


def _closing_worker(job):
    """A superqt ``GeneratorWorker`` running ``job`` that closes it when it stops, in its thread.

    superqt's worker leaves its loop on ``quit()`` (or when a signal can
    no longer be emitted) without closing the generator, so the job's
    ``finally`` blocks would wait for the garbage collector. This one closes
    the job on every way out: finished, stopped or failed.
    """
    from superqt.utils import GeneratorWorker

    class _ClosingWorker(GeneratorWorker):
        def work(self):
            try:
                return super().work()
            finally:
                job.close()  # the job is suspended at a yield (or done): safe to close here

    return _ClosingWorker(_guarded, job)


def _alive(owner):
    """False once the Qt object ``owner`` has been deleted (``None``: no owner, always alive)."""
    if owner is None:
        return True
    try:
        owner.objectName()
    except RuntimeError:  # "wrapped C/C++ object ... has been deleted"
        return False
    return True


class JobRunner:
    """Runs generator jobs in worker threads, one per slot.

    Parameters
    ----------
    on_progress : callable, optional
        ``on_progress(slot, done, total)`` (or ``(slot, done, total, stage)``
        for a job that names its stages) on each yield of a job.
    on_error : callable, optional
        ``on_error(slot, exception)`` when a job raises (stale or not);
        default: a napari error notification.
    on_idle : callable, optional
        ``on_idle()`` when the last running job has finished.
    owner : QObject, optional
        The widget the callbacks belong to. When it is deleted (its viewer
        closed), running jobs are stopped and no callback is made any more.
    """

    def __init__(self, on_progress=None, on_error=None, on_idle=None, owner=None):
        self.generation = 0
        self._cancels = 0  # what makes lasting jobs stale: cancel()
        self._workers = {}
        self._pending = {}
        self._on_progress = on_progress
        self._on_error = on_error or _notify_error
        self._on_idle = on_idle
        self._owner = owner
        if owner is not None:
            workers = self._workers  # not self: the slot runs while the owner is being deleted

            def stop_all(*_):
                for worker in list(workers.values()):
                    worker.quit()

            owner.destroyed.connect(stop_all)

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
    def submit(self, slot, make_job, lasting=False):
        """Run a job in ``slot``.

        Parameters
        ----------
        slot : str
            The kind of job (one job per slot at a time).
        make_job : callable
            ``make_job()`` returns ``(generator, on_result)``,
            ``(generator, on_result, on_partial)`` or ``None`` (nothing to
            do); it is called when the slot is free. ``on_result(result)``
            (and ``on_partial(value)`` for each :class:`Partial` the job
            yields) is called only if no parameter changed and no newer
            request came for the slot since the job started.

        lasting : bool
            The result holds whatever the parameters: :meth:`bump` does not
            make it stale (a newer request for the slot and :meth:`cancel` do).

        If ``slot`` is busy, the running job is asked to stop and this
        request replaces any earlier one waiting for the slot.
        """
        if slot in self._workers:
            self._pending[slot] = (make_job, lasting)
            self._workers[slot].quit()
            return
        self._start(slot, make_job, lasting)

    def stop(self, slot):
        """Stop the job of ``slot`` (if any) and drop a request waiting for it.

        Returns
        -------
        bool
            True if a job was running there.
        """
        self._pending.pop(slot, None)
        worker = self._workers.get(slot)
        if worker is not None:
            worker.quit()
        return worker is not None

    def cancel(self):
        """Stop every job, drop waiting requests, and make results in flight stale."""
        self._pending.clear()
        self.bump()
        self._cancels += 1
        for worker in list(self._workers.values()):
            worker.quit()

    def shutdown(self, timeout_s=10.0):
        """Cancel everything and wait (processing events) for the jobs to end.

        Returns
        -------
        bool
            True if every job ended within ``timeout_s``.
        """
        from qtpy.QtCore import QCoreApplication

        self.cancel()
        deadline = time.monotonic() + timeout_s
        while self._workers and time.monotonic() < deadline:
            QCoreApplication.processEvents()
            time.sleep(0.005)
        return not self._workers

    # -- internals --------------------------------------------------------------
    def _start(self, slot, make_job, lasting=False):
        made = make_job()
        if made is None:
            self._finish(slot, None)
            return None
        generator, on_result = made[:2]
        on_partial = made[2] if len(made) > 2 else None
        generation, cancels = self.generation, self._cancels
        worker = _closing_worker(generator)
        self._workers[slot] = worker

        def current():
            fresh = cancels == self._cancels if lasting else generation == self.generation
            return fresh and slot not in self._pending and _alive(self._owner)

        def returned(result):
            if result is not _FAILED and current():
                on_result(result)

        def yielded(step):
            if not _alive(self._owner):
                return
            if isinstance(step, _Failed):
                # reported even for a superseded job: an error is never dropped
                self._on_error(slot, step.error)
                return
            if not current():
                return
            if isinstance(step, Partial):
                if on_partial is not None:
                    on_partial(step.value)
            elif self._on_progress is not None:
                self._on_progress(slot, *step)

        def errored(error):  # not expected (jobs are guarded), but never dropped
            if _alive(self._owner):
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
        if not _alive(self._owner):
            self._pending.clear()
            return
        waiting = self._pending.pop(slot, None)
        if waiting is not None:
            self._start(slot, *waiting)
        elif not self._workers and self._on_idle is not None:
            self._on_idle()


def _notify_error(slot, error):
    from napari.utils.notifications import show_error

    show_error(f"{slot} failed: {error}")
