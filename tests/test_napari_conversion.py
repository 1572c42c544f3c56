"""Lenslet conversion widget and sample data in a real viewer (run under xvfb-run)."""

import numpy as np
import pytest

pytest.importorskip("napari")

import napari_lfalias as lfa  # noqa: E402
from napari_lfalias._napari._conversion_widget import LensletConversionWidget  # noqa: E402
from napari_lfalias._napari._layers import lightfield_of  # noqa: E402

pytestmark = pytest.mark.napari

from test_napari_jobs import no_leaked_worker_threads  # noqa: E402,F401  (autouse: no thread outlives a test)

PLUGIN = "napari-lfalias"
TIMEOUT_MS = 60000
GUV = ("Lightfield_GUVExperim1.tif", "Radiometry_GUVExperim1.tif", "DarkFrame_GUVExperim1.tif")


def _role_layers(viewer, role):
    return [layer for layer in viewer.layers if (layer.metadata or {}).get("lfalias") == role]


@pytest.fixture
def guv(lf_data):
    return [lf_data / "napari_lf_guv" / name for name in GUV]


def _finish(qtbot, widget):
    """Wait for the widget's job; fail with its message if it failed."""
    qtbot.waitUntil(lambda: not widget.jobs.busy(), timeout=TIMEOUT_MS)
    assert "failed" not in widget.status.text(), widget.status.text()


def _conversion_widget(viewer, raw=None, white=None, dark=None):
    widget = LensletConversionWidget(viewer)
    viewer.window.add_dock_widget(widget)
    widget.raw_field.set_path(raw)
    widget.white_field.set_path(white)
    widget.dark_field.set_path(dark)
    return widget


def test_calibration_draws_the_fitted_microlens_centres(make_napari_viewer, qtbot, guv):
    from napari_lfalias.decoders import calibrate

    raw, white, dark = guv
    viewer = make_napari_viewer()
    widget = _conversion_widget(viewer, raw)
    widget._guess_frames()  # fills white and dark from the names beside the raw image
    assert widget.white_field.path() == white
    assert widget.dark_field.path() == dark
    widget.calibrate()
    _finish(qtbot, widget)
    points = _role_layers(viewer, "grid")[0]
    expected = calibrate(white, dark=dark)
    assert widget.grid == expected
    np.testing.assert_array_equal(points.data, expected.centres)
    # ~15.4 px pitch on a 436 px frame: hundreds of lenses, all on the image
    assert 700 < len(points.data) < 850
    assert points.data.min() >= -1 and points.data.max() <= 437
    # one circle of the lens' diameter per lens
    np.testing.assert_allclose(points.size, expected.pitch)
    background = _role_layers(viewer, "white")[0]
    assert background.data.shape == (436, 436)
    # the circles sit on the lens discs: the white image is brighter at the centres than between them
    centres = np.round(points.data).astype(int)
    between = np.clip(centres + np.round(expected.pitch / 2).astype(int), 0, 435)
    on = background.data[centres[:, 0], centres[:, 1]]
    off = background.data[between[:, 0], between[:, 1]]
    assert np.median(on) > 2 * np.median(off)
    assert widget.save_button.isEnabled()
    # calibrating again replaces the layers instead of piling them up
    widget.calibrate()
    qtbot.waitUntil(lambda: not widget.jobs.busy(), timeout=TIMEOUT_MS)
    assert len(_role_layers(viewer, "grid")) == 1
    assert widget.shutdown()


def test_conversion_adds_the_decoded_lightfield(make_napari_viewer, qtbot, guv):
    raw, white, dark = guv
    viewer = make_napari_viewer()
    widget = _conversion_widget(viewer, raw, white, dark)
    widget.convert()
    _finish(qtbot, widget)
    layer = next(layer for layer in viewer.layers if lightfield_of(layer) is not None)
    expected = lfa.load(raw, white=white, dark=dark)
    lf = lightfield_of(layer)
    np.testing.assert_array_equal(lf.data, expected.data)
    np.testing.assert_array_equal(lf.weights, expected.weights)
    assert layer.name == f"{raw.stem} (napari_lf_guv)" and lf.shape == (15, 15, 28, 28, 1)
    assert lf.meta["microscope"]["na"] == 1.2  # the optics beside the capture came along
    assert widget.grid == expected.meta["grid"]  # kept: "Save grid" can write it
    assert widget.shutdown()


def test_converting_after_calibration_uses_the_grid_drawn(make_napari_viewer, qtbot, guv, tmp_path):
    raw, white, dark = guv
    viewer = make_napari_viewer()
    widget = _conversion_widget(viewer, raw, white, dark)
    widget.calibrate()
    _finish(qtbot, widget)
    drawn = widget.grid
    widget.convert()
    _finish(qtbot, widget)
    layer = next(layer for layer in viewer.layers if lightfield_of(layer) is not None)
    lf = lightfield_of(layer)
    assert lf.meta["grid"] is drawn
    # the light field lies over the white image it was decoded from (one pixel per lens, in
    # micrometres in the specimen), and the white image and grid no longer cover it
    (white_layer,) = _role_layers(viewer, "white")
    (grid_layer,) = _role_layers(viewer, "grid")
    assert layer.visible and not white_layer.visible and not grid_layer.visible
    um = lf.meta["microscope"]["pixel_size_um"] / lf.meta["microscope"]["magnification"]
    assert tuple(white_layer.scale) == pytest.approx((um, um))
    assert tuple(layer.scale[-2:]) == pytest.approx((drawn.row_step * um, drawn.pitch * um))
    assert tuple(layer.translate[-2:]) == pytest.approx(tuple(drawn.centres[0] * um))
    assert [str(unit) for unit in layer.units[-2:]] == ["micrometer", "micrometer"]
    corner = np.array(layer.translate[-2:]) + (np.array(lf.image_shape) - 1) * np.array(layer.scale[-2:])
    assert np.allclose(corner, drawn.centres[-1] * um, atol=drawn.pitch * um)  # the last lens, too
    # the saved grid opens the capture again without the white image's calibration step
    saved = widget.save_grid(tmp_path / "guv.grid.json")
    assert saved == tmp_path / "guv.grid.json"
    again = lfa.load(raw, white=white, dark=dark, grid=saved)
    np.testing.assert_array_equal(again.data, lf.data)
    # an existing file is not replaced unless asked: the failure is shown, not raised
    assert widget.save_grid(saved) is None
    assert "saving the grid failed" in widget.status.text() and "guv.grid.json" in widget.status.text()
    assert "--overwrite" not in widget.status.text() and "choose another name" in widget.status.text()
    assert widget.save_grid(saved, overwrite=True) == saved
    assert widget.shutdown()


def test_grid_kind_is_passed_to_the_calibration(make_napari_viewer, qtbot, guv):
    raw, white, dark = guv
    viewer = make_napari_viewer()
    widget = _conversion_widget(viewer, raw, white, dark)
    widget.kind_combo.setCurrentText("hexagonal")  # wrong for this rectangular grid: no fit
    widget.calibrate()
    qtbot.waitUntil(lambda: not widget.jobs.busy(), timeout=TIMEOUT_MS)
    status = widget.status.text()
    assert "calibrate failed" in status and "Radiometry_GUVExperim1.tif" in status and "lattice" in status
    assert widget.grid is None and not _role_layers(viewer, "grid")
    widget.kind_combo.setCurrentText("rectangular")
    widget.calibrate()
    _finish(qtbot, widget)
    assert widget.grid.kind == "rectangular"
    assert widget.shutdown()


def test_missing_inputs_are_reported_not_raised(make_napari_viewer, qtbot, tmp_path):
    viewer = make_napari_viewer()
    widget = _conversion_widget(viewer, tmp_path / "raw.tif")
    widget.convert()
    assert "white" in widget.status.text()
    assert widget.convert_button.isEnabled()
    widget.white_field.set_path(tmp_path / "missing_white.tif")
    widget.calibrate()
    assert "missing_white.tif: no such file" in widget.status.text()
    assert widget.calibrate_button.isEnabled() and not widget.jobs.busy()
    assert len(viewer.layers) == 0


def test_unreadable_white_image_fails_in_the_worker_with_its_name(make_napari_viewer, qtbot, tmp_path):
    bad = tmp_path / "broken_white.tif"
    bad.write_bytes(b"II*\x00 not really a tiff")
    viewer = make_napari_viewer()
    widget = _conversion_widget(viewer, white=bad)
    widget.calibrate()
    qtbot.waitUntil(lambda: not widget.jobs.busy(), timeout=TIMEOUT_MS)
    assert "calibrate failed" in widget.status.text()
    assert "broken_white.tif" in widget.status.text()
    assert widget.calibrate_button.isEnabled()
    assert len(viewer.layers) == 0


def test_sample_data_are_in_the_manifest(make_napari_viewer):
    from npe2 import PluginManager

    manifest = PluginManager.instance().get_manifest(PLUGIN)
    keys = {sample.key for sample in manifest.contributions.sample_data}
    assert keys == {"brick_room", "guv"}
    widgets = {w.display_name for w in manifest.contributions.widgets}
    assert widgets == {"Refocus and aliasing", "Lenslet conversion"}


def test_guv_sample_opens_decoded(make_napari_viewer):
    from napari_lfalias._paths import sample_data_dir

    viewer = make_napari_viewer()
    viewer.open_sample(PLUGIN, "guv")
    assert len(viewer.layers) == 1
    lf = lightfield_of(viewer.layers[0])
    folder = sample_data_dir() / "guv"
    expected = lfa.load(folder / GUV[0], white=folder / GUV[1], dark=folder / GUV[2])
    np.testing.assert_array_equal(lf.data, expected.data)
    assert lf.shape == (15, 15, 28, 28, 1)
    assert lf.meta["microscope"]["magnification"] == 60.0


def test_brick_room_sample_is_the_synthetic_scene(make_napari_viewer):
    from napari_lfalias._napari._sample_data import brick_room
    from napari_lfalias.synthetic import brick_room as make_scene

    data, kwargs, layer_type = brick_room(n_views=5, size=64)[0]
    scene = make_scene(n_views=5, size=64, seed=0)
    assert layer_type == "image" and kwargs["rgb"]
    np.testing.assert_array_equal(data, scene.lightfield.data)
    viewer = make_napari_viewer()
    layer = viewer.add_image(data, **kwargs)
    assert lightfield_of(layer) is kwargs["metadata"]["lightfield"]


def test_full_size_brick_room_sample_opens(make_napari_viewer):
    viewer = make_napari_viewer()
    viewer.open_sample(PLUGIN, "brick_room")
    lf = lightfield_of(viewer.layers[0])
    assert lf.shape == (8, 8, 256, 256, 3)  # synthetic.brick_room(n_views=8, size=256, seed=0)


def test_the_conversion_widget_follows_the_decode_steps(make_napari_viewer, qtbot, guv):
    raw, white, dark = guv
    viewer = make_napari_viewer()
    widget = _conversion_widget(viewer, raw, white, dark)
    values, texts = [], []
    widget.progress.valueChanged.connect(values.append)
    widget.status.setText("")
    original = widget._on_progress

    def record(slot, done, total, step=None):
        original(slot, done, total, step)
        texts.append(widget.status.text())

    widget.jobs._on_progress = record
    widget.convert()
    _finish(qtbot, widget)
    assert any("calibrating the microlens grid" in text for text in texts)
    assert sum("slicing views" in text for text in texts) == 8
    assert values == sorted(values) and values[-1] == widget.progress.maximum() and len(set(values)) > 5
    assert not widget.progress.isVisible()  # hidden once the job is done
    assert widget.shutdown()
