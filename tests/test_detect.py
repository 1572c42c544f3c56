"""Aliasing detection (Algorithm 1): exact and Monte-Carlo Cv, numerics, skipping, parameters."""

import functools
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import napari_lfalias as lfa
from napari_lfalias import detect as detect_module
from napari_lfalias.detect import AliasingDetector, sampling_patterns, smallest_subset, variance_factors
from napari_lfalias.errors import ParameterError
from napari_lfalias.lightfield import REC709
from napari_lfalias.pyramid import lightfield_pyramid
from napari_lfalias.synthetic import brick_room, textureless_plane

#: These tests are about the paper's Cv (Algorithm 1): the detection method is the exact Cv unless a
#: test names another (the package's default is the disparity-guided method, tested in test_depth_guided).
detect_cv = functools.partial(lfa.detect_aliasing, method="analytic")


@pytest.fixture(scope="module")
def room():
    return brick_room(n_views=5, size=64, seed=0).lightfield


def random_lf(shape=(4, 4, 24, 28, 3), seed=0, offset=0.0, scale=1.0):
    rng = np.random.default_rng(seed)
    return lfa.LightField(offset + scale * rng.random(shape))


def float64_cv(lf, slope, gamma, dark_floor=0.0):
    """The exact Cv in float64 numpy, from the formula (interior pixels), for comparison."""
    views = lf.views().astype(np.float64) @ REC709.astype(np.float64) if lf.n_channels == 3 else \
        lf.views()[..., 0].astype(np.float64)
    shifted = lfa.shift_views(lfa.LightField(views.reshape(lf.grid_shape + views.shape[1:])), slope)
    values = shifted.values[..., 0].astype(np.float64)
    n = lf.n_views
    mean = values.mean(axis=0)
    variance = ((values - mean) ** 2).mean(axis=0)
    k = np.arange(smallest_subset(n, gamma), n + 1)
    factor = (n * np.mean(1.0 / k) - 1) / (n - 1)
    return np.sqrt(factor * variance) / np.maximum(mean, dark_floor)


# -- the statistics --------------------------------------------------------------------


def test_variance_factor_of_a_fully_seen_pixel_is_the_finite_population_formula():
    for n, gamma in [(64, 0.2), (81, 0.2), (25, 0.5), (9, 0.05)]:
        k = np.arange(smallest_subset(n, gamma), n + 1)
        expected = (n * np.mean(1.0 / k) - 1) / (n - 1)
        assert variance_factors(n, gamma)[n] == pytest.approx(expected, rel=1e-12)


def test_variance_factor_of_a_partly_seen_pixel_matches_sampled_patterns():
    """A border pixel seen by 5 of 16 views: the hypergeometric factor against 200k patterns."""
    n, n_seen, gamma = 16, 5, 0.4
    rng = np.random.default_rng(1)
    x = rng.random(n_seen)
    patterns = sampling_patterns(n, gamma, 200_000, seed=2)[:, :n_seen]
    kept = patterns.sum(axis=1)
    means = (patterns @ x)[kept > 0] / kept[kept > 0]
    assert means.var() / x.var() == pytest.approx(variance_factors(n, gamma)[n_seen], rel=0.02)


def test_sampling_patterns_keep_between_ceil_1_minus_gamma_n_and_n_views():
    patterns = sampling_patterns(64, 0.2, 2000, seed=0)
    sizes = patterns.sum(axis=1)
    assert sizes.min() == 52 and sizes.max() == 64
    # k is uniform on 52..64: every size appears, none dominates
    counts = np.bincount(sizes.astype(int))[52:]
    assert counts.min() > 0.5 * 2000 / 13
    # every view is dropped about equally often
    assert np.ptp(patterns.mean(axis=0)) < 0.08
    np.testing.assert_array_equal(patterns, sampling_patterns(64, 0.2, 2000, seed=0))


# -- exact Cv: numerics ---------------------------------------------------------------------


def test_constant_light_field_has_zero_cv_everywhere():
    lf = lfa.LightField(np.full((4, 4, 20, 20, 3), 0.3, np.float32))
    for method in ("analytic", "monte_carlo"):
        det = detect_cv(lf, 1.7, method=method, seed=0, skip_flat=False)
        assert np.all(det.cv == 0) and not det.mask.any()


def test_black_pixels_have_a_finite_cv_and_noise_in_the_dark_is_no_alarm():
    rng = np.random.default_rng(0)
    data = np.zeros((5, 5, 32, 32, 1), np.float32)
    data[:, :, :16] = 0.8 * rng.random((5, 5, 16, 32, 1))  # bright textured top half
    data[:, :, 16:24] = rng.integers(0, 2, (5, 5, 8, 32, 1)) / 255.0  # 8-bit noise in the dark
    det = detect_cv(lfa.LightField(data), 0.0, skip_flat=False)
    assert np.all(np.isfinite(det.cv))
    assert np.all(det.cv[24:] == 0)  # black
    assert not det.mask[16:24].any()
    assert det.mask[:16].any()  # the textured half does alias: the test could fail


@pytest.mark.parametrize("method", ["analytic", "monte_carlo"])
def test_scaling_the_data_leaves_cv_unchanged(method):
    lf = random_lf()
    base = detect_cv(lf, 0.6, method=method, seed=3, skip_flat=False)
    scaled = detect_cv(lfa.LightField(lf.data * 37.5), 0.6, method=method, seed=3, skip_flat=False)
    np.testing.assert_allclose(scaled.cv, base.cv, rtol=1e-5, atol=1e-7)


def test_exact_cv_matches_a_float64_reference():
    lf = random_lf(seed=4)
    det = detect_cv(lf, -0.8, gamma=0.3, skip_flat=False, dark_floor=0.0)
    reference = float64_cv(lf, -0.8, 0.3)
    inner = np.s_[3:-3, 3:-3]  # where every view sees the pixel
    np.testing.assert_allclose(det.cv[inner], reference[inner], rtol=1e-4)


def test_float32_and_float64_input_agree():
    data = np.random.default_rng(5).random((3, 4, 20, 22, 1))
    a = detect_cv(lfa.LightField(data), 1.1, skip_flat=False)
    b = detect_cv(lfa.LightField(data.astype(np.float32)), 1.1, skip_flat=False)
    np.testing.assert_allclose(a.cv, b.cv, rtol=1e-4, atol=1e-7)


@pytest.mark.parametrize("method", ["analytic", "monte_carlo"])
def test_a_large_offset_keeps_its_precision(method):
    """1000 + variations of 1e-2 (Cv ~ 1e-7): the float32 data hold them; Cv must keep them.

    The reference is Eq. 7 in float64 on the very float32 samples the light
    field holds (slope 0: no resampling), so only the algorithm's own
    rounding is measured. ``E[x^2] - E[x]^2`` in float32 would lose every digit.
    """
    rng = np.random.default_rng(6)
    lf = lfa.LightField(1000.0 + 0.01 * rng.random((4, 4, 16, 16, 1)))
    det = detect_cv(lf, 0.0, method=method, seed=1, skip_flat=False, dark_floor=0.0)
    samples = lf.views()[..., 0].reshape(lf.n_views, -1).astype(np.float64)  # (n, P)
    if method == "analytic":
        factor = variance_factors(lf.n_views, 0.2)[lf.n_views]
        expected = np.sqrt(factor * samples.var(axis=0)) / samples.mean(axis=0)
    else:
        patterns = sampling_patterns(lf.n_views, 0.2, 100, seed=1).astype(np.float64)
        means = patterns @ samples / patterns.sum(axis=1, keepdims=True)
        expected = means.std(axis=0) / means.mean(axis=0)
    assert 1e-8 < expected.min() and expected.max() < 1e-6
    np.testing.assert_allclose(det.cv.ravel(), expected, rtol=1e-3)


# -- Monte Carlo --------------------------------------------------------------------------


def test_monte_carlo_equals_the_papers_loop_over_patterns(room):
    """Refocus once per pattern from the shifted stack (the paper's loop) and take Eq. 7 in float64."""
    slope, n_patterns = 1.3, 30
    det = detect_cv(room, slope, method="monte_carlo", n_patterns=n_patterns, seed=3,
                              skip_flat=False, dark_floor=0.0)
    stack = lfa.shift_views(room, slope)
    patterns = sampling_patterns(room.n_views, 0.2, n_patterns, seed=3)
    images = np.stack([stack.mean(p).astype(np.float64) @ REC709 for p in patterns])
    expected = images.std(axis=0) / images.mean(axis=0)
    np.testing.assert_allclose(det.cv, expected, rtol=1e-4, atol=1e-7)


def test_same_seed_same_result_other_seed_other_result(room):
    kwargs = dict(method="monte_carlo", n_patterns=20, skip_flat=False)
    a = detect_cv(room, 2.0, seed=11, **kwargs)
    b = detect_cv(room, 2.0, seed=11, **kwargs)
    c = detect_cv(room, 2.0, seed=12, **kwargs)
    np.testing.assert_array_equal(a.cv, b.cv)
    assert np.abs(a.cv - c.cv).max() > 0


def test_monte_carlo_converges_to_the_exact_cv_with_the_predicted_spread(room):
    """The relative error of a std estimated from N samples is about 1/sqrt(2 (N - 1)).

    That is the normal-theory value; the means of random subsets of random
    size k (k = n among them, with no spread at all) have heavier tails than
    a normal, which widens it by a constant factor (measured 1.2-1.3 here).
    The 1/sqrt(N) law itself must hold closely.
    """
    slope = 4.0
    exact = detect_cv(room, slope, skip_flat=False)
    textured = exact.cv > 0.2 * exact.cv.max()
    spreads = {}
    for n_patterns in (20, 200):
        errors = []
        for seed in range(4):
            mc = detect_cv(room, slope, method="monte_carlo", n_patterns=n_patterns, seed=seed,
                                     skip_flat=False)
            errors.append((mc.cv[textured] - exact.cv[textured]) / exact.cv[textured])
        errors = np.concatenate(errors)
        spreads[n_patterns] = errors.std()
        predicted = 1 / math.sqrt(2 * (n_patterns - 1))
        assert 0.9 < spreads[n_patterns] / predicted < 1.5
        assert abs(np.median(errors)) < 0.5 * predicted  # centred on the exact value
    assert spreads[200] / spreads[20] == pytest.approx(math.sqrt(19 / 199), rel=0.15)


# -- what T means -----------------------------------------------------------------------


def test_angular_scale_does_not_depend_on_the_number_of_views():
    scene5, scene9 = (brick_room(n_views=n, size=48, seed=0).lightfield for n in (5, 9))
    det5 = detect_cv(scene5, 0.0, skip_flat=False)
    det9 = detect_cv(scene9, 0.0, skip_flat=False)
    ratio = math.sqrt(variance_factors(81, 0.2)[81] / variance_factors(25, 0.2)[25])
    inner = np.s_[12:-12, 12:-12]
    # Both arrays span the same scene; their Cv differ by sqrt(c), their angular Cv much less.
    cv_ratio = np.median(det9.cv[inner]) / np.median(det5.cv[inner])
    angular_ratio = np.median(det9.angular_cv[inner]) / np.median(det5.angular_cv[inner])
    assert abs(np.log(angular_ratio)) < 0.5 * abs(np.log(cv_ratio)) and ratio < 0.95
    angular = detect_cv(scene5, 0.0, threshold=0.3, threshold_scale="angular", skip_flat=False)
    np.testing.assert_array_equal(angular.mask, angular.angular_cv > 0.3)
    np.testing.assert_allclose(angular.angular_cv * angular.cv_scale, angular.cv, rtol=1e-6)


def test_rethreshold_equals_a_new_detection(room):
    det = detect_cv(room, 4.0, threshold=0.01)
    higher = det.rethreshold(0.03)
    np.testing.assert_array_equal(higher.mask, detect_cv(room, 4.0, threshold=0.03).mask)
    np.testing.assert_array_equal(higher.cv, det.cv)


def test_rethreshold_below_a_skipped_tile_asks_for_a_new_detection():
    lf = textureless_plane(n_views=5, size=256, seed=0).lightfield
    det = detect_cv(lf, 0.0, threshold=0.02)
    assert not det.evaluated.all()
    with pytest.raises(ParameterError, match="threshold"):
        det.rethreshold(1e-9)
    full = detect_cv(lf, 0.0, threshold=0.02, skip_flat=False)
    np.testing.assert_array_equal(full.rethreshold(1e-9).mask, full.cv > 1e-9)


# -- skipping ---------------------------------------------------------------------------


@pytest.mark.parametrize("method", ["analytic", "monte_carlo"])
def test_skipped_tiles_are_flat_and_change_no_decision(method):
    lf = textureless_plane(n_views=5, size=256, seed=0, wall_disparity=0.0, object_disparity=2.0).lightfield
    kwargs = dict(method=method, seed=0, n_patterns=20)
    skipped = detect_cv(lf, 2.0, **kwargs)
    full = detect_cv(lf, 2.0, skip_flat=False, **kwargs)
    assert 0.3 < skipped.evaluated.mean() < 0.9  # the wall is skipped, the object is not
    np.testing.assert_array_equal(skipped.mask, full.mask)
    np.testing.assert_array_equal(skipped.cv[skipped.evaluated], full.cv[skipped.evaluated])
    assert full.cv[~skipped.evaluated].max() <= 0.02


def test_flat_tiles_are_skipped_only_where_it_pays():
    from napari_lfalias.detect import AliasingDetector

    # a flat column and row of a small image: the runs left would cost more than one whole pass
    lf = textureless_plane(n_views=5, size=192, seed=0).lightfield
    detector = AliasingDetector(lf)
    assert detector._provably_flat(0, 0.0, 0.02, "cv", "analytic", 0.2).any()
    det = detector.detect(0.0, method="analytic")
    assert det.evaluated.all()
    np.testing.assert_array_equal(det.mask, detect_cv(lf, 0.0, skip_flat=False).mask)
    # provably flat tiles between textured ones, one tile wide: computed rather than split around
    rng = np.random.default_rng(1)
    data = np.full((3, 3, 128, 512, 1), 0.5, np.float32)
    for start in range(0, 512, 128):  # a textured tile column, then three flat ones
        data[:, :, :, start:start + 32] += 0.4 * rng.random((3, 3, 128, 32, 1), dtype=np.float32)
    striped = lfa.LightField(data)
    detector = AliasingDetector(striped)
    flat = detector._provably_flat(0, 0.0, 0.02, "cv", "analytic", 0.2)
    assert flat[:, 2::4].all() and not flat[:, 0::4].any()  # between textured columns, provably flat
    assert detector.detect(0.0, method="analytic").evaluated.all()
    # Monte Carlo evaluates pixel by pixel: there every flat tile is skipped
    assert not detect_cv(striped, 0.0, method="monte_carlo", n_patterns=4, seed=0).evaluated.all()


def test_a_textured_scene_is_not_skipped(room):
    det = detect_cv(room, -4.0, threshold=0.001)
    assert det.evaluated.all()


# -- pyramid levels and regions ---------------------------------------------------------------


def test_detection_on_a_level_is_detection_on_that_pyramid_level(room):
    slope = 3.0
    det = detect_cv(room, slope, level=1, skip_flat=False)
    level1 = lightfield_pyramid(room.luminance(), 1)[1]
    direct = detect_cv(level1, slope / 2, skip_flat=False)
    assert det.cv.shape == (32, 32) and det.level == 1
    np.testing.assert_allclose(det.cv, direct.cv, rtol=1e-5, atol=1e-7)


def test_region_limits_the_evaluated_pixels(room):
    region = np.zeros(room.image_shape, bool)
    region[10:20, 30:50] = True
    det = AliasingDetector(room, skip_flat=False).detect(4.0, region=region, method="analytic")
    full = detect_cv(room, 4.0, skip_flat=False)
    np.testing.assert_array_equal(det.evaluated, region)
    np.testing.assert_array_equal(det.cv[region], full.cv[region])
    assert not det.mask[~region].any()


def test_a_detector_reuses_moments_and_stacks_when_only_gamma_or_n_change(room, monkeypatch):
    calls = []
    run = detect_module._run
    monkeypatch.setattr(detect_module, "_run", lambda name, *a: (calls.append(name), run(name, *a)))
    shifts = []
    shift = detect_module.shift_views
    monkeypatch.setattr(detect_module, "shift_views", lambda *a: (shifts.append(a[1]), shift(*a))[1])
    detector = AliasingDetector(room, skip_flat=False)
    detector.detect(2.0, gamma=0.2, method="analytic")
    detector.detect(2.0, gamma=0.4, method="analytic")
    assert calls.count("moments") == 1
    detector.detect(2.0, method="monte_carlo", n_patterns=10, seed=0)
    detector.detect(2.0, method="monte_carlo", n_patterns=50, gamma=0.3, seed=1)
    assert shifts == [2.0]
    detector.detect(2.5, method="analytic")
    assert calls.count("moments") == 2


# -- parameters and properties ----------------------------------------------------------------


@pytest.mark.parametrize(
    "kwargs, word",
    [
        (dict(gamma=0.0), "gamma"), (dict(gamma=1.0), "gamma"), (dict(gamma=float("nan")), "gamma"),
        (dict(n_patterns=1), "n_patterns"), (dict(n_patterns=2.5), "n_patterns"),
        (dict(threshold=0.0), "threshold"), (dict(threshold=-1.0), "threshold"),
        (dict(method="exact"), "method"), (dict(seed=-1), "seed"), (dict(level=-1), "level"),
        (dict(threshold_scale="relative"), "threshold_scale"), (dict(luminance="mean"), "luminance"),
        (dict(dark_floor=-0.1), "dark_floor"),
    ],
)
def test_bad_parameters_are_parameter_errors_naming_the_parameter(room, kwargs, word):
    with pytest.raises(ParameterError, match=word):
        detect_cv(room, 1.0, **kwargs)


@pytest.mark.parametrize("slope", [float("inf"), float("nan"), "1"])
def test_bad_slope_is_a_parameter_error(room, slope):
    with pytest.raises(ParameterError, match="slope"):
        detect_cv(room, slope)


def test_not_a_light_field_is_a_parameter_error():
    with pytest.raises(ParameterError, match="LightField"):
        detect_cv(np.zeros((2, 2, 8, 8)), 0.0)


def test_per_channel_max_is_at_least_the_luminance_cv(room):
    lum = detect_cv(room, 3.0, skip_flat=False)
    per_channel = detect_cv(room, 3.0, luminance="max", skip_flat=False)
    # Each channel's Cv against the luminance's: a weighted mean of the channels varies less.
    assert np.median(per_channel.cv) >= np.median(lum.cv)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    grid=st.tuples(st.integers(1, 4), st.integers(1, 4)),
    size=st.tuples(st.integers(1, 40), st.integers(1, 40)),
    channels=st.sampled_from([1, 3]),
    slope=st.floats(-6, 6, allow_nan=False),
    gamma=st.floats(0.01, 0.99),
    n_patterns=st.integers(2, 40),
    threshold=st.floats(1e-4, 2.0),
    method=st.sampled_from(["analytic", "monte_carlo"]),
    level=st.integers(0, 3),
    skip=st.booleans(),
    seed=st.integers(0, 2**31),
)
def test_properties_over_random_inputs(grid, size, channels, slope, gamma, n_patterns, threshold, method,
                                       level, skip, seed):
    rng = np.random.default_rng(seed)
    data = rng.random(grid + size + (channels,), dtype=np.float32) * rng.choice([1e-3, 1.0, 500.0])
    lf = lfa.LightField(data)
    det = detect_cv(lf, slope, gamma=gamma, n_patterns=n_patterns, threshold=threshold,
                              method=method, seed=seed, level=level, skip_flat=skip)
    assert det.cv.dtype == np.float32 and det.mask.dtype == np.bool_
    assert np.all(np.isfinite(det.cv)) and det.cv.min() >= 0
    np.testing.assert_array_equal(det.mask, det.cv > np.float32(threshold))
    assert det.cv.shape == lightfield_pyramid(lf, level)[level].image_shape
