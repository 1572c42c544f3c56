"""The widget's computations for one light field, with their caches (no Qt here).

What is cached follows DESIGN section 4: for the current slope the
luminance moments of the shifted views (exact method) and the shifted stack
(Monte Carlo) are kept, so changing gamma, N, the method or the seed
re-detects without shifting the views again; the last detection is kept, so
changing T only re-thresholds its Cv. Each computation is a generator that yields
``(done, total)`` between its steps, so a worker running it can report
progress and stop early when it is cancelled.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["DetectionParams", "AliasingSession", "LiveDetection", "exact_detection", "focus_range"]

#: Smallest mean luminance a Cv is divided by (dark pixels would blow Cv up).
MEAN_FLOOR = 1e-3

#: Focus range used when the data carry no disparities, in pixels per view step.
DEFAULT_FOCUS_RANGE = (-2.0, 2.0)


@dataclass(frozen=True)
class DetectionParams:
    """Parameters of Algorithm 1 (and 2), as the widget's controls hold them."""

    gamma: float = 0.2
    n_patterns: int = 100
    threshold: float = 0.02
    method: str = "analytic"
    seed: int = 0
    max_level: int = 3

    def api_kwargs(self):
        """Keyword arguments of ``detect_aliasing`` and ``reduce_aliasing``."""
        return {
            "gamma": self.gamma,
            "n_patterns": self.n_patterns,
            "threshold": self.threshold,
            "method": self.method,
            "seed": self.seed,
        }

    def detection_key(self, slope):
        """What a Cv depends on (everything but the threshold and the level)."""
        seed = self.seed if self.method == "monte_carlo" else None
        n_patterns = self.n_patterns if self.method == "monte_carlo" else None
        return (float(slope), self.gamma, n_patterns, self.method, seed)


def _finite_range(values):
    values = np.asarray(values, dtype=np.float64)
    values = values[np.isfinite(values)]
    if values.size == 0:
        return None
    return float(values.min()), float(values.max())


def focus_range(lf):
    """The slope range a focus control should span for ``lf``.

    Uses ``lf.meta["disparity_range"]`` when the decoder set it, else the
    range of a ground-truth disparity map in the metadata (``"disparity"``,
    ``"gt_disparity"``), padded by 10 %; else +/-2 px.

    Returns
    -------
    (low, high) : tuple of float
    """
    meta = lf.meta
    span = None
    if meta.get("disparity_range") is not None:
        span = _finite_range(meta["disparity_range"])
    else:
        for key in ("disparity", "gt_disparity", "disparity_gt"):
            if meta.get(key) is not None:
                span = _finite_range(meta[key])
                break
        if span is not None:
            pad = 0.1 * max(span[1] - span[0], 0.5)
            span = (span[0] - pad, span[1] + pad)
    if span is None or not span[1] > span[0]:
        return DEFAULT_FOCUS_RANGE
    return span


@dataclass(frozen=True)
class LiveDetection:
    """An exact Cv map (from kept moments) and its mask at one threshold.

    Offers what the widget uses of :class:`napari_lfalias.Detection`:
    ``cv``, ``mask`` and ``rethreshold``.
    """

    cv: np.ndarray
    threshold: float

    @property
    def mask(self):
        """Aliased pixels: ``cv > threshold``."""
        return self.cv > self.threshold

    def rethreshold(self, threshold):
        """The same Cv at another threshold."""
        return LiveDetection(self.cv, float(threshold))


def exact_detection(moments, params):
    """Exact (N -> infinity) Monte-Carlo Cv from the luminance moments of the views.

    DESIGN section 4: the mean of a uniformly random k-subset of the n views
    that see a pixel has variance ``s^2 (n - k) / (k (n - 1))``; with k
    uniform on ``ceil((1 - gamma) n) .. n`` the variance is
    ``s^2 (n E[1/k] - 1) / (n - 1)``, and Cv is its square root over the
    mean (floored).
    """
    count = np.asarray(moments.count).astype(np.intp, copy=False)
    factors = _variance_factors(int(count.max()) if count.size else 0, params.gamma)
    variance = moments.variance[..., 0] * factors[count]
    cv = np.sqrt(variance, dtype=np.float32) / np.maximum(moments.mean[..., 0], MEAN_FLOOR)
    return LiveDetection(cv.astype(np.float32, copy=False), params.threshold)


def _variance_factors(n_max, gamma):
    """``(n E[1/k] - 1) / (n - 1)`` for n = 0 .. n_max (0 where n < 2)."""
    factors = np.zeros(n_max + 1, np.float32)
    for n in range(2, n_max + 1):
        k = np.arange(math.ceil((1 - gamma) * n - 1e-9), n + 1, dtype=np.float64)
        factors[n] = (n * np.mean(1.0 / k) - 1.0) / (n - 1)
    return factors


class AliasingSession:
    """Refocus, detection and reduction of one light field, with caches.

    Parameters
    ----------
    lf : LightField
        The light field (a lazy one is read into memory once, by the first job).
    """

    def __init__(self, lf):
        self._source = lf
        self._lf = lf
        self._luminance = None  # the luminance light field, made when needed
        self._moments = None  # (slope, image, ViewMoments) of the last refocus
        self._stack = None  # ShiftedStack for one slope
        self._detection = None  # (key, Detection)

    @property
    def source_lf(self):
        """The light field as given (lazy ones stay lazy): for its metadata and shape."""
        return self._source

    @property
    def lf(self):
        """The light field, in memory (a lazy one is read on first use, in a worker)."""
        if self._lf.is_lazy:
            self._lf = self._lf.compute()
        return self._lf

    def close(self):
        """Free the caches."""
        self._luminance = self._stack = self._detection = self._moments = None

    # -- caches -------------------------------------------------------------
    def cached_stack(self, slope):
        """The shifted stack for ``slope`` if it is cached, else ``None``."""
        stack = self._stack
        if stack is not None and stack.slope == float(slope):
            return stack
        return None

    def stack(self, slope):
        """The views shifted for ``slope`` (computed once per slope)."""
        from .. import shift_views

        stack = self.cached_stack(slope)
        if stack is None:
            stack = shift_views(self.lf, float(slope))
            self._stack = stack
        return stack

    def cached_detection(self, slope, params):
        """The detection for ``slope`` and ``params``, thresholded at ``params.threshold``.

        Returns ``None`` when no detection with the same Cv is cached. A
        new threshold re-thresholds the cached Cv (no recomputation).
        """
        cached = self._detection
        if cached is None or cached[0] != params.detection_key(slope):
            return None
        key, detection, threshold = cached
        if threshold != params.threshold:
            detection = detection.rethreshold(params.threshold)
            self._detection = (key, detection, params.threshold)
        return detection

    def _remember(self, slope, params, detection):
        self._detection = (params.detection_key(slope), detection, params.threshold)

    # -- computations (generators yielding (done, total)) --------------------
    @property
    def luminance(self):
        """The one-channel (Rec. 709) light field, made once: the exact Cv is taken on it."""
        if self._luminance is None:
            self._luminance = self.lf.luminance()
        return self._luminance

    def focus(self, slope, params, with_detection=True):
        """Refocus on ``slope`` and, if asked, detect aliasing there.

        The exact method works from the refocus and the moments of the
        shifted luminance; Monte Carlo goes through the shifted stack.
        Yields ``(done, total)``; returns ``(image, detection or None)``.
        """
        slope = float(slope)
        if with_detection and params.method != "analytic":
            return (yield from self._focus_from_stack(slope, params))
        yield (0, 2)
        image, moments = self._refocus_and_moments(slope)
        if not with_detection:
            return image, None
        yield (1, 2)
        detection = self.cached_detection(slope, params)
        if detection is None:
            detection = exact_detection(moments, params)
            self._remember(slope, params, detection)
        return image, detection

    def _refocus_and_moments(self, slope):
        """The refocused image and the luminance moments at ``slope``, kept for the last slope.

        With the moments kept, a new gamma re-detects without touching the
        views, as a cached shifted stack does for Monte Carlo.
        """
        from .. import refocus, view_moments

        cached = self._moments
        if cached is not None and cached[0] == slope:
            return cached[1], cached[2]
        image, moments = refocus(self.lf, slope), view_moments(self.luminance, slope)
        self._moments = (slope, image, moments)
        return image, moments

    def _focus_from_stack(self, slope, params):
        from .. import detect_aliasing

        stack = self.stack(slope)
        yield (1, 3)
        image = stack.mean()
        yield (2, 3)
        detection = self.cached_detection(slope, params)
        if detection is None:
            detection = detect_aliasing(self.lf, slope, stack=stack, **params.api_kwargs())
            self._remember(slope, params, detection)
        return image, detection

    def detect(self, slope, params):
        """Detect aliasing at ``slope`` (reusing the shifted stack).

        Yields ``(done, total)``; returns the Detection.
        """
        image, detection = yield from self.focus(slope, params, with_detection=True)
        return detection

    def reduce(self, slope, params):
        """Reduce aliasing at ``slope`` (Algorithm 2).

        Yields ``(done, total)``; returns the Reduction.
        """
        from .. import reduce_aliasing

        yield (0, 1)
        reduction = reduce_aliasing(
            self.lf, float(slope), max_level=params.max_level, **params.api_kwargs()
        )
        yield (1, 1)
        return reduction
