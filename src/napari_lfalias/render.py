"""Refocusing that renders what a dense aperture would record.

A sparse set of views refocused by shift-and-add holds, for a surface at
residual disparity ``r = d - slope``, one copy of it per view, spaced by
``|r| * spacing`` pixels (the angular aliasing the paper detects). A dense
aperture integrates the rays *between* the views too: each view stands for
the cell of the aperture around it, and over that cell the surface moves
by ``|r| * spacing`` pixels, so the copies turn into one box per view that
tiles the whole aperture's blur.

:func:`antialiased_refocus` renders exactly that, given the disparity of
every pixel (estimated by :func:`~napari_lfalias.disparity.estimate_disparity`
when not given):

1. The centre-of-aperture disparity is forward-warped into every view
   (nearest surface wins), so each view knows which surface each of its
   samples shows.
2. Each view's shifted samples (as in :func:`~napari_lfalias.refocus`) are
   split into disparity bins of at most ``BIN_PX`` px of blur width.
3. Each bin (premultiplied colour and coverage) is blurred by the box its
   surface sweeps over the view's cell, ``|d - slope| * spacing`` px wide
   on each axis, and the bins are composited front to back: a defocused
   occluder spreads over the in-focus surface it partly hides, and hides
   it in proportion. Only clearly nearer bins hide (their blur widths
   differ by :data:`OCCLUSION_GAP_PX` or more); bins of one surface add up.
   A blurred surface goes on behind what hides it, with the colour of what
   is seen of it nearby, so its blur reaches under an occluder's outline.
4. The views' composites are summed and normalised by their coverage.

Pixels in focus (``|d - slope| * spacing < 0.5`` px) with no defocused
surface over them are the naive refocus exactly. The renderer is also the
depth-aware baseline of the paper (:func:`~napari_lfalias.depth_aware_refocus`
calls it with a known disparity).

Measured against the dense-aperture references of the synthetic scenes and
the real sub-grid cases in ``benchmarks/results/accuracy.md``.

References
----------
.. [1] X. Yu, R. Wang, J. Yu, "Real-time depth of field rendering via dynamic
   light field generation and filtering", Computer Graphics Forum 29(7), 2010.
.. [2] A. Isaksen, L. McMillan, S. J. Gortler, "Dynamically reparameterized
   light fields", SIGGRAPH 2000.
"""

from __future__ import annotations

import importlib
import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from . import _validate
from .errors import ParameterError
from .lightfield import LightField
from .refocus import _KERNEL_LOCK, refocus, shift_views

__all__ = ["antialiased_refocus", "Rendering", "render_dense_aperture", "BIN_PX"]

#: Largest spread (px) of blur widths within one disparity bin.
BIN_PX = 1.0
#: Most disparity bins (a map with a wider range gets wider bins).
MAX_BINS = 32
#: Pixels whose surface moves less than this (px) between neighbouring views are in focus.
IN_FOCUS_PX = 0.5
#: Bins whose blur widths differ by less than this (px) are parts of one surface: they add up
#: rather than hide each other (a continuous or noisily estimated surface spans several bins).
OCCLUSION_GAP_PX = 4.0
#: Share of the views that must show an in-focus surface at a pixel before it fills what the other
#: views' cells leave uncovered there.
FILL_SHARE = 0.25


@dataclass(frozen=True)
class Rendering:
    """What :func:`render_dense_aperture` returns.

    Attributes
    ----------
    image : ndarray, shape (Y, X, C), float32
        The dense-aperture rendering (the naive refocus where nothing is
        blurred and nothing defocused covers the pixel).
    blurred_share : ndarray, shape (Y, X), float32
        The share of each pixel's coverage that comes from blurred
        (defocused) surfaces.
    trust : ndarray, shape (Y, X), float32
        The coverage-weighted confidence of the disparities that made the
        pixel (1 with a known disparity).
    """

    image: np.ndarray
    blurred_share: np.ndarray
    trust: np.ndarray


def _kernels():
    return importlib.import_module("._render_kernels", __package__)


def _run(name, *args):
    with _KERNEL_LOCK:
        getattr(_kernels(), name)(*args)


def _bins(disparity, slope, spacing, max_bins):
    """Bin edges ``(K + 1,)`` over the disparity range and each bin's box taps ``(K, 4)``."""
    from .baselines import _box_taps

    low, high = float(np.min(disparity)), float(np.max(disparity))
    count = max(1, min(max_bins, int(math.ceil((high - low) * spacing / BIN_PX))))
    edges = np.linspace(low, high, count + 1)
    edges[0], edges[-1] = -np.inf, np.inf
    index = np.clip(np.searchsorted(edges, disparity.ravel(), side="right") - 1, 0, count - 1)
    sums = np.bincount(index, weights=disparity.ravel(), minlength=count)
    counts = np.bincount(index, minlength=count)
    inner = np.linspace(low, high, count + 1)
    centres = np.where(counts > 0, sums / np.maximum(counts, 1), 0.5 * (inner[:-1] + inner[1:]))
    taps = np.zeros((count, 4))
    widest = 2.0 * max(disparity.shape) + 3.0  # a wider box is the layer's mean anyway
    for k, centre in enumerate(centres):
        width = min(abs(centre - slope) * spacing, widest)
        if width >= 2 * IN_FOCUS_PX:
            taps[k] = (*_box_taps(width), *_box_taps(width))
    return edges, centres, taps


def _in_focus_colour(stack, bins, taps, order, occluders):
    """The colour of the in-focus background at each pixel, from the views whose sample shows it.

    Only in-focus surfaces behind a clearly nearer one count (what an
    occluder's blurred edge uncovers is the background it hides; what a
    defocused background leaves uncovered behind an in-focus occluder is
    more of that background, left to the normalisation), and only where
    at least :data:`FILL_SHARE` of the views (by weight) show one: not a
    stray sample.

    Returns ``(fill (Y, X, C) float32, has_fill (Y, X) bool)``.
    """
    sharp = ~np.any(taps != 0, axis=1)
    behind = np.zeros(len(taps), bool)
    behind[order] = occluders >= 0
    shows = np.append(sharp & behind, False)[bins] & (stack.weights > 0)  # bin -1 (no surface): False
    weight = np.where(shows, stack.weights, 0).astype(np.float32)
    total = weight.sum(axis=0)
    colour = np.einsum("nyx,nyxc->yxc", weight, stack.values)
    has_fill = total >= FILL_SHARE * np.maximum(stack.weights.sum(axis=0), 1e-6)
    np.divide(colour, total[..., None], out=colour, where=has_fill[..., None])
    return np.ascontiguousarray(colour, np.float32), has_fill


def _with_mixed_edges(disparity, slope, gap):
    """``disparity`` with the pixels on an occluding edge given to the side sharper at ``slope``.

    A pixel on the edge of an occluder mixes the occluder's colour with
    the background's. Whichever side it is counted to, its colour is spread
    by that side's blur; counted to the more blurred side, the other side's
    share turns into a bright or dark fringe. Counted to the sharper side
    it stays where it is, as it does in the dense aperture.
    """
    low = ndimage.minimum_filter(disparity, size=3)
    high = ndimage.maximum_filter(disparity, size=3)
    sharper = np.where(np.abs(low - slope) <= np.abs(high - slope), low, high)
    edge = (high - low >= gap) & (np.abs(sharper - slope) < np.abs(disparity - slope))
    return np.where(edge, sharper, disparity)


def _occluders(ordered_centres, gap):
    """For each bin in front-to-back order, the last position of a bin at least ``gap`` nearer (-1: none)."""
    out = np.full(len(ordered_centres), -1, np.int64)
    for o, centre in enumerate(ordered_centres):
        nearer = np.flatnonzero(np.abs(ordered_centres[:o] - centre) >= gap)
        out[o] = nearer[-1] if nearer.size else -1
    return out


def render_dense_aperture(lf, slope, disparity, confidence=None, *, larger_first=True, max_bins=MAX_BINS):
    """The dense-aperture refocus of ``lf`` at ``slope`` for a known disparity (module notes).

    Parameters
    ----------
    lf : LightField
        The light field (sample weights are honoured).
    slope : float
        Disparity in focus.
    disparity : ndarray, shape (Y, X)
        Finite disparity of every pixel of the centre of the aperture.
    confidence : ndarray, shape (Y, X), optional
        Confidence of each disparity in [0, 1] (default 1): carried into
        ``Rendering.trust``.
    larger_first : bool
        Whether larger disparities are in front (the occlusion order).
    max_bins : int
        Most disparity bins.

    Returns
    -------
    Rendering
    """
    from .baselines import view_spacing

    positions = np.ascontiguousarray(lf.flat_positions(), np.float64)
    spacing = view_spacing(lf.positions)
    disparity = np.ascontiguousarray(disparity, np.float64)
    confidence = np.ones(disparity.shape, np.float32) if confidence is None else confidence
    confidence = np.ascontiguousarray(confidence, np.float32)
    disparity = _with_mixed_edges(disparity, float(slope), OCCLUSION_GAP_PX / spacing)
    n = lf.n_views
    shape = lf.image_shape
    warped = np.empty((n,) + shape, np.float64)
    warped_conf = np.empty((n,) + shape, np.float32)
    _run("warp_disparity", disparity, confidence, positions, bool(larger_first), warped, warped_conf)
    edges, centres, taps = _bins(disparity, slope, spacing, max_bins)
    bins = np.empty((n,) + shape, np.int16)
    sample_conf = np.empty((n,) + shape, np.float32)
    _run("shifted_bins", warped, warped_conf, positions, float(slope), edges, bins, sample_conf)
    stack = shift_views(lf, slope)
    order = np.argsort(-centres if larger_first else centres, kind="stable").astype(np.int64)
    occluders = _occluders(centres[order], OCCLUSION_GAP_PX / spacing)
    fill, has_fill = _in_focus_colour(stack, bins, taps, order, occluders)
    chunks = 4
    num = np.zeros((chunks,) + shape + (lf.n_channels,), np.float32)
    den, blurred, trust = (np.zeros((chunks,) + shape, np.float32) for _ in range(3))
    _run("composite_views", np.ascontiguousarray(stack.values), np.ascontiguousarray(stack.weights), bins,
         sample_conf, order, occluders, taps, fill, has_fill, chunks, num, den, blurred, trust)
    num, den, blurred, trust = num.sum(0), den.sum(0), blurred.sum(0), trust.sum(0)
    seen = den > 1e-6
    image = np.divide(num, den[..., None], out=np.zeros_like(num), where=seen[..., None])
    share = np.divide(blurred, den, out=np.zeros_like(den), where=seen)
    trust = np.divide(trust, den, out=np.zeros_like(den), where=seen)
    naive = refocus(lf, slope)
    in_focus = (np.abs(disparity - slope) * spacing < IN_FOCUS_PX) & (share < 1e-3)
    image = np.where((in_focus | ~seen)[..., None], naive, image).astype(np.float32)
    return Rendering(image, share.astype(np.float32), np.clip(trust, 0, 1).astype(np.float32))


def antialiased_refocus(lf, slope, disparity=None, *, nearer="auto"):
    """Refocus ``lf`` at ``slope`` as a dense aperture would record it.

    Parameters
    ----------
    lf : LightField
        The light field.
    slope : float
        Disparity in focus (pixels per unit of view position).
    disparity : ndarray (Y, X) or DisparityEstimate, optional
        The disparity of every pixel of the centre of the aperture; an
        estimate's confidence is kept. Estimated with
        :func:`~napari_lfalias.disparity.estimate_disparity` when not given.
    nearer : {"auto", "larger", "smaller"}
        Which disparities are in front; ``"auto"`` judges it from the
        views at the depth edges.

    Returns
    -------
    image : ndarray, shape (Y, X, C), float32
        The rendering; the naive refocus exactly where the pixel is in
        focus and no defocused surface covers it.

    Raises
    ------
    ParameterError
        For a disparity of the wrong shape, not real, or with NaN/Inf, or
        bad parameters.

    Notes
    -----
    This is the rendering the default reduction puts in its aliased pixels
    (:class:`~napari_lfalias.depth_guided.DepthGuide`): surfaces the views
    themselves show in focus at ``slope``
    (:class:`~napari_lfalias.disparity.FocusTest`) are rendered in focus
    whatever the disparity says there.

    Examples
    --------
    >>> import numpy as np
    >>> import napari_lfalias as lfa
    >>> from napari_lfalias.synthetic import brick_room
    >>> scene = brick_room(n_views=4, size=64, seed=0)
    >>> image = lfa.antialiased_refocus(scene.lightfield, 4.0, scene.disparity)
    >>> image.shape
    (64, 64, 3)
    """
    from .depth_guided import DepthGuide

    if not isinstance(lf, LightField):
        raise ParameterError(f"lf must be a napari_lfalias.LightField, got {type(lf).__name__}")
    slope = _validate.finite_float("slope", slope)
    guide = DepthGuide(lf, disparity, nearer=nearer)
    guide.estimate  # a bad disparity is named before any rendering
    return guide.rendering(slope).image
