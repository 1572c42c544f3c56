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

__all__ = ["split_shifts", "refocus_sum", "shifted_stack", "moments", "stack_moments", "stack_mean"]

#: Bilinear taps lighter than this are dropped, so near-integer shifts stay exact.
TAP_EPS = 1e-7


def split_shifts(shifts):
    """Integer parts ``(n, 2)`` int64 and fractions ``(n, 2)`` float64 of ``(dy, dx)`` shifts.

    Fractions within ``TAP_EPS`` of 0 or 1 are snapped to whole pixels.
    """
    shifts = np.asarray(shifts, np.float64)
    base = np.floor(shifts)
    frac = shifts - base
    up = frac >= 1.0 - TAP_EPS
    base[up] += 1.0
    frac[up | (frac <= TAP_EPS)] = 0.0
    return base.astype(np.int64), frac


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
def _sample_row(view, weight, has_weight, n_ch, y, by, fy, bx, fx, num, den):
    """Tap sums of output row ``y`` of one view ``(Y, X*C)`` into ``num (X*C)`` and ``den (X)``."""
    n_rows, n_cols = view.shape[0], view.shape[1] // n_ch
    y0 = y + by
    wy0 = (1.0 - fy) if 0 <= y0 < n_rows else 0.0
    wy1 = fy if 0 <= y0 + 1 < n_rows else 0.0
    r0 = _clamp(y0, n_rows)
    r1 = _clamp(y0 + 1, n_rows)
    if has_weight:
        for x in range(n_cols):
            _sample_px(view, weight, has_weight, n_ch, x, r0, r1, wy0, wy1, bx, fx, num, den)
        return
    # interior: both column taps inside, constant weights, one contiguous (vectorised) loop
    start = min(max(-bx, 0), n_cols)
    stop = max(min(n_cols - 1 - bx, n_cols), start)
    for x in range(start):
        _sample_px(view, weight, has_weight, n_ch, x, r0, r1, wy0, wy1, bx, fx, num, den)
    for x in range(stop, n_cols):
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
    """Every view resampled: ``out_values (n, Y, X, C)`` normalised (0 where unseen), ``out_weights (n, Y, X)``."""
    n, n_rows, n_cols = views.shape[0], views.shape[1], views.shape[2] // n_ch
    for y in prange(n_rows):
        num = np.empty(n_cols * n_ch)
        den = np.empty(n_cols)
        for i in range(n):
            _sample_row(views[i], weights[i if has_weight else 0], has_weight, n_ch, y,
                        base[i, 0], frac[i, 0], base[i, 1], frac[i, 1], num, den)
            for x in range(n_cols):
                w = den[x]
                out_weights[i, y, x] = w
                inv = 1.0 / w if w > 0.0 else 0.0
                for ch in range(n_ch):
                    out_values[i, y, x, ch] = num[x * n_ch + ch] * inv


@njit(cache=True, inline="always")
def _welford_row(values, weights, normalise, n_ch, mean, m2, wsum, count):
    """Fold one view's row into running weighted moments (weighted Welford update).

    ``values (X*C)`` are the samples, or their tap sums when ``normalise``
    (divided by ``weights (X)`` here); deviations are taken from the
    running mean, so a large offset costs no precision.
    """
    for x in range(wsum.shape[0]):
        w = weights[x]
        if w <= 0.0:
            continue
        total = wsum[x] + w
        share = w / total
        inv = 1.0 / w if normalise else 1.0
        for ch in range(n_ch):
            k = x * n_ch + ch
            delta = values[k] * inv - mean[k]
            mean[k] += share * delta
            m2[k] += w * delta * (delta - share * delta)
        wsum[x] = total
        count[x] += 1


@njit(cache=True, inline="always")
def _store_moments(y, n_ch, mean, m2, wsum, count, out_mean, out_var, out_wsum, out_count):
    for x in range(wsum.shape[0]):
        out_wsum[y, x] = wsum[x]
        out_count[y, x] = count[x]
        inv = 1.0 / wsum[x] if wsum[x] > 0.0 else 0.0
        for ch in range(n_ch):
            k = x * n_ch + ch
            out_mean[y, x, ch] = mean[k]
            out_var[y, x, ch] = max(m2[k] * inv, 0.0)


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
        mean = np.zeros(n_cols * n_ch)
        m2 = np.zeros(n_cols * n_ch)
        wsum = np.zeros(n_cols)
        count = np.zeros(n_cols, np.int32)
        for i in range(n):
            _sample_row(views[i], weights[i if has_weight else 0], has_weight, n_ch, y,
                        base[i, 0], frac[i, 0], base[i, 1], frac[i, 1], num, den)
            _welford_row(num, den, True, n_ch, mean, m2, wsum, count)
        _store_moments(y, n_ch, mean, m2, wsum, count, out_mean, out_var, out_wsum, out_count)


@njit(cache=True, parallel=True)
def stack_moments(values, n_ch, weights, out_mean, out_var, out_wsum, out_count):
    """:func:`moments` of an already shifted stack: values ``(n, Y, X*C)``, weights ``(n, Y, X)``."""
    n, n_rows, n_cols = values.shape[0], values.shape[1], values.shape[2] // n_ch
    for y in prange(n_rows):
        mean = np.zeros(n_cols * n_ch)
        m2 = np.zeros(n_cols * n_ch)
        wsum = np.zeros(n_cols)
        count = np.zeros(n_cols, np.int32)
        for i in range(n):
            _welford_row(values[i, y], weights[i, y], False, n_ch, mean, m2, wsum, count)
        _store_moments(y, n_ch, mean, m2, wsum, count, out_mean, out_var, out_wsum, out_count)


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
