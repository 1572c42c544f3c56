"""Sensor readers: TIFF/PNG, camera raw / DNG through rawpy, Lytro files, Bayer demosaicing."""

import json

import imageio.v3 as iio
import numpy as np
import pytest
import tifffile

from napari_lfalias.decoders.bayer import BAYER_PATTERNS, demosaic, mosaic
from napari_lfalias.decoders.sensor import as_sensor_image, read_sensor
from napari_lfalias.errors import DecodeError, ParameterError

LYTRO_PROCESSED = ("IMG_0001-stk.lfp", "IMG_0002-stk.lfp", "IMG_0002-dm.lfp")


# -- TIFF and PNG -------------------------------------------------------------------


def test_grey_tiff_and_png_read_as_unit_floats(tmp_path):
    pixels = np.arange(12 * 10, dtype=np.uint16).reshape(12, 10) * 500
    tifffile.imwrite(tmp_path / "raw.tif", pixels)
    iio.imwrite(tmp_path / "raw.png", pixels)
    for name, kind in (("raw.tif", "TIFF"), ("raw.png", "PNG")):
        image = read_sensor(tmp_path / name)
        assert image.format == kind and image.bayer is None and image.shape == (12, 10)
        np.testing.assert_allclose(np.asarray(image), pixels / 65535.0, rtol=1e-6)


def test_a_grey_tiff_can_be_declared_a_bayer_mosaic(tmp_path):
    tifffile.imwrite(tmp_path / "raw.tif", np.zeros((8, 8), np.uint16))
    assert read_sensor(tmp_path / "raw.tif", bayer="grbg").bayer == "GRBG"
    with pytest.raises(ParameterError, match="bayer"):
        read_sensor(tmp_path / "raw.tif", bayer="RGBX")
    tifffile.imwrite(tmp_path / "rgb.tif", np.zeros((8, 8, 3), np.uint8), photometric="rgb")
    with pytest.raises(DecodeError, match="rgb.tif.*already colour"):
        read_sensor(tmp_path / "rgb.tif", bayer="RGGB")


@pytest.mark.parametrize("name, content, reason", [
    ("cut.png", None, "truncated"),
    ("broken.tif", b"II*\x00 not really a tiff", "cannot read"),
    ("capture.xyz", b"whatever", "unsupported file type"),
])
def test_unreadable_and_unsupported_files_name_the_file(tmp_path, name, content, reason):
    path = tmp_path / name
    if content is None:
        iio.imwrite(tmp_path / "whole.png", np.full((64, 64), 7, np.uint16))
        content = (tmp_path / "whole.png").read_bytes()[:60]
    path.write_bytes(content)
    with pytest.raises(DecodeError) as info:
        read_sensor(path)
    assert name in str(info.value) and reason in str(info.value)
    with pytest.raises(DecodeError, match="missing.tif: no such file"):
        read_sensor(tmp_path / "missing.tif")


def test_arrays_are_checked_and_never_copied_into():
    array = np.full((6, 7), 0.5, np.float32)
    image = as_sensor_image(array)
    assert np.shares_memory(image.data, array) and image.label() == "array of shape (6, 7)"
    with pytest.raises(ParameterError, match="white must be an"):
        as_sensor_image(np.zeros((4, 4, 2)), name="white")
    with pytest.raises(ParameterError, match="NaN"):
        as_sensor_image(np.full((4, 4), np.nan))


# -- camera raw / DNG (rawpy) ---------------------------------------------------------------


def _write_dng(path, mosaic_u16, cfa=(0, 1, 1, 2), black=64, white=4000):
    """A minimal DNG (CFA, black and white level, identity colour matrix) that LibRaw reads."""
    extratags = [
        (33421, "H", 2, (2, 2)),
        (33422, "B", 4, cfa),
        (50706, "B", 4, (1, 4, 0, 0)),
        (50707, "B", 4, (1, 1, 0, 0)),
        (50708, "s", 0, "napari-lfalias test"),
        (50714, "H", 1, black),
        (50717, "H", 1, white),
        (50721, "2i", 9, (1, 1, 0, 1, 0, 1, 0, 1, 1, 1, 0, 1, 0, 1, 0, 1, 1, 1)),
        (50778, "H", 1, 21),
    ]
    tifffile.imwrite(path, mosaic_u16, photometric=32803, extratags=extratags, subfiletype=0)


@pytest.mark.parametrize("cfa, layout", [((0, 1, 1, 2), "RGGB"), ((1, 0, 2, 1), "GRBG")])
def test_dng_levels_and_layout_come_from_the_file(tmp_path, cfa, layout):
    pytest.importorskip("rawpy")
    counts = np.random.default_rng(1).integers(64, 4000, size=(24, 36)).astype(np.uint16)
    _write_dng(tmp_path / "capture.dng", counts, cfa=cfa)
    image = read_sensor(tmp_path / "capture.dng")
    assert image.bayer == layout and image.format == "DNG"
    np.testing.assert_allclose(image.data, (counts - 64.0) / (4000 - 64), atol=1e-6)
    assert image.meta["white_level"] == 4000


def test_a_broken_camera_raw_file_is_a_decode_error(tmp_path):
    pytest.importorskip("rawpy")
    (tmp_path / "shot.nef").write_bytes(b"\x00" * 4096)
    with pytest.raises(DecodeError, match="shot.nef: cannot read the camera raw file"):
        read_sensor(tmp_path / "shot.nef")


# -- Lytro ----------------------------------------------------------------------------------


@pytest.mark.parametrize("name", LYTRO_PROCESSED)
def test_processed_lytro_pictures_are_refused_with_the_reason(lf_data, name):
    path = lf_data / "lytro_lfp_processed_samples" / name
    with pytest.raises(DecodeError) as info:
        read_sensor(path)
    message = str(info.value)
    assert name in message and "processed Lytro picture" in message and "raw sensor image" in message
    kind = "depthMap" if "-dm" in name else None
    assert kind is None or kind in message


def test_a_truncated_lytro_file_says_truncated(lf_data, tmp_path):
    source = lf_data / "lytro_lfp_processed_samples" / "IMG_0002-stk.lfp"
    cut = tmp_path / "cut.lfp"
    cut.write_bytes(source.read_bytes()[:50000])
    with pytest.raises(DecodeError, match="cut.lfp: truncated Lytro file"):
        read_sensor(cut)


def _pack_f01(counts):
    """Pack 12-bit counts as the Lytro F01 sensor does: two pixels in three bytes."""
    a, b = counts[:, 0::2].ravel().astype(np.uint16), counts[:, 1::2].ravel().astype(np.uint16)
    packed = np.empty(a.size * 3, np.uint8)
    packed[0::3] = a >> 4
    packed[1::3] = ((a & 15) << 4) | (b >> 8)
    packed[2::3] = b & 255
    return packed.tobytes()


def test_a_lytro_f01_raw_file_reads_through_imageio_with_its_levels(tmp_path):
    size = 3280
    rows = np.arange(size, dtype=np.int64)[:, None]
    cols = np.arange(size, dtype=np.int64)[None, :]
    counts = (168 + (rows * 7 + cols * 3) % 3000).astype(np.uint16)
    (tmp_path / "IMG_0007.raw").write_bytes(_pack_f01(counts))
    meta = {"image": {"rawDetails": {
        "mosaic": {"tile": "r,gr:gb,b", "upperLeftPixel": "b"},
        "pixelFormat": {"black": {"r": 168, "gr": 168, "gb": 168, "b": 168},
                        "white": {"r": 4095, "gr": 4095, "gb": 4095, "b": 4095}}}},
        "devices": {"mla": {"lensPitch": 1.4e-5, "rotation": 0.0017}, "sensor": {"pixelPitch": 1.4e-6}}}
    (tmp_path / "IMG_0007.json").write_text(json.dumps(meta))
    image = read_sensor(tmp_path / "IMG_0007.raw")
    assert image.bayer == "BGGR" and image.shape == (size, size)
    assert image.meta["lens_pitch_px"] == pytest.approx(10.0)
    probe = (slice(1000, 1004), slice(2000, 2006))
    np.testing.assert_allclose(image.data[probe], (counts[probe] - 168.0) / (4095 - 168), atol=1e-6)


def test_a_raw_file_of_the_wrong_size_is_not_a_lytro_sensor(tmp_path):
    (tmp_path / "short.raw").write_bytes(b"\x00" * 1000)
    with pytest.raises(DecodeError, match="short.raw: a .raw file of 1000 bytes is neither"):
        read_sensor(tmp_path / "short.raw")


# -- demosaicing ------------------------------------------------------------------------------


@pytest.mark.parametrize("layout", BAYER_PATTERNS)
def test_demosaicing_recovers_smooth_colour_for_every_layout(layout):
    y, x = np.mgrid[0:40, 0:40] / 40.0
    rgb = np.stack([0.2 + 0.6 * x, 0.5 + 0.2 * y, 0.7 - 0.4 * x * y], axis=-1)
    back = demosaic(mosaic(rgb, layout), layout)
    np.testing.assert_allclose(back[4:-4, 4:-4], rgb[4:-4, 4:-4], atol=0.01)
    wrong = demosaic(mosaic(rgb, layout), "BGGR" if layout == "RGGB" else "RGGB")
    assert np.abs(wrong[4:-4, 4:-4] - rgb[4:-4, 4:-4]).max() > 0.1
