"""The in-focus layer of a refocused pixel: the largest group of agreeing views."""

import numpy as np
import pytest

from napari_lfalias import LightField
from napari_lfalias.in_focus import REL_TOL, in_focus_layer


def views_with_values(values, size=6):
    """A grey 2x2-view light field whose views are flat at ``values`` (row-major)."""
    data = np.empty((2, 2, size, size, 1), np.float32)
    data.reshape(4, size, size)[:] = np.asarray(values, np.float32)[:, None, None]
    return LightField(data)


def test_agreement_within_the_tolerance_forms_one_group():
    lf = views_with_values([0.5, 0.5 * (1 + REL_TOL / 2), 0.9, 0.2])
    share, colour = in_focus_layer(lf, 0.0, np.ones((6, 6), bool), 0.01)
    assert share[3, 3] == pytest.approx(0.5)
    assert colour[3, 3, 0] == pytest.approx(0.5 * (1 + REL_TOL / 4), rel=1e-6)


def test_no_group_large_enough_gives_share_zero_and_only_asked_pixels_are_split():
    lf = views_with_values([0.1, 0.3, 0.6, 0.9])
    pixels = np.zeros((6, 6), bool)
    pixels[2, 3] = True
    share, colour = in_focus_layer(lf, 0.0, pixels, 0.01, min_share=0.5)
    assert not share.any() and not colour.any()
    share, _ = in_focus_layer(lf, 0.0, pixels, 0.01, min_share=0.25)
    assert share[2, 3] == pytest.approx(0.25) and np.count_nonzero(share) == 1


def test_dark_samples_agree_within_the_floor():
    lf = views_with_values([0.001, 0.004, 0.5, 0.8])
    share, _ = in_focus_layer(lf, 0.0, np.ones((6, 6), bool), 0.005)
    assert share[3, 3] == pytest.approx(0.5)


def test_views_that_do_not_see_a_pixel_carry_no_weight():
    """Views at (+-0.5, +-0.5) shifted by slope 2: only the view at (0.5, 0.5) sees pixel (0, 0)."""
    lf = views_with_values([0.5, 0.5, 0.5, 0.9])
    share, colour = in_focus_layer(lf, 2.0, np.ones((6, 6), bool), 0.01)
    assert share[0, 0] == pytest.approx(1.0) and colour[0, 0, 0] == pytest.approx(0.9)
    assert share[3, 3] == pytest.approx(0.75) and colour[3, 3, 0] == pytest.approx(0.5)


def test_colour_is_the_mean_colour_of_the_group():
    rng = np.random.default_rng(0)
    data = np.repeat(rng.random((1, 1, 8, 8, 3), np.float32), 3, axis=0).repeat(3, axis=1)
    data[0, 0] = 1.0 - data[0, 0]  # one view of nine disagrees everywhere
    share, colour = in_focus_layer(LightField(data), 0.0, np.ones((8, 8), bool), 0.01)
    differs = np.abs((data[1, 1] - data[0, 0]) @ [0.2126, 0.7152, 0.0722]) > 0.05
    np.testing.assert_allclose(share[differs], 8 / 9, rtol=1e-6)
    np.testing.assert_allclose(colour[differs], data[1, 1][differs], atol=1e-6)
