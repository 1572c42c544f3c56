"""Image-quality and detection metrics: PSNR, SSIM, gradient differences, ROC AUC, precision/recall.

Images are ``(Y, X)`` or ``(Y, X, C)`` arrays; a ``mask`` ``(Y, X)`` of
bools restricts a score to its pixels (for example the in-focus or the
aliased region). Every input is checked: shapes must match, values must
be finite, a mask must select at least one pixel; a bad input raises
:class:`~napari_lfalias.errors.ParameterError` naming the parameter.

Examples
--------
>>> import numpy as np
>>> from napari_lfalias.metrics import psnr, ssim
>>> reference = np.zeros((16, 16))
>>> round(psnr(reference + 0.1, reference), 6)
20.0
>>> round(ssim(reference, reference), 6)
1.0
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy import ndimage, stats

from . import _validate
from .errors import ParameterError

__all__ = [
    "psnr",
    "ssim",
    "gradient_difference",
    "GradientDifference",
    "roc_auc",
    "precision_recall_f1",
    "DetectionScores",
    "luminance_difference",
    "aliased_pixels",
    "PERCEPTIBLE",
]

#: Relative luminance difference a viewer perceives (the paper's T = 0.02, "minimal intensity of
#: perceivable aliasing"): the ground truth of aliasing (DESIGN section 8).
PERCEPTIBLE = 0.02
#: The light blur (Gaussian sigma, px) applied before comparing, so single-pixel noise does not count.
TRUTH_BLUR = 1.0
#: The luminance a difference is divided by is at least this fraction of the brightest.
TRUTH_FLOOR = 0.01

#: SSIM settings of Wang et al. (2004): Gaussian window, its truncation (11 taps), K1, K2.
SSIM_SIGMA = 1.5
SSIM_TRUNCATE = 3.5
SSIM_K1 = 0.01
SSIM_K2 = 0.03


# -- input checks ---------------------------------------------------------------

def _finite_array(name, array):
    array = np.asarray(array)
    if array.dtype == np.bool_ or not np.issubdtype(array.dtype, np.number) \
            or np.issubdtype(array.dtype, np.complexfloating):
        raise ParameterError(f"{name} must be a real numeric array, got dtype {array.dtype}")
    array = array.astype(np.float64, copy=False)
    if not np.all(np.isfinite(array)):
        raise ParameterError(f"{name} holds NaN or Inf values")
    return array


def _image_pair(image, reference):
    """Both images as float64 ``(Y, X, C)`` arrays of the same shape."""
    image = _finite_array("image", image)
    reference = _finite_array("reference", reference)
    if image.ndim not in (2, 3) or min(image.shape, default=0) < 1:
        raise ParameterError(f"image must have shape (Y, X) or (Y, X, C), got {image.shape}")
    if reference.shape != image.shape:
        raise ParameterError(f"reference must have the shape of image {image.shape}, got {reference.shape}")
    if image.ndim == 2:
        image, reference = image[..., None], reference[..., None]
    return image, reference


def _region(mask, shape):
    """``mask`` checked against the image's ``(Y, X)``; ``None`` selects every pixel."""
    if mask is None:
        return np.ones(shape, bool)
    mask = np.asarray(mask)
    if mask.dtype != np.bool_:
        raise ParameterError(f"mask must be a boolean array, got dtype {mask.dtype}")
    if mask.shape != shape:
        raise ParameterError(f"mask must have the image's shape (Y, X) = {shape}, got {mask.shape}")
    if not mask.any():
        raise ParameterError("mask selects no pixel; pass a mask with at least one True value")
    return mask


def _data_range(data_range):
    return _validate.positive_float("data_range", data_range)


# -- image quality ---------------------------------------------------------------

def psnr(image, reference, data_range=1.0, mask=None):
    """Peak signal-to-noise ratio in dB: ``10 log10(data_range^2 / MSE)``.

    Parameters
    ----------
    image, reference : array_like, shape (Y, X) or (Y, X, C)
        The image to score and the ground truth.
    data_range : float
        The range of the intensities (1 for images in [0, 1]).
    mask : array_like of bool, shape (Y, X), optional
        The pixels the mean squared error runs over (every channel).

    Returns
    -------
    float
        ``inf`` when the images are equal on the region.

    Examples
    --------
    >>> import numpy as np
    >>> a = np.zeros((4, 4, 3))
    >>> b = a.copy()
    >>> b[0, 0] = 0.4  # squared error 0.16 on 1 of 16 pixels
    >>> round(psnr(b, a), 4)
    20.0
    """
    image, reference = _image_pair(image, reference)
    data_range = _data_range(data_range)
    region = _region(mask, image.shape[:2])
    mse = float(np.mean((image[region] - reference[region]) ** 2))
    if mse == 0.0:
        return float("inf")
    return float(10.0 * np.log10(data_range ** 2 / mse))


def _ssim_map(a, b, data_range):
    """SSIM map of two 2-D float64 images (Wang et al. 2004, population statistics)."""

    def blur(x):
        return ndimage.gaussian_filter(x, SSIM_SIGMA, truncate=SSIM_TRUNCATE, mode="reflect")

    mu_a, mu_b = blur(a), blur(b)
    var_a = blur(a * a) - mu_a * mu_a
    var_b = blur(b * b) - mu_b * mu_b
    cov = blur(a * b) - mu_a * mu_b
    c1 = (SSIM_K1 * data_range) ** 2
    c2 = (SSIM_K2 * data_range) ** 2
    return ((2 * mu_a * mu_b + c1) * (2 * cov + c2)) / ((mu_a ** 2 + mu_b ** 2 + c1) * (var_a + var_b + c2))


def ssim(image, reference, data_range=1.0, mask=None, full=False):
    """Mean structural similarity (Wang et al. 2004).

    Gaussian window with sigma 1.5 truncated to 11 taps, ``K1 = 0.01``,
    ``K2 = 0.03``, population (co)variances, reflected borders. The mean
    leaves out a 5-pixel border (half the window), as
    :func:`skimage.metrics.structural_similarity` does; with ``mask`` it
    is the mean of the SSIM map over the masked pixels of that interior.
    Colour images score the mean over channels.

    Parameters
    ----------
    image, reference : array_like, shape (Y, X) or (Y, X, C)
        The image to score and the ground truth, at least 11 x 11.
    data_range : float
        The range of the intensities (1 for images in [0, 1]).
    mask : array_like of bool, shape (Y, X), optional
        The pixels to average over.
    full : bool
        Also return the SSIM map (mean over channels), shape (Y, X).

    Returns
    -------
    float, or (float, ndarray)

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> a = rng.random((32, 32))
    >>> ssim(a, a) == 1.0, ssim(a, 1 - a) < 0
    (True, True)
    """
    image, reference = _image_pair(image, reference)
    data_range = _data_range(data_range)
    region = _region(mask, image.shape[:2])
    pad = int(SSIM_TRUNCATE * SSIM_SIGMA + 0.5)
    if min(image.shape[:2]) < 2 * pad + 1:
        raise ParameterError(f"image must be at least {2 * pad + 1} x {2 * pad + 1} pixels for SSIM, "
                             f"got {image.shape[:2]}")
    maps = [_ssim_map(image[..., c], reference[..., c], data_range) for c in range(image.shape[2])]
    ssim_map = np.mean(maps, axis=0)
    interior = np.zeros(region.shape, bool)
    interior[pad:-pad, pad:-pad] = True
    region = region & interior
    if not region.any():
        raise ParameterError(f"mask selects no pixel more than {pad} pixels from the image's border")
    mean = float(ssim_map[region].mean())
    return (mean, ssim_map) if full else mean


class GradientDifference(NamedTuple):
    """Statistics of ``|grad(image) - grad(reference)|`` over a region (Xiao et al. 2014, Figure 6)."""

    mean: float
    variance: float


def gradient_difference(image, reference, mask=None, full=False):
    """Mean and variance of the magnitude of the gradient difference.

    The gradients are central differences (one-sided at the border,
    :func:`numpy.gradient`) of each channel; the magnitude at a pixel is
    the Euclidean norm over both axes and every channel of
    ``grad(image) - grad(reference)``. The variance is the population
    variance over the region.

    Parameters
    ----------
    image, reference : array_like, shape (Y, X) or (Y, X, C)
        The image to score and the reference (at least 2 x 2).
    mask : array_like of bool, shape (Y, X), optional
        The pixels the statistics run over.
    full : bool
        Also return the magnitude map ``(Y, X)``.

    Returns
    -------
    GradientDifference, or (GradientDifference, ndarray)

    Examples
    --------
    >>> import numpy as np
    >>> ramp = np.tile(np.arange(8.0), (8, 1))
    >>> gradient_difference(2 * ramp, ramp)   # the x-gradients differ by 1 everywhere
    GradientDifference(mean=1.0, variance=0.0)
    """
    image, reference = _image_pair(image, reference)
    region = _region(mask, image.shape[:2])
    if min(image.shape[:2]) < 2:
        raise ParameterError(f"image must be at least 2 x 2 pixels, got {image.shape[:2]}")
    dy, dx = np.gradient(image - reference, axis=(0, 1))
    magnitude = np.sqrt((dy ** 2 + dx ** 2).sum(axis=2))
    values = magnitude[region]
    result = GradientDifference(float(values.mean()), float(values.var()))
    return (result, magnitude) if full else result


# -- detection -----------------------------------------------------------------------

def _truth(name, truth, shape):
    truth = np.asarray(truth)
    if truth.dtype != np.bool_:
        raise ParameterError(f"{name} must be a boolean array, got dtype {truth.dtype}")
    if truth.shape != shape:
        raise ParameterError(f"{name} must have shape {shape}, got {truth.shape}")
    return truth


def roc_auc(scores, truth):
    """Area under the ROC curve of ``scores`` predicting ``truth``.

    The Mann-Whitney statistic: the probability that a random positive
    scores higher than a random negative, ties counting one half (average
    ranks), so it is exact for any number of tied scores.

    Parameters
    ----------
    scores : array_like
        A score per sample (higher = more likely positive), e.g. the Cv map.
    truth : array_like of bool, same shape
        The true labels; both classes must occur.

    Returns
    -------
    float
        In [0, 1]; 0.5 for scores that carry no information.

    Examples
    --------
    >>> roc_auc([0.1, 0.4, 0.35, 0.8], [False, False, True, True])
    0.75
    >>> roc_auc([1, 1, 1, 1], [False, True, False, True])
    0.5
    """
    scores = _finite_array("scores", scores)
    truth = _truth("truth", truth, scores.shape)
    scores, truth = scores.ravel(), truth.ravel()
    n_pos = int(truth.sum())
    n_neg = truth.size - n_pos
    if n_pos == 0 or n_neg == 0:
        raise ParameterError(
            f"truth must hold both classes to define a ROC curve; got {n_pos} positives and {n_neg} negatives"
        )
    ranks = stats.rankdata(scores)  # average ranks of ties
    u = ranks[truth].sum() - n_pos * (n_pos + 1) / 2.0
    return float(u / (n_pos * n_neg))


class DetectionScores(NamedTuple):
    """Precision, recall and F1 of a binary detection."""

    precision: float
    recall: float
    f1: float


def precision_recall_f1(mask, truth):
    """Precision, recall and F1 score of the detection ``mask`` against ``truth``.

    ``precision = TP / (TP + FP)``, ``recall = TP / (TP + FN)``,
    ``F1 = 2 P R / (P + R)``. An empty detection has precision 1 when the
    truth is empty too, else 0; an empty truth gives recall 1 when the
    detection is empty too, else 0 (an empty detection of an empty truth
    scores 1, 1, 1).

    Parameters
    ----------
    mask : array_like of bool
        The detection (e.g. ``Detection.mask``).
    truth : array_like of bool, same shape
        The true labels.

    Returns
    -------
    DetectionScores

    Examples
    --------
    >>> precision_recall_f1([True, True, False, False], [True, False, True, False])
    DetectionScores(precision=0.5, recall=0.5, f1=0.5)
    """
    mask = np.asarray(mask)
    if mask.dtype != np.bool_:
        raise ParameterError(f"mask must be a boolean array, got dtype {mask.dtype}")
    truth = _truth("truth", truth, mask.shape)
    tp = int(np.count_nonzero(mask & truth))
    predicted = int(np.count_nonzero(mask))
    actual = int(np.count_nonzero(truth))
    precision = tp / predicted if predicted else float(actual == 0)
    recall = tp / actual if actual else float(predicted == 0)
    f1 = 2 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0
    return DetectionScores(float(precision), float(recall), float(f1))


# -- the ground truth of aliasing ---------------------------------------------------------

def _luminance(image):
    from .lightfield import REC709

    image = np.asarray(image, np.float32)
    if image.ndim == 2:
        return image
    return image[..., 0] if image.shape[-1] == 1 else image @ REC709


def luminance_difference(image, reference, sigma=TRUTH_BLUR, floor=TRUTH_FLOOR):
    """Relative luminance difference of ``image`` from ``reference`` after a light blur.

    ``|G*L(image) - G*L(reference)| / max(G*L(reference), floor * max L(reference))``
    with ``L`` the Rec. 709 luminance and ``G`` a Gaussian of ``sigma`` px.

    Parameters
    ----------
    image, reference : array_like, shape (Y, X) or (Y, X, C)
        Linear intensity.
    sigma : float
        The blur (0: none).
    floor : float
        Fraction of the reference's brightest luminance that floors the
        divisor (dark pixels do not blow up).

    Returns
    -------
    ndarray, shape (Y, X), float32

    Examples
    --------
    >>> import numpy as np
    >>> a = np.full((8, 8, 1), 0.50, np.float32)
    >>> round(float(luminance_difference(a * 1.02, a).max()), 3)
    0.02
    """
    image, reference = _image_pair(image, reference)
    return _relative_difference(_blurred_luminance(image, sigma), _blurred_luminance(reference, sigma), floor)


def _blurred_luminance(image, sigma=TRUTH_BLUR):
    """``G*L(image)`` of :func:`luminance_difference`, for a checked ``(Y, X, C)`` image (one that several
    differences share is made once)."""
    luminance = _luminance(image)
    return ndimage.gaussian_filter(luminance, sigma) if sigma > 0 else luminance


def _relative_difference(blurred, blurred_reference, floor=TRUTH_FLOOR):
    """:func:`luminance_difference` of two :func:`_blurred_luminance` images."""
    bottom = max(float(floor) * float(blurred_reference.max(initial=0.0)), float(np.finfo(np.float32).tiny))
    return (np.abs(blurred - blurred_reference) / np.maximum(blurred_reference, bottom)).astype(np.float32)


def aliased_pixels(naive, reference, tolerance=PERCEPTIBLE):
    """The ground truth of aliasing: where the naive refocus differs perceptibly from the dense aperture.

    Parameters
    ----------
    naive : array_like, shape (Y, X, C)
        The sparse refocus (:func:`napari_lfalias.refocus`).
    reference : array_like, shape (Y, X, C)
        What a dense aperture records (a synthetic scene's
        ``reference(slope)``, or the refocus of all views of a real array
        when ``naive`` uses a sub-grid spanning the same aperture).
    tolerance : float
        Relative luminance difference that counts (after a 1 px blur).

    Returns
    -------
    ndarray, shape (Y, X), bool

    Examples
    --------
    >>> import numpy as np
    >>> ref = np.full((8, 8, 3), 0.5, np.float32)
    >>> int(aliased_pixels(ref * 1.05, ref).sum()), int(aliased_pixels(ref * 1.01, ref).sum())
    (64, 0)
    """
    return luminance_difference(naive, reference) > tolerance
