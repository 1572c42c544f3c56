"""Real-camera artefacts in lenslet captures: vignetting and saturation are not aliasing; bad frames are named."""

import numpy as np
import pytest
import tifffile

import napari_lfalias as lfa
from napari_lfalias.decoders import decode_lenslet, load_lenslet
from napari_lfalias.decoders.devignetting import CLIPPED_WEIGHT
from napari_lfalias.errors import DarkFrameError, DecodeError, LightFieldError, WhiteImageError
from napari_lfalias.synthetic import render_lenslet, textured_plane


@pytest.fixture(scope="module")
def bright_capture():
    """Strong vignetting (70 % lost in the corners) and a scene brighter than the sensor: 9 % of pixels clip."""
    plane = textured_plane(n_views=1, size=256, seed=5, disparity=0.25)
    capture = render_lenslet(plane, shape=(320, 340), pitch=14.6, rotation=0.3, noise=0.002, vignetting=0.7,
                             exposure=2.6, saturation=1.0, seed=3)
    assert 0.03 < (capture.raw >= 1.0).mean() < 0.2
    return capture


@pytest.fixture(scope="module")
def decoded(bright_capture):
    capture = bright_capture
    lf = decode_lenslet(capture.raw, capture.white, capture.dark)
    return lf, capture.reference(lf), capture.layers_disparity["plane"]


def _regions(shape):
    y, x = np.mgrid[0:shape[0], 0:shape[1]]
    corner = (np.minimum(y, shape[0] - 1 - y) < shape[0] // 4) & (np.minimum(x, shape[1] - 1 - x) < shape[1] // 4)
    centre = (abs(y - shape[0] / 2) < shape[0] / 6) & (abs(x - shape[1] / 2) < shape[1] / 6)
    return corner, centre


def test_the_vignette_neither_darkens_a_refocus_nor_raises_cv(decoded):
    lf, reference, slope = decoded
    image, truth = lfa.refocus(lf, slope)[..., 0], lfa.refocus(reference, slope)[..., 0]
    corner, centre = _regions(image.shape)
    unclipped = truth < 1.0  # below the clipping ceiling (about 1.15 here)
    for region in (corner, centre):
        assert image[region & unclipped].mean() / truth[region & unclipped].mean() == pytest.approx(1.0, abs=0.02)
    detection = lfa.detect_aliasing(lf, slope, threshold=0.005, method="analytic")
    assert not detection.mask[corner].any()
    assert np.percentile(detection.cv[corner], 95) < 2 * np.percentile(detection.cv[centre], 95)
    # the weights are what does it: the same views without them darken the corners and flag all of them
    bare = lfa.LightField(lf.data, lf.positions)
    assert lfa.refocus(bare, slope)[..., 0][corner & unclipped].mean() < 0.9 * truth[corner & unclipped].mean()
    assert lfa.detect_aliasing(bare, slope, threshold=0.005, method="analytic").mask[corner].mean() > 0.5


def test_saturated_light_agrees_across_views_and_is_marked(bright_capture, decoded):
    lf, reference, slope = decoded
    truth = lfa.refocus(reference, slope)[..., 0]
    saturated = truth > 1.3  # well above the ceiling: clipped in every view
    assert saturated.mean() > 0.1
    centre = lf.grid_shape[0] // 2
    ceiling = None
    for view in ((centre, centre), (centre, centre - 4), (centre + 3, centre + 3)):
        clipped = (reference.data[view][..., 0] > 1.3) & (lf.weights[view] > 0)  # this view's clipped samples
        values = lf.data[view][..., 0][clipped]
        ceiling = np.median(values) if ceiling is None else ceiling
        assert np.mean(np.isclose(values, ceiling, rtol=0.005)) > 0.95  # a few at the edges blend
    seen = (lf.weights[centre, centre] > 0) & saturated
    # marked: half the weight the white image alone gives
    plain = decode_lenslet(bright_capture.raw, bright_capture.white, bright_capture.dark, saturation=False)
    ratio = lf.weights[centre, centre][seen] / plain.weights[centre, centre][seen]
    assert np.median(ratio) == pytest.approx(CLIPPED_WEIGHT, abs=0.01)
    # not aliasing: nothing is flagged there at a sensitive threshold, though the unclipped decode disagrees
    detection = lfa.detect_aliasing(lf, slope, threshold=0.002, method="analytic")
    assert not detection.mask[saturated].any()
    before = lfa.detect_aliasing(plain, slope, threshold=0.002, method="analytic")
    assert np.percentile(before.angular_cv[saturated], 95) > 1.5 * np.percentile(detection.angular_cv[saturated], 95)


def test_a_given_clipping_level_and_turning_it_off(bright_capture):
    capture = bright_capture
    auto = decode_lenslet(capture.raw, capture.white, capture.dark)
    given = decode_lenslet(capture.raw, capture.white, capture.dark, saturation=1.0)
    np.testing.assert_array_equal(auto.data, given.data)
    with pytest.raises(LightFieldError, match="saturation must be"):
        decode_lenslet(capture.raw, capture.white, saturation=-1)


# -- frames that do not belong together: named errors -----------------------------------------------


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    capture = render_lenslet(textured_plane(n_views=1, size=128), shape=(160, 170), pitch=9.7, noise=0.002, seed=2)
    return capture, capture.write(tmp_path_factory.mktemp("frames"), prefix="cap")


def test_a_dark_frame_equal_to_the_capture_is_refused(files):
    _, paths = files
    with pytest.raises(DarkFrameError) as info:
        load_lenslet(paths["raw"], white=paths["white"], dark=paths["raw"])
    message = str(info.value)
    assert f"dark={paths['raw']}" in message and "leaves nothing" in message and "lens capped" in message


def test_a_colour_white_image_for_a_grey_capture_is_refused(files, tmp_path):
    capture, paths = files
    rgb = tmp_path / "white_rgb.tif"
    tifffile.imwrite(rgb, np.repeat(np.round(capture.white[..., None] * 65535).astype(np.uint16), 3, axis=2),
                     photometric="rgb")
    with pytest.raises(WhiteImageError) as info:
        load_lenslet(paths["raw"], white=rgb)
    assert f"white={rgb}" in str(info.value) and "grey" in str(info.value)


def test_nan_pixels_are_named(files, tmp_path):
    capture, paths = files
    white = capture.white.copy()
    white[50:52, 60:70] = np.nan
    path = tmp_path / "white_nan.tif"
    tifffile.imwrite(path, white)
    with pytest.raises(WhiteImageError) as info:
        load_lenslet(paths["raw"], white=path)
    assert f"white={path}" in str(info.value) and "20 pixel(s) are NaN" in str(info.value)
    raw = capture.raw.copy()
    raw[0, 0] = np.inf
    raw_path = tmp_path / "raw_inf.tif"
    tifffile.imwrite(raw_path, raw)
    with pytest.raises(DecodeError, match=f"raw={raw_path}: 1 pixel"):
        load_lenslet(raw_path, white=paths["white"])


def test_progress_is_reported_step_by_step(files):
    capture, paths = files
    seen = []
    lf = load_lenslet(paths["raw"], white=paths["white"], progress=lambda *step: seen.append(step))
    assert seen[0][2] == "reading the capture" and seen[-1] == (seen[-1][1], seen[-1][1], "done")
    decoding = seen[1:]
    assert [done for done, _, _ in decoding] == sorted(done for done, _, _ in decoding)
    assert any(step.startswith("calibrating") for _, _, step in decoding)
    assert sum(step.startswith("slicing views") for _, _, step in decoding) == 8
    again = decode_lenslet(capture.raw, capture.white, grid=lf.meta["grid"], progress=lambda *step: seen.append(step))
    assert again.shape == lf.shape
