"""The widget's session: the exact Cv it shows, and its caches (no viewer needed)."""

import numpy as np
import pytest

import napari_lfalias as lfa
from napari_lfalias._napari._session import AliasingSession, DetectionParams, exact_detection

pytestmark = pytest.mark.napari


def _textured(shape, seed=0):
    rng = np.random.default_rng(seed)
    return lfa.LightField(rng.random(shape, dtype=np.float32))


def _run(generator):
    """Drive a session job to its end (as a worker would) and return its result."""
    steps = []
    try:
        while True:
            steps.append(next(generator))
    except StopIteration as stop:
        return stop.value, steps


def test_exact_cv_is_the_limit_of_many_random_patterns():
    # Algorithm 1 by brute force: N random k-subsets (k uniform on
    # ceil((1-gamma) n) .. n), Cv = population std / mean of their refocused luminance.
    lf = _textured((3, 3, 12, 12, 3), seed=6)
    slope, gamma, n_patterns = 0.6, 0.3, 20000
    luminance = lf.luminance()
    stack = lfa.shift_views(luminance, slope)
    n = stack.n_views
    rng = np.random.default_rng(0)
    low = int(np.ceil((1 - gamma) * n))
    refocused = []
    for _ in range(n_patterns):
        k = rng.integers(low, n + 1)
        pattern = np.zeros(n, np.float32)
        pattern[rng.choice(n, k, replace=False)] = 1
        refocused.append(stack.mean(pattern)[..., 0])
    refocused = np.array(refocused, np.float64)
    monte_carlo = refocused.std(axis=0) / refocused.mean(axis=0)
    moments = lfa.view_moments(luminance, slope)
    exact = exact_detection(moments, DetectionParams(gamma=gamma, threshold=0.02)).cv
    inside = (slice(1, -1), slice(1, -1))  # every view sees the interior
    np.testing.assert_allclose(exact[inside], monte_carlo[inside], rtol=0.05)
    assert np.abs(exact[inside] - monte_carlo[inside]).mean() < 0.02 * monte_carlo[inside].mean()


def test_session_focus_is_the_api_refocus_and_keeps_its_moments():
    lf = _textured((4, 4, 20, 24, 3), seed=7)
    session = AliasingSession(lf)
    params = DetectionParams(gamma=0.25)
    (image, detection), steps = _run(session.focus(0.8, params))
    assert steps and all(done <= total for done, total in steps)
    np.testing.assert_allclose(image, lfa.refocus(lf, 0.8), atol=1e-6)
    moments = lfa.view_moments(lf.luminance(), 0.8)
    np.testing.assert_allclose(detection.cv, exact_detection(moments, params).cv, rtol=1e-5, atol=1e-7)
    # T only re-thresholds; gamma re-detects from the kept moments
    kept = session._moments
    other = session.cached_detection(0.8, DetectionParams(gamma=0.25, threshold=0.05))
    np.testing.assert_array_equal(other.mask, detection.cv > 0.05)
    (_, regamma), _ = _run(session.focus(0.8, DetectionParams(gamma=0.5)))
    assert session._moments is kept
    assert not np.allclose(regamma.cv, detection.cv)


def test_exact_factor_falls_with_gamma_and_is_zero_for_one_view():
    lf = _textured((3, 3, 8, 8, 1), seed=8)
    moments = lfa.view_moments(lf, 0.0)
    low = exact_detection(moments, DetectionParams(gamma=0.1)).cv
    high = exact_detection(moments, DetectionParams(gamma=0.6)).cv
    assert np.all(high >= low) and high.mean() > low.mean()
    single = lfa.LightField(lf.data[:1, :1])
    assert not exact_detection(lfa.view_moments(single, 0.0), DetectionParams()).cv.any()
