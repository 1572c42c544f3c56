"""Calibration of the microlens grid on synthetic white images with a known grid, JSON, errors."""

import json

import numpy as np
import pytest
import tifffile
from scipy.spatial import cKDTree

from napari_lfalias.decoders import GridModel, calibrate
from napari_lfalias.errors import CalibrationError, DecodeError, ParameterError
from napari_lfalias.synthetic import render_lenslet, textured_plane

PITCH_TOL = 0.02  # px
ROTATION_TOL = 0.05  # degrees


@pytest.fixture(scope="module")
def scene():
    return textured_plane(n_views=1, size=256, seed=3, disparity=0.2)


def _truth_centres(capture, margin=-0.5):
    """True lens centres at least ``margin`` px inside the image (-0.5: the model's own rule)."""
    grid = capture.grid
    points = grid.lens_grid().reshape(-1, 2)
    height, width = grid.image_shape
    inside = ((points[:, 0] >= margin) & (points[:, 0] <= height - 1 - margin)
              & (points[:, 1] >= margin) & (points[:, 1] <= width - 1 - margin))
    return points[inside]


def _assert_same_lenses(found, capture, transpose=False, tol=0.15):
    """Every fitted centre lies within ``tol`` px of a true one, and no lens clearly inside is missed."""
    flip = (lambda p: p[:, ::-1]) if transpose else (lambda p: p)
    truth = flip(_truth_centres(capture, margin=-np.inf))
    distance, index = cKDTree(truth).query(found)
    assert distance.max() < tol, distance.max()
    assert len(set(index.tolist())) == len(found)  # no lens counted twice
    inner = flip(_truth_centres(capture, margin=0.0))
    assert cKDTree(found).query(inner)[0].max() < tol  # none missed


@pytest.mark.parametrize("kind, pitch, rotation, bayer", [
    ("rectangular", 15.37, 0.37, None),
    ("rectangular", 9.81, -1.3, "RGGB"),
    ("hexagonal", 12.83, -0.61, None),
    ("hexagonal", 16.29, 0.9, "GRBG"),
])
def test_the_grid_is_recovered_within_tolerance(scene, kind, pitch, rotation, bayer):
    capture = render_lenslet(scene, shape=(300, 330), pitch=pitch, rotation=rotation, kind=kind, bayer=bayer,
                             noise=0.003, vignetting=0.45, dark_border=6, seed=1)
    grid = calibrate(capture.white, capture.dark, bayer=bayer)
    assert grid.kind == kind and not grid.transposed
    assert abs(grid.pitch - pitch) < PITCH_TOL
    assert abs(grid.rotation - rotation) < ROTATION_TOL
    assert grid.distortion == ()  # an ideal grid stays an ideal lattice
    _assert_same_lenses(grid.centres, capture)
    assert grid.fit["lenses_fitted"] > 0.8 * grid.n_lenses


def test_a_hexagonal_grid_with_vertical_rows_is_modelled_transposed(scene):
    capture = render_lenslet(scene, shape=(300, 300), pitch=13.1, rotation=0.4, kind="hexagonal", seed=2)
    grid = calibrate(capture.white.T.copy(), capture.dark.T.copy())
    assert grid.kind == "hexagonal" and grid.transposed
    assert grid.image_shape == (300, 300)
    assert abs(grid.pitch - 13.1) < PITCH_TOL and abs(grid.rotation - 0.4) < ROTATION_TOL
    _assert_same_lenses(grid.centres, capture, transpose=True)


def test_json_round_trip_keeps_the_model(scene, tmp_path):
    capture = render_lenslet(scene, shape=(200, 220), pitch=11.2, rotation=-0.3, kind="hexagonal", seed=4)
    grid = calibrate(capture.white)
    text = grid.to_json()
    again = GridModel.from_json(text)
    assert again == grid and again.fit == grid.fit
    np.testing.assert_array_equal(again.centres, grid.centres)
    data = json.loads(text)
    assert data["format"] == "napari-lfalias lenslet grid" and data["kind"] == "hexagonal"
    assert data["hex_shift_row"] in (0, 1)


@pytest.mark.parametrize("text, reason", [
    ("not json", "not valid JSON"),
    ('{"kind": "rectangular"}', "lacks pitch"),
    ('{"format": "something else"}', "not a lenslet grid model"),
    ('{"kind": "triangular", "pitch": 10, "rotation": 0, "offset": [0, 0], "n_rows": 2, "n_cols": 2,'
     ' "image_shape": [20, 20]}', "grid kind"),
    ('{"kind": "rectangular", "pitch": -3, "rotation": 0, "offset": [0, 0], "n_rows": 2, "n_cols": 2,'
     ' "image_shape": [20, 20]}', "pitch must be at least 2"),
])
def test_malformed_grid_json_is_a_calibration_error(text, reason):
    with pytest.raises(CalibrationError, match=reason):
        GridModel.from_json(text)


def test_the_distortion_polynomial_moves_the_centres():
    flat = GridModel("rectangular", 10.0, 0.0, (5.0, 5.0), 6, 8, (60, 80))
    terms = [[0.0] * 10, [0.0] * 10]
    terms[1][2] = 0.5  # x displacement = 0.5 * normalised x
    bent = GridModel("rectangular", 10.0, 0.0, (5.0, 5.0), 6, 8, (60, 80), distortion=terms)
    shift = bent.lens_grid() - flat.lens_grid()
    np.testing.assert_allclose(shift[..., 0], 0.0)
    np.testing.assert_allclose(shift[..., 1], 0.5 * (flat.lens_grid()[..., 1] - 40) / 40)
    assert GridModel.from_json(bent.to_json()) == bent
    with pytest.raises(CalibrationError, match="10 coefficients"):
        GridModel("rectangular", 10.0, 0.0, (5.0, 5.0), 6, 8, (60, 80), distortion=[[1.0], [2.0]])


# -- images with no grid --------------------------------------------------------------------


@pytest.mark.parametrize("name, make", [
    ("noise.tif", lambda rng: rng.integers(0, 65535, size=(256, 256))),
    ("flat.tif", lambda rng: np.full((256, 256), 30000) + rng.integers(0, 50, size=(256, 256))),
    ("stripes.tif", lambda rng: 30000 + 20000 * np.sin(np.arange(256) * 2 * np.pi / 11.3)[None, :]
     + np.zeros((256, 1))),
])
def test_an_image_without_a_lens_grid_is_a_calibration_error(tmp_path, name, make):
    rng = np.random.default_rng(0)
    path = tmp_path / name
    tifffile.imwrite(path, make(rng).astype(np.uint16))
    with pytest.raises(CalibrationError) as info:
        calibrate(path)
    assert str(path) in str(info.value) and "no microlens grid found" in str(info.value)


def test_calibration_checks_its_inputs(tmp_path, scene):
    capture = render_lenslet(scene, shape=(200, 200), pitch=10.5, seed=0)
    with pytest.raises(DecodeError, match="dark frame is 100 x 100 px but the white image"):
        calibrate(capture.white, np.zeros((100, 100), np.float32))
    with pytest.raises(ParameterError, match="kind must be"):
        calibrate(capture.white, kind="square")
    with pytest.raises(ParameterError, match="pitch must be"):
        calibrate(capture.white, pitch=0.5)
    with pytest.raises(CalibrationError, match="too small"):
        calibrate(np.ones((8, 8), np.float32))
    # an approximate pitch picks the same grid
    assert calibrate(capture.white, pitch=10).pitch == pytest.approx(calibrate(capture.white).pitch)


# -- the accuracy goals: a tenth of a pixel, a hundredth of a percent -----------------------------


def _centre_error(grid, truth):
    """RMS distance (px) of the fitted model's lens centres from the true centres that rendered them."""
    found = grid.centres
    true = truth.lens_grid().reshape(-1, 2)
    if grid.transposed != truth.transposed:
        true = true[:, ::-1]
    distance = cKDTree(true).query(found)[0]
    return float(np.sqrt(np.mean(distance ** 2)))


def _random_cases(count, seed):
    rng = np.random.default_rng(seed)
    for i in range(count):
        pitch = float(rng.uniform(8.0, 30.0))
        side = int(max(300, 15 * pitch))
        yield {
            "kind": ("rectangular", "hexagonal")[i % 2],
            "pitch": pitch,
            "rotation": float(rng.uniform(-2.0, 2.0)),
            "offset": tuple(rng.uniform(-3.0, -2.0, size=2) * pitch),  # the true grid covers the sensor
            "hex_shift_row": int(rng.integers(2)),
            "vignetting": float(rng.uniform(0.2, 0.5)),
            "bayer": (None, "RGGB", "GRBG", "BGGR")[int(rng.integers(4))],
            "edge": float(rng.uniform(1.0, 3.0)),
            "shape": (side, side + int(rng.integers(0, 40))),
            "seed": i,
        }


@pytest.mark.parametrize("case", list(_random_cases(12, seed=15)), ids=lambda c: f"{c['kind'][:4]}-{c['pitch']:.1f}")
def test_round_trips_recover_the_grid_within_the_goals(case):
    """Random pitch (8-30 px), rotation (+-2 deg), offset, row parity, vignetting, Bayer, noise: the goals hold."""
    capture = render_lenslet(None, noise=0.002, **case)
    grid = calibrate(capture.white, capture.dark, bayer=case["bayer"])
    assert grid.kind == case["kind"] and not grid.transposed
    assert abs(grid.pitch - case["pitch"]) / case["pitch"] <= 1e-4  # 0.01 %
    assert abs(grid.row_step - capture.grid.row_step) / capture.grid.row_step <= 1e-4
    assert _centre_error(grid, capture.grid) <= 0.1
    _assert_same_lenses(grid.centres, capture, tol=0.15)


@pytest.mark.parametrize("parity", [0, 1])
def test_both_row_parities_and_orientations_of_a_hexagonal_grid(parity):
    capture = render_lenslet(None, shape=(320, 300), pitch=11.7, rotation=0.8, kind="hexagonal",
                             hex_shift_row=parity, noise=0.002, seed=parity)
    upright = calibrate(capture.white, capture.dark)
    turned = calibrate(capture.white.T.copy(), capture.dark.T.copy())
    assert not upright.transposed and turned.transposed
    for grid, transpose in ((upright, False), (turned, True)):
        assert grid.kind == "hexagonal"
        assert abs(grid.pitch - 11.7) / 11.7 <= 1e-4 and abs(grid.rotation - 0.8) < 0.01
        _assert_same_lenses(grid.centres, capture, transpose=transpose, tol=0.1)
    # the parity of the shifted rows is the fit's, and it places every lens: the models agree lens for lens
    distance, _ = cKDTree(turned.centres[:, ::-1]).query(upright.centres)
    assert np.percentile(distance, 99) < 0.05 and upright.hex_shift_row in (0, 1)


@pytest.mark.parametrize("ratio", [1.005, 0.98])
def test_rows_closer_or_farther_than_a_regular_hexagon_are_fitted(ratio):
    """The row spacing is fitted on its own: a 0.5 % squeeze once cost a 0.2 % pitch error."""
    pitch = 10.37
    capture = render_lenslet(None, shape=(420, 480), pitch=pitch, rotation=0.6, kind="hexagonal",
                             row_spacing=ratio * pitch * np.sqrt(3) / 2, noise=0.002, vignetting=0.35, edge=2.5)
    grid = calibrate(capture.white, capture.dark)
    assert abs(grid.pitch - pitch) / pitch <= 1e-4
    assert abs(grid.row_step - capture.grid.row_step) / capture.grid.row_step <= 1e-4
    assert _centre_error(grid, capture.grid) <= 0.05 and grid.distortion == ()
