"""napari readers: real files through ``viewer.open(path, plugin="napari-lfalias")``.

Run under ``xvfb-run``.
"""

import shutil

import numpy as np
import pytest

pytest.importorskip("napari")

import imageio.v3 as iio  # noqa: E402

import napari_lfalias as lfa  # noqa: E402
from napari_lfalias._napari import _reader  # noqa: E402
from napari_lfalias._napari._layers import lightfield_of  # noqa: E402

pytestmark = pytest.mark.napari

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
    assert lf.grid_shape[0] >= 5 and lf.grid_shape[1] >= 5


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


def test_processed_lytro_file_is_claimed_and_fails_clearly(make_napari_viewer, lf_data):
    # The only real LFP files offline hold a processed focal stack, not sensor data.
    path = lf_data / "lytro_lfp_processed_samples" / "IMG_0001-stk.lfp"
    assert _reader.get_lytro_reader(str(path)) is not None
    viewer = make_napari_viewer()
    with pytest.raises(Exception) as info:
        viewer.open(path, plugin=PLUGIN)
    assert "IMG_0001-stk.lfp" in str(info.value) or "IMG_0001-stk.lfp" in str(info.value.__cause__)
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
