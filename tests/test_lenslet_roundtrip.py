"""Round trips through the lenslet forward model: decode, compare with the scene, check the sign."""

import numpy as np
import pytest

import napari_lfalias as lfa
from napari_lfalias.decoders import GridModel, calibrate, decode_lenslet, load_lenslet
from napari_lfalias.errors import CalibrationError, DecodeError, ParameterError
from napari_lfalias.synthetic import brick_room, render_lenslet, textured_plane

MIN_PSNR = 35.0


@pytest.fixture(scope="module")
def scene():
    # disparities of -0.5 and +0.5 decoded px per view step (scale 0.5)
    return brick_room(n_views=1, size=256, seed=1, wall_disparity=-0.25, cube_disparity=0.25)


@pytest.fixture(scope="module")
def rect_capture(scene):
    return render_lenslet(scene, shape=(320, 340), pitch=15.37, rotation=0.37, noise=0.002, vignetting=0.4,
                          dark_border=5, seed=1)


@pytest.fixture(scope="module")
def hex_capture(scene):
    return render_lenslet(scene, shape=(300, 320), pitch=13.29, rotation=-0.55, kind="hexagonal", bayer="RGGB",
                          noise=0.002, vignetting=0.4, seed=2)


def _psnr(a, b):
    return 10 * np.log10(1.0 / np.mean((np.asarray(a, np.float64) - b) ** 2))


def _interior_psnrs(lf, reference, max_radius):
    """PSNR of every view within ``max_radius`` of the centre, over samples all those views see well."""
    radius = np.hypot(*np.moveaxis(lf.positions, -1, 0))
    views = np.argwhere(radius <= max_radius)
    seen = np.all([lf.weights[u, v] >= 0.5 for u, v in views], axis=0)
    seen[[0, -1], :] = seen[:, [0, -1]] = False
    assert seen.mean() > 0.7
    return [_psnr(lf.data[u, v][seen], reference.data[u, v][seen]) for u, v in views]


@pytest.mark.parametrize("which", ["rect_capture", "hex_capture"])
def test_interior_views_match_the_scene(request, which):
    capture = request.getfixturevalue(which)
    lf = decode_lenslet(capture.raw, capture.white, capture.dark, bayer=capture.bayer)
    grid = lf.meta["grid"]
    assert grid.kind == capture.grid.kind
    assert abs(grid.pitch - capture.grid.pitch) < 0.02 and abs(grid.rotation - capture.grid.rotation) < 0.05
    count = 2 * int(capture.grid.pitch // 2) + 1
    assert lf.grid_shape == (count, count) and lf.n_channels == (1 if capture.bayer is None else 3)
    np.testing.assert_array_equal(lf.positions, lfa.LightField(np.zeros((count, count, 1, 1))).positions)
    psnrs = _interior_psnrs(lf, capture.reference(lf), max_radius=0.5 * grid.pitch - 2.5)
    assert min(psnrs) >= MIN_PSNR, psnrs
    # views outside the microlens disc carry no weight; the central one is seen everywhere, with the
    # vignetting of the white image as its weight
    centre = lf.weights[count // 2, count // 2]
    assert lf.weights[0, 0].max() == 0 and (centre[1:-1, 1:-1] > 0.4).all() and centre.max() > 0.8


def test_refocus_at_the_true_disparity_is_sharp():
    """The sign convention: refocus(lf, d) brings a plane of disparity d into focus, -d does not."""
    plane = textured_plane(n_views=1, size=256, seed=5, disparity=0.35)
    capture = render_lenslet(plane, shape=(320, 320), pitch=14.6, rotation=-0.8, noise=0.001, seed=3)
    lf = decode_lenslet(capture.raw, capture.white, capture.dark)
    disparity = capture.layers_disparity["plane"]
    assert disparity == pytest.approx(0.7)
    reference = capture.reference(lf)
    centre = lf.grid_shape[0] // 2
    sharp = reference.data[centre, centre]  # a single plane in focus looks like the central view
    inner = (slice(3, -3), slice(3, -3))
    in_focus = lfa.refocus(lf, disparity)
    wrong_sign = lfa.refocus(lf, -disparity)
    assert _psnr(in_focus[inner], sharp[inner]) > 33
    assert _psnr(wrong_sign[inner], sharp[inner]) < _psnr(in_focus[inner], sharp[inner]) - 8
    assert np.std(np.diff(in_focus[inner][..., 0], axis=1)) > 1.5 * np.std(np.diff(wrong_sign[inner][..., 0], axis=1))


def test_views_outside_the_disc_are_cropped_on_request(rect_capture):
    cropped = decode_lenslet(rect_capture.raw, rect_capture.white, rect_capture.dark, outside="crop")
    assert cropped.grid_shape == (11, 11)  # half-width 5 <= 7.685 / sqrt(2)
    assert (np.hypot(*np.moveaxis(cropped.positions, -1, 0)) <= rect_capture.grid.pitch / 2).all()
    assert all((cropped.weights[u, v, 1:-1, 1:-1] > 0.2).all() for u in range(11) for v in range(11))
    chosen = decode_lenslet(rect_capture.raw, rect_capture.white, rect_capture.dark, n_views=5)
    assert chosen.grid_shape == (5, 5)


def test_the_users_arrays_are_not_modified(hex_capture):
    raw, white, dark = hex_capture.raw.copy(), hex_capture.white.copy(), hex_capture.dark.copy()
    decode_lenslet(hex_capture.raw, hex_capture.white, hex_capture.dark, bayer="RGGB")
    for before, after in ((raw, hex_capture.raw), (white, hex_capture.white), (dark, hex_capture.dark)):
        np.testing.assert_array_equal(before, after)


def test_a_vertical_hexagonal_grid_decodes_to_the_transposed_views(scene):
    capture = render_lenslet(scene, shape=(260, 260), pitch=12.7, rotation=0.3, kind="hexagonal", seed=4)
    upright = decode_lenslet(capture.raw, capture.white, trim=False)
    turned = decode_lenslet(capture.raw.T.copy(), capture.white.T.copy(), trim=False)
    assert turned.meta["grid"].transposed and not upright.meta["grid"].transposed
    expected = upright.data.transpose(1, 0, 3, 2, 4)
    assert turned.shape == expected.shape
    np.testing.assert_allclose(turned.data, expected, atol=1e-4)


def test_files_decode_like_arrays_and_a_saved_grid_skips_calibration(rect_capture, tmp_path):
    files = rect_capture.write(tmp_path)
    lf = load_lenslet(files["raw"], white=files["white"], dark=files["dark"])
    from_arrays = decode_lenslet(rect_capture.raw, rect_capture.white, rect_capture.dark)
    assert lf.shape == from_arrays.shape and lf.meta["format"] == "lenslet TIFF"
    assert lf.meta["source"] == str(files["raw"]) and lf.meta["white"] == str(files["white"])
    seen = lf.weights > 0.5
    assert _psnr(lf.data[seen], from_arrays.data[seen]) > 55  # 16-bit quantisation only
    grid_file = tmp_path / "grid.json"
    grid_file.write_text(lf.meta["grid"].to_json())
    again = lfa.load(files["raw"], white=files["white"], dark=files["dark"], grid=grid_file)
    np.testing.assert_array_equal(again.data, lf.data)
    np.testing.assert_array_equal(again.weights, lf.weights)
    # without a white image, a grid still slices the views (no devignetting, disc weights only)
    bare = decode_lenslet(rect_capture.raw, grid=lf.meta["grid"])
    assert bare.shape == lf.shape and set(np.unique(bare.weights[7, 7]).round(3)) <= {0.0, 1.0}


def test_mismatched_frames_and_options_are_clear_errors(rect_capture, tmp_path):
    files = rect_capture.write(tmp_path, prefix="cap")
    small = np.zeros((100, 90), np.float32)
    with pytest.raises(DecodeError, match="white image is 90 x 100 px but the capture .*cap_raw.tif"):
        load_lenslet(files["raw"], white=small)
    with pytest.raises(DecodeError, match="cap_raw.tif: a lenslet capture needs a white image"):
        lfa.load(files["raw"])
    grid = calibrate(files["white"])
    other = GridModel(grid.kind, grid.pitch, grid.rotation, grid.offset, grid.n_rows, grid.n_cols, (100, 90))
    with pytest.raises(CalibrationError, match="fitted on a 90 x 100 px image"):
        load_lenslet(files["raw"], white=files["white"], grid=other)
    with pytest.raises(ParameterError, match="unknown option.*lazy"):
        load_lenslet(files["raw"], white=files["white"], lazy=True)
    with pytest.raises(ParameterError, match="grid=\\(U, V\\) applies to folders"):
        load_lenslet(files["raw"], white=files["white"], grid=(3, 3))
    with pytest.raises(ParameterError, match="outside must be one of"):
        load_lenslet(files["raw"], white=files["white"], outside="drop")
