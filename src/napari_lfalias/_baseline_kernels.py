"""Numba kernels of the baselines (:mod:`napari_lfalias.baselines`).

- a separable box filter with fractional widths (running sums, zero
  outside the image), for one image or every view in parallel;
- the depth-aware renderer's pieces: the spread of the views at each
  pixel's own disparity (which side of a depth edge is in front), the
  centre view's layer map forward-warped into every view (nearest layer
  wins, disocclusions filled from the farther side), and the colour of
  one disparity layer gathered from the views that see it.

Views are ``(n, Y, X, C)`` float32; bilinear samples outside a view carry
no weight, as in :mod:`napari_lfalias._kernels`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from ._kernels import bilinear_point

__all__ = ["box_image", "box_views", "view_spread", "warp_layers", "layer_colour"]


# -- box filter -----------------------------------------------------------------------

@njit(cache=True, inline="always")
def _box_pass_x(src, out, n, f):
    """Sum of the box ``(n, f)`` along axis 1 of ``src (Y, X, K)``, zero outside.

    The box has ``2n + 1`` full taps and an end tap of weight ``f`` on each
    side; each row goes through prefix sums (float64).
    """
    n_rows, n_cols, n_k = src.shape
    prefix = np.zeros((n_cols + 1, n_k))
    for y in range(n_rows):
        for x in range(n_cols):
            for k in range(n_k):
                prefix[x + 1, k] = prefix[x, k] + src[y, x, k]
        for x in range(n_cols):
            low = max(x - n, 0)
            high = min(x + n + 1, n_cols)
            for k in range(n_k):
                out[y, x, k] = prefix[high, k] - prefix[low, k]
            if f > 0.0:
                if x - n - 1 >= 0:
                    for k in range(n_k):
                        out[y, x, k] += f * src[y, x - n - 1, k]
                if x + n + 1 < n_cols:
                    for k in range(n_k):
                        out[y, x, k] += f * src[y, x + n + 1, k]


@njit(cache=True, inline="always")
def _box_pass_y(src, out, n, f):
    """Sum of the box ``(n, f)`` along axis 0 of ``src (Y, M)``, zero outside."""
    n_rows, n_m = src.shape
    window = np.zeros(n_m)
    for y in range(min(n, n_rows - 1) + 1):
        for m in range(n_m):
            window[m] += src[y, m]
    for y in range(n_rows):
        low, high = y - n - 1, y + n + 1
        for m in range(n_m):
            edge = 0.0
            if low >= 0:
                edge += src[low, m]
            if high < n_rows:
                edge += src[high, m]
            out[y, m] = window[m] + f * edge
        if high < n_rows:
            for m in range(n_m):
                window[m] += src[high, m]
        if y - n >= 0:
            for m in range(n_m):
                window[m] -= src[y - n, m]


@njit(cache=True)
def box_image(src, ny, fy, nx, fx, out):
    """Separable box sum of one image ``src (Y, X, K)`` (contiguous float32) into ``out``."""
    tmp = np.empty(src.shape, np.float32)
    _box_pass_x(src, tmp, nx, fx)
    _box_pass_y(tmp.reshape(src.shape[0], src.shape[1] * src.shape[2]),
                out.reshape(src.shape[0], src.shape[1] * src.shape[2]), ny, fy)


@njit(cache=True, parallel=True)
def box_views(views, ny, fy, nx, fx, out):
    """:func:`box_image` of every view of ``views (n, Y, X, K)``, in parallel over the views."""
    for i in prange(views.shape[0]):
        box_image(views[i], ny, fy, nx, fx, out[i])


# -- depth-aware rendering ------------------------------------------------------------------

@njit(cache=True, parallel=True)
def view_spread(views, positions, disparity, pixels, out):
    """Variance across the views (summed over channels) of each listed pixel, sampled at its own disparity.

    ``pixels (m, 2)`` int64 ``(y, x)``; view ``i`` is sampled at
    ``p + disparity[p] * positions[i]``; ``out (m,)``.
    """
    n, n_ch = views.shape[0], views.shape[3]
    for k in prange(pixels.shape[0]):
        y, x = pixels[k, 0], pixels[k, 1]
        d = disparity[y, x]
        value = np.zeros(n_ch)
        mean = np.zeros(n_ch)
        m2 = np.zeros(n_ch)
        wsum = 0.0
        for i in range(n):
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


@njit(cache=True, parallel=True)
def warp_layers(rank, layer_disparity, positions, out):
    """The centre view's layer ranks ``rank (Y, X)`` (0 = nearest) forward-warped into every view.

    A pixel of layer rank ``r`` (disparity ``layer_disparity[r]``) lands
    in view ``i`` at ``round(p + d * positions[i])``; the nearest layer
    wins. Pixels no layer lands on (disocclusions) take the farther of the
    layers at the two ends of their run along the row (one end at the
    image's edge: that end). ``out (n, Y, X)`` int32.
    """
    n_rows, n_cols = rank.shape
    n_layers = layer_disparity.shape[0]
    hole = np.iinfo(np.int32).max
    for i in prange(out.shape[0]):
        target = out[i]
        target[:] = hole
        shift_y = np.empty(n_layers, np.int64)
        shift_x = np.empty(n_layers, np.int64)
        for r in range(n_layers):  # p is integral: round(p + s) = p + round(s)
            shift_y[r] = int(math.floor(layer_disparity[r] * positions[i, 0] + 0.5))
            shift_x[r] = int(math.floor(layer_disparity[r] * positions[i, 1] + 0.5))
        for y in range(n_rows):
            for x in range(n_cols):
                r = rank[y, x]
                ty = y + shift_y[r]
                tx = x + shift_x[r]
                if 0 <= ty < n_rows and 0 <= tx < n_cols and r < target[ty, tx]:
                    target[ty, tx] = r
        for y in range(n_rows):
            x = 0
            while x < n_cols:
                if target[y, x] != hole:
                    x += 1
                    continue
                start = x
                while x < n_cols and target[y, x] == hole:
                    x += 1
                left = target[y, start - 1] if start > 0 else -1
                right = target[y, x] if x < n_cols else -1
                fill = max(left, right)
                if fill < 0:
                    fill = n_layers - 1
                for k in range(start, x):
                    target[y, k] = fill


@njit(cache=True, parallel=True)
def layer_colour(views, has_weight, positions, warped, r, d, y0, x0, needed, colour, count):
    """Colour of the layer of rank ``r`` (disparity ``d``) on a window of the centre view.

    For the window's pixel ``(y0 + a, x0 + b)`` every view whose warped
    layer map shows rank ``r`` at ``round(p + d * q_i)`` contributes its
    bilinear sample at ``p + d * q_i``: ``colour (A, B, C)`` is their
    validity-weighted mean and ``count (A, B)`` their number (0: no view
    sees the layer there); pixels not ``needed (A, B)`` are skipped. With
    ``has_weight`` the views' last channel is the sample weight and the
    others are premultiplied by it. Each window row reads one row pair of
    each view in turn (cache friendly).
    """
    n, n_rows, n_cols, n_k = views.shape
    n_ch = colour.shape[2]
    width = colour.shape[1]
    for a in prange(colour.shape[0]):
        value = np.zeros(n_k)
        total = np.zeros((width, n_ch))
        wsum = np.zeros(width)
        seen = np.zeros(width, np.int32)
        y = y0 + a
        for i in range(n):
            sy = y + d * positions[i, 0]
            ty = int(math.floor(sy + 0.5))
            if ty < 0 or ty >= n_rows:
                continue
            shift_x = d * positions[i, 1]
            for b in range(width):
                if not needed[a, b]:
                    continue
                sx = x0 + b + shift_x
                tx = int(math.floor(sx + 0.5))
                if tx < 0 or tx >= n_cols or warped[i, ty, tx] != r:
                    continue
                w = bilinear_point(views[i], views[i, :, :, 0], False, sy, sx, value)
                if has_weight:
                    w = value[n_k - 1]
                if w <= 0.0:
                    continue
                seen[b] += 1
                wsum[b] += w
                for c in range(n_ch):
                    total[b, c] += value[c]
        for b in range(width):
            count[a, b] = seen[b]
            for c in range(n_ch):
                colour[a, b, c] = total[b, c] / wsum[b] if wsum[b] > 0.0 else 0.0
