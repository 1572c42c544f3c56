"""The disparity-guided method in the aliasing widget, in real napari viewers (run under xvfb-run).

The disparity is estimated once per light field in a worker, then "Reduce aliasing" with the
default method (dense aperture) gives the API's ``reduce_aliasing(lf, slope, disparity=est)``,
with the anti-aliased rendering beside it; the focus stays live on the exact Cv.
"""

import threading

import numpy as np
import pytest
from scipy import ndimage

pytest.importorskip("napari")

import napari_lfalias as lfa  # noqa: E402
from napari_lfalias._napari._layers import adaptive_limits, find_output_layer  # noqa: E402

pytestmark = pytest.mark.napari

from test_napari_jobs import no_leaked_worker_threads  # noqa: E402,F401  (autouse: no thread outlives a test)
from test_napari_session import _never_estimated_again  # noqa: E402
from test_napari_widget import (  # noqa: E402,F401  (_forget_widgets: autouse)
    TIMEOUT_MS,
    _add,
    _forget_widgets,
    _idle,
    _magenta_share,
    _open_widget,
    _scene,
    _wait_for,
)


@pytest.fixture(scope="module", autouse=True)
def _kernels_ready():
    """Every kernel the widget runs, compiled before the first wait (a cold numba cache on a loaded
    machine takes longer than a test waits for a result); a second or so when cached."""
    from napari_lfalias._napari import _warmup

    lf = _warmup._tiny_lightfield()
    for _, step in _warmup.STEPS:
        step(lf)


def _disparity_layer(qtbot, viewer):
    qtbot.waitUntil(lambda: find_output_layer(viewer, "disparity") is not None, timeout=TIMEOUT_MS)
    return find_output_layer(viewer, "disparity")


@pytest.fixture
def gated_sweep(monkeypatch):
    """The disparity estimate waits for ``gate`` after its first stage; ``ran`` lists the stages run.

    So a test can cancel it while it is certainly between two stages.
    """
    from napari_lfalias import disparity as disparity_module

    gate, entered, ran = threading.Event(), threading.Event(), []
    real = disparity_module.iter_estimate_disparity

    def estimate(lf, *args, **kwargs):  # the real generator, its stages recorded and gated
        steps = real(lf, *args, **kwargs)
        while True:
            try:
                done, total, stage = next(steps)
            except StopIteration as finished:
                return finished.value
            ran.append(stage)
            yield done, total, stage
            if stage == "inputs":
                entered.set()
                assert gate.wait(30), "the test never opened the gate"

    monkeypatch.setattr(disparity_module, "iter_estimate_disparity", estimate)
    yield gate, entered, ran
    gate.set()


def _open_while_estimating(make_napari_viewer, qtbot, entered, size):
    """A viewer and widget on a brick room whose disparity estimate waits at the ``gated_sweep`` gate."""
    viewer = make_napari_viewer()
    lf = _scene(n_views=5, size=size)
    _add(viewer, lf)
    widget = _open_widget(viewer, qtbot)
    qtbot.waitUntil(entered.is_set, timeout=TIMEOUT_MS)  # the estimate is between its first two stages
    return viewer, widget, lf


def test_the_disparity_worker_gives_the_apis_estimate_with_progress(make_napari_viewer, qtbot, monkeypatch):
    viewer = make_napari_viewer()
    lf = _scene(n_views=5, size=96)
    _add(viewer, lf, name="room")
    widget = _open_widget(viewer, qtbot)
    assert widget.method == "depth" and widget.method_combo.currentText() == "dense aperture (disparity)"
    values, seen = [], []
    widget.progress.valueChanged.connect(values.append)
    original = widget.disparity_state.setText  # what the disparity line says, in turn
    widget.disparity_state.setText = lambda text: (seen.append(text), original(text))
    layer = _disparity_layer(qtbot, viewer)
    _idle(qtbot, widget)
    expected = lfa.estimate_disparity(lf)
    np.testing.assert_array_equal(layer.data, expected.disparity)
    np.testing.assert_array_equal(widget.session.estimate.confidence, expected.confidence)
    # handed to the session's detector (for Reduce aliasing), never estimated again
    _never_estimated_again(monkeypatch)
    np.testing.assert_array_equal(widget.session.detector.guide.estimate[0], expected.disparity)
    # honest progress: each stage named as it ends, the bar moving from 0 to the end
    assert "estimating: 2/5 stages done (coarse sweep)" in seen
    assert "estimating: 4/5 stages done (aggregation)" in seen
    assert widget.disparity_state.text().startswith("ready (")
    assert 0 in values
    estimating = values[values.index(0):]
    assert estimating == sorted(estimating) and estimating[-1] == 100 and len(set(estimating)) >= 3
    # the layout rules: over the refocus, hidden, turbo with a colorbar, contrast from its own range
    refocused = find_output_layer(viewer, "refocus")
    assert not layer.visible and layer.colorbar.visible and layer.colormap.name == "turbo"
    assert tuple(layer.translate) == tuple(refocused.translate)
    assert list(layer.contrast_limits) == pytest.approx(adaptive_limits(expected.disparity, from_zero=False))
    assert layer.contrast_limits[0] < -3 and layer.contrast_limits[1] > 3  # the wall at -4, the cube at +4
    assert layer.metadata["lfalias_source"] == "room"
    assert viewer.layers.index(layer) > viewer.layers.index(refocused)  # shown, it lies over the refocus
    # the focus stays live: a new slope updates refocus and Cv; the disparity is not estimated again
    widget.focus_slider.setValue(1.5)
    cv = _wait_for(qtbot, viewer, "cv", slope=1.5, method="analytic")
    _idle(qtbot, widget)
    np.testing.assert_array_equal(cv.data, lfa.detect_aliasing(lf, 1.5, skip_flat=False, method="analytic").cv)
    assert find_output_layer(viewer, "disparity") is layer
    assert widget.shutdown()


def test_cancel_stops_the_disparity_between_stages_and_reduce_estimates_it_again(make_napari_viewer, qtbot,
                                                                                 gated_sweep):
    gate, entered, ran = gated_sweep
    viewer, widget, lf = _open_while_estimating(make_napari_viewer, qtbot, entered, size=96)
    assert widget.jobs.busy("disparity") and widget.cancel_button.isEnabled()
    widget.cancel()
    gate.set()
    _idle(qtbot, widget)
    assert len(ran) < 5 and "fill" not in ran  # stopped between two stages, not run to its end
    assert widget.session.estimate is None and find_output_layer(viewer, "disparity") is None
    assert "cancelled" in widget.disparity_state.text() and not widget.cancel_button.isEnabled()
    assert not widget.session._lock.locked()
    # the focus still works, and Reduce aliasing estimates the disparity first, then reduces
    widget.focus_slider.setValue(4.0)
    _wait_for(qtbot, viewer, "mask", slope=4.0)
    ran.clear()
    widget.reduce()
    assert "once the disparity is ready" in widget.status.text()
    fused = _wait_for(qtbot, viewer, "fused", slope=4.0)
    _idle(qtbot, widget)
    assert ran == ["inputs", "coarse sweep", "sweep", "aggregation", "fill"]
    estimate = lfa.estimate_disparity(lf)
    np.testing.assert_array_equal(fused.data, lfa.reduce_aliasing(lf, 4.0, disparity=estimate).image)
    np.testing.assert_array_equal(find_output_layer(viewer, "disparity").data, estimate.disparity)
    assert widget.shutdown()


def test_a_reduction_waiting_for_the_disparity_is_stopped_by_a_focus_change(make_napari_viewer, qtbot,
                                                                             gated_sweep):
    gate, entered, _ = gated_sweep
    viewer, widget, _ = _open_while_estimating(make_napari_viewer, qtbot, entered, size=64)
    widget.reduce()  # waits for the disparity
    widget.focus_slider.setValue(-2.0)
    assert widget.status.text().startswith("reduction stopped: the focus moved to -2.00")
    gate.set()
    _disparity_layer(qtbot, viewer)  # the estimate goes on: it holds for every focus
    _idle(qtbot, widget)
    assert find_output_layer(viewer, "fused") is None  # no reduction was started for the old focus
    assert widget.session.estimate is not None
    assert widget.shutdown()


def test_not_live_the_disparity_waits_for_reduce(make_napari_viewer, qtbot):
    viewer = make_napari_viewer()
    widget = _open_widget(viewer, qtbot)
    widget.live_check.setChecked(False)  # only Detect and Reduce aliasing compute
    lf = _scene(n_views=4, size=64)
    _add(viewer, lf)
    qtbot.wait(200)
    assert not widget.jobs.busy() and widget.session.estimate is None
    assert widget.disparity_state.text() == "not estimated"
    widget.reduce()
    fused = _wait_for(qtbot, viewer, "fused", slope=widget.slope)
    _idle(qtbot, widget)
    estimate = lfa.estimate_disparity(lf)
    np.testing.assert_array_equal(fused.data, lfa.reduce_aliasing(lf, widget.slope, disparity=estimate).image)
    # a refocus made after the disparity layer goes under it (the disparity, shown, lies over it)
    widget.update_button.click()
    refocused = _wait_for(qtbot, viewer, "refocus", slope=widget.slope)
    _idle(qtbot, widget)
    assert viewer.layers.index(refocused) < viewer.layers.index(find_output_layer(viewer, "disparity"))
    assert find_output_layer(viewer, "fused") is fused  # made at this focus: kept
    assert widget.shutdown()


def test_reduce_with_the_depth_method_is_the_apis_reduction_and_follows_the_focus(make_napari_viewer, qtbot):
    from napari_lfalias.synthetic import brick_room

    viewer = make_napari_viewer()
    scene = brick_room(n_views=5, size=96, seed=0)
    lf = scene.lightfield
    _add(viewer, lf, name="room")
    widget = _open_widget(viewer, qtbot)
    assert not widget.level_spin.isEnabled() and not widget.keep_check.isEnabled()  # Algorithm 2 only
    widget.focus_slider.setValue(4.0)  # on the cube: the wall behind it aliases
    _disparity_layer(qtbot, viewer)
    _wait_for(qtbot, viewer, "mask", slope=4.0)
    _idle(qtbot, widget)
    assert widget.mask_source.text() == "exact Cv > T (live)"
    widget.reduce()
    fused = _wait_for(qtbot, viewer, "fused", slope=4.0)
    _idle(qtbot, widget)
    estimate = lfa.estimate_disparity(lf)
    expected = lfa.reduce_aliasing(lf, 4.0, disparity=estimate)
    np.testing.assert_array_equal(fused.data, expected.image)
    np.testing.assert_array_equal(find_output_layer(viewer, "level").data, expected.level)
    antialiased = find_output_layer(viewer, "antialiased")
    np.testing.assert_array_equal(antialiased.data, lfa.antialiased_refocus(lf, 4.0, estimate))
    for layer in (fused, antialiased):
        assert layer.metadata["lfalias_params"]["method"] == "depth"
        assert layer.metadata["lfalias_params"]["threshold"] == expected.detections[0].threshold
    # the layout rules: the anti-aliased rendering beside the refocus, hidden under the reduced image
    assert fused.visible and not antialiased.visible
    assert tuple(antialiased.translate) == tuple(fused.translate) and fused.translate[-1] > 96
    assert viewer.layers.index(antialiased) > viewer.layers.index(fused)
    # the mask now shows what the reduction replaced, and the widget says so
    mask = find_output_layer(viewer, "mask")
    np.testing.assert_array_equal(mask.data.astype(bool), expected.detections[0].mask)
    assert mask.metadata["lfalias_params"]["method"] == "depth"
    assert widget.mask_source.text() == "pixels Reduce aliasing flagged at focus 4.00 (predicted error > T)"
    # the Cv layer is still the live exact Cv
    cv = find_output_layer(viewer, "cv")
    np.testing.assert_array_equal(cv.data, lfa.detect_aliasing(lf, 4.0, skip_flat=False, method="analytic").cv)
    # the aliasing is removed: nearer the dense-aperture reference than the naive refocus is, where aliased
    reference = scene.reference(4.0)
    naive = find_output_layer(viewer, "refocus").data
    aliased = expected.level > 0
    assert np.abs(fused.data - reference)[aliased].mean() < 0.5 * np.abs(naive - reference)[aliased].mean()
    near = ndimage.binary_dilation(aliased, iterations=3)  # the replaced pixels' soft edge
    np.testing.assert_array_equal(fused.data[~near], naive[~near])  # nothing else touched
    assert (~near).mean() > 0.05  # the cube, in focus
    # a new focus: the results of the old one are removed, the mask is the live Cv again
    widget.focus_slider.setValue(3.0)
    _wait_for(qtbot, viewer, "mask", slope=3.0)
    _idle(qtbot, widget)
    for role in ("fused", "level", "antialiased"):
        assert find_output_layer(viewer, role) is None, role
    assert widget.mask_source.text() == "exact Cv > T (live)"
    assert find_output_layer(viewer, "mask").metadata["lfalias_params"]["method"] == "analytic"
    np.testing.assert_array_equal(find_output_layer(viewer, "disparity").data, estimate.disparity)
    # T applies to both: the live Cv mask and the next reduction's predicted error
    widget.threshold_slider.setValue(0.01)
    widget.reduce()
    fused = _wait_for(qtbot, viewer, "fused", slope=3.0, threshold=0.01)
    np.testing.assert_array_equal(fused.data, lfa.reduce_aliasing(lf, 3.0, threshold=0.01, disparity=estimate).image)
    assert widget.shutdown()


def test_the_occlusion_order_chosen_is_the_apis_nearer(make_napari_viewer, qtbot):
    from napari_lfalias.synthetic import brick_room

    viewer = make_napari_viewer()
    scene = brick_room(n_views=5, size=96, seed=0)  # the cube (+4) in front of the wall (-4)
    lf = scene.lightfield
    _add(viewer, lf, name="room")
    widget = _open_widget(viewer, qtbot)
    assert widget.nearer == "auto" and widget.order_combo.currentText() == "judged from the views"
    widget.focus_slider.setValue(4.0)
    _disparity_layer(qtbot, viewer)
    _idle(qtbot, widget)
    estimate = lfa.estimate_disparity(lf)
    results = {}
    for nearer in ("smaller", "auto"):  # the wrong order, then the one judged from the views
        widget.set_nearer(nearer)
        widget.reduce()
        fused = _wait_for(qtbot, viewer, "fused", slope=4.0, nearer=nearer)
        _idle(qtbot, widget)
        expected = lfa.reduce_aliasing(lf, 4.0, disparity=estimate, nearer=nearer)
        np.testing.assert_array_equal(fused.data, expected.image)
        antialiased = find_output_layer(viewer, "antialiased")
        assert antialiased.metadata["lfalias_params"]["nearer"] == nearer
        np.testing.assert_array_equal(antialiased.data, lfa.antialiased_refocus(lf, 4.0, estimate, nearer=nearer))
        results[nearer] = fused.data.copy()
    # what "auto" judged is shown, so that a user can overrule it
    assert widget.order_combo.itemText(0) == "judged: larger in front (at 4.00)"
    assert widget.nearer == "auto"
    assert not np.array_equal(results["smaller"], results["auto"])  # the choice reached the rendering
    reference = scene.reference(4.0)
    assert np.abs(results["auto"] - reference).mean() < np.abs(results["smaller"] - reference).mean()
    # only the dense-aperture method renders by depth
    widget.set_method("analytic")
    assert not widget.order_combo.isEnabled()
    widget.set_method("depth")
    assert widget.order_combo.isEnabled()
    # a light field that declares its order: "auto" says so, and a new light field is back at "auto"
    widget.set_nearer("larger")
    declared = lfa.LightField(lf.data, lf.positions, meta={**lf.meta, "nearer": "smaller"})
    _add(viewer, declared, name="declared")
    widget.layer_combo.setCurrentIndex(widget.layer_combo.findText("declared"))
    assert widget.source == "declared"
    assert widget.nearer == "auto"
    assert widget.order_combo.currentText() == "declared: smaller in front"
    _idle(qtbot, widget)
    assert widget.shutdown()


def test_the_depth_layout_on_screen(make_napari_viewer, qtbot):
    viewer = make_napari_viewer(show=True)
    lf = _scene(n_views=5, size=96)
    _add(viewer, lf, name="room")
    widget = _open_widget(viewer, qtbot)
    widget.focus_slider.setValue(4.0)
    _disparity_layer(qtbot, viewer)
    _wait_for(qtbot, viewer, "mask", slope=4.0)
    _idle(qtbot, widget)
    widget.reduce()
    _wait_for(qtbot, viewer, "fused", slope=4.0)
    _idle(qtbot, widget)
    viewer.reset_view()
    qtbot.wait(100)
    shot = viewer.screenshot(canvas_only=True, flash=False)
    assert shot[..., :3].std() > 20  # not blank, not one flat colour
    columns = np.flatnonzero(shot[..., :3].max(axis=(0, 2)) > 30)  # where the two panels are drawn
    rows = np.flatnonzero(shot[..., :3].max(axis=(1, 2)) > 30)
    shot = shot[rows[0]:rows[-1] + 1]
    middle = (columns[0] + columns[-1]) // 2
    left, right = shot[:, columns[0]:middle], shot[:, middle:columns[-1]]
    assert left[..., :3].std() > 20 and right[..., :3].std() > 20  # the refocus and the reduced image
    assert _magenta_share(left) > 0.05 > _magenta_share(right)  # the replaced pixels, over the refocus only
    # the disparity, once shown, covers the refocus with its colormap (turbo): the wall at -4 blue,
    # the cube at +4 red
    find_output_layer(viewer, "disparity").visible = True
    qtbot.wait(100)
    shown = viewer.screenshot(canvas_only=True, flash=False)[rows[0]:rows[-1] + 1, columns[0]:middle, :3]
    shown = shown.astype(int)
    assert np.abs(shown - left[..., :3].astype(int)).mean() > 10
    red, blue = shown[..., 0], shown[..., 2]
    assert np.mean(blue > red + 60) > 0.4 and np.mean(red > blue + 60) > 0.05
    # the anti-aliased rendering, once shown, takes the reduced image's place (they differ little)
    find_output_layer(viewer, "antialiased").visible = True
    qtbot.wait(100)
    beside = viewer.screenshot(canvas_only=True, flash=False)[rows[0]:rows[-1] + 1, middle:columns[-1], :3]
    beside = beside.astype(int)
    assert beside.std() > 20 and np.abs(beside - right[..., :3].astype(int)).mean() < 10
    assert widget.shutdown()


def test_the_brick_room_sample_opens_and_its_aliasing_is_removed(make_napari_viewer, qtbot):
    from npe2 import PluginManager

    from napari_lfalias import metrics
    from napari_lfalias.synthetic import brick_room

    contribution = next(sample for sample in PluginManager.instance().iter_sample_data()
                        if sample[0] == "napari-lfalias")[1]
    names = {sample.key: sample.display_name for sample in contribution}
    assert set(names) == {"brick_room", "guv"} and "aliasing" in names["brick_room"]
    viewer = make_napari_viewer()
    viewer.open_sample("napari-lfalias", "brick_room")
    (layer,) = viewer.layers
    scene = brick_room(n_views=8, size=256, seed=0)
    lf = layer.metadata["lightfield"]
    assert lf.grid_shape == (8, 8) and lf.image_shape == (256, 256)
    np.testing.assert_array_equal(lf.data, scene.lightfield.data)
    widget = _open_widget(viewer, qtbot)
    widget.focus_slider.setValue(4.0)  # the cube in focus: the wall's copies 8 px apart
    _disparity_layer(qtbot, viewer)
    widget.reduce()
    fused = _wait_for(qtbot, viewer, "fused", slope=4.0)
    _idle(qtbot, widget)
    reference = scene.reference(4.0)
    naive = find_output_layer(viewer, "refocus").data
    aliased = metrics.aliased_pixels(naive, reference)
    assert aliased.mean() > 0.3  # the wall: strongly aliased

    def psnr(image):
        return 10 * np.log10(1.0 / np.mean((image[aliased] - reference[aliased]) ** 2))

    assert psnr(fused.data) > psnr(naive) + 6  # visibly removed
    assert widget.shutdown()


def test_the_disparity_layer_is_saved_and_opened_with_its_parameters(make_napari_viewer, qtbot, tmp_path):
    from napari_lfalias._napari._writer import write_layer

    viewer = make_napari_viewer()
    lf = _scene(n_views=4, size=48)
    _add(viewer, lf, name="room")
    widget = _open_widget(viewer, qtbot)
    layer = _disparity_layer(qtbot, viewer)
    _idle(qtbot, widget)
    (path,) = write_layer(tmp_path / "disparity.tif", *layer.as_layer_data_tuple()[:2])
    opened = viewer.open(path, plugin="napari-lfalias")[0]
    np.testing.assert_array_equal(opened.data, layer.data)
    assert opened.metadata["lfalias"] == "disparity" and opened.colormap.name == "turbo"
    assert opened.metadata["lfalias_params"]["disparity_range"] == pytest.approx(
        list(widget.session.estimate.disparity_range))
    assert widget.shutdown()
