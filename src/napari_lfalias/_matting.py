"""The soft outline of an in-focus occluder over a defocused background, matted from the views.

An occluder's outline is not a step: the optics (and a synthetic scene's
band limit) spread it over a few pixels, and there every view records a mix
of the occluder and the background. In focus, the occluder's share is the
same in every view; the background's point differs from view to view. The
renderer counts each pixel to one surface: counted to the background, the
occluder's share is blurred away with it; counted to the occluder (the one
pixel :func:`~napari_lfalias.render._with_mixed_edges` gives it), the
background's share keeps its aliasing. Measured on the brick room (5x5
views, 64 px, slope 4, the cube in focus, the true disparity), the pixels
within 5 px of the cube held most of the rendering's error on clean pixels:
41.9 dB there against the naive refocus's 45.7 (``tests/test_render.py``).

For a pixel ``p`` of the background within :data:`BAND_PX` of a nearer
surface in focus, with the background's residual disparity ``r``:

1. What each view ``u`` would show there without the occluder is the
   background's point that view ``j`` shows at ``p + r (q_j - q_u)``; it
   is taken from the view nearest ``u`` that shows that point clean (the background's bin, all four
   bilinear taps farther than :data:`BAND_PX` from the occluder).
2. Across the views, the recorded samples are regressed on those points,
   ``S_u = a + b W_u`` (``b``: the background's share, one for all
   channels; ``a``: the occluder's contribution).
3. The dense aperture sees the occluder's contribution ``a`` and the
   background's share of its whole blur: ``a + b box(p)``, ``box(p)`` the
   background over every view's cell (the renderer's box, whole-pixel taps),
   each point taken clean as in 1.

Where fewer than :data:`MIN_VIEWS` views find their point, the points vary
too little to tell the shares apart (:data:`MIN_SPREAD`), or explain too
little of the samples (:data:`MIN_FIT`), or too few of the box's points are
found (:data:`MIN_BOX`), the rendering stays as it was. A wrong
disparity leaves the points unrelated to the samples: ``b`` goes to 0 and
the pixel to the mean of its samples, the naive refocus.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange
from scipy import ndimage

#: How far (px) from a surface in focus its outline mixes into the background's pixels.
BAND_PX = 6
#: Least share of the samples' variance across the views that the background points explain (R^2): a wrong
#: disparity leaves them unrelated.
MIN_FIT = 0.8
#: Least background share of an outline's mixed sample that stands in, its fit taken off, for the background.
MIN_UNMIXED = 0.5
#: Least share of the box's points found for a pixel to be matted (the others are hidden from every view, or
#: beyond the image's edge: the mean of those found would be another box's).
MIN_BOX = 0.5
#: An occluder in focus is at least this many px wide (narrower in-focus specks have no outline to matte).
SURFACE_PX = 5
#: Fewest views whose background point is found for a pixel to be matted.
MIN_VIEWS = 3
#: Least variance of the background points across the views (luminance-like, summed over the channels) for
#: the shares to be told apart: below it the background is flat there and its aliasing nil.
MIN_SPREAD = 1e-5


@njit(cache=True)
def _clean_sample(values, weights, bins, mixed, share, offset, usable, k, y, x, out):
    """The least weight of the bilinear taps at grid ``(y, x)`` where they all show bin ``k`` (in the view's
    ``bins``, or as the background of an outline's ``mixed`` pixel) with weight and a large enough background
    ``share`` (``usable``, of :func:`_usable_taps`), and the background's colour there (each tap less its
    ``offset``, over its share) into ``out``; -1 where they do not."""
    n_rows, n_cols = share.shape
    y0, x0 = int(np.floor(y)), int(np.floor(x))
    if y0 < 0 or x0 < 0 or y0 + 1 >= n_rows or x0 + 1 >= n_cols or not usable[y0, x0]:
        return -1.0
    weight = np.inf
    for yy in range(y0, y0 + 2):
        for xx in range(x0, x0 + 2):
            if not ((bins[yy, xx] == k or mixed[yy, xx] == k) and weights[yy, xx] > 0.0):
                return -1.0
            weight = min(weight, weights[yy, xx])
    fy, fx = y - y0, x - x0
    for c in range(out.shape[0]):
        out[c] = ((1.0 - fy) * ((1.0 - fx) * (values[y0, x0, c] - offset[y0, x0, c]) / share[y0, x0]
                                + fx * (values[y0, x0 + 1, c] - offset[y0, x0 + 1, c]) / share[y0, x0 + 1])
                  + fy * ((1.0 - fx) * (values[y0 + 1, x0, c] - offset[y0 + 1, x0, c]) / share[y0 + 1, x0]
                          + fx * (values[y0 + 1, x0 + 1, c] - offset[y0 + 1, x0 + 1, c]) / share[y0 + 1, x0 + 1]))
    return weight


@njit(cache=True)
def _background_point(values, weights, bins, mixed, share, offset, usable, k, r, positions, order, apart, qy, qx, y,
                      x, out, to_usable):
    """The background's point the ray from aperture position ``(qy, qx)`` through grid pixel ``(y, x)`` meets
    (residual ``r``), from the first view of ``order`` that shows it (:func:`_clean_sample`): its weight there,
    -1 where none does. ``order``: the views nearest ``(qy, qx)`` first, ``apart`` their distances from it;
    ``usable``, ``to_usable``: of :func:`_usable_taps`; a view whose offset moves the point less than
    ``to_usable`` (less the taps' reach) cannot show it, and the search starts past them."""
    need = to_usable[int(y), int(x)] - 2.0
    first, last = 0, order.shape[0]
    if need > 0.0:  # the first view far enough, by bisection: ``apart`` ascends
        while first < last:
            middle = (first + last) // 2
            if abs(r) * apart[middle] < need:
                first = middle + 1
            else:
                last = middle
    for i in range(first, order.shape[0]):  # view j shows at p + r (q_j - q) what the view at q shows at p
        j = order[i]
        sy = y + r * (positions[j, 0] - qy)
        sx = x + r * (positions[j, 1] - qx)
        weight = _clean_sample(values[j], weights[j], bins[j], mixed, share, offset, usable, k, sy, sx, out)
        if weight > 0.0:
            return weight
    return -1.0


@njit(cache=True, parallel=True)
def fit_band(values, weights, bins, mixed, clean, zero, band_y, band_x, band_bin, band_r, positions, nearest, apart,
             min_views, min_spread, min_fit, usable, to_clean, out_offset, out_share, fitted):
    """Each band pixel's samples regressed on the clean background points its views would show there
    (module notes, 1 and 2): ``out_offset (P, C)`` (``a``), ``out_share (P,)`` (``b``), ``fitted (P,)``."""
    n = values.shape[0]
    n_ch = values.shape[3]
    for p in prange(band_y.shape[0]):
        y, x, k, r = band_y[p], band_x[p], band_bin[p], band_r[p]
        point = np.empty(n_ch)
        s_sum = np.zeros(n_ch)
        w_sum = np.zeros(n_ch)
        sw = np.zeros(n_ch)
        ww = np.zeros(n_ch)
        ss = np.zeros(n_ch)
        count = 0
        total = 0.0
        fitted[p] = False
        for u in range(n):
            if not weights[u, y, x] > 0.0:
                continue
            found = _background_point(values, weights, bins, mixed, clean, zero, usable, k, r, positions, nearest[u],
                                      apart[u], positions[u, 0], positions[u, 1], y, x, point, to_clean)
            if found <= 0.0:
                continue
            weight = min(weights[u, y, x], found)  # the noisier of the two samples (a vignette's corners)
            count += 1
            total += weight
            for c in range(n_ch):
                sample = values[u, y, x, c]
                s_sum[c] += weight * sample
                w_sum[c] += weight * point[c]
                sw[c] += weight * sample * point[c]
                ww[c] += weight * point[c] * point[c]
                ss[c] += weight * sample * sample
        if count < min_views:
            continue
        covariance = 0.0
        variance = 0.0
        recorded = 0.0
        for c in range(n_ch):
            covariance += sw[c] / total - s_sum[c] * w_sum[c] / (total * total)
            variance += ww[c] / total - w_sum[c] * w_sum[c] / (total * total)
            recorded += ss[c] / total - s_sum[c] * s_sum[c] / (total * total)
        if variance < min_spread or recorded <= 0.0 or covariance * covariance < min_fit * variance * recorded:
            continue
        b = min(max(covariance / variance, 0.0), 1.0)
        for c in range(n_ch):
            out_offset[p, c] = s_sum[c] / total - b * w_sum[c] / total
        out_share[p] = b
        fitted[p] = True


@njit(cache=True, parallel=True)
def fill_zone(values, weights, bins, mixed, share, offset, usable, k, r, zone_y, zone_x, positions, nearest, apart,
              to_usable, out, ok):
    """For every view ``u`` and zone pixel (grid ``zone_y``, ``zone_x``): the background (bin ``k``, residual
    ``r``) that the view's sample there stands for in a box, ``out (n, Z, C)``: its own where it shows it
    (:func:`_clean_sample`), else the nearest view's that does; ``ok (n, Z)`` where one does. Made once for
    every outline pixel whose box reads it."""
    n = values.shape[0]
    n_ch = values.shape[3]
    for u in prange(n):  # view by view: its own samples, most of what is found, are read in order
        point = np.empty(n_ch)
        for z in range(zone_y.shape[0]):
            ok[u, z] = _background_point(values, weights, bins, mixed, share, offset, usable, k, r, positions,
                                         nearest[u], apart[u], positions[u, 0], positions[u, 1], zone_y[z], zone_x[z],
                                         point, to_usable) > 0.0
            if ok[u, z]:
                for c in range(n_ch):
                    out[u, z, c] = point[c]


@njit(cache=True, parallel=True)
def box_band(weights, zone_index, filled, ok, band_y, band_x, band_r, cell, min_box, band_offset, band_share, fitted,
             out, done):
    """Each fitted outline pixel's colour in the dense aperture, ``a + b box`` (module notes, 3): ``out (P, C)``,
    ``done (P,)``. The box is the renderer's (whole-pixel taps of each view's own samples, end taps of weight
    ``f``), each tap counting by its own sample's validity (beyond the view's image, not at all, as in the
    dense aperture) and taking the background :func:`fill_zone` found for it."""
    n = weights.shape[0]
    n_ch = filled.shape[2]
    for p in prange(band_y.shape[0]):
        done[p] = False
        if not fitted[p]:
            continue
        y, x = band_y[p], band_x[p]
        width = abs(band_r[p]) * cell
        n_taps = int((width - 1.0) // 2.0) if width >= 1.0 else 0
        f = (width - (2 * n_taps + 1)) / 2.0 if width >= 1.0 else 0.0
        box = np.zeros(n_ch)
        found = 0.0
        total = 0.0
        for u in range(n):
            for ty in range(-n_taps - 1, n_taps + 2):
                wy = f if (ty == -n_taps - 1 or ty == n_taps + 1) else 1.0
                if wy <= 0.0:
                    continue
                for tx in range(-n_taps - 1, n_taps + 2):
                    wx = f if (tx == -n_taps - 1 or tx == n_taps + 1) else 1.0
                    if wx <= 0.0:
                        continue
                    gy, gx = y + ty, x + tx
                    z = zone_index[gy, gx]
                    if z < 0 or not weights[u, gy, gx] > 0.0:
                        continue
                    tap = wy * wx * weights[u, gy, gx]
                    total += tap
                    if ok[u, z]:
                        found += tap
                        for c in range(n_ch):
                            box[c] += tap * filled[u, z, c]
        if found < min_box * total:
            continue
        for c in range(n_ch):
            out[p, c] = band_offset[p, c] + band_share[p] * box[c] / found
        done[p] = True


def _usable_taps(share, least):
    """Where a bilinear sample's four taps (rows and columns ``y, y + 1`` and ``x, x + 1``) all have a background
    ``share`` of at least ``least``, ``(Y, X)`` bool at ``(y, x)``, and each pixel's distance (px) to the nearest
    pixel with that share, ``(Y, X)`` float64."""
    enough = share >= least
    usable = np.zeros(share.shape, bool)
    usable[:-1, :-1] = enough[:-1, :-1] & enough[1:, :-1] & enough[:-1, 1:] & enough[1:, 1:]
    return usable, ndimage.distance_transform_edt(~enough)


def matted(image, layers, slope, spacing, where=None):
    """``image`` (the composite of ``layers``, ``(Y, X, C)``) with the soft outlines of in-focus occluders
    matted (module notes), ``where`` (``(Y, X)`` bool; ``None``: everywhere): a new array, or ``image`` itself
    where there is nothing to matte. A pixel's box un-mixes the outline samples it reads with their own
    fits, so with ``where`` every outline pixel within reach of it is fitted too: the pixels matted are
    the same as the whole image's there."""
    from .render import _bin_index, sharp_at

    disparity = layers.given  # the outlines where they are, not given to the sharper side
    # surfaces in focus, not the specks the views' focus test puts in focus where they happen to agree
    sharp = ndimage.binary_opening(sharp_at(disparity, slope, spacing), np.ones((SURFACE_PX, SURFACE_PX), bool))
    if not sharp.any() or sharp.all():
        return image
    pad = (layers.view_bins.shape[1] - disparity.shape[0]) // 2
    distance = ndimage.distance_transform_edt(~sharp)
    residual = disparity - slope
    behind = (residual < 0) if layers.larger_first else (residual > 0)  # the sharp surface (at the slope) is nearer
    band = (distance <= BAND_PX) & ~sharp & behind & (np.abs(residual) * spacing >= 1.0)
    wanted = band if where is None else band & where
    if not wanted.any():
        return image
    stack = layers.stack
    positions = np.ascontiguousarray(stack.positions, np.float64)
    apart = np.hypot(*(positions[:, None, :] - positions[None, :, :]).transpose(2, 0, 1))
    if where is not None:  # the fits a box of ``where`` reads: its taps', and those of the views' points they stand for
        widest = float(np.abs(residual[band]).max()) + float(np.diff(layers.bins[1]).max(initial=0.0))
        read_from = math.sqrt(2.0) * (widest * spacing / 2.0 + 1.0) + widest * float(apart.max()) + 3.0
        band &= ndimage.distance_transform_edt(~where) <= read_from
    clean = np.pad((distance > BAND_PX).astype(np.float64), pad)
    ys, xs = np.nonzero(band)
    wanted = wanted[ys, xs]
    nearest = np.ascontiguousarray(np.argsort(apart, axis=1, kind="stable"))  # each view first, then the nearest
    apart = np.ascontiguousarray(np.take_along_axis(apart, nearest, axis=1))  # ascending along each row
    n_ch = image.shape[-1]
    zero = np.zeros(clean.shape + (n_ch,))
    grid_y, grid_x = (ys + pad).astype(np.int64), (xs + pad).astype(np.int64)
    bins = _bin_index(layers.bins[0], disparity[ys, xs]).astype(np.int64)
    residual = residual[ys, xs].astype(np.float64)
    offset = np.zeros((len(ys), n_ch))
    share = np.zeros(len(ys))
    fitted = np.zeros(len(ys), bool)
    mixed = np.full(clean.shape, -1, np.int64)  # none yet: the first pass takes clean samples only
    fit_band(stack.values, stack.weights, layers.view_bins, mixed, clean, zero, grid_y, grid_x, bins, residual,
             positions, nearest, apart, MIN_VIEWS, MIN_SPREAD, MIN_FIT, *_usable_taps(clean, 1.0), offset, share,
             fitted)
    if not fitted.any():
        return image
    # the outline's samples, their fits taken off, stand in for the background they mix
    shares, offsets = clean.copy(), zero
    shares[grid_y[fitted], grid_x[fitted]] = share[fitted]
    offsets[grid_y[fitted], grid_x[fitted]] = offset[fitted]
    mixed[grid_y[fitted], grid_x[fitted]] = bins[fitted]  # in focus, their mix is the same in every view
    out = np.empty((len(ys), n_ch))
    done = np.zeros(len(ys), bool)
    centres = layers.bins[1]
    usable, to_usable = _usable_taps(shares, MIN_UNMIXED)
    for k in np.unique(bins[fitted & wanted]):  # each background bin's zone: its outline pixels' boxes
        mine = fitted & wanted & (bins == k)
        reach = int(math.ceil(np.abs(residual[mine]).max() * spacing / 2.0)) + 1  # the widest box's
        zone = np.zeros(clean.shape, bool)
        zone[grid_y[mine], grid_x[mine]] = True
        zone = ndimage.maximum_filter(zone, size=2 * reach + 1, mode="constant")
        zone_y, zone_x = np.nonzero(zone)
        zone_index = np.full(zone.shape, -1, np.int64)
        zone_index[zone_y, zone_x] = np.arange(len(zone_y))
        filled = np.empty((len(positions), len(zone_y), n_ch))
        ok = np.empty((len(positions), len(zone_y)), bool)
        fill_zone(stack.values, stack.weights, layers.view_bins, mixed, shares, offsets, usable, int(k),
                  float(centres[k] - slope), zone_y.astype(np.int64), zone_x.astype(np.int64), positions, nearest,
                  apart, to_usable, filled, ok)
        made = np.zeros(len(ys), bool)
        box_band(stack.weights, zone_index, filled, ok, grid_y, grid_x, residual, float(spacing), MIN_BOX, offset,
                 share, mine, out, made)
        done |= made
    if not done.any():
        return image
    image = image.copy()
    image[ys[done], xs[done]] = out[done]
    return image
