"""Lazy slope sweeps (``lfa.refocus_sweep``) and the disparity-range estimate."""

import importlib
import os

import dask.array as da
import numpy as np
import pytest

import napari_lfalias as lfa
from napari_lfalias.errors import ParameterError
from napari_lfalias.sweep import estimate_slope_range

from _cli_scenes import plane_lightfield

# The module, not the function the package exports under the same name.
refocus_module = importlib.import_module("napari_lfalias.refocus")

SLOPES = [-1.0, 0.0, 0.5, 1.0]


@pytest.fixture(scope="module")
def lf():
    return plane_lightfield(n=5, size=40, disparity=1, channels=3, seed=1)


def test_refocus_sweep_is_one_lazy_chunk_per_slope(lf):
    sweep = lfa.refocus_sweep(lf, SLOPES)
    assert isinstance(sweep, da.Array)
    assert sweep.shape == (4, 40, 40, 3) and sweep.dtype == np.float32
    assert sweep.chunks[0] == (1, 1, 1, 1)
    assert sweep.chunks[1:] == ((40,), (40,), (3,))


def test_each_plane_is_the_refocus_at_its_slope(lf):
    planes = lfa.refocus_sweep(lf, SLOPES).compute()
    for plane, slope in zip(planes, SLOPES):
        np.testing.assert_array_equal(plane, lfa.refocus(lf, slope))
    # The plane is in focus at its disparity: least variation from the centre view there.
    centre = lf.data[2, 2, 4:-4, 4:-4]
    errors = [np.abs(p[4:-4, 4:-4] - centre).mean() for p in planes]
    assert int(np.argmin(errors)) == SLOPES.index(1.0)


@pytest.fixture
def refocus_calls(monkeypatch):
    """The slopes ``refocus`` is called with, in order."""
    calls = []
    original = refocus_module.refocus

    def counting(light_field, slope):
        calls.append(slope)
        return original(light_field, slope)

    monkeypatch.setattr(refocus_module, "refocus", counting)
    return calls


def test_a_slice_computes_only_its_own_slope(lf, refocus_calls):
    calls = refocus_calls
    sweep = lfa.refocus_sweep(lf, SLOPES)
    assert calls == []
    sweep[2].compute()
    assert calls == [0.5]


def test_sweep_of_a_lazy_light_field(lf):
    lazy = lfa.LightField(da.from_array(lf.data, chunks=(1, 1, 40, 40, 3)), lf.positions)
    plane = lfa.refocus_sweep(lazy, [0.5])[0].compute()
    np.testing.assert_array_equal(plane, lfa.refocus(lf, 0.5))


@pytest.mark.parametrize("what", ["cv", "mask"])
def test_cv_and_mask_sweeps_match_detect_aliasing(lf, what):
    options = {"gamma": 0.2, "threshold": 0.02, "method": "analytic"}
    sweep = lfa.refocus_sweep(lf, SLOPES, what=what, **options)
    assert sweep.shape == (4, 40, 40)
    assert sweep.dtype == (np.float32 if what == "cv" else np.bool_)
    for i, slope in enumerate(SLOPES):
        expected = getattr(lfa.detect_aliasing(lf, slope, **options), what)
        np.testing.assert_array_equal(sweep[i].compute(), expected)


def test_cv_sweep_checks_detection_options_up_front(lf):
    with pytest.raises(ParameterError, match="gamma"):
        lfa.refocus_sweep(lf, SLOPES, what="cv", gamma=1.5)


@pytest.mark.parametrize(
    "slopes, kwargs, match",
    [
        ([], {}, "non-empty"),
        ([[0.0, 1.0]], {}, "1-D"),
        ([0.0, np.nan], {}, "finite"),
        (["a"], {}, "real numbers"),
        ([0.0], {"what": "depth"}, "what"),
        ([0.0], {"gamma": 0.3}, "only apply"),
    ],
)
def test_bad_sweeps_raise_parameter_errors(lf, slopes, kwargs, match):
    with pytest.raises(ParameterError, match=match):
        lfa.refocus_sweep(lf, slopes, **kwargs)


def test_sweep_needs_a_lightfield():
    with pytest.raises(ParameterError, match="LightField"):
        lfa.refocus_sweep(np.zeros((3, 3, 8, 8)), [0.0])


@pytest.mark.parametrize("disparity", [-2, 1, 3])
def test_estimated_slope_range_finds_the_plane(disparity):
    lf = plane_lightfield(n=5, size=48, disparity=disparity, seed=disparity + 10)
    low, high = estimate_slope_range(lf)
    assert low == pytest.approx(disparity) and high == pytest.approx(disparity)


def test_estimated_slope_range_of_two_planes_spans_both():
    near = plane_lightfield(n=5, size=48, disparity=-1, seed=4).data
    far = plane_lightfield(n=5, size=48, disparity=2, seed=5).data
    data = np.concatenate([near[:, :, :, :24], far[:, :, :, 24:]], axis=3)
    low, high = estimate_slope_range(lfa.LightField(data), percentiles=(1, 99))
    assert low == pytest.approx(-1) and high == pytest.approx(2)


@pytest.mark.parametrize("size, tolerance", [(48, 0.0), (300, 0.3)])
def test_estimated_slope_range_ignores_samples_of_zero_weight(size, tolerance):
    """A lenslet decode leaves samples outside the lenses at 0 with weight 0: they carry no depth cue."""
    lf = plane_lightfield(n=5, size=size, disparity=2, seed=8)
    weights = (np.random.default_rng(1).random(lf.data.shape[:4]) > 0.3).astype(np.float32)
    holed = lfa.LightField(lf.data * weights[..., None], lf.positions, weights=weights)
    low, high = estimate_slope_range(holed)
    assert abs(low - 2) <= tolerance and abs(high - 2) <= tolerance


@pytest.mark.parametrize("n_views, expected", [(5, 33), (8, 57), (15, 113), (40, 257)])
def test_estimate_candidates_are_one_pixel_of_aperture_apart(n_views, expected):
    from napari_lfalias.sweep import _default_candidates

    lf = lfa.LightField(np.zeros((n_views, n_views, 4, 4, 1), np.float32))
    assert _default_candidates(lf, 4.0) == expected  # whole slopes are among them (but for the capped 40 x 40)


def test_estimated_slope_range_of_a_flat_scene_is_zero():
    lf = lfa.LightField(np.full((3, 3, 32, 32, 1), 0.4, np.float32))
    assert estimate_slope_range(lf) == (0.0, 0.0)


def test_aliasing_by_slope_is_least_on_the_plane():
    from napari_lfalias.sweep import aliasing_by_slope

    lf = plane_lightfield(n=5, size=48, disparity=1, seed=2)
    slopes, fractions = aliasing_by_slope(lf, n_slopes=5, threshold=0.02)
    # The estimated range is the plane's, padded by 0.5 on each side.
    np.testing.assert_allclose(slopes, [0.5, 0.75, 1.0, 1.25, 1.5])
    assert fractions.shape == (5,)
    assert int(np.argmin(fractions)) == 2 and fractions[2] < 0.05
    assert fractions[0] > 0.5 and fractions[-1] > 0.5
    same = aliasing_by_slope(lf, slopes=[1.0, 0.5], threshold=0.02)[1]
    np.testing.assert_array_equal(same, fractions[[2, 0]])
    # One shared detector gives what one detection per slope (the lazy mask sweep) gives.
    masks = lfa.refocus_sweep(lf, slopes, what="mask", threshold=0.02).compute()
    np.testing.assert_array_equal(fractions, masks.mean(axis=(1, 2)))
    done = []
    aliasing_by_slope(lf, slopes=[0.0, 1.0], progress=done.append)
    assert done == [0.0, 1.0]
    from napari_lfalias.detect import AliasingDetector

    detector = AliasingDetector(lf)
    np.testing.assert_array_equal(aliasing_by_slope(lf, slopes, detector=detector, threshold=0.02)[1], fractions)
    with pytest.raises(ParameterError, match="detector"):
        aliasing_by_slope(plane_lightfield(n=5, size=48), slopes, detector=detector)


def test_disparity_range_prefers_stated_then_true_then_estimated():
    from napari_lfalias.sweep import disparity_range

    lf = plane_lightfield(n=5, size=48, disparity=1, seed=6)
    assert disparity_range(lf) == (1.0, 1.0, "metadata")
    lf.meta.pop("disparity_range")
    lf.meta["disparity"] = np.array([[-0.5, np.nan], [0.75, 0.0]])
    assert disparity_range(lf) == (-0.5, 0.75, "ground truth")
    lf.meta.pop("disparity")
    assert disparity_range(lf) == (1.0, 1.0, "estimated")


def _has_display():
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
                or os.environ.get("QT_QPA_PLATFORM") in ("offscreen", "minimal"))


@pytest.mark.napari
@pytest.mark.skipif(not _has_display(), reason="needs a display: run under xvfb-run (as .ci/run does)")
def test_napari_slider_computes_only_the_slope_on_screen(make_napari_viewer, lf, refocus_calls):
    pytest.importorskip("napari")
    calls = refocus_calls
    sweep = lfa.refocus_sweep(lf, SLOPES)
    viewer = make_napari_viewer()
    layer = viewer.add_image(sweep, rgb=True, contrast_limits=(0, 1), name="focus sweep")
    assert viewer.dims.nsteps[0] == len(SLOPES)
    # Adding the layer computes the slope on screen (napari may also read the first one), not the stack.
    on_screen = viewer.dims.current_step[0]
    assert on_screen != 3 and SLOPES[on_screen] in calls and SLOPES[3] not in calls
    assert len(set(calls)) <= 2
    before = set(calls)
    viewer.dims.set_current_step(0, 3)
    assert set(calls) == before | {SLOPES[3]}
    np.testing.assert_array_equal(np.asarray(layer._slice.image.raw), lfa.refocus(lf, SLOPES[3]))
