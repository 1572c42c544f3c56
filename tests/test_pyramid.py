"""Gaussian pyramids of images and light fields."""

import numpy as np
import pytest
from scipy import ndimage

import napari_lfalias as lfa
from napari_lfalias.errors import ParameterError
from napari_lfalias.pyramid import gaussian_pyramid, level_shape, lightfield_pyramid, pyr_down, pyr_up
from napari_lfalias.synthetic import textured_plane

KERNEL = np.array([1, 4, 6, 4, 1]) / 16


def normalised_reference(image, weights):
    """Zero-padded binomial blur of ``w x`` over that of ``w``, at the even pixels (float64)."""
    kernel = np.outer(KERNEL, KERNEL)
    num = ndimage.correlate(image * weights, kernel, mode="constant")
    den = ndimage.correlate(weights, kernel, mode="constant")
    inside = ndimage.correlate(np.ones_like(weights), kernel, mode="constant")
    return (num / den)[::2, ::2], (den / inside)[::2, ::2]


@pytest.mark.parametrize("shape", [(16, 16), (17, 9), (1, 5), (2, 2)])
def test_pyr_down_is_the_normalised_binomial_blur_at_the_even_pixels(shape):
    rng = np.random.default_rng(0)
    image = rng.random(shape)
    reduced, weights = pyr_down(image.astype(np.float32))
    expected, _ = normalised_reference(image, np.ones(shape))
    assert reduced.shape == level_shape(shape, 1) and weights is None
    np.testing.assert_allclose(reduced, expected, rtol=1e-5, atol=1e-6)


def test_a_constant_stays_constant_borders_included():
    reduced, _ = pyr_down(np.full((13, 10, 3), 0.7, np.float32))
    np.testing.assert_allclose(reduced, 0.7, rtol=1e-6)
    np.testing.assert_allclose(pyr_up(reduced, (13, 10)), 0.7, rtol=1e-6)


def test_samples_of_weight_zero_carry_no_weight():
    rng = np.random.default_rng(1)
    image = rng.random((12, 14)).astype(np.float32)
    weights = (rng.random((12, 14)) > 0.3).astype(np.float32)
    image[weights == 0] = 1e6  # would dominate if it counted
    reduced, reduced_weights = pyr_down(image, weights)
    expected, expected_weights = normalised_reference(image.astype(np.float64), weights.astype(np.float64))
    np.testing.assert_allclose(reduced, expected, rtol=1e-5)
    np.testing.assert_allclose(reduced_weights, expected_weights, rtol=1e-5)
    assert reduced.max() < 1.0 and 0 < reduced_weights.min() and reduced_weights.max() <= 1


def test_pyr_up_interpolates_a_linear_ramp_exactly_inside():
    y, x = np.mgrid[0:9, 0:11].astype(np.float32)
    coarse = 2.0 * y + 3.0 * x  # values at the even pixels of the fine grid...
    fine = pyr_up(coarse, (17, 21))
    fy, fx = np.mgrid[0:17, 0:21] / 2.0
    np.testing.assert_allclose(fine[1:-1, 1:-1], (2.0 * fy + 3.0 * fx)[1:-1, 1:-1], atol=1e-5)


def test_gaussian_pyramid_levels_shrink_by_two():
    levels = gaussian_pyramid(np.zeros((100, 37, 3)), 3)
    assert [level.shape for level in levels] == [(100, 37, 3), (50, 19, 3), (25, 10, 3), (13, 5, 3)]


def test_a_plane_of_disparity_d_has_disparity_d_over_two_one_level_up():
    scene = textured_plane(n_views=5, size=96, seed=0, disparity=2.0)
    level1 = lightfield_pyramid(scene.lightfield.luminance(), 1)[1]
    assert level1.image_shape == (48, 48) and level1.meta["pyramid_level"] == 1

    def spread(slope):
        return float(np.median(lfa.view_moments(level1, slope).variance[8:-8, 8:-8]))

    assert spread(1.0) < 0.05 * min(spread(0.5), spread(1.5))


def test_weights_of_a_light_field_are_reduced_with_its_views():
    data = np.random.default_rng(2).random((2, 2, 16, 16, 1)).astype(np.float32)
    weights = np.ones((2, 2, 16, 16), np.float32)
    weights[0, 0, :, :8] = 0
    level1 = lightfield_pyramid(lfa.LightField(data, weights=weights), 1)[1]
    assert level1.weights.shape == (2, 2, 8, 8)
    assert level1.weights[0, 0, :, :3].max() == 0 and level1.weights[1, 1].min() == 1


@pytest.mark.parametrize(
    "call",
    [
        lambda: pyr_down(np.zeros((2, 3, 4, 5))),
        lambda: pyr_down(np.zeros((4, 4)), weights=np.ones((3, 4))),
        lambda: pyr_up(np.zeros((4, 4)), (16, 16)),
        lambda: gaussian_pyramid(np.zeros((4, 4)), -1),
        lambda: lightfield_pyramid(np.zeros((2, 2, 4, 4)), 1),
    ],
)
def test_bad_input_is_a_parameter_error(call):
    with pytest.raises(ParameterError):
        call()
