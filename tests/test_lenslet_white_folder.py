"""A folder of white images: one chosen per capture by zoom and focus (as LFToolbox does), grids cached."""

import json

import numpy as np
import pytest
import tifffile

import napari_lfalias as lfa
from napari_lfalias.decoders import calibration, decode_lenslet
from napari_lfalias.decoders.white_images import WhiteImageFolder, capture_settings, grid_cache_dir
from napari_lfalias.errors import WhiteImageError
from napari_lfalias.synthetic import render_lenslet, textured_plane

SHAPE = (200, 230)
#: (zoom step, focus step, pitch): zoom and focus move the micro-images, so each setting has its own grid.
SETTINGS = [(1, 100, 10.05), (5, 100, 10.22), (5, 300, 10.37), (9, 300, 10.61)]


def _write(path, image):
    tifffile.imwrite(path, np.clip(np.round(image * 65535), 0, 65535).astype(np.uint16))


def _lytro_metadata(zoom, focus, serial="B5152000123"):
    """The layout of a Lytro camera's white-image metadata (``MOD_0000.TXT``)."""
    frame = {"metadata": {"devices": {"lens": {"zoomStep": zoom, "focusStep": focus},
                                      "shutter": {"frameExposureDuration": 0.02}},
                          "camera": {"model": "ILLUM"}},
             "privateMetadata": {"camera": {"serialNumber": serial}}}
    return {"master": {"picture": {"frameArray": [{"frame": frame}]}}}


@pytest.fixture
def cache(tmp_path, monkeypatch):
    folder = tmp_path / "cache"
    monkeypatch.setenv("NAPARI_LFALIAS_CACHE", str(folder))
    return folder


@pytest.fixture(scope="module")
def camera(tmp_path_factory):
    """A folder of white images (Lytro-style .txt metadata beside each) and a capture at zoom 5, focus 280."""
    root = tmp_path_factory.mktemp("camera")
    whites = root / "white images"
    (whites / "sub").mkdir(parents=True)
    for index, (zoom, focus, pitch) in enumerate(SETTINGS):
        capture = render_lenslet(None, shape=SHAPE, pitch=pitch, rotation=0.4, kind="hexagonal", noise=0.002,
                                 seed=index)
        folder = whites / "sub" if index % 2 else whites  # searched recursively
        _write(folder / f"MOD_{index:04d}.tif", capture.white)
        (folder / f"MOD_{index:04d}.txt").write_text(json.dumps(_lytro_metadata(zoom, focus)))
    _write(whites / "notes.png", np.zeros((8, 8)))  # an image without settings: not a candidate
    scene = textured_plane(n_views=1, size=128, seed=1, disparity=0.2)
    capture = render_lenslet(scene, shape=SHAPE, pitch=10.37, rotation=0.4, kind="hexagonal", noise=0.002, seed=9)
    raw = root / "IMG_0001.tif"
    _write(raw, capture.raw)
    raw.with_suffix(".json").write_text(json.dumps({"zoom_step": 4.8, "focus_step": 280, "serial": "B5152000123"}))
    return whites, raw, capture


def test_the_white_image_nearest_in_zoom_then_focus_is_chosen(camera, cache):
    whites, raw, capture = camera
    lf = lfa.load(raw, white=whites)
    choice = lf.meta["white_choice"]
    assert choice["path"].endswith("MOD_0002.tif")  # zoom 5 (nearest 4.8), then focus 300 (nearest 280)
    assert (choice["zoom_step"], choice["focus_step"], choice["serial"]) == (5.0, 300.0, "B5152000123")
    assert lf.meta["white"] == choice["path"]
    grid = lf.meta["grid"]
    assert abs(grid.pitch - 10.37) / 10.37 < 1e-4  # the capture's own grid, not a neighbour's
    direct = decode_lenslet(raw, whites / "MOD_0002.tif")
    np.testing.assert_array_equal(lf.data, direct.data)
    folder = WhiteImageFolder(whites)
    assert len(folder.images) == 4 and [p.name for p in folder.without_settings] == ["notes.png"]
    assert folder.choose({"zoom_step": 9, "focus_step": -50}).path.name == "MOD_0003.tif"
    assert folder.choose({"zoom_step": 1.2, "focus_step": 900}).path.name == "MOD_0000.tif"


def test_each_white_image_is_calibrated_once(camera, cache, monkeypatch):
    whites, raw, _ = camera
    first = lfa.load(raw, white=whites)
    cached = list(cache.glob("grids/*.json"))
    assert len(cached) == 1 and grid_cache_dir() == cache / "grids"

    def refuse(*args, **kwargs):
        raise AssertionError("calibrated again although the grid is cached")

    monkeypatch.setattr(calibration, "calibrate", refuse)
    again = lfa.load(raw, white=whites)  # a new folder object: the grid comes from the disk cache
    assert again.meta["grid"] == first.meta["grid"]
    folder = WhiteImageFolder(whites)
    assert decode_lenslet(raw, white=folder).meta["grid"] == first.meta["grid"]
    # a white image that changed is fitted again
    white = whites / "MOD_0002.tif"
    white.write_bytes(white.read_bytes())
    with pytest.raises(AssertionError, match="calibrated again"):
        lfa.load(raw, white=whites)


def test_progress_through_a_folder_reaches_its_total(camera, cache):
    whites, raw, _ = camera
    steps = []
    lfa.load(raw, white=whites, progress=lambda *step: steps.append(step))
    decode = [step for step in steps if step[1] > 1]  # after reading the capture (0 of 1)
    assert decode[0] == (0, 11, "choosing the white image and fitting its grid")
    assert [done for done, _, _ in decode] == list(range(12)) and decode[-1] == (11, 11, "done")


def test_no_fitting_white_image_is_a_clear_error(camera, cache, tmp_path):
    whites, raw, capture = camera
    other = tmp_path / "other.tif"
    _write(other, capture.raw)
    other.with_suffix(".json").write_text(json.dumps({"zoom_step": 5, "focus_step": 300, "serial": "A0000"}))
    with pytest.raises(WhiteImageError) as info:
        lfa.load(other, white=whites)
    assert str(other) in str(info.value) and "camera A0000" in str(info.value) and "B5152000123" in str(info.value)
    bare = tmp_path / "bare.tif"
    _write(bare, capture.raw)
    with pytest.raises(WhiteImageError) as info:
        lfa.load(bare, white=whites)
    assert str(bare) in str(info.value) and "no zoom and focus settings" in str(info.value)
    empty = tmp_path / "empty"
    empty.mkdir()
    _write(empty / "white.tif", capture.white)
    with pytest.raises(WhiteImageError, match="no white image with zoom and focus settings.*1 image"):
        lfa.load(raw, white=empty)


def test_settings_come_from_lytro_metadata():
    from napari_lfalias.decoders.sensor import SensorImage

    image = SensorImage(np.zeros((4, 4), np.float32), meta={"zoom_step": 3.0, "focus_step": -20.0, "serial": "X"})
    assert capture_settings(image) == {"zoom_step": 3.0, "focus_step": -20.0, "serial": "X"}
    from napari_lfalias.decoders.lytro import camera_settings

    found = camera_settings(_lytro_metadata(7, 410))
    assert found == {"zoom_step": 7.0, "focus_step": 410.0, "exposure_s": 0.02, "serial": "B5152000123",
                     "camera_model": "ILLUM"}
