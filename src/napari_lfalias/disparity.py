"""Disparity from the light field itself: an occlusion-aware plane sweep.

:func:`estimate_disparity` returns, for every pixel of the centre of the
aperture, the disparity ``d`` (pixels per unit of view position, the
convention of DESIGN section 2: ``refocus(lf, d)`` brings the point into
focus) and a confidence in [0, 1].

Method
------
1. **Features.** Every view's luminance ``L`` (normalised by the light
   field's bright level) and its gradients ``(2 dL/dy, 2 dL/dx)``. The
   gradients make the cost sharp on weak, smooth textures, where
   intensity alone leaves a broad valley (on HCI antinous they cut the
   pixels off by more than 0.07 px from 29 % to 13 % on its wall).
2. **Plane sweep.** For each candidate slope every view is resampled at
   ``p + slope * q_i`` (bilinear, one pass per view and row) and compared
   with the reference, the mean of the central views at the same slope.
   The cost of a pixel is the smallest mean squared difference over nine
   groups of views: all of them, and the eight half-apertures (left,
   right, top, bottom and the four diagonal halves). Near an occlusion
   edge the half that does not see the occluder still agrees on the
   occluded surface, so the edge does not spread. In a concave corner of
   an occluder only a quadrant of the aperture does: on grids with enough
   views the four quadrants count too, at a multiple of their cost
   (:data:`QUADRANT_COST`). Each view's squared difference is scaled to undo the noise
   that resampling it between pixels averages away (half way:
   :data:`NOISE_CORRECTION`), else a weak, noisy texture's cost is least
   at the slopes that blur most. Near the image's border a slope that
   pushes the outer views (the largest differences) out of the image would
   win by that alone, a periodic texture a period off: on the coarse level
   (which sets each tile's slopes) only the groups with the most views
   inside count there, and the cost is raised by the share of views
   outside (:data:`OUTSIDE_PENALTY`).
3. **Coarse to fine.** The whole slope range is swept on a coarse pyramid
   level (about 0.5 px of motion of the outermost view per slope step
   there); at full resolution every 32 px tile sweeps only the slopes
   that the coarse estimate of the tile and its neighbours allows, with
   the same step at full resolution. A tile where the coarse level loses
   the texture (fine stripes or checkers near its Nyquist rate, whose
   coarse cost is flat) sweeps every slope, and a slope beyond those its
   neighbours allow wins there only where the views clearly prefer it
   (:data:`LOST_TEXTURE_SHARE`).
4. **Aggregation.** Per slope, the cost relative to each pixel's best
   (logarithmic, truncated, so that a few strongly textured pixels do not
   out-vote the rest of a window) is smoothed by a guided filter (He et
   al. 2013) whose guide is the centre of the aperture: the window follows
   the image's edges. Where the first estimate is steeply slanted (blocks
   of 32 px, away from depth edges), the cost is aggregated again along
   sheared planes of that slant, and each pixel and slope keeps the lesser
   of the two: a fronto-parallel window on a slanted floor holds many
   disparities at once.
5. **Winner and sub-step.** The slope of least aggregated cost, refined
   by a parabola through its neighbours. The confidence is the gap from
   the best cost to the best cost more than two steps away (0: flat or
   ambiguous cost, 1: one sharp minimum).
6. **Fill.** Where the confidence is low (no texture), the disparity is
   taken from the plane the confident pixels around follow, where they
   follow one (a slanted floor goes on down its slope where its texture
   fades out), else from an edge-aware smoothing of the confident pixels
   (the fast global smoother of Min et al. 2014, guided by the centre
   image, and stopped by steps between confident disparities where the
   image's edge is faint: :data:`FILL_SPREAD`).
7. **Edges.** An unsure pixel at a depth edge of the estimate takes part
   of the step to its neighbour across (:data:`EDGE_BLEND`): which side
   it lies on is what the views tell worst, and the expected value has
   the least squared error.

Accuracy and speed are measured in ``benchmarks/bench_disparity.py``.

References
----------
.. [1] K. He, J. Sun, X. Tang, "Guided image filtering", IEEE TPAMI 35(6), 2013.
.. [2] D. Min, S. Choi, J. Lu, B. Ham, K. Sohn, M. N. Do, "Fast global image
   smoothing based on weighted least squares", IEEE TIP 23(12), 2014.
.. [3] T.-C. Wang, A. A. Efros, R. Ramamoorthi, "Occlusion-aware depth
   estimation using light-field cameras", ICCV 2015 (half-aperture costs).
.. [4] K. Honauer, O. Johannsen, D. Kondermann, B. Goldluecke, "A dataset and
   evaluation methodology for depth estimation on 4D light fields", ACCV 2016
   (the BadPix and MSE metrics of :func:`disparity_scores`).
"""

from __future__ import annotations

import functools
import importlib
import math
from dataclasses import dataclass, field

import numpy as np

from . import _validate
from ._tiles import tiles_holding
from .errors import ParameterError
from .lightfield import LightField
from .pyramid import _reduce_stack, level_shape

__all__ = ["DisparityEstimate", "estimate_disparity", "iter_estimate_disparity", "disparity_scores", "FocusTest"]

#: Weight of the luminance gradients against the luminance in the matching features.
GRADIENT_WEIGHT = 2.0
#: Motion (px) of the outermost view between two candidate slopes, at every level.
STEP_PX = 0.5
#: Truncation of the relative log cost before aggregation.
COST_CAP = 0.5
#: Cost floor added before the logarithm (features are normalised to a bright level of 1).
COST_EPS = 1e-6
#: On the coarse level, where some views sample outside the image, a pixel's cost is multiplied by
#: ``1 + OUTSIDE_PENALTY * (share of the views outside)``: of two slopes that fit about equally well (a periodic
#: texture a period off), the one more views see wins. Applied at full resolution too it fixed a little more of
#: a 4x4 checker wall (fresh scene 707 at -2.2: -7.5 -> -4.6 dB against the naive refocus) but pulled the
#: outermost pixels of an in-focus noise plane up to 0.25 px towards smaller slopes.
OUTSIDE_PENALTY = 0.5
#: (rows, columns) of the tiles the sweep runs over: each needs only the slopes the coarse level
#: allows around it, and wide tiles keep the inner loops long.
TILE = (32, 128)
#: The sweep runs through each tile in blocks of this many rows, every slope of the tile per block: a
#: block's samples of all the views (9x9 views x 3 planes x 9 rows x 129 px: 1.1 MB) stay in the cache
#: from one slope to the next, where a whole tile's (4 MB) did not (HCI 9x9: the sweep 2.1 -> 1.2 s, its
#: costs the same bit for bit).
SWEEP_BLOCK_ROWS = 8
#: Smallest side (px) of the coarse level (it goes as coarse as this allows, at most three levels).
MIN_COARSE_SIZE = 96
#: Coarsest level of the first, full sweep.
MAX_COARSE_LEVEL = 3
#: A second valley of a pixel's aggregated cost at most this far above the least (relative log cost, as
#: :data:`COST_CAP`) makes its disparity ambiguous (:attr:`DisparityEstimate.alternative`).
AMBIGUOUS_GAP = 0.25
#: Coarse pixels at least this confident set the slope range of the full-resolution sweep. A periodic texture's
#: copies a period apart fit about equally well, its coarse confidence (the noise between them) often above
#: 0.3: at 0.3 a checkerboard wall at disparity 4.9 seen by 3x3 views widened the range to +-20 and came out
#: at -19.1, -7.1 or 16.9 on 80 % of its pixels; at 0.5 the other layers set the range and 94 % is right.
COARSE_SURE = 0.5
#: A texture the coarse level cannot see: fine stripes or checkers near its Nyquist rate keep under this
#: share of their local variance there (in the reference view), and their coarse cost is flat ...
LOST_TEXTURE_KEPT = 0.15
#: ... where the full-resolution variance is at least this (luminance scaled to a bright level of 1; sensor
#: noise alone stays below) ...
LOST_TEXTURE_VARIANCE = 1e-3
#: ... and a tile where at least this share of the coarse pixels is such a texture, unsure, sweeps every
#: slope: the sure pixels around it say nothing of its depth (fresh 2613: a stripes square at 4.1 in front
#: of a wall at -2.4 never swept beyond -1, and rendered at an alias). A slope beyond those the sure pixels
#: around suggest wins there only where its aggregated cost is below theirs by more than
#: :data:`AMBIGUOUS_GAP`: a periodic wall's aliases fit alike, and picking among them by the noise put a
#: checker wall's pixels a period off (fresh 1415).
LOST_TEXTURE_SHARE = 0.05
#: A view agrees with the centre of the aperture where its squared feature difference is at most this
#: share of the local texture energy (:class:`FocusTest`) ...
IN_FOCUS_COST = 0.1
#: ... and a slope brings a pixel into focus where at least this share of the views (besides the
#: central ones the comparison is made with) agree.
IN_FOCUS_SHARE = 0.4
#: Floor of the texture energy a view's difference is compared with (features normalised to a bright
#: level of 1) ...
TEXTURE_FLOOR = 1e-5
#: ... and the energy below which a patch is too flat to tell whether it is in focus.
TEXTURE_MIN = 1e-4
#: Radius (px) of the patch whose texture energy the focus test measures.
FOCUS_RADIUS = 1
#: Side (px) of the window in which a surface matched by one central view alone must fill half
#: (:meth:`FocusTest.at_any`).
ALONE_WINDOW = 5
#: Regularisation of the guided filter (guide normalised to [0, 1]). Below a window's guide variance the
#: filter keeps the guide's edges; HCI antinous's dark, weakly textured wall varies by about 1e-4, so at 1e-4
#: the statue's cost spread over it (9x9 MSE x 100: 4.50 at 1e-4, 3.92 at 3e-5, 3.56 at 1e-5; 5x5 5.03 ->
#: 4.03, 3x3 3.79 -> 3.27, BadPix(0.07) within 0.1 point). The synthetic scenes' strong textures lose a
#: little (mean BadPix(0.07) without the checkerboard 14.76 -> 14.91 %).
GUIDE_EPS = 1e-5
#: Exponent of the correction of the noise that bilinear resampling averages away (:func:`_blur_scales`):
#: 0 none, 1 as for white noise (which over-corrects real textures, whose fine detail the resampling
#: also blurs).
NOISE_CORRECTION = 0.5
#: Side (px) of the blocks whose slant is read from the first estimate; a block is slanted where the median
#: of its disparity gradient exceeds :data:`SLANT_MIN` (px per px) along its steeper axis, and its cost (and
#: its neighbours') is aggregated again along planes of slant :data:`SLANT` that way (see
#: :func:`_slanted_aggregate`).
SLANT_BLOCK = 32
SLANT_MIN = 0.02
SLANT = 0.06
#: A disparity gradient (px per px, after a 9 px box) above this is a depth edge, not a slant.
SLANT_EDGE = 0.2
#: The slanted aggregation searches this far (px) either side of the first estimate's sheared disparities.
SLANT_REACH = 1.0
#: The fill takes, where the confident disparities within :data:`PLANE_RADIUS` px (at most an eighth of the
#: image's smaller side) follow a plane, that plane (:func:`_local_planes`): each pixel weighs
#: ``confidence ** PLANE_POWER``, and the plane counts fully up to the first weighted RMS residual of :data:`PLANE_RESIDUAL` (px), not at all
#: from the second, nor where the mean weight over its window is below :data:`PLANE_SUPPORT` (1 % of the window
#: at confidence 0.46). HCI antinous 9x9 BadPix(0.07) / MSE x 100 9.04 / 3.57 -> 6.85 / 2.42 (the floor's bottom
#: rows 1.18 -> 0.04 of the MSE), 5x5 8.89 / 4.03 -> 7.05 / 2.58, 3x3 9.31 / 3.28 -> 7.47 / 2.00.
PLANE_RADIUS = 32
PLANE_POWER = 6
PLANE_RESIDUAL = (0.05, 0.15)
PLANE_SUPPORT = 1e-4
#: A quadrant of the aperture's cost counts this many times its mean squared difference (:func:`_groups`): it wins
#: a slope only where it fits that much better than every half. More groups fit noise better (the quadrants at
#: the halves' own cost: HCI 9x9 BadPix(0.03) 24.9 -> 26.6 %, 3x3 33.2 -> 37.8 %). HCI 9x9 / 5x5 MSE x 100
#: (before the edge blend): 2.42 / 2.58 without quadrants, at factor 2 2.25 / 2.33, 3 2.17 / 2.29, 4 2.14 / 2.20,
#: 5 2.12 / 2.18, 6 2.85 / 2.19 (the dark wall beside the statue's left flank took its disparity over 15 px),
#: 12 2.16 / 2.28.
QUADRANT_COST = 4.0
#: The quadrants count only where each holds at least this many views besides the central ones: on 3x3 (three
#: views) they cost the checkerboard holdout 12 points of BadPix(0.07) and gave nothing on HCI.
QUADRANT_MIN_VIEWS = 6
#: Where a pixel's disparity differs from a 4-neighbour's by more than :data:`EDGE_JUMP` px (a depth edge of the
#: estimate) and its confidence is below :data:`EDGE_SURE`, it moves towards that neighbour's disparity by
#: ``EDGE_BLEND * (1 - confidence / EDGE_SURE)`` of the step (:func:`_blend_edges`): the expected value of
#: an edge pixel that may lie on either side. After the quadrants (without :data:`FILL_SPREAD`), HCI 9x9 / 5x5 /
#: 3x3 MSE x 100 2.14 / 2.20 / 2.00 -> 1.84 / 1.92 / 1.88 and BadPix(0.07) +0.18 point on each (the pixels it
#: moves by more than 0.07 px); blends of 0.3-0.5 with sure limits of 0.15-0.4 gave 1.81-1.92 on 9x9. The
#: synthetic scenes' MSE fell on every one (3-14 %), their BadPix(0.07) rose by 0.1-0.35 point (the checkerboard
#: holdout, a period off anyway, 66.8 -> 68.2).
EDGE_JUMP = 0.5
EDGE_BLEND = 0.35
EDGE_SURE = 0.3
#: The fill's smoothing weakens the link between neighbours whose disparities differ by ``step`` by
#: ``exp(-c * (step / FILL_SPREAD) ** 2)``, ``c`` the lesser confidence of the two (:func:`_smooth`). Where the
#: statue of HCI antinous has a dark rim like the wall behind, the guide's edge is faint and the smoothing carried
#: the statue's disparity 5-10 px over the wall. With the edge blend, HCI 9x9 / 5x5 / 3x3 MSE x 100 1.84 / 1.92 /
#: 1.88 without it, at 0.5 1.61 / 1.71 / 1.78, 1.0 1.71 / 1.80 / 1.80, 2.0 1.80 / 1.88 / 1.86. The sharper edges it
#: leaves cost the synthetic scenes, whose edges are off by a pixel rather than spread: at 0.5 "smooth over fine
#: noise" MSE x 100 7.97 -> 9.20 and the three layers 58.1 -> 63.5 (main: 8.05, 61.5), at 1.0 8.33 and 62.1, at
#: 2.0 8.04 and 60.0.
FILL_SPREAD = 1.0


@dataclass(frozen=True)
class DisparityEstimate:
    """The result of :func:`estimate_disparity`.

    Attributes
    ----------
    disparity : ndarray, shape (Y, X), float32
        Disparity of every pixel of the centre of the aperture, in pixels
        per unit of view position (``refocus(lf, d)`` focuses on it).
    confidence : ndarray, shape (Y, X), float32
        In [0, 1]: how sharply the matching cost singles out that
        disparity (0 where it was filled in from confident neighbours).
    disparity_range : (float, float)
        The slopes that were searched.
    params : dict
        The options used and the time of each stage (``"seconds"``).
    alternative : ndarray, shape (Y, X), float32, optional
        Where the views fit a second disparity about as well (a periodic
        texture, a period away: :data:`AMBIGUOUS_GAP`), that disparity;
        NaN elsewhere. The dense-aperture renderer takes whichever of the
        two is nearer the slope it renders: the smaller change to the
        naive refocus of what the views cannot tell apart.
    """

    disparity: np.ndarray
    confidence: np.ndarray
    disparity_range: tuple
    params: dict = field(default_factory=dict)
    alternative: np.ndarray | None = None


def checked_estimate(disparity, shape):
    """A given disparity as ``(disparity float64 (Y, X), confidence float32 (Y, X), alternative float32
    (Y, X) or None)``, checked.

    ``disparity`` is a :class:`DisparityEstimate` (its confidence and
    alternative are kept) or an array (trusted everywhere: confidence 1,
    no alternative).

    Raises
    ------
    ParameterError
        For a map not of ``shape``, not real, or holding NaN/Inf, a
        confidence outside [0, 1], or an alternative of another shape.
    """
    from .baselines import _disparity_map

    if isinstance(disparity, DisparityEstimate):
        values = _disparity_map(disparity.disparity, shape)
        confidence = np.asarray(disparity.confidence)
        if confidence.shape != values.shape or not np.all((confidence >= 0) & (confidence <= 1)):
            raise ParameterError(f"disparity.confidence must be a {values.shape} array in [0, 1]")
        alternative = disparity.alternative
        if alternative is not None:
            alternative = np.asarray(alternative, np.float32)
            if alternative.shape != values.shape:
                raise ParameterError(f"disparity.alternative must be a {values.shape} array (NaN where there is "
                                     f"none), got shape {alternative.shape}")
        return values, np.ascontiguousarray(confidence, np.float32), alternative
    values = _disparity_map(disparity, shape)
    return values, np.ones(values.shape, np.float32), None


def _kernels():
    return importlib.import_module("._disparity_kernels", __package__)


def _run(name, *args):
    from .refocus import _KERNEL_LOCK

    with _KERNEL_LOCK:
        getattr(_kernels(), name)(*args)


# -- inputs ------------------------------------------------------------------------------

def _luminance_views(lf, luminance=None):
    """Luminance ``(n, Y, X)`` float32 scaled so the bright level is 1, and the sample weights ``(n, Y, X)``
    relative to the largest at each pixel, or None. ``luminance``: ``lf.luminance()``
    (:meth:`~napari_lfalias.LightField.luminance`), where already made (it is not changed)."""
    luminance = lf.luminance() if luminance is None else luminance
    lum = np.asarray(luminance.views()[..., 0], np.float32)  # scaled into a copy below
    weights = lf.flat_weights()
    valid = None
    if weights is not None:
        # relative to the best view at each pixel: a calibrated vignette lowers every view's weight
        # towards the image corners, and the views there still see the scene
        top = weights.max(axis=0)
        valid = np.divide(weights, top, out=np.zeros(weights.shape, np.float32), where=top > 0)
        valid = np.ascontiguousarray(valid, np.float32)
    scale = _bright_level(lum, valid)
    if not math.isfinite(scale) or scale <= 0:
        seen = lum if valid is None else lum[valid > 0.5]
        scale = float(np.max(np.abs(seen), initial=0.0)) or 1.0
    return lum * np.float32(1.0 / scale), valid


@functools.lru_cache(maxsize=2)
def _subsample(size, samples):
    """The fixed random indices (read-only) :func:`_bright_level` takes of ``size`` values: the same draw
    for every light field of that size, made once (a tenth of the level's time), in ascending order (the
    same values, read in order: half the level's time)."""
    pick = np.sort(np.random.default_rng(0).integers(0, size, samples))
    pick.flags.writeable = False
    return pick


def _bright_level(values, valid=None, samples=1 << 20):
    """The 99.5th percentile of ``values`` (where ``valid > 0.5``), from at most ``samples`` of them.

    A fixed random subsample: the level only scales the features, and the
    exact percentile of a 9x9x512x512 stack costs most of a second.
    """
    flat = values.reshape(-1)
    if flat.size > samples:
        pick = _subsample(flat.size, samples)
        flat = flat[pick]
        if valid is not None:
            flat = flat[valid.reshape(-1)[pick] > 0.5]
    elif valid is not None:
        flat = flat[valid.reshape(-1) > 0.5]
    return float(np.percentile(flat, 99.5)) if flat.size else 0.0


def _features(lum):
    """Planes ``(n, 3, Y, X)`` float32: luminance and its central-difference gradients (weighted)."""
    lum = np.ascontiguousarray(lum, np.float32)
    out = np.empty((lum.shape[0], 3) + lum.shape[1:], np.float32)
    _run("feature_planes", lum, np.float32(GRADIENT_WEIGHT / 2.0), out)
    return out


def _groups(positions):
    """Membership ``(n, G)`` of all views, the eight half-apertures (split along the rows, the columns
    and both diagonals) and, on grids large enough, the four quadrants; the least summed sample weight
    each needs to count (a third of its views, at least 1.5); and the factor ``(G,)`` of each group's
    cost (:data:`QUADRANT_COST` for the quadrants, else 1).

    Only the diagonal halves keep a pixel beside a diagonal occluding edge
    clear of the occluder's views: without them the statue of HCI antinous
    spread 2-4 px over the weakly textured wall at its upper left and right
    (9x9: BadPix(0.07) 9.78 -> 9.00 %, MSE x 100 5.35 -> 4.50). Halves at
    22.5 degrees besides made the MSE worse (6.0). In a concave corner of
    an occluder (where the neck meets the shoulder) every half holds views
    the occluder covers, and only a quadrant sees the surface behind
    (:data:`QUADRANT_COST`, :data:`QUADRANT_MIN_VIEWS`).
    """
    q = positions
    eps = 1e-9
    along = [q[:, 1], q[:, 0], q[:, 0] + q[:, 1], q[:, 0] - q[:, 1]]
    halves = [np.ones(len(q), bool)] + [half for a in along for half in (a <= eps, a >= -eps)]
    quadrants = [(sy * q[:, 0] <= eps) & (sx * q[:, 1] <= eps) for sy in (1, -1) for sx in (1, -1)]
    others = np.ones(len(q), bool)
    others[_reference_views(q)] = False
    if min(int(np.sum(quadrant & others)) for quadrant in quadrants) < QUADRANT_MIN_VIEWS:
        quadrants = []
    member = np.stack(halves + quadrants, axis=1)
    counts = member.sum(axis=0)
    min_count = np.maximum(1.5, 0.3 * counts).astype(np.float32)
    scale = np.array([1.0] * len(halves) + [QUADRANT_COST] * len(quadrants), np.float32)
    return np.ascontiguousarray(member), min_count, scale


def _reference_views(positions):
    """Indices of the views nearest the centre of the aperture (one, or the central 2 or 4)."""
    radius = np.hypot(positions[:, 0], positions[:, 1])
    return np.flatnonzero(radius <= radius.min() + 1e-6).astype(np.int64)


def _guide(lf):
    """The centre of the aperture ``(Y, X, C)`` float32 in [0, 1]: the mean of the reference views."""
    views = lf.views()
    ref = _reference_views(lf.flat_positions())
    image = views[ref].mean(axis=0)
    top = _bright_level(image)
    return np.clip(image / (top if top > 0 else 1.0), 0.0, 1.0).astype(np.float32)


# -- the sweep ------------------------------------------------------------------------------

def _tile_plan(needed, shape, tile, block_rows=SWEEP_BLOCK_ROWS):
    """Blocks ``(B, 4)`` (``(y0, y1, x0, x1)``: each tile cut into ``block_rows`` rows) and their slope lists
    (``first (B + 1,)``, ``order``) from ``needed (m, TY, TX)``."""
    height, width = shape
    blocks, first, order = [], [0], []
    for ty in range(needed.shape[1]):
        for tx in range(needed.shape[2]):
            slopes = np.flatnonzero(needed[:, ty, tx]).tolist()
            if not slopes:
                continue
            y_end, x0, x1 = min((ty + 1) * tile[0], height), tx * tile[1], min((tx + 1) * tile[1], width)
            for y0 in range(ty * tile[0], y_end, block_rows):
                blocks.append((y0, min(y0 + block_rows, y_end), x0, x1))
                order.extend(slopes)
                first.append(len(order))
    return (np.array(blocks, np.int64).reshape(-1, 4), np.array(first, np.int64), np.array(order, np.int64))


def _tile_grid(shape, tile):
    """``(TY, TX)``: how many tiles of ``tile`` px cover an image of ``shape`` (the last ones cut short)."""
    return -(-shape[0] // tile[0]), -(-shape[1] // tile[1])


def _all_tiles(n_slopes, shape, tile):
    """``needed`` for a full sweep: every slope in every tile."""
    return np.ones((n_slopes,) + _tile_grid(shape, tile), bool)


def _sweep(features, valid, positions, slopes, needed, shape, tile, border_rule=False):
    """Cost volume ``(m, Y, X)`` float32 (``inf`` where not computed or not enough views). With
    ``border_rule``, where some views sample outside the image only the groups with the largest share of
    their views inside count, and the cost is raised by :data:`OUTSIDE_PENALTY` (see ``sweep_costs``)."""
    member, min_count, group_scale = _groups(positions)
    out = np.full((len(slopes),) + shape, np.inf, np.float32)
    has_valid = valid is not None
    valid = valid if has_valid else np.ones((1, 1, 1), np.float32)
    blocks, first, order = _tile_plan(needed, shape, tile)
    _run("sweep_costs", features, valid, has_valid, np.ascontiguousarray(positions, np.float64),
         np.ascontiguousarray(slopes, np.float64), _reference_views(positions), member, min_count, group_scale,
         border_rule, np.float32(OUTSIDE_PENALTY), blocks, first, order, _blur_scales(positions, slopes), out)
    return out


def _interpolation_gain(shift):
    """The factor by which bilinear interpolation at ``shift`` (px, along one axis) scales the variance of
    white noise: ``(1 - f)^2 + f^2`` for the fraction ``f``."""
    fraction = shift - np.floor(shift)
    return (1.0 - fraction) ** 2 + fraction ** 2


def _blur_scales(positions, slopes, power=None):
    """``(m, n)`` float32: the factor of each view's squared differences at each slope that undoes the
    noise the bilinear resampling averages away, to the power :data:`NOISE_CORRECTION`.

    Resampling a view between pixels averages its noise: the difference
    to the reference has the variance ``v = sum_u c_u^2 g_u`` (``c``: the
    coefficients of the view and of the reference views, ``g``:
    :func:`_interpolation_gain` of each), less than ``v0`` at whole-pixel
    shifts. Left alone, a weak, noisy texture's cost is least at the
    slopes that blur most (a comb of false minima one pixel per view step
    apart on HCI antinous's floor); ``(v0 / v) ** power`` evens it out.
    """
    power = NOISE_CORRECTION if power is None else power
    ref = _reference_views(positions)
    gain = (_interpolation_gain(np.outer(slopes, positions[:, 0]))
            * _interpolation_gain(np.outer(slopes, positions[:, 1])))
    in_ref = np.zeros(len(positions))
    in_ref[ref] = 1.0
    own = 1.0 - 2.0 * in_ref / len(ref)  # a view's own coefficient squared, less its share of the reference
    variance = gain * own + gain[:, ref].sum(axis=1, keepdims=True) / len(ref) ** 2
    whole = own + 1.0 / len(ref)
    scale = np.ones_like(variance)
    alone = whole > 1e-9  # the only reference view differs from itself by nothing: left at 1
    np.divide(whole[None], variance, out=scale, where=alone[None] & (variance > 1e-9))
    return np.ascontiguousarray(scale ** power, np.float32)


def _relative_cost(cost):
    """``min(log(c + eps) - min_s log(c + eps), cap)``; ``cap`` where not computed."""
    cost = np.ascontiguousarray(cost, np.float32)
    out = np.empty_like(cost)
    _run("relative_costs", cost, np.float32(COST_EPS), np.float32(COST_CAP), out)
    return out


# -- aggregation ----------------------------------------------------------------------------

def _box(stack, radius):
    stack = np.ascontiguousarray(stack, np.float32)
    squeeze = stack.ndim == 2
    if squeeze:
        stack = stack[None]
    out = np.empty_like(stack)
    _run("box_mean_stack", stack, int(radius), out)
    return out[0] if squeeze else out


def _down2(stack):
    """Mean of 2x2 blocks over the last two axes (the last row/column repeated when odd)."""
    height, width = stack.shape[-2:]
    if height % 2 or width % 2:
        pad = [(0, 0)] * (stack.ndim - 2) + [(0, height % 2), (0, width % 2)]
        stack = np.pad(stack, pad, mode="edge")
    return 0.25 * (stack[..., 0::2, 0::2] + stack[..., 1::2, 0::2] + stack[..., 0::2, 1::2] + stack[..., 1::2, 1::2])


def _up_axis(array, n_out, axis):
    """Linear interpolation by 2 along ``axis`` (sample centres at half pixels), to ``n_out`` samples."""
    n_in = array.shape[axis]
    where = (np.arange(n_out) + 0.5) / 2.0 - 0.5
    low = np.clip(np.floor(where).astype(np.int64), 0, n_in - 1)
    high = np.minimum(low + 1, n_in - 1)
    frac = np.clip(where - low, 0.0, 1.0).astype(np.float32)
    shape = [1] * array.ndim
    shape[axis] = n_out
    frac = frac.reshape(shape)
    return np.take(array, low, axis=axis) * (1 - frac) + np.take(array, high, axis=axis) * frac


def _up2(stack, shape):
    return _up_axis(_up_axis(stack, shape[0], stack.ndim - 2), shape[1], stack.ndim - 1)


class _GuidedFilter:
    """He et al.'s guided filter (grey or colour guide) on stacks of images, its coefficients
    computed at half resolution (the "fast guided filter" of He and Sun 2015): on HCI antinous the
    disparity this aggregates loses 0.2 points of BadPix(0.07) against the full-resolution filter
    and the aggregation runs four times faster."""

    def __init__(self, guide, radius, eps=GUIDE_EPS):
        guide = np.asarray(guide, np.float32)
        self.guide = guide if guide.ndim == 3 else guide[..., None]
        self.shape = self.guide.shape[:2]
        self.radius = max(1, radius // 2)
        channels = _down2(np.moveaxis(self.guide, -1, 0))  # (C, y, x)
        self.channels = channels
        self.mean = _box(channels, self.radius)
        n_ch = channels.shape[0]
        products = np.stack([channels[a] * channels[b] for a in range(n_ch) for b in range(n_ch)])
        means = np.stack([self.mean[a] * self.mean[b] for a in range(n_ch) for b in range(n_ch)])
        cov = (_box(products, self.radius) - means).reshape((n_ch, n_ch) + channels.shape[1:])
        cov = np.moveaxis(cov, (0, 1), (-2, -1)).astype(np.float64) + eps * np.eye(n_ch)
        self.inverse = np.linalg.inv(cov).astype(np.float32)  # (y, x, C, C)

    def __call__(self, stack):
        """Filter every image of ``stack (m, Y, X)``."""
        return self.window(stack, 0, 0)

    def window(self, stack, y0, x0):
        """Filter ``stack (m, h, w)``, the window of the image at even offsets ``(y0, x0)``.

        Pixels within the filter's reach of a window edge that is not an
        image edge see a cut window; callers keep only the inner part.
        """
        stack = np.ascontiguousarray(stack, np.float32)
        out = np.empty_like(stack)
        _run("guided_windows", stack, int(y0), int(x0), np.ascontiguousarray(self.guide),
             np.ascontiguousarray(self.channels, np.float32), np.ascontiguousarray(self.mean, np.float32),
             np.ascontiguousarray(self.inverse), int(self.radius), out)
        return out

    def window_numpy(self, stack, y0, x0):
        """:meth:`window` in plain numpy (the reference the kernel is tested against)."""
        n_ch = self.channels.shape[0]
        height, width = stack.shape[1:]
        ys = slice(y0 // 2, y0 // 2 + -(-height // 2))
        xs = slice(x0 // 2, x0 // 2 + -(-width // 2))
        channels, mean, inverse = self.channels[:, ys, xs], self.mean[:, ys, xs], self.inverse[ys, xs]
        small = _down2(np.asarray(stack, np.float32))
        mean_p = _box(small, self.radius)
        cov_ip = np.stack([_box(small * channels[c], self.radius) - mean[c] * mean_p
                           for c in range(n_ch)], axis=-1)  # (m, y, x, C)
        a = np.einsum("yxcd,myxd->myxc", inverse, cov_ip)
        b = mean_p - np.einsum("myxc,cyx->myx", a, mean)
        out = _up2(_box(b, self.radius), (height, width))
        guide = self.guide[y0:y0 + height, x0:x0 + width]
        for c in range(n_ch):
            out += _up2(_box(np.ascontiguousarray(a[..., c]), self.radius), (height, width)) * guide[..., c]
        return out


def _aggregate(relative, needed, guided, radius):
    """The guided filter of every slope's relative cost, computed only over the tiles that need the
    slope (their bounding box in tile units, grown by the filter's reach); ``COST_CAP`` elsewhere."""
    m, height, width = relative.shape
    tile_h, tile_w = -(-height // needed.shape[1]), -(-width // needed.shape[2])
    reach = 2 * radius + 2
    out = np.full(relative.shape, COST_CAP, np.float32)
    boxes = {}
    for j in range(m):
        rows, cols = np.flatnonzero(needed[j].any(axis=1)), np.flatnonzero(needed[j].any(axis=0))
        if rows.size:
            key = (rows[0], rows[-1], cols[0], cols[-1])
            boxes.setdefault(key, []).append(j)
    for (r0, r1, c0, c1), js in boxes.items():
        y0, y1 = r0 * tile_h, min(height, (r1 + 1) * tile_h)
        x0, x1 = c0 * tile_w, min(width, (c1 + 1) * tile_w)
        # grow by the filter's reach, to even offsets (the coefficients live at half resolution)
        gy0, gx0 = max(0, y0 - reach) // 2 * 2, max(0, x0 - reach) // 2 * 2
        gy1, gx1 = min(height, y1 + reach), min(width, x1 + reach)
        filtered = guided.window(relative[js, gy0:gy1, gx0:gx1], gy0, gx0)
        out[js, y0:y1, x0:x1] = filtered[:, y0 - gy0:y1 - gy0, x0 - gx0:x1 - gx0]
    return out


def _block_slants(disparity, block=SLANT_BLOCK):
    """``(gy, gx)``: the median disparity gradient (px per px) of every ``block`` x ``block`` block, over its
    pixels away from depth edges (a gradient above :data:`SLANT_EDGE`, and 4 px around); 0 for a block
    with less than half its pixels left."""
    from scipy import ndimage

    gy, gx = np.gradient(_box(disparity, 4).astype(np.float64))
    edge = ndimage.binary_dilation(np.hypot(gy, gx) > SLANT_EDGE, iterations=4)
    height, width = disparity.shape
    n_y, n_x = -(-height // block), -(-width // block)

    def medians(gradient):
        padded = np.full((n_y * block, n_x * block), np.nan)
        padded[:height, :width] = np.where(edge, np.nan, gradient)
        per_block = padded.reshape(n_y, block, n_x, block).transpose(0, 2, 1, 3).reshape(n_y, n_x, -1)
        enough = np.isfinite(per_block).sum(axis=-1) >= block * block // 2
        per_block[~enough] = 0.0
        return np.nanmedian(per_block, axis=-1)

    return medians(gy), medians(gx)


def _shears(disparity, block=SLANT_BLOCK):
    """``{(slant_y, slant_x): blocks (n_y, n_x) bool}``: the slanted planes to aggregate along and where.

    A block whose median gradient (:func:`_block_slants`) exceeds
    :data:`SLANT_MIN` along its steeper axis asks for :data:`SLANT` that
    way, for itself and its two neighbours that way (the first estimate
    flattens a slant towards its ends, where the fronto-parallel windows
    fail most).
    """
    gy, gx = _block_slants(disparity, block)
    shears = {}
    for i, j in np.argwhere(np.maximum(np.abs(gy), np.abs(gx)) >= SLANT_MIN):
        along_y = abs(gy[i, j]) >= abs(gx[i, j])
        slant = (math.copysign(SLANT, gy[i, j]), 0.0) if along_y else (0.0, math.copysign(SLANT, gx[i, j]))
        blocks = shears.setdefault(slant, np.zeros(gy.shape, bool))
        if along_y:
            blocks[max(i - 1, 0):i + 2, j] = True
        else:
            blocks[i, max(j - 1, 0):j + 2] = True
    return shears


def _sheared_range(needed, tile, window, shear, centre):
    """``(k_lo, k_hi)``: the sheared slope indices (``t - shear . (p - centre)``) that hold a computed cost
    in ``window = (y0, y1, x0, x1)``, from the slopes every tile there needed; None if none."""
    y0, y1, x0, x1 = window
    k_lo, k_hi = np.inf, -np.inf
    for ty in range(y0 // tile[0], -(-y1 // tile[0])):
        for tx in range(x0 // tile[1], -(-x1 // tile[1])):
            used = np.flatnonzero(needed[:, ty, tx])
            if used.size == 0:
                continue
            ys = np.array([max(y0, ty * tile[0]), min(y1, (ty + 1) * tile[0]) - 1]) - y0 - centre[0]
            xs = np.array([max(x0, tx * tile[1]), min(x1, (tx + 1) * tile[1]) - 1]) - x0 - centre[1]
            shifts = shear[0] * ys[:, None] + shear[1] * xs[None, :]
            k_lo = min(k_lo, used[0] - shifts.max())
            k_hi = max(k_hi, used[-1] - shifts.min())
    return None if k_lo > k_hi else (k_lo, k_hi)


def _slanted_aggregate(relative, needed, guided, radius, step, slant, blocks, first, out, block=SLANT_BLOCK):
    """Lower ``out`` (the fronto-parallel aggregation) to the guided filter of ``relative`` along planes of
    ``slant`` (px per px, ``(y, x)``) where that is less, over the pixels of ``blocks``, for the slopes within
    :data:`SLANT_REACH` of the plane of that slant through the first estimate (``first``, in slope indices);
    returns the boxes ``(y0, y1, x0, x1)`` it may have changed.

    A window of a strongly slanted surface holds many disparities: its
    fronto-parallel aggregate is broad and its minimum drifts (HCI
    antinous's floor, 0.06 px per px). Sheared along the slant
    (:func:`_disparity_kernels.shear_slices`), filtered, and sheared back,
    every pixel's cost is aggregated over the plane of that slant through
    it; the least of the two costs per pixel and slope keeps fronto-parallel
    surfaces (and edges) as they were.
    """
    from scipy import ndimage

    m, height, width = relative.shape
    tile = (-(-height // needed.shape[1]), -(-width // needed.shape[2]))
    reach = 2 * radius + 2
    shear = (slant[0] / step, slant[1] / step)
    labels, _ = ndimage.label(blocks)
    boxes = []
    for index, (rows, cols) in enumerate(ndimage.find_objects(labels), start=1):
        y0, y1 = rows.start * block, min(height, rows.stop * block)
        x0, x1 = cols.start * block, min(width, cols.stop * block)
        gy0, gx0 = max(0, y0 - reach) // 2 * 2, max(0, x0 - reach) // 2 * 2
        gy1, gx1 = min(height, y1 + reach), min(width, x1 + reach)
        centre = (0.5 * (gy1 - gy0 - 1), 0.5 * (gx1 - gx0 - 1))
        span = _sheared_range(needed, tile, (gy0, gy1, gx0, gx1), shear, centre)
        if span is None:
            continue
        # the sheared indices of the first estimate: nearly constant along a slant it half follows
        ys, xs = np.ogrid[0:gy1 - gy0, 0:gx1 - gx0]
        along = first[gy0:gy1, gx0:gx1] - shear[0] * (ys - centre[0]) - shear[1] * (xs - centre[1])
        low, high = np.percentile(along, [5, 95])
        around = SLANT_REACH / step
        j0 = int(math.floor(max(span[0], low - around)))
        top = int(math.ceil(min(span[1], high + around)))
        if top <= j0:
            continue
        sheared = np.empty((top - j0 + 1, gy1 - gy0, gx1 - gx0), np.float32)
        _run("shear_slices", relative, gy0, gx0, j0, shear[0], shear[1], centre[0], centre[1], COST_CAP, sheared)
        filtered = guided.window(sheared, gy0, gx0)
        inside = np.zeros(sheared.shape[1:], bool)
        mine = np.repeat(np.repeat(labels[rows, cols] == index, block, 0), block, 1)
        inside[y0 - gy0:y1 - gy0, x0 - gx0:x1 - gx0] = mine[:y1 - y0, :x1 - x0]
        _run("unshear_min", filtered, j0, shear[0], shear[1], centre[0], centre[1], gy0, gx0, inside, 0, m - 1, out)
        boxes.append((y0, y1, x0, x1))
    return boxes


def _winner(aggregated, slopes, step, cost=None):
    """Sub-step argmin of the aggregated cost and the confidence of the choice.

    The sub-step offset is the vertex of a parabola through the costs
    around the winner: the raw ``cost`` volume's over a 3x3 window when
    given (the aggregated cost is capped, :data:`COST_CAP`, and flattens
    the curve's sides: its vertex snaps to the grid), else the aggregated.

    Returns the disparity, the confidence and the alternative: the slope
    of a second valley of the cost within :data:`AMBIGUOUS_GAP` of the
    least (a periodic texture a period away), NaN where there is none.
    """
    m = len(slopes)
    aggregated = np.ascontiguousarray(aggregated, np.float32)
    best, second_at = np.empty(aggregated.shape[1:], np.int64), np.empty(aggregated.shape[1:], np.int64)
    least, second = np.empty(best.shape, np.float32), np.empty(best.shape, np.float32)
    _run("winner_scan", aggregated, 2, best, least, second, second_at)
    inner = np.clip(best, 1, max(m - 2, 1))
    if cost is not None and m >= 3:
        offset = np.empty(best.shape, np.float32)
        _run("subslope_offsets", np.ascontiguousarray(cost, np.float32), best, 1, offset)
        disparity = slopes[best] + offset * step
    elif m >= 3:
        c0 = np.take_along_axis(aggregated, (inner - 1)[None], 0)[0]
        c1 = np.take_along_axis(aggregated, inner[None], 0)[0]
        c2 = np.take_along_axis(aggregated, (inner + 1)[None], 0)[0]
        curvature = c0 - 2 * c1 + c2
        safe = np.where(curvature > 1e-9, curvature, 1.0)
        offset = np.where(curvature > 1e-9, 0.5 * (c0 - c2) / safe, 0.0)
        disparity = slopes[inner] + np.clip(offset, -0.5, 0.5) * step
    else:
        disparity = slopes[best].astype(np.float64)
    gap = np.where(np.isfinite(second), second - least, 0.0)
    confidence = 1.0 - np.exp(-np.maximum(gap, 0.0) / (0.6 * COST_CAP))
    at_end = (best == 0) | (best == m - 1)
    confidence[at_end] *= 0.25
    ambiguous = (second_at >= 0) & (gap < AMBIGUOUS_GAP)
    alternative = np.where(ambiguous, slopes[np.maximum(second_at, 0)], np.nan)
    return disparity.astype(np.float32), confidence.astype(np.float32), alternative.astype(np.float32)


# -- filling ---------------------------------------------------------------------------------

def _filled(disparity, confidence, guide):
    """``disparity`` where confident; where not, the plane the confident values around follow
    (:func:`_local_planes`) where they follow one, else an edge-aware smoothing of them that stops at the
    image's edges and at steps between confident disparities (:data:`FILL_SPREAD`)."""
    smooth, _ = _smooth(disparity, confidence ** 2, guide, lam=30.0, gate=confidence)
    # at most an eighth of a small image: its window would hold all of it (a whole vesicle fitted by one plane)
    radius = max(2, min(PLANE_RADIUS, min(disparity.shape) // 8))
    plane, fit = _local_planes(disparity, confidence, radius)
    smooth = fit * plane + (1 - fit) * smooth
    keep = confidence ** 2
    return (keep * disparity + (1 - keep) * smooth).astype(np.float32)


def _largest_step(disparity):
    """``(step, across)`` ``(Y, X)``: the largest absolute difference of every pixel's disparity to one of
    its four neighbours, and that neighbour's disparity (the pixel's own where it has no neighbour)."""
    d = np.asarray(disparity, np.float32)
    padded = np.pad(d, 1, mode="edge")
    height, width = d.shape
    step, across = np.zeros_like(d), d.copy()
    for dy, dx in ((-1, 0), (1, 0), (0, -1), (0, 1)):
        neighbour = padded[1 + dy:1 + dy + height, 1 + dx:1 + dx + width]
        difference = np.abs(neighbour - d)
        larger = difference > step
        step = np.where(larger, difference, step)
        across = np.where(larger, neighbour, across)
    return step, across


def _blend_edges(disparity, confidence):
    """``disparity`` with its unsure pixels at depth edges moved towards the other side's disparity.

    Where a pixel's disparity jumps by more than :data:`EDGE_JUMP` to a
    neighbour's and its confidence is below :data:`EDGE_SURE`, the pixel
    takes ``w`` of the step to that neighbour, ``w = EDGE_BLEND * (1 -
    confidence / EDGE_SURE)``. Which side an edge pixel lies on is what the
    views decide worst (they see it partly covered); an estimate that takes
    one side is off by the whole jump where it is wrong, and the mean
    squared error is least at the expected value, ``p`` of the way across
    for the chance ``p`` of being wrong. On HCI antinous (9x9) the pixels at
    such jumps were on the wrong side in 42 % at confidence below 0.05,
    30 % at 0.1-0.2, 9 % at 0.3-0.5 and 1 % above.

    Examples
    --------
    >>> import numpy as np
    >>> d = np.repeat([[0.0, 0.0, 2.0, 2.0]], 2, axis=0)
    >>> out = _blend_edges(d, np.array([[0.9, 0.0, 0.15, 0.9]] * 2))
    >>> [round(float(v), 3) for v in out[0]]  # the unsure pixels step 0.35 and 0.175 of the jump
    [0.0, 0.7, 1.65, 2.0]
    """
    step, across = _largest_step(disparity)
    weight = EDGE_BLEND * np.clip(1.0 - np.asarray(confidence, np.float32) / EDGE_SURE, 0.0, 1.0)
    weight = np.where(step > EDGE_JUMP, weight, np.float32(0.0))
    return (disparity + weight * (across - disparity)).astype(np.float32)


def _local_planes(disparity, confidence, radius):
    """``(plane, fit)`` ``(Y, X)``: the least-squares plane of ``disparity`` over the square of ``radius``
    around every pixel (weights ``confidence ** PLANE_POWER``) at that pixel, and how well the plane fits:
    1 where the weighted RMS residual is at most ``PLANE_RESIDUAL[0]`` px, 0 from ``PLANE_RESIDUAL[1]`` on
    (a window across a depth edge, or a curved surface), linear between.

    The smoothing fill is of order zero: beyond the last confident pixel of a slanted surface it holds
    that pixel's value. HCI antinous's floor (0.06 px per px) loses its texture towards the image's bottom,
    where the fill held +1.0 over a truth of -0.8 (a third of the 9x9 squared error, in the bottom 30 rows);
    the plane goes on down the slope. A steep weight (a pixel at confidence 0.5 counts 1/64 of a sure
    one) keeps the wrong, unsure winners there out of the fit.

    Examples
    --------
    >>> import numpy as np
    >>> ys, xs = np.mgrid[0:64, 0:64]
    >>> ramp = 0.05 * ys + 0.01 * xs
    >>> sure = (ys < 40).astype(float)  # unsure winners at 9 below row 40
    >>> plane, fit = _local_planes(np.where(sure > 0, ramp, 9.0), sure, radius=16)
    >>> bool(fit[40:55].min() == 1), bool(np.abs(plane - ramp)[40:55].max() < 1e-3)
    (True, True)
    >>> bool(fit[55:].max() == 0)  # within the radius one confident row (a line: no plane) or none
    True
    """
    height, width = disparity.shape
    # centred coordinates keep the float32 moments precise (their spread, not their offset, matters)
    ys = (np.arange(height, dtype=np.float32) - np.float32(0.5 * (height - 1)))[:, None]
    xs = (np.arange(width, dtype=np.float32) - np.float32(0.5 * (width - 1)))[None, :]
    d = np.asarray(disparity, np.float32)
    w = np.asarray(confidence, np.float32) ** PLANE_POWER
    wy, wx, wd = w * ys, w * xs, w * d
    total, my, mx, syy, syx, sxx, md, sdy, sdx, sdd = _box(
        np.stack([w, wy, wx, wy * ys, wy * xs, wx * xs, wd, wd * ys, wd * xs, wd * d]), radius)
    enough = total > PLANE_SUPPORT
    inverse = np.float32(1.0) / np.where(enough, total, np.float32(1.0))
    my, mx, md = my * inverse, mx * inverse, md * inverse
    cyy, cyx, cxx = syy * inverse - my * my, syx * inverse - my * mx, sxx * inverse - mx * mx
    cdy, cdx, cdd = sdy * inverse - md * my, sdx * inverse - md * mx, sdd * inverse - md * md
    det = cyy * cxx - cyx * cyx
    enough &= det > 1e-6 * radius ** 4  # the confident pixels do not all lie on one line
    det = np.where(enough, det, np.float32(1.0))
    gy = np.where(enough, (cdy * cxx - cdx * cyx) / det, np.float32(0.0))
    gx = np.where(enough, (cdx * cyy - cdy * cyx) / det, np.float32(0.0))
    plane = md + gy * (ys - my) + gx * (xs - mx)
    residual = np.sqrt(np.maximum(cdd - gy * cdy - gx * cdx, np.float32(0.0)))
    low, high = PLANE_RESIDUAL
    fit = np.clip((high - residual) * np.float32(1.0 / (high - low)), 0.0, 1.0) * enough
    return plane, fit


def _smooth(values, weights, guide, lam, sigma=0.02, iterations=3, gate=None):
    """Edge-aware normalised smoothing of ``values`` with data ``weights`` (fast global smoother).

    With a ``gate (Y, X)`` in [0, 1], the link between two neighbours
    weakens by ``exp(-min(gate) * (step / FILL_SPREAD) ** 2)`` for the
    ``step`` between their ``values`` too: a depth edge of the values the
    gate trusts on both sides stops the smoothing where the guide's edge
    is faint.
    """
    stack = np.stack([values * weights, weights], axis=-1).astype(np.float64)
    guide = np.ascontiguousarray(guide if guide.ndim == 3 else guide[..., None], np.float64)
    guide_t = np.ascontiguousarray(guide.transpose(1, 0, 2))
    depth = np.ascontiguousarray(values, np.float64)
    gate = np.zeros(depth.shape) if gate is None else np.ascontiguousarray(gate, np.float64)
    depth_t, gate_t = np.ascontiguousarray(depth.T), np.ascontiguousarray(gate.T)
    inv_spread2 = 1.0 / FILL_SPREAD ** 2
    for t in range(iterations):
        # the schedule of Min et al.: lam shrinks by 4 per iteration, summing to 1.5 lam
        lam_t = lam * 1.5 * 4.0 ** (iterations - t - 1) / (4.0 ** iterations - 1)
        out = np.empty_like(stack)
        _run("wls_rows", np.ascontiguousarray(stack), guide, lam_t, sigma, depth, gate, inv_spread2, out)
        stack_t = np.ascontiguousarray(out.transpose(1, 0, 2))
        out_t = np.empty_like(stack_t)
        _run("wls_rows", stack_t, guide_t, lam_t, sigma, depth_t, gate_t, inv_spread2, out_t)
        stack = out_t.transpose(1, 0, 2)
    den = stack[..., 1]
    safe = np.where(den > 1e-9, den, 1.0)
    return np.where(den > 1e-9, stack[..., 0] / safe, values), den


# -- the public entry point ---------------------------------------------------------------

def _search_range(lf, disparity_range, qmax):
    if disparity_range is None:
        known = lf.meta.get("disparity_range")
        if known is not None:
            low, high = (float(v) for v in known)
            margin = 0.1 * max(high - low, 1.0)
            return low - margin, high + margin
        reach = 0.1 * min(lf.image_shape) / max(qmax, 1e-9)
        return -reach, reach
    return _validate.value_range("disparity_range", disparity_range)


def _coarse_level(shape):
    """The pyramid level of the full sweep: as coarse as keeps ``MIN_COARSE_SIZE`` pixels a side."""
    level = 0
    while level < MAX_COARSE_LEVEL and min(level_shape(shape, level + 1)) >= MIN_COARSE_SIZE:
        level += 1
    return level


def _slope_grid(low, high, step):
    count = int(math.floor((high - low) / step + 1e-9)) + 1
    start = 0.5 * (low + high) - 0.5 * (count - 1) * step
    return start + step * np.arange(count)


def _reduce_views(lum, valid, levels):
    """Luminance views and sample weights reduced ``levels`` times (normalised convolution)."""
    for _ in range(levels):
        lum, valid = _reduce_stack(lum, valid, per_weight=1)
    return lum, valid


def _lost_texture(reference, coarse_reference, coarse_level, radius=2):
    """``(h, w)`` bool: coarse pixels whose texture the coarse level loses.

    Where the reference view's luminance ``reference (Y, X)`` varies (by at
    least :data:`LOST_TEXTURE_VARIANCE` around each coarse pixel) and its
    reduction ``coarse_reference (h, w)`` keeps under :data:`LOST_TEXTURE_KEPT`
    of that variance (over ``radius`` coarse pixels): stripes or checkers
    near the coarse level's Nyquist rate, whose coarse cost is flat.
    """
    def local_variance(image, r):
        mean = _box(image, r)
        return np.maximum(_box(image * image, r) - mean * mean, 0.0)

    scale = 2 ** coarse_level
    height, width = coarse_reference.shape
    fine = local_variance(reference, radius * scale + scale // 2)[::scale, ::scale][:height, :width]
    kept = local_variance(coarse_reference, radius)
    return (fine >= LOST_TEXTURE_VARIANCE) & (kept < LOST_TEXTURE_KEPT * fine)


def _lost_tiles(lost, coarse_level, shape, tile):
    """``(TY, TX)`` bool: the tiles where at least :data:`LOST_TEXTURE_SHARE` of the coarse pixels are
    ``lost`` (:func:`_lost_texture`)."""
    scale = 2 ** coarse_level
    n_ty, n_tx = _tile_grid(shape, tile)
    out = np.zeros((n_ty, n_tx), bool)
    for ty in range(n_ty):
        for tx in range(n_tx):
            inner = lost[ty * tile[0] // scale:-(-(ty + 1) * tile[0] // scale),
                         tx * tile[1] // scale:-(-(tx + 1) * tile[1] // scale)]
            out[ty, tx] = inner.size > 0 and inner.mean() >= LOST_TEXTURE_SHARE
    return out


def _clearly_beyond(aggregated, near, tiles, tile, slopes, positions):
    """Where ``tiles (TY, TX)`` holds, pixels keep a slope beyond those their tile's ``near (m, TY, TX)``
    names only where every view sees the pixel inside the image at that slope and its ``aggregated
    (m, Y, X)`` cost is below the least of the near slopes' by more than :data:`AMBIGUOUS_GAP`; elsewhere
    the costs beyond are set to :data:`COST_CAP` (in place).

    Near the image's border a far slope pushes the outer views out of the
    image, and what is left fits by that alone (fresh 314: the border rows of
    a stripes wall at -3.7 came out at 12.5, the end of the range).
    """
    height, width = aggregated.shape[1:]
    reach_y, reach_x = np.abs(positions).max(axis=0)
    for ty, tx in zip(*np.nonzero(tiles)):
        inside = near[:, ty, tx]
        if not inside.any() or inside.all():
            continue
        ys = slice(ty * tile[0], min((ty + 1) * tile[0], height))
        xs = slice(tx * tile[1], min((tx + 1) * tile[1], width))
        block = aggregated[:, ys, xs]
        beyond = block[~inside]
        y = np.arange(ys.start, ys.stop)[:, None]
        x = np.arange(xs.start, xs.stop)[None, :]
        margin = np.minimum(np.minimum(y, height - 1 - y) / max(reach_y, 1e-9),
                            np.minimum(x, width - 1 - x) / max(reach_x, 1e-9))  # the largest |slope| all views see
        seen = np.abs(slopes[~inside])[:, None, None] <= margin[None]
        beyond = np.where(seen, beyond, COST_CAP)
        unclear = beyond.min(axis=0) >= block[inside].min(axis=0) - AMBIGUOUS_GAP
        beyond[:, unclear] = COST_CAP
        block[~inside] = beyond
    return aggregated


def _tile_slopes(coarse, coarse_level, shape, slopes, margin, tile):
    """``(m, TY, TX)``: the slopes each tile needs, from the coarse estimate over the tile and half a tile
    around it (NaN: not sure; a tile with nothing sure around it needs every slope), widened by ``margin``.
    ``coarse`` is one map ``(h, w)`` or several ``(k, h, w)`` (the estimate and its alternatives)."""
    scale = 2 ** coarse_level
    n_ty, n_tx = _tile_grid(shape, tile)
    needed = np.zeros((len(slopes), n_ty, n_tx), bool)
    coarse = coarse.reshape((-1,) + coarse.shape[-2:])
    height, width = coarse.shape[1:]
    for ty in range(n_ty):
        ys = slice(max(0, (ty * tile[0] - tile[0] // 2) // scale), min(height, -(-((ty + 1) * tile[0] + tile[0] // 2) // scale)))
        for tx in range(n_tx):
            xs = slice(max(0, (tx * tile[1] - tile[0] // 2) // scale),
                       min(width, -(-((tx + 1) * tile[1] + tile[0] // 2) // scale)))
            block = coarse[:, ys, xs]
            block = block[np.isfinite(block)]
            if block.size == 0:  # nothing sure around the tile: every slope of the grid
                needed[:, ty, tx] = True
                continue
            low, high = float(block.min()) - margin, float(block.max()) + margin
            needed[:, ty, tx] = (slopes >= low) & (slopes <= high)
    return needed


def estimate_disparity(lf, disparity_range=None, *, radius=None, fill=True, progress=None):
    """Estimate the disparity of every pixel from the light field alone.

    Parameters
    ----------
    lf : LightField
        The light field (at least two views; colour or grey). Sample
        weights are honoured: every comparison counts by its weight.
    disparity_range : (float, float), optional
        Smallest and largest disparity to search (pixels per unit of view
        position). Default: ``lf.meta["disparity_range"]`` widened by 10 %,
        else up to 10 % of the image size of motion of the outermost view
        either way.
    radius : int, optional
        Radius (px) of the guided-filter window that aggregates the cost;
        default ``max(2, min(Y, X) // 50)``.
    fill : bool
        Replace low-confidence disparities by an edge-aware smoothing of
        the confident ones and blend unsure pixels at depth edges with the
        other side (default). False returns the raw winners.
    progress : callable, optional
        Called as ``progress(done, total, step)`` after each stage
        (:func:`iter_estimate_disparity` gives the same steps as a
        generator, for a worker that may be stopped between them).

    Returns
    -------
    DisparityEstimate
        ``disparity`` and ``confidence`` (Y, X) float32.

    Raises
    ------
    ParameterError
        For a light field with one view, or a bad range or radius.

    Notes
    -----
    The method is described in the module docstring; accuracy (HCI
    benchmark metrics) and time are in ``benchmarks/results/disparity.md``.

    Examples
    --------
    >>> import numpy as np
    >>> from napari_lfalias.synthetic import textured_plane
    >>> lf = textured_plane(n_views=5, size=64, disparity=1.25).lightfield
    >>> est = estimate_disparity(lf, disparity_range=(-3, 3))
    >>> bool(abs(np.median(est.disparity[16:-16, 16:-16]) - 1.25) < 0.05)
    True
    """
    steps = iter_estimate_disparity(lf, disparity_range, radius=radius, fill=fill)
    while True:
        try:
            done, total, step = next(steps)
        except StopIteration as finished:
            return finished.value
        if progress is not None:
            progress(done, total, step)


def iter_estimate_disparity(lf, disparity_range=None, *, radius=None, fill=True):
    """:func:`estimate_disparity` step by step: yields ``(done, total, step)`` after each stage and returns
    the :class:`DisparityEstimate` (``StopIteration.value``); closing it between stages stops the work.

    Parameters and errors are those of :func:`estimate_disparity`, checked
    when the generator is first advanced.

    Examples
    --------
    >>> from napari_lfalias.synthetic import textured_plane
    >>> steps = iter_estimate_disparity(textured_plane(n_views=3, size=32).lightfield)
    >>> [step for _, _, step in steps]
    ['inputs', 'coarse sweep', 'sweep', 'aggregation', 'fill']
    """
    import time

    if not isinstance(lf, LightField):
        raise ParameterError(f"lf must be a napari_lfalias.LightField, got {type(lf).__name__}")
    if lf.is_lazy:
        lf = lf.compute()
    if lf.n_views < 2:
        raise ParameterError("estimate_disparity needs at least two views; this light field has one")
    positions = lf.flat_positions().astype(np.float64)
    qmax = float(np.abs(positions).max())
    if qmax <= 0:
        raise ParameterError("every view sits at the same position: there is no parallax to measure")
    fill = _validate.boolean("fill", fill)
    shape = lf.image_shape
    if radius is None:
        radius = max(2, min(shape) // 50)
    radius = _validate.integer_at_least("radius", radius, 1)
    low, high = _search_range(lf, disparity_range, qmax)
    # Beyond this the outermost views no longer overlap the centre's image: nothing to match.
    reach = max(shape) / qmax
    low, high = max(low, -reach), min(high, reach)
    if low > high:
        raise ParameterError(f"disparity_range {disparity_range!r} lies beyond +-{reach:.3g} px per view step, "
                             "where the outermost views no longer overlap the image")
    seconds = {}
    clock = time.perf_counter()

    lum, valid = _luminance_views(lf)
    guide = _guide(lf)
    step = STEP_PX / qmax
    slopes = _slope_grid(low, high, step)
    level = _coarse_level(shape)
    seconds["inputs"] = time.perf_counter() - clock
    yield (1, 5, "inputs")

    clock = time.perf_counter()
    if level > 0:
        small, small_valid = _reduce_views(lum, valid, level)
        c_step = step * 2 ** level
        c_slopes = _slope_grid(low, high, c_step)
        c_shape = small.shape[1:]
        # the border rule only here (it sets each tile's slopes): at full resolution its complete groups cost
        # HCI antinous's edges and its penalty moved an in-focus plane's outermost pixels (OUTSIDE_PENALTY)
        cost = _sweep(_features(small), small_valid, positions, c_slopes / 2 ** level,
                      _all_tiles(len(c_slopes), c_shape, TILE), c_shape, TILE, border_rule=True)
        c_guide, _ = _reduce_views(np.moveaxis(guide, -1, 0).copy(), None, level)
        aggregated = _GuidedFilter(np.moveaxis(c_guide, 0, -1), max(1, radius // 2 ** level))(_relative_cost(cost))
        coarse, c_confidence, c_alternative = _winner(aggregated, c_slopes, c_step)
        margin = 1.5 * c_step
        # ambiguous coarse pixels (flat or periodic cost) say nothing about the range
        sure = c_confidence >= COARSE_SURE
        if sure.mean() < 0.01:
            sure = np.ones(coarse.shape, bool)
        # a periodic texture's second fit stays in the sweep: the fine level must see both to say so
        second = np.where(sure & np.isfinite(c_alternative), c_alternative, np.nan)
        low_c, high_c = np.percentile(np.concatenate([coarse[sure], second[np.isfinite(second)]]), [0.5, 99.5])
        inside = (slopes >= low_c - margin) & (slopes <= high_c + margin)
        near = np.zeros((len(slopes),) + _tile_grid(shape, TILE), bool)
        near[inside] = _tile_slopes(np.stack([np.where(sure, coarse, np.nan), second]), level, shape,
                                    slopes[inside], margin=margin, tile=TILE)
        # a texture the coarse level cannot see: the sure pixels around it say little of its depth
        ref = _reference_views(positions)[0]
        lost = _lost_tiles(_lost_texture(lum[ref], small[ref], level) & ~sure, level, shape, TILE)
        needed = near.copy()
        needed[:, lost] = True
        swept = np.flatnonzero(inside | needed.any(axis=(1, 2)))  # a grid without gaps (sub-step, slants)
        span = slice(swept[0], swept[-1] + 1)
        slopes, needed, near = slopes[span], needed[span], near[span]
    else:
        needed = _all_tiles(len(slopes), shape, TILE)
        lost = None
    seconds["coarse"] = time.perf_counter() - clock
    yield (2, 5, "coarse sweep")

    clock = time.perf_counter()
    cost = _sweep(_features(lum), valid, positions, slopes, needed, shape, TILE)
    seconds["sweep"] = time.perf_counter() - clock
    yield (3, 5, "sweep")
    clock = time.perf_counter()
    relative = _relative_cost(cost)
    guided = _GuidedFilter(guide, radius)
    aggregated = _aggregate(relative, needed, guided, radius)
    if lost is not None and lost.any():
        _clearly_beyond(aggregated, near, lost, TILE, slopes, positions)
    disparity, confidence, alternative = _winner(aggregated, slopes, step, cost)
    first = _filled(disparity, confidence, guide) if len(slopes) >= 3 else None
    shears = _shears(first) if first is not None else {}
    for slant, blocks in shears.items():
        first_index = (first - slopes[0]) / step
        for y0, y1, x0, x1 in _slanted_aggregate(relative, needed, guided, radius, step, slant, blocks, first_index,
                                                 aggregated):
            # the winner again there (one pixel more around: the sub-step reads a 3x3 window of the cost)
            ys, xs = slice(max(y0 - 1, 0), y1 + 1), slice(max(x0 - 1, 0), x1 + 1)
            box_disparity, box_confidence, box_alternative = _winner(aggregated[:, ys, xs], slopes, step,
                                                                     cost[:, ys, xs])
            inner = (slice(y0 - ys.start, y1 - ys.start), slice(x0 - xs.start, x1 - xs.start))
            disparity[y0:y1, x0:x1] = box_disparity[inner]
            confidence[y0:y1, x0:x1] = box_confidence[inner]
            alternative[y0:y1, x0:x1] = box_alternative[inner]
    seconds["aggregate"] = time.perf_counter() - clock
    yield (4, 5, "aggregation")

    clock = time.perf_counter()
    if fill:  # nothing changed since the first estimate was filled unless a slant was aggregated
        disparity = first if first is not None and not shears else _filled(disparity, confidence, guide)
        disparity = _blend_edges(disparity, confidence)
    seconds["fill"] = time.perf_counter() - clock
    yield (5, 5, "fill")
    params = {"radius": radius, "step": step, "coarse_level": level, "n_slopes": len(slopes),
              "evaluated_share": float(needed.mean()),
              "slanted_share": float(np.mean(np.logical_or.reduce(list(shears.values())))) if shears else 0.0,
              "seconds": seconds}
    return DisparityEstimate(disparity, np.clip(confidence, 0, 1).astype(np.float32), (low, high), params,
                             alternative)




class FocusTest:
    """Which pixels a slope brings into focus, from the views themselves (for the dense-aperture renderer).

    At slope ``s`` a pixel is in focus where enough of the views agree with
    the centre of the aperture (the mean of the central views; on an even
    grid also one of them alone, :meth:`at_any`): at least
    :data:`IN_FOCUS_SHARE` of the other views differ from it by at most
    :data:`IN_FOCUS_COST` of the local
    texture energy (luminance and gradient features, as the estimator
    matches), on a patch textured enough to tell (:data:`TEXTURE_MIN`). The views a defocused occluder covers disagree, the others
    still agree, so a surface partly hidden by an occluder's blur counts as
    in focus too. The test overrides an estimate that says otherwise (a
    periodic texture's wrong period, weak texture, an edge the estimate
    fattened), so the renderer never blurs a surface the views show in focus.

    Parameters
    ----------
    lf : LightField
        The light field (its luminance features are made once and kept).
    luminance : LightField, optional
        ``lf.luminance()``, where already made.

    The test is conservative: a view resampled between pixels differs from
    the centre by its interpolation error, so on a textured plane in focus
    at a fractional disparity about half the pixels pass, and almost none
    out of focus (a missed pixel keeps the estimate's disparity).

    Examples
    --------
    >>> from napari_lfalias.synthetic import textured_plane
    >>> test = FocusTest(textured_plane(n_views=5, size=64, disparity=1.25).lightfield)
    >>> bool(test(1.25).mean() > 0.3), bool(test(-1.0).mean() < 0.01)
    (True, True)
    """

    def __init__(self, lf, luminance=None):
        self.positions = lf.flat_positions().astype(np.float64)
        lum, self.valid = _luminance_views(lf, luminance)
        self.features = _features(lum)
        energy = np.mean([_texture_energy(self.features[view]) for view in _reference_views(self.positions)], axis=0)
        self.tolerance = IN_FOCUS_COST * np.maximum(energy, TEXTURE_FLOOR)
        self.textured = energy >= TEXTURE_MIN  # a flat patch looks the same in or out of focus

    def __call__(self, slope):
        """``(Y, X)`` bool: in focus at ``slope`` (never on flat patches: they say nothing)."""
        return self.at_any([slope])

    def at_any(self, slopes, where=None):
        """``(Y, X)`` bool: in focus at one of ``slopes`` at least, on ``where`` only (default: everywhere;
        the tiles of :data:`TILE` without a pixel of it are not tested).

        On an even grid the central views lie half a view step off the
        centre of the aperture: beside a defocused occluder some of them see
        its edge where the centre sees the surface behind, up to the two's
        disparity step times that offset away (3.5 px for a step of 7), and
        their mean matches no view there. So each central view alone is a
        reference too, where a surface passes so (at least half of a window
        of :data:`ALONE_WINDOW` px in focus either way): a single pixel that
        matches one view alone is chance (fresh scene 319 at 3.6, lines 8.1 px
        per view step out of focus, 12 pixels: 0.6 dB lost). Not where some
        views sample beyond the image: the views left are those on one side,
        near the one reference, and agree with it out of focus too.
        """
        slopes = np.asarray(slopes, np.float64).reshape(-1)
        where = self.textured if where is None else where & self.textured
        if not where.any():
            return np.zeros(where.shape, bool)  # not self.textured itself: callers add to what comes back
        central = _reference_views(self.positions)
        n, n_ref = len(self.positions), len(central)
        # the mean of the central views, then (on an even grid) each of them alone
        references = np.zeros((1 + (n_ref if n_ref > 1 else 0), n), np.float32)
        references[0, central] = 1.0
        if n_ref > 1:
            references[np.arange(1, n_ref + 1), central] = 1.0
        needed = _all_tiles(slopes.size, where.shape, TILE) & tiles_holding(where, TILE)
        blocks, first, order = _tile_plan(needed, where.shape, TILE)
        share = np.zeros((slopes.size, len(references)) + where.shape, np.float32)
        valid = self.valid if self.valid is not None else np.ones((1, 1, 1), np.float32)
        _run("agreeing_shares", self.features, valid, self.valid is not None, self.positions, slopes, references,
             blocks, first, order, self.tolerance, share)
        # each reference's views agree with themselves: count the others only
        counted = references.sum(axis=1)[None, :, None, None]
        agree = (share * n - counted) / np.maximum(n - counted, 1) >= IN_FOCUS_SHARE
        found = agree[:, 0].any(axis=0) & where
        if n_ref > 1:
            from scipy import ndimage

            alone = agree[:, 1:].any(axis=(0, 1)) & where & self._seen_by_all(slopes) & ~found
            if alone.any():
                around = ndimage.uniform_filter((found | alone).astype(np.float32), ALONE_WINDOW)
                found |= alone & (around >= 0.5)
        return found

    def _seen_by_all(self, slopes):
        """``(Y, X)`` bool: the pixels every view samples within its image at each of ``slopes``."""
        shape = self.features.shape[2:]
        reach = np.ceil(np.abs(slopes).max(initial=0.0) * np.abs(self.positions).max(axis=0)).astype(int) + 1
        inside = np.zeros(shape, bool)
        inside[reach[0]:max(shape[0] - reach[0], 0), reach[1]:max(shape[1] - reach[1], 0)] = True
        return inside


def _texture_energy(features):
    """The local variance ``(Y, X)`` of one view's feature planes ``(K, Y, X)`` over the focus test's window.

    Each reference view's own: the views nearest the centre of an even
    grid see a surface shifted against each other by its disparity, and
    their mean cancels its texture (a checkerboard at 3.9 px per view step,
    6x6 views: under a tenth of it textured enough to be tested, so a wall
    the views show in focus was rendered out of focus; fresh scene 1510).
    """
    return _box(np.square(features - _box(features, FOCUS_RADIUS)), FOCUS_RADIUS).sum(axis=0)


def disparity_scores(disparity, truth, border=15):
    """The HCI 4D light-field benchmark's scores of a disparity map against the truth.

    Parameters
    ----------
    disparity, truth : array_like, shape (Y, X)
        Estimated and true disparity (same convention and units).
    border : int
        Pixels ignored along every edge (the benchmark ignores 15).

    Returns
    -------
    dict
        ``"badpix_0.07"`` and ``"badpix_0.03"`` (percent of pixels whose
        error exceeds 0.07 / 0.03) and ``"mse_x100"`` (mean squared error
        times 100).

    Examples
    --------
    >>> import numpy as np
    >>> truth = np.zeros((40, 40))
    >>> scores = disparity_scores(truth + 0.05, truth)
    >>> scores["badpix_0.07"], scores["badpix_0.03"], round(scores["mse_x100"], 3)
    (0.0, 100.0, 0.25)
    """
    disparity = np.asarray(disparity, np.float64)
    truth = np.asarray(truth, np.float64)
    if disparity.ndim != 2 or disparity.shape != truth.shape:
        raise ParameterError(f"disparity and truth must be (Y, X) maps of one shape, got {disparity.shape} "
                             f"and {truth.shape}")
    border = _validate.integer_at_least("border", border, 0)
    inner = (slice(border, disparity.shape[0] - border), slice(border, disparity.shape[1] - border))
    error = disparity[inner] - truth[inner]
    ok = np.isfinite(error)
    if not ok.any():
        raise ParameterError("no pixel left to score (border too wide, or no finite values)")
    error = error[ok]
    return {"badpix_0.07": float(np.mean(np.abs(error) > 0.07) * 100),
            "badpix_0.03": float(np.mean(np.abs(error) > 0.03) * 100),
            "mse_x100": float(np.mean(error ** 2) * 100)}
