"""The baselines of Xiao et al. (2014): prefiltered and depth-aware refocusing.

Prefiltering (Levoy & Hanrahan 1996; Chai et al. 2000)
------------------------------------------------------
:func:`prefilter_refocus` low-passes every view before the shift-and-add.
A scene point of disparity ``d`` lands ``|d - slope| * spacing`` pixels
apart in adjacent views (``spacing`` the distance between neighbouring
view positions, 1 on a regular grid), so the widest gap over the scene's
disparity range is ``w = max |d - slope| * spacing`` pixels. Each view is
filtered by a box of width ``w`` on both axes (fractional widths by
fractional end taps), with nothing outside the view (normalised
convolution). For a point at the far end of the range the shifted boxes
tile the aperture, which is the dense-aperture result; points nearer the
focal plane are blurred more than they should be -- the in-focus blur the
paper criticises. Cost: one box filter per view (running sums, numba,
parallel over the views) and a refocus, about 0.3-0.4 s at 8x8x512x512x3
on this 2-core machine.

Depth-aware rendering (after Yu et al. 2010)
--------------------------------------------
:func:`depth_aware_refocus` knows the disparity ``d(p)`` at the centre of
the aperture and renders the defocus of a dense aperture directly: each
view's samples are cut into disparity layers, each layer is blurred by the
box its surface sweeps over the view's cell of the aperture,
``|d - slope| * spacing`` px wide, and the layers are composited front to
back. It is :func:`napari_lfalias.render.render_dense_aperture` (the
renderer of the default reduction and of
:func:`~napari_lfalias.antialiased_refocus`) given a disparity it trusts
everywhere; the module notes of :mod:`napari_lfalias.render` describe it.

Which side of a depth edge is in front follows from the views (``nearer
="auto"``): at an occlusion boundary the occluder is seen by every view
(its samples agree), while the occluded side near it is partly hidden in
some views (its samples vary).

Examples
--------
>>> from napari_lfalias.synthetic import brick_room
>>> from napari_lfalias.baselines import depth_aware_refocus, prefilter_refocus
>>> scene = brick_room(n_views=4, size=48, seed=0)
>>> prefilter_refocus(scene.lightfield, -4.0).shape
(48, 48, 3)
>>> depth_aware_refocus(scene.lightfield, -4.0, scene.disparity).dtype
dtype('float32')
"""

from __future__ import annotations

import importlib

import numpy as np
from scipy import ndimage

from . import _validate
from .errors import ParameterError
from .lightfield import LightField
from .refocus import _KERNEL_LOCK, refocus

__all__ = ["prefilter_refocus", "depth_aware_refocus", "prefilter_width", "view_spacing"]

#: Disparity layers of :func:`depth_aware_refocus` at most (a continuous map is quantised).
MAX_LAYERS = 32  # the renderer's MAX_BINS


# -- geometry -------------------------------------------------------------------------

def view_spacing(positions):
    """Distance between neighbouring views: the median nearest-neighbour distance (1 if one view).

    Parameters
    ----------
    positions : array_like, shape (U, V, 2) or (n, 2)

    Returns
    -------
    float

    Examples
    --------
    >>> from napari_lfalias import regular_positions
    >>> view_spacing(regular_positions(3, 4))
    1.0
    """
    flat = np.asarray(positions, np.float64).reshape(-1, 2)
    if len(flat) < 2:
        return 1.0
    dist = np.sqrt(((flat[:, None, :] - flat[None, :, :]) ** 2).sum(-1))
    np.fill_diagonal(dist, np.inf)
    return float(np.median(dist.min(axis=1)))




def _disparity_range(lf, disparity_range):
    if disparity_range is None:
        if lf.meta.get("disparity_range") is not None:
            disparity_range = lf.meta["disparity_range"]
        elif lf.meta.get("disparity") is not None:
            values = np.asarray(lf.meta["disparity"], np.float64)
            values = values[np.isfinite(values)]
            if values.size:
                disparity_range = (values.min(), values.max())
    if disparity_range is None:
        raise ParameterError(
            "disparity_range is needed to size the prefilter: pass disparity_range=(low, high) "
            "(the scene's smallest and largest disparity, px per view step); the light field's "
            "meta has neither 'disparity_range' nor a 'disparity' map"
        )
    return _validate.value_range("disparity_range", disparity_range)


def prefilter_width(lf, slope, disparity_range=None):
    """Width in pixels of the prefilter box: ``max |d - slope|`` over the range, times the view spacing.

    Parameters
    ----------
    lf : LightField
    slope : float
        Disparity in focus.
    disparity_range : (float, float), optional
        The scene's disparity range; default from ``lf.meta``
        (``"disparity_range"``, else the range of ``"disparity"``).

    Returns
    -------
    float
    """
    lf = _lightfield(lf)
    slope = _validate.finite_float("slope", slope)
    low, high = _disparity_range(lf, disparity_range)
    return max(abs(low - slope), abs(high - slope)) * view_spacing(lf.positions)


def _lightfield(lf):
    if not isinstance(lf, LightField):
        raise ParameterError(f"lf must be a napari_lfalias.LightField, got {type(lf).__name__}")
    return lf.compute() if lf.is_lazy else lf


# -- box filter -----------------------------------------------------------------------------

def _box_taps(width):
    """``(n, f)`` of a box of ``width`` px: ``2n + 1`` full taps and end taps of weight ``f`` in [0, 1)."""
    if width < 1.0:
        return 0, 0.0
    n = int((width - 1.0) // 2.0)
    return n, (width - (2 * n + 1)) / 2.0




def _kernels():
    return importlib.import_module("._baseline_kernels", __package__)


def _box_sum(image, width_y, width_x):
    """Box sum of widths (y, x) px of ``image (Y, X, K)``, zero outside; float32."""
    image = np.ascontiguousarray(image, np.float32)
    out = np.empty_like(image)
    with _KERNEL_LOCK:
        _kernels().box_image(image, *_box_taps(width_y), *_box_taps(width_x), out)
    return out


# -- prefiltering -------------------------------------------------------------------------

def prefilter_refocus(lf, slope, disparity_range=None, *, width=None):
    """Refocus after low-passing every view (Levoy & Hanrahan 1996 prefiltering).

    Parameters
    ----------
    lf : LightField
        The light field.
    slope : float
        Disparity in focus (pixels per unit of view position).
    disparity_range : (float, float), optional
        Smallest and largest disparity of the scene; default from
        ``lf.meta["disparity_range"]`` or the range of
        ``lf.meta["disparity"]``.
    width : float, optional
        The box width in pixels; default :func:`prefilter_width`
        (``max |d - slope|`` over the range times the view spacing).

    Returns
    -------
    image : ndarray, shape (Y, X, C), float32

    Raises
    ------
    ParameterError
        If no disparity range is given or known, or a parameter is out
        of range.

    Examples
    --------
    >>> import numpy as np
    >>> from napari_lfalias import LightField
    >>> lf = LightField(np.full((3, 3, 20, 20, 1), 0.25, np.float32))
    >>> image = prefilter_refocus(lf, 0.5, disparity_range=(-1.0, 2.0))
    >>> bool(np.allclose(image, 0.25))
    True
    """
    lf = _lightfield(lf)
    slope = _validate.finite_float("slope", slope)
    if width is None:
        width = prefilter_width(lf, slope, disparity_range)
    else:
        width = _validate.non_negative_float("width", width)
    views = lf.views()
    weights = lf.flat_weights()
    n, f = _box_taps(width)
    if n == 0 and f == 0.0:
        return refocus(lf, slope)
    # normalised convolution: filter(w * v) / filter(w), with w = 1 inside the view, 0 outside
    if weights is None:
        numerator = np.empty_like(views)
        with _KERNEL_LOCK:
            _kernels().box_views(views, n, f, n, f, numerator)
        numerator /= _box_sum(np.ones(views.shape[1:3] + (1,), np.float32), width, width)
        filtered = numerator
    else:
        stacked = np.concatenate([views * weights[..., None], weights[..., None]], axis=-1)
        summed = np.empty_like(stacked)
        with _KERNEL_LOCK:
            _kernels().box_views(stacked, n, f, n, f, summed)
        coverage = summed[..., -1:]
        filtered = np.divide(summed[..., :-1], coverage, out=np.zeros_like(views), where=coverage > 0)
    filtered_lf = LightField(filtered.reshape(lf.shape), lf.positions, lf.meta, weights=lf.weights)
    return refocus(filtered_lf, slope)


# -- depth-aware rendering -----------------------------------------------------------------

def _disparity_map(disparity, shape=None):
    """``disparity`` as a finite float64 (Y, X) array: of ``shape`` if given, else of any 2-D shape."""
    disparity = np.asarray(disparity)
    if shape is None and disparity.ndim != 2:
        raise ParameterError(f"disparity must be a (Y, X) array, got shape {disparity.shape}")
    if shape is not None and disparity.shape != tuple(shape):
        raise ParameterError(f"disparity must have the views' shape (Y, X) = {tuple(shape)}, got {disparity.shape}")
    if (disparity.dtype == np.bool_ or not np.issubdtype(disparity.dtype, np.number)
            or np.issubdtype(disparity.dtype, np.complexfloating)):
        raise ParameterError(f"disparity must be a real array, got dtype {disparity.dtype}")
    disparity = disparity.astype(np.float64)
    if not np.all(np.isfinite(disparity)):
        raise ParameterError("disparity holds NaN or Inf values; fill them first")
    return disparity




#: Confidence from which an estimate's pixel counts in judging which side of a depth edge is in front
#: (:func:`_larger_is_nearer`). Fresh scenes 1300 / 1308 (checkers estimated a period off in patches) and
#: 1315 (a smooth wall's noisy estimate): the edges inside the one surface, median confidence 0.1-0.3 there,
#: outvoted the outlines, where the estimate is sure; judged right from 0.2 to 0.6.
SURE_CONFIDENCE = 0.5
#: Fewest sure pixels a side of the depth edges needs to be judged by them alone (else by all its pixels).
MIN_SURE_PIXELS = 100
#: Ratio of the two sides' median spreads at the depth edges within which they do not tell which side is
#: in front (:func:`_larger_is_nearer`). On the random scenes of fresh-a..l (240), 7 judged within 1.3:
#: 5 wrong, 2 right; the order that explains the views by what it hides got all 7 right (none wrong above).
CLEAR_SPREAD_RATIO = 1.3
#: Least disparity step (px per view step) at which a nearer surface is taken to hide a view's samples.
HIDING_STEP = 1.0
#: Farthest (px) a surface is looked for to hide a pixel's samples (:func:`_hidden_views_explain_larger_first`).
HIDING_REACH_CAP = 24


def _depth_edges(disparity, jump):
    """Pixels with a 4-neighbour whose disparity differs by more than ``jump``."""
    edges = np.zeros(disparity.shape, bool)
    jumps_y = np.abs(np.diff(disparity, axis=0)) > jump
    jumps_x = np.abs(np.diff(disparity, axis=1)) > jump
    edges[:-1] |= jumps_y
    edges[1:] |= jumps_y
    edges[:, :-1] |= jumps_x
    edges[:, 1:] |= jumps_x
    return edges


def _larger_is_nearer(views, positions, disparity, confidence=None, jump=0.25, band=3, max_pixels=20_000):
    """Whether larger disparities are in front, judged from the views at the depth edges.

    Near an occlusion boundary the occluder is seen by every view (its
    samples at its own disparity agree), while the occluded side is hidden
    in some views (its samples vary). Compares the median spread of the two
    sides within ``band`` px of the edges where the disparity jumps by
    more than ``jump`` (at most ``max_pixels`` of them, evenly picked).
    With a ``confidence`` (Y, X) in [0, 1] (an estimate's), a side counts
    only its pixels of :data:`SURE_CONFIDENCE` or more where it has
    :data:`MIN_SURE_PIXELS` of them: an estimate a period off, or noisy on
    a smooth surface, makes edges inside one surface whose wrong side's
    samples vary at the wrong disparity, not for being hidden. Where the
    two sides' spreads lie within :data:`CLEAR_SPREAD_RATIO` of each other,
    the order that explains the views' disagreement by what it hides
    decides (:func:`_hidden_views_explain_larger_first`).
    True when there is no such edge.
    """
    edges = _depth_edges(disparity, jump)
    if not edges.any():
        return True
    near_edge = ndimage.binary_dilation(edges, iterations=band)
    size = 2 * band + 1
    middle = 0.5 * (ndimage.maximum_filter(disparity, size) + ndimage.minimum_filter(disparity, size))
    sides = []
    for side in (near_edge & (disparity > middle), near_edge & (disparity < middle)):
        pixels = _sure_pixels(side, confidence, max_pixels)
        if len(pixels) == 0:
            return True
        sides.append(np.median(_spreads(views, positions, disparity, pixels)))
    larger_first = bool(sides[0] <= sides[1])
    if max(sides) < CLEAR_SPREAD_RATIO * min(sides):
        return _hidden_views_explain_larger_first(views, positions, disparity, confidence, larger_first, max_pixels)
    return larger_first


def _sure_pixels(where, confidence, max_pixels):
    """``(m, 2)`` int64 pixels of ``where``: its sure ones (:data:`SURE_CONFIDENCE`) where it has
    :data:`MIN_SURE_PIXELS` of them, at most ``max_pixels``, evenly picked."""
    if confidence is not None:
        sure = where & (confidence >= SURE_CONFIDENCE)
        where = sure if np.count_nonzero(sure) >= MIN_SURE_PIXELS else where
    pixels = np.argwhere(where)
    return pixels[:: max(1, len(pixels) // max_pixels)].astype(np.int64)


def _spreads(views, positions, disparity, pixels, front=None):
    """The views' spread at each of ``pixels`` (``_baseline_kernels.view_spread``); with ``front`` (Y, X),
    leaving out the samples a surface at that disparity hides."""
    spread = np.empty(len(pixels))
    with _KERNEL_LOCK:
        _kernels().view_spread(views, positions, disparity, pixels, disparity if front is None else front, spread)
    return spread


def _hidden_views_explain_larger_first(views, positions, disparity, confidence, fallback, max_pixels):
    """Whether the views disagree less with the samples that larger disparities in front would hide left out
    than with those smaller ones in front would hide.

    Each pixel within the reach of a surface at least :data:`HIDING_STEP`
    nearer or farther (its disparity times the aperture's half width) is
    sampled at its own disparity twice: without the samples the largest
    disparity around would hide if larger were nearer, and without those
    the smallest would hide if smaller were. The true order leaves out the
    samples that show the occluder, the wrong one leaves them in. Where the
    two spreads at the edges alone cannot tell (a smooth wall hidden by a
    surface whose estimate spills over it: fresh scene 1113), the mean
    spreads can. ``fallback`` where no pixel is that near a step.
    """
    positions = np.asarray(positions, np.float64)
    reach = _hiding_reach(positions, disparity)
    larger, larger_near = _hiding_front(disparity, reach, True)
    smaller, smaller_near = _hiding_front(disparity, reach, False)
    pixels = _sure_pixels(larger_near | smaller_near, confidence, max_pixels)
    if len(pixels) == 0:
        return fallback
    return bool(_spreads(views, positions, disparity, pixels, larger).mean()
                <= _spreads(views, positions, disparity, pixels, smaller).mean())


def _hiding_reach(positions, disparity):
    """How far (px) a surface in front may hide a pixel's samples: the disparities' range (1st to 99th
    percentile) times the aperture's half width, at most :data:`HIDING_REACH_CAP`."""
    half_width = float(np.abs(positions - positions.mean(axis=0)).max(initial=0.0))
    low, high = np.percentile(disparity, [1, 99])
    return int(min(HIDING_REACH_CAP, np.ceil(half_width * (high - low)) + 1))


def _hiding_front(disparity, reach, larger_first):
    """``(front, near)``, each ``(Y, X)``: the disparity of the surface that may hide each pixel's samples in
    the order ``larger_first`` (the largest within ``reach`` px if larger disparities are in front, else the
    smallest, where at least :data:`HIDING_STEP` nearer; the pixel's own elsewhere), and where there is one
    (:func:`_hiding_reach`)."""
    if larger_first:
        extreme = ndimage.maximum_filter(disparity, 2 * reach + 1)
        near = extreme - disparity > HIDING_STEP
    else:
        extreme = ndimage.minimum_filter(disparity, 2 * reach + 1)
        near = disparity - extreme > HIDING_STEP
    return np.where(near, extreme, disparity), near


def _hidden_spread(views, positions, disparity, pixels, larger_first):
    """The mean spread of the views at ``pixels`` (``(m, 2)``), each sampled at its own ``disparity`` without
    the samples the surface in front of it within reach hides, in the order ``larger_first``
    (:func:`_hiding_front`): how well that disparity map, in that order, explains the views there."""
    positions = np.asarray(positions, np.float64)
    front, _ = _hiding_front(disparity, _hiding_reach(positions, disparity), larger_first)
    return float(_spreads(views, positions, disparity, pixels, front).mean())


def depth_aware_refocus(lf, slope, disparity, *, nearer="auto", max_layers=MAX_LAYERS):
    """Refocus with a known disparity map: layered per-pixel defocus (after Yu et al. 2010).

    The dense-aperture renderer
    (:func:`napari_lfalias.render.render_dense_aperture`) given a
    disparity it trusts everywhere: every view's samples are cut into
    disparity layers, each blurred by the box its surface sweeps over the
    view's cell of the aperture, and composited front to back. In-focus
    layers stay sharp; a blurred foreground spreads over the background it
    partly hides. :func:`~napari_lfalias.antialiased_refocus` is the same
    rendering with a disparity estimated from the views when none is
    given, and surfaces the views show in focus kept in focus.

    Parameters
    ----------
    lf : LightField
        The light field.
    slope : float
        Disparity in focus.
    disparity : array_like, shape (Y, X)
        Disparity of the scene at the centre of the aperture (a synthetic
        scene's ``disparity``, a decoder's ``lf.meta["disparity"]``).
    nearer : {"auto", "larger", "smaller"}
        Which disparities are in front (the order of the layers);
        ``"auto"``: the light field's ``meta["nearer"]`` where it has one,
        else judged from the views at the depth edges
        (:func:`~napari_lfalias.depth_guided.occlusion_order`).
    max_layers : int
        Most disparity layers; a map with more distinct values is
        quantised into this many equal bins. Time grows with the layers.

    Returns
    -------
    image : ndarray, shape (Y, X, C), float32

    Examples
    --------
    >>> import numpy as np
    >>> from napari_lfalias import LightField
    >>> lf = LightField(np.full((3, 3, 16, 16, 3), 0.5, np.float32))
    >>> image = depth_aware_refocus(lf, 1.0, np.zeros((16, 16)))
    >>> bool(np.allclose(image, 0.5))
    True
    """
    from .render import render_dense_aperture

    lf = _lightfield(lf)
    slope = _validate.finite_float("slope", slope)
    from .depth_guided import occlusion_order

    nearer = occlusion_order(lf, nearer)
    max_layers = _validate.integer_at_least("max_layers", max_layers, 1)
    disparity = _disparity_map(disparity, lf.image_shape)
    if nearer == "auto":
        larger_first = _larger_is_nearer(np.ascontiguousarray(lf.views()), np.ascontiguousarray(lf.flat_positions()),
                                         disparity)
    else:
        larger_first = nearer == "larger"
    return render_dense_aperture(lf, slope, disparity, larger_first=larger_first, max_bins=max_layers).image
