"""napari readers: real files through ``viewer.open(path, plugin="napari-lfalias")``.

Run under ``xvfb-run``.
"""

import os
import shutil
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("napari")

import imageio.v3 as iio  # noqa: E402

import napari_lfalias as lfa  # noqa: E402
from napari_lfalias._napari import _reader  # noqa: E402
from napari_lfalias._napari._layers import lightfield_of  # noqa: E402

pytestmark = pytest.mark.napari

from test_napari_jobs import no_leaked_worker_threads  # noqa: E402,F401  (autouse: no thread outlives a test)

PLUGIN = "napari-lfalias"
GUV = ("Lightfield_GUVExperim1.tif", "Radiometry_GUVExperim1.tif", "DarkFrame_GUVExperim1.tif")


def _views(n_rows=3, n_cols=3, size=16, seed=0):
    rng = np.random.default_rng(seed)
    return rng.integers(0, 256, (n_rows, n_cols, size, size, 3), dtype=np.uint8)


def _write_views(folder, views, name):
    folder.mkdir()
    for u in range(views.shape[0]):
        for v in range(views.shape[1]):
            iio.imwrite(folder / name(u, v, views.shape[1]), views[u, v])
    return folder


def _open_one(viewer, path):
    layers = viewer.open(path, plugin=PLUGIN)
    assert len(layers) == 1
    layer = layers[0]
    lf = lightfield_of(layer)
    assert isinstance(lf, lfa.LightField)
    return layer, lf


def _check_layer_shows(layer, lf):
    expected = lf.data if lf.n_channels == 3 else lf.data[..., 0]
    assert layer.rgb == (lf.n_channels == 3)
    np.testing.assert_array_equal(np.asarray(layer.data), np.asarray(expected))


# -- camera arrays ---------------------------------------------------------------------


@pytest.mark.parametrize(
    "name",
    [
        lambda u, v, n: f"input_Cam{u * n + v:03d}.png",
        lambda u, v, n: f"view_{u:02d}_{v:02d}.png",
        lambda u, v, n: f"out_{u:02d}_{v:02d}_{-10.5 * u:.3f}_{12.25 * v:.3f}.png",
    ],
    ids=["hci", "rr_cc", "stanford"],
)
def test_camera_array_folder_opens_as_lightfield(make_napari_viewer, tmp_path, name):
    views = _views()
    folder = _write_views(tmp_path / "array", views, name)
    viewer = make_napari_viewer()
    layer, lf = _open_one(viewer, folder)
    assert lf.shape == (3, 3, 16, 16, 3)
    _check_layer_shows(layer, lf)
    # the views land where their names say (top-left and bottom-right)
    np.testing.assert_allclose(lf.data[0, 0], views[0, 0] / 255, atol=1e-6)
    np.testing.assert_allclose(lf.data[2, 2], views[2, 2] / 255, atol=1e-6)
    assert layer.metadata["lightfield"] is lf


def test_hci_scene_opens_like_the_api(make_napari_viewer, lf_data):
    folder = lf_data / "hci_antinous"
    viewer = make_napari_viewer()
    layer, lf = _open_one(viewer, folder)
    assert lf.shape == (9, 9, 512, 512, 3)
    expected = lfa.load(folder)
    np.testing.assert_array_equal(lf.data, expected.data)
    np.testing.assert_array_equal(lf.positions, expected.positions)
    assert layer.axis_labels == ("u", "v", "y", "x")


# -- lenslet captures ---------------------------------------------------------------------


def test_guv_lenslet_capture_opens_with_its_white_and_dark(make_napari_viewer, lf_data):
    folder = lf_data / "napari_lf_guv"
    viewer = make_napari_viewer()
    layer, lf = _open_one(viewer, folder / GUV[0])
    expected = lfa.load(folder / GUV[0], white=folder / GUV[1], dark=folder / GUV[2])
    np.testing.assert_array_equal(lf.data, expected.data)
    _check_layer_shows(layer, lf)
    assert lf.grid_shape == (15, 15)
    assert lf.meta["dark"] is not None  # the dark frame beside it was used
    # the microscope optics of the README beside it: 60x / NA 1.2 in water (n = 1.35)
    assert lf.meta["microscope"] == {"ulens_pitch_um": 100.0, "pixel_size_um": 6.5, "magnification": 60.0,
                                     "na": 1.2, "medium_index": 1.35}


def test_antleg_png_capture_pairs_with_its_radiometry_frame(make_napari_viewer, lf_data):
    folder = lf_data / "napari_lf_antleg"
    assert _reader.find_calibration_frames(folder / "light_field.png") == (
        folder / "radiometry_frame.png", None)
    viewer = make_napari_viewer()
    layer, lf = _open_one(viewer, folder / "light_field.png")
    expected = lfa.load(folder / "light_field.png", white=folder / "radiometry_frame.png")
    np.testing.assert_array_equal(lf.data, expected.data)
    _check_layer_shows(layer, lf)
    assert lf.meta["microscope"]["magnification"] == 20.0


def test_lenslet_capture_opens_with_a_grid_model_saved_beside_it(make_napari_viewer, lf_data, tmp_path):
    from napari_lfalias.decoders import calibrate
    from napari_lfalias.io_write import write_json

    source = lf_data / "napari_lf_guv"
    shutil.copy(source / GUV[0], tmp_path / "capture.tif")  # no white image beside it
    viewer = make_napari_viewer()
    with pytest.raises(_reader.ReadError, match="needs a white image"):  # claimed, and says why
        viewer.open(tmp_path / "capture.tif", plugin=PLUGIN)
    grid = calibrate(source / GUV[1], dark=source / GUV[2])
    write_json(tmp_path / "capture.grid.json", grid)
    layer, lf = _open_one(viewer, tmp_path / "capture.tif")
    expected = lfa.load(tmp_path / "capture.tif", grid=tmp_path / "capture.grid.json")
    np.testing.assert_array_equal(lf.data, expected.data)
    assert lf.meta["grid"] == grid and lf.meta["white"] is None


def test_lenslet_capture_opens_with_its_white_image_given(make_napari_viewer, lf_data, tmp_path):
    # names the pairing beside it would not find: the capture is opened together with its frames
    source = lf_data / "napari_lf_guv"
    paths = [tmp_path / "a" / "cells.tif", tmp_path / "b" / "cells_white.tif", tmp_path / "b" / "cells_dark.tif"]
    for path, name in zip(paths, GUV):
        path.parent.mkdir(exist_ok=True)
        shutil.copy(source / name, path)
    viewer = make_napari_viewer()
    layers = viewer.open([str(p) for p in (paths[1], paths[0], paths[2])], stack=True, plugin=PLUGIN)
    assert len(layers) == 1 and layers[0].name == "cells (a)"
    lf = lightfield_of(layers[0])
    expected = lfa.load(paths[0], white=paths[1], dark=paths[2])
    np.testing.assert_array_equal(lf.data, expected.data)
    # two captures and no white, or a white of another size: not a capture with its frames
    assert _reader.get_lenslet_reader([str(paths[0]), str(paths[2])]) is None
    iio.imwrite(tmp_path / "small_white.tif", np.zeros((40, 40), np.uint16))
    assert _reader.get_lenslet_reader([str(paths[0]), str(tmp_path / "small_white.tif")]) is None


def test_lenslet_pairing_by_name_in_tmp(make_napari_viewer, lf_data, tmp_path):
    # Two captures in one folder: each must pair with its own white image.
    source = lf_data / "napari_lf_guv"
    shutil.copy(source / GUV[0], tmp_path / "sampleA.tif")
    shutil.copy(source / GUV[1], tmp_path / "sampleA_white.tif")
    raw = iio.imread(source / GUV[0])
    iio.imwrite(tmp_path / "sampleB.tif", raw[::-1].copy())
    shutil.copy(source / GUV[1], tmp_path / "sampleB_white.tif")
    assert _reader.find_calibration_frames(tmp_path / "sampleA.tif") == (
        tmp_path / "sampleA_white.tif",
        None,
    )
    viewer = make_napari_viewer()
    layer, lf = _open_one(viewer, tmp_path / "sampleA.tif")
    expected = lfa.load(tmp_path / "sampleA.tif", white=tmp_path / "sampleA_white.tif")
    np.testing.assert_array_equal(lf.data, expected.data)


# -- Lytro --------------------------------------------------------------------------------


def _lenslet_frames(shape, pitch, rng):
    """A white image (lens discs on a rectangular lattice) and a capture of a textured plane."""
    y, x = np.mgrid[0 : shape[0], 0 : shape[1]].astype(np.float32)
    fy, fx = (y - 3.3) / pitch, (x - 5.1) / pitch
    radius = np.hypot(fy - np.round(fy), fx - np.round(fx))
    white = np.clip(1.0 - (radius / 0.47) ** 4, 0.0, 1.0) * 0.8
    texture = 0.3 + 0.6 * rng.random((shape[0] // int(pitch) + 2, shape[1] // int(pitch) + 2))
    lens = texture[np.round(fy).astype(int) + 1, np.round(fx).astype(int) + 1]
    return white, white * lens


def _write_f01_raw(path, image):
    """A bare Lytro F01 sensor file (12-bit packed) with its JSON metadata beside it."""
    import json

    from test_sensor import _pack_f01

    black, top = 168, 4095
    counts = np.clip(black + image * (top - black), 0, top).round().astype(np.uint16)
    path.write_bytes(_pack_f01(counts))
    levels = {channel: None for channel in ("r", "gr", "gb", "b")}
    meta = {"image": {"rawDetails": {
        "mosaic": {"tile": "r,gr:gb,b", "upperLeftPixel": "b"},
        "pixelFormat": {"black": dict.fromkeys(levels, black), "white": dict.fromkeys(levels, top)}}}}
    path.with_suffix(".json").write_text(json.dumps(meta))


@pytest.mark.slow
def test_lytro_raw_capture_opens_with_its_white_image(make_napari_viewer, tmp_path):
    white, capture = _lenslet_frames((3280, 3280), 13.7, np.random.default_rng(3))
    _write_f01_raw(tmp_path / "IMG_0007.raw", capture)
    _write_f01_raw(tmp_path / "IMG_0007_white.raw", white)
    assert _reader.get_lytro_reader(str(tmp_path / "IMG_0007_white.raw")) is None  # the white itself
    viewer = make_napari_viewer()
    layer, lf = _open_one(viewer, tmp_path / "IMG_0007.raw")
    expected = lfa.load(tmp_path / "IMG_0007.raw", white=tmp_path / "IMG_0007_white.raw")
    np.testing.assert_array_equal(lf.data, expected.data)
    _check_layer_shows(layer, lf)
    assert lf.meta["grid"].pitch == pytest.approx(13.7, abs=0.02)
    assert lf.grid_shape == (13, 13) and lf.n_channels == 3


def test_processed_lytro_file_is_claimed_and_fails_clearly(make_napari_viewer, lf_data):
    # The only real LFP files offline hold a processed focal stack, not sensor data.
    path = lf_data / "lytro_lfp_processed_samples" / "IMG_0001-stk.lfp"
    assert _reader.get_lytro_reader(str(path)) is not None
    viewer = make_napari_viewer()
    with pytest.raises(Exception) as info:
        viewer.open(path, plugin=PLUGIN)
    message = str(info.value) + str(info.value.__cause__)
    assert "IMG_0001-stk.lfp" in message and "processed Lytro picture" in message
    assert len(viewer.layers) == 0


# -- what the readers must not claim ---------------------------------------------------------


def test_readers_decline_unrelated_files(tmp_path):
    image = np.zeros((32, 32), np.uint16)
    iio.imwrite(tmp_path / "photo.png", image)
    iio.imwrite(tmp_path / "stack.tif", image)
    (tmp_path / "notes.lfp").write_bytes(b"not a lytro file at all")
    (tmp_path / "sub").mkdir()
    iio.imwrite(tmp_path / "sub" / "a.png", image)
    iio.imwrite(tmp_path / "sub" / "b.png", image)
    assert _reader.get_lenslet_reader(str(tmp_path / "photo.png")) is None  # no white beside
    assert _reader.get_lenslet_reader(str(tmp_path / "stack.tif")) is None
    assert _reader.get_lytro_reader(str(tmp_path / "notes.lfp")) is None  # wrong magic
    assert _reader.get_camera_array_reader(str(tmp_path / "sub")) is None  # no view names
    assert _reader.get_camera_array_reader(str(tmp_path / "photo.png")) is None  # a file
    assert _reader.get_lenslet_reader([str(tmp_path / "photo.png")] * 2) is None  # a stack
    (tmp_path / "short.raw").write_bytes(b"\x00" * 1000)
    assert _reader.get_lytro_reader(str(tmp_path / "short.raw")) is None  # not a Lytro sensor size
    # a JSON beside a capture that is not a grid model, and a grid of another size
    (tmp_path / "photo.grid.json").write_text('{"format": "something else"}')
    assert _reader.get_lenslet_reader(str(tmp_path / "photo.png")) is None
    from napari_lfalias.decoders import GridModel

    grid = GridModel("rectangular", pitch=8.0, rotation=0.0, offset=(4.0, 4.0), n_rows=5, n_cols=5,
                     image_shape=(40, 40))
    (tmp_path / "photo.grid.json").write_text(grid.to_json())
    assert _reader.get_lenslet_reader(str(tmp_path / "photo.png")) is None  # fitted on 40 x 40, not 32 x 32
    assert _reader.find_grid_file(tmp_path / "photo.png") == tmp_path / "photo.grid.json"


def test_lenslet_reader_declines_white_dark_and_mismatched_sizes(tmp_path):
    iio.imwrite(tmp_path / "capture.png", np.zeros((40, 40), np.uint16))
    iio.imwrite(tmp_path / "capture_white.png", np.zeros((40, 48), np.uint16))
    iio.imwrite(tmp_path / "capture_dark.png", np.zeros((40, 40), np.uint16))
    # the calibration frames themselves are not captures
    assert _reader.get_lenslet_reader(str(tmp_path / "capture_white.png")) is None
    assert _reader.get_lenslet_reader(str(tmp_path / "capture_dark.png")) is None
    # a white image of another size is not this capture's white image
    assert _reader.get_lenslet_reader(str(tmp_path / "capture.png")) is None
    iio.imwrite(tmp_path / "capture_white.png", np.zeros((40, 40), np.uint16))
    assert _reader.get_lenslet_reader(str(tmp_path / "capture.png")) is not None
    # a file that only pretends to be a PNG is declined from its header
    (tmp_path / "fake.png").write_bytes(b"\x00" * 64)
    iio.imwrite(tmp_path / "fake_white.png", np.zeros((40, 40), np.uint16))
    assert _reader.get_lenslet_reader(str(tmp_path / "fake.png")) is None


def test_viewer_open_of_unrelated_file_names_no_plugin_reader(make_napari_viewer, tmp_path):
    iio.imwrite(tmp_path / "photo.png", np.zeros((8, 8), np.uint8))
    viewer = make_napari_viewer()
    with pytest.raises(Exception, match="photo.png"):
        viewer.open(tmp_path / "photo.png", plugin=PLUGIN)
    assert len(viewer.layers) == 0


@pytest.mark.parametrize("suffix", [".tif", ".zarr"])
def test_saved_lightfield_opens_with_positions_and_meta(make_napari_viewer, tmp_path, suffix):
    from napari_lfalias.io_write import write_lightfield

    rng = np.random.default_rng(5)
    positions = lfa.regular_positions(3, 2) * 1.5
    lf = lfa.LightField(rng.random((3, 2, 12, 10, 3), dtype=np.float32), positions,
                        meta={"disparity_range": [-1.0, 2.0]})
    path = write_lightfield(tmp_path / f"saved{suffix}", lf)
    viewer = make_napari_viewer()
    layer, read = _open_one(viewer, path)
    np.testing.assert_array_equal(np.asarray(read.data), lf.data)
    np.testing.assert_array_equal(read.positions, positions)
    assert list(read.meta["disparity_range"]) == [-1.0, 2.0]
    # a plain TIFF beside it is not claimed by this reader
    iio.imwrite(tmp_path / "plain.tif", np.zeros((12, 10), np.uint16))
    assert _reader.get_saved_lightfield_reader(str(tmp_path / "plain.tif")) is None


# -- readers say why ------------------------------------------------------------------------


def _notifications_since(count):
    from napari.utils.notifications import notification_manager

    return [str(record.message) for record in notification_manager.records[count:]]


def _choose_in_the_reader_dialog(monkeypatch, choice):
    """Answer napari's "Choose reader" dialog with ``choice`` (a display name); record what it showed."""
    from napari._qt.dialogs import qt_reader_dialog

    shown = {}

    def answer(dialog):
        shown["readers"] = [button.text() for button in dialog.reader_btn_group.buttons()]
        return choice, False

    monkeypatch.setattr(qt_reader_dialog.QtReaderDialog, "get_user_choices", answer)
    return shown


def test_a_partial_camera_array_opens_and_says_what_is_missing(make_napari_viewer, lf_data, tmp_path, monkeypatch):
    """A folder missing views opens (the missing views at weight 0), and the library's note reaches the user."""
    from napari.utils.notifications import notification_manager

    from napari_lfalias._napari._controls import PLUGIN_MENU

    folder = tmp_path / "antinous_partial"
    folder.mkdir()
    for index in range(81):
        if index != 40:  # the centre view is missing
            (folder / f"input_Cam{index:03d}.png").symlink_to(lf_data / "hci_antinous" / f"input_Cam{index:03d}.png")
    assert _reader.get_camera_array_reader(str(folder)) is not None  # claimed: it looks like ours
    viewer = make_napari_viewer()
    shown = _choose_in_the_reader_dialog(monkeypatch, PLUGIN_MENU)
    before = len(notification_manager.records)
    # as File > Open Folder does: napari's own reader claims folders too, so it asks which to use
    with pytest.warns(lfa.errors.LightFieldWarning, match="input_Cam040.png"):
        viewer.window._qt_viewer._qt_open([str(folder)], stack=False)
    assert PLUGIN_MENU in shown["readers"]  # the choice says what this reader opens
    (layer,) = viewer.layers
    lf = lightfield_of(layer)
    assert lf.grid_shape == (9, 9) and not lf.weights[4, 4].any() and lf.weights[0, 0].all()
    del before  # the warning itself is the message (napari shows warnings as notifications)


def test_a_lenslet_capture_without_its_white_image_says_what_to_do(make_napari_viewer, lf_data, tmp_path):
    from napari.utils.notifications import notification_manager

    shutil.copy(lf_data / "napari_lf_guv" / GUV[0], tmp_path / GUV[0])  # no white image beside it
    viewer = make_napari_viewer()
    before = len(notification_manager.records)
    with pytest.raises(_reader.ReadError) as info:
        viewer.open(tmp_path / GUV[0], plugin=PLUGIN)
    message = str(info.value)
    assert GUV[0] in message and "needs a white image" in message
    assert "File > Open Files as Stack" in message and "Lenslet conversion" in message
    assert "--white" not in message and "white=..." not in message
    assert any("needs a white image" in text for text in _notifications_since(before))


def test_making_this_plugin_the_default_reader_as_the_guide_says(make_napari_viewer, tmp_path):
    """docs/napari.md: ``extension2reader`` (Preferences > Plugins) picks this plugin without asking."""
    from napari.settings import get_settings

    from napari_lfalias.io_write import write_lightfield

    lf = lfa.LightField(np.random.default_rng(1).random((2, 3, 8, 8, 1), dtype=np.float32))
    path = write_lightfield(tmp_path / "views.tif", lf)
    folder = _write_views(tmp_path / "array", _views(), lambda u, v, n: f"view_{u:02d}_{v:02d}.png")
    viewer = make_napari_viewer()
    settings = get_settings().plugins
    kept = dict(settings.extension2reader)
    try:
        settings.extension2reader = {**kept, "*.tif": PLUGIN, f"{tmp_path}{os.sep}*{os.sep}": PLUGIN}
        layers = viewer.open(path, plugin=None)  # as File > Open does: no plugin named
        assert lightfield_of(layers[0]).grid_shape == (2, 3)
        layers = viewer.open(folder, plugin=None)
        assert lightfield_of(layers[0]).grid_shape == (3, 3)
    finally:
        settings.extension2reader = kept


def test_two_captures_of_the_same_name_open_as_two_names(make_napari_viewer, lf_data, tmp_path):
    source = lf_data / "napari_lf_guv"
    for folder in ("day1", "day2"):
        (tmp_path / folder).mkdir()
        shutil.copy(source / GUV[0], tmp_path / folder / "light_field.tif")
        shutil.copy(source / GUV[1], tmp_path / folder / "light_field_white.tif")
    viewer = make_napari_viewer()
    names = [viewer.open(tmp_path / folder / "light_field.tif", plugin=PLUGIN)[0].name for folder in ("day1", "day2")]
    assert names == ["light_field (day1)", "light_field (day2)"]


def test_the_names_napari_shows_say_what_the_plugin_and_each_reader_do():
    from npe2 import PluginManifest

    import napari_lfalias
    from napari_lfalias._napari._controls import PLUGIN_MENU

    manifest = PluginManifest.from_file(Path(napari_lfalias.__file__).parent / "napari.yaml")
    assert manifest.display_name == PLUGIN_MENU  # what the reader and writer choices list
    titles = {command.id.split(".")[-1]: command.title for command in manifest.contributions.commands}
    assert "folder of views" in titles["read_camera_array"] and "lenslet" in titles["read_lenslet"]
    assert "Lytro" in titles["read_lytro"] and "saved" in titles["read_saved"]
    assert {writer.display_name for writer in manifest.contributions.writers} == {
        "light field or aliasing output", "aliasing mask or level map"}
