"""Numba kernels of the baselines (:mod:`napari_lfalias.baselines`).

- a separable box filter with fractional widths (running sums, zero
  outside the image), for one image or every view in parallel;
- means over a window of its own size around every pixel (a summed-area
  table);
- the spread of the views at each pixel's own disparity (which side of a
  depth edge is in front).

Views are ``(n, Y, X, C)`` float32; bilinear samples outside a view carry
no weight, as in :mod:`napari_lfalias._kernels`.
"""

from __future__ import annotations


import numpy as np
from numba import njit, prange

from ._kernels import bilinear_point

__all__ = ["box_image", "box_image_into", "window_means", "box_views", "view_spread"]


# -- box filter -----------------------------------------------------------------------

@njit(cache=True, inline="always")
def _box_pass_x(src, out, n, f):
    """Sum of the box ``(n, f)`` along axis 1 of ``src (Y, X, K)`` (C-contiguous), zero outside.

    The box has ``2n + 1`` full taps and an end tap of weight ``f`` on each
    side; each row goes through prefix sums (float64). The columns whose
    box and end taps lie inside the row are summed in one flat loop over
    views that start where each tap reads (indices that cannot be negative:
    the loop vectorises), the others column by column; each sum is rounded
    to float32 where the one end tap, then the other, is added, as one
    column at a time would.
    """
    n_rows, n_cols, n_k = src.shape
    size = n_cols * n_k
    prefix = np.zeros((n_cols + 1, n_k))
    flat_prefix = prefix.reshape((n_cols + 1) * n_k)
    tap = (n + 1) * n_k  # from a column to its end taps
    lo = min(n + 1, n_cols)  # the columns [lo, hi) have both end taps inside the row
    hi = max(lo, n_cols - n - 1)
    a, b = lo * n_k, hi * n_k
    inner = b - a
    box_high = flat_prefix[a + tap:b + tap]
    box_low = flat_prefix[a - n * n_k:b - n * n_k] if inner > 0 else flat_prefix[:0]
    for y in range(n_rows):
        row = src[y]
        summed = out[y]
        for x in range(n_cols):
            for k in range(n_k):
                prefix[x + 1, k] = prefix[x, k] + row[x, k]
        if inner > 0:
            flat_row = row.reshape(size)
            middle = summed.reshape(size)[a:b]
            if f > 0.0:
                left, right = flat_row[a - tap:b - tap], flat_row[a + tap:b + tap]
                for j in range(inner):
                    value = np.float32(box_high[j] - box_low[j])
                    value = np.float32(value + f * left[j])
                    middle[j] = np.float32(value + f * right[j])
            else:
                for j in range(inner):
                    middle[j] = np.float32(box_high[j] - box_low[j])
        for x in range(n_cols):
            if lo <= x < hi:
                continue
            low = max(x - n, 0)
            high = min(x + n + 1, n_cols)
            for k in range(n_k):
                value = np.float32(prefix[high, k] - prefix[low, k])
                if f > 0.0 and x - n - 1 >= 0:
                    value = np.float32(value + f * row[x - n - 1, k])
                if f > 0.0 and x + n + 1 < n_cols:
                    value = np.float32(value + f * row[x + n + 1, k])
                summed[x, k] = value


@njit(cache=True, inline="always")
def _box_pass_y(src, out, n, f):
    """Sum of the box ``(n, f)`` along axis 0 of ``src (Y, M)``, zero outside."""
    n_rows, n_m = src.shape
    window = np.zeros(n_m)
    for y in range(min(n, n_rows - 1) + 1):
        for m in range(n_m):
            window[m] += src[y, m]
    # rows outside the image read as zeros; one branch-free loop per row (the same sums in the same order)
    zeros = np.zeros(n_m, src.dtype)
    for y in range(n_rows):
        low, high = y - n - 1, y + n + 1
        below = src[low] if low >= 0 else zeros
        above = src[high] if high < n_rows else zeros  # an end tap, and the row that enters the window
        leaving = src[y - n] if y - n >= 0 else zeros
        for m in range(n_m):
            out[y, m] = window[m] + f * (0.0 + below[m] + above[m])
            window[m] = (window[m] + above[m]) - leaving[m]


@njit(cache=True)
def box_image(src, ny, fy, nx, fx, out):
    """Separable box sum of one image ``src (Y, X, K)`` (contiguous float32) into ``out``."""
    box_image_into(src, ny, fy, nx, fx, out, np.empty(src.shape, np.float32))


@njit(cache=True)
def box_image_into(src, ny, fy, nx, fx, out, tmp):
    """:func:`box_image` with the scratch ``tmp`` (contiguous, the shape of ``src``) given."""
    _box_pass_x(src, tmp, nx, fx)
    _box_pass_y(tmp.reshape(src.shape[0], src.shape[1] * src.shape[2]),
                out.reshape(src.shape[0], src.shape[1] * src.shape[2]), ny, fy)


@njit(cache=True)
def window_means(values, y0, y1, x0, x1, out):
    """The mean of ``values (Y, X, K)`` over each pixel's window ``[y0, y1) x [x0, x1)`` (each ``(Y, X)``
    int64) into ``out (Y, X, K)`` float64, from a float64 summed-area table made in the order
    ``np.cumsum`` makes it (down the columns, then along the rows)."""
    n_rows, n_cols, n_k = values.shape
    table = np.zeros((n_rows + 1, n_cols + 1, n_k))
    column = np.zeros((n_cols, n_k))  # the columns' running sums down to the current row
    for y in range(n_rows):
        for x in range(n_cols):
            for k in range(n_k):
                column[x, k] += values[y, x, k]
                table[y + 1, x + 1, k] = table[y + 1, x, k] + column[x, k]
    for y in range(n_rows):
        for x in range(n_cols):
            a, b, c, d = y0[y, x], y1[y, x], x0[y, x], x1[y, x]
            area = float((b - a) * (d - c))
            for k in range(n_k):
                out[y, x, k] = (table[b, d, k] - table[a, d, k] - table[b, c, k] + table[a, c, k]) / area


@njit(cache=True, parallel=True)
def box_views(views, ny, fy, nx, fx, out):
    """:func:`box_image` of every view of ``views (n, Y, X, K)``, in parallel over the views."""
    for i in prange(views.shape[0]):
        box_image(views[i], ny, fy, nx, fx, out[i])


# -- depth-aware rendering ------------------------------------------------------------------

@njit(cache=True, parallel=True)
def view_spread(views, positions, disparity, pixels, front, out):
    """Variance across the views (summed over channels) of each listed pixel, sampled at its own disparity.

    ``pixels (m, 2)`` int64 ``(y, x)``; view ``i`` is sampled at
    ``p + disparity[p] * positions[i]``; ``out (m,)``. A view's sample is
    left out where a surface at ``front[p]`` hides it: where the disparity
    at ``p + (disparity[p] - front[p]) * positions[i]`` (the point of that
    surface the view sees there, rounded) lies nearer ``front[p]`` than
    ``disparity[p]``. ``front`` = ``disparity`` leaves every sample in.
    """
    n, n_rows, n_cols, n_ch = views.shape
    for k in prange(pixels.shape[0]):
        y, x = pixels[k, 0], pixels[k, 1]
        d = disparity[y, x]
        step = d - front[y, x]
        value = np.zeros(n_ch)
        mean = np.zeros(n_ch)
        m2 = np.zeros(n_ch)
        wsum = 0.0
        for i in range(n):
            if step != 0.0:
                cy = int(np.rint(y + step * positions[i, 0]))
                cx = int(np.rint(x + step * positions[i, 1]))
                if 0 <= cy < n_rows and 0 <= cx < n_cols and abs(disparity[cy, cx] - front[y, x]) < 0.5 * abs(step):
                    continue
            w = bilinear_point(views[i], views[i, :, :, 0], False, y + d * positions[i, 0], x + d * positions[i, 1], value)
            if w <= 0.0:
                continue
            wsum += w
            share = w / wsum
            for c in range(n_ch):
                delta = value[c] / w - mean[c]
                mean[c] += share * delta
                m2[c] += w * delta * (delta - share * delta)
        out[k] = m2.sum() / wsum if wsum > 0.0 else 0.0

