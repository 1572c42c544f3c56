"""Quality and detection metrics against hand-computed cases and scikit-image."""

import itertools

import numpy as np
import pytest
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

from napari_lfalias import ParameterError
from napari_lfalias.metrics import (
    DetectionScores,
    GradientDifference,
    gradient_difference,
    precision_recall_f1,
    psnr,
    roc_auc,
    ssim,
)


@pytest.fixture
def pair():
    rng = np.random.default_rng(0)
    reference = rng.random((40, 48, 3))
    image = np.clip(reference + rng.normal(0, 0.05, reference.shape), 0, 1)
    return image, reference


# -- PSNR -------------------------------------------------------------------------

def test_psnr_hand_case():
    reference = np.zeros((4, 5))
    image = reference.copy()
    image[1, 2] = 0.5  # MSE = 0.25 / 20
    assert psnr(image, reference) == pytest.approx(10 * np.log10(20 / 0.25))
    assert psnr(image, reference, data_range=2.0) == pytest.approx(10 * np.log10(4 * 20 / 0.25))
    assert psnr(reference, reference) == float("inf")


def test_psnr_matches_skimage_and_restricts_to_the_mask(pair):
    image, reference = pair
    assert psnr(image, reference) == pytest.approx(peak_signal_noise_ratio(reference, image, data_range=1.0))
    mask = np.zeros(image.shape[:2], bool)
    mask[5:20, 10:30] = True
    expected = peak_signal_noise_ratio(reference[mask], image[mask], data_range=1.0)
    assert psnr(image, reference, mask=mask) == pytest.approx(expected)
    image[~mask] = 0  # damage outside the mask changes nothing inside
    assert psnr(image, reference, mask=mask) == pytest.approx(expected)


# -- SSIM -------------------------------------------------------------------------

def skimage_ssim(image, reference, data_range, **kwargs):
    return structural_similarity(image, reference, data_range=data_range, gaussian_weights=True, sigma=1.5,
                                 use_sample_covariance=False, **kwargs)


@pytest.mark.parametrize("data_range", [1.0, 4.0])
def test_ssim_matches_skimage_with_wang_settings(pair, data_range):
    image, reference = pair
    colour = ssim(image, reference, data_range=data_range)
    assert colour == pytest.approx(skimage_ssim(image, reference, data_range, channel_axis=-1), abs=1e-10)
    grey = ssim(image[..., 1], reference[..., 1], data_range=data_range)
    assert grey == pytest.approx(skimage_ssim(image[..., 1], reference[..., 1], data_range), abs=1e-10)


def test_ssim_data_range_is_used(pair):
    image, reference = pair
    assert ssim(image, reference, data_range=1.0) < ssim(image, reference, data_range=10.0)


def test_ssim_mask_is_the_mean_of_the_map_over_the_mask(pair):
    image, reference = pair
    _, skimage_map = skimage_ssim(image, reference, 1.0, channel_axis=-1, full=True)
    mask = np.zeros(image.shape[:2], bool)
    mask[10:30, 8:25] = True
    value, ssim_map = ssim(image, reference, mask=mask, full=True)
    np.testing.assert_allclose(ssim_map, skimage_map.mean(axis=-1), atol=1e-10)
    assert value == pytest.approx(skimage_map.mean(axis=-1)[mask].mean(), abs=1e-12)
    assert ssim(reference, reference, mask=mask) == pytest.approx(1.0)


def test_ssim_hand_case_constant_images():
    # constant images: SSIM = (2 a b + C1) / (a^2 + b^2 + C1), the structure term is 1
    a, b = np.full((16, 16), 0.2), np.full((16, 16), 0.6)
    c1 = (0.01 * 1.0) ** 2
    assert ssim(a, b) == pytest.approx((2 * 0.2 * 0.6 + c1) / (0.2 ** 2 + 0.6 ** 2 + c1))


# -- gradient differences ------------------------------------------------------------------

def test_gradient_difference_hand_cases():
    y, x = np.mgrid[0:10, 0:12].astype(float)
    reference = np.sin(x) * np.cos(y)
    assert gradient_difference(reference + 0.3, reference) == pytest.approx(GradientDifference(0.0, 0.0), abs=1e-15)
    # a ramp of slope 0.5 in x and 0.25 in y: |difference| = sqrt(0.5^2 + 0.25^2) everywhere
    result = gradient_difference(reference + 0.5 * x + 0.25 * y, reference)
    assert result.mean == pytest.approx(np.hypot(0.5, 0.25))
    assert result.variance == pytest.approx(0.0, abs=1e-20)


def test_gradient_difference_statistics_over_a_mask_and_channels():
    x = np.tile(np.arange(12.0), (10, 1))
    reference = np.zeros((10, 12, 2))
    image = np.zeros((10, 12, 2))
    image[:, :6, 0] = 1.0 * x[:, :6]  # slope 1 in channel 0 on the left half
    image[:, 6:, 1] = 3.0 * x[:, 6:]  # slope 3 in channel 1 on the right half
    left, right = np.zeros((10, 12), bool), np.zeros((10, 12), bool)
    left[:, :5], right[:, 7:] = True, True  # away from the seam
    assert gradient_difference(image, reference, mask=left) == pytest.approx((1.0, 0.0))
    assert gradient_difference(image, reference, mask=right) == pytest.approx((3.0, 0.0))
    both = gradient_difference(image, reference, mask=left | right)
    n_left, n_right = left.sum(), right.sum()
    mean = (n_left * 1 + n_right * 3) / (n_left + n_right)
    var = (n_left * (1 - mean) ** 2 + n_right * (3 - mean) ** 2) / (n_left + n_right)
    assert both.mean == pytest.approx(mean) and both.variance == pytest.approx(var)


# -- detection ---------------------------------------------------------------------------

def brute_force_auc(scores, truth):
    pos, neg = scores[truth], scores[~truth]
    wins = sum(1.0 if p > n else 0.5 if p == n else 0.0 for p, n in itertools.product(pos, neg))
    return wins / (len(pos) * len(neg))


def test_roc_auc_hand_cases():
    assert roc_auc([0.1, 0.4, 0.35, 0.8], [False, False, True, True]) == pytest.approx(0.75)
    assert roc_auc([0, 1, 2, 3], [False, False, True, True]) == 1.0
    assert roc_auc([3, 2, 1, 0], [False, False, True, True]) == 0.0
    assert roc_auc([1, 1, 1, 1], [True, False, True, False]) == 0.5


def test_roc_auc_handles_ties_like_pairwise_counting():
    rng = np.random.default_rng(1)
    scores = rng.integers(0, 5, size=60).astype(float)  # many ties
    truth = rng.random(60) < 0.4
    assert roc_auc(scores, truth) == pytest.approx(brute_force_auc(scores, truth))
    assert roc_auc(scores.reshape(6, 10), truth.reshape(6, 10)) == pytest.approx(brute_force_auc(scores, truth))


def test_precision_recall_f1_hand_cases():
    mask = np.array([True, True, True, False, False, False])
    truth = np.array([True, False, False, True, False, False])
    p, r, f1 = precision_recall_f1(mask, truth)
    assert (p, r) == pytest.approx((1 / 3, 1 / 2))
    assert f1 == pytest.approx(2 * (1 / 3) * (1 / 2) / (1 / 3 + 1 / 2))
    assert isinstance(precision_recall_f1(mask, truth), DetectionScores)
    assert precision_recall_f1(np.zeros(4, bool), np.zeros(4, bool)) == (1.0, 1.0, 1.0)
    assert precision_recall_f1(np.zeros(4, bool), truth[:4]) == (0.0, 0.0, 0.0)
    assert precision_recall_f1(mask[:4], np.zeros(4, bool)) == (0.0, 0.0, 0.0)


# -- bad input ------------------------------------------------------------------------------

@pytest.mark.parametrize("metric", [psnr, ssim, gradient_difference])
def test_image_metrics_reject_bad_input(metric):
    good = np.zeros((16, 16, 3))
    with pytest.raises(ParameterError, match="reference"):
        metric(good, np.zeros((16, 15, 3)))
    with pytest.raises(ParameterError, match="image"):
        metric(np.full((16, 16, 3), np.nan), good)
    with pytest.raises(ParameterError, match="image"):
        metric(np.zeros(16), np.zeros(16))
    with pytest.raises(ParameterError, match="mask"):
        metric(good, good, mask=np.zeros((16, 16), bool))
    with pytest.raises(ParameterError, match="mask"):
        metric(good, good, mask=np.ones((16, 16), np.uint8))
    with pytest.raises(ParameterError, match="mask"):
        metric(good, good, mask=np.ones((15, 16), bool))


def test_metrics_reject_bad_parameters():
    good = np.zeros((16, 16))
    for value in (0.0, -1.0, float("nan")):
        with pytest.raises(ParameterError, match="data_range"):
            psnr(good, good, data_range=value)
        with pytest.raises(ParameterError, match="data_range"):
            ssim(good, good, data_range=value)
    with pytest.raises(ParameterError, match="image"):
        ssim(np.zeros((8, 8)), np.zeros((8, 8)))  # smaller than the 11-tap window
    with pytest.raises(ParameterError, match="truth"):
        roc_auc([1, 2, 3], [True, True, True])
    with pytest.raises(ParameterError, match="truth"):
        roc_auc([1, 2, 3], [1, 0, 1])
    with pytest.raises(ParameterError, match="scores"):
        roc_auc([1, np.inf, 3], [True, False, True])
    with pytest.raises(ParameterError, match="truth"):
        precision_recall_f1(np.ones(3, bool), np.ones(4, bool))
    with pytest.raises(ParameterError, match="mask"):
        precision_recall_f1(np.ones(3), np.ones(3, bool))
