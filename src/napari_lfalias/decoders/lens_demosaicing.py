"""Demosaicing that stays inside each microlens: every missing colour from the same lens only.

A general demosaicing (OpenCV's, :func:`.bayer.demosaic16`) interpolates a
pixel's missing colours from the pixels around it, so next to a lens rim it
mixes in the neighbouring lens, which sees another part of the scene: the
rim views of noise-free Bayer captures reached 26-33 dB, 13 to 20 dB below
the grey ones (``benchmarks/results/lenslet_hexagonal_rim.md``).

Here every pixel belongs to its nearest lens centre (of the fitted grid,
distortion included), and only lit pixels of that lens are used. Each
missing colour is the bilinear interpolation of that colour's pixels in
the 3 x 3 neighbourhood (the mean of the four green neighbours, of the two
or four red or blue ones), normalised over the usable ones; where none is
usable (a corner of the lens) the 5 x 5 neighbourhood with tent weights;
where none is there either, the pixel's own value (grey). Interpolating
colour differences (``red - green``) instead was tried: on the rendered
brick room (colours that vary apart) it made the interior error in red and
blue 1.5 to 1.8 times larger. Dropped pixels (validity 0) are written as 0:
the slicing gives them no weight. Away from the rims this is the bilinear
demosaicing: the benchmark's interior views match those of OpenCV's
edge-aware method to 0.1 dB (43 to 69 dB, noise-free), while the rim
views gain 8 to 11 dB.

The work is one numba kernel, parallel over bands of sensor rows: each band
finds the lens of its pixels (and of two rows either side) by drawing every
lens's neighbourhood into a small buffer, nearest centre wins, then
interpolates.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .bayer import bayer_pattern, channel_index

__all__ = ["demosaic_in_lenses"]

#: Sensor rows per band of the kernel (each band also finds the lenses of 2 rows either side).
_BAND = 64
_MARGIN = 2


def _lens_centres(grid):
    """Image (row, col) centres of every lens, padded past the grid's ends, sorted by row: ``(n, 2)``."""
    from .slicing import lens_rows

    centres = lens_rows(grid).reshape(-1, 2)
    if grid.transposed:
        centres = centres[:, ::-1]
    return np.ascontiguousarray(centres[np.argsort(centres[:, 0], kind="stable")], np.float64)


def demosaic_in_lenses(mosaic, valid, pattern, grid, top=None):
    """Demosaic a devignetted Bayer mosaic lens by lens, kept in 16 bits: ``(rgb16, step)``.

    Parameters
    ----------
    mosaic : ndarray, shape (H, W), float32
        The ratio to the white image, one Bayer colour per pixel.
    valid : ndarray, shape (H, W), float32
        Validity of each pixel (0: dropped; never used for another's colour).
    pattern : str
        One of :data:`.bayer.BAYER_PATTERNS`.
    grid : GridModel
        The microlens grid of the capture (lens membership: nearest centre).
    top : float, optional
        The mosaic's maximum when known; the 16-bit scale spans ``[0, max(top, 1)]``.

    Returns
    -------
    rgb16 : ndarray, shape (H, W, 3), uint16
    step : float
        ``rgb16 * step`` is the colour image.

    Examples
    --------
    Two lenses side by side, one red and one blue: a pixel at the border of
    each keeps its own lens's colour (a general demosaicing blends them).

    >>> from napari_lfalias.decoders.grid import GridModel
    >>> from napari_lfalias.decoders.bayer import mosaic as to_mosaic
    >>> grid = GridModel("rectangular", 8.0, 0.0, (3.5, 3.5), 1, 2, (8, 16))
    >>> rgb = np.zeros((8, 16, 3), np.float32); rgb[:, :8, 0] = 1.0; rgb[:, 8:, 2] = 1.0
    >>> image, step = demosaic_in_lenses(to_mosaic(rgb, "RGGB"), np.ones((8, 16), np.float32), "RGGB", grid)
    >>> (image[4, 7] * step).round(3).tolist(), (image[4, 8] * step).round(3).tolist()
    ([1.0, 0.0, 0.0], [0.0, 0.0, 1.0])
    """
    pattern = bayer_pattern(pattern)
    mosaic = np.ascontiguousarray(mosaic, np.float32)
    valid = np.ascontiguousarray(valid, np.float32)
    top = (float(mosaic.max()) if mosaic.size else 1.0) if top is None else float(top)
    scale = 65535.0 / max(top, 1.0)
    out = np.empty(mosaic.shape + (3,), np.uint16)
    _demosaic_kernel(mosaic, valid, channel_index(pattern, (2, 2)).astype(np.int64), _lens_centres(grid),
                     _cell_reach(grid), scale, out)
    return out, 1.0 / scale


def _cell_reach(grid):
    """Farthest a pixel of a lens's cell lies from its centre (the cell's corner), plus 1 px for distortion."""
    pitch, rows = grid.pitch, grid.row_step
    if not grid.is_hexagonal:
        return 0.5 * math.hypot(pitch, rows) + 1.0
    # the corner: the centre of the circle through two neighbours of a row and the lens between them below
    height = (rows * rows - pitch * pitch / 4.0) / (2.0 * rows)
    return math.hypot(pitch / 2.0, height) + 1.0


@njit(cache=True, inline="always")
def _lens_labels(centres, reach, valid, y0, y1):
    """Lens of the pixels of rows ``y0 .. y1 - 1``: ``labels[y - y0 + 1, x + 1]`` is the index of the nearest centre.

    -1 beyond every centre's reach; -2 where the pixel is dropped and on a
    border of one pixel around the sensor (so neighbours need no bounds checks).
    """
    height, width = valid.shape
    labels = np.full((y1 - y0 + 2, width + 2), -2, np.int32)
    labels[1:-1, 1:-1] = -1
    best = np.full((y1 - y0, width), np.inf, np.float32)
    first = np.searchsorted(centres[:, 0], y0 - reach)
    last = np.searchsorted(centres[:, 0], y1 - 1 + reach, side="right")
    for i in range(first, last):
        cy = centres[i, 0]
        cx = centres[i, 1]
        for y in range(max(y0, int(math.ceil(cy - reach))), min(y1 - 1, int(math.floor(cy + reach))) + 1):
            dy2 = (y - cy) * (y - cy)
            half = math.sqrt(max(reach * reach - dy2, 0.0))  # the disc of radius reach, row by row
            xa = max(0, int(math.ceil(cx - half)))
            xb = min(width - 1, int(math.floor(cx + half))) + 1
            scores = best[y - y0, xa:xb]
            marks = labels[y - y0 + 1, xa + 1:xb + 1]
            dy2f = np.float32(dy2)
            start = np.float32(xa - cx)
            for k in range(xb - xa):  # float32 and no branch, so it vectorises: a third faster on an Illum
                dx = start + np.float32(k)
                d2 = dy2f + dx * dx
                closer = d2 < scores[k]
                scores[k] = min(d2, scores[k])
                marks[k] = np.int32(i) if closer else marks[k]
    for y in range(y0, y1):
        for x in range(width):
            if valid[y, x] <= 0.0:
                labels[y - y0 + 1, x + 1] = -2
    return labels


@njit(cache=True, inline="always")
def _take(mosaic, labels, ly0, y, x, own):
    """``(value, 1)`` of pixel ``(y, x)`` when it is lit and of lens ``own``, else ``(0, 0)``."""
    if labels[y - ly0 + 1, x + 1] == own:
        return mosaic[y, x], 1
    return 0.0, 0


@njit(cache=True, inline="always")
def _colour_in_reach(mosaic, tile, labels, ly0, y, x, colour):
    """Colour ``colour`` at ``(y, x)`` from its usable pixels in the 5 x 5 neighbourhood, tent weights."""
    height, width = mosaic.shape
    own = labels[y - ly0 + 1, x + 1]
    total = 0.0
    weight = 0.0
    for yy in range(max(0, y - 2), min(height, y + 3)):
        for xx in range(max(0, x - 2), min(width, x + 3)):
            if tile[yy & 1, xx & 1] == colour and labels[yy - ly0 + 1, xx + 1] == own:
                w = (3.0 - abs(yy - y)) * (3.0 - abs(xx - x))
                total += w * mosaic[yy, xx]
                weight += w
    return total / weight if weight > 0.0 else mosaic[y, x]  # none in reach: grey


@njit(cache=True, inline="always")
def _mean2(mosaic, tile, labels, ly0, y, x, dy, dx, colour):
    """Mean of the usable pixels at ``(y, x) -+ (dy, dx)`` (of colour ``colour``), else the wider reach."""
    own = labels[y - ly0 + 1, x + 1]
    a, m = _take(mosaic, labels, ly0, y - dy, x - dx, own)
    b, n = _take(mosaic, labels, ly0, y + dy, x + dx, own)
    if m + n > 0:
        return (a + b) / (m + n)
    return _colour_in_reach(mosaic, tile, labels, ly0, y, x, colour)


@njit(cache=True, inline="always")
def _mean4(mosaic, tile, labels, ly0, y, x, diagonal, colour):
    """Mean of the usable pixels of the four neighbours across (``diagonal`` 0) or diagonal (1), else wider."""
    own = labels[y - ly0 + 1, x + 1]
    if diagonal:
        a, m = _take(mosaic, labels, ly0, y - 1, x - 1, own)
        b, n = _take(mosaic, labels, ly0, y - 1, x + 1, own)
        c, o = _take(mosaic, labels, ly0, y + 1, x - 1, own)
        d, p = _take(mosaic, labels, ly0, y + 1, x + 1, own)
    else:
        a, m = _take(mosaic, labels, ly0, y - 1, x, own)
        b, n = _take(mosaic, labels, ly0, y + 1, x, own)
        c, o = _take(mosaic, labels, ly0, y, x - 1, own)
        d, p = _take(mosaic, labels, ly0, y, x + 1, own)
    if m + n + o + p > 0:
        return (a + b + c + d) / (m + n + o + p)
    return _colour_in_reach(mosaic, tile, labels, ly0, y, x, colour)


@njit(cache=True, inline="always")
def _store(out, y, x, c, value, scale):
    v = value * scale + 0.5
    out[y, x, c] = 0 if v < 0.0 else (65535 if v > 65535.0 else int(v))


@njit(cache=True, parallel=True)
def _demosaic_kernel(mosaic, valid, tile, centres, reach, scale, out):
    height, width = mosaic.shape
    n_bands = (height + _BAND - 1) // _BAND
    for band in prange(n_bands):
        y0 = band * _BAND
        y1 = min(height, y0 + _BAND)
        ly0 = max(0, y0 - _MARGIN)
        labels = _lens_labels(centres, reach, valid, ly0, min(height, y1 + _MARGIN))
        column = np.empty(width + 2, np.int32)
        for y in range(y0, y1):
            row = y - ly0 + 1
            for x in range(width + 2):  # the pixel's lens where its column of three is in one lens, else -3
                here = labels[row, x]
                column[x] = here if labels[row - 1, x] == here and labels[row + 1, x] == here else -3
            for start in range(2):  # one Bayer colour per pass: its branches all go the same way
                mine = tile[y & 1, start]
                across = tile[y & 1, 1 - start]  # the colour along the row (at a green pixel)
                for x in range(start, width, 2):
                    own = labels[row, x + 1]
                    if own == -2:  # dropped
                        out[y, x, 0] = 0
                        out[y, x, 1] = 0
                        out[y, x, 2] = 0
                        continue
                    if column[x] == own and column[x + 1] == own and column[x + 2] == own:
                        # the 3 x 3 neighbourhood is lit and in the lens: plain bilinear interpolation
                        if mine == 1:
                            _store(out, y, x, across, 0.5 * (mosaic[y, x - 1] + mosaic[y, x + 1]), scale)
                            _store(out, y, x, 2 - across, 0.5 * (mosaic[y - 1, x] + mosaic[y + 1, x]), scale)
                        else:
                            _store(out, y, x, 1, 0.25 * (mosaic[y - 1, x] + mosaic[y + 1, x] + mosaic[y, x - 1]
                                                         + mosaic[y, x + 1]), scale)
                            _store(out, y, x, 2 - mine, 0.25 * (mosaic[y - 1, x - 1] + mosaic[y - 1, x + 1]
                                                                + mosaic[y + 1, x - 1] + mosaic[y + 1, x + 1]), scale)
                    elif mine == 1:  # green: red and blue along the row and the column, in some order
                        _store(out, y, x, across, _mean2(mosaic, tile, labels, ly0, y, x, 0, 1, across), scale)
                        _store(out, y, x, 2 - across, _mean2(mosaic, tile, labels, ly0, y, x, 1, 0, 2 - across),
                               scale)
                    else:  # red or blue: green across, the other on the diagonals
                        _store(out, y, x, 1, _mean4(mosaic, tile, labels, ly0, y, x, 0, 1), scale)
                        _store(out, y, x, 2 - mine, _mean4(mosaic, tile, labels, ly0, y, x, 1, 2 - mine), scale)
                    _store(out, y, x, mine, mosaic[y, x], scale)
