"""Angular-aliasing detection: Algorithm 1 of Xiao et al. (CVPR 2014).

A refocused pixel is aliased when refocusing it from slightly different
subsets of the views changes it noticeably. Algorithm 1 draws ``N`` random
sampling patterns, each keeping a uniformly random subset of ``k`` of the
``n`` views (``k`` uniform on ``ceil((1 - gamma) n) .. n``), refocuses with
each, and measures the coefficient of variation of the ``N`` results
(Eq. 7) on luminance::

    Cv = std / mean      (population std over the N refocused values)

A pixel is aliased where ``Cv > T``.

Two methods
-----------
``"monte_carlo"``
    The paper's estimate. The views are shifted once (one
    :class:`~napari_lfalias.refocus.ShiftedStack` per slope and pyramid
    level). A pattern drops at most ``gamma n`` views, so each of the
    ``N`` refocused values is the sum over all views less the few dropped
    ones: about 6 additions per pattern and pixel for 8x8 views at
    gamma = 0.2, where the matrix product ``W @ S`` of DESIGN section 4
    makes 58. Seeded, so runs repeat.
``"analytic"`` (default)
    The ``N -> infinity`` limit of the same estimate, exactly and in one
    pass. The mean of a uniformly random ``m``-subset of ``n_p`` values has
    variance ``s^2 (n_p - m) / (m (n_p - 1))`` (finite-population
    correction), ``s^2`` the population variance of the ``n_p`` shifted
    views that see the pixel. Averaging over ``k`` and over the number ``m``
    of the kept views that see the pixel (hypergeometric), given ``m >= 1``,
    gives ``Var = c(gamma, n, n_p) s^2`` (:func:`variance_factors`), so
    ``Cv = sqrt(c) s / mean``. With every view seeing the pixel,
    ``c = (n E[1/k] - 1) / (n - 1)``.

What ``T`` means
----------------
``Cv = sqrt(c) * (s / mean)``: the paper's Cv is the *angular* coefficient
of variation ``s / mean`` of the shifted views, scaled by ``sqrt(c)``, which
depends on gamma and on the number of views (0.042 for 8x8 views at
gamma = 0.2, 0.038 for 9x9). The paper's ``T = 0.02`` therefore flags
angular variations above about 48 % on an 8x8 array and 53 % on 9x9.
``threshold_scale="angular"`` states ``T`` on ``s / mean`` itself, the
same sensitivity for any array and gamma (``Detection.angular_cv``).

Measured against ground truth (``benchmarks/results/detection.md``: the
naive refocus 2 % away from the dense-aperture reference, on synthetic
scenes): the paper's ``T = 0.02`` finds little of the perceptible aliasing
(F1 0.01-0.02 on the paper's 8x8 set-up); ``T`` between 0.001 and 0.004
on Cv finds it best (F1 0.49-0.96). The best angular threshold varies
more across array sizes than the best Cv threshold, because Cv's
``sqrt(c)`` also tracks how aliasing fades as views get denser; so the
default stays the paper's scale and value, and a lower ``T`` (e.g.
0.003) is the measured choice for "anything visible".

Numerics
--------
Moments are accumulated in float64 as deviations from one of each pixel's
own samples (:func:`~napari_lfalias.refocus.view_moments`), never as
``E[x^2] - E[x]^2`` of the raw values; variances are clamped at 0. The
Monte-Carlo pattern means are taken as deviations from each pixel's mean
over all views, so an offset (data = 1000 + small variations) costs no
precision. The mean a Cv is divided by is floored at
``dark_floor`` times the brightest luminance of the light field (default
1 %), so black and near-black pixels get a finite Cv that sensor noise
cannot push over ``T``, and Cv stays invariant to a scaling of the data.
Data whose brightest luminance lies outside ``[2**-16, 2**16]`` are first
multiplied by a power of two that brings it near 1 (exact in float32), so
float32 moments neither overflow nor underflow: Cv is the same for any
finite positive scale of the data (1e-30 and 1e30 included).
A spread across views below ``2**-24`` of the mean (half a float32 step)
is rounding of the sums, not in the float32 data: it counts as 0, so a
constant light field has Cv exactly 0.

Work a scene does not need is skipped
-------------------------------------
Before anything is shifted, the image is cut into tiles; a tile whose
samples, over every view and over the footprint the shifts can reach, span
``[a, b]`` has ``s <= (b - a) / 2`` and ``mean >= a``, which bounds its Cv.
A tile whose bound cannot exceed ``T`` is not computed (its ``cv`` reads 0
and ``Detection.evaluated`` is False there) -- when skipping pays: the exact
method then computes runs of tiles, which cost more per pixel than one
pass over the image, so narrow gaps are computed and nothing is skipped
unless the runs left are predicted to cost less (:data:`SKIP_WORTH`; where
nothing can be skipped, skipping costs a few per cent, see
``benchmarks/results/skip_flat.md``). The per-tile ranges do not depend on
the slope and are made once per light field, in the same pass as the
luminance.
:class:`AliasingDetector` keeps them, the pyramid, the moments and the
shifted stacks of the last slope: a new gamma, ``N`` or seed reuses the
shifted views, and a new ``T`` only re-thresholds (:meth:`Detection.rethreshold`).
"""

from __future__ import annotations

import functools
import math
import threading
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from scipy import ndimage
from scipy.special import gammaln

from . import _budget, _validate
from ._numerics import unit_scale
from ._tiles import tiles_holding
from .errors import ParameterError
from .lightfield import REC709, LightField
from .presets import METHODS, THRESHOLD_SCALES, detection_options
from .pyramid import MAX_LEVEL, lightfield_pyramid
from .refocus import _inputs, _run, shift_views

__all__ = [
    "Detection",
    "AliasingDetector",
    "detect_aliasing",
    "variance_factors",
    "sampling_patterns",
    "smallest_subset",
    "METHODS",
    "THRESHOLD_SCALES",
    "DARK_FLOOR",
]

#: The methods that compute the paper's Cv (Eq. 7).
CV_METHODS = ("analytic", "monte_carlo")
LUMINANCE_MODES = ("rec709", "max")
#: Floor of the mean a Cv is divided by, as a fraction of the light field's brightest luminance.
DARK_FLOOR = 0.01
#: Side of the tiles that are skipped when they cannot alias (pixels).
TILE = 32
#: Cost of the exact method's moments computed on runs of tiles, relative to one pass over the
#: whole image: per pixel, and per row of each run (in pixels of the whole-image pass); measured
#: in benchmarks/results/skip_flat.md. Skipping flat tiles must never cost more than it saves.
TILED_PIXEL_COST = 1.2
TILED_RUN_COST = 64.0
#: Skip flat tiles only if the runs left are predicted to cost at most this share of the whole pass.
SKIP_WORTH = 0.9


# -- the statistics of random sampling patterns ------------------------------------

def smallest_subset(n, gamma):
    """Fewest views a sampling pattern keeps: ``ceil((1 - gamma) n)``, at least 1.

    Examples
    --------
    >>> smallest_subset(64, 0.2)
    52
    """
    return max(1, math.ceil((1.0 - gamma) * n - 1e-9))


def _log_comb(a, b):
    """``log C(a, b)``, ``-inf`` where ``b < 0`` or ``b > a`` (broadcasting)."""
    a, b = np.broadcast_arrays(np.asarray(a, np.float64), np.asarray(b, np.float64))
    valid = (b >= 0) & (b <= a)
    safe_b = np.where(valid, b, 0)
    out = gammaln(a + 1) - gammaln(safe_b + 1) - gammaln(a - safe_b + 1)
    return np.where(valid, out, -np.inf)


@lru_cache(maxsize=64)
def _variance_factors(n, gamma):
    factors = np.zeros(n + 1)
    if n < 2:
        return factors
    sizes = np.arange(smallest_subset(n, gamma), n + 1, dtype=np.float64)[:, None]  # k
    kept = np.arange(1, n + 1, dtype=np.float64)[None, :]  # m >= 1
    for n_seen in range(2, n + 1):
        log_p = _log_comb(n_seen, kept) + _log_comb(n - n_seen, sizes - kept) - _log_comb(n, sizes)
        p = np.exp(log_p)  # P(m | k), one row per k; k itself is uniform
        ratio = (n_seen - kept) / (kept * (n_seen - 1))
        factors[n_seen] = float((p * ratio).sum() / p.sum())
    factors.setflags(write=False)
    return factors


def variance_factors(n, gamma):
    """``c(n_p)``: variance of a random pattern's mean over the views' variance ``s^2``.

    Parameters
    ----------
    n : int
        Number of views of the light field.
    gamma : float
        Relaxation: a pattern keeps ``k`` views, ``k`` uniform on
        ``ceil((1 - gamma) n) .. n``.

    Returns
    -------
    factors : ndarray, shape (n + 1,), float64, read-only
        ``factors[n_p]`` for a pixel seen by ``n_p`` views (0 for
        ``n_p < 2``): the expectation, over ``k`` and over the number
        ``m >= 1`` of kept views that see the pixel (hypergeometric), of
        ``(n_p - m) / (m (n_p - 1))``.

    Examples
    --------
    >>> f = variance_factors(64, 0.2)
    >>> k = np.arange(52, 65)
    >>> bool(np.isclose(f[64], (64 * np.mean(1 / k) - 1) / 63))
    True
    """
    n = _validate.integer_at_least("n", n, 0)
    gamma = _validate.in_open_interval("gamma", gamma, 0.0, 1.0)
    return _variance_factors(n, gamma)


def sampling_patterns(n, gamma, n_patterns, seed=None):
    """The random sampling patterns of Algorithm 1, as a 0/1 matrix.

    Parameters
    ----------
    n : int
        Number of views.
    gamma : float
        Relaxation factor, ``0 < gamma < 1``.
    n_patterns : int
        Number of patterns ``N``.
    seed : int, optional
        Seed of the generator (the same seed gives the same patterns).

    Returns
    -------
    patterns : ndarray, shape (N, n), float32
        Row ``i`` keeps a uniformly random subset of ``k_i`` views,
        ``k_i`` uniform on ``ceil((1 - gamma) n) .. n``.

    Examples
    --------
    >>> p = sampling_patterns(64, 0.2, 5, seed=1)
    >>> p.shape, bool(((p.sum(axis=1) >= 52) & (p.sum(axis=1) <= 64)).all())
    ((5, 64), True)
    """
    n = _validate.integer_at_least("n", n, 1)
    gamma = _validate.in_open_interval("gamma", gamma, 0.0, 1.0)
    n_patterns = _validate.integer_at_least("n_patterns", n_patterns, 2)
    _budget.check(n_patterns * n * 4, f"n_patterns={n_patterns}: {n_patterns} patterns of {n} views")
    patterns = np.empty((n_patterns, n), np.float32)
    row = 0
    for sizes, order in _pattern_blocks(n, gamma, n_patterns, seed):
        keep = (np.arange(n)[None, :] < sizes[:, None]).astype(np.float32)
        np.put_along_axis(patterns[row:row + len(sizes)], order, keep, axis=1)
        row += len(sizes)
    return patterns


#: Random numbers drawn per block of patterns: memory stays bounded however many patterns there are.
_PATTERN_BLOCK_ELEMENTS = 2**18


def _pattern_blocks(n, gamma, n_patterns, seed):
    """The patterns of :func:`sampling_patterns`, a block at a time, from one generator.

    Yields ``(sizes (b,), order (b, n))``: pattern ``j`` keeps the views
    ``order[j, :sizes[j]]``. The blocks have a size set by ``n`` alone, so a
    seed gives the same patterns however they are consumed.
    """
    rng = np.random.default_rng(seed)
    block = max(1, _PATTERN_BLOCK_ELEMENTS // n)
    low = smallest_subset(n, gamma)
    for start in range(0, n_patterns, block):
        count = min(block, n_patterns - start)
        sizes = rng.integers(low, n + 1, size=count)
        yield sizes, np.argsort(rng.random((count, n)), axis=1)


# -- the result -----------------------------------------------------------------------

@dataclass(frozen=True)
class Detection:
    """The result of :func:`detect_aliasing`.

    Attributes
    ----------
    cv : ndarray, shape (Y, X), float32
        Coefficient of variation of the refocused luminance over the
        sampling patterns (Eq. 7); 0 where it was not evaluated.
    mask : ndarray, shape (Y, X), bool
        Aliased pixels: ``cv > threshold`` (``threshold_scale="cv"``) or
        ``angular_cv > threshold`` (``"angular"``). For ``method="depth"``,
        ``cv`` is the predicted error and the mask where it exceeds the
        threshold and the reduction's cautious score a quarter of it
        (:meth:`~napari_lfalias.depth_guided.DepthGuide.flagged`).
    cv_scale : ndarray, shape (Y, X), float32
        ``sqrt(c)`` of each pixel (:func:`variance_factors`): ``cv`` is
        ``cv_scale`` times the angular coefficient of variation.
    evaluated : ndarray, shape (Y, X), bool
        Where ``cv`` was computed; elsewhere a bound proved the pixel
        alias-free at ``threshold`` (or it lies outside the requested region).
    threshold : float
    threshold_scale : {"cv", "angular"}
    slope : float
        Slope at full resolution.
    level : int
        Pyramid level the detection ran on (``cv`` has that level's size).
    params : dict
        ``gamma``, ``n_patterns``, ``method``, ``seed``.
    """

    cv: np.ndarray
    mask: np.ndarray
    cv_scale: np.ndarray
    evaluated: np.ndarray
    threshold: float
    threshold_scale: str
    slope: float
    level: int = 0
    params: dict = field(default_factory=dict)

    @property
    def angular_cv(self):
        """``cv / cv_scale``: the angular coefficient of variation ``s / mean`` (0 where unseen)."""
        out = np.zeros_like(self.cv)
        np.divide(self.cv, self.cv_scale, out=out, where=self.cv_scale > 0)
        return out

    def rethreshold(self, threshold, threshold_scale=None):
        """The same Cv at another threshold, without recomputing anything.

        Parameters
        ----------
        threshold : float
            The new ``T`` (> 0).
        threshold_scale : {"cv", "angular"}, optional
            Default: this detection's.

        Raises
        ------
        ParameterError
            If the new threshold is lower where pixels were not evaluated
            (tiles skipped as provably below the old threshold, or pixels
            outside the region): their Cv was never computed. Detect again
            (an :class:`AliasingDetector` keeps what it computed). Also for a
            ``method="depth"`` detection, whose mask is not a threshold of
            its ``cv`` alone.
        """
        threshold = _validate.positive_float("threshold", threshold)
        if self.params.get("method") == "depth":
            raise ParameterError("a method='depth' detection's mask needs the reduction's cautious score too "
                                 "(DepthGuide.flagged), not the predicted error alone: call detect again (an "
                                 "AliasingDetector keeps the renderings, so a new threshold costs little)")
        scale = self.threshold_scale if threshold_scale is None else threshold_scale
        _validate.one_of("threshold_scale", scale, THRESHOLD_SCALES)
        lowered = _mask_threshold(threshold, scale, self.cv_scale) < _mask_threshold(
            self.threshold, self.threshold_scale, self.cv_scale)
        if np.any(lowered & ~self.evaluated):
            raise ParameterError(
                f"threshold {threshold} is below the {self.threshold} that flat tiles were skipped at; "
                "call detect_aliasing again (or pass skip_flat=False to keep every Cv)"
            )
        return Detection(self.cv, _mask(self.cv, threshold, scale, self.cv_scale), self.cv_scale,
                         self.evaluated, threshold, scale, self.slope, self.level, self.params)


def _mask_threshold(threshold, scale, cv_scale):
    """The threshold on ``cv`` itself, per pixel."""
    return np.float32(threshold) if scale == "cv" else np.float32(threshold) * cv_scale


def _mask(cv, threshold, scale, cv_scale):
    return cv > _mask_threshold(threshold, scale, cv_scale)


def _one_at_a_time(method):
    """Run a method of :class:`AliasingDetector` under its lock: its caches are filled in place."""
    @functools.wraps(method)
    def locked(self, *args, **kwargs):
        with self._lock:
            return method(self, *args, **kwargs)

    return locked


#: Most pattern x view x pixel visits a Monte-Carlo Cv may take (about ten minutes here).
MAX_PATTERN_VISITS = 1e12


def _pattern_cv(values, weights, n_ch, index, gamma, n_patterns, seed, floor):
    """Monte-Carlo Cv and view count of the pixels ``index`` of a shifted stack (Eq. 7).

    The patterns are drawn and accumulated a block at a time
    (:func:`_pattern_blocks`, the ``pattern_moments`` kernel): memory does
    not grow with ``n_patterns``.
    """
    from ._kernels import ROUNDING

    n = weights.shape[0]
    m = index.size
    if float(n_patterns) * n * m > MAX_PATTERN_VISITS:
        raise ParameterError(
            f"n_patterns={n_patterns}: {n_patterns} patterns x {n} views x {m} pixels is "
            f"{float(n_patterns) * n * m:.1e} sample visits, beyond the {MAX_PATTERN_VISITS:.0e} "
            "(about ten minutes) allowed; the Monte-Carlo Cv converges as 1/sqrt(n_patterns) "
            "(n_patterns=10000 is within about 1 % of the exact Cv): use fewer, or method='analytic' "
            "for the exact value")
    acc_n, acc_mean, acc_m2, reference = (np.zeros((m, n_ch)) for _ in range(4))
    count = np.zeros(m, np.int32)
    most_dropped = max(n - smallest_subset(n, gamma), 1)
    for sizes, order in _pattern_blocks(n, gamma, n_patterns, seed):
        # Pattern j drops order[j, sizes[j]:], the first n - sizes[j] of the reversed order.
        drops = np.ascontiguousarray(order[:, ::-1][:, :most_dropped], np.int64)
        _run("pattern_moments", values, weights, n_ch, drops, (n - sizes).astype(np.int64), index,
             acc_n, acc_mean, acc_m2, reference, count)
    std = np.sqrt(np.divide(acc_m2, acc_n, out=np.zeros_like(acc_m2), where=acc_n > 0))
    level = reference + acc_mean
    resolved = (acc_n > 0) & (std > ROUNDING * np.abs(level))  # else float32 data cannot hold it: rounding
    cv = np.where(resolved, std / np.maximum(level, floor), 0.0)
    return cv.max(axis=1).astype(np.float32), count


def _narrow_gaps(computed, flat):
    """Flat tiles in gaps narrower than a run's fixed cost between two computed tiles of a row.

    Computing such a gap costs less than splitting the run around it.
    """
    narrow = max(1, int(TILED_RUN_COST // (TILED_PIXEL_COST * TILE)))
    gaps = np.zeros_like(flat)
    for ty in range(flat.shape[0]):
        columns = np.flatnonzero(computed[ty])
        for left, right in zip(columns[:-1], columns[1:]):
            if 1 < right - left <= narrow + 1 and flat[ty, left + 1:right].all():
                gaps[ty, left + 1:right] = True
    return gaps


# -- the detector ---------------------------------------------------------------------

@dataclass
class _Moments:
    """Moments of the shifted views of one (level, slope), filled tile by tile."""

    mean: np.ndarray
    variance: np.ndarray
    count: np.ndarray
    done: np.ndarray  # (tile rows, tile cols) bool


class AliasingDetector:
    """Algorithm 1 on one light field, keeping what a new parameter can reuse.

    Parameters
    ----------
    lf : LightField
        The light field (a lazy one is read into memory once).
    luminance : {"rec709", "max"}
        Detect on Rec. 709 luminance (default), or on every colour channel
        and keep the largest Cv.
    dark_floor : float
        Floor of the mean a Cv is divided by, as a fraction of the
        brightest luminance of ``lf`` (module notes).
    skip_flat : bool
        Skip tiles whose Cv provably cannot exceed the threshold.
    tile : int
        Side of those tiles, in pixels.
    disparity : ndarray (Y, X) or DisparityEstimate, optional
        ``method="depth"``: a disparity you already have; estimated from
        the light field on first use when not given.
    nearer : {"auto", "larger", "smaller"}
        ``method="depth"``: which disparities are in front where surfaces
        occlude each other; ``"auto"``: the light field's
        ``meta["nearer"]`` where it has one, else judged from the views
        (:func:`~napari_lfalias.depth_guided.occlusion_order`).

    Notes
    -----
    A detector may be shared by threads (a napari session and a script,
    say): its methods run one at a time, under a lock, because they fill
    shared caches. Threads that want detections at the same time gain
    nothing from separate detectors either, as the kernels already use
    every core; a separate detector only spends memory on its own caches.

    Examples
    --------
    >>> import numpy as np
    >>> from napari_lfalias import LightField
    >>> lf = LightField(np.random.default_rng(0).random((3, 3, 32, 32, 1), np.float32))
    >>> detector = AliasingDetector(lf)
    >>> det = detector.detect(1.0, threshold=0.05)
    >>> det.cv.shape, det.mask.dtype
    ((32, 32), dtype('bool'))
    >>> again = detector.detect(1.0, gamma=0.3)   # reuses the moments of slope 1.0
    """

    def __init__(self, lf, luminance="rec709", dark_floor=DARK_FLOOR, skip_flat=True, tile=TILE, *,
                 disparity=None, nearer="auto"):
        from .depth_guided import occlusion_order

        if not isinstance(lf, LightField):
            raise ParameterError(f"lf must be a napari_lfalias.LightField, got {type(lf).__name__}")
        self.nearer = occlusion_order(lf, nearer)
        _validate.one_of("luminance", luminance, LUMINANCE_MODES)
        self.dark_floor = _validate.non_negative_float("dark_floor", dark_floor)
        self.skip_flat = _validate.boolean("skip_flat", skip_flat)
        self.tile = _validate.integer_at_least("tile", tile, 4)
        self.luminance = luminance
        self.source = lf  # as given (lazy ones stay lazy)
        self.lf = lf.compute() if lf.is_lazy else lf
        self._levels = []  # the detection light field of each pyramid level, level 0 made on first use
        self._ranges = {}
        self._slope = None  # the slope whose moments and stacks are kept
        self._moments = {}
        self._stacks = {}
        self._scale = 1.0  # the power of two the detection light field was multiplied by (_unit_scaled)
        self._lock = threading.RLock()
        self._disparity = disparity
        self._guide = None

    def use_disparity(self, disparity):
        """Use ``disparity`` (a ``(Y, X)`` map or a :class:`~napari_lfalias.disparity.DisparityEstimate`)
        for ``method="depth"`` from now on, instead of estimating it (a worker may estimate it with
        progress, then hand it over)."""
        with self._lock:
            self._disparity = disparity
            self._guide = None

    def use_nearer(self, nearer):
        """Render ``method="depth"`` with the occlusion order ``nearer`` from now on.

        ``nearer`` is as for the constructor (``"auto"``: the light field's
        ``meta["nearer"]`` where it has one, else judged from the views).
        The disparity is kept; the renderings of the other order are dropped.

        Examples
        --------
        >>> from napari_lfalias.synthetic import brick_room
        >>> detector = AliasingDetector(brick_room(n_views=3, size=32).lightfield)
        >>> detector.use_nearer("smaller")
        >>> detector.nearer
        'smaller'
        """
        from .depth_guided import occlusion_order

        nearer = occlusion_order(self.source, nearer)
        with self._lock:
            if nearer != self.nearer:
                self.nearer = nearer
                self._guide = None

    @property
    def guide(self):
        """The :class:`~napari_lfalias.depth_guided.DepthGuide` of the light field (disparity estimated
        on first use, unless one was given), for ``method="depth"``."""
        with self._lock:
            if self._guide is None:
                from .depth_guided import DepthGuide

                self._guide = DepthGuide(self.lf, self._disparity, nearer=self.nearer)
            return self._guide

    # -- cached inputs -----------------------------------------------------------
    @_one_at_a_time
    def level(self, level):
        """The detection light field (luminance or colour) of pyramid ``level``."""
        level = _validate.integer_at_least("level", level, 0)
        if not self._levels:
            self._levels = [self._unit_scaled(self._luminance_and_ranges(self.lf, self.luminance == "rec709", 0))]
        while len(self._levels) <= level:  # one level at a time, each from the one before
            coarser = lightfield_pyramid(self._levels[-1], 1)[1]
            coarser.meta["pyramid_level"] = len(self._levels)
            self._levels.append(coarser)
        return self._levels[level]

    def _luminance_and_ranges(self, lf, combine, level):
        """The light field Cv is taken on, and the per-tile ranges of its level, in one pass.

        With ``combine`` (Rec. 709 on colour data) the luminance views are
        made in the same pass; otherwise ``lf`` itself is returned.
        """
        views = lf.views()
        n, height, width, n_ch = views.shape
        combine = combine and n_ch > 1
        shape = (-(-height // self.tile), -(-width // self.tile))
        low, high = np.empty((n,) + shape, np.float32), np.empty((n,) + shape, np.float32)
        lum = np.empty((n, height, width) if combine else (1, 1, 1), np.float32)
        weights = lf.flat_weights()
        has_weight = weights is not None
        weights = np.ascontiguousarray(weights) if has_weight else np.ones((1, 1, 1), np.float32)
        _run("luminance_ranges", np.ascontiguousarray(views).reshape(n, height, width * n_ch), n_ch,
             REC709.astype(np.float32), combine, weights, has_weight, self.tile, lum, low, high)
        self._ranges[level] = (low.min(axis=0).astype(np.float64), high.max(axis=0).astype(np.float64))
        if not combine:
            return lf
        data = lum.reshape(lf.grid_shape + (height, width, 1))
        return LightField._derived(data, lf.positions, lf.meta, lf.weights)

    def _tile_ranges(self, level):
        """Per-tile least and greatest sample over every view ``(tile rows, tile cols)``, kept per level."""
        lf = self.level(level)
        if level not in self._ranges:
            self._luminance_and_ranges(lf, False, level)
        return self._ranges[level]

    def _unit_scaled(self, lf):
        """``lf`` (level 0) and its tile ranges times a power of two that brings the peak near 1.

        Cv is a ratio, so scaling changes nothing but where float32 moments
        overflow (a peak above ~1e19) or underflow (below ~1e-12): any finite
        positive data scale gives the same Cv (module notes: Numerics).
        """
        low, high = self._ranges[0]
        self._scale = unit_scale(float(np.max(high[np.isfinite(high)], initial=0.0)))
        if self._scale == 1.0:
            return lf
        self._ranges[0] = (low * self._scale, high * self._scale)
        if lf is self.lf:  # the caller's data: scale a copy
            return LightField._derived(lf.data * np.float32(self._scale), lf.positions, lf.meta, lf.weights)
        lf.data *= np.float32(self._scale)  # our own luminance views
        return lf

    @property
    def _floor(self):
        """The floor of the mean, in the units of the detection light field (:meth:`_unit_scaled`)."""
        high = self._tile_ranges(0)[1]
        peak = float(np.max(high[np.isfinite(high)], initial=0.0))
        return max(self.dark_floor * peak, float(np.finfo(np.float32).tiny))

    @property
    @_one_at_a_time
    def floor(self):
        """The floor of the mean a Cv is divided by (``dark_floor`` x brightest luminance), in data units."""
        return self._floor / self._scale

    def _keep_slope(self, slope):
        if self._slope != slope:
            self._slope, self._moments, self._stacks = slope, {}, {}

    # -- which tiles need work -----------------------------------------------------
    def _candidate_tiles(self, level, region):
        """Tiles that hold at least one pixel of ``region`` (all of them without one)."""
        if region is None:
            return np.ones(self._tile_ranges(level)[0].shape, bool)
        return tiles_holding(region, self.tile)

    def _flat_tiles(self, level, slope, threshold, scale, method, gamma, candidates):
        """Tiles to skip: their Cv provably stays at or below the threshold, and skipping them pays.

        The exact method computes the tiles left as runs of whole tiles
        along each tile row, which costs more per pixel than one pass over
        the image, plus a fixed cost per run and row (:data:`TILED_PIXEL_COST`,
        :data:`TILED_RUN_COST`): narrow gaps between computed tiles are
        computed rather than skipped, and nothing is skipped unless the
        runs left are predicted to cost at most :data:`SKIP_WORTH` of the
        work without skipping. Monte Carlo evaluates pixel by pixel: every
        provably flat tile is skipped.
        """
        flat = self._provably_flat(level, slope, threshold, scale, method, gamma)
        if method != "analytic":
            return flat
        flat &= ~_narrow_gaps(candidates & ~flat, flat)
        if self._tile_work(level, candidates & ~flat) > SKIP_WORTH * self._tile_work(level, candidates):
            return np.zeros_like(flat)
        return flat

    def _tile_work(self, level, tiles):
        """Predicted work of the moments on ``tiles``, in pixels of one pass over the whole image."""
        height, width = self.level(level).image_shape
        if tiles.all():
            return float(height * width)
        spans = self._spans(level, tiles)
        rows, widths = spans[:, 1] - spans[:, 0], spans[:, 3] - spans[:, 2]
        return float(np.sum(rows * (TILED_PIXEL_COST * widths + TILED_RUN_COST)))

    def _provably_flat(self, level, slope, threshold, scale, method, gamma):
        """Tiles whose Cv provably stays at or below the threshold (decided before shifting)."""
        lf = self.level(level)
        low, high = self._tile_ranges(level)
        # Beyond the image, a wider footprint adds nothing (and a huge slope would ask for a huge filter).
        reach = math.ceil(min(abs(slope) * float(np.abs(lf.positions).max(initial=0.0)), max(lf.image_shape))) + 1
        size = 2 * math.ceil(reach / self.tile) + 1
        # Samples beyond the image carry no weight: they widen no range.
        low = ndimage.minimum_filter(low, size=size, mode="constant", cval=np.inf)
        high = ndimage.maximum_filter(high, size=size, mode="constant", cval=-np.inf)
        with np.errstate(invalid="ignore", over="ignore"):
            relative = (high - low) / np.maximum(low, self._floor)  # (b - a) / max(a, floor)
        relative = np.where(np.isfinite(relative), relative, np.inf)
        n = lf.n_views
        factors = variance_factors(n, gamma)
        seen = factors[2:]  # any number of views may see a pixel near the border
        f_low, f_high = (float(seen.min()), float(seen.max())) if seen.size else (0.0, 0.0)
        if method == "analytic":  # Cv = sqrt(c) s / mean, s <= (b - a) / 2, mean >= a, any weights
            angular_bound = relative / 2
            with np.errstate(invalid="ignore"):  # 0 * inf (one view): NaN, never skipped
                cv_bound = math.sqrt(f_high) * angular_bound
        else:
            # With every view seeing the tile at full weight, a pattern's mean is within
            # (n - k) / n (b - a) of the full mean; near the border or with sample
            # weights, only within (b - a).
            height, width = lf.image_shape
            ty, tx = np.indices(low.shape)
            inside = ((ty * self.tile - reach >= 0) & ((ty + 1) * self.tile + reach <= height)
                      & (tx * self.tile - reach >= 0) & ((tx + 1) * self.tile + reach <= width))
            share = np.where(inside & (lf.weights is None), (n - smallest_subset(n, gamma)) / n, 1.0)
            cv_bound = share * relative
            angular_bound = cv_bound / math.sqrt(f_low) if f_low > 0 else np.full(low.shape, np.inf)
        bound = cv_bound if scale == "cv" else angular_bound
        return bound <= threshold

    def _tile_pixels(self, level, tiles):
        """Boolean pixel map of ``tiles`` at ``level``."""
        height, width = self.level(level).image_shape
        pixels = np.repeat(np.repeat(tiles, self.tile, axis=0), self.tile, axis=1)
        return pixels[:height, :width]

    def _spans(self, level, tiles):
        """``(K, 4)`` int64 ``(y0, y1, x0, x1)``: runs of consecutive tiles of each tile row."""
        height, width = self.level(level).image_shape
        spans = []
        for ty, row in enumerate(tiles):
            padded = np.concatenate([[False], row, [False]])
            edges = np.flatnonzero(padded[1:] != padded[:-1])
            for start, stop in zip(edges[::2], edges[1::2]):
                spans.append((ty * self.tile, min((ty + 1) * self.tile, height),
                              start * self.tile, min(stop * self.tile, width)))
        return np.array(spans, np.int64).reshape(-1, 4)

    # -- the two estimates ------------------------------------------------------------
    def _moments_for(self, level, slope, tiles):
        """Moments of the shifted views at (level, slope), computed on ``tiles`` if not yet done."""
        lf = self.level(level)
        moments = self._moments.get(level)
        if moments is None:
            shape = lf.image_shape
            moments = _Moments(np.zeros(shape + (lf.n_channels,), np.float32),
                               np.zeros(shape + (lf.n_channels,), np.float32),
                               np.zeros(shape, np.int32), np.zeros(tiles.shape, bool))
            self._moments[level] = moments
        missing = tiles & ~moments.done
        if not missing.any():
            return moments
        wsum = np.zeros(lf.image_shape, np.float32)
        outputs = (moments.mean, moments.variance, wsum, moments.count)
        if missing.all():
            _run("moments", *_inputs(lf, slope), *outputs)
        else:
            _run("moments_tiles", *_inputs(lf, slope), self._spans(level, missing), *outputs)
        moments.done |= missing
        return moments

    def _stack_for(self, level, slope):
        """The shifted views at (level, slope) as ``values (n, P*C)`` and ``weights (n, P)`` (kept)."""
        stack = self._stacks.get(level)
        if stack is None:
            shifted = shift_views(self.level(level), slope)
            n = shifted.values.shape[0]
            stack = (shifted.values.reshape(n, -1), shifted.weights.reshape(n, -1), shifted.values.shape[-1])
            self._stacks[level] = stack
        return stack

    def _analytic_cv(self, level, slope, tiles, factors):
        from ._kernels import ROUNDING  # numba is loaded by now: the moments ran

        moments = self._moments_for(level, slope, tiles)
        rounding = (np.float32(ROUNDING) * moments.mean) ** 2  # below it: rounding, not the data
        variance = np.where(moments.variance > rounding, moments.variance, np.float32(0))
        variance *= factors.astype(np.float32)[moments.count][..., None]
        cv = np.sqrt(np.maximum(variance, 0)) / np.maximum(moments.mean, np.float32(self._floor))
        return cv.max(axis=-1), moments.count

    def _monte_carlo_cv(self, level, slope, pixels, gamma, n_patterns, seed):
        values, weights, n_ch = self._stack_for(level, slope)
        cv = np.zeros(weights.shape[1], np.float32)
        count = np.zeros(weights.shape[1], np.int32)
        index = np.flatnonzero(pixels.ravel())
        cv[index], count[index] = _pattern_cv(values, weights, n_ch, index, gamma, n_patterns, seed, self._floor)
        shape = self.level(level).image_shape
        return cv.reshape(shape), count.reshape(shape)

    def _depth_detection(self, slope, threshold, level, region):
        """``method="depth"``: the predicted error against a dense aperture (:mod:`.depth_guided`)."""
        if _validate.integer_at_least("level", level, 0) != 0:
            raise ParameterError("method='depth' detects on the full-resolution refocus only (level=0); "
                                 "pyramid levels belong to the Cv methods")
        shape = self.lf.image_shape
        if region is not None:
            region = np.asarray(region)
            if region.dtype != np.bool_ or region.shape != shape:
                raise ParameterError(f"region must be a boolean array of shape {shape}, got {region.dtype} "
                                     f"{region.shape}")
        score = self.guide.refocus_errors(slope)
        evaluated = np.ones(shape, bool) if region is None else region
        score = np.where(evaluated, score, np.float32(0)).astype(np.float32)
        ones = np.ones(shape, np.float32)
        params = {"method": "depth", "gamma": None, "n_patterns": None, "seed": None}
        mask = self.guide.flagged(slope, threshold) & evaluated
        return Detection(score, mask, ones, evaluated, threshold, "cv", slope, 0, params)

    # -- the public entry point ----------------------------------------------------------
    @_one_at_a_time
    def detect(self, slope, gamma=None, n_patterns=None, threshold=None, method=None, seed=None, *,
               level=0, threshold_scale="cv", region=None, preset=None):
        """Detect angular aliasing at ``slope`` (see :func:`detect_aliasing`).

        Parameters
        ----------
        slope, gamma, n_patterns, threshold, method, seed, level, threshold_scale
            As in :func:`detect_aliasing`.
        region : ndarray of bool, shape of the level, optional
            Only pixels of ``region`` are evaluated (Algorithm 2 passes the
            pixels still aliased); ``cv`` is 0 and ``mask`` False elsewhere.

        Returns
        -------
        Detection
        """
        options = detection_options(preset, method=method, threshold=threshold, gamma=gamma, n_patterns=n_patterns,
                                    seed=seed, threshold_scale=threshold_scale)
        method, threshold, gamma, n_patterns, seed = (options[k] for k in ("method", "threshold", "gamma",
                                                                           "n_patterns", "seed"))
        slope = _validate.finite_float("slope", slope)
        if method == "depth":
            return self._depth_detection(slope, threshold, level, region)
        level = _validate.integer_between("level", level, 0, MAX_LEVEL)
        lf = self.level(level)
        if region is not None:
            region = np.asarray(region)
            if region.dtype != np.bool_ or region.shape != lf.image_shape:
                raise ParameterError(
                    f"region must be a boolean array of the level's shape {lf.image_shape}, "
                    f"got {region.dtype} {region.shape}"
                )
        self._keep_slope(slope)
        level_slope = slope / 2**level
        factors = variance_factors(lf.n_views, gamma)
        tiles = self._candidate_tiles(level, region)
        if self.skip_flat:
            tiles &= ~self._flat_tiles(level, level_slope, threshold, threshold_scale, method, gamma, tiles)
        pixels = self._tile_pixels(level, tiles)
        if region is not None:
            pixels &= region
        if method == "analytic":
            cv, count = self._analytic_cv(level, level_slope, tiles, factors)
        else:
            cv, count = self._monte_carlo_cv(level, level_slope, pixels, gamma, n_patterns, seed)
        cv = np.where(pixels, cv, np.float32(0)).astype(np.float32)
        cv_scale = np.sqrt(factors).astype(np.float32)[np.where(pixels, count, lf.n_views)]
        params = {"gamma": gamma, "n_patterns": n_patterns, "method": method, "seed": seed}
        return Detection(cv, _mask(cv, threshold, threshold_scale, cv_scale), cv_scale, pixels,
                         threshold, threshold_scale, slope, level, params)


def detect_aliasing(lf, slope, gamma=None, n_patterns=None, threshold=None, method=None, seed=None, *,
                    level=0, threshold_scale="cv", luminance="rec709", dark_floor=DARK_FLOOR, skip_flat=True,
                    disparity=None, nearer="auto", preset=None):
    """Detect angular aliasing in the refocus of ``lf`` at ``slope`` (Algorithm 1).

    Parameters
    ----------
    lf : LightField
        The light field.
    slope : float
        Disparity in focus (pixels per unit of view position).
    gamma : float
        Relaxation, ``0 < gamma < 1``: a sampling pattern keeps between
        ``ceil((1 - gamma) n)`` and ``n`` of the ``n`` views.
    n_patterns : int
        Number of random sampling patterns ``N >= 2`` (Monte Carlo only).
    threshold : float
        ``T > 0``: a pixel is aliased where its Cv exceeds it.
    method : {"depth", "analytic", "monte_carlo"}
        ``"depth"`` (default): where the refocus differs from what a dense
        aperture records, predicted from the light field's disparity
        (:mod:`napari_lfalias.depth_guided`); ``"analytic"``: the exact
        ``N -> infinity`` Cv; ``"monte_carlo"``: the paper's estimate from
        ``n_patterns`` random patterns.
    seed : int, optional
        Seed of the Monte-Carlo patterns (same seed, same result).
    level : int
        Pyramid level to detect on: the views are blurred and decimated
        ``level`` times first (Algorithm 2); the result has that level's size.
    threshold_scale : {"cv", "angular"}
        ``"cv"`` (the paper): ``T`` applies to Cv. ``"angular"``: ``T``
        applies to the angular coefficient of variation ``Cv / sqrt(c)``,
        which does not depend on gamma or the number of views.
    luminance : {"rec709", "max"}
        Detect on Rec. 709 luminance, or per colour channel keeping the largest Cv.
    dark_floor : float
        Floor of the mean a Cv is divided by, as a fraction of the
        brightest luminance of ``lf``.
    skip_flat : bool
        Skip tiles that provably cannot exceed ``T``.
    disparity, nearer
        ``method="depth"``: as :class:`AliasingDetector`'s.
    preset : {None, "paper"}
        ``"paper"``: Xiao et al. (2014) as published
        (:mod:`napari_lfalias.presets`); parameters given explicitly win.

    Returns
    -------
    Detection
        ``cv`` and ``mask`` (Y, X) at the level's size, and what produced them.

    Raises
    ------
    ParameterError
        For a parameter out of range or a light field that is not one.

    Notes
    -----
    See the module docstring for the two methods, the meaning of ``T``,
    the numerics and the skipped tiles. To reuse work across calls (a new
    gamma, ``N``, ``T`` or seed at the same slope), use an
    :class:`AliasingDetector`.

    Examples
    --------
    >>> import napari_lfalias as lfa
    >>> from napari_lfalias.synthetic import brick_room
    >>> lf = brick_room(n_views=4, size=64, seed=0).lightfield
    >>> det = lfa.detect_aliasing(lf, slope=4.0)            # focus on the cube
    >>> det.cv.shape, bool(det.mask.any())
    ((64, 64), True)
    """
    detector = AliasingDetector(lf, luminance=luminance, dark_floor=dark_floor, skip_flat=skip_flat,
                                disparity=disparity, nearer=nearer)
    return detector.detect(slope, gamma, n_patterns, threshold, method, seed,
                           level=level, threshold_scale=threshold_scale, preset=preset)
