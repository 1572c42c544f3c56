"""The aliasing widget in a real napari viewer (run under xvfb-run).

Small light fields (5x5 views of 64x64 of the brick room) keep these quick; the arrays the
widget puts in its layers are compared with the public API's.
"""

import numpy as np
import pytest

pytest.importorskip("napari")

import napari_lfalias as lfa  # noqa: E402
from napari_lfalias._napari._layers import (  # noqa: E402
    find_output_layer,
    lightfield_layer_data,
)
from napari_lfalias._napari._widget import AliasingWidget  # noqa: E402

pytestmark = pytest.mark.napari

from test_napari_jobs import no_leaked_worker_threads  # noqa: E402,F401  (autouse: no thread outlives a test)

TIMEOUT_MS = 20000


def _scene(n_views=5, size=64, seed=0):
    """The synthetic brick room (the paper's Figure 6): a brick wall at disparity -4, a cube at +4.

    Its ground-truth disparity map is in the metadata; between the two
    planes both alias, so masks are neither empty nor full.
    """
    from napari_lfalias.synthetic import brick_room

    return brick_room(n_views=n_views, size=size, seed=seed).lightfield


def _add(viewer, lf, name="lf"):
    data, kwargs, _ = lightfield_layer_data(lf, name)
    return viewer.add_image(data, **kwargs)


#: Widgets of the running test (so a wait can fail fast on a job's error).
_OPEN_WIDGETS = []


@pytest.fixture(autouse=True)
def _forget_widgets():
    yield
    _OPEN_WIDGETS.clear()  # no reference may keep a closed viewer alive


def _open_widget(viewer, qtbot):
    widget = AliasingWidget(viewer)
    viewer.window.add_dock_widget(widget, name="aliasing")
    _OPEN_WIDGETS[:] = [w for w in _OPEN_WIDGETS if w.viewer is viewer] + [widget]
    return widget


def _params(viewer, role):
    layer = find_output_layer(viewer, role)
    return None if layer is None else layer.metadata.get("lfalias_params")


def _wait_for(qtbot, viewer, role, **expected):
    """Wait for the output layer of ``role`` computed with ``expected`` parameters.

    Fails at once if a widget job reported an error instead.
    """
    widgets = [w for w in _OPEN_WIDGETS if w.viewer is viewer]

    def done():
        for widget in widgets:
            if "failed" in widget.status.text():
                pytest.fail(widget.status.text(), pytrace=False)
        params = _params(viewer, role)
        return params is not None and all(params.get(k) == v for k, v in expected.items())

    qtbot.waitUntil(done, timeout=TIMEOUT_MS)
    return find_output_layer(viewer, role)


def _idle(qtbot, widget):
    qtbot.waitUntil(lambda: not widget.jobs.busy(), timeout=TIMEOUT_MS)


def _scene_viewer(make_napari_viewer, qtbot, show):
    viewer = make_napari_viewer(show=show)
    lf = _scene()
    _add(viewer, lf)
    widget = _open_widget(viewer, qtbot)
    yield viewer, widget, lf
    assert widget.shutdown()


@pytest.fixture
def scene_viewer(make_napari_viewer, qtbot):
    yield from _scene_viewer(make_napari_viewer, qtbot, show=False)


@pytest.fixture
def shown_scene_viewer(make_napari_viewer, qtbot):
    """The scene in a viewer shown on screen (the canvas draws each update, as for a user)."""
    yield from _scene_viewer(make_napari_viewer, qtbot, show=True)


def test_focus_range_comes_from_the_ground_truth_disparity(scene_viewer):
    viewer, widget, lf = scene_viewer
    disparity = np.asarray(lf.meta.get("disparity", lf.meta.get("gt_disparity")))
    low, high = widget.focus_slider.minimum(), widget.focus_slider.maximum()
    assert low <= disparity.min() and high >= disparity.max()
    assert high - low < 4 * (disparity.max() - disparity.min()) + 1


def test_focus_change_gives_the_api_refocus_and_exact_cv(scene_viewer, qtbot):
    viewer, widget, lf = scene_viewer
    widget.focus_slider.setValue(0.75)
    slope = widget.slope
    refocused = _wait_for(qtbot, viewer, "refocus", slope=slope)
    cv = _wait_for(qtbot, viewer, "cv", slope=slope)
    mask = _wait_for(qtbot, viewer, "mask", slope=slope)
    np.testing.assert_array_equal(refocused.data, lfa.refocus(lf, slope))
    detection = lfa.detect_aliasing(lf, slope, gamma=0.2, threshold=widget.params().threshold,
                                    method="analytic", skip_flat=False)
    np.testing.assert_array_equal(cv.data, detection.cv)
    assert mask._type_string == "labels"
    np.testing.assert_array_equal(mask.data.astype(bool), detection.mask)
    assert 0 < detection.mask.mean() < 1  # the mask is not trivially empty or full
    # outputs are updated in place: one layer per role (and the disparity, once it is estimated)
    _idle(qtbot, widget)
    roles = [layer.metadata.get("lfalias") for layer in viewer.layers if layer.metadata.get("lfalias")]
    assert sorted(roles) == ["cv", "disparity", "mask", "refocus"]


def test_a_drag_of_the_focus_ends_on_its_last_slope(scene_viewer, qtbot):
    viewer, widget, lf = scene_viewer
    shown = []
    widget.outputs_updated.connect(lambda role, params: shown.append((role, params.get("slope"))))
    for value in np.linspace(-0.9, 1.3, 12):  # faster than the worker can follow
        widget.focus_slider.setValue(float(value))
    slope = widget.slope
    refocused = _wait_for(qtbot, viewer, "refocus", slope=slope)
    _wait_for(qtbot, viewer, "cv", slope=slope)
    _idle(qtbot, widget)
    np.testing.assert_array_equal(refocused.data, lfa.refocus(lf, slope))
    # superseded slopes were dropped, not all queued up and shown in turn
    assert len({s for role, s in shown if role == "refocus"}) < 12
    assert [s for role, s in shown if role != "disparity"][-1] == slope


def test_threshold_rethresholds_without_recomputing(scene_viewer, qtbot):
    viewer, widget, lf = scene_viewer
    slope = widget.slope
    cv_layer = _wait_for(qtbot, viewer, "cv", slope=slope)
    _idle(qtbot, widget)
    cv_values = cv_layer.data.copy()
    new_threshold = 0.005 if widget.params().threshold > 0.01 else 0.05
    widget.threshold_slider.setValue(new_threshold)
    threshold = widget.params().threshold
    mask = find_output_layer(viewer, "mask")
    # synchronous: no worker was started, the mask changed at once, Cv was kept
    assert not widget.jobs.busy()
    assert mask.metadata["lfalias_params"]["threshold"] == threshold
    np.testing.assert_array_equal(mask.data.astype(bool), cv_values > threshold)
    np.testing.assert_array_equal(find_output_layer(viewer, "cv").data, cv_values)
    assert cv_layer.metadata["lfalias_params"]["threshold"] == threshold


def test_monte_carlo_matches_the_api_with_the_same_seed(scene_viewer, qtbot):
    viewer, widget, lf = scene_viewer
    widget.n_spin.setValue(20)
    widget.seed_spin.setValue(7)
    widget.set_method("monte_carlo")
    slope = widget.slope
    cv = _wait_for(qtbot, viewer, "cv", slope=slope, method="monte_carlo", n_patterns=20, seed=7)
    expected = lfa.detect_aliasing(lf, slope, gamma=0.2, n_patterns=20, method="monte_carlo",
                                   seed=7, threshold=widget.params().threshold, skip_flat=False)
    np.testing.assert_array_equal(cv.data, expected.cv)


def test_gamma_change_reuses_the_shifted_stack(scene_viewer, qtbot):
    viewer, widget, lf = scene_viewer
    widget.set_method("monte_carlo")
    widget.n_spin.setValue(10)
    slope = widget.slope
    _wait_for(qtbot, viewer, "cv", slope=slope, method="monte_carlo", n_patterns=10)
    _idle(qtbot, widget)
    stack = widget.session.detector._stacks[0]  # the views shifted for this slope
    widget.gamma_spin.setValue(0.4)
    cv = _wait_for(qtbot, viewer, "cv", slope=slope, gamma=0.4, n_patterns=10)
    assert widget.session.detector._stacks[0] is stack
    expected = lfa.detect_aliasing(lf, slope, gamma=0.4, n_patterns=10, method="monte_carlo",
                                   seed=0, threshold=widget.params().threshold, skip_flat=False)
    np.testing.assert_array_equal(cv.data, expected.cv)


def test_gamma_change_with_the_exact_method_reuses_the_moments(scene_viewer, qtbot):
    viewer, widget, lf = scene_viewer
    slope = widget.slope
    _wait_for(qtbot, viewer, "cv", slope=slope, gamma=0.2)
    _idle(qtbot, widget)
    kept = widget.session.detector._moments[0]
    widget.gamma_spin.setValue(0.4)
    cv = _wait_for(qtbot, viewer, "cv", slope=slope, gamma=0.4)
    assert widget.session.detector._moments[0] is kept  # no view was shifted again
    expected = lfa.detect_aliasing(lf, slope, gamma=0.4, method="analytic",
                                   threshold=widget.params().threshold, skip_flat=False)
    np.testing.assert_array_equal(cv.data, expected.cv)


def test_reduction_runs_in_a_worker_while_events_are_processed(make_napari_viewer, qtbot, monkeypatch):
    """The reduction's fusion waits for three ticks of a GUI-thread timer while the job is busy.

    It can only finish if the GUI thread processes events while the worker
    reduces, however fast the reduction itself is.
    """
    import threading

    from qtpy.QtCore import QTimer

    from napari_lfalias import reduce as reduce_module

    gate = threading.Event()
    fuse = reduce_module.fuse_gradients

    def gated_fuse(*args, **kwargs):
        assert gate.wait(30), "the GUI thread processed no events while the reduction worked"
        return fuse(*args, **kwargs)

    monkeypatch.setattr(reduce_module, "fuse_gradients", gated_fuse)
    viewer = make_napari_viewer()
    lf = _scene(n_views=5, size=128)
    _add(viewer, lf)
    widget = _open_widget(viewer, qtbot)
    widget.set_method("analytic")  # Algorithm 2, whose fusion is gated
    _wait_for(qtbot, viewer, "cv", slope=widget.slope)
    _idle(qtbot, widget)

    ticks_while_busy = []

    def tick():
        ticks_while_busy.append(widget.jobs.busy("reduce"))
        if sum(ticks_while_busy) >= 3:
            gate.set()

    timer = QTimer()
    timer.setInterval(5)
    timer.timeout.connect(tick)
    timer.start()
    widget.reduce()
    assert widget.jobs.busy("reduce")
    fused = _wait_for(qtbot, viewer, "fused", slope=widget.slope)
    timer.stop()
    assert gate.is_set() and sum(ticks_while_busy) >= 3  # the GUI thread ticked while the worker reduced

    expected = lfa.reduce_aliasing(lf, widget.slope, **widget.params().reduce_kwargs())
    np.testing.assert_array_equal(fused.data, expected.image)
    level = find_output_layer(viewer, "level")
    np.testing.assert_array_equal(level.data, expected.level)
    assert level._type_string == "labels" and expected.level.max() > 0
    assert widget.shutdown()


def test_monte_carlo_at_the_default_controls_reduces_as_the_paper(scene_viewer, qtbot):
    viewer, widget, lf = scene_viewer
    widget.set_method("monte_carlo")
    widget.focus_slider.setValue(4.0)
    _idle(qtbot, widget)
    widget.reduce()
    fused = _wait_for(qtbot, viewer, "fused", slope=4.0, method="monte_carlo")
    _idle(qtbot, widget)
    paper = lfa.reduce_aliasing(lf, 4.0, preset="paper", seed=widget.params().seed)
    np.testing.assert_array_equal(fused.data, paper.image)
    screened = lfa.reduce_aliasing(lf, 4.0, method="monte_carlo", seed=widget.params().seed)
    assert not np.array_equal(fused.data, screened.image)  # the project's screened fusion differs


def test_keep_in_focus_box_gives_the_api_reduction(scene_viewer, qtbot):
    viewer, widget, lf = scene_viewer
    widget.set_method("analytic")  # the box belongs to Algorithm 2
    widget.focus_slider.setValue(-4.0)  # on the wall, behind the defocused cube
    widget.threshold_slider.setValue(0.005)
    widget.keep_check.setChecked(True)
    _idle(qtbot, widget)
    widget.reduce()
    fused = _wait_for(qtbot, viewer, "fused", slope=widget.slope)
    params = widget.params()
    assert params.keep_in_focus and params.threshold == pytest.approx(0.005, rel=0.02)
    expected = lfa.reduce_aliasing(lf, widget.slope, **params.reduce_kwargs())
    assert params.reduce_kwargs()["keep_in_focus"] is True
    np.testing.assert_array_equal(fused.data, expected.image)
    paper = lfa.reduce_aliasing(lf, widget.slope, max_level=params.max_level, **params.detect_kwargs())
    assert not np.allclose(fused.data, paper.image, atol=1e-3)


def test_stale_reduction_is_dropped_and_cancel_stops(scene_viewer, qtbot):
    viewer, widget, lf = scene_viewer
    _idle(qtbot, widget)
    widget.reduce()
    widget.focus_slider.setValue(widget.slope + 0.5)  # the running reduction is now stale
    _wait_for(qtbot, viewer, "refocus", slope=widget.slope)
    _idle(qtbot, widget)
    assert find_output_layer(viewer, "fused") is None
    widget.reduce()
    widget.cancel()
    _idle(qtbot, widget)
    assert find_output_layer(viewer, "fused") is None
    assert widget.status.text() == "cancelled"


def test_layer_chooser_follows_the_viewer(make_napari_viewer, qtbot):
    viewer = make_napari_viewer()
    widget = _open_widget(viewer, qtbot)
    assert widget.session is None and widget.layer_combo.count() == 0
    viewer.add_image(np.zeros((8, 8)), name="plain image")  # not a light field
    assert widget.layer_combo.count() == 0
    lf = lfa.LightField(np.random.default_rng(0).random((3, 3, 16, 16, 1), dtype=np.float32))
    _add(viewer, lf, name="small")
    assert widget.layer_combo.currentText() == "small"
    # the first job of a layer says what it does, with a busy bar (not "100 %")
    assert "preparing it" in widget.status.text() and widget.progress.maximum() == 0
    # no disparities in the metadata: the default +/-2 px range
    assert (widget.focus_slider.minimum(), widget.focus_slider.maximum()) == (-2.0, 2.0)
    refocused = _wait_for(qtbot, viewer, "refocus", slope=widget.slope)
    np.testing.assert_array_equal(refocused.data, lfa.refocus(lf, widget.slope)[..., 0])
    _idle(qtbot, widget)
    viewer.layers.remove("small")
    assert widget.layer_combo.count() == 0 and widget.session is None
    assert widget.shutdown()


def _magenta_share(image):
    """Share of pixels where the aliasing mask's magenta shows (red and blue well above green)."""
    rgb = image[..., :3].astype(int)
    return float(np.mean((rgb[..., 0] - rgb[..., 1] > 60) & (rgb[..., 2] - rgb[..., 1] > 60)))


def test_default_layout_shows_refocus_mask_and_the_reduced_image_beside_it(make_napari_viewer, qtbot):
    viewer = make_napari_viewer(show=True)
    lf = _scene(n_views=5, size=96)
    _add(viewer, lf, name="room")
    widget = _open_widget(viewer, qtbot)
    widget.focus_slider.setValue(4.0)  # on the cube: the wall behind it aliases
    _wait_for(qtbot, viewer, "mask", slope=widget.slope)
    _idle(qtbot, widget)
    widget.reduce()
    fused = _wait_for(qtbot, viewer, "fused", slope=widget.slope)
    _idle(qtbot, widget)
    refocused, cv, mask = (find_output_layer(viewer, role) for role in ("refocus", "cv", "mask"))
    level = find_output_layer(viewer, "level")
    # the rules: refocus and mask shown, the mask translucent over it; Cv and level map hidden;
    # the reduced image beside the refocused one, a gap apart
    assert refocused.visible and mask.visible and fused.visible
    assert not cv.visible and not level.visible and not viewer.layers["room"].visible
    assert 0 < mask.opacity < 1
    assert fused.translate[-1] > 96 and refocused.translate[-1] == 0
    assert cv.colorbar.visible and cv.colormap.name == "magma"
    assert widget.legend.isVisible() and "level map" in widget.legend.text()
    qtbot.wait(100)
    shot = viewer.screenshot(canvas_only=True, flash=False)
    assert shot[..., :3].std() > 20  # not blank, not one flat colour
    columns = np.flatnonzero(shot[..., :3].max(axis=(0, 2)) > 30)  # where the two panels are drawn
    middle = (columns[0] + columns[-1]) // 2
    left, right = shot[:, columns[0]:middle], shot[:, middle:columns[-1]]
    assert left[..., :3].std() > 20 and right[..., :3].std() > 20  # both panels show an image
    assert _magenta_share(left) > 0.05 > _magenta_share(right)  # the mask marks the refocus only
    # the Cv, once shown, covers the refocus opaquely with its own colours and a colorbar
    cv.visible = True
    qtbot.wait(100)
    with_cv = viewer.screenshot(canvas_only=True, flash=False)
    assert with_cv.shape == shot.shape
    assert np.abs(with_cv[:, columns[0]:middle].astype(int) - left.astype(int)).mean() > 5
    assert widget.shutdown()


def test_cv_contrast_follows_the_data_until_the_user_sets_it(scene_viewer, qtbot):
    viewer, widget, lf = scene_viewer
    cv = _wait_for(qtbot, viewer, "cv", slope=widget.slope)
    _idle(qtbot, widget)
    threshold = widget.params().threshold
    top = max(2 * threshold, float(np.percentile(cv.data, 99.5)))
    assert cv.contrast_limits == pytest.approx([0.0, top], rel=1e-4)
    widget.focus_slider.setValue(-4.0)
    cv = _wait_for(qtbot, viewer, "cv", slope=-4.0)
    _idle(qtbot, widget)
    assert cv.contrast_limits[1] == pytest.approx(max(2 * threshold, float(np.percentile(cv.data, 99.5))), rel=1e-4)
    cv.contrast_limits = [0.0, 0.5]  # the user's own choice stays
    widget.focus_slider.setValue(1.0)
    _wait_for(qtbot, viewer, "cv", slope=1.0)
    _idle(qtbot, widget)
    assert cv.contrast_limits == [0.0, 0.5]


def test_no_worker_threads_outlive_the_widget(make_napari_viewer, qtbot):
    from qtpy.QtCore import QThreadPool

    viewer = make_napari_viewer()
    _add(viewer, _scene())
    widget = _open_widget(viewer, qtbot)
    widget.set_method("monte_carlo")
    widget.reduce()
    assert widget.jobs.busy()
    assert widget.shutdown()
    assert QThreadPool.globalInstance().waitForDone(TIMEOUT_MS)
    assert QThreadPool.globalInstance().activeThreadCount() == 0


def test_lazy_lightfield_is_read_in_the_worker(make_napari_viewer, qtbot, tmp_path):
    from napari_lfalias.io_write import write_lightfield

    lf = _scene(n_views=3, size=32)
    path = write_lightfield(tmp_path / "scene.zarr", lf)
    viewer = make_napari_viewer()
    layer = viewer.open(path, plugin="napari-lfalias")[0]
    assert layer.metadata["lightfield"].is_lazy
    widget = _open_widget(viewer, qtbot)
    # the layer's light field stays lazy: the session reads its own copy, in the worker
    assert widget.session.source_lf is layer.metadata["lightfield"]
    refocused = _wait_for(qtbot, viewer, "refocus", slope=widget.slope)
    np.testing.assert_array_equal(refocused.data, lfa.refocus(lf, widget.slope))
    assert layer.metadata["lightfield"].is_lazy
    assert widget.shutdown()


def test_threshold_slider_is_logarithmic(qtbot):
    from napari_lfalias._napari._controls import LogSlider

    slider = LogSlider(1e-4, 1.0, 0.02, steps=400)
    qtbot.addWidget(slider)
    assert slider.value() == 0.02  # set values are kept exactly
    seen = []
    slider.valueChanged.connect(seen.append)
    for position, expected in ((0, 1e-4), (100, 1e-3), (200, 1e-2), (400, 1.0)):
        slider.slider.setValue(position)
        assert slider.value() == pytest.approx(expected, rel=1e-3)
    assert seen == pytest.approx([1e-4, 1e-3, 1e-2, 1.0], rel=1e-3)
    assert slider.spin.value() == 1.0


def test_a_failing_job_is_shown_to_the_user(scene_viewer, qtbot, monkeypatch):
    from napari.utils.notifications import notification_manager

    from napari_lfalias.errors import ParameterError
    from napari_lfalias._napari._session import AliasingSession

    viewer, widget, lf = scene_viewer
    _idle(qtbot, widget)

    def failing_reduce(self, slope, params):
        yield (0, 1)
        raise ParameterError("max_level: the light field is too small for 9 levels")

    monkeypatch.setattr(AliasingSession, "reduce", failing_reduce)
    before = len(notification_manager.records)
    widget.reduce()
    _idle(qtbot, widget)
    assert widget.status.text() == "reduce failed: coarsest level: the light field is too small for 9 levels"
    messages = [str(record.message) for record in notification_manager.records[before:]]
    assert any("too small for 9 levels" in message for message in messages)
    assert find_output_layer(viewer, "fused") is None
    assert not widget.cancel_button.isEnabled()  # idle again: the slot was freed


def test_monte_carlo_reports_progress_and_the_detect_button_works_when_not_live(scene_viewer, qtbot):
    viewer, widget, lf = scene_viewer
    _idle(qtbot, widget)
    widget.live_check.setChecked(False)
    widget.set_method("monte_carlo")
    widget.n_spin.setValue(16)
    widget.focus_slider.setValue(-2.0)
    qtbot.wait(50)
    assert not widget.jobs.busy()  # not live: nothing computed
    assert _params(viewer, "cv")["slope"] != -2.0
    progress = []
    widget.progress.valueChanged.connect(progress.append)
    widget.update_button.click()
    cv = _wait_for(qtbot, viewer, "cv", slope=-2.0, method="monte_carlo", n_patterns=16)
    _idle(qtbot, widget)
    assert progress[0] == 0 and progress[-1] == 100 and len(set(progress)) >= 2
    expected = lfa.detect_aliasing(lf, -2.0, n_patterns=16, method="monte_carlo", seed=0,
                                   threshold=widget.params().threshold, skip_flat=False)
    np.testing.assert_array_equal(cv.data, expected.cv)


def test_focus_stays_live_while_the_detector_is_busy(scene_viewer, qtbot):
    viewer, widget, lf = scene_viewer
    _wait_for(qtbot, viewer, "cv", slope=widget.slope)
    _idle(qtbot, widget)
    old = widget.slope
    widget.session._lock.acquire()  # as a long reduction holds it
    try:
        widget.focus_slider.setValue(old + 1.5)
        slope = widget.slope
        refocused = _wait_for(qtbot, viewer, "refocus", slope=slope)  # shown without the detector
        np.testing.assert_array_equal(refocused.data, lfa.refocus(lf, slope))
        qtbot.wait(100)
        assert _params(viewer, "cv")["slope"] == old  # the Cv waits for the detector
        assert widget.jobs.busy("focus")
    finally:
        widget.session._lock.release()
    cv = _wait_for(qtbot, viewer, "cv", slope=slope)
    np.testing.assert_array_equal(cv.data, lfa.detect_aliasing(lf, slope, skip_flat=False, method="analytic").cv)


# -- no deadlock: a stopped job gives the detector back ----------------------------------------


@pytest.fixture
def gated_levels(monkeypatch):
    """Detections of pyramid levels >= 1 (the reduction's second stage on) wait for ``gate``.

    So a reduction is certainly running, between two of its stages, when
    the test cancels it; the event ``entered`` is set when one waits.
    """
    import threading

    from napari_lfalias.detect import AliasingDetector

    gate, entered = threading.Event(), threading.Event()
    detect = AliasingDetector.detect

    def gated(self, slope, *args, level=0, **kwargs):
        if level >= 1:
            entered.set()
            assert gate.wait(30), "the test never opened the gate"
        return detect(self, slope, *args, level=level, **kwargs)

    monkeypatch.setattr(AliasingDetector, "detect", gated)
    yield gate, entered
    gate.set()


def _start_gated_reduction(qtbot, widget, entered):
    widget.set_method("analytic")  # Algorithm 2: its second stage detects on level 1
    _idle(qtbot, widget)
    entered.clear()
    widget.reduce()
    qtbot.waitUntil(entered.is_set, timeout=TIMEOUT_MS)  # inside its second stage


def test_cancel_during_a_reduction_then_a_focus_change_updates_the_cv(shown_scene_viewer, qtbot, gated_levels):
    viewer, widget, lf = shown_scene_viewer
    gate, entered = gated_levels
    _wait_for(qtbot, viewer, "cv", slope=widget.slope)
    _start_gated_reduction(qtbot, widget, entered)
    widget.cancel()
    gate.set()  # the stage ends; the job stops at its next step and gives the detector back
    _idle(qtbot, widget)
    assert not widget.session._lock.locked()
    assert not widget.cancel_button.isEnabled()
    widget.focus_slider.setValue(1.25)
    slope = widget.slope
    cv = _wait_for(qtbot, viewer, "cv", slope=slope)
    np.testing.assert_array_equal(cv.data, lfa.detect_aliasing(lf, slope, skip_flat=False, method="analytic").cv)
    assert find_output_layer(viewer, "fused") is None
    # Monte Carlo after the cancel runs to its end too (it waited on the lock before)
    widget.n_spin.setValue(12)
    widget.set_method("monte_carlo")
    cv = _wait_for(qtbot, viewer, "cv", slope=slope, method="monte_carlo", n_patterns=12)
    _idle(qtbot, widget)
    assert widget.progress.value() == 100
    expected = lfa.detect_aliasing(lf, slope, n_patterns=12, method="monte_carlo", seed=0, skip_flat=False)
    np.testing.assert_array_equal(cv.data, expected.cv)


def test_a_second_reduce_click_stops_the_first_and_finishes(shown_scene_viewer, qtbot, gated_levels):
    viewer, widget, lf = shown_scene_viewer
    gate, entered = gated_levels
    _start_gated_reduction(qtbot, widget, entered)
    widget.reduce()  # the second click while the first reduction runs
    assert "stopped" in widget.status.text()
    gate.set()
    fused = _wait_for(qtbot, viewer, "fused", slope=widget.slope)
    _idle(qtbot, widget)
    expected = lfa.reduce_aliasing(lf, widget.slope, **widget.params().reduce_kwargs())
    np.testing.assert_array_equal(fused.data, expected.image)
    assert not widget.session._lock.locked() and not widget.cancel_button.isEnabled()
    assert [layer.metadata.get("lfalias") for layer in viewer.layers].count("fused") == 1


def test_a_reduction_stopped_by_a_focus_change_says_so(shown_scene_viewer, qtbot, gated_levels):
    from napari.utils.notifications import notification_manager

    viewer, widget, lf = shown_scene_viewer
    gate, entered = gated_levels
    _start_gated_reduction(qtbot, widget, entered)
    before = len(notification_manager.records)
    widget.focus_slider.setValue(-2.0)
    assert widget.status.text().startswith("reduction stopped: the focus moved to -2.00")
    messages = [str(record.message) for record in notification_manager.records[before:]]
    assert any(message.startswith("reduction stopped") for message in messages)
    gate.set()
    _wait_for(qtbot, viewer, "cv", slope=-2.0)
    _idle(qtbot, widget)
    assert find_output_layer(viewer, "fused") is None and not widget.session._lock.locked()


def test_closing_the_viewer_during_a_reduction_ends_cleanly(make_napari_viewer, qtbot, gated_levels):
    import warnings

    from qtpy.QtCore import QThreadPool

    gate, entered = gated_levels
    viewer = make_napari_viewer(show=True)
    _add(viewer, _scene())
    widget = _open_widget(viewer, qtbot)
    _wait_for(qtbot, viewer, "cv", slope=widget.slope)
    session = widget.session
    with qtbot.capture_exceptions() as exceptions, warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        _start_gated_reduction(qtbot, widget, entered)
        viewer.close()  # the widget is deleted with its window while the job runs
        gate.set()
        assert QThreadPool.globalInstance().waitForDone(TIMEOUT_MS)
        qtbot.wait(100)  # the worker's last signals reach the GUI thread (and nobody)
    assert exceptions == []
    assert not [w for w in caught if "deleted" in str(w.message) or "aborted thread" in str(w.message)]
    assert not session._lock.locked()  # the stopped job was closed: it holds nothing


CLOSE_SCRIPT = """
import napari
from qtpy.QtCore import QTimer
from napari_lfalias._napari._layers import lightfield_layer_data
from napari_lfalias._napari._widget import AliasingWidget
from napari_lfalias.synthetic import brick_room

viewer = napari.Viewer(show=True)
data, kwargs, _ = lightfield_layer_data(brick_room(n_views=8, size=256, seed=0).lightfield, "room")
viewer.add_image(data, **kwargs)
widget = AliasingWidget(viewer)
viewer.window.add_dock_widget(widget)

def start():
    widget.set_method("monte_carlo")
    widget.reduce()
    QTimer.singleShot(60, viewer.close)  # while the reduction runs

QTimer.singleShot(300, start)
napari.run()
print("event loop ended", flush=True)
"""


def test_closing_the_napari_window_mid_job_exits_the_process_cleanly(tmp_path):
    """The whole application, as a user runs it: close the window during a reduction, then exit."""
    import os
    import subprocess
    import sys

    script = tmp_path / "close_mid_job.py"
    script.write_text(CLOSE_SCRIPT)
    run = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300,
                         env={**os.environ, "PYTHONFAULTHANDLER": "1"})
    output = run.stdout + run.stderr
    assert run.returncode == 0, output
    assert "event loop ended" in run.stdout
    for sign in ("Traceback", "has been deleted", "Fatal", "Aborted"):
        assert sign not in output, output


# -- controls that explain themselves ---------------------------------------------------------


def test_every_control_explains_itself_in_gui_words(scene_viewer):
    from qtpy.QtWidgets import QFormLayout

    viewer, widget, lf = scene_viewer
    form = widget.layout().itemAt(0).layout()
    assert isinstance(form, QFormLayout)
    labels = []
    for row in range(form.rowCount()):
        field = form.itemAt(row, QFormLayout.ItemRole.FieldRole).widget()
        label = form.itemAt(row, QFormLayout.ItemRole.LabelRole)
        if label is not None and label.widget() is not None and label.widget().text():
            labels.append(label.widget().text())
        assert field.toolTip(), f"row {row} has no tooltip"
    for button in (widget.live_check, widget.update_button, widget.reduce_button, widget.cancel_button):
        assert button.toolTip()
    # no clash with napari's display gamma, no Python or CLI names
    assert "gamma" not in " ".join(labels) and "relaxation \u03b3" in labels
    assert "not the display gamma" in widget.gamma_spin.toolTip()
    assert not any("_" in label or "--" in label for label in labels)
    # T's measured meaning, and what it means for this light field (5 x 5 views at gamma 0.2)
    assert "F1" in widget.threshold_slider.toolTip()
    from napari_lfalias.detect import variance_factors

    root_c = float(np.sqrt(variance_factors(25, 0.2)[25]))
    spread = widget.params().threshold / root_c
    assert f"{spread:.0%}" in widget.threshold_hint.text() and "25 views" in widget.threshold_hint.text()


def test_n_and_seed_only_for_monte_carlo_and_they_never_recompute_the_exact_cv(scene_viewer, qtbot):
    viewer, widget, lf = scene_viewer
    _wait_for(qtbot, viewer, "cv", slope=widget.slope)
    _idle(qtbot, widget)
    assert widget.method == "depth" and widget.params().live_method == "analytic"
    assert not widget.n_spin.isEnabled() and not widget.seed_spin.isEnabled()
    updates = []
    widget.outputs_updated.connect(lambda role, params: updates.append(role))
    widget.n_spin.setValue(37)
    widget.seed_spin.setValue(5)
    assert not widget.jobs.busy()
    qtbot.wait(50)
    assert updates == []
    widget.set_method("monte_carlo")
    assert widget.n_spin.isEnabled() and widget.seed_spin.isEnabled()
    cv = _wait_for(qtbot, viewer, "cv", slope=widget.slope, method="monte_carlo", n_patterns=37, seed=5)
    expected = lfa.detect_aliasing(lf, widget.slope, n_patterns=37, method="monte_carlo", seed=5,
                                   skip_flat=False)
    np.testing.assert_array_equal(cv.data, expected.cv)


def test_threshold_can_be_typed(scene_viewer, qtbot):
    from qtpy.QtCore import Qt

    viewer, widget, lf = scene_viewer
    cv = _wait_for(qtbot, viewer, "cv", slope=widget.slope)
    _idle(qtbot, widget)
    box = widget.threshold_slider.spin
    box.selectAll()
    qtbot.keyClicks(box, "0.0037")
    assert widget.params().threshold != pytest.approx(0.0037)  # not per keystroke
    qtbot.keyClick(box, Qt.Key.Key_Return)
    assert widget.params().threshold == pytest.approx(0.0037)
    mask = _wait_for(qtbot, viewer, "mask", threshold=widget.params().threshold)
    np.testing.assert_array_equal(mask.data.astype(bool), cv.data > np.float32(0.0037))


def test_the_controls_show_the_librarys_defaults(make_napari_viewer, qtbot, monkeypatch):
    import inspect

    from napari_lfalias import reduce as reduce_module
    from napari_lfalias._napari._session import DetectionParams, library_defaults

    from napari_lfalias.presets import INTERACTIVE_METHOD

    signature = inspect.signature(reduce_module.reduce_aliasing).parameters
    defaults = library_defaults()
    resolved, max_level, _ = reduce_module.reduction_options()  # what the library uses for None
    library = {**resolved, "max_level": max_level}
    for name in defaults:
        expected = signature[name].default if signature[name].default is not None else library[name]
        assert defaults[name] == expected, name
    assert defaults["method"] == "depth"  # the library's default, offered as "dense aperture (disparity)"
    assert DetectionParams().live_method == INTERACTIVE_METHOD  # the live Cv layer's method
    viewer = make_napari_viewer()
    widget = _open_widget(viewer, qtbot)
    shown = widget.params()
    assert {name: getattr(shown, name) for name in defaults} == defaults
    assert widget.shutdown()

    # a change of the library's defaults reaches the widget (nothing is copied)
    def changed(lf, slope, gamma=0.3, n_patterns=50, threshold=0.004, max_level=2, method="analytic",
                seed=None, *, keep_in_focus=True, nearer="larger"):
        raise AssertionError("not called")

    monkeypatch.setattr(reduce_module, "reduce_aliasing", changed)
    assert DetectionParams().threshold == 0.004 and DetectionParams().max_level == 2
    other = AliasingWidget(viewer)
    params = other.params()
    assert (params.gamma, params.n_patterns, params.threshold, params.max_level, params.keep_in_focus,
            params.nearer) == (0.3, 50, pytest.approx(0.004), 2, True, "larger")
    assert other.shutdown()


# -- nothing silent ---------------------------------------------------------------------------


def test_renaming_the_light_field_layer_is_followed(scene_viewer, qtbot):
    viewer, widget, lf = scene_viewer
    cv = _wait_for(qtbot, viewer, "cv", slope=widget.slope)
    _idle(qtbot, widget)
    cv.name = "my Cv"  # a name the user chose stays
    viewer.layers["lf"].name = "scene A"
    assert widget.layer_combo.currentText() == "scene A" and widget.layer_combo.count() == 1
    assert widget.source == "scene A"
    refocused = find_output_layer(viewer, "refocus")
    assert refocused.metadata["lfalias_source"] == "scene A" and refocused.name == "refocused [scene A]"
    assert cv.name == "my Cv" and cv.metadata["lfalias_source"] == "scene A"
    widget.focus_slider.setValue(0.5)  # the outputs are still found and updated in place
    _wait_for(qtbot, viewer, "cv", slope=0.5)
    _idle(qtbot, widget)
    roles = [layer.metadata.get("lfalias") for layer in viewer.layers if layer.metadata.get("lfalias")]
    assert sorted(roles) == ["cv", "disparity", "mask", "refocus"]
    assert find_output_layer(viewer, "disparity").name == "disparity [scene A]"


def test_a_large_light_field_shows_a_preview_then_the_full_result(make_napari_viewer, qtbot):
    viewer = make_napari_viewer()
    lf = lfa.LightField(np.random.default_rng(2).random((8, 8, 368, 368, 1), dtype=np.float32))
    _add(viewer, lf)
    widget = _open_widget(viewer, qtbot)
    assert widget.session.previews()
    _wait_for(qtbot, viewer, "cv", slope=widget.slope)
    _idle(qtbot, widget)
    seen = []
    widget.outputs_updated.connect(lambda role, params: seen.append((role, bool(params.get("preview")))))
    widget.focus_slider.setValue(1.0)
    qtbot.waitUntil(lambda: ("cv", False) in seen, timeout=TIMEOUT_MS)
    _idle(qtbot, widget)
    assert seen.index(("refocus", True)) < seen.index(("refocus", False))
    assert ("cv", True) in seen and ("mask", True) in seen
    refocused, cv = find_output_layer(viewer, "refocus"), find_output_layer(viewer, "cv")
    assert not refocused.metadata["lfalias_params"].get("preview")
    np.testing.assert_array_equal(refocused.data, lfa.refocus(lf, 1.0)[..., 0])
    np.testing.assert_array_equal(cv.data, lfa.detect_aliasing(lf, 1.0, skip_flat=False, method="analytic").cv)
    assert widget.shutdown()


# -- honest progress ----------------------------------------------------------------------------


def test_while_the_kernels_compile_the_widget_says_so(scene_viewer, qtbot, monkeypatch):
    from napari_lfalias._napari import _warmup

    viewer, widget, lf = scene_viewer
    _idle(qtbot, widget)
    state = {"now": "compiling"}
    monkeypatch.setattr(_warmup, "state", lambda: state["now"])
    widget._warm_timer.start()
    widget.focus_slider.setValue(0.25)  # a job that would wait for the kernels
    qtbot.waitUntil(lambda: "compiling the numeric kernels (first use only" in widget.status.text(),
                    timeout=TIMEOUT_MS)
    assert widget.progress.maximum() == 0  # a busy bar, not "100 %"
    state["now"] = "ready"
    qtbot.waitUntil(lambda: "compiling" not in widget.status.text(), timeout=TIMEOUT_MS)
    _idle(qtbot, widget)
    assert widget.progress.maximum() == 100 and widget.progress.value() == 100
    assert widget.status.text().startswith("slope 0.25")


def test_the_warm_up_compiles_in_the_background_and_reports_it(monkeypatch):
    import threading

    from napari_lfalias._napari import _warmup

    release = threading.Event()
    ran = []
    monkeypatch.setattr(_warmup, "STEPS", (("slow kernel", lambda lf: (ran.append(1), release.wait(10))),))
    monkeypatch.setattr(_warmup, "COMPILING_AFTER_S", 0.05)
    monkeypatch.setattr(_warmup, "_thread", None)
    monkeypatch.setattr(_warmup, "_done", threading.Event())
    monkeypatch.setattr(_warmup, "_compiled", [])
    assert _warmup.state() == "idle"
    thread = _warmup.start()
    assert _warmup.start() is thread  # once per process
    import time

    time.sleep(0.2)
    assert _warmup.state() == "compiling" and ran == [1]
    release.set()
    assert _warmup.wait(10) and _warmup.state() == "ready"
    assert _warmup._compiled == ["slow kernel"]


def test_the_plugin_starts_the_warm_up_when_napari_activates_it(make_napari_viewer):
    from npe2 import PluginManager

    from napari_lfalias._napari import _warmup

    make_napari_viewer()
    PluginManager.instance().activate("napari-lfalias")
    assert _warmup.state() in ("loading", "compiling", "ready")
    assert _warmup.wait(120)
    assert _warmup._failed == []  # a failed step would leave its kernels to the first use


def test_every_warm_up_step_runs_what_the_widget_runs():
    """Each step calls the core as the widget does (a step that raised would warm nothing)."""
    from napari_lfalias._napari import _warmup

    lf = _warmup._tiny_lightfield()
    names = []
    for name, step in _warmup.STEPS:
        step(lf)  # raises if the core refuses the call
        names.append(name)
    assert "disparity estimate and dense-aperture rendering" in names and "aliasing detection" in names


# -- physical scale -----------------------------------------------------------------------------


def test_a_microscope_light_field_and_its_outputs_carry_micrometres(make_napari_viewer, qtbot):
    from napari_lfalias._napari._optics import spatial_calibration

    viewer = make_napari_viewer()
    viewer.open_sample("napari-lfalias", "guv")
    layer = viewer.layers[0]
    lf = layer.metadata["lightfield"]
    where = spatial_calibration(lf)
    optics = lf.meta["microscope"]
    pitch_um = lf.meta["grid"].pitch * optics["pixel_size_um"] / optics["magnification"]
    assert where.unit == "um" and where.scale[1] == pytest.approx(pitch_um)
    assert 1.5 < pitch_um < 1.8  # 15.4 px of 6.5 um behind a 60x objective
    assert [str(unit) for unit in layer.units[-2:]] == ["micrometer", "micrometer"]
    assert tuple(layer.scale[-2:]) == pytest.approx(where.scale)
    widget = _open_widget(viewer, qtbot)
    cv = _wait_for(qtbot, viewer, "cv", slope=widget.slope)
    for output in (cv, find_output_layer(viewer, "refocus"), find_output_layer(viewer, "mask")):
        assert tuple(output.scale) == pytest.approx(where.scale)
        assert [str(unit) for unit in output.units] == ["micrometer", "micrometer"]
    from napari_lfalias._napari._widget import scale_bar

    assert scale_bar(viewer).visible
    assert widget.shutdown()
