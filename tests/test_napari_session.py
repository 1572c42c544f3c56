"""The widget's session: what it computes is the public API's, and its caches (no viewer needed)."""

import threading

import numpy as np
import pytest

import napari_lfalias as lfa
from napari_lfalias._napari._jobs import Partial
from napari_lfalias._napari._session import AliasingSession, DetectionParams, focus_range

pytestmark = pytest.mark.napari


def _textured(shape, seed=0):
    rng = np.random.default_rng(seed)
    return lfa.LightField(rng.random(shape, dtype=np.float32))


def _run(generator):
    """Drive a session job to its end (as a worker would); return its result and what it yielded."""
    steps = []
    try:
        while True:
            steps.append(next(generator))
    except StopIteration as stop:
        return stop.value, steps


def _partials(steps):
    return [step.value for step in steps if isinstance(step, Partial)]


@pytest.fixture(scope="module")
def room():
    from napari_lfalias.synthetic import brick_room

    return brick_room(n_views=4, size=96, seed=3).lightfield


def test_focus_gives_the_api_refocus_and_exact_cv(room):
    session = AliasingSession(room)
    params = DetectionParams(gamma=0.25, threshold=0.01)
    (image, detection), steps = _run(session.focus(4.0, params))
    assert not _partials(steps)  # the detector was free: image and Cv come together
    assert all(done <= total for done, total in steps)
    np.testing.assert_array_equal(image, lfa.refocus(room, 4.0))
    # every Cv is computed (skip_flat=False): equal to the API's everywhere ...
    full = lfa.detect_aliasing(room, 4.0, gamma=0.25, threshold=0.01, skip_flat=False, method="analytic")
    np.testing.assert_array_equal(detection.cv, full.cv)
    np.testing.assert_array_equal(detection.mask, full.mask)
    # ... and to the default call wherever that one evaluates, with the same mask
    default = lfa.detect_aliasing(room, 4.0, gamma=0.25, threshold=0.01, method="analytic")
    np.testing.assert_array_equal(detection.cv[default.evaluated], default.cv[default.evaluated])
    np.testing.assert_array_equal(detection.mask, default.mask)
    assert detection.mask.any() and not detection.mask.all()


def test_dark_floor_and_border_factors_are_the_cores(room):
    # a dark corner and a border where fewer views see the pixel: the core's floor and factors apply
    data = room.data.copy()
    data[:, :, :24, :24] *= 0.001
    lf = lfa.LightField(data, room.positions)
    detection, _ = _run(AliasingSession(lf).detect(2.5, DetectionParams()))
    expected = lfa.detect_aliasing(lf, 2.5, skip_flat=False, method="analytic")
    np.testing.assert_array_equal(detection.cv, expected.cv)
    np.testing.assert_array_equal(detection.cv_scale, expected.cv_scale)
    assert len(np.unique(detection.cv_scale)) > 1  # border pixels have their own factor


def test_threshold_rethresholds_the_kept_detection(room):
    session = AliasingSession(room)
    params = DetectionParams(threshold=0.02)
    detection, _ = _run(session.detect(-4.0, params))
    lower = session.detection(-4.0, DetectionParams(threshold=0.002))
    assert lower is not None and lower.cv is detection.cv  # nothing recomputed, even when lowered
    np.testing.assert_array_equal(lower.mask, detection.cv > np.float32(0.002))
    assert lower.mask.sum() > detection.mask.sum()
    # another slope, gamma or method: nothing kept
    assert session.detection(-3.0, params) is None
    assert session.detection(-4.0, DetectionParams(gamma=0.3)) is None
    assert session.detection(-4.0, DetectionParams(method="monte_carlo")) is None


def test_new_gamma_and_seed_reuse_the_shifted_views(room):
    session = AliasingSession(room)
    _run(session.detect(1.0, DetectionParams()))
    detector = session.detector
    moments = detector._moments[0]
    regamma, _ = _run(session.detect(1.0, DetectionParams(gamma=0.5)))
    assert detector._moments[0] is moments  # the same moments: no view shifted again
    np.testing.assert_array_equal(regamma.cv, lfa.detect_aliasing(room, 1.0, gamma=0.5, skip_flat=False, method="analytic").cv)

    mc = DetectionParams(method="monte_carlo", n_patterns=12, seed=4)
    first, _ = _run(session.detect(1.0, mc))
    stack = detector._stacks[0]
    reseeded, _ = _run(session.detect(1.0, DetectionParams(method="monte_carlo", n_patterns=12, seed=5)))
    assert detector._stacks[0] is stack
    expected = lfa.detect_aliasing(room, 1.0, n_patterns=12, method="monte_carlo", seed=5, skip_flat=False)
    np.testing.assert_array_equal(reseeded.cv, expected.cv)
    assert not np.array_equal(first.cv, reseeded.cv)


def test_reduce_is_the_api_reduction_with_the_sessions_detector(room):
    session = AliasingSession(room)
    params = DetectionParams(threshold=0.01, max_level=2, method="analytic")
    reduced, _ = _run(session.reduce(4.0, params))
    expected = lfa.reduce_aliasing(room, 4.0, threshold=0.01, max_level=2, seed=0, method="analytic")
    np.testing.assert_array_equal(reduced.reduction.level, expected.level)
    np.testing.assert_array_equal(reduced.reduction.image, expected.image)
    assert reduced.reduction.level.max() > 0
    assert reduced.antialiased is None and session.estimate is None  # a Cv method needs no disparity


def test_a_stopped_reduction_stops_between_stages_and_frees_the_detector(room, monkeypatch):
    from napari_lfalias import reduce as reduce_module

    fused = []
    monkeypatch.setattr(reduce_module, "fuse_gradients", lambda *a, **k: fused.append(1))
    session = AliasingSession(room)
    job = session.reduce(4.0, DetectionParams(threshold=0.01, max_level=3, method="analytic"))
    steps = []
    while len([s for s in steps if isinstance(s, tuple) and s[1] == 6]) < 2:
        steps.append(next(job))  # the core's stages: (done, 6) for max_level 3
    job.close()  # what a worker's quit() does at a yield
    assert fused == [] and not session._lock.locked()
    assert [s for s in steps if isinstance(s, tuple) and s[1] == 6] == [(1, 6), (2, 6)]


def test_a_job_waiting_for_the_detector_yields_and_refocuses_meanwhile(room):
    session = AliasingSession(room)
    _run(session.detect(0.0, DetectionParams()))  # the detector exists
    session._lock.acquire()  # as a running reduction would hold it
    try:
        job = session.focus(2.0, DetectionParams())
        steps = [next(job) for _ in range(6)]
    finally:
        session._lock.release()
    (image,) = _partials(steps)  # the refocused image came before the lock
    np.testing.assert_array_equal(image, lfa.refocus(room, 2.0))
    assert steps[-1] == (1, 2)  # still waiting, yielding: a worker can stop it here
    (again, detection), _ = _run(job)
    assert again is image
    np.testing.assert_array_equal(detection.cv, lfa.detect_aliasing(room, 2.0, skip_flat=False, method="analytic").cv)
    assert not session._lock.locked()
    # without detection (Monte Carlo asks for it in its own job): the image alone
    (image, nothing), steps = _run(session.focus(1.0, DetectionParams(), detect=False))
    assert nothing is None and not _partials(steps)
    np.testing.assert_array_equal(image, lfa.refocus(room, 1.0))


def test_jobs_in_two_threads_share_the_detector_safely(room):
    session = AliasingSession(room)
    results = {}

    def work(name, job):
        results[name] = _run(job)[0]

    threads = [
        threading.Thread(target=work, args=("reduce", session.reduce(4.0, DetectionParams(threshold=0.01,
                                                                                         method="analytic")))),
        threading.Thread(target=work, args=("detect", session.detect(-1.5, DetectionParams()))),
    ]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(60)
    np.testing.assert_array_equal(results["detect"].cv, lfa.detect_aliasing(room, -1.5, skip_flat=False, method="analytic").cv)
    np.testing.assert_array_equal(results["reduce"].reduction.image,
                                  lfa.reduce_aliasing(room, 4.0, threshold=0.01, seed=0, method="analytic").image)


def test_focus_range_from_metadata_or_the_data_geometry(room):
    assert focus_range(room) == pytest.approx((-4.0, 4.0))  # the brick room's disparity range
    lf = _textured((3, 3, 16, 16, 1))
    assert focus_range(lf) == (-2.0, 2.0)  # capped at 2 px per view step
    guv_like = _textured((15, 15, 28, 28, 1))
    assert focus_range(guv_like) == (-1.0, 1.0)  # the outermost view moves a quarter of 28 px
    with_map = lfa.LightField(lf.data, meta={"disparity": np.array([[-1.0, 0.5]])})
    assert focus_range(with_map) == pytest.approx((-1.15, 0.65))


def test_previews_go_one_level_coarser_while_they_are_slow(monkeypatch):
    from napari_lfalias._napari import _session

    lf = _textured((8, 8, 384, 384, 1), seed=4)
    session = AliasingSession(lf)
    assert session.previews() and session.preview_level() == 2  # 9.4 M samples: 1.5 M at most
    params = DetectionParams()
    monkeypatch.setattr(_session, "PREVIEW_BUDGET_S", 0.0)  # every preview is too slow
    levels = []
    for slope in (0.25, 0.5, 0.625, 0.75):  # the first makes the level's caches; then two in a row
        _, steps = _run(session.focus(slope, params))
        levels.append(_partials(steps)[0].level)
    assert levels == [2, 2, 2, 3] and session.preview_level() == 3
    _, steps = _run(session.focus(0.75, params))
    (second,) = _partials(steps)
    assert second.level == 3 and second.image.shape == (384, 384, 1)
    # the coarser preview is that level's exact refocus and Cv, each pixel a 8 x 8 block
    from napari_lfalias.pyramid import lightfield_pyramid

    level3 = lightfield_pyramid(lf, 3)[3]
    np.testing.assert_array_equal(second.image[::8, ::8], lfa.refocus(level3, 0.75 / 8))
    np.testing.assert_array_equal(second.cv[::8, ::8],
                                  lfa.detect_aliasing(lf, 0.75, level=3, skip_flat=False, method="analytic").cv)
    monkeypatch.setattr(_session, "PREVIEW_BUDGET_S", 1e6)  # quick again: back to the finer level
    for slope in (1.0, 1.25):
        _run(session.focus(slope, params))
    assert session.preview_level() == 2


# -- the disparity-guided method ---------------------------------------------------------------


def _never_estimated_again(monkeypatch):
    """Make any further ``estimate_disparity`` call fail: what was handed over must be used."""
    from napari_lfalias import disparity as disparity_module

    def estimate_again(*args, **kwargs):
        raise AssertionError("the disparity was estimated again instead of the one handed over")

    monkeypatch.setattr(disparity_module, "estimate_disparity", estimate_again)


def test_the_disparity_job_reports_stages_and_gives_the_apis_estimate(room, monkeypatch):
    session = AliasingSession(room)
    estimate, steps = _run(session.disparity())
    stages = [step[2] for step in steps if len(step) == 3 and step[0] > 0]
    assert stages[:5] == ["inputs", "coarse sweep", "sweep", "aggregation", "fill"]
    assert all(done <= total == 5 for done, total, _ in steps)
    expected = lfa.estimate_disparity(room)
    np.testing.assert_array_equal(estimate.disparity, expected.disparity)
    np.testing.assert_array_equal(estimate.confidence, expected.confidence)
    # handed to the detector: its guide renders with this estimate, none of its own
    assert session.estimate is estimate
    _never_estimated_again(monkeypatch)
    np.testing.assert_array_equal(session.detector.guide.estimate[0], estimate.disparity)
    again, steps = _run(session.disparity())  # kept: no stage runs again
    assert again is estimate and not [step for step in steps if len(step) == 3 and step[0] > 0]


def test_a_stopped_disparity_job_stops_between_stages(room, monkeypatch):
    from napari_lfalias import disparity as disparity_module

    ran = []
    real = disparity_module._aggregate

    def counted(*args, **kwargs):
        ran.append("aggregation")
        return real(*args, **kwargs)

    monkeypatch.setattr(disparity_module, "_aggregate", counted)
    session = AliasingSession(room)
    job = session.disparity()
    step = next(job)
    while not (len(step) == 3 and step[2] == "coarse sweep"):
        step = next(job)
    job.close()  # what a worker's quit() does at a yield
    assert ran == [] and session.estimate is None and not session._lock.locked()
    estimate, _ = _run(session.disparity())  # a new job estimates it from the start
    assert ran == ["aggregation"] and session.estimate is estimate


def test_a_depth_reduction_is_the_apis_with_the_sessions_disparity(room):
    session = AliasingSession(room)
    params = DetectionParams(method="depth", threshold=0.02)
    reduced, steps = _run(session.reduce(4.0, params))  # no disparity yet: estimated first, with stages
    progress = [step for step in steps if isinstance(step, tuple)]
    assert [step[2] for step in progress if len(step) == 3] == ["inputs", "coarse sweep", "sweep", "aggregation",
                                                                "fill"]
    # the reduction's stages count one more, the anti-aliased rendering, which comes after the reduction
    assert [step for step in progress if len(step) == 2][-1] == (4, 5)
    (first,) = _partials(steps)
    assert first.reduction is reduced.reduction and first.antialiased is None
    assert isinstance(steps[-1], Partial)
    estimate = lfa.estimate_disparity(room)
    np.testing.assert_array_equal(session.estimate.disparity, estimate.disparity)
    expected = lfa.reduce_aliasing(room, 4.0, disparity=estimate)
    np.testing.assert_array_equal(reduced.reduction.image, expected.image)
    np.testing.assert_array_equal(reduced.reduction.level, expected.level)
    np.testing.assert_array_equal(reduced.antialiased, lfa.antialiased_refocus(room, 4.0, estimate))
    assert 0 < expected.level.astype(bool).mean() < 1
    # the live Cv is unchanged by the method: the exact one
    detection, _ = _run(session.detect(4.0, params))
    np.testing.assert_array_equal(detection.cv, lfa.detect_aliasing(room, 4.0, skip_flat=False,
                                                                    method="analytic").cv)
