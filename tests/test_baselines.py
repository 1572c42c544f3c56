"""Prefiltered and depth-aware refocusing against the dense-aperture reference of synthetic scenes."""

import numpy as np
import pytest
from scipy import ndimage

from napari_lfalias import LightField, ParameterError, refocus, regular_positions
from napari_lfalias.baselines import (_larger_is_nearer, depth_aware_refocus, prefilter_refocus, prefilter_width,
                                      view_spacing)
from napari_lfalias.metrics import psnr, ssim
from napari_lfalias.synthetic import brick_room, layered_scene, textured_plane


@pytest.fixture(scope="module")
def room():
    """The paper's brick room (8x8 views, 8 px between adjacent views when focused on either plane)."""
    return brick_room(n_views=8, size=160, seed=0)


def regions(scene, slope, margin=4):
    """In-focus and out-of-focus pixels, ``margin`` px away from the depth edges."""
    in_focus = np.abs(scene.disparity - slope) < 0.5
    return (ndimage.binary_erosion(in_focus, iterations=margin),
            ndimage.binary_erosion(~in_focus, iterations=margin))


# -- geometry -------------------------------------------------------------------

def test_view_spacing_and_prefilter_width(room):
    assert view_spacing(regular_positions(3, 5)) == 1.0
    assert view_spacing(2.5 * regular_positions(4, 4)) == 2.5
    assert view_spacing(np.zeros((1, 1, 2))) == 1.0
    lf = room.lightfield
    assert prefilter_width(lf, -4.0) == pytest.approx(8.0)  # range (-4, 4)
    assert prefilter_width(lf, 1.0) == pytest.approx(5.0)
    assert prefilter_width(lf, 0.0, disparity_range=(-1.0, 0.5)) == pytest.approx(1.0)
    wide = LightField(lf.data, 2 * lf.positions, lf.meta)
    assert prefilter_width(wide, -4.0) == pytest.approx(16.0)


# -- prefilter ------------------------------------------------------------------

def box_reference(image, kernel):
    """Normalised separable convolution with zero outside (independent: scipy.ndimage)."""
    def filt(a):
        for axis in (0, 1):
            a = ndimage.correlate1d(a, kernel, axis=axis, mode="constant")
        return a
    return filt(image) / filt(np.ones(image.shape[:2]))[..., None]


@pytest.mark.parametrize("width, kernel", [(3.0, [1, 1, 1]), (2.0, [0.5, 1, 0.5]), (4.5, [0.75, 1, 1, 1, 0.75])])
def test_prefilter_of_one_view_is_a_normalised_box_filter(width, kernel):
    image = np.random.default_rng(0).random((1, 1, 19, 23, 3)).astype(np.float32)
    out = prefilter_refocus(LightField(image), 0.0, width=width)
    np.testing.assert_allclose(out, box_reference(image[0, 0].astype(np.float64), kernel), atol=1e-5)


def test_prefilter_keeps_constants_and_zero_width_is_the_naive_refocus(room):
    flat = LightField(np.full((3, 3, 20, 20, 3), 0.3, np.float32))
    np.testing.assert_allclose(prefilter_refocus(flat, 0.7, disparity_range=(-2, 2)), 0.3, atol=1e-6)
    lf = room.lightfield
    assert np.array_equal(prefilter_refocus(lf, 1.3, width=0.5), refocus(lf, 1.3))


def test_prefilter_uses_sample_weights():
    data = np.full((2, 2, 12, 12, 1), 0.5, np.float32)
    data[0, 0, :, :6] = 100.0  # garbage with zero weight
    weights = np.ones((2, 2, 12, 12), np.float32)
    weights[0, 0, :, :6] = 0.0
    out = prefilter_refocus(LightField(data, weights=weights), 0.0, width=3.0)
    np.testing.assert_allclose(out, 0.5, atol=1e-6)


def test_prefilter_trades_aliasing_for_in_focus_blur(room):
    """The paper's criticism: less aliasing out of focus, but the in-focus plane is blurred."""
    slope = 4.0  # the cube in focus, the brick wall 8 px per view step away
    reference = room.reference(slope)
    in_focus, out_focus = regions(room, slope)
    naive = refocus(room.lightfield, slope)
    filtered = prefilter_refocus(room.lightfield, slope)
    assert psnr(filtered, reference, mask=out_focus) > psnr(naive, reference, mask=out_focus) + 10
    assert psnr(filtered, reference, mask=in_focus) < psnr(naive, reference, mask=in_focus) - 20
    assert filtered.dtype == np.float32 and filtered.shape == naive.shape


def test_prefilter_needs_a_disparity_range():
    lf = LightField(np.zeros((2, 2, 8, 8, 1), np.float32))
    with pytest.raises(ParameterError, match="disparity_range"):
        prefilter_refocus(lf, 0.0)
    with pytest.raises(ParameterError, match="disparity_range"):
        prefilter_refocus(lf, 0.0, disparity_range=(2.0, 1.0))
    with pytest.raises(ParameterError, match="disparity_range"):
        prefilter_refocus(lf, 0.0, disparity_range=5.0)
    # a ground-truth map in the metadata is enough
    lf.meta["disparity"] = np.linspace(-1, 3, 64).reshape(8, 8)
    assert prefilter_width(lf, 0.0) == pytest.approx(3.0)


def test_prefilter_rejects_bad_parameters(room):
    with pytest.raises(ParameterError, match="slope"):
        prefilter_refocus(room.lightfield, float("nan"))
    with pytest.raises(ParameterError, match="width"):
        prefilter_refocus(room.lightfield, 0.0, width=-1.0)
    with pytest.raises(ParameterError, match="lf"):
        prefilter_refocus(np.zeros((2, 2, 8, 8, 1)), 0.0)


# -- depth-aware ----------------------------------------------------------------

@pytest.mark.parametrize("slope", [-4.0, 4.0])
def test_depth_aware_beats_naive_out_of_focus_and_stays_sharp_in_focus(room, slope):
    reference = room.reference(slope)
    in_focus, out_focus = regions(room, slope)
    naive = refocus(room.lightfield, slope)
    aware = depth_aware_refocus(room.lightfield, slope, room.disparity)
    assert aware.dtype == np.float32 and aware.shape == naive.shape
    assert np.all(np.isfinite(aware))
    # aliased (out-of-focus) region: closer to the dense aperture than the naive refocus
    assert psnr(aware, reference, mask=out_focus) > psnr(naive, reference, mask=out_focus) + 3
    # in focus: as sharp as the naive refocus
    assert psnr(aware, reference, mask=in_focus) > psnr(naive, reference, mask=in_focus) - 0.5
    assert ssim(aware, reference, mask=in_focus) > 0.99


def test_depth_aware_in_focus_plane_equals_the_naive_refocus():
    scene = textured_plane(n_views=5, size=64, seed=1, disparity=1.0)
    lf = scene.lightfield
    aware = depth_aware_refocus(lf, 1.0, scene.disparity)
    np.testing.assert_allclose(aware, refocus(lf, 1.0), atol=1e-5)


def test_depth_aware_finds_which_side_is_in_front(room):
    """Mirroring the view positions and negating the disparity describes the same views: same image."""
    lf = room.lightfield
    auto = depth_aware_refocus(lf, 4.0, room.disparity)
    assert np.array_equal(auto, depth_aware_refocus(lf, 4.0, room.disparity, nearer="larger"))
    assert not np.allclose(auto, depth_aware_refocus(lf, 4.0, room.disparity, nearer="smaller"), atol=1e-3)
    mirrored = LightField(lf.data, -lf.positions, lf.meta)
    flipped = depth_aware_refocus(mirrored, -4.0, -room.disparity)
    np.testing.assert_allclose(flipped, auto, atol=1e-5)


def test_depth_aware_quantises_a_continuous_map_and_keeps_constants():
    flat = LightField(np.full((3, 3, 24, 24, 3), 0.4, np.float32))
    ramp = np.tile(np.linspace(-2, 2, 24), (24, 1))
    out = depth_aware_refocus(flat, 0.5, ramp, max_layers=6)
    np.testing.assert_allclose(out, 0.4, atol=1e-5)


def test_depth_aware_uses_sample_weights():
    data = np.full((2, 2, 16, 16, 1), 0.5, np.float32)
    data[1, 1, 4:10, 4:10] = 50.0
    weights = np.ones((2, 2, 16, 16), np.float32)
    weights[1, 1, 4:10, 4:10] = 0.0
    out = depth_aware_refocus(LightField(data, weights=weights), 1.0, np.zeros((16, 16)))
    np.testing.assert_allclose(out, 0.5, atol=1e-5)


@pytest.mark.parametrize(
    "kwargs, name",
    [
        (dict(disparity=np.zeros((8, 9))), "disparity"),
        (dict(disparity=np.full((8, 8), np.nan)), "disparity"),
        (dict(disparity=np.zeros((8, 8), bool)), "disparity"),
        (dict(nearer="front"), "nearer"),
        (dict(max_layers=0), "max_layers"),
        (dict(slope=float("inf")), "slope"),
    ],
)
def test_depth_aware_rejects_bad_parameters(kwargs, name):
    args = dict(lf=LightField(np.zeros((2, 2, 8, 8, 1), np.float32)), slope=0.0, disparity=np.zeros((8, 8)))
    args.update(kwargs)
    with pytest.raises(ParameterError, match=name):
        depth_aware_refocus(args.pop("lf"), args.pop("slope"), args.pop("disparity"), **args)


def _box_pass_x_column_by_column(src, n, f):
    """The box along the rows, one column at a time: float64 prefix sums, each end tap added to the float32 sum."""
    out = np.empty_like(src)
    n_cols = src.shape[1]
    for y in range(src.shape[0]):
        prefix = np.zeros((n_cols + 1, src.shape[2]))
        prefix[1:] = np.cumsum(src[y].astype(np.float64), axis=0)
        for x in range(n_cols):
            value = (prefix[min(x + n + 1, n_cols)] - prefix[max(x - n, 0)]).astype(np.float32)
            if f > 0.0 and x - n - 1 >= 0:
                value = (value + f * src[y, x - n - 1].astype(np.float64)).astype(np.float32)
            if f > 0.0 and x + n + 1 < n_cols:
                value = (value + f * src[y, x + n + 1].astype(np.float64)).astype(np.float32)
            out[y, x] = value
    return out


@pytest.mark.parametrize("n, f", [(0, 0.0), (0, 0.4), (2, 0.0), (3, 0.25), (10, 0.7), (18, 0.5), (19, 0.1), (40, 0.3)])
def test_the_box_along_the_rows_is_the_sum_column_by_column_bit_for_bit(n, f):
    # the kernel sums the columns whose box lies inside the row in one flat loop: the same float roundings
    from napari_lfalias._baseline_kernels import _box_pass_x

    src = np.random.default_rng(n).random((3, 37, 5)).astype(np.float32) * 7.0
    out = np.empty_like(src)
    _box_pass_x(src, out, n, f)
    np.testing.assert_array_equal(out, _box_pass_x_column_by_column(src, n, f))


def test_the_occlusion_order_is_judged_from_the_sure_pixels_of_an_estimate():
    """A checker wall behind a square, estimated a period off in patches: depth edges inside the wall, whose
    wrong side's views disagree (sampled at the wrong disparity, as if hidden) and outvote the square's
    outline. An estimate is unsure on a periodic wall but for the band along an occluder's outline, where
    the outline is texture that only one disparity fits: counted only where sure, the square is in front."""
    scene = layered_scene([(3.0, "noise", (0.3, 0.7, 0.3, 0.7)), (-2.0, "checker", None)], n_views=5,
                          size=96, seed=4)
    views, positions = np.ascontiguousarray(scene.lightfield.views()), scene.lightfield.flat_positions()
    square = scene.disparity == np.float32(3.0)
    confidence = np.where(ndimage.binary_dilation(square, iterations=6), 0.8, 0.2).astype(np.float32)
    y, x = np.mgrid[:96, :96]
    disparity = scene.disparity.astype(np.float64)
    disparity[(y % 12 < 4) & (x % 12 < 4) & ~square] = 4.0  # a period off
    assert _larger_is_nearer(views, positions, scene.disparity.astype(np.float64))  # the true disparity
    assert not _larger_is_nearer(views, positions, disparity)  # the trap: every pixel counted
    assert _larger_is_nearer(views, positions, disparity, confidence)


def _square_over_smooth_wall(front, back, n_views, seed, spill):
    """A brick square at ``front`` before a smooth wall at ``back``, noisy, and an estimate whose square
    spills ``spill`` px over the wall (a fattened edge): the views, their positions and that estimate."""
    from napari_lfalias.synthetic.camera import capture

    scene = layered_scene([(front, "bricks", (0.3, 0.7, 0.3, 0.7)), (back, "smooth", None)], n_views=n_views,
                          size=96, seed=seed)
    lf = capture(scene.lightfield, read_noise=0.003, shot_noise=0.007, seed=seed)
    square = ndimage.binary_dilation(scene.disparity == np.float32(front), iterations=spill)
    return np.ascontiguousarray(lf.views()), lf.flat_positions(), np.where(square, front, back).astype(np.float64)


@pytest.mark.parametrize("front, back", [(4.0, -4.5), (-4.0, 4.5)])
def test_the_samples_the_true_order_hides_explain_the_views(front, back):
    # the wall's band outside the fattened edge is seen by every view; only leaving out the samples the
    # square hides under the true order explains why the views disagree inside the spill
    from napari_lfalias.baselines import _hidden_views_explain_larger_first

    views, positions, disparity = _square_over_smooth_wall(front, back, 4, seed=2, spill=8)
    assert _hidden_views_explain_larger_first(views, positions, disparity, None, None, 20_000) == (front > back)


def test_where_the_edges_spreads_are_alike_the_hidden_samples_judge_the_order(monkeypatch):
    import napari_lfalias.baselines as baselines

    views, positions, disparity = _square_over_smooth_wall(-4.0, 4.5, 4, seed=3, spill=10)
    monkeypatch.setattr(baselines, "CLEAR_SPREAD_RATIO", 0.0)  # the edges' spreads alone: wrong here
    assert _larger_is_nearer(views, positions, disparity)
    monkeypatch.undo()
    assert not _larger_is_nearer(views, positions, disparity)
