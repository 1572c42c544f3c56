"""The aliasing widget in a real napari viewer (run under xvfb-run).

Small light fields (5x5 views of 64x64) keep these quick; the arrays the
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

TIMEOUT_MS = 20000


def _scene(n_views=5, size=64, seed=0):
    """A small brick room (with its ground-truth disparity in the metadata)."""
    from napari_lfalias.synthetic import brick_room

    return brick_room(n_views=n_views, size=size, seed=seed).lightfield


def _add(viewer, lf, name="lf"):
    data, kwargs, _ = lightfield_layer_data(lf, name)
    return viewer.add_image(data, **kwargs)


def _open_widget(viewer, qtbot):
    widget = AliasingWidget(viewer)
    viewer.window.add_dock_widget(widget, name="aliasing")
    return widget


def _params(viewer, role):
    layer = find_output_layer(viewer, role)
    return None if layer is None else layer.metadata.get("lfalias_params")


def _wait_for(qtbot, viewer, role, **expected):
    def done():
        params = _params(viewer, role)
        return params is not None and all(params.get(k) == v for k, v in expected.items())

    qtbot.waitUntil(done, timeout=TIMEOUT_MS)
    return find_output_layer(viewer, role)


def _idle(qtbot, widget):
    qtbot.waitUntil(lambda: not widget.jobs.busy(), timeout=TIMEOUT_MS)


@pytest.fixture
def scene_viewer(make_napari_viewer, qtbot):
    viewer = make_napari_viewer()
    lf = _scene()
    _add(viewer, lf)
    widget = _open_widget(viewer, qtbot)
    yield viewer, widget, lf
    assert widget.shutdown()


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
    np.testing.assert_allclose(refocused.data, lfa.refocus(lf, slope), atol=1e-5)
    detection = lfa.detect_aliasing(lf, slope, gamma=0.2, threshold=widget.params().threshold,
                                    method="analytic")
    np.testing.assert_allclose(cv.data, detection.cv, rtol=1e-4, atol=1e-5)
    assert mask._type_string == "labels"
    np.testing.assert_array_equal(mask.data.astype(bool), detection.mask)
    # outputs are updated in place: one layer per role
    roles = [layer.metadata.get("lfalias") for layer in viewer.layers]
    assert sorted(r for r in roles if r) == ["cv", "mask", "refocus"]


def test_threshold_rethresholds_without_recomputing(scene_viewer, qtbot):
    viewer, widget, lf = scene_viewer
    slope = widget.slope
    cv_layer = _wait_for(qtbot, viewer, "cv", slope=slope)
    _idle(qtbot, widget)
    cv_before = cv_layer.data
    new_threshold = 0.005 if widget.params().threshold > 0.01 else 0.05
    widget.threshold_slider.setValue(new_threshold)
    threshold = widget.params().threshold
    mask = find_output_layer(viewer, "mask")
    # synchronous: no worker was started, the mask changed at once
    assert not widget.jobs.busy()
    assert mask.metadata["lfalias_params"]["threshold"] == threshold
    np.testing.assert_array_equal(mask.data.astype(bool), cv_before > threshold)
    assert find_output_layer(viewer, "cv").data is cv_before


def test_monte_carlo_matches_the_api_with_the_same_seed(scene_viewer, qtbot):
    viewer, widget, lf = scene_viewer
    widget.n_spin.setValue(20)
    widget.seed_spin.setValue(7)
    widget.method_combo.setCurrentText("monte_carlo")
    slope = widget.slope
    cv = _wait_for(qtbot, viewer, "cv", slope=slope, method="monte_carlo", n_patterns=20, seed=7)
    expected = lfa.detect_aliasing(lf, slope, gamma=0.2, n_patterns=20, method="monte_carlo",
                                   seed=7, threshold=widget.params().threshold)
    np.testing.assert_allclose(cv.data, expected.cv, rtol=1e-4, atol=1e-5)


def test_gamma_change_reuses_the_shifted_stack(scene_viewer, qtbot):
    viewer, widget, lf = scene_viewer
    widget.method_combo.setCurrentText("monte_carlo")
    widget.n_spin.setValue(10)
    slope = widget.slope
    _wait_for(qtbot, viewer, "cv", slope=slope, method="monte_carlo", n_patterns=10)
    _idle(qtbot, widget)
    stack = widget.session.cached_stack(slope)
    assert stack is not None
    widget.gamma_spin.setValue(0.4)
    cv = _wait_for(qtbot, viewer, "cv", slope=slope, gamma=0.4, n_patterns=10)
    assert widget.session.cached_stack(slope) is stack
    expected = lfa.detect_aliasing(lf, slope, gamma=0.4, n_patterns=10, method="monte_carlo",
                                   seed=0, threshold=widget.params().threshold)
    np.testing.assert_allclose(cv.data, expected.cv, rtol=1e-4, atol=1e-5)


def test_reduction_runs_in_a_worker_while_events_are_processed(make_napari_viewer, qtbot):
    from qtpy.QtCore import QTimer

    viewer = make_napari_viewer()
    lf = _scene(n_views=5, size=128)
    _add(viewer, lf)
    widget = _open_widget(viewer, qtbot)
    _wait_for(qtbot, viewer, "cv", slope=widget.slope)
    _idle(qtbot, widget)

    ticks_while_busy = []
    timer = QTimer()
    timer.setInterval(5)
    timer.timeout.connect(lambda: ticks_while_busy.append(widget.jobs.busy("reduce")))
    timer.start()
    widget.reduce()
    assert widget.jobs.busy("reduce")
    fused = _wait_for(qtbot, viewer, "fused", slope=widget.slope)
    timer.stop()
    assert sum(ticks_while_busy) >= 2  # the GUI thread ticked while the worker reduced

    params = widget.params()
    expected = lfa.reduce_aliasing(lf, widget.slope, gamma=params.gamma, n_patterns=params.n_patterns,
                                   threshold=params.threshold, max_level=params.max_level,
                                   method=params.method, seed=params.seed)
    np.testing.assert_allclose(fused.data, expected.image, atol=1e-4)
    level = find_output_layer(viewer, "level")
    np.testing.assert_array_equal(level.data, expected.level)
    assert widget.shutdown()


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
    # no disparities in the metadata: the default +/-2 px range
    assert (widget.focus_slider.minimum(), widget.focus_slider.maximum()) == (-2.0, 2.0)
    refocused = _wait_for(qtbot, viewer, "refocus", slope=widget.slope)
    np.testing.assert_allclose(refocused.data, lfa.refocus(lf, widget.slope)[..., 0], atol=1e-5)
    _idle(qtbot, widget)
    viewer.layers.remove("small")
    assert widget.layer_combo.count() == 0 and widget.session is None
    assert widget.shutdown()


def test_screenshot_shows_the_cv_layer(make_napari_viewer, qtbot):
    viewer = make_napari_viewer(show=True)
    lf = _scene()
    _add(viewer, lf, name="room")
    widget = _open_widget(viewer, qtbot)
    cv = _wait_for(qtbot, viewer, "cv", slope=widget.slope)
    _idle(qtbot, widget)
    for layer in viewer.layers:
        layer.visible = layer is cv
    viewer.reset_view()
    qtbot.wait(50)
    shot = viewer.screenshot(canvas_only=True, flash=False)
    assert shot.ndim == 3 and shot[..., :3].std() > 5
    cv.visible = False
    qtbot.wait(50)
    blank = viewer.screenshot(canvas_only=True, flash=False)
    assert np.abs(shot.astype(int) - blank.astype(int)).mean() > 1
    assert widget.shutdown()


def test_no_worker_threads_outlive_the_widget(make_napari_viewer, qtbot):
    from qtpy.QtCore import QThreadPool

    viewer = make_napari_viewer()
    _add(viewer, _scene())
    widget = _open_widget(viewer, qtbot)
    widget.method_combo.setCurrentText("monte_carlo")
    widget.reduce()
    assert widget.jobs.busy()
    assert widget.shutdown()
    assert QThreadPool.globalInstance().waitForDone(TIMEOUT_MS)
    assert QThreadPool.globalInstance().activeThreadCount() == 0
