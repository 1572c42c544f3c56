"""The widget's fast live path computes what the core API computes."""

import numpy as np
import pytest

import napari_lfalias as lfa
from napari_lfalias._napari._preview import LivePreview, tap_profile
from napari_lfalias.refocus import bilinear_shift

pytestmark = pytest.mark.napari

SLOPES = [0.0, 0.37, -1.25, 2.5, 6.8, 1e-9, -3.0]


def _textured(shape, seed=0, offset=0.0):
    rng = np.random.default_rng(seed)
    return lfa.LightField(offset + rng.random(shape, dtype=np.float32))


@pytest.mark.parametrize("shape", [(5, 5, 48, 40, 3), (3, 4, 33, 50, 1)])
@pytest.mark.parametrize("slope", SLOPES)
def test_live_refocus_and_moments_equal_the_core(shape, slope):
    lf = _textured(shape)
    image, moments = LivePreview(lf).compute(slope)
    np.testing.assert_allclose(image, lfa.refocus(lf, slope), atol=1e-6)
    expected = lfa.view_moments(lf.luminance(), slope)
    np.testing.assert_allclose(moments.mean, expected.mean, atol=1e-6)
    np.testing.assert_allclose(moments.variance, expected.variance, atol=1e-6)
    np.testing.assert_allclose(moments.weight_sum, expected.weight_sum, rtol=1e-6)
    np.testing.assert_array_equal(moments.count, expected.count)


def test_irregular_positions_follow_the_light_field():
    lf = _textured((3, 3, 32, 32, 3), seed=2)
    rng = np.random.default_rng(3)
    positions = lf.positions + rng.uniform(-0.3, 0.3, lf.positions.shape)
    lf = lfa.LightField(lf.data, positions)
    image, moments = LivePreview(lf).compute(1.7)
    np.testing.assert_allclose(image, lfa.refocus(lf, 1.7), atol=1e-6)
    np.testing.assert_allclose(
        moments.variance, lfa.view_moments(lf.luminance(), 1.7).variance, atol=1e-6
    )


def _float64_variance(lf, slope):
    """Weighted variance of the shifted views, all in float64 (the reference)."""
    values, weights = [], []
    for view, (qy, qx) in zip(lf.views().astype(np.float64), lf.flat_positions()):
        sampled, weight = bilinear_shift(view[..., 0], slope * qy, slope * qx)
        values.append(np.divide(sampled, weight, out=np.zeros_like(sampled), where=weight > 0))
        weights.append(weight)
    values, weights = np.array(values), np.array(weights, np.float64)
    mean = (weights * values).sum(0) / weights.sum(0)
    return (weights * (values - mean) ** 2).sum(0) / weights.sum(0)


def test_variance_keeps_precision_on_a_large_offset():
    # tiny variations on a large mean: E[x^2] - E[x]^2 in float32 would lose them all
    rng = np.random.default_rng(4)
    data = (100.0 + 1e-3 * rng.random((4, 4, 24, 24, 1))).astype(np.float32)
    lf = lfa.LightField(data)
    _, moments = LivePreview(lf).compute(0.8)
    reference = _float64_variance(lf, 0.8)
    error = np.abs(moments.variance[..., 0] - reference)
    # float32 samples of values near 100 are only good to ~1e-5: that, not the
    # accumulation, bounds the error (the core's two-pass float32 is no better)
    assert np.median(error / reference) < 0.02
    assert error.max() < 0.1 * reference.mean()
    core_error = np.abs(lfa.view_moments(lf, 0.8).variance[..., 0] - reference)
    assert error.max() < 2 * core_error.max()


@pytest.mark.parametrize("shift", [0.0, 0.25, -0.75, 3.5, -7.0, 40.0])
def test_tap_profile_is_the_core_sampling_weight(shift):
    _, weight = bilinear_shift(np.ones((1, 30), np.float32), 0.0, shift)
    np.testing.assert_allclose(tap_profile(30, shift), weight[0], atol=1e-7)


def test_weighted_or_lazy_light_fields_are_not_taken():
    data = np.ones((2, 2, 8, 8, 1), np.float32)
    weighted = lfa.LightField(data, weights=np.full((2, 2, 8, 8), 0.5, np.float32))
    assert not LivePreview.supports(weighted)
    with pytest.raises(ValueError, match="without sample weights"):
        LivePreview(weighted)
    assert LivePreview.supports(lfa.LightField(data))
