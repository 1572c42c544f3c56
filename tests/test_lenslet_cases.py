"""The lenslet cases of the accuracy benchmark: decoded captures and their dense-aperture ground truth."""

import copy
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import napari_lfalias as lfa
from napari_lfalias import metrics
from napari_lfalias.errors import ParameterError

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from lenslet_cases import LensletGroundTruth, _in_focus_pixels, capture_case, lenslet_cases  # noqa: E402

#: Naive refocus of the decoded views against the dense reference, on an in-focus layer at 1 px of
#: disparity per view (grey sensor, noise 0.002): the decoder's residual (45 dB measured at size 128).
IN_FOCUS_PSNR = 40.0


@pytest.fixture(scope="module")
def wall_case():
    """A hexagonal grey capture: a noise occluder at +1 before a line-textured wall at -1."""
    return capture_case("test wall", "holdout", [(1.0, "noise", (0.35, 0.65, 0.35, 0.65)), (-1.0, "lines", None)],
                        [-1.0, 5.0], size=96, kind="hexagonal", pitch=9.9, rotation=-0.7, noise=0.002,
                        vignetting=0.5, seed=34)


def test_the_reference_agrees_with_the_naive_refocus_in_focus(wall_case):
    truth = wall_case.extra["truth"]
    lf = wall_case.lightfield
    naive = lfa.refocus(lf, -1.0)
    reference = wall_case.reference(-1.0)
    focus = _in_focus_pixels(truth, -1.0, naive.shape[:2])
    assert focus.sum() > 1500
    assert metrics.psnr(naive, reference, mask=focus) >= IN_FOCUS_PSNR
    # the agreement is a property of the geometry: the same reference placed one pixel off fails it
    shifted = copy.copy(truth)
    shifted.origin = (truth.origin[0] + 1.0, truth.origin[1])
    assert metrics.psnr(naive, shifted.reference(-1.0), mask=focus) < IN_FOCUS_PSNR - 10


def test_out_of_focus_the_wall_aliases_and_the_reference_does_not(wall_case):
    naive = lfa.refocus(wall_case.lightfield, 5.0)
    reference, comb = wall_case.reference(5.0), wall_case.comb(5.0)
    aliased = wall_case.truth(5.0, naive)
    assert aliased.mean() > 0.1  # ghost spacing 6 px on the wall's lines
    # the views' comb and the decoded refocus show the same ghosts; the dense aperture does not
    assert metrics.psnr(naive, comb, mask=aliased) > metrics.psnr(naive, reference, mask=aliased) + 3
    # across the lines' ghosts, the dense aperture is smooth
    def ripple(image):
        return np.abs(np.diff(image[..., 0], axis=1))[aliased[:, 1:]].mean()

    assert ripple(reference) < 0.5 * ripple(comb)


def test_the_reference_converges_as_the_aperture_gets_denser(wall_case):
    truth = wall_case.extra["truth"]
    m = truth.samples_per_view(5.0)
    assert m == 24  # 6 px per view step / 0.25 px
    finest = truth.reference(5.0, 4 * m)
    errors = [np.abs(truth.reference(5.0, k) - finest).max() for k in (1, 3, m // 2, m)]
    assert all(a > b for a, b in zip(errors, errors[1:])), errors
    assert errors[-1] < 2e-3 and errors[0] > 0.05
    # one sample per view cell is the views' own comb
    np.testing.assert_allclose(truth.reference(5.0, 1), wall_case.comb(5.0), atol=1e-6)


def test_the_ground_truth_follows_the_decoded_geometry(wall_case):
    lf = wall_case.lightfield
    truth = wall_case.extra["truth"]
    assert lf.meta["grid"].kind == "hexagonal" and lf.n_channels == 1
    assert truth.geometry_error < 0.01
    assert wall_case.reference(5.0).shape == lf.image_shape + (1,)
    assert wall_case.disparity.shape == lf.image_shape
    assert set(np.unique(wall_case.disparity)) == {-1.0, 1.0}
    # the views the decoder keeps: those inside the microlens disc, corner views excluded
    assert truth.on.sum() == int((np.hypot(*np.moveaxis(lf.positions, -1, 0)) <= 9.9 / 2).sum())
    assert not truth.on[0, 0] and truth.on[4, 4]


def test_the_lenslet_cases_build_at_a_small_size():
    cases = lenslet_cases(size=40)
    assert len({case.name for case in cases}) == len(cases) >= 4
    assert {case.split for case in cases} == {"tune", "holdout"}
    for case in cases:
        lf = case.lightfield
        assert lf.weights is not None and lf.meta["format"].startswith("lenslet TIFF")
        slope = case.slopes[0]
        reference = case.reference(slope)
        assert reference.shape == lf.image_shape + (lf.n_channels,) and np.isfinite(reference).all()
        assert case.comb(slope).shape == reference.shape and case.disparity.shape == lf.image_shape


def test_cases_render_at_scale_one_only(wall_case):
    capture = replace(wall_case.extra["truth"].capture, scale=0.5)
    with pytest.raises(ParameterError, match="scale=1"):
        LensletGroundTruth(wall_case.extra["truth"].scene, capture, wall_case.lightfield)
