"""The widgets' job runner in real Qt worker threads (run under xvfb-run)."""

import threading

import pytest

pytest.importorskip("napari")

from napari_lfalias._napari._jobs import JobRunner, Partial  # noqa: E402

pytestmark = pytest.mark.napari


@pytest.fixture(autouse=True)
def no_leaked_worker_threads(qtbot):
    """After each test, no worker thread of the global Qt pool is left running.

    Imported by the other napari test modules, where it is autouse too.
    """
    yield
    from qtpy.QtCore import QThreadPool

    pool = QThreadPool.globalInstance()
    assert pool.waitForDone(30000), "a worker thread outlived its test"
    assert pool.activeThreadCount() == 0


def _blocking_job(release, value, steps):
    """Yield until ``release`` is set (or the worker is asked to quit), then return ``value``."""
    while not release.wait(0.005):
        steps.append(value)
        yield (len(steps), 0)
    return value


def _wait_idle(qtbot, runner):
    qtbot.waitUntil(lambda: not runner.busy(), timeout=5000)


def test_result_arrives_and_progress_is_reported(qtbot):
    progress = []
    runner = JobRunner(on_progress=lambda slot, done, total: progress.append((slot, done, total)))
    results = []

    def job():
        yield (1, 2)
        yield (2, 2)
        return 42

    runner.submit("a", lambda: (job(), results.append))
    _wait_idle(qtbot, runner)
    assert results == [42]
    assert ("a", 2, 2) in progress


def test_stale_result_is_dropped(qtbot):
    runner = JobRunner()
    release, steps, results = threading.Event(), [], []
    runner.submit("a", lambda: (_blocking_job(release, "old", steps), results.append))
    qtbot.waitUntil(lambda: len(steps) > 0, timeout=5000)
    runner.bump()  # a parameter changed while the job ran
    release.set()
    _wait_idle(qtbot, runner)
    assert results == []


def test_newer_request_replaces_running_job(qtbot):
    runner = JobRunner()
    release_old, steps_old = threading.Event(), []
    results = []
    runner.submit("a", lambda: (_blocking_job(release_old, "old", steps_old), results.append))
    qtbot.waitUntil(lambda: len(steps_old) > 0, timeout=5000)

    def new_job():
        yield (0, 1)
        return "new"

    # Two newer requests while the first runs: only the last one runs.
    made = []
    runner.submit("a", lambda: made.append("middle") or (new_job(), results.append))
    runner.submit("a", lambda: made.append("last") or (new_job(), results.append))
    _wait_idle(qtbot, runner)
    assert made == ["last"]
    assert results == ["new"]
    assert not release_old.is_set()  # the old job stopped on quit(), not by finishing


def test_cancel_stops_a_job_that_would_never_end(qtbot):
    runner = JobRunner()
    never, steps, results = threading.Event(), [], []
    runner.submit("a", lambda: (_blocking_job(never, "x", steps), results.append))
    qtbot.waitUntil(lambda: len(steps) > 0, timeout=5000)
    runner.cancel()
    _wait_idle(qtbot, runner)
    assert results == []


def test_errors_are_reported_not_raised(qtbot):
    errors = []
    runner = JobRunner(on_error=lambda slot, error: errors.append((slot, str(error))))

    def job():
        yield (0, 1)
        raise ValueError("bad slope")

    runner.submit("b", lambda: (job(), print))
    _wait_idle(qtbot, runner)
    assert errors == [("b", "bad slope")]


def test_shutdown_waits_for_threads(qtbot):
    from qtpy.QtCore import QThreadPool

    runner = JobRunner()
    never, steps = threading.Event(), []
    runner.submit("a", lambda: (_blocking_job(never, "x", steps), print))
    qtbot.waitUntil(lambda: len(steps) > 0, timeout=5000)
    assert runner.shutdown(timeout_s=5)
    assert QThreadPool.globalInstance().waitForDone(5000)
    assert QThreadPool.globalInstance().activeThreadCount() == 0


def test_partial_results_arrive_before_the_result_and_go_stale_too(qtbot):
    runner = JobRunner()
    seen = []

    def job():
        yield Partial("image")
        yield (1, 2)
        return "cv"

    runner.submit("a", lambda: (job(), lambda r: seen.append(("result", r)),
                                lambda v: seen.append(("partial", v))))
    _wait_idle(qtbot, runner)
    assert seen == [("partial", "image"), ("result", "cv")]

    release, steps, dropped = threading.Event(), [], []

    def slow():
        yield from _blocking_job(release, "x", steps)
        yield Partial("late image")
        return "late"

    runner.submit("a", lambda: (slow(), dropped.append, dropped.append))
    qtbot.waitUntil(lambda: len(steps) > 0, timeout=5000)
    runner.bump()
    release.set()
    _wait_idle(qtbot, runner)
    assert dropped == []


def test_errors_of_stale_jobs_are_still_reported(qtbot):
    errors = []
    runner = JobRunner(on_error=lambda slot, error: errors.append(str(error)))
    release, steps = threading.Event(), []

    def job():
        yield from _blocking_job(release, "x", steps)
        raise RuntimeError("out of memory while shifting")

    runner.submit("a", lambda: (job(), print))
    qtbot.waitUntil(lambda: len(steps) > 0, timeout=5000)
    runner.bump()
    release.set()
    _wait_idle(qtbot, runner)
    assert errors == ["out of memory while shifting"]
