"""Lazy slope sweeps: a refocus (or Cv, or mask) per slope as one dask array.

A sweep is ``(S, Y, X[, C])`` with one slope per chunk, so nothing is
computed until a slice is asked for: a script computes what it needs, and
napari's dimension slider computes the slope on screen. The light field is
one node of the task graph, shared by every slope.
"""

from __future__ import annotations

import math
import uuid

import numpy as np

from . import _budget, _validate
from .errors import ParameterError
from .presets import INTERACTIVE_METHOD
from .lightfield import LightField

__all__ = ["refocus_sweep", "disparity_range", "estimate_slope_range", "aliasing_by_slope", "SWEEP_KINDS"]

#: How far (pixels per view step) a default sweep goes past the scene's disparities.
SLOPE_PAD = 0.5
#: What a sweep can hold per slope.
SWEEP_KINDS = ("refocus", "cv", "mask")
#: The detection method of sweeps unless one is given (:data:`~napari_lfalias.presets.INTERACTIVE_METHOD`).
SWEEP_METHOD = INTERACTIVE_METHOD


def _slope_plane(lf, slope, what, detect_kw):
    if what == "refocus":
        from .refocus import refocus

        return refocus(lf, slope)
    from .detect import detect_aliasing

    detection = detect_aliasing(lf, slope, **detect_kw)
    return detection.cv if what == "cv" else detection.mask


def _slopes_array(slopes):
    try:
        slopes = np.asarray(slopes, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"slopes must be a sequence of real numbers, got {slopes!r}") from exc
    if slopes.ndim != 1 or slopes.size == 0:
        raise ParameterError(f"slopes must be a non-empty 1-D sequence, got shape {slopes.shape}")
    if not np.all(np.isfinite(slopes)):
        raise ParameterError(f"slopes must be finite, got {slopes.tolist()}")
    return slopes


def refocus_sweep(lf, slopes, what="refocus", **detect_kw):
    """Refocused images, Cv maps or aliasing masks over a range of slopes, computed lazily.

    Parameters
    ----------
    lf : LightField
        The light field. A lazy one is read into memory once per
        ``compute`` call, by one node shared by every slope asked for.
    slopes : sequence of float
        The slopes (disparities in focus), one output plane each.
    what : {"refocus", "cv", "mask"}
        ``"refocus"``: :func:`~napari_lfalias.refocus` images,
        ``(S, Y, X, C)`` float32; ``"cv"``: the Cv map of
        :func:`~napari_lfalias.detect_aliasing`, ``(S, Y, X)`` float32;
        ``"mask"``: its aliasing mask, ``(S, Y, X)`` bool.
    **detect_kw
        Passed to :func:`~napari_lfalias.detect_aliasing`; the method is the
        exact Cv unless one is given (:data:`SWEEP_METHOD`) (``gamma``,
        ``n_patterns``, ``threshold``, ``method``, ``seed``); not allowed
        with ``what="refocus"``.

    Returns
    -------
    dask.array.Array
        Chunked one slope per chunk; ``sweep[i]`` is the plane of
        ``slopes[i]``.

    Raises
    ------
    ParameterError
        For empty or non-finite slopes, an unknown ``what``, or detection
        options given to a refocus sweep.

    Examples
    --------
    >>> import numpy as np
    >>> import napari_lfalias as lfa
    >>> lf = lfa.LightField(np.full((3, 3, 8, 8, 1), 0.5, np.float32))
    >>> sweep = lfa.refocus_sweep(lf, [-1.0, 0.0, 1.0])
    >>> sweep.shape, sweep.chunksize[0]
    ((3, 8, 8, 1), 1)
    >>> float(sweep[2].mean().compute())
    0.5

    In napari, ``viewer.add_image(sweep)`` puts the slopes on a slider.
    """
    import dask
    import dask.array as da

    if not isinstance(lf, LightField):
        raise ParameterError(f"lf must be a napari_lfalias.LightField, got {type(lf).__name__}")
    _validate.one_of("what", what, SWEEP_KINDS)
    if what != "refocus":
        detect_kw = {"method": SWEEP_METHOD, **detect_kw}
    if what == "refocus" and detect_kw:
        raise ParameterError(
            f"detection options {sorted(detect_kw)} only apply to what='cv' or what='mask'"
        )
    slopes = _slopes_array(slopes)
    if what != "refocus":
        # Check the options now, not when napari first draws a slice.
        from .detect import detect_aliasing

        small = LightField(np.zeros(lf.grid_shape + (4, 4, 1), np.float32), lf.positions)
        detect_aliasing(small, float(slopes[0]), **detect_kw)

    token = uuid.uuid4().hex
    # Naming the light field's node keeps dask from hashing its whole array.
    lf_node = dask.delayed(lf, name=f"lightfield-{token}", pure=True)
    if lf.is_lazy:
        lf_node = dask.delayed(LightField.compute, pure=True)(lf_node, dask_key_name=f"lightfield-data-{token}")
    image_shape = lf.image_shape
    if what == "refocus":
        shape, dtype = image_shape + (lf.n_channels,), np.float32
    else:
        shape, dtype = image_shape, (np.float32 if what == "cv" else np.bool_)
    planes = []
    for i, slope in enumerate(slopes):
        plane = dask.delayed(_slope_plane, pure=True)(
            lf_node, float(slope), what, detect_kw, dask_key_name=f"sweep-{what}-{token}-{i}"
        )
        planes.append(da.from_delayed(plane, shape=shape, dtype=dtype))
    return da.stack(planes)


def _block_mean(lf, factor):
    """Light field of luminance views shrunk by ``factor`` (block means), positions and sample weights kept.

    With sample weights (a lenslet decode), a block averages its samples by
    weight and takes their mean weight: samples outside a microlens do not
    pull the view towards 0.
    """
    lum = lf.luminance()
    views = lum.views()[..., 0]
    weights = lum.flat_weights()
    n, height, width = views.shape
    height, width = height // factor * factor, width // factor * factor

    def shrink(array):
        return array[:, :height, :width].reshape(n, height // factor, factor, width // factor, factor).sum(axis=(2, 4))

    if weights is None:
        views, weights = shrink(views) / factor**2, None
    else:
        total = shrink(weights)
        views = np.divide(shrink(views * weights), total, out=np.zeros_like(total), where=total > 0)
        weights = (total / factor**2).reshape(lf.grid_shape + total.shape[1:])
    return LightField(views.reshape(lf.grid_shape + views.shape[1:]), lf.positions, weights=weights)


#: Most candidate slopes :func:`estimate_slope_range` tries by default.
MAX_CANDIDATES = 257
#: Most view rows (and columns) :func:`estimate_slope_range` compares: the central block of views.
MAX_VIEWS_PER_AXIS = 9


def _central_views(lf, most=MAX_VIEWS_PER_AXIS):
    """The central ``most`` x ``most`` block of views (all of them when the grid is smaller), at their positions.

    Photo-consistency needs a few neighbouring views, not all of them: a
    lenslet decode's 27 x 27 views cost 9 times more than the central 9 x 9
    and find the same range. Neighbouring views, because a sparse sub-grid
    spanning the aperture aliases (periodic texture matches at wrong
    slopes: the bundled GUV capture's range came out as -3.9 .. 3.8 instead
    of -0.5 .. 0.1); central ones, because they are the best lit.
    """
    def block(n):
        start = max(0, (n - most) // 2)
        return slice(start, start + min(n, most))

    n_rows, n_cols = lf.grid_shape
    if n_rows <= most and n_cols <= most:
        return lf
    return lf.subset(block(n_rows), block(n_cols))


def _default_candidates(lf, max_slope):
    """Candidates one pixel apart across the aperture: a step of ``1 / ceil(aperture span)``.

    A step of 1/k px per view step moves the outermost views by at most one
    pixel from one candidate to the next; whole slopes are always among them.
    """
    span = float(np.ptp(lf.flat_positions(), axis=0).max())
    per_unit = max(1, int(np.ceil(span - 1e-9)))
    return min(MAX_CANDIDATES, int(round(2 * max_slope * per_unit)) + 1)


def estimate_slope_range(lf, max_slope=4.0, n_slopes=None, max_size=128, percentiles=(5, 95)):
    """Estimate the range of disparities in a scene from the photo-consistency of its views.

    For each candidate slope the variance across the shifted views is
    computed on a reduced copy of the luminance (block means down to
    ``max_size`` pixels, and the central ``MAX_VIEWS_PER_AXIS`` x
    ``MAX_VIEWS_PER_AXIS`` views); each textured pixel
    takes the slope of least variance, and the range spans ``percentiles``
    of those picks. Flat regions carry no depth cue and are left out.

    Parameters
    ----------
    lf : LightField
    max_slope : float
        Candidates span ``[-max_slope, max_slope]`` pixels per unit of view
        position (full-resolution pixels).
    n_slopes : int, optional
        Number of candidates. Default: one pixel of shift across the
        views compared between neighbours (33 for 5 x 5 views, 65 for
        9 x 9 and larger grids), at most ``MAX_CANDIDATES``.
    max_size : int
        Longest side of the reduced views.
    percentiles : (float, float)
        Percentiles of the per-pixel picks reported as the range.

    Returns
    -------
    (float, float)
        Low and high slope, in full-resolution pixels per unit of view
        position; ``(0.0, 0.0)`` when no pixel has a clear best slope
        (a flat or noise-like scene).
    """
    from .refocus import view_moments

    if not isinstance(lf, LightField):
        raise ParameterError(f"lf must be a napari_lfalias.LightField, got {type(lf).__name__}")
    max_slope = _validate.positive_float("max_slope", max_slope)
    if lf.is_lazy:
        lf = lf.compute()
    compared = _central_views(lf)
    if n_slopes is None:
        n_slopes = _default_candidates(compared, max_slope)
    n_slopes = _validate.integer_at_least("n_slopes", n_slopes, 3)
    factor = max(1, int(np.ceil(max(lf.image_shape) / max_size)))
    small = _block_mean(compared, factor)
    _budget.check(n_slopes * math.prod(small.image_shape) * 4, f"n_slopes={n_slopes}: the variances of every slope")
    slopes = np.linspace(-max_slope, max_slope, n_slopes)
    variances = np.stack([view_moments(small, s / factor).variance[..., 0] for s in slopes])
    centre = small.data[small.grid_shape[0] // 2, small.grid_shape[1] // 2, ..., 0]
    gy, gx = np.gradient(centre)
    texture = np.hypot(gy, gx)
    # A pixel votes when it has texture and its best slope stands out from the rest.
    confident = (texture > np.percentile(texture, 75)) & (variances.min(axis=0) < 0.25 * variances.mean(axis=0))
    if not confident.any():
        return 0.0, 0.0
    picks = slopes[variances.argmin(axis=0)][confident]
    low, high = np.percentile(picks, percentiles)
    return float(low), float(high)


def disparity_range(lf):
    """The range of disparities in ``lf``, and where it comes from.

    In order: ``lf.meta["disparity_range"]`` (set by a decoder or a
    synthetic scene), the range of a ground-truth map ``lf.meta["disparity"]``,
    else :func:`estimate_slope_range`.

    Returns
    -------
    low, high : float
    source : str
        ``"metadata"``, ``"ground truth"`` or ``"estimated"``.
    """
    meta = lf.meta
    if meta.get("disparity_range") is not None:
        low, high = meta["disparity_range"]
        return float(low), float(high), "metadata"
    if meta.get("disparity") is not None:
        truth = np.asarray(meta["disparity"], np.float64)
        if np.isfinite(truth).any():
            return float(np.nanmin(truth)), float(np.nanmax(truth)), "ground truth"
    low, high = estimate_slope_range(lf)
    return low, high, "estimated"


#: Options of :func:`~napari_lfalias.detect_aliasing` that configure the detector, not one detection.
_DETECTOR_OPTIONS = ("luminance", "dark_floor", "skip_flat")


def aliasing_by_slope(lf, slopes=None, n_slopes=9, progress=None, detector=None, **detect_kw):
    """Fraction of aliased pixels at each slope of a sweep.

    One :class:`~napari_lfalias.detect.AliasingDetector` serves every
    slope (the luminance, the tile ranges and the pyramid are made once),
    so this needs neither dask nor one light-field copy per slope.

    Parameters
    ----------
    lf : LightField
    slopes : sequence of float, optional
        The slopes. Default: ``n_slopes`` across :func:`disparity_range`,
        widened by ``SLOPE_PAD`` on each side.
    n_slopes : int
        Number of slopes when ``slopes`` is not given.
    progress : callable, optional
        Called with each slope once it is done (a progress bar).
    detector : AliasingDetector, optional
        A detector of ``lf`` to use (and to leave warm for later detections);
        ``luminance``, ``dark_floor`` and ``skip_flat`` are then its own.
    **detect_kw
        Passed to :func:`~napari_lfalias.detect_aliasing`; the method is the
        exact Cv unless one is given (:data:`SWEEP_METHOD`).

    Returns
    -------
    slopes : ndarray, shape (S,)
    fractions : ndarray, shape (S,)
        Fraction of pixels whose Cv exceeds the threshold at each slope (the
        mean of ``refocus_sweep(lf, slopes, what="mask")`` per slope).

    Examples
    --------
    >>> import napari_lfalias as lfa
    >>> from napari_lfalias.synthetic import brick_room
    >>> lf = brick_room(n_views=4, size=64, seed=0).lightfield
    >>> slopes, fractions = aliasing_by_slope(lf, slopes=[-4.0, 0.0, 4.0])
    >>> fractions.shape
    (3,)
    """
    from .detect import AliasingDetector

    if not isinstance(lf, LightField):
        raise ParameterError(f"lf must be a napari_lfalias.LightField, got {type(lf).__name__}")
    if slopes is None:
        n_slopes = _validate.integer_at_least("n_slopes", n_slopes, 1)
        low, high, _ = disparity_range(lf)
        slopes = np.linspace(low - SLOPE_PAD, high + SLOPE_PAD, n_slopes)
    slopes = _slopes_array(slopes)
    detect_kw = {"method": SWEEP_METHOD, **detect_kw}
    detector_kw = {key: detect_kw.pop(key) for key in _DETECTOR_OPTIONS if key in detect_kw}
    if detector is None:
        detector = AliasingDetector(lf, **detector_kw)
    elif not isinstance(detector, AliasingDetector) or detector.source is not lf or detector_kw:
        raise ParameterError("detector must be an AliasingDetector of this light field (lf), "
                             f"and {', '.join(_DETECTOR_OPTIONS)} are then its own")
    fractions = np.empty(slopes.size, np.float64)
    for i, slope in enumerate(slopes):
        fractions[i] = detector.detect(float(slope), **detect_kw).mask.mean()
        if progress is not None:
            progress(float(slope))
    return slopes, fractions
