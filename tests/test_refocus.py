"""Refocus, shifted stacks, view moments and bilinear shifts against independent float64 references."""

import numpy as np
import pytest

import napari_lfalias as lfa
from napari_lfalias import LightField, ParameterError, refocus, shift_views, view_moments
from napari_lfalias.refocus import ShiftedStack, ViewMoments, bilinear_shift


def bilinear64(image, dy, dx):
    """Float64 reference: taps of ``(y + dy, x + dx)``, zero outside; returns (tap sum, tap weight)."""
    n_rows, n_cols = image.shape[:2]
    y = np.arange(n_rows)[:, None] + dy
    x = np.arange(n_cols)[None, :] + dx
    y0, x0 = np.floor(y).astype(int), np.floor(x).astype(int)
    fy, fx = y - y0, x - x0
    num = np.zeros(image.shape, np.float64)
    den = np.zeros((n_rows, n_cols), np.float64)
    for oy, wy in ((0, 1 - fy), (1, fy)):
        for ox, wx in ((0, 1 - fx), (1, fx)):
            yy, xx = y0 + oy, x0 + ox
            inside = (yy >= 0) & (yy < n_rows) & (xx >= 0) & (xx < n_cols)
            w = np.where(inside, wy * wx, 0.0)
            num += w[..., None] * image[np.clip(yy, 0, n_rows - 1), np.clip(xx, 0, n_cols - 1)].astype(np.float64)
            den += w
    return num, den


def stack64(lf, slope):
    """Float64 shifted values (n, Y, X, C) and weights (n, Y, X), honouring per-sample weights."""
    views = lf.views().astype(np.float64)
    sample_weights = lf.flat_weights()
    values, weights = [], []
    for i, (dy, dx) in enumerate(slope * lf.flat_positions()):
        w = np.ones(lf.image_shape) if sample_weights is None else sample_weights[i].astype(np.float64)
        num, _ = bilinear64(views[i] * w[..., None], dy, dx)
        den, _ = bilinear64(w[..., None], dy, dx)
        den = den[..., 0]
        values.append(np.divide(num, den[..., None], out=np.zeros_like(num), where=den[..., None] > 0))
        weights.append(den)
    return np.array(values), np.array(weights)


def moments64(lf, slope):
    values, weights = stack64(lf, slope)
    wsum = weights.sum(axis=0)
    safe = np.where(wsum > 0, wsum, 1)[..., None]
    mean = (weights[..., None] * values).sum(axis=0) / safe
    var = (weights[..., None] * (values - mean) ** 2).sum(axis=0) / safe
    return mean, var, wsum


@pytest.fixture
def random_lf():
    rng = np.random.default_rng(3)
    return LightField(rng.random((3, 4, 23, 31, 3), dtype=np.float32))


def irregular_positions(shape, seed=5):
    rng = np.random.default_rng(seed)
    return rng.normal(scale=1.5, size=shape + (2,))


# -- exactness -----------------------------------------------------------------

@pytest.mark.parametrize("disparity", [1, 2, -1])
def test_plane_is_reproduced_exactly_at_its_disparity(disparity):
    # views of a fronto-parallel plane: view q shows the texture at p - d*q
    rng = np.random.default_rng(disparity + 10)
    n_views, size, margin = 5, 40, 2 * 2 * abs(disparity) + 2
    texture = rng.random((size + 2 * margin, size + 2 * margin, 3)).astype(np.float32)
    positions = lfa.regular_positions(n_views, n_views)  # integer positions
    data = np.empty((n_views, n_views, size, size, 3), np.float32)
    for u in range(n_views):
        for v in range(n_views):
            oy, ox = (margin - disparity * positions[u, v]).astype(int)
            data[u, v] = texture[oy:oy + size, ox:ox + size]
    image = refocus(LightField(data, positions), disparity)
    np.testing.assert_allclose(image, texture[margin:margin + size, margin:margin + size], atol=1e-5, rtol=0)
    # any other slope blurs the plane
    assert np.abs(refocus(LightField(data, positions), disparity + 0.5) - image).max() > 0.1


@pytest.mark.parametrize("slope", [0.0, 0.37, -1.5, 2.0, 9.3])
@pytest.mark.parametrize("irregular", [False, True])
def test_constant_light_field_refocuses_to_the_constant_borders_included(slope, irregular):
    data = np.full((3, 4, 17, 21, 3), 0.625, np.float32)
    positions = irregular_positions((3, 4)) if irregular else None
    lf = LightField(data, positions)
    image = refocus(lf, slope)
    seen = view_moments(lf, slope).weight_sum > 0
    assert seen[seen.shape[0] // 2, seen.shape[1] // 2]
    np.testing.assert_allclose(image[seen], 0.625, atol=1e-6)
    np.testing.assert_array_equal(image[~seen], 0.0)
    if slope in (0.0, 0.37, -1.5):
        assert seen.all()  # small shifts: every pixel is seen by some view, borders too


def test_refocus_matches_float64_reference_irregular_positions(random_lf):
    lf = LightField(random_lf.data, irregular_positions(random_lf.grid_shape))
    for slope in (0.0, 0.8, -2.45):
        values, weights = stack64(lf, slope)
        num = (weights[..., None] * values).sum(axis=0)
        den = weights.sum(axis=0)[..., None]
        truth = np.divide(num, den, out=np.zeros_like(num), where=den > 0)
        np.testing.assert_allclose(refocus(lf, slope), truth, atol=2e-6, rtol=0)


def test_shift_views_matches_float64_reference(random_lf):
    values, weights = stack64(random_lf, 1.7)
    stack = shift_views(random_lf, 1.7)
    assert isinstance(stack, ShiftedStack) and stack.slope == 1.7 and stack.n_views == 12
    np.testing.assert_allclose(stack.values, values, atol=2e-6, rtol=0)
    np.testing.assert_allclose(stack.weights, weights, atol=1e-6, rtol=0)
    np.testing.assert_array_equal(stack.positions, random_lf.flat_positions())
    np.testing.assert_allclose(stack.mean(), refocus(random_lf, 1.7), atol=1e-6)


def test_weighted_borders_ignore_unobserved_samples():
    rng = np.random.default_rng(8)
    shape = (3, 3, 20, 24)
    weights = rng.uniform(0.2, 1.0, shape).astype(np.float32)
    weights[rng.random(shape) < 0.3] = 0.0
    weights[1, 1, :, :3] = 0.0  # the centre view has no samples along its left border
    data = np.full(shape + (3,), 0.4, np.float32)
    data[weights == 0] = 50.0  # garbage where nothing was observed
    lf = LightField(data, weights=weights)
    for slope in (0.0, 1.25, -0.6):
        image = refocus(lf, slope)
        moments = view_moments(lf, slope)
        seen = moments.weight_sum > 0
        np.testing.assert_allclose(image[seen], 0.4, atol=1e-6)
        np.testing.assert_allclose(moments.variance[seen], 0.0, atol=1e-10)
        np.testing.assert_allclose(shift_views(lf, slope).mean()[seen], 0.4, atol=1e-6)
    # against the float64 reference on varied data
    lf = LightField(rng.random(shape + (3,), dtype=np.float32), weights=weights)
    values, w = stack64(lf, 0.9)
    truth = (w[..., None] * values).sum(0) / np.maximum(w.sum(0), 1e-30)[..., None]
    seen = w.sum(0) > 0
    np.testing.assert_allclose(refocus(lf, 0.9)[seen], truth[seen], atol=2e-6)


def test_views_with_zero_weight_equal_refocus_without_them():
    rng = np.random.default_rng(9)
    data = rng.random((3, 3, 16, 16, 1), dtype=np.float32)
    weights = np.ones((3, 3, 16, 16), np.float32)
    weights[0] = 0.0
    weighted = LightField(data, weights=weights)
    np.testing.assert_allclose(refocus(weighted, 1.4), refocus(LightField(data).subset(rows=slice(1, 3)), 1.4),
                               atol=1e-6)


# -- stacks and moments ------------------------------------------------------

def test_stack_mean_with_view_weights_equals_refocus_of_the_subset(random_lf):
    stack = shift_views(random_lf, -1.3)
    mask = np.zeros(random_lf.grid_shape)
    mask[1:, 1:3] = 1
    expected = refocus(random_lf.subset(rows=slice(1, 3), cols=slice(1, 3)), -1.3)
    np.testing.assert_allclose(stack.mean(mask.ravel()), expected, atol=1e-6)
    # fractional view weights are a weighted mean
    a = np.linspace(0.1, 1.0, stack.n_views)
    w = stack.weights * a[:, None, None]
    truth = (w[..., None] * stack.values).sum(0) / w.sum(0)[..., None]
    np.testing.assert_allclose(stack.mean(a), truth, atol=1e-6)


def test_stack_mean_rejects_bad_view_weights(random_lf):
    stack = shift_views(random_lf, 0.5)
    for bad in (np.ones(3), -np.ones(stack.n_views), np.full(stack.n_views, np.nan)):
        with pytest.raises(ParameterError, match="view_weights"):
            stack.mean(bad)


@pytest.mark.parametrize("channels", [1, 3])
def test_view_moments_match_float64_reference(channels):
    rng = np.random.default_rng(channels)
    lf = LightField(rng.random((4, 3, 19, 26, channels), dtype=np.float32), irregular_positions((4, 3)))
    for slope in (0.0, 1.1, -3.7):
        mean, var, wsum = moments64(lf, slope)
        moments = view_moments(lf, slope)
        assert isinstance(moments, ViewMoments)
        np.testing.assert_allclose(moments.mean, mean, atol=2e-6)
        np.testing.assert_allclose(moments.variance, var, atol=2e-6)
        np.testing.assert_allclose(moments.weight_sum, wsum, atol=1e-5)
        np.testing.assert_array_equal(moments.count, (stack64(lf, slope)[1] > 0).sum(0))
        again = view_moments(lf, slope, stack=shift_views(lf, slope))
        np.testing.assert_allclose(again.variance, var, atol=2e-6)
        np.testing.assert_allclose(again.mean, mean, atol=2e-6)


def test_view_moments_keep_precision_on_a_large_offset():
    rng = np.random.default_rng(11)
    small = rng.normal(scale=1e-3, size=(4, 4, 12, 15, 1))
    lf = LightField((1000.0 + small).astype(np.float32))
    _, var, _ = moments64(lf, 0.6)
    moments = view_moments(lf, 0.6)
    assert var.mean() > 1e-7  # the variations survive the float32 storage
    np.testing.assert_allclose(moments.variance, var, rtol=1e-3, atol=1e-10)
    # the naive one-pass formula in float32 is useless here (what the kernel avoids)
    values = shift_views(lf, 0.6).values
    naive = (values ** 2).mean(0) - values.mean(0) ** 2
    assert np.abs(naive - var).max() > 10 * np.abs(moments.variance - var).max()


def test_bilinear_shift_matches_float64_reference():
    rng = np.random.default_rng(2)
    image = rng.random((14, 9, 3)).astype(np.float32)
    for dy, dx in ((0.0, 0.0), (1.25, -0.5), (-13.5, 2.0), (3.0, 20.0)):
        sampled, weight = bilinear_shift(image, dy, dx)
        num, den = bilinear64(image, dy, dx)
        np.testing.assert_allclose(sampled, num, atol=1e-6)
        np.testing.assert_allclose(weight, den, atol=1e-6)
    grey, weight = bilinear_shift(image[..., 0], 0.3, 0.6)
    assert grey.shape == weight.shape == (14, 9)
    with pytest.raises(ParameterError, match="dy"):
        bilinear_shift(image, np.inf, 0)


def test_lazy_light_field_gives_the_same_result(random_lf):
    da = pytest.importorskip("dask.array")
    lazy = LightField(da.from_array(random_lf.data, chunks=(1, 1, 23, 31, 3)))
    np.testing.assert_array_equal(refocus(lazy, 0.7), refocus(random_lf, 0.7))


@pytest.mark.parametrize("slope", [np.nan, np.inf, "1", None])
def test_bad_slope_is_a_parameter_error(random_lf, slope):
    with pytest.raises(ParameterError, match="slope"):
        refocus(random_lf, slope)
    with pytest.raises(ParameterError, match="slope"):
        view_moments(random_lf, slope)


def test_not_a_light_field_is_a_parameter_error():
    with pytest.raises(ParameterError, match="LightField"):
        refocus(np.zeros((2, 2, 4, 4, 1)), 0.0)
