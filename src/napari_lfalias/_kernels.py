"""Fused numba kernels of the shift-and-add core (DESIGN section 4).

Each output row is computed for every view in turn while it sits in the
cache, so the light field is read once and the output written once: the
cost is close to one pass over the data (see
``benchmarks/results/refocus.md``). Rows are split over threads.

Every kernel samples view ``i`` at ``(y + dy_i, x + dx_i)`` with bilinear
taps; taps outside the view carry no weight. With per-sample weights ``w``
the taps sample ``w * v`` and ``w``; the sample value is their ratio.
Sums run in float64 row buffers and are stored as float32.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

__all__ = [
    "split_shifts", "refocus_sum", "shifted_stack", "moments", "moments_tiles", "stack_moments", "stack_mean",
    "pyr_down", "luminance_ranges", "pattern_moments", "bilinear_point", "in_focus_consensus", "points_cv", "rec709",
]

#: Bilinear taps lighter than this are dropped, so near-integer shifts stay exact.
TAP_EPS = 1e-7
#: Half the spacing of float32 numbers near 1: a spread across views smaller than
#: this fraction of the mean is rounding of the float64 sums, not in the float32 data.
ROUNDING = 2.0 ** -24


#: Largest shift (pixels) the kernels take; beyond any image, far below int64 overflow.
MAX_SHIFT = 2.0**40


def split_shifts(shifts):
    """Integer parts ``(n, 2)`` int64 and fractions ``(n, 2)`` float64 of ``(dy, dx)`` shifts.

    Fractions within ``TAP_EPS`` of 0 or 1 are snapped to whole pixels.
    Shifts are clipped to ``MAX_SHIFT`` pixels: a view shifted that far
    sees nothing of any image, as it would at any larger shift, and the
    integer parts stay far from overflow.
    """
    shifts = np.clip(np.asarray(shifts, np.float64), -MAX_SHIFT, MAX_SHIFT)
    base = np.floor(shifts)
    frac = shifts - base
    up = frac >= 1.0 - TAP_EPS
    base[up] += 1.0
    frac[up | (frac <= TAP_EPS)] = 0.0
    return base.astype(np.int64), frac


@njit(cache=True, inline="always")
def bilinear_point(image, valid, has_valid, py, px, sums):
    """Bilinear taps of ``image (Y, X, C)`` at ``(py, px)`` summed into ``sums (C,)``; returns their weight.

    Taps outside the image carry no weight; with ``has_valid``, each tap is
    also weighted by ``valid (Y, X)`` (0 = not observed).
    """
    n_rows, n_cols, n_ch = image.shape
    for c in range(n_ch):
        sums[c] = 0.0
    y0 = int(np.floor(py))
    x0 = int(np.floor(px))
    fy = py - y0
    fx = px - x0
    total = 0.0
    for dy in range(2):
        yy = y0 + dy
        if yy < 0 or yy >= n_rows:
            continue
        wy = fy if dy == 1 else 1.0 - fy
        for dx in range(2):
            xx = x0 + dx
            if xx < 0 or xx >= n_cols:
                continue
            w = wy * (fx if dx == 1 else 1.0 - fx)
            if has_valid:
                w *= valid[yy, xx]
            if w <= 0.0:
                continue
            total += w
            for c in range(n_ch):
                sums[c] += w * image[yy, xx, c]
    return total


@njit(cache=True, inline="always")
def _bilinear_inside(image, valid, has_valid, y0, x0, fy, fx):
    """:func:`bilinear_point`'s weight and tap sum of channel 0 where all four taps lie inside the image:
    the same arithmetic in the same order, without its bounds tests."""
    total = 0.0
    value = 0.0
    for dy in range(2):
        wy = fy if dy == 1 else 1.0 - fy
        for dx in range(2):
            w = wy * (fx if dx == 1 else 1.0 - fx)
            if has_valid:
                w *= valid[y0 + dy, x0 + dx]
            if w <= 0.0:
                continue
            total += w
            value += w * image[y0 + dy, x0 + dx, 0]
    return total, value


#: Samples of a view per block of :func:`points_cv` (its points times their disparities): each view is sampled
#: over a block's points in turn (points in raster order lie in a few rows of every view, which then stay in
#: the cache).
POINTS_BLOCK = 256


@njit(cache=True, parallel=True)
def points_cv(views, valid, has_valid, positions, ys, xs, disparities, floor, out):
    """Angular coefficient of variation (weighted std / mean) of one-channel ``views (n, Y, X, 1)`` at the
    points ``(ys, xs)`` ``(m,)``, each at its own disparities ``(m, k)``: view ``i`` sampled at
    ``p + d positions[i]`` with :func:`bilinear_point` (``valid (n, Y, X)`` weighting the taps with
    ``has_valid``), each sample weighted by its taps' weight, as :func:`moments` weights it. ``out (m, k)``:
    inf where no view sees the point. A point's ``k`` disparities are sampled together: near ones read
    the same rows of a view, which then come from the cache.
    """
    n = views.shape[0]
    m, n_tried = disparities.shape
    block_size = max(POINTS_BLOCK // n_tried, 1)  # points
    for block in prange((m + block_size - 1) // block_size):
        start = block * block_size
        stop = min(start + block_size, m)
        sums = np.empty(1)
        values = np.empty((stop - start, n_tried, n))
        weights = np.empty((stop - start, n_tried, n))
        for i in range(n):
            view, view_valid = views[i], valid[i if has_valid else 0]
            n_rows, n_cols = view.shape[0], view.shape[1]
            for k in range(start, stop):
                for j in range(n_tried):
                    py = ys[k] + disparities[k, j] * positions[i, 0]
                    px = xs[k] + disparities[k, j] * positions[i, 1]
                    y0, x0 = int(np.floor(py)), int(np.floor(px))
                    if 0 <= y0 < n_rows - 1 and 0 <= x0 < n_cols - 1:  # all four taps inside
                        w, value = _bilinear_inside(view, view_valid, has_valid, y0, x0, py - y0, px - x0)
                    else:
                        w = bilinear_point(view, view_valid, has_valid, py, px, sums)
                        value = sums[0]
                    weights[k - start, j, i] = w
                    values[k - start, j, i] = value / w if w > 0.0 else 0.0
        for k in range(start, stop):
            for j in range(n_tried):
                point_weights, point_values = weights[k - start, j], values[k - start, j]
                total = 0.0
                mean = 0.0
                for i in range(n):
                    total += point_weights[i]
                    mean += point_weights[i] * point_values[i]
                if total <= 0.0:
                    out[k, j] = np.inf
                    continue
                mean /= total
                spread = 0.0
                for i in range(n):
                    spread += point_weights[i] * (point_values[i] - mean) ** 2
                out[k, j] = np.sqrt(spread / total) / max(mean, floor)


@njit(cache=True, parallel=True)
def rec709(colour, weights, out):
    """``out (m,)`` = ``colour (m, 3) @ weights (3,)`` in float32, summed left to right (no fused
    multiply-add), in blocks of pixels over the cores."""
    m = colour.shape[0]
    block = 1 << 14
    for start in prange((m + block - 1) // block):
        for j in range(start * block, min(start * block + block, m)):
            out[j] = colour[j, 0] * weights[0] + colour[j, 1] * weights[1] + colour[j, 2] * weights[2]


@njit(cache=True, inline="always")
def _clamp(i, n):
    return min(max(i, 0), n - 1)


@njit(cache=True, inline="always")
def _sample_px(view, weight, has_weight, n_ch, x, r0, r1, wy0, wy1, bx, fx, num, den):
    """Tap sums of one output pixel, any taps possibly outside the view."""
    n_cols = view.shape[1] // n_ch
    x0 = x + bx
    wx0 = (1.0 - fx) if 0 <= x0 < n_cols else 0.0
    wx1 = fx if 0 <= x0 + 1 < n_cols else 0.0
    c0 = _clamp(x0, n_cols)
    c1 = _clamp(x0 + 1, n_cols)
    a = wy0 * wx0
    b = wy0 * wx1
    c = wy1 * wx0
    d = wy1 * wx1
    if has_weight:
        a *= weight[r0, c0]
        b *= weight[r0, c1]
        c *= weight[r1, c0]
        d *= weight[r1, c1]
    den[x] = a + b + c + d
    for ch in range(n_ch):
        k0 = c0 * n_ch + ch
        k1 = c1 * n_ch + ch
        num[x * n_ch + ch] = a * view[r0, k0] + b * view[r0, k1] + c * view[r1, k0] + d * view[r1, k1]


@njit(cache=True, inline="always")
def _sample_row(view, weight, has_weight, n_ch, y, by, fy, bx, fx, num, den, x_lo=0, x_hi=-1):
    """Tap sums of output row ``y`` of one view ``(Y, X*C)`` into ``num (X*C)`` and ``den (X)``.

    Only columns ``x_lo <= x < x_hi`` are written (``x_hi = -1``: to the end of the row).
    """
    n_rows, n_cols = view.shape[0], view.shape[1] // n_ch
    if x_hi < 0:
        x_hi = n_cols
    y0 = y + by
    wy0 = (1.0 - fy) if 0 <= y0 < n_rows else 0.0
    wy1 = fy if 0 <= y0 + 1 < n_rows else 0.0
    r0 = _clamp(y0, n_rows)
    r1 = _clamp(y0 + 1, n_rows)
    if has_weight:
        for x in range(x_lo, x_hi):
            _sample_px(view, weight, has_weight, n_ch, x, r0, r1, wy0, wy1, bx, fx, num, den)
        return
    # interior: both column taps inside, constant weights, one contiguous (vectorised) loop
    start = min(max(-bx, x_lo), x_hi)
    stop = max(min(n_cols - 1 - bx, x_hi), start)
    for x in range(x_lo, start):
        _sample_px(view, weight, has_weight, n_ch, x, r0, r1, wy0, wy1, bx, fx, num, den)
    for x in range(stop, x_hi):
        _sample_px(view, weight, has_weight, n_ch, x, r0, r1, wy0, wy1, bx, fx, num, den)
    a = wy0 * (1.0 - fx)
    b = wy0 * fx
    c = wy1 * (1.0 - fx)
    d = wy1 * fx
    # 1-D rows, shifted so that the loop reads ``row[k]``: lets LLVM vectorise it
    k0, k1 = start * n_ch, stop * n_ch
    row00 = view[r0, k0 + bx * n_ch:]
    row01 = view[r0, k0 + (bx + 1) * n_ch:]
    row10 = view[r1, k0 + bx * n_ch:]
    row11 = view[r1, k0 + (bx + 1) * n_ch:]
    out = num[k0:k1]
    for k in range(k1 - k0):
        out[k] = a * row00[k] + b * row01[k] + c * row10[k] + d * row11[k]
    total = a + b + c + d
    for x in range(start, stop):
        den[x] = total


@njit(cache=True, parallel=True)
def refocus_sum(views, n_ch, weights, has_weight, base, frac, view_weights, out_num, out_den):
    """``out_num (Y, X, C)`` = sum of the tap-weighted samples, ``out_den (Y, X)`` = summed tap weight.

    ``view_weights (n,)`` scales each view (1 for a plain refocus).
    """
    n, n_rows, n_cols = views.shape[0], views.shape[1], views.shape[2] // n_ch
    for y in prange(n_rows):
        num = np.empty(n_cols * n_ch)
        den = np.empty(n_cols)
        acc = np.zeros(n_cols * n_ch)
        acc_den = np.zeros(n_cols)
        for i in range(n):
            a = view_weights[i]
            if a == 0.0:
                continue
            _sample_row(views[i], weights[i if has_weight else 0], has_weight, n_ch, y,
                        base[i, 0], frac[i, 0], base[i, 1], frac[i, 1], num, den)
            for k in range(n_cols * n_ch):
                acc[k] += a * num[k]
            for x in range(n_cols):
                acc_den[x] += a * den[x]
        for x in range(n_cols):
            out_den[y, x] = acc_den[x]
            for ch in range(n_ch):
                out_num[y, x, ch] = acc[x * n_ch + ch]


@njit(cache=True, parallel=True)
def shifted_stack(views, n_ch, weights, has_weight, base, frac, out_values, out_weights):
    """Every view resampled: ``out_values (n, Y', X', C)`` normalised (0 where unseen), ``out_weights (n, Y', X')``.

    The output may be larger than the views by ``pad`` px on every side
    (``Y' = Y + 2 pad``): its pixel ``(y, x)`` is the image's ``(y - pad, x - pad)``.
    """
    n, n_rows, n_cols = out_weights.shape
    pad = (n_rows - views.shape[1]) // 2
    for y in prange(n_rows):
        num = np.empty(n_cols * n_ch)
        den = np.empty(n_cols)
        for i in range(n):
            _sample_row(views[i], weights[i if has_weight else 0], has_weight, n_ch, y,
                        base[i, 0] - pad, frac[i, 0], base[i, 1] - pad, frac[i, 1], num, den, 0, n_cols)
            for x in range(n_cols):
                w = den[x]
                out_weights[i, y, x] = w
                inv = 1.0 / w if w > 0.0 else 0.0
                for ch in range(n_ch):
                    out_values[i, y, x, ch] = num[x * n_ch + ch] * inv


@njit(cache=True, inline="always")
def _accumulate_row(values, weights, normalise, n_ch, shift, s1, s2, wsum, count, sample_w, fresh):
    """Fold one view's row into weighted sums of deviations from a per-pixel shift.

    ``values (X*C)`` are the samples, or their tap sums when ``normalise``
    (divided by ``weights (X)`` here). Each pixel's sums run about
    ``shift``, the first sample seen there, so the deviations stay within
    the spread of the data whatever its offset, and the float64 sums of
    their squares lose nothing the float32 samples hold (``E[x^2] - E[x]^2``
    of the raw values would). Branch-free, so the loop vectorises.
    ``sample_w`` (float64) and ``fresh`` (bool), ``(X*C)``, are scratch for colour rows.
    """
    if n_ch == 1:  # luminance, what detection runs on: one flat loop LLVM can vectorise
        for x in range(wsum.shape[0]):
            w = weights[x]
            v = values[x] / max(w, 1e-30) if normalise else values[x]  # tap sums are 0 where w is
            shift[x] = v if wsum[x] == 0.0 else shift[x]
            d = v - shift[x]
            s1[x] += w * d
            s2[x] += w * d * d
            wsum[x] += w
            count[x] += w > 0.0
        return
    # colour: a weight (and a "first sample" flag) per sample, so the main loop runs flat over X*C
    n_cols = wsum.shape[0]
    for x in range(n_cols):
        for ch in range(n_ch):
            sample_w[x * n_ch + ch] = weights[x]
            fresh[x * n_ch + ch] = wsum[x] == 0.0
    for k in range(n_cols * n_ch):
        w = sample_w[k]
        v = values[k] / max(w, 1e-30) if normalise else values[k]
        shift[k] = v if fresh[k] else shift[k]
        d = v - shift[k]
        s1[k] += w * d
        s2[k] += w * d * d
    for x in range(n_cols):
        w = weights[x]
        wsum[x] += w
        count[x] += w > 0.0


@njit(cache=True, inline="always")
def _store_moments(y, n_ch, shift, s1, s2, wsum, count, out_mean, out_var, out_wsum, out_count):
    for x in range(wsum.shape[0]):
        out_wsum[y, x] = wsum[x]
        out_count[y, x] = count[x]
        inv = 1.0 / wsum[x] if wsum[x] > 0.0 else 0.0
        for ch in range(n_ch):
            k = x * n_ch + ch
            offset = s1[k] * inv
            out_mean[y, x, ch] = shift[k] + offset
            out_var[y, x, ch] = max(s2[k] * inv - offset * offset, 0.0)


@njit(cache=True, parallel=True)
def moments(views, n_ch, weights, has_weight, base, frac, out_mean, out_var, out_wsum, out_count):
    """Weighted mean and population variance across the shifted views, in one pass.

    Each view's sample is its normalised bilinear value, weighted by its tap
    weight (the :class:`~napari_lfalias.refocus.ShiftedStack` weight).
    """
    n, n_rows, n_cols = views.shape[0], views.shape[1], views.shape[2] // n_ch
    for y in prange(n_rows):
        num = np.empty(n_cols * n_ch)
        den = np.empty(n_cols)
        shift = np.zeros(n_cols * n_ch)
        s1 = np.zeros(n_cols * n_ch)
        s2 = np.zeros(n_cols * n_ch)
        wsum = np.zeros(n_cols)
        count = np.zeros(n_cols, np.int32)
        sample_w = np.empty(n_cols * n_ch)
        fresh = np.empty(n_cols * n_ch, np.bool_)
        for i in range(n):
            _sample_row(views[i], weights[i if has_weight else 0], has_weight, n_ch, y,
                        base[i, 0], frac[i, 0], base[i, 1], frac[i, 1], num, den)
            _accumulate_row(num, den, True, n_ch, shift, s1, s2, wsum, count, sample_w, fresh)
        _store_moments(y, n_ch, shift, s1, s2, wsum, count, out_mean, out_var, out_wsum, out_count)


@njit(cache=True, parallel=True)
def moments_tiles(views, n_ch, weights, has_weight, base, frac, tiles, out_mean, out_var, out_wsum, out_count):
    """:func:`moments` of the tiles ``(K, 4)`` = ``(y0, y1, x0, x1)`` only; other pixels are not written."""
    n, n_cols = views.shape[0], views.shape[2] // n_ch
    for t in prange(tiles.shape[0]):
        y0, y1, x0, x1 = tiles[t, 0], tiles[t, 1], tiles[t, 2], tiles[t, 3]
        width = x1 - x0
        num = np.empty(n_cols * n_ch)
        den = np.empty(n_cols)
        shift = np.empty(width * n_ch)
        s1 = np.empty(width * n_ch)
        s2 = np.empty(width * n_ch)
        wsum = np.empty(width)
        count = np.empty(width, np.int32)
        sample_w = np.empty(width * n_ch)
        fresh = np.empty(width * n_ch, np.bool_)
        for y in range(y0, y1):
            s1[:] = 0.0
            s2[:] = 0.0
            wsum[:] = 0.0
            count[:] = 0
            for i in range(n):
                _sample_row(views[i], weights[i if has_weight else 0], has_weight, n_ch, y,
                            base[i, 0], frac[i, 0], base[i, 1], frac[i, 1], num, den, x0, x1)
                _accumulate_row(num[x0 * n_ch:x1 * n_ch], den[x0:x1], True, n_ch, shift, s1, s2, wsum, count,
                                sample_w, fresh)
            _store_moments(y, n_ch, shift, s1, s2, wsum, count, out_mean[:, x0:x1], out_var[:, x0:x1],
                           out_wsum[:, x0:x1], out_count[:, x0:x1])


@njit(cache=True, parallel=True)
def stack_moments(values, n_ch, weights, out_mean, out_var, out_wsum, out_count):
    """:func:`moments` of an already shifted stack: values ``(n, Y, X*C)``, weights ``(n, Y, X)``."""
    n, n_rows, n_cols = values.shape[0], values.shape[1], values.shape[2] // n_ch
    for y in prange(n_rows):
        shift = np.zeros(n_cols * n_ch)
        s1 = np.zeros(n_cols * n_ch)
        s2 = np.zeros(n_cols * n_ch)
        wsum = np.zeros(n_cols)
        count = np.zeros(n_cols, np.int32)
        sample_w = np.empty(n_cols * n_ch)
        fresh = np.empty(n_cols * n_ch, np.bool_)
        for i in range(n):
            _accumulate_row(values[i, y], weights[i, y], False, n_ch, shift, s1, s2, wsum, count, sample_w, fresh)
        _store_moments(y, n_ch, shift, s1, s2, wsum, count, out_mean, out_var, out_wsum, out_count)


@njit(cache=True, parallel=True)
def stack_mean(values, n_ch, weights, view_weights, out):
    """``out (Y, X, C)`` = ``sum_i a_i w_i x_i / sum_i a_i w_i`` over a stack ``(n, Y, X*C)`` (0 where unseen)."""
    n, n_rows, n_cols = values.shape[0], values.shape[1], values.shape[2] // n_ch
    for y in prange(n_rows):
        acc = np.zeros(n_cols * n_ch)
        acc_w = np.zeros(n_cols)
        for i in range(n):
            a = view_weights[i]
            if a == 0.0:
                continue
            row, w_row = values[i, y], weights[i, y]
            for x in range(n_cols):
                w = a * w_row[x]
                acc_w[x] += w
                for ch in range(n_ch):
                    acc[x * n_ch + ch] += w * row[x * n_ch + ch]
        for x in range(n_cols):
            inv = 1.0 / acc_w[x] if acc_w[x] > 0.0 else 0.0
            for ch in range(n_ch):
                out[y, x, ch] = acc[x * n_ch + ch] * inv


#: The 5-tap binomial kernel of the Burt-Adelson Gaussian pyramid.
BINOMIAL5 = np.array([1.0, 4.0, 6.0, 4.0, 1.0]) / 16.0


@njit(cache=True, inline="always")
def _binomial_taps(center, n):
    """The summed weight of the 5-tap kernel's taps that fall inside ``0 .. n - 1`` around ``center``."""
    k = BINOMIAL5
    total = 0.0
    for t in range(5):
        if 0 <= center + t - 2 < n:
            total += k[t]
    return total


@njit(cache=True, parallel=True)
def pyr_down(images, weights, has_weight, per_weight, out, out_weights):
    """Binomial blur and 2x decimation of ``images (m, Y, X)`` into ``out (m, ceil(Y/2), ceil(X/2))``.

    Taps outside the image, or of weight 0, carry no weight: each output is
    the normalised convolution ``sum k w x / sum k w``. ``weights (m / per_weight, Y, X)``
    are shared by ``per_weight`` consecutive images (the channels of one view);
    with weights, ``out_weights`` receives the valid fraction of the
    in-bounds kernel weight; without, it is not written. Rows and columns
    whose five taps all lie inside take a branch-free (vectorised) path.
    """
    m, n_rows, n_cols = images.shape
    out_rows, out_cols = out.shape[1], out.shape[2]
    k0, k1, k2 = BINOMIAL5[0], BINOMIAL5[1], BINOMIAL5[2]
    for job in prange(m * out_rows):
        i = job // out_rows
        yo = job % out_rows
        w_i = i // per_weight if has_weight else 0
        acc = np.zeros(n_cols)
        acc_w = np.zeros(n_cols)
        y_c = 2 * yo
        if not has_weight and 2 <= y_c < n_rows - 2:
            r0, r1, r2, r3, r4 = images[i, y_c - 2], images[i, y_c - 1], images[i, y_c], images[i, y_c + 1], images[i, y_c + 2]
            for x in range(n_cols):
                acc[x] = k0 * (r0[x] + r4[x]) + k1 * (r1[x] + r3[x]) + k2 * r2[x]
            acc_w[:] = 1.0
        else:
            for t in range(5):
                y = y_c + t - 2
                if y < 0 or y >= n_rows:
                    continue
                kt = BINOMIAL5[t]
                if has_weight:
                    for x in range(n_cols):
                        w = kt * weights[w_i, y, x]
                        acc[x] += w * images[i, y, x]
                        acc_w[x] += w
                else:
                    for x in range(n_cols):
                        acc[x] += kt * images[i, y, x]
                        acc_w[x] += kt
        k_rows = _binomial_taps(y_c, n_rows)
        row = out[i, yo]
        if not has_weight:
            # acc_w is constant along the row: one division for the whole row
            norm = 1.0 / acc_w[0]
            for xo in range(1, (n_cols - 3) // 2 + 1):
                x = 2 * xo
                row[xo] = (k0 * (acc[x - 2] + acc[x + 2]) + k1 * (acc[x - 1] + acc[x + 1]) + k2 * acc[x]) * norm
            for xo in range(out_cols):
                x = 2 * xo
                if 2 <= x < n_cols - 2:
                    continue
                total = 0.0
                k_cols = 0.0
                for t in range(5):
                    xx = x + t - 2
                    if 0 <= xx < n_cols:
                        total += BINOMIAL5[t] * acc[xx]
                        k_cols += BINOMIAL5[t]
                row[xo] = total * norm / k_cols
            continue
        for xo in range(out_cols):
            total = 0.0
            total_w = 0.0
            k_cols = 0.0
            for t in range(5):
                x = 2 * xo + t - 2
                if 0 <= x < n_cols:
                    total += BINOMIAL5[t] * acc[x]
                    total_w += BINOMIAL5[t] * acc_w[x]
                    k_cols += BINOMIAL5[t]
            row[xo] = total / total_w if total_w > 0.0 else 0.0
            if i % per_weight == 0:
                out_weights[w_i, yo, xo] = total_w / (k_rows * k_cols)


@njit(cache=True, parallel=True, fastmath=True)
def luminance_ranges(views, n_ch, coeffs, combine, weights, has_weight, tile, out_lum, out_min, out_max):
    """Luminance of ``views (n, Y, X*C)`` and the least and greatest value of each ``tile x tile`` block.

    With ``combine``, each sample's value is ``sum_c coeffs[c] x_c``, written to
    ``out_lum (n, Y, X)``; without, every channel is a value and ``out_lum``
    is not written. ``out_min`` and ``out_max`` are ``(n, tile rows, tile
    cols)``: per view (the caller reduces over views). Samples of weight 0
    are left out; a block with none keeps ``+inf`` and ``-inf``.
    """
    n, n_rows, n_cols = views.shape[0], views.shape[1], views.shape[2] // n_ch
    n_tile_rows, n_tile_cols = out_min.shape[1], out_min.shape[2]
    width = n_cols if combine else n_cols * n_ch
    per_tile = tile if combine else tile * n_ch
    c0 = coeffs[0]
    c1 = coeffs[1] if n_ch > 1 else 0.0
    c2 = coeffs[2] if n_ch > 2 else 0.0
    for job in prange(n * n_tile_rows):
        i = job // n_tile_rows
        ty = job % n_tile_rows
        low = np.full(n_tile_cols, np.inf, np.float32)
        high = np.full(n_tile_cols, -np.inf, np.float32)
        row = np.empty(width, np.float32)
        upper = np.empty(width, np.float32)
        for y in range(ty * tile, min((ty + 1) * tile, n_rows)):
            source = views[i, y]
            if combine:
                lum = out_lum[i, y]
                for x in range(n_cols):
                    lum[x] = c0 * source[3 * x] + c1 * source[3 * x + 1] + c2 * source[3 * x + 2]
                row[:] = lum
            else:
                row[:] = source
            upper[:] = row
            if has_weight:  # unseen samples widen no range
                for k in range(width):
                    if weights[i, y, k if combine else k // n_ch] <= 0.0:
                        row[k] = np.inf
                        upper[k] = -np.inf
            for b in range(n_tile_cols):
                start = b * per_tile
                stop = min(start + per_tile, width)
                lo, hi = low[b], high[b]
                for k in range(start, stop):
                    lo = min(lo, row[k])
                    hi = max(hi, upper[k])
                low[b], high[b] = lo, hi
        for b in range(n_tile_cols):
            out_min[i, ty, b] = low[b]
            out_max[i, ty, b] = high[b]


@njit(cache=True, inline="always")
def _less_dropped(total, per_view, drops, n_drops, out):
    """``out = total - sum of per_view[i]`` over the ``n_drops`` views ``drops[:n_drops]``."""
    out[:] = total
    for d in range(n_drops):
        row = per_view[drops[d]]
        for q in range(out.shape[0]):
            out[q] -= row[q]


@njit(cache=True, parallel=True)
def pattern_moments(values, weights, n_ch, drops, n_drops, pixels, acc_n, acc_mean, acc_m2, out_reference,
                    out_count):
    """Accumulate the refocused values of a block of sampling patterns (Algorithm 1, Eq. 7).

    ``values (n, P*C)`` are the shifted views (normalised), ``weights (n, P)``
    their validity; the pixels are ``pixels (M,)``. Pattern ``j`` keeps
    every view but ``drops[j, :n_drops[j]]``, so its weighted sums are the
    totals over all views less the few dropped ones. Each pattern's mean is
    taken as a deviation from the pixel's mean over all views (float64,
    ``out_reference (M, C)``), so an offset costs no precision; patterns
    that keep no view seeing the pixel are left out. The deviations are
    added to running counts, means and sums of squared differences
    (Welford: ``acc_n``, ``acc_mean``, ``acc_m2``, each ``(M, C)``), so the
    patterns can come in blocks and memory does not grow with their
    number. ``out_count (M,)`` receives the number of views that see each pixel.
    """
    n = weights.shape[0]
    n_patterns = drops.shape[0]
    count = pixels.shape[0]
    block = 128
    for b in prange((count + block - 1) // block):
        start = b * block
        m = min(start + block, count) - start
        w = np.empty((n, m))
        total_w = np.zeros(m)
        for i in range(n):
            for q in range(m):
                w[i, q] = weights[i, pixels[start + q]]
                total_w[q] += w[i, q]
        den = np.empty(m)
        x = np.empty((n, m))
        dev = np.empty((n, m))
        offset = np.empty(m)
        for ch in range(n_ch):
            total = np.zeros(m)
            for i in range(n):
                for q in range(m):
                    x[i, q] = values[i, pixels[start + q] * n_ch + ch]
                    total[q] += w[i, q] * x[i, q]
            reference = np.zeros(m)
            for q in range(m):
                if total_w[q] > 0.0:
                    reference[q] = total[q] / total_w[q]
                out_reference[start + q, ch] = reference[q]
            base = np.zeros(m)  # sum of w (x - reference) over all views: 0 up to rounding
            for i in range(n):
                for q in range(m):
                    dev[i, q] = w[i, q] * (x[i, q] - reference[q])
                    base[q] += dev[i, q]
            for j in range(n_patterns):
                _less_dropped(total_w, w, drops[j], n_drops[j], den)
                _less_dropped(base, dev, drops[j], n_drops[j], offset)
                for q in range(m):
                    if den[q] > 1e-6:
                        value = offset[q] / den[q]
                        k = start + q
                        acc_n[k, ch] += 1.0
                        delta = value - acc_mean[k, ch]
                        acc_mean[k, ch] += delta / acc_n[k, ch]
                        acc_m2[k, ch] += delta * (value - acc_mean[k, ch])
        for q in range(m):
            seen = 0
            for i in range(n):
                if w[i, q] > 0.0:
                    seen += 1
            out_count[start + q] = seen


@njit(cache=True, inline="always")
def _sort_by(keys, order, m):
    """Insertion sort of ``order[:m] = 0 .. m-1`` by ``keys``: no allocation, quick for the few dozen views."""
    for a in range(m):
        order[a] = a
    for a in range(1, m):
        item = order[a]
        key = keys[item]
        b = a - 1
        while b >= 0 and keys[order[b]] > key:
            order[b + 1] = order[b]
            b -= 1
        order[b + 1] = item


@njit(cache=True, parallel=True)
def in_focus_consensus(views, valid, has_valid, shifts, coeffs, ys, xs, rel_tol, floor, min_share,
                       out_share, out_colour):
    """The largest group of views that agree at each pixel ``(ys[k], xs[k])`` of the refocus.

    View ``i`` (``views (n, Y, X, C)``) is sampled at ``(y + shifts[i, 0],
    x + shifts[i, 1])``. The samples are sorted by luminance (``coeffs``)
    and the heaviest window of width ``max(rel_tol * its lowest value,
    floor)`` is the group. Where its share of the summed weight reaches
    ``min_share``, ``out_share`` receives that share and ``out_colour`` the
    group's mean colour; other pixels are left untouched.
    """
    n, _, _, n_ch = views.shape
    count = ys.shape[0]
    block = 256
    for b in prange((count + block - 1) // block):
        colour = np.empty((n, n_ch))
        lum = np.empty(n)
        weight = np.empty(n)
        order = np.empty(n, np.int64)
        sums = np.empty(n_ch)
        for k in range(b * block, min(count, (b + 1) * block)):
            y, x = ys[k], xs[k]
            seen = 0
            total = 0.0
            for i in range(n):
                w = bilinear_point(views[i], valid[i], has_valid, y + shifts[i, 0], x + shifts[i, 1], sums)
                if w <= TAP_EPS:
                    continue
                value = 0.0
                for c in range(n_ch):
                    colour[seen, c] = sums[c] / w
                    value += coeffs[c] * colour[seen, c]
                lum[seen] = value
                weight[seen] = w
                total += w
                seen += 1
            if seen == 0:
                continue
            _sort_by(lum, order, seen)
            best, first, last = 0.0, 0, 0
            end, window = 0, 0.0
            for start in range(seen):  # windows [lum[start], lum[start] + width], two pointers
                low = lum[order[start]]
                width = max(rel_tol * abs(low), floor)
                while end < seen and lum[order[end]] <= low + width:
                    window += weight[order[end]]
                    end += 1
                if window > best:
                    best, first, last = window, start, end
                window -= weight[order[start]]
            if best < min_share * total:
                continue
            out_share[y, x] = best / total
            for c in range(n_ch):
                acc = 0.0
                for t in range(first, last):
                    acc += weight[order[t]] * colour[order[t], c]
                out_colour[y, x, c] = acc / best
