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
too little to tell the shares apart (:data:`MIN_SPREAD`), or under half of
the box's points are found, the rendering stays as it was. A wrong
disparity leaves the points unrelated to the samples: ``b`` goes to 0 and
the pixel to the mean of its samples, the naive refocus.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange
from scipy import ndimage

#: How far (px) from a surface in focus its outline mixes into the background's pixels.
BAND_PX = 6
#: Fewest views whose background point is found for a pixel to be matted.
MIN_VIEWS = 3
#: Least variance of the background points across the views (luminance-like, summed over the channels) for
#: the shares to be told apart: below it the background is flat there and its aliasing nil.
MIN_SPREAD = 1e-5


@njit(cache=True)
def _clean_sample(values, weights, bins, clean, k, y, x, out):
    """Whether the bilinear taps at grid ``(y, x)`` all show bin ``k`` clean with weight; if so the value
    into ``out``."""
    n_rows, n_cols = clean.shape
    y0, x0 = int(np.floor(y)), int(np.floor(x))
    if y0 < 0 or x0 < 0 or y0 + 1 >= n_rows or x0 + 1 >= n_cols:
        return False
    for yy in range(y0, y0 + 2):
        for xx in range(x0, x0 + 2):
            if not (clean[yy, xx] and bins[yy, xx] == k and weights[yy, xx] > 0.0):
                return False
    fy, fx = y - y0, x - x0
    for c in range(out.shape[0]):
        out[c] = ((1.0 - fy) * ((1.0 - fx) * values[y0, x0, c] + fx * values[y0, x0 + 1, c])
                  + fy * ((1.0 - fx) * values[y0 + 1, x0, c] + fx * values[y0 + 1, x0 + 1, c]))
    return True


@njit(cache=True)
def _background_point(values, weights, bins, clean, k, r, positions, order, qy, qx, y, x, out):
    """The background's point the ray from aperture position ``(qy, qx)`` through grid pixel ``(y, x)`` meets
    (residual ``r``), from the first view of ``order`` that shows it clean; whether one does."""
    for j in order:  # view j shows at p + r (q_j - q) what the view at q shows at p
        sy = y + r * (positions[j, 0] - qy)
        sx = x + r * (positions[j, 1] - qx)
        if _clean_sample(values[j], weights[j], bins[j], clean, k, sy, sx, out):
            return True
    return False


@njit(cache=True, parallel=True)
def matte_band(values, weights, bins, clean, band_y, band_x, band_bin, band_r, positions, nearest, cell,
               min_views, min_spread, out, done):
    """Matte each band pixel (grid ``band_y``, ``band_x``; its background's bin and residual): ``out (P, C)``
    the matted colour, ``done (P,)`` where one was made (module notes)."""
    n = values.shape[0]
    n_ch = values.shape[3]
    for p in prange(band_y.shape[0]):
        y, x, k, r = band_y[p], band_x[p], band_bin[p], band_r[p]
        point = np.empty(n_ch)
        s_sum = np.zeros(n_ch)
        w_sum = np.zeros(n_ch)
        sw = np.zeros(n_ch)
        ww = np.zeros(n_ch)
        count = 0
        for u in range(n):
            if not weights[u, y, x] > 0.0:
                continue
            if not _background_point(values, weights, bins, clean, k, r, positions, nearest[u],
                                     positions[u, 0], positions[u, 1], y, x, point):
                continue
            count += 1
            for c in range(n_ch):
                s = values[u, y, x, c]
                s_sum[c] += s
                w_sum[c] += point[c]
                sw[c] += s * point[c]
                ww[c] += point[c] * point[c]
        done[p] = False
        if count < min_views:
            continue
        covariance = 0.0
        variance = 0.0
        for c in range(n_ch):
            covariance += sw[c] / count - s_sum[c] * w_sum[c] / (count * count)
            variance += ww[c] / count - w_sum[c] * w_sum[c] / (count * count)
        if variance < min_spread:
            continue
        share = min(max(covariance / variance, 0.0), 1.0)
        # the box over the view's cell, as the renderer's: whole-pixel taps in the view's own grid and end taps
        # of weight f, each point taken clean from the view nearest that shows it
        width = abs(r) * cell
        n_taps = int((width - 1.0) // 2.0) if width >= 1.0 else 0
        f = (width - (2 * n_taps + 1)) / 2.0 if width >= 1.0 else 0.0
        box = np.zeros(n_ch)
        found = 0.0
        total = 0.0
        for u in range(n):
            base_y = r * positions[u, 0]
            base_x = r * positions[u, 1]
            for ty in range(-n_taps - 1, n_taps + 2):
                wy = f if (ty == -n_taps - 1 or ty == n_taps + 1) else 1.0
                if wy <= 0.0:
                    continue
                for tx in range(-n_taps - 1, n_taps + 2):
                    wx = f if (tx == -n_taps - 1 or tx == n_taps + 1) else 1.0
                    if wx <= 0.0:
                        continue
                    total += wy * wx
                    # the tap at p + t of view u's own samples stands for the view at q_u - t / r
                    if _background_point(values, weights, bins, clean, k, r, positions, nearest[u],
                                         positions[u, 0] - ty / r, positions[u, 1] - tx / r, y, x, point):
                        found += wy * wx
                        for c in range(n_ch):
                            box[c] += wy * wx * point[c]
        if 2 * found < total:
            continue
        for c in range(n_ch):
            out[p, c] = s_sum[c] / count - share * w_sum[c] / count + share * box[c] / found
        done[p] = True


def matted(image, layers, slope, spacing, larger_first, where=None):
    """``image`` (the composite of ``layers``, ``(Y, X, C)``) with the soft outlines of in-focus occluders
    matted (module notes); ``where``: only these pixels (``None``: all). A new array, or ``image`` itself
    where there is nothing to matte."""
    from .render import _bin_index, sharp_at

    disparity = layers.given  # the outlines where they are, not given to the sharper side
    sharp = sharp_at(disparity, slope, spacing)
    if not sharp.any() or sharp.all():
        return image
    pad = (layers.view_bins.shape[1] - disparity.shape[0]) // 2
    distance = ndimage.distance_transform_edt(~sharp)
    residual = disparity - slope
    behind = (residual < 0) if larger_first else (residual > 0)  # the sharp surface (at the slope) is nearer
    band = (distance <= BAND_PX) & ~sharp & behind & (np.abs(residual) * spacing >= 1.0)
    if where is not None:
        band &= where
    if not band.any():
        return image
    clean = np.pad(distance > BAND_PX, pad, constant_values=False)
    ys, xs = np.nonzero(band)
    edges = layers.bins[0]
    stack = layers.stack
    positions = np.ascontiguousarray(stack.positions, np.float64)
    apart = np.hypot(*(positions[:, None, :] - positions[None, :, :]).transpose(2, 0, 1))
    nearest = np.ascontiguousarray(np.argsort(apart, axis=1, kind="stable"))  # each view first, then the nearest
    out = np.empty((len(ys), image.shape[-1]), np.float64)
    done = np.empty(len(ys), bool)
    matte_band(stack.values, stack.weights, layers.view_bins, clean, (ys + pad).astype(np.int64),
               (xs + pad).astype(np.int64), _bin_index(edges, disparity[ys, xs]).astype(np.int64),
               residual[ys, xs].astype(np.float64), positions, nearest, float(spacing), MIN_VIEWS,
               MIN_SPREAD, out, done)
    if not done.any():
        return image
    image = image.copy()
    image[ys[done], xs[done]] = out[done]
    return image
