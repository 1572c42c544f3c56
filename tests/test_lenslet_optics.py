"""The occlusion order a decoded lenslet capture declares, checked against optics traced ray by ray.

The synthetic lenslet captures of the other tests lay a light field out
under the lenses by this project's own convention, so they cannot check
which sign of disparity a real camera gives a nearer surface. Here a
plenoptic camera is traced ray by ray instead: a thin main lens, thin
microlenses at its image plane, the sensor one microlens focal length
behind them. A plane nearer than the plane in focus must decode to a
negative disparity, a farther one to a positive disparity, as
``decoders/lenslet.py`` derives, and so the decoder's
``meta["nearer"] == "smaller"``.
"""

import numpy as np
import pytest
from scipy import ndimage

import napari_lfalias as lfa
from napari_lfalias.decoders.lenslet import decode_lenslet

#: Sensor pixels: the microlens pitch, the microlenses' focal length, the main lens' focal length and its
#: distance to the microlenses, the sensor's side.
PITCH, F_MICRO, F_MAIN, Z_MICRO, SIZE = 10.0, 40.0, 1000.0, 2000.0, 320
#: The main lens' aperture radius: its image under a microlens is 0.9 pitch across.
R_APERTURE = 0.45 * PITCH * Z_MICRO / F_MICRO
RAYS = 3_000_000


def _texture(seed=1):
    """Smooth noise in cells of 4 sensor pixels, as a function of positions ``(N, 2)`` on the microlens plane."""
    rng = np.random.default_rng(seed)
    pattern = ndimage.gaussian_filter(rng.random((SIZE // 4 + 40, SIZE // 4 + 40)), 2.0)
    pattern = 0.2 + 0.8 * (pattern - pattern.min()) / np.ptp(pattern)

    def value(points):
        cell = np.clip((points / 4).astype(int) + 20, 0, pattern.shape[0] - 1)
        return pattern[cell[:, 0], cell[:, 1]]

    return value


def _sensor_image(image_distance, texture, seed):
    """The sensor image of a fronto-parallel plane whose image lies ``image_distance`` behind the main lens.

    Each ray leaves a point of the aperture for the image point it converges
    to, crosses the microlens plane in some lens, and that lens (thin, its
    focal length in front of the sensor) bends it onto the sensor at the
    lens' centre plus its focal length times the ray's slope.
    """
    rng = np.random.default_rng(seed)
    radius, angle = R_APERTURE * np.sqrt(rng.random(RAYS)), 2 * np.pi * rng.random(RAYS)
    aperture = np.stack([radius * np.cos(angle), radius * np.sin(angle)], 1)
    crossing = rng.uniform(-2 * PITCH, SIZE + 2 * PITCH, (RAYS, 2))  # where each ray meets the microlenses
    image_point = aperture + (crossing - aperture) * image_distance / Z_MICRO
    lens_centre = (np.floor(crossing / PITCH) + 0.5) * PITCH
    hit = np.floor(lens_centre + F_MICRO * (image_point - aperture) / image_distance).astype(int)
    inside = ((hit >= 0) & (hit < SIZE)).all(1)
    sensor = np.zeros((SIZE, SIZE))
    np.add.at(sensor, (hit[inside, 0], hit[inside, 1]), texture(image_point * Z_MICRO / image_distance)[inside])
    return sensor.astype(np.float32)


@pytest.fixture(scope="module")
def white():
    return _sensor_image(Z_MICRO, lambda points: np.ones(len(points)), seed=2)


@pytest.mark.parametrize("image_distance, side", [(1.1 * Z_MICRO, "nearer"), (0.92 * Z_MICRO, "farther")])
def test_a_plane_nearer_than_focus_decodes_to_a_smaller_disparity(white, image_distance, side):
    lf = decode_lenslet(_sensor_image(image_distance, _texture(), seed=3), white=white)
    assert lf.meta["nearer"] == "smaller"
    estimate = lfa.estimate_disparity(lf)
    measured = float(np.median(estimate.disparity[estimate.confidence > 0.5]))
    # paraxial: the ray from aperture position a crosses the microlenses (1 - Z/z) a from the central ray's
    # point, and one view step (one sensor pixel under a lens) is Z / f of aperture
    expected = -(1.0 - Z_MICRO / image_distance) * (Z_MICRO / F_MICRO) / PITCH
    assert (expected < 0) == (side == "nearer")
    assert np.sign(measured) == np.sign(expected)
    assert measured == pytest.approx(expected, abs=0.15)
