"""Microlens-to-pinhole slicing: a devignetted lenslet image to ``(U, V, Y, X, C)`` views.

Every microlens is a pixel of every view and every pixel under a
microlens is a view. View ``(u, v)`` samples, under each microlens, the
point at offset ``q = (u - c_u, v - c_v) * step`` pixels from the lens
centre along the grid's axes (``e_y``, ``e_x``; ``c`` the central view), so
the views are straightened (rotation removed) in the same single
interpolation. The sensor is sampled bilinearly, each tap weighted by the
white image's validity, so a sample near a lens rim or the sensor's edge
never blends in unlit pixels.

Hexagonal grids: the half-pitch offset of alternate rows
---------------------------------------------------------
Output pixels are squares of side ``row_step`` (the distance between lens
rows): one output row per lens row, and ``pitch / row_step`` (2 / sqrt(3)
on a regular grid) output pixels per lens along it, so the decoded views
hold as many samples as the lenses and more (a regular hexagonal grid has
one lens per ``pitch * row_step``; the output one pixel per ``row_step^2``).
Output pixel ``x`` of row ``i`` lies ``x * row_step / pitch - s_i / 2``
lenses along that row (``s_i = 1`` on the shifted rows), so the two
parities of rows are resampled at positions half a lens apart and land on
one square grid: the shift is removed by the resampling itself, never by
moving whole rows. The value is a Catmull-Rom cubic along the row through
the four nearest lenses of that row, each sampled at the same view offset
(exact for cubic polynomials along the row, so no comb between rows of
the two parities; tested by ``tests/test_lenslet_roundtrip.py``). Where one
of the four is invalid it falls back to the two nearest lenses, linearly.

The work is one numba kernel, parallel over lens rows: each lens row is
sampled once per view into a small buffer that stays in the cache, then
resampled to the output row, so every sensor sample is read once per view
whatever the number of output pixels it feeds.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .._kernels import bilinear_point

__all__ = ["view_offsets", "row_taps", "lens_rows", "Slicer", "slice_views", "PAD_LEFT"]

#: Lens columns sampled left of column 0 (the cubic of the first output pixel of a shifted row needs two).
PAD_LEFT = 2


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


def row_taps(grid):
    """First lens (padded column index) and cubic weights of every output pixel, for each row parity.

    Returns
    -------
    first : ndarray, shape (2, X), int64
        Index into the padded lens columns (column ``j`` is ``j + PAD_LEFT``)
        of the first of the four lenses feeding output pixel ``x`` on an
        unshifted (0) and a shifted (1) row.
    weights : ndarray, shape (2, X, 4)
        Their Catmull-Rom weights.

    Examples
    --------
    >>> from napari_lfalias.decoders.grid import GridModel
    >>> grid = GridModel("hexagonal", 10.0, 0.0, (0.0, 0.0), 4, 5, (40, 50))
    >>> first, weights = row_taps(grid)
    >>> first[:, 0].tolist(), weights[1, 0].round(3).tolist()  # a shifted row starts half a lens early
    ([1, 0], [-0.062, 0.562, 0.562, -0.062])
    """
    n_out = grid.output_shape()[1]
    shift = np.array([0.0, 0.5])[:, None]
    xi = np.arange(n_out)[None, :] * grid.column_step / grid.pitch - shift  # lens units along the row
    base = np.floor(xi)
    first = (base - 1 + PAD_LEFT).astype(np.int64)
    return np.ascontiguousarray(first), np.ascontiguousarray(_catmull_rom(xi - base))


def lens_rows(grid):
    """Model (y, x) centres of every lens, padded ``(n_rows, n_cols + PAD_LEFT + 2, 2)`` on a hexagonal grid.

    Distortion included; the padding columns continue the lattice past
    the grid's ends (a rectangular grid is not padded).
    """
    pad_right = 2 if grid.is_hexagonal else 0
    pad_left = PAD_LEFT if grid.is_hexagonal else 0
    e_y, e_x = grid.axes
    rows = np.arange(grid.n_rows, dtype=np.float64)[:, None]
    cols = np.arange(-pad_left, grid.n_cols + pad_right, dtype=np.float64)[None, :]
    along = (cols + 0.5 * grid.row_shifts()[:, None]) * grid.pitch
    ideal = np.asarray(grid.offset) + (rows * grid.row_step)[..., None] * e_y + along[..., None] * e_x
    return ideal + grid.displacement(ideal)


@njit(cache=True, inline="always")
def _sample_lens_row(image, scale, valid, swap, lenses, y, dy, dx, j0, j1, sums, values, valids):
    """Validity-weighted bilinear samples (times ``scale``) of lenses ``j0 .. j1 - 1`` of lens row ``y``.

    Each is taken at the lens centre plus the view offset ``(dy, dx)``.
    """
    n_rows, n_cols = valid.shape
    n_ch = image.shape[2]
    for j in range(j0, j1):
        py = lenses[y, j, 0] + dy
        px = lenses[y, j, 1] + dx
        if swap:
            py, px = px, py
        iy = int(np.floor(py))
        ix = int(np.floor(px))
        if iy < 0 or ix < 0 or iy + 1 >= n_rows or ix + 1 >= n_cols:  # at the sensor's edge: the general taps
            total = bilinear_point(image, valid, True, py, px, sums)
            valids[j] = total
            for c in range(n_ch):
                values[j, c] = sums[c] * scale / total if total > 0.0 else 0.0
            continue
        fy = py - iy
        fx = px - ix
        w00 = (1.0 - fy) * (1.0 - fx) * valid[iy, ix]
        w01 = (1.0 - fy) * fx * valid[iy, ix + 1]
        w10 = fy * (1.0 - fx) * valid[iy + 1, ix]
        w11 = fy * fx * valid[iy + 1, ix + 1]
        total = w00 + w01 + w10 + w11
        valids[j] = total
        inv = scale / total if total > 0.0 else 0.0
        for c in range(n_ch):
            values[j, c] = (w00 * image[iy, ix, c] + w01 * image[iy, ix + 1, c]
                            + w10 * image[iy + 1, ix, c] + w11 * image[iy + 1, ix + 1, c]) * inv


@njit(cache=True, inline="always")
def _row_cubic(values, valids, first, tap_weights, tap_norm, p, x, dest, k):
    """Output pixel ``x`` of a hexagonal row (into ``dest[k]``) and its weight.

    The Catmull-Rom cubic of the four lenses of the row around it; where one
    of them is invalid, linear between the two middle ones.
    """
    n_ch = values.shape[1]
    j = first[p, x]
    t0 = tap_weights[p, x, 0]
    t1 = tap_weights[p, x, 1]
    t2 = tap_weights[p, x, 2]
    t3 = tap_weights[p, x, 3]
    v0 = valids[j]
    v1 = valids[j + 1]
    v2 = valids[j + 2]
    v3 = valids[j + 3]
    if v0 > 0.0 and v1 > 0.0 and v2 > 0.0 and v3 > 0.0:
        for c in range(n_ch):
            dest[k, c] = t0 * values[j, c] + t1 * values[j + 1, c] + t2 * values[j + 2, c] + t3 * values[j + 3, c]
        return (abs(t0) * v0 + abs(t1) * v1 + abs(t2) * v2 + abs(t3) * v3) / tap_norm[p, x]
    t = t2 + 2.0 * t3 - t0  # the fraction, for Catmull-Rom weights
    w1 = (1.0 - t) * v1
    w2 = t * v2
    if w1 + w2 <= 0.0:
        return 0.0
    inv = 1.0 / (w1 + w2)
    for c in range(n_ch):
        dest[k, c] = (w1 * values[j + 1, c] + w2 * values[j + 2, c]) * inv
    return w1 + w2


@njit(cache=True, inline="always")
def _output_row(values, valids, on, cubic, first, tap_weights, tap_norm, p, x0, x1, min_weight, dest, dest_weight):
    """Output pixels ``x0 .. x1 - 1`` of a row (into ``dest[x - x0]``) from its sampled lenses.

    Weights are at most 1; below ``min_weight`` weight and value are 0.
    """
    n_ch = values.shape[1]
    for x in range(x0, x1):
        k = x - x0
        weight = 0.0
        if on:
            if cubic:
                weight = min(_row_cubic(values, valids, first, tap_weights, tap_norm, p, x, dest, k), 1.0)
            else:
                weight = min(valids[x], 1.0)
                for c in range(n_ch):
                    dest[k, c] = values[x, c]
        if weight < min_weight:
            weight = 0.0
            for c in range(n_ch):
                dest[k, c] = 0.0
        dest_weight[k] = weight


@njit(cache=True, parallel=True)
def _slice_kernel(image, scale, valid, swap, lenses, parity, first, tap_weights, tap_norm, offsets, view_on, min_weight,
                  rows, x0, x1, y0, out, out_weight):
    n_u, n_v = view_on.shape
    n_lens = lenses.shape[1]
    n_ch = image.shape[2]
    cubic = tap_weights.shape[2] > 0
    for r in prange(rows.shape[0]):
        y = rows[r]
        sums = np.zeros(n_ch)
        values = np.zeros((n_lens, n_ch))
        valids = np.zeros(n_lens)
        buffer = np.zeros((x1 - x0, n_ch), np.float32)
        buffer_weight = np.zeros(x1 - x0, np.float32)
        p = parity[y]
        j0 = first[p, x0] if cubic else x0
        j1 = first[p, x1 - 1] + 4 if cubic else x1
        for u in range(n_u):
            for v in range(n_v):
                on = view_on[u, v]
                if on:
                    _sample_lens_row(image, scale, valid, swap, lenses, y, offsets[u, v, 0], offsets[u, v, 1], j0,
                                     j1, sums, values, valids)
                if swap:  # write a column of the transposed output
                    _output_row(values, valids, on, cubic, first, tap_weights, tap_norm, p, x0, x1, min_weight,
                                buffer, buffer_weight)
                    out[v, u, :, y - y0] = buffer
                    out_weight[v, u, :, y - y0] = buffer_weight
                else:
                    _output_row(values, valids, on, cubic, first, tap_weights, tap_norm, p, x0, x1, min_weight,
                                out[u, v, y - y0], out_weight[u, v, y - y0])


@njit(cache=True)
def _seen_kernel(image, scale, valid, swap, lenses, parity, first, tap_weights, tap_norm, offsets, view_on, min_weight,
                 rows, x0, x1, seen):
    """``seen[r, x - x0]``: some view sees output pixel ``(rows[r], x)`` with weight >= min_weight."""
    n_u, n_v = view_on.shape
    n_lens = lenses.shape[1]
    n_ch = image.shape[2]
    cubic = tap_weights.shape[2] > 0
    sums = np.zeros(n_ch)
    values = np.zeros((n_lens, n_ch))
    valids = np.zeros(n_lens)
    buffer = np.zeros((x1 - x0, n_ch), np.float32)
    buffer_weight = np.zeros(x1 - x0, np.float32)
    for r in range(rows.shape[0]):
        y = rows[r]
        p = parity[y]
        j0 = first[p, x0] if cubic else x0
        j1 = first[p, x1 - 1] + 4 if cubic else x1
        for u in range(n_u):
            for v in range(n_v):
                if not view_on[u, v]:
                    continue
                _sample_lens_row(image, scale, valid, swap, lenses, y, offsets[u, v, 0], offsets[u, v, 1], j0, j1,
                                 sums, values, valids)
                _output_row(values, valids, True, cubic, first, tap_weights, tap_norm, p, x0, x1, min_weight,
                            buffer, buffer_weight)
                for k in range(x1 - x0):
                    if buffer_weight[k] > 0.0:
                        seen[r, k] = True


class Slicer:
    """The sampling plan of one grid and view count: lens centres, cubic taps, view offsets.

    Parameters
    ----------
    image : ndarray, shape (H, W, C), float32 or uint16
        Devignetted sensor image, in the image's own orientation (a
        transposed grid is handled while sampling); its values times
        ``scale`` are the ratio to the white image.
    valid : ndarray, shape (H, W), float32
        Validity of each sensor pixel in [0, 1] (0: unlit or unusable).
    grid : GridModel
    n_views : int
        Views per side.
    view_on : ndarray, shape (n_views, n_views), bool
        Views to fill; the others get zero data and weight.
    step : float
        Pixels between neighbouring views under a lens.
    min_weight : float
        Samples whose weight is below this get weight 0 and value 0.
    scale : float
        Factor on the image's values (the step of a 16-bit image).
    """

    def __init__(self, image, valid, grid, n_views, view_on, step=1.0, min_weight=0.0, scale=1.0):
        image = np.asarray(image)
        self.image = np.ascontiguousarray(image, np.uint16 if image.dtype == np.uint16 else np.float32)
        self.scale = float(scale)
        self.valid = np.ascontiguousarray(valid, np.float32)
        self.grid = grid
        self.n_views = int(n_views)
        self.lenses = np.ascontiguousarray(lens_rows(grid), np.float64)
        if grid.is_hexagonal:
            self.first, self.tap_weights = row_taps(grid)
        else:
            self.first, self.tap_weights = np.zeros((2, 0), np.int64), np.zeros((2, 0, 0))
        self.tap_norm = np.ascontiguousarray(np.abs(self.tap_weights).sum(axis=2))
        self.parity = np.ascontiguousarray(grid.row_shifts(), np.int64)
        self.offsets = np.ascontiguousarray(view_offsets(grid, n_views, step)[0], np.float64)
        self.view_on = np.ascontiguousarray(view_on, np.bool_)
        self.min_weight = float(min_weight)
        self.shape = grid.output_shape()  # model (rows, columns)

    def _arguments(self):
        return (self.image, self.scale, self.valid, bool(self.grid.transposed), self.lenses, self.parity, self.first,
                self.tap_weights, self.tap_norm, self.offsets, self.view_on, self.min_weight)

    def seen(self, rows, x0=0, x1=None):
        """``(len(rows), x1 - x0)`` bool: model output pixels some view sees with weight >= min_weight."""
        x1 = self.shape[1] if x1 is None else x1
        rows = np.ascontiguousarray(rows, np.int64)
        seen = np.zeros((len(rows), x1 - x0), np.bool_)
        _seen_kernel(*self._arguments(), rows, int(x0), int(x1), seen)
        return seen

    def window(self):
        """Model ``(y0, y1, x0, x1)`` of the output pixels any view sees, or ``None`` when none is seen.

        Found from the borders inwards, so a grid whose lenses are all lit
        costs four rows and columns of sampling.
        """
        n_y, n_x = self.shape
        y0 = next((y for y in range(n_y) if self.seen([y]).any()), None)
        if y0 is None:
            return None
        y1 = next(y for y in range(n_y - 1, y0 - 1, -1) if self.seen([y]).any()) + 1
        rows = np.arange(y0, y1)
        x0 = next(x for x in range(n_x) if self.seen(rows, x, x + 1).any())
        x1 = next(x for x in range(n_x - 1, x0 - 1, -1) if self.seen(rows, x, x + 1).any()) + 1
        return y0, y1, x0, x1

    def allocate(self, window):
        """Empty ``data (U, V, Y, X, C)`` and ``weights (U, V, Y, X)`` for a model window, in image orientation."""
        y0, y1, x0, x1 = window
        size = (x1 - x0, y1 - y0) if self.grid.transposed else (y1 - y0, x1 - x0)
        shape = (self.n_views, self.n_views) + size
        return np.empty(shape + (self.image.shape[2],), np.float32), np.empty(shape, np.float32)

    def fill(self, window, rows, data, weights):
        """Compute model output rows ``rows`` (within ``window``) into ``data`` and ``weights``."""
        y0, _, x0, x1 = window
        _slice_kernel(*self._arguments(), np.ascontiguousarray(rows, np.int64), int(x0), int(x1), int(y0),
                      data, weights)


def slice_views(image, valid, grid, n_views, view_on, step=1.0, min_weight=0.0):
    """Slice a devignetted sensor image into views (every output pixel, no trimming).

    Parameters are those of :class:`Slicer`.

    Returns
    -------
    data : ndarray, shape (n_views, n_views, Y, X, C), float32
        In the image's orientation (rows and views swapped back for a
        transposed grid).
    weights : ndarray, shape (n_views, n_views, Y, X), float32
    """
    slicer = Slicer(image, valid, grid, n_views, view_on, step, min_weight)
    window = (0, slicer.shape[0], 0, slicer.shape[1])
    data, weights = slicer.allocate(window)
    slicer.fill(window, np.arange(slicer.shape[0]), data, weights)
    return data, weights
