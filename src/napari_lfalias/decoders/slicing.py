"""Microlens-to-pinhole slicing: a devignetted lenslet image to ``(U, V, Y, X, C)`` views.

Every microlens is a pixel of every view and every pixel under a
microlens is a view. View ``(u, v)`` samples, under each microlens, the
point at offset ``q = (u - c_u, v - c_v) * step`` pixels from the lens
centre along the grid's axes (``e_y``, ``e_x``; ``c`` the central view), so
the views are straightened (rotation removed) in the same single
interpolation. The sensor is sampled bilinearly, each tap weighted by the
white image's validity, so a sample near a lens rim or the sensor's edge
never blends in unlit pixels.

On a hexagonal grid the output pixels are squares of side ``row_step``;
a pixel between two lenses of its row is a Catmull-Rom cubic of the four
nearest lenses of that row (each sampled at the same view offset), which
removes the half-pitch shift of every other row; where a tap is invalid it
falls back to the two nearest lenses, linearly.

The work is one numba kernel, parallel over output rows: each view row
reads a few sensor rows that sit in the cache, and writes contiguous output.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .._kernels import bilinear_point

__all__ = ["view_offsets", "output_taps", "slice_views"]


def view_offsets(grid, n_views, step=1.0):
    """Sensor offsets ``(n, n, 2)`` (model (y, x) pixels) of every view's sample from its lens centre.

    Parameters
    ----------
    grid : GridModel
    n_views : int
        Views per side; view ``u`` sits at ``(u - (n - 1) / 2) * step`` along ``e_y``.
    step : float
        Pixels between neighbouring views.

    Returns
    -------
    offsets : ndarray, shape (n, n, 2)
    radius : ndarray, shape (n, n)
        Distance of each view's sample from the lens centre, in pixels.
    """
    e_y, e_x = grid.axes
    q = (np.arange(n_views, dtype=np.float64) - (n_views - 1) / 2.0) * step
    offsets = q[:, None, None] * e_y + q[None, :, None] * e_x
    radius = np.hypot(q[:, None], q[None, :])
    return offsets, radius


def _catmull_rom(t):
    """Weights of the taps at -1, 0, 1, 2 for a fraction ``t`` in [0, 1) (arrays)."""
    t2, t3 = t * t, t * t * t
    return np.stack([
        0.5 * (-t3 + 2 * t2 - t),
        0.5 * (3 * t3 - 5 * t2 + 2),
        0.5 * (-3 * t3 + 4 * t2 + t),
        0.5 * (t3 - t2),
    ], axis=-1)


def output_taps(grid):
    """Lens centres and weights feeding every output pixel.

    Returns
    -------
    centres : ndarray, shape (Y, X, K, 2)
        Model (y, x) centres of the lenses combined into each output pixel
        (``K = 1`` on a rectangular grid, 4 on a hexagonal one).
    weights : ndarray, shape (Y, X, K)
        Their interpolation weights.
    """
    n_rows, n_out = grid.output_shape()
    e_y, e_x = grid.axes
    offset = np.asarray(grid.offset)
    if not grid.is_hexagonal:
        return grid.lens_grid()[:, :, None, :], np.ones((n_rows, n_out, 1))
    shifts = grid.row_shifts()[:, None]
    xi = np.arange(n_out)[None, :] * grid.row_step / grid.pitch - 0.5 * shifts  # lens units along the row
    base = np.floor(xi)
    weights = np.broadcast_to(_catmull_rom(xi - base), (n_rows, n_out, 4))
    cols = base[..., None] + np.arange(-1, 3)  # (Y, X, 4)
    rows = np.arange(n_rows, dtype=np.float64)[:, None, None]
    along = (cols + 0.5 * shifts[..., None]) * grid.pitch
    centres = offset + (rows * grid.row_step)[..., None] * e_y + along[..., None] * e_x
    return centres + grid.displacement(centres), np.ascontiguousarray(weights)


@njit(cache=True, parallel=True)
def _slice_kernel(image, valid, centres, tap_weights, offsets, view_on, out, out_weight):
    n_u, n_v, n_y, n_x, n_ch = out.shape
    n_taps = tap_weights.shape[2]
    for y in prange(n_y):
        sums = np.zeros(n_ch)
        values = np.zeros((n_taps, n_ch))
        valids = np.zeros(n_taps)
        for u in range(n_u):
            for v in range(n_v):
                if not view_on[u, v]:
                    for x in range(n_x):
                        out_weight[u, v, y, x] = 0.0
                        for c in range(n_ch):
                            out[u, v, y, x, c] = 0.0
                    continue
                oy = offsets[u, v, 0]
                ox = offsets[u, v, 1]
                for x in range(n_x):
                    for k in range(n_taps):
                        total = bilinear_point(image, valid, True, centres[y, x, k, 0] + oy, centres[y, x, k, 1] + ox, sums)
                        valids[k] = total
                        for c in range(n_ch):
                            values[k, c] = sums[c] / total if total > 0.0 else 0.0
                    if n_taps == 1:
                        weight = valids[0]
                        for c in range(n_ch):
                            out[u, v, y, x, c] = values[0, c]
                    else:
                        weight = _combine_row_taps(values, valids, tap_weights[y, x], out[u, v, y, x])
                    out_weight[u, v, y, x] = min(weight, 1.0)


@njit(cache=True, inline="always")
def _combine_row_taps(values, valids, weights, dest):
    """Cubic across the four lenses of a row; linear on the two middle ones where a tap is invalid."""
    n_ch = values.shape[1]
    all_valid = True
    for k in range(4):
        if valids[k] <= 0.0:
            all_valid = False
    if all_valid:
        norm = 0.0
        weight = 0.0
        for k in range(4):
            norm += abs(weights[k])
            weight += abs(weights[k]) * valids[k]
        for c in range(n_ch):
            acc = 0.0
            for k in range(4):
                acc += weights[k] * values[k, c]
            dest[c] = acc
        return weight / norm
    # linear between taps 1 and 2 (fraction from the cubic weights' centre of mass)
    t = weights[2] + weights[3] * 2.0 - weights[0]  # equals the fraction for Catmull-Rom weights
    w1 = (1.0 - t) * valids[1]
    w2 = t * valids[2]
    if w1 + w2 <= 0.0:
        for c in range(n_ch):
            dest[c] = 0.0
        return 0.0
    for c in range(n_ch):
        dest[c] = (w1 * values[1, c] + w2 * values[2, c]) / (w1 + w2)
    return w1 + w2


def slice_views(image, valid, grid, n_views, view_on, step=1.0):
    """Slice a devignetted sensor image into views.

    Parameters
    ----------
    image : ndarray, shape (H, W, C), float32
        Devignetted sensor image in model coordinates (transposed already
        for a transposed grid).
    valid : ndarray, shape (H, W), float32
        Validity of each sensor pixel in [0, 1] (0: unlit or unusable).
    grid : GridModel
    n_views : int
        Views per side.
    view_on : ndarray, shape (n_views, n_views), bool
        Views to fill; the others get zero data and weight.
    step : float
        Pixels between neighbouring views under a lens.

    Returns
    -------
    data : ndarray, shape (n_views, n_views, Y, X, C), float32
    weights : ndarray, shape (n_views, n_views, Y, X), float32
    """
    centres, tap_weights = output_taps(grid)
    offsets, _ = view_offsets(grid, n_views, step)
    n_y, n_x = centres.shape[:2]
    n_ch = image.shape[2]
    out = np.empty((n_views, n_views, n_y, n_x, n_ch), np.float32)
    out_weight = np.empty((n_views, n_views, n_y, n_x), np.float32)
    _slice_kernel(
        np.ascontiguousarray(image, np.float32), np.ascontiguousarray(valid, np.float32),
        np.ascontiguousarray(centres, np.float64), np.ascontiguousarray(tap_weights, np.float64),
        np.ascontiguousarray(offsets, np.float64), np.ascontiguousarray(view_on, np.bool_), out, out_weight,
    )
    return out, out_weight
