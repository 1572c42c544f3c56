"""Poisson solvers and gradient fusion against known answers and independent references."""

import numpy as np
import pytest
from scipy import ndimage

from napari_lfalias import ParameterError, refocus
from napari_lfalias.poisson import (
    divergence,
    fuse_gradients,
    gradients,
    laplacian,
    solve_dirichlet,
    solve_neumann,
)
from napari_lfalias.synthetic import brick_room

MASKED = ("lu", "multigrid", "auto")


def smooth(shape=(48, 64), channels=3, dtype=np.float64):
    """A smooth analytic image (known answer of the solves)."""
    y, x = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float64)
    planes = [np.cos(y / 7.0 + c) * np.sin(x / 9.0 - c) + 0.3 * (y / shape[0]) ** 2 + 0.1 * c
              for c in range(channels)]
    return np.stack(planes, axis=-1).astype(dtype)


def blob_mask(shape, fraction, seed=0, sigma=4.0):
    noise = ndimage.gaussian_filter(np.random.default_rng(seed).normal(size=shape), sigma)
    return noise > np.quantile(noise, 1 - fraction)


# -- operators ------------------------------------------------------------------

def test_laplacian_is_the_five_point_stencil_with_mirrored_edges():
    f = np.random.default_rng(1).random((13, 17))
    stencil = np.array([[0, 1, 0], [1, -4, 1], [0, 1, 0]], float)
    expected = ndimage.convolve(f, stencil, mode="nearest")  # a replicated neighbour adds 0
    np.testing.assert_allclose(laplacian(f), expected, atol=1e-12)


def test_divergence_is_minus_the_adjoint_of_the_gradient():
    rng = np.random.default_rng(2)
    f = rng.random((11, 9, 2))
    gy, gx = rng.random((2, 11, 9, 2))
    gy[-1] = 0  # edges leaving the image do not exist
    gx[:, -1] = 0
    fy, fx = gradients(f)
    assert np.isclose((fy * gy).sum() + (fx * gx).sum(), -(f * divergence(gy, gx)).sum())


# -- known answers --------------------------------------------------------------

def test_dct_solve_recovers_a_smooth_image_from_its_laplacian():
    f = smooth()
    g = solve_neumann(laplacian(f), mean=f.mean(axis=(0, 1)))
    assert g.dtype == np.float64
    np.testing.assert_allclose(g, f, atol=1e-10)


@pytest.mark.parametrize("method", MASKED)
def test_masked_solve_recovers_a_smooth_image_whatever_the_masked_values(method):
    f = smooth()
    mask = blob_mask(f.shape[:2], 0.4)
    mask[:, :3] = True  # unknowns on the image's edge: Neumann there
    garbage = np.where(mask[..., None], 5.0, f)  # masked values must not matter
    g = solve_dirichlet(garbage, mask, laplacian(f), method=method, tol=1e-8)
    atol = 1e-5 if method != "lu" else 1e-9
    np.testing.assert_allclose(g, f.astype(np.float32), atol=atol)


@pytest.mark.parametrize("method", MASKED + ("dct",))
def test_fast_and_exact_solvers_agree_on_a_known_answer(method):
    """Fusing ``f + p`` into ``f``, ``p`` a zero-mean bump inside the mask: every solver gives ``f + p``."""
    f = smooth((64, 64))
    y, x = np.mgrid[0:64, 0:64] - 32.0
    radius2 = (y ** 2 + x ** 2) / 14.0 ** 2
    bump = np.where(radius2 < 1, (1 - radius2) ** 3, 0.0) * x / 14.0  # odd in x: zero mean
    source = f + bump[..., None]
    labels = (radius2 < 1.6).astype(np.int8)  # the guidance is the gradient of f + p everywhere
    fused = fuse_gradients(f, [source], labels, method=method, tol=1e-7)
    np.testing.assert_allclose(fused, source.astype(np.float32), atol=2e-5)


def test_masked_solvers_agree_with_each_other_on_random_data():
    rng = np.random.default_rng(3)
    image = rng.random((60, 70, 3))
    div = rng.normal(size=(60, 70, 3))
    mask = blob_mask((60, 70), 0.35, seed=4)
    exact = solve_dirichlet(image, mask, div, method="lu")
    for tol, atol in ((1e-4, 5e-2), (1e-7, 1e-4)):
        approx = solve_dirichlet(image, mask, div, method="multigrid", tol=tol)
        assert np.abs(approx - exact).max() < atol
    # the exact solution satisfies the discrete equation on every unknown
    residual = laplacian(exact.astype(np.float64)) - div
    assert np.abs(residual[mask]).max() < 1e-4


@pytest.mark.parametrize("method", MASKED)
def test_masked_solve_leaves_pixels_outside_the_mask_untouched(method):
    rng = np.random.default_rng(5)
    image = rng.random((40, 50, 3)).astype(np.float32)
    mask = blob_mask((40, 50), 0.3, seed=6)
    out = solve_dirichlet(image, mask, rng.normal(size=image.shape), method=method)
    assert np.array_equal(out[~mask], image[~mask])
    assert not np.allclose(out[mask], image[mask])


def test_whole_image_mask_is_solved_with_the_mean_of_the_image():
    f = smooth(channels=1)[..., 0]
    image = np.full(f.shape, 0.25)
    g = solve_dirichlet(image, np.ones(f.shape, bool), laplacian(f))
    np.testing.assert_allclose(g, f - f.mean() + 0.25, atol=1e-5)


def test_screened_dct_pins_low_frequencies_to_the_reference():
    f = smooth()
    # f satisfies the screened equation with itself as reference, for any weight
    np.testing.assert_allclose(solve_neumann(laplacian(f), screen=0.05, reference=f), f, atol=1e-9)
    # with no guidance the result is a low-pass of the reference, same mean
    rng = np.random.default_rng(7)
    reference = rng.random((32, 32))
    low = solve_neumann(np.zeros((32, 32)), screen=0.1, reference=reference)
    assert np.isclose(low.mean(), reference.mean())
    assert low.std() < 0.5 * reference.std()


# -- fusion ---------------------------------------------------------------------

@pytest.mark.parametrize("method", MASKED + ("dct",))
def test_fusing_an_image_with_itself_is_the_identity(method):
    base = np.random.default_rng(8).random((50, 40, 3)).astype(np.float32)
    labels = np.zeros((50, 40), np.int8)
    labels[5:30, 10:35] = 1
    labels[20:45, 3:20] = 2
    fused = fuse_gradients(base, [base, base], labels, method=method)
    assert fused.dtype == np.float32 and fused.shape == base.shape
    np.testing.assert_allclose(fused, base, atol=1e-6)


def test_fusion_solves_the_guidance_equation_with_the_larger_label_per_edge():
    """An independent loop implementation of Perez et al. Eq. 7 with the edge rule."""
    rng = np.random.default_rng(9)
    shape = (24, 30)
    base = rng.random(shape + (2,))
    sources = [rng.random(shape + (2,)), rng.random(shape + (2,))]
    labels = np.zeros(shape, np.int64)
    labels[4:18, 5:20] = 1
    labels[10:22, 12:28] = 2
    fused = fuse_gradients(base, sources, labels, method="lu").astype(np.float64)
    images = [base] + sources
    worst = 0.0
    for y, x in zip(*np.nonzero(labels)):
        lhs = np.zeros(2)
        rhs = np.zeros(2)
        for qy, qx in ((y - 1, x), (y + 1, x), (y, x - 1), (y, x + 1)):
            if 0 <= qy < shape[0] and 0 <= qx < shape[1]:
                k = max(labels[y, x], labels[qy, qx])
                lhs += fused[qy, qx] - fused[y, x]
                rhs += images[k][qy, qx] - images[k][y, x]
        worst = max(worst, np.abs(lhs - rhs).max())
    assert worst < 1e-5
    assert np.array_equal(fused[labels == 0], base[labels == 0].astype(np.float32))


@pytest.mark.parametrize("method", MASKED)
def test_fusion_keeps_base_exactly_where_the_label_is_zero(method):
    rng = np.random.default_rng(10)
    base = rng.random((64, 64, 3)).astype(np.float32)
    source = ndimage.gaussian_filter(rng.random((64, 64, 3)), (2, 2, 0)).astype(np.float32)
    labels = blob_mask((64, 64), 0.3, seed=11).astype(np.uint8)
    fused = fuse_gradients(base, [source], labels, method=method)
    assert np.array_equal(fused[labels == 0], base[labels == 0])
    # inside, fused - source is harmonic (it takes the source's gradients)
    diff = laplacian(fused.astype(np.float64) - source)
    interior = ndimage.binary_erosion(labels > 0)
    assert np.abs(diff[interior]).max() < 1e-4


def test_dct_fusion_moves_pixels_outside_the_mask():
    rng = np.random.default_rng(12)
    base = rng.random((64, 64)).astype(np.float32)
    source = base + np.linspace(0, 1, 64, dtype=np.float32)[None, :]  # a ramp: inconsistent at the mask's edge
    labels = np.zeros((64, 64), np.int8)
    labels[20:40, 20:40] = 1
    exact = fuse_gradients(base, [source], labels, method="lu")
    fast = fuse_gradients(base, [source], labels, method="dct")
    assert fast.ndim == 2
    assert np.abs(fast - base)[labels == 0].max() > 1e-3
    assert np.abs(exact - base)[labels == 0].max() == 0


def test_fusion_on_a_refocused_scene_is_finite_and_within_range():
    scene = brick_room(n_views=4, size=96, seed=0)
    base = refocus(scene.lightfield, -4.0)
    sources = [ndimage.gaussian_filter(base, (s, s, 0)) for s in (1.0, 2.0, 4.0)]
    aliased = np.abs(scene.disparity + 4.0) > 0.5
    labels = np.where(aliased, 1 + (np.arange(96)[:, None] // 32) % 3, 0).astype(np.int8)
    low = min(base.min(), min(s.min() for s in sources))
    high = max(base.max(), max(s.max() for s in sources))
    for method in MASKED:
        fused = fuse_gradients(base, sources, labels, method=method)
        assert np.all(np.isfinite(fused))
        assert fused.min() >= low - 0.05 and fused.max() <= high + 0.05
        assert np.array_equal(fused[~aliased], base[~aliased])


def test_no_labels_returns_a_copy_of_base():
    base = np.ones((8, 8, 3), np.float32)
    fused = fuse_gradients(base, [base * 2], np.zeros((8, 8), int))
    assert np.array_equal(fused, base) and fused is not base


# -- bad input ------------------------------------------------------------------

@pytest.mark.parametrize(
    "kwargs, name",
    [
        (dict(method="fft"), "method"),
        (dict(tol=0.0), "tol"),
        (dict(tol=1.5), "tol"),
        (dict(screen=-1.0), "screen"),
        (dict(labels=np.zeros((8, 9), int)), "labels"),
        (dict(labels=np.full((8, 8), 3)), "labels"),
        (dict(labels=np.full((8, 8), -1)), "labels"),
        (dict(labels=np.zeros((8, 8))), "labels"),
        (dict(sources=[np.ones((8, 8, 3)), np.ones((8, 7, 3))]), "sources[1]"),
        (dict(sources=np.ones((8, 8, 3)) * 0 + np.nan), "sources[0]"),
        (dict(sources=5), "sources"),
        (dict(base=np.ones(8)), "base"),
        (dict(base=np.full((8, 8, 3), np.inf)), "base"),
    ],
)
def test_fusion_rejects_bad_parameters(kwargs, name):
    args = dict(base=np.ones((8, 8, 3)), sources=[np.ones((8, 8, 3)), np.ones((8, 8, 3))],
                labels=np.zeros((8, 8), int))
    args.update(kwargs)
    with pytest.raises(ParameterError, match=name.replace("[", r"\[").replace("]", r"\]")):
        fuse_gradients(args.pop("base"), args.pop("sources"), args.pop("labels"), **args)


@pytest.mark.parametrize(
    "kwargs, name",
    [
        (dict(mask=np.ones((8, 8), np.uint8)), "mask"),
        (dict(mask=np.ones((8, 9), bool)), "mask"),
        (dict(div=np.ones((8, 8, 2))), "div"),
        (dict(method="cg"), "method"),
        (dict(screen=float("nan")), "screen"),
    ],
)
def test_dirichlet_solve_rejects_bad_parameters(kwargs, name):
    args = dict(image=np.ones((8, 8, 3)), mask=np.ones((8, 8), bool), div=np.ones((8, 8, 3)))
    args.update(kwargs)
    with pytest.raises(ParameterError, match=name):
        solve_dirichlet(args.pop("image"), args.pop("mask"), args.pop("div"), **args)


def test_neumann_solve_rejects_bad_parameters():
    with pytest.raises(ParameterError, match="screen"):
        solve_neumann(np.zeros((4, 4)), screen=-0.1)
    with pytest.raises(ParameterError, match="reference"):
        solve_neumann(np.zeros((4, 4)), screen=0.1, reference=np.zeros((4, 5)))
    with pytest.raises(ParameterError, match="div"):
        solve_neumann(np.zeros((4, 4, 3, 1)))


@pytest.mark.parametrize("small", [0, 400, 10_000])
def test_auto_splits_the_mask_into_components_and_agrees_with_lu(monkeypatch, small):
    """Components go to the LU (small ones) or multigrid, packed side by side: same answer."""
    import napari_lfalias.poisson as poisson

    monkeypatch.setattr(poisson, "SMALL_COMPONENT", small)
    rng = np.random.default_rng(13)
    base = rng.random((90, 120, 3)).astype(np.float32)
    source = ndimage.gaussian_filter(rng.random((90, 120, 3)), (3, 3, 0)).astype(np.float32)
    labels = np.zeros((90, 120), np.int8)
    labels[5:35, 5:40] = 1  # large components
    labels[50:85, 60:115] = 1
    labels[0:30, 80:120] = 1  # on the image's corner: Neumann there
    for y, x in rng.integers(40, 85, size=(25, 2)):  # small ones, some touching
        labels[y:y + 4, x - 35:x - 30] = 1
    labels[-3:, :4] = 1
    exact = fuse_gradients(base, [source], labels, method="lu")
    auto = fuse_gradients(base, [source], labels, method="auto", tol=1e-7)
    np.testing.assert_allclose(auto, exact, atol=1e-5)
    assert np.array_equal(auto[labels == 0], base[labels == 0])
