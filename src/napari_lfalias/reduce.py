"""Angular-aliasing reduction: Algorithm 2 of Xiao et al. (CVPR 2014).

Angular aliasing fades on coarser levels of a Gaussian pyramid: blurring
and decimating the views lowers the spatial frequencies that the sparse
views alias. For every pixel, Algorithm 2 finds the lowest level ``l*``
on which it is no longer aliased (Eq. 8)::

    l* = min(l, max_level)  such that  Cv_l <= T

and replaces the aliased regions of the full-resolution refocus by the
rendering of level ``l*``, fused in the gradient domain (Perez et al.
2003) so that no seam shows: the pixels with ``l* = 0`` keep the naive
refocus exactly, the others solve a Poisson equation whose guidance
field is the gradient of the level-``l*`` rendering upsampled to full
resolution (:func:`napari_lfalias.poisson.fuse_gradients`).

What is computed
----------------
- Level 0: the refocus and the Cv of every pixel (:mod:`.detect`).
- Level ``l >= 1``: the Cv only on the pixels still aliased after level
  ``l - 1`` (the luminance pyramid of the views is built once per light
  field, level ``l`` refocused at ``slope / 2**l``); the loop stops as
  soon as no pixel is left.
- Renderings: level ``l`` of the refocused image's Gaussian pyramid
  (blurring, decimation and shift-and-add commute), expanded back to full
  resolution, only for the levels some pixel takes. The pyramid pools only
  the pixels with ``l* > 0`` (normalised convolution): in-focus content
  next to an aliased region does not bleed into its coarse rendering.
- The in-focus layer (``keep_in_focus``, :mod:`.in_focus`): where a
  defocused occluder partly hides an in-focus surface, the views that
  agree on the surface are split off the pixel; the renderings blur only
  the occluder's share and contribution and keep the surface sharp. This
  goes beyond the paper, whose blur of the whole pixel costs the in-focus
  texture around every defocused occluder; it is an option (off by
  default) because it pays off only at low thresholds (measured in
  ``benchmarks/results/reduction.md``).
- The Poisson solve only on the bounding box of the pixels with
  ``l* > 0``; nothing when no pixel is aliased.

A level map of your own (a depth map's, a mask's, a synthetic scene's
ground truth) goes straight to the rendering and fusion:
:func:`fuse_levels`, with :func:`levels_from_disparity` for a known
disparity. The benchmarks use the two to measure the ceiling of the
method, Algorithm 2 with a perfect detector.

The level renderings come from the refocused image rather than from a
refocus of each level's views: the two differ only in how the border
weights are pooled, and the former costs one image pyramid instead of
one light-field pyramid per channel.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from . import _validate
from .baselines import _disparity_map
from .detect import DARK_FLOOR, AliasingDetector
from .depth_guided import NEARER
from .errors import ParameterError
from .in_focus import in_focus_layer
from .poisson import _labels, fuse_gradients
from .presets import detection_options, resolve
from .pyramid import MAX_LEVEL, level_shape, pyr_down, pyr_up

__all__ = ["Reduction", "reduce_aliasing", "iter_reduce_aliasing", "reduction_options", "fuse_levels", "levels_from_disparity",
           "SOLVERS", "SCREEN", "MAX_LEVEL"]

#: Solvers of the gradient-domain fusion (see :mod:`napari_lfalias.poisson`).
SOLVERS = ("auto", "lu", "multigrid", "dct")
#: Default weight of the data term of the screened fusion (module notes).
SCREEN = 0.25


@dataclass(frozen=True)
class Reduction:
    """The result of :func:`reduce_aliasing`.

    Attributes
    ----------
    image : ndarray, shape (Y, X, C), float32
        The aliasing-reduced refocus.
    level : ndarray, shape (Y, X), uint8
        0 where the naive refocus is kept exactly; elsewhere, for the Cv
        methods ``l*`` (Eq. 8), and for ``method="depth"`` the pyramid level
        the pixel's disparity implies (:func:`levels_from_disparity`), at
        least 1 on every changed pixel, the blend's soft edge included.
    cv : ndarray, shape (Y, X), float32
        The level-0 Cv (Algorithm 1 on the full-resolution refocus); for
        ``method="depth"``, the aliasing score (the predicted relative
        luminance error of the naive refocus against a dense aperture).
    refocused : ndarray, shape (Y, X, C), float32
        The naive refocus (level 0), for comparison.
    detections : list of Detection
        The detection of every level that ran (level ``l`` only on the
        pixels still aliased after level ``l - 1``).
    """

    image: np.ndarray
    level: np.ndarray
    cv: np.ndarray
    refocused: np.ndarray
    detections: list = field(default_factory=list)


def reduction_options(preset=None, *, max_level=None, solver="auto", screen=None, keep_in_focus=False,
                      **detection):
    """Every parameter of :func:`reduce_aliasing` resolved (preset, defaults) and checked, whatever the method.

    Returns
    -------
    (dict, int, float)
        The detection options (:func:`~napari_lfalias.presets.detection_options`),
        ``max_level`` and ``screen``.

    Raises
    ------
    ParameterError
        Naming the parameter out of range.

    Examples
    --------
    >>> options, max_level, screen = reduction_options(preset="paper")
    >>> options["method"], max_level, screen
    ('monte_carlo', 3, 0.0)
    """
    options = detection_options(preset, **detection)
    chosen = resolve(preset, max_level=max_level, screen=screen)
    max_level = _validate.integer_between("max_level", 3 if chosen["max_level"] is None else chosen["max_level"],
                                          0, MAX_LEVEL)
    _validate.one_of("solver", solver, SOLVERS)
    _validate.boolean("keep_in_focus", keep_in_focus)
    screen = _validate.non_negative_float("screen", SCREEN if chosen["screen"] is None else chosen["screen"])
    return options, max_level, screen


def _to_level(mask, level):
    """Pixels of pyramid ``level`` that hold at least one pixel of the full-resolution ``mask``.

    Level pixel ``j`` sits over full-resolution pixel ``2**level * j``; a
    full-resolution pixel belongs to the nearest level pixel.
    """
    height, width = level_shape(mask.shape, level)
    rows = _nearest(mask.shape[0], level, height)
    cols = _nearest(mask.shape[1], level, width)
    out = np.zeros((height, width), bool)
    ys, xs = np.nonzero(mask)
    out[rows[ys], cols[xs]] = True
    return out


def _nearest(n, level, n_level):
    """Index of the nearest level-``level`` sample for each of ``n`` full-resolution samples."""
    step = 2**level
    return np.minimum((np.arange(n) + step // 2) // step, n_level - 1)


def _from_level(level_mask, shape, level):
    """The full-resolution pixels whose nearest level pixel is set in ``level_mask``."""
    rows = _nearest(shape[0], level, level_mask.shape[0])
    cols = _nearest(shape[1], level, level_mask.shape[1])
    return level_mask[np.ix_(rows, cols)]


def _level_renderings(image, levels, weights):
    """Levels ``1 .. max(levels)`` of ``image``'s Gaussian pyramid, each expanded back to full size.

    ``weights (Y, X)`` are the pixels the pyramid may pool (normalised
    convolution): the aliased ones, so that the in-focus content around
    them does not bleed into their coarse rendering. The pyramid is built
    once; only the levels in ``levels`` are expanded.

    Returns
    -------
    dict of int to ndarray (Y, X, C)
    """
    shapes, pyramid = [image.shape[:2]], []
    reduced = image
    for _ in range(max(levels)):
        reduced, weights = pyr_down(reduced, weights)
        shapes.append(reduced.shape[:2])
        pyramid.append((reduced * weights[..., None], weights))
    out = {}
    for level in levels:
        num, den = pyramid[level - 1]
        for shape in reversed(shapes[:level]):
            num, den = pyr_up(num, shape), pyr_up(den, shape)
        rendering = np.zeros_like(num)
        np.divide(num, den[..., None], out=rendering, where=den[..., None] > 1e-6)
        out[level] = rendering
    return out


def _renderings(refocused, level_map):
    """The level renderings (:func:`_level_renderings`) of the levels ``level_map`` uses, pooling its pixels > 0."""
    present = np.flatnonzero(np.bincount(level_map.ravel()))
    return _level_renderings(refocused, [int(level) for level in present if level > 0],
                             (level_map > 0).astype(np.float32))


def _fuse(refocused, level_map, renderings, solver, screen):
    """``refocused`` where ``level_map`` is 0, the gradients of ``renderings[l]`` where it is ``l``."""
    sources = [renderings.get(level, refocused) for level in range(1, int(level_map.max()) + 1)]
    return fuse_gradients(refocused, sources, level_map, method=solver, screen=screen)


def fuse_levels(refocused, level_map, *, solver="auto", screen=SCREEN):
    """Algorithm 2's rendering and fusion for a level map you already have.

    :func:`reduce_aliasing` finds ``l*`` by detection (Eq. 8) and then
    calls this: the aliased pixels take the gradients of the level-``l*``
    rendering, fused with the naive refocus (module notes). With a level
    map from elsewhere (a depth map, a hand-drawn mask, the ground truth
    of a synthetic scene) it renders what Algorithm 2 would make of it:
    ``benchmarks/bench_reduce.py`` uses it to measure the ceiling of the
    method, the result with a perfect detector.

    Parameters
    ----------
    refocused : array_like, shape (Y, X, C)
        The naive refocus (level 0), e.g. :func:`~napari_lfalias.refocus`.
    level_map : array_like of int, shape (Y, X)
        The pyramid level of each pixel: 0 keeps ``refocused``, ``l >= 1``
        takes the level-``l`` rendering. At most :data:`MAX_LEVEL`.
    solver : {"auto", "lu", "multigrid", "dct"}
        The Poisson solver, as in :func:`reduce_aliasing`.
    screen : float
        Weight of the data term of the screened fusion (>= 0).

    Returns
    -------
    ndarray, shape (Y, X, C), float32
        The fused image; equal to ``refocused`` where ``level_map`` is 0
        (for every solver but ``"dct"``).

    Raises
    ------
    ParameterError
        For an image that is not (Y, X, C) and finite, a level map of
        another shape, not integer, or outside ``0 .. MAX_LEVEL``, or a
        bad ``solver`` or ``screen``.

    Examples
    --------
    >>> import numpy as np
    >>> import napari_lfalias as lfa
    >>> from napari_lfalias.reduce import fuse_levels
    >>> from napari_lfalias.synthetic import brick_room
    >>> lf = brick_room(n_views=4, size=64, seed=0).lightfield
    >>> res = lfa.reduce_aliasing(lf, slope=4.0, threshold=0.01, method="analytic")
    >>> bool(np.array_equal(fuse_levels(res.refocused, res.level), res.image))
    True
    """
    refocused = np.asarray(refocused)
    if refocused.ndim != 3 or min(refocused.shape) < 1 or not np.issubdtype(refocused.dtype, np.floating):
        raise ParameterError(
            f"refocused must be a float array of shape (Y, X, C), got {refocused.dtype} {refocused.shape}")
    if not np.all(np.isfinite(refocused)):
        raise ParameterError("refocused holds NaN or Inf values; pass a finite image")
    level_map = _labels(level_map, refocused.shape[:2], MAX_LEVEL, "level_map", "0 = refocused, l = level l")
    _validate.one_of("solver", solver, SOLVERS)
    screen = _validate.non_negative_float("screen", screen)
    refocused = refocused.astype(np.float32, copy=False)
    level_map = level_map.astype(np.uint8)
    if not level_map.any():
        return refocused.copy()
    return _fuse(refocused, level_map, _renderings(refocused, level_map), solver, screen)


def levels_from_disparity(disparity, slope, spacing=1.0, max_level=3):
    """The level map a known disparity implies: where a point moves one pixel or less between views.

    A point of disparity ``d`` moves ``|d - slope| * spacing`` pixels
    between neighbouring views of the refocus at ``slope``, and half as
    far on each coarser pyramid level; its level is the first on which
    that shift is at most one pixel (the views sample it densely there),
    ``ceil(log2(shift))``, clipped to ``0 .. max_level``. This is the
    level map a perfect detector would hand :func:`fuse_levels`.

    Parameters
    ----------
    disparity : array_like, shape (Y, X)
        Disparity of every pixel (pixels per unit of view position).
    slope : float
        Disparity in focus.
    spacing : float
        Distance between neighbouring views, in units of view position
        (:func:`~napari_lfalias.baselines.view_spacing`).
    max_level : int
        The coarsest level, ``0 .. MAX_LEVEL``.

    Returns
    -------
    ndarray, shape (Y, X), uint8

    Raises
    ------
    ParameterError
        For a disparity that is not a finite (Y, X) array, or a bad
        ``slope``, ``spacing`` or ``max_level``.

    Examples
    --------
    >>> import numpy as np
    >>> levels_from_disparity(np.array([[0.0, 1.5, 2.0, 5.0, 40.0]]), slope=0.0)
    array([[0, 1, 1, 3, 3]], dtype=uint8)
    """
    disparity = _disparity_map(disparity)
    slope = _validate.finite_float("slope", slope)
    spacing = _validate.positive_float("spacing", spacing)
    max_level = _validate.integer_between("max_level", max_level, 0, MAX_LEVEL)
    shift = np.abs(disparity - slope) * spacing
    with np.errstate(divide="ignore"):
        level = np.ceil(np.log2(shift))
    return np.clip(level, 0, max_level).astype(np.uint8)


def _keep_in_focus(lf, slope, level_map, refocused, renderings, floor):
    """``renderings`` with the in-focus layer of each aliased pixel kept sharp (:mod:`.in_focus`).

    Where a group of agreeing views is found, the level-``l`` rendering is
    ``blur_l(share) * colour + blur_l(rest)``: the occluder's silhouette
    (``share``) and contribution (``rest = refocused - share * colour``)
    blurred, the surface's ``colour`` kept. The blur pools every pixel,
    the unaliased ones as fully in focus (share 1, rest 0), so the
    silhouette fades into the in-focus surface around it. Elsewhere the
    rendering is left as it is.
    """
    aliased = level_map > 0
    share, colour = in_focus_layer(lf, slope, aliased, floor)
    found = share > 0
    if not found.any():
        return renderings
    share[~aliased] = 1.0
    colour[~aliased] = refocused[~aliased]
    layers = np.concatenate([share[..., None], refocused - share[..., None] * colour], axis=-1)
    blurred = _level_renderings(layers, list(renderings), np.ones(share.shape, np.float32))
    return {level: np.where(found[..., None], blurred[level][..., :1] * colour + blurred[level][..., 1:], rendering)
            for level, rendering in renderings.items()}


def _reduce_depth_guided(detector, slope, threshold):
    """``method="depth"``: the pixels whose cautious score exceeds the threshold take the dense-aperture
    rendering (:mod:`.depth_guided`), and so do the pixels connected to them whose score exceeds
    :data:`~napari_lfalias.depth_guided.REPLACE_FRACTION` of the threshold and does not depend on where
    the depth edges are, and the faint aliasing anywhere (:func:`_replaced`). The detection returned is
    the plain predicted error
    (:meth:`~napari_lfalias.depth_guided.DepthGuide.predicted_errors`).

    Yields ``(done, 4)`` after the disparity, the naive refocus, the
    detection (which renders, unless the views agree everywhere) and the
    blend; returns the :class:`Reduction` (``level`` holds the pyramid
    level equivalent to the blur of each pixel the rendering changed, the
    soft edge around the flagged pixels included; 0: the naive refocus
    exactly).
    """
    from .baselines import view_spacing

    slope = _validate.finite_float("slope", slope)
    guide = detector.guide
    guide.check_estimate()
    yield (1, 4)
    refocused = guide.naive(slope)
    yield (2, 4)
    detection = detector.detect(slope, threshold=threshold, method="depth")
    yield (3, 4)
    replaced = _replaced(guide, slope, detection.threshold)
    if replaced.any():
        weight = guide.blend_weight(replaced)
        image = guide.blend(refocused, guide.scored_rendering(slope).image, replaced, weight)
        changed = weight > 0
    else:
        image, changed = refocused.copy(), replaced
    level = np.zeros(changed.shape, np.uint8)
    if changed.any():
        disparity = guide.estimate[0]
        level = np.where(changed, levels_from_disparity(disparity, slope, view_spacing(detector.lf.positions),
                                                        MAX_LEVEL), 0).astype(np.uint8)
        level[changed & (level == 0)] = 1
    yield (4, 4)
    return Reduction(image, level, detection.cv, refocused.copy(), [detection])


def _replaced(guide, slope, threshold):
    """The pixels the depth-guided reduction replaces at ``slope``: :func:`replaced_pixels` of the guide's
    cautious scores (:meth:`~napari_lfalias.depth_guided.DepthGuide.scores`), their edge spread
    (:meth:`~napari_lfalias.depth_guided.DepthGuide.edge_spread`) and where the faint aliasing may be
    taken (:meth:`~napari_lfalias.depth_guided.DepthGuide.faint_where`), near the image's edge only
    where the aliased region runs on to it
    (:meth:`~napari_lfalias.depth_guided.DepthGuide.kept_off_the_edge`)."""
    from .depth_guided import FAINT_FRACTION

    score = guide.cautious_scores(slope)
    # below the faint floor nothing is replaced: the edge spread (a rendering, where the views agree
    # everywhere) is not needed
    if not (score > np.float32(FAINT_FRACTION * threshold)).any():
        return np.zeros(score.shape, bool)
    replaced = replaced_pixels(score, guide.edge_spread(slope), threshold, guide.faint_where(slope))
    return guide.kept_off_the_edge(slope, replaced)


def replaced_pixels(score, spread, threshold, faint_where=None, *, replace_fraction=None, faint_fraction=None,
                    faint_margin=None):
    """The depth-guided reduction's rule: which pixels take the rendering.

    Those whose cautious score exceeds ``threshold``; their fringe
    (hysteresis): the pixels connected to them whose score exceeds
    ``replace_fraction`` of the threshold and the rendering's dependence
    on where the depth edges are (``spread``), and the gaps of up to
    :data:`~napari_lfalias.depth_guided.GAP_PX` between them whose spread is below that fraction of the
    threshold; and the faint aliasing
    anywhere in ``faint_where``: the pixels whose score exceeds
    ``faint_fraction`` of the threshold and ``faint_margin`` times that
    dependence. Below the threshold the rendering is trusted only where
    the naive refocus is farther from it than the rendering is from itself
    with the edges moved.

    Parameters
    ----------
    score, spread : ndarray, shape (Y, X)
        The cautious score of the naive refocus and the rendering's edge
        spread (:class:`~napari_lfalias.depth_guided.DepthGuide`).
    threshold : float
        ``T``.
    faint_where : ndarray of bool, shape (Y, X), optional
        Where the faint aliasing may be taken (default: everywhere).
    replace_fraction, faint_fraction, faint_margin : float, optional
        Default :data:`~napari_lfalias.depth_guided.REPLACE_FRACTION`,
        :data:`~napari_lfalias.depth_guided.FAINT_FRACTION`,
        :data:`~napari_lfalias.depth_guided.FAINT_MARGIN` (other values
        let ``benchmarks/replacement_rules.py`` compare rules).

    Returns
    -------
    ndarray of bool, shape (Y, X)

    Examples
    --------
    >>> import numpy as np
    >>> score = np.array([[0.03, 0.006, 0.0], [0.0, 0.0, 0.004]], np.float32)
    >>> replaced_pixels(score, np.zeros_like(score), 0.02).astype(int)
    array([[1, 1, 0],
           [0, 0, 1]])
    """
    from . import depth_guided

    replace_fraction = depth_guided.REPLACE_FRACTION if replace_fraction is None else replace_fraction
    faint_fraction = depth_guided.FAINT_FRACTION if faint_fraction is None else faint_fraction
    faint_margin = depth_guided.FAINT_MARGIN if faint_margin is None else faint_margin
    replaced = (score > np.float32(faint_fraction * threshold)) & (np.float32(faint_margin) * spread < score)
    if faint_where is not None:
        replaced &= faint_where
    seeds = score > np.float32(threshold)
    if seeds.any():
        fringe = (score > np.float32(replace_fraction * threshold)) & (spread < score)
        aliased = ndimage.binary_propagation(seeds, structure=np.ones((3, 3), bool), mask=fringe)
        # the score crosses zero between an aliasing pattern's crests: the gaps are the region's too, where
        # the rendering depends on where the depth edges are less than the fringe's least score
        gaps = np.ones((2 * depth_guided.GAP_PX + 1,) * 2, bool)
        steady = spread < np.float32(replace_fraction * threshold)
        replaced |= aliased | (ndimage.binary_closing(aliased, structure=gaps) & steady)
    return replaced


def reduce_aliasing(lf, slope, gamma=None, n_patterns=None, threshold=None, max_level=None, method=None,
                    seed=None, *, threshold_scale="cv", luminance="rec709", dark_floor=DARK_FLOOR,
                    solver="auto", screen=None, keep_in_focus=False, detector=None, disparity=None, nearer="auto",
                    preset=None):
    """Refocus ``lf`` at ``slope`` with angular aliasing reduced.

    Two methods, chosen by ``method`` (or ``preset``):

    - ``"depth"`` (the default): the pixels where the refocus differs from
      what a dense aperture records, predicted from the light field's own
      disparity, take the dense-aperture rendering; every other pixel keeps
      the naive refocus exactly (:mod:`napari_lfalias.depth_guided`).
    - ``"analytic"`` / ``"monte_carlo"``: Algorithm 2 of the paper with its
      Cv (Algorithm 1): the aliased pixels take coarser pyramid levels,
      fused in the gradient domain (module notes). ``preset="paper"`` is
      this algorithm exactly as published.

    ``benchmarks/results/accuracy.md`` measures both on data they were not
    tuned on.

    Parameters
    ----------
    lf : LightField
        The light field.
    slope : float
        Disparity in focus (pixels per unit of view position).
    gamma, n_patterns, threshold, method, seed, threshold_scale, luminance, dark_floor
        The detection parameters of :func:`~napari_lfalias.detect_aliasing`
        (``None``: the preset's or the method's default), used on every
        level by the Cv methods.
    max_level : int, optional
        Cv methods: the coarsest pyramid level (>= 0; 0 returns the naive
        refocus); pixels still aliased there take it anyway (Eq. 8).
        Default 3.
    solver : {"auto", "lu", "multigrid", "dct"}
        Cv methods: the Poisson solver of the fusion
        (:mod:`napari_lfalias.poisson`). ``"auto"`` is exact and never
        changes a pixel with ``l* = 0``.
    screen : float, optional
        Cv methods: weight of the data term of the screened fusion (>= 0;
        module notes); 0 is the plain Poisson fusion of Perez et al.
        Default :data:`SCREEN` (0 with ``preset="paper"``).
    keep_in_focus : bool
        Cv methods: keep the in-focus surface sharp where a defocused
        occluder partly hides it (module notes, :mod:`napari_lfalias.in_focus`).
        False is the paper's Algorithm 2, which blurs the whole pixel.
    detector : AliasingDetector, optional
        A detector of ``lf`` to reuse (its disparity, pyramid, moments and
        stacks).
    disparity : ndarray (Y, X) or DisparityEstimate, optional
        ``method="depth"``: a disparity you already have; estimated from
        the light field when not given (once per detector).
    nearer : {"auto", "larger", "smaller"}
        ``method="depth"``: which disparities are in front where surfaces
        occlude each other; ``"auto"``: the light field's
        ``meta["nearer"]`` where it has one, else judged from the views
        (:func:`~napari_lfalias.depth_guided.occlusion_order`). With a
        ``detector``, the detector's.
    preset : {None, "paper"}
        ``"paper"``: Xiao et al. (2014) as published
        (:mod:`napari_lfalias.presets`); parameters given explicitly win.

    Returns
    -------
    Reduction
        ``image`` (Y, X, C), ``level`` (Y, X) (``"depth"``: the pyramid
        level equivalent to the blur of each replaced pixel) and the
        level-0 ``cv`` (``"depth"``: the aliasing score).

    Raises
    ------
    ParameterError
        For a parameter out of range, or a detector of another light field.

    Examples
    --------
    >>> import numpy as np
    >>> import napari_lfalias as lfa
    >>> from napari_lfalias.synthetic import brick_room
    >>> scene = brick_room(n_views=4, size=64, seed=0)
    >>> res = lfa.reduce_aliasing(scene.lightfield, slope=4.0)
    >>> res.image.shape, bool(res.level.any())
    ((64, 64, 3), True)
    >>> paper = lfa.reduce_aliasing(scene.lightfield, slope=4.0, preset="paper", seed=0)
    >>> int(paper.level.max()) <= 3
    True
    """
    steps = iter_reduce_aliasing(lf, slope, gamma, n_patterns, threshold, max_level, method, seed,
                                 threshold_scale=threshold_scale, luminance=luminance, dark_floor=dark_floor,
                                 solver=solver, screen=screen, keep_in_focus=keep_in_focus, detector=detector,
                                 disparity=disparity, nearer=nearer, preset=preset)
    while True:
        try:
            next(steps)
        except StopIteration as done:
            return done.value


def iter_reduce_aliasing(lf, slope, gamma=None, n_patterns=None, threshold=None, max_level=None, method=None,
                         seed=None, *, threshold_scale="cv", luminance="rec709", dark_floor=DARK_FLOOR,
                         solver="auto", screen=None, keep_in_focus=False, detector=None, disparity=None,
                         nearer="auto", preset=None):
    """:func:`reduce_aliasing` step by step: a generator for progress reports and cancellation.

    Yields ``(done, total)`` after each stage (``"depth"``: the disparity,
    the rendering, the detection, the blend; Cv methods: the detection of
    every level, the level renderings, the fusion) and returns the
    :class:`Reduction` (``StopIteration.value``; ``yield from`` hands it
    over). Closing the generator between two stages stops the work there:
    each stage takes at most a few hundred milliseconds on 8x8x512x512x3.
    Parameters and errors are those of :func:`reduce_aliasing`; they are
    checked when the generator is first advanced.

    Examples
    --------
    >>> import napari_lfalias as lfa
    >>> from napari_lfalias.synthetic import brick_room
    >>> lf = brick_room(n_views=4, size=32, seed=0).lightfield
    >>> steps = iter_reduce_aliasing(lf, 4.0, threshold=0.01, max_level=2, method="analytic")
    >>> progress = []
    >>> while True:
    ...     try:
    ...         progress.append(next(steps))
    ...     except StopIteration as done:
    ...         result = done.value
    ...         break
    >>> progress[-1], result.image.shape
    ((5, 5), (32, 32, 3))
    """
    from .refocus import refocus

    options, max_level, screen = reduction_options(preset, method=method, threshold=threshold, gamma=gamma,
                                                   n_patterns=n_patterns, seed=seed,
                                                   threshold_scale=threshold_scale, max_level=max_level,
                                                   solver=solver, screen=screen, keep_in_focus=keep_in_focus)
    slope = _validate.finite_float("slope", slope)
    if detector is None:
        detector = AliasingDetector(lf, luminance=luminance, dark_floor=dark_floor, disparity=disparity,
                                    nearer=nearer)
    elif not isinstance(detector, AliasingDetector) or detector.source is not lf:
        raise ParameterError("detector must be an AliasingDetector made for this light field (lf)")
    elif _validate.one_of("nearer", nearer, NEARER) not in ("auto", detector.nearer):
        raise ParameterError(f"nearer={nearer!r} differs from the detector's own ({detector.nearer!r}): make the "
                             "detector with it (AliasingDetector(lf, nearer=...))")
    lf = detector.lf
    if options["method"] == "depth":
        return (yield from _reduce_depth_guided(detector, slope, options["threshold"]))
    total = max_level + 3  # level 0, levels 1 .. max_level, renderings, fusion
    first = detector.detect(slope, **options)
    refocused = refocus(lf, slope)
    yield (1, total)
    shape = lf.image_shape
    level_map = np.zeros(shape, np.uint8)
    detections = [first]
    still = first.mask.copy()
    for level in range(1, max_level + 1):
        if still.any():
            detection = detector.detect(slope, **options, level=level, region=_to_level(still, level))
            detections.append(detection)
            resolved = still & ~_from_level(detection.mask, shape, level)
            level_map[resolved] = level
            still &= ~resolved
        yield (1 + level, total)
    level_map[still] = max_level
    if not level_map.any():
        yield (total, total)
        return Reduction(refocused, level_map, first.cv, refocused, detections)
    renderings = _renderings(refocused, level_map)
    if keep_in_focus:
        renderings = _keep_in_focus(lf, slope, level_map, refocused, renderings, detector.floor)
    yield (total - 1, total)
    image = _fuse(refocused, level_map, renderings, solver, screen)
    yield (total, total)
    return Reduction(image, level_map, first.cv, refocused, detections)
