"""The soft outline of an in-focus occluder over a defocused background, matted from the views
(napari_lfalias._matting), against the dense-aperture reference of synthetic scenes."""

import numpy as np
import pytest
from scipy import ndimage

import napari_lfalias as lfa
from napari_lfalias import _matting, metrics
from napari_lfalias.synthetic import layered_scene

from _accuracy_scenes import as_user_has_it

BOX = (0.3, 0.7, 0.3, 0.7)


def _judged(layers, n_views, slope, seed, background_error=0.0, matting=True, monkeypatch=None):
    """(rendering, naive, reference, band): the rendering with the true disparity (its background's off by
    ``background_error``), and the background's pixels within 8 px of the in-focus occluder."""
    scene = layered_scene(layers, n_views=n_views, size=96, seed=seed)
    lf = as_user_has_it(scene.lightfield)
    truth = scene.disparity
    front = truth == np.float32(layers[0][0])
    given = np.where(front, truth, truth + np.float32(background_error))
    if not matting:
        monkeypatch.setattr(_matting, "BAND_PX", 0)
    rendering = np.asarray(lfa.antialiased_refocus(lf, slope, given))
    band = (ndimage.distance_transform_edt(~front) <= 8) & ~front
    return rendering, lfa.refocus(lf, slope), scene.reference(slope, interpolation="exact"), band


@pytest.mark.parametrize("layers, n_views, slope, seed, least", [
    # measured on the band: 59.7 dB (naive 43.2, the rendering unmatted 43.8)
    ([(0.0, "tiles", BOX), (-4.0, "lines", None)], 5, 0.0, 3, 55.0),
    # measured: 51.8 (naive 51.8, unmatted 41.9: the outline's mix blurred into a ring)
    ([(0.0, "noise", BOX), (3.0, "bricks", None)], 4, 0.0, 4, 50.0),
    # measured: 53.2 (naive 54.5, unmatted 45.8)
    ([(2.0, "checker", BOX), (-2.0, "noise", None)], 6, 2.0, 5, 51.0),
], ids=["tiles before lines", "noise before bricks", "checker before noise"])
def test_the_outline_of_an_in_focus_occluder_is_what_the_dense_aperture_sees(layers, n_views, slope, seed, least,
                                                                              monkeypatch):
    rendering, naive, reference, band = _judged(layers, n_views, slope, seed)
    assert metrics.psnr(rendering, reference, mask=band) >= least
    unmatted = _judged(layers, n_views, slope, seed, matting=False, monkeypatch=monkeypatch)[0]
    assert metrics.psnr(unmatted, reference, mask=band) < least - 5  # the ring it replaces is real


def test_a_wrong_background_disparity_is_not_matted_into_a_worse_outline():
    """Off by 1.5 px per view step, the background points taken for the views' samples are the wrong ones: the
    fit explains too little of the samples (``MIN_FIT``) and the outline is left as the renderer had it
    (measured on the band: 43.6 dB, the naive refocus 43.2; without the gate 36.2)."""
    layers = [(0.0, "tiles", BOX), (-4.0, "lines", None)]
    rendering, naive, reference, band = _judged(layers, 5, 0.0, 3, background_error=1.5)
    assert metrics.psnr(rendering, reference, mask=band) >= metrics.psnr(naive, reference, mask=band)


def test_a_flat_background_is_left_as_the_renderer_had_it(monkeypatch):
    """Its points do not vary across the views: the shares cannot be told apart, nor is there aliasing."""
    layers = [(0.0, "tiles", BOX), (-4.0, "flat", None)]
    rendering = _judged(layers, 5, 0.0, 3)[0]
    np.testing.assert_array_equal(rendering, _judged(layers, 5, 0.0, 3, matting=False, monkeypatch=monkeypatch)[0])
