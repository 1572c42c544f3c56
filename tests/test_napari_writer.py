"""Saving from napari: light fields and the widget's outputs, opened again by the plugin's readers.

Run under ``xvfb-run``; the save dialog is napari's own (File > Save Selected Layers...), with
the file name and file type a user would pick.
"""

import numpy as np
import pytest

pytest.importorskip("napari")

import napari_lfalias as lfa  # noqa: E402
from napari_lfalias._napari._layers import find_output_layer, lightfield_layer_data, lightfield_of  # noqa: E402

pytestmark = pytest.mark.napari

from test_napari_jobs import no_leaked_worker_threads  # noqa: E402,F401  (autouse: no thread outlives a test)

PLUGIN = "napari-lfalias"


def _save_with_the_dialog(viewer, monkeypatch, layer, path, file_type):
    """File > Save Selected Layers... with ``layer`` selected, ``path`` typed and ``file_type`` chosen."""
    from qtpy.QtWidgets import QFileDialog

    offered = []

    def dialog(self, parent, caption, directory, filter, options):
        offered.extend(filter.split(";;"))
        chosen = next(entry for entry in offered if file_type in entry)
        return str(path), chosen

    monkeypatch.setattr(QFileDialog, "getSaveFileName", dialog)
    viewer.layers.selection = {layer}
    viewer.window._qt_viewer._save_layers_dialog(selected=True)
    return offered


def _lightfield():
    rng = np.random.default_rng(3)
    positions = lfa.regular_positions(3, 4) * np.array([1.0, 1.5])  # an irregular spacing to keep
    return lfa.LightField(rng.random((3, 4, 20, 16, 3), dtype=np.float32), positions,
                          meta={"disparity_range": [-1.5, 2.0], "note": "kept"})


@pytest.mark.parametrize("suffix", [".tif", ".zarr"])
def test_save_then_open_round_trips_a_light_field_with_its_positions(make_napari_viewer, tmp_path,
                                                                     monkeypatch, suffix):
    lf = _lightfield()
    viewer = make_napari_viewer()
    data, kwargs, _ = lightfield_layer_data(lf, "scene")
    layer = viewer.add_image(data, **kwargs)
    offered = _save_with_the_dialog(viewer, monkeypatch, layer, tmp_path / f"scene{suffix}", "light field")
    assert any("Light fields" in entry and f"*{suffix}" in entry for entry in offered)
    opened = viewer.open(tmp_path / f"scene{suffix}", plugin=PLUGIN)
    assert len(opened) == 1
    read = lightfield_of(opened[0])
    np.testing.assert_array_equal(np.asarray(read.data), lf.data)
    np.testing.assert_array_equal(read.positions, lf.positions)
    assert list(read.meta["disparity_range"]) == [-1.5, 2.0] and read.meta["note"] == "kept"
    assert read.positions[0, 1, 1] - read.positions[0, 0, 1] == pytest.approx(1.5)
    # the file is the library's own format (io_write.read_lightfield, which lfa.load will call)
    from napari_lfalias.io_write import read_lightfield

    np.testing.assert_array_equal(read_lightfield(tmp_path / f"scene{suffix}").positions, lf.positions)


def test_saved_outputs_open_again_with_their_parameters(make_napari_viewer, qtbot, tmp_path, monkeypatch):
    from napari_lfalias._napari._widget import AliasingWidget
    from napari_lfalias.synthetic import brick_room

    lf = brick_room(n_views=4, size=48, seed=0).lightfield
    viewer = make_napari_viewer()
    data, kwargs, _ = lightfield_layer_data(lf, "room")
    viewer.add_image(data, **kwargs)
    widget = AliasingWidget(viewer)
    viewer.window.add_dock_widget(widget)
    widget.focus_slider.setValue(4.0)
    qtbot.waitUntil(lambda: (layer := find_output_layer(viewer, "mask")) is not None
                    and layer.metadata["lfalias_params"]["slope"] == 4.0, timeout=20000)
    qtbot.waitUntil(lambda: not widget.jobs.busy(), timeout=20000)
    saved = {}
    for role, file_type in (("refocus", "light field or aliasing output"), ("cv", "light field or aliasing output"),
                            ("mask", "aliasing mask or level map")):
        layer = find_output_layer(viewer, role)
        saved[role] = (np.array(layer.data), dict(layer.metadata["lfalias_params"]), layer._type_string)
        _save_with_the_dialog(viewer, monkeypatch, layer, tmp_path / f"{role}.tif", file_type)
    for role, (values, params, kind) in saved.items():
        opened = viewer.open(tmp_path / f"{role}.tif", plugin=PLUGIN)[0]
        assert opened._type_string == kind
        np.testing.assert_array_equal(opened.data, values)
        assert opened.metadata["lfalias"] == role and opened.metadata["lfalias_source"] == "room"
        assert opened.metadata["lfalias_params"] == params
        assert opened.metadata["lfalias_file"] == str(tmp_path / f"{role}.tif")
        assert opened._type_string != "image" or opened.rgb == (values.ndim == 3)
    # the widget keeps updating its own layers, never the ones opened from files
    widget.focus_slider.setValue(-4.0)
    qtbot.waitUntil(lambda: find_output_layer(viewer, "cv").metadata["lfalias_params"]["slope"] == -4.0,
                    timeout=20000)
    qtbot.waitUntil(lambda: not widget.jobs.busy(), timeout=20000)
    reopened = [layer for layer in viewer.layers if layer.metadata.get("lfalias_file")]
    assert len(reopened) == 3
    assert all(layer.metadata["lfalias_params"]["slope"] == 4.0 for layer in reopened)
    assert widget.shutdown()


def test_the_writer_refuses_what_it_cannot_keep(make_napari_viewer, tmp_path):
    from napari_lfalias._napari._writer import write_layer
    from napari_lfalias.errors import LightFieldError
    from napari_lfalias.io_write import write_lightfield

    viewer = make_napari_viewer()
    plain = viewer.add_image(np.zeros((8, 8), np.float32), name="plain")
    with pytest.raises(LightFieldError, match="neither a light field nor an output"):
        write_layer(tmp_path / "plain.tif", *plain.as_layer_data_tuple()[:2])
    # a saved light field is never written over the file it was read from
    path = write_lightfield(tmp_path / "scene.tif", _lightfield())
    layer = viewer.open(path, plugin=PLUGIN)[0]
    before = path.read_bytes()
    with pytest.raises(LightFieldError, match="read from; choose another name"):
        write_layer(path, *layer.as_layer_data_tuple()[:2])
    assert path.read_bytes() == before


@pytest.mark.parametrize("channels", [3, 1])
def test_a_light_field_saved_with_naparis_own_file_type_opens_and_says_what_was_lost(
        make_napari_viewer, tmp_path, monkeypatch, channels):
    """The dialog's first file type is napari's builtin TIFF writer: the views come back, the positions do not."""
    lf = _lightfield()
    lf = lfa.LightField(lf.data[..., :channels], lf.positions, meta=lf.meta)
    viewer = make_napari_viewer()
    data, kwargs, _ = lightfield_layer_data(lf, "scene")
    layer = viewer.add_image(data, **kwargs)
    offered = _save_with_the_dialog(viewer, monkeypatch, layer, tmp_path / "scene.tif", "napari builtins lossless")
    assert offered[0].startswith("napari builtins")  # what a user who picks nothing gets
    with pytest.warns(lfa.errors.LightFieldWarning, match="scene.tif holds the views .* not their positions"):
        opened = viewer.open(tmp_path / "scene.tif", plugin=PLUGIN)
    read = lightfield_of(opened[0])
    np.testing.assert_array_equal(np.asarray(read.data), lf.data)
    np.testing.assert_array_equal(read.positions, lfa.regular_positions(3, 4))


def test_plain_stacks_that_are_no_light_field_are_left_to_napari(tmp_path):
    import tifffile

    from napari_lfalias._napari import _reader

    rng = np.random.default_rng(0)
    for name, array, kwargs in (
        ("zstack.tif", rng.random((5, 32, 32), dtype=np.float32), {}),  # 3-D
        ("two_views.tif", rng.random((1, 2, 32, 32), dtype=np.float32), {}),  # fewer than 4 views
        # views smaller than the grid
        ("tiny_views.tif", rng.random((9, 9, 4, 4), dtype=np.float32), {"photometric": "minisblack"}),
        ("imagej.tif", rng.random((3, 3, 32, 32), dtype=np.float32), {"imagej": True}),  # not napari's writer
    ):
        tifffile.imwrite(tmp_path / name, array, **kwargs)
        assert _reader.get_saved_lightfield_reader(str(tmp_path / name)) is None, name
