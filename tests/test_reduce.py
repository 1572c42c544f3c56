"""Aliasing reduction (Algorithm 2): levels, fusion, accuracy against the dense aperture, parameters."""

import functools
import numpy as np
import pytest

import napari_lfalias as lfa
from napari_lfalias import detect as detect_module
from napari_lfalias import reduce as reduce_module
from napari_lfalias.detect import AliasingDetector
from napari_lfalias.baselines import view_spacing
from napari_lfalias.errors import ParameterError
from napari_lfalias.reduce import fuse_levels, levels_from_disparity
from napari_lfalias.synthetic import brick_room, textured_plane

#: These tests are about Algorithm 2 with the paper's Cv: the method is the exact Cv unless a test names
#: another (the package's default, the disparity-guided reduction, is tested in test_depth_guided).
reduce_cv = functools.partial(lfa.reduce_aliasing, method="analytic")
iter_reduce_cv = functools.partial(reduce_module.iter_reduce_aliasing, method="analytic")


@pytest.fixture(scope="module")
def room():
    return brick_room(n_views=8, size=128, seed=0)


def psnr(image, reference, mask):
    return 10 * np.log10(1.0 / np.mean((image - reference)[mask] ** 2))


def test_a_light_field_without_aliasing_comes_back_as_the_naive_refocus():
    lf = textured_plane(n_views=5, size=64, seed=0, disparity=1.0).lightfield
    result = reduce_cv(lf, 1.0)
    assert not result.level.any()
    np.testing.assert_allclose(result.image, lfa.refocus(lf, 1.0), atol=1e-6)
    np.testing.assert_array_equal(result.cv, lfa.detect_aliasing(lf, 1.0, method="analytic").cv)


def test_max_level_zero_is_the_naive_refocus_with_its_cv(room):
    result = reduce_cv(room.lightfield, 4.0, threshold=0.005, max_level=0)
    np.testing.assert_array_equal(result.image, lfa.refocus(room.lightfield, 4.0))
    assert not result.level.any() and result.cv.max() > 0.005


@pytest.mark.parametrize("max_level", [1, 2, 3])
def test_level_map_follows_the_detections(room, max_level):
    """l* = 0 where level 0 is alias-free; l* = l where levels < l alias and l does not; never above max_level."""
    result = reduce_cv(room.lightfield, 4.0, threshold=0.005, max_level=max_level)
    level0 = lfa.detect_aliasing(room.lightfield, 4.0, threshold=0.005, method="analytic")
    assert result.level.dtype == np.uint8 and result.level.max() <= max_level
    np.testing.assert_array_equal(result.level == 0, ~level0.mask)
    assert (result.level > 0).mean() > 0.3  # the wall aliases: the test could fail
    # below the top level, the pixels of level 1 were not aliased on level 1 (nearest level
    # pixel); on the top level, Eq. 8 puts every pixel still aliased
    if max_level > 1:
        level1 = result.detections[1]
        ys, xs = np.nonzero(result.level == 1)
        assert not level1.mask[np.minimum((ys + 1) // 2, level1.mask.shape[0] - 1),
                               np.minimum((xs + 1) // 2, level1.mask.shape[1] - 1)].any()


def test_pixels_kept_at_level_zero_are_unchanged(room):
    result = reduce_cv(room.lightfield, 4.0, threshold=0.005)
    keep = result.level == 0
    assert keep.any() and (~keep).any()
    np.testing.assert_array_equal(result.image[keep], result.refocused[keep])


def test_output_is_finite_and_within_the_input_range(room):
    result = reduce_cv(room.lightfield, 4.0, threshold=0.005)
    data = room.lightfield.data
    assert np.all(np.isfinite(result.image))
    assert result.image.min() >= data.min() - 0.05 and result.image.max() <= data.max() + 0.05


def test_reduction_is_closer_to_the_dense_aperture_where_it_acts(room):
    """Focused on the cube, the wall aliases; the fused result must be nearer the dense-aperture reference there."""
    slope = 4.0
    result = reduce_cv(room.lightfield, slope, threshold=0.005)
    reference = room.reference(slope)
    acted = result.level > 0
    assert psnr(result.image, reference, acted) >= psnr(result.refocused, reference, acted) + 3.0


def test_keeping_the_in_focus_layer_keeps_the_wall_sharp_around_the_defocused_cube(room):
    """Focused on the wall, the defocused cube's halo hides part of it: the wall must stay nearer the reference."""
    slope = -4.0
    reference = room.reference(slope)
    paper = reduce_cv(room.lightfield, slope, threshold=0.005)
    kept = reduce_cv(room.lightfield, slope, threshold=0.005, keep_in_focus=True)
    np.testing.assert_array_equal(kept.level, paper.level)
    halo = (kept.level > 0) & (room.disparity == slope)  # in-focus wall pixels the reduction acted on
    assert halo.mean() > 0.01
    assert psnr(kept.image, reference, halo) >= psnr(paper.image, reference, halo) + 2.0
    np.testing.assert_array_equal(kept.image[kept.level == 0], kept.refocused[kept.level == 0])


def test_coarser_levels_are_only_computed_where_pixels_are_still_aliased(room, monkeypatch):
    regions = []
    detect = AliasingDetector.detect

    def spy(self, slope, *args, region=None, level=0, **kwargs):
        regions.append((level, None if region is None else region.mean()))
        return detect(self, slope, *args, region=region, level=level, **kwargs)

    monkeypatch.setattr(AliasingDetector, "detect", spy)
    reduce_cv(room.lightfield, 4.0, threshold=0.005)
    assert regions[0] == (0, None)
    fractions = [fraction for level, fraction in regions[1:]]
    assert fractions and all(0 < f < 1 for f in fractions)
    # and no level at all where nothing aliases
    regions.clear()
    reduce_cv(room.lightfield, 4.0, threshold=10.0)
    assert [level for level, _ in regions] == [0]


def test_the_steps_report_progress_and_give_the_same_result(room):
    steps = iter_reduce_cv(room.lightfield, 4.0, threshold=0.005, max_level=3)
    progress = []
    while True:
        try:
            progress.append(next(steps))
        except StopIteration as done:
            result = done.value
            break
    assert progress == [(k, 6) for k in range(1, 7)]
    np.testing.assert_array_equal(result.image, reduce_cv(room.lightfield, 4.0, threshold=0.005).image)


def test_closing_the_steps_stops_the_work(room, monkeypatch):
    from napari_lfalias import reduce as reduce_module

    calls = []
    monkeypatch.setattr(reduce_module, "fuse_gradients", lambda *a, **k: calls.append("fuse"))
    steps = iter_reduce_cv(room.lightfield, 4.0, threshold=0.005)
    assert next(steps) == (1, 6)
    steps.close()
    assert calls == []


def test_a_detector_can_be_reused(room, monkeypatch):
    detector = AliasingDetector(room.lightfield)
    first = reduce_cv(room.lightfield, 4.0, threshold=0.005, detector=detector)
    shifted = []
    monkeypatch.setattr(detect_module, "_run", lambda name, *a, _run=detect_module._run: (shifted.append(name), _run(name, *a)))
    again = reduce_cv(room.lightfield, 4.0, threshold=0.005, detector=detector)
    assert "moments" not in shifted  # level 0 reused
    np.testing.assert_array_equal(first.image, again.image)
    with pytest.raises(ParameterError, match="detector"):
        reduce_cv(textured_plane(n_views=3, size=16).lightfield, 0.0, detector=detector)


@pytest.mark.parametrize(
    "kwargs, word",
    [
        (dict(max_level=-1), "max_level"), (dict(max_level=1.5), "max_level"), (dict(solver="cg"), "solver"),
        (dict(gamma=2.0), "gamma"), (dict(n_patterns=0), "n_patterns"), (dict(threshold=0.0), "threshold"),
        (dict(method="exact"), "method"), (dict(keep_in_focus="yes"), "keep_in_focus"),
    ],
)
def test_bad_parameters_are_parameter_errors(room, kwargs, word):
    with pytest.raises(ParameterError, match=word):
        reduce_cv(room.lightfield, 1.0, **kwargs)


def test_bad_slope_and_light_field_are_parameter_errors(room):
    with pytest.raises(ParameterError, match="slope"):
        reduce_cv(room.lightfield, float("nan"))
    with pytest.raises(ParameterError, match="LightField"):
        reduce_cv(np.zeros((2, 2, 8, 8, 1)), 0.0)


def test_fuse_levels_renders_what_the_reduction_made_of_its_own_level_map(room):
    result = reduce_cv(room.lightfield, 4.0, threshold=0.005)
    np.testing.assert_array_equal(fuse_levels(result.refocused, result.level), result.image)
    np.testing.assert_array_equal(fuse_levels(result.refocused, np.zeros_like(result.level)), result.refocused)


def test_the_ground_truth_level_map_blurs_only_the_defocused_and_brings_it_nearer_the_reference(room):
    """The ceiling of Algorithm 2 (a perfect detector): in focus on the cube, the defocused wall gains."""
    slope = 4.0
    level = levels_from_disparity(room.disparity, slope, view_spacing(room.lightfield.positions))
    in_focus = np.abs(room.disparity - slope) < 0.5
    assert not level[in_focus].any() and level.max() == 3
    naive = lfa.refocus(room.lightfield, slope)
    fused = fuse_levels(naive, level)
    np.testing.assert_array_equal(fused[level == 0], naive[level == 0])
    reference = room.reference(slope)
    acted = level > 0
    assert psnr(fused, reference, acted) >= psnr(naive, reference, acted) + 3.0


def test_levels_from_disparity_is_the_first_level_where_a_point_moves_a_pixel_or_less():
    shift = np.array([[0.0, 0.5, 1.0, 1.01, 2.0, 2.01, 4.0, 4.01, 8.0, 100.0]])
    np.testing.assert_array_equal(levels_from_disparity(shift + 3.0, 3.0, max_level=3)[0],
                                  [0, 0, 0, 1, 1, 2, 2, 3, 3, 3])
    np.testing.assert_array_equal(levels_from_disparity(-shift / 4, 0.0, spacing=4.0, max_level=5)[0],
                                  [0, 0, 0, 1, 1, 2, 2, 3, 3, 5])


@pytest.mark.parametrize(
    "image, level, kwargs, word",
    [
        (np.zeros((8, 8)), np.zeros((8, 8), int), {}, "refocused"),
        (np.full((8, 8, 3), np.nan), np.zeros((8, 8), int), {}, "refocused"),
        (np.zeros((8, 8, 3)), np.zeros((8, 9), int), {}, "level_map"),
        (np.zeros((8, 8, 3)), np.zeros((8, 8)), {}, "level_map"),
        (np.zeros((8, 8, 3)), np.full((8, 8), -1), {}, "level_map"),
        (np.zeros((8, 8, 3)), np.full((8, 8), 17), {}, "level_map"),
        (np.zeros((8, 8, 3)), np.ones((8, 8), int), dict(solver="cg"), "solver"),
        (np.zeros((8, 8, 3)), np.ones((8, 8), int), dict(screen=-1.0), "screen"),
    ],
)
def test_fuse_levels_rejects_bad_input(image, level, kwargs, word):
    with pytest.raises(ParameterError, match=word):
        fuse_levels(image, level, **kwargs)


@pytest.mark.parametrize(
    "disparity, kwargs, word",
    [
        (np.zeros(8), {}, "disparity"), (np.full((4, 4), np.inf), {}, "disparity"),
        (np.zeros((4, 4)), dict(slope=float("nan")), "slope"), (np.zeros((4, 4)), dict(spacing=0.0), "spacing"),
        (np.zeros((4, 4)), dict(max_level=17), "max_level"), (np.zeros((4, 4)), dict(max_level=-1), "max_level"),
    ],
)
def test_levels_from_disparity_rejects_bad_input(disparity, kwargs, word):
    kwargs = {"slope": 0.0, **kwargs}
    with pytest.raises(ParameterError, match=word):
        levels_from_disparity(disparity, **kwargs)
