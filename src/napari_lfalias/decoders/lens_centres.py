"""Microlens centres in a white image: rough peaks, then sub-pixel centres of each lens' own cell.

Two passes, because a sub-pixel estimate needs to know where a lens ends:

1. :func:`find_peaks` gives one point per lit lens, good to a few tenths
   of a pixel (enough to give each its lattice index): local maxima of the
   white image divided by its envelope and smoothed, found at a resolution
   of about 7 pixels per pitch (a large sensor is reduced first), each
   refined by a parabola.
2. :func:`cell_centroids` measures every lens of a fitted lattice inside
   its own Voronoi cell (the points nearer to it than to any other lens),
   whose faces fade over one pixel so that whole pixels do not lock the
   estimate. The weight of a pixel is its excess over the cell's mid level
   (halfway between the lens' top and the gap between lenses), so the
   light of the neighbours, the dark gaps and a flat top carry nothing and
   the centroid of any symmetric lens image -- a flat disc with soft
   edges, a Gaussian-like spot, a disc touching its neighbours -- is its
   centre. Vignetting tilts a lens image; the tilt (the relative slope of
   the white level, from a smooth fit of the lens brightnesses, see
   :class:`Brightness`) is divided out of each cell before its centroid is
   taken. Noise averages out over the cell.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .grid import distortion_terms

__all__ = ["find_peaks", "cell_centroids", "Brightness", "cell_faces", "least_squares", "DARK_FRACTION"]

#: Lens regions darker than this fraction of the bright level are ignored.
DARK_FRACTION = 0.2
#: Pixels per pitch at which the rough peaks are found.
_PEAK_RESOLUTION = 7.0
#: Width (pixels) over which a cell's faces fade out.
_RAMP = 1.0


def _reduced(grey, pitch, even=False):
    """The image averaged over ``f x f`` blocks (f >= 1 keeps >= 7 px per pitch; even if asked), and ``f``."""
    import cv2

    factor = max(1, int(pitch // _PEAK_RESOLUTION))
    if even and factor > 1:
        factor -= factor % 2
    if factor == 1:
        return grey, 1
    height, width = (grey.shape[0] // factor) * factor, (grey.shape[1] // factor) * factor
    small = cv2.resize(grey[:height, :width], (width // factor, height // factor), interpolation=cv2.INTER_AREA)
    return small, factor


def _envelope(grey, pitch):
    """The image's slow envelope (vignetting): a Gaussian of one pitch, computed at low resolution."""
    import cv2

    height, width = grey.shape
    factor = max(1.0, pitch / 4.0)
    small_size = (max(8, int(round(width / factor))), max(8, int(round(height / factor))))
    small = cv2.resize(grey, small_size, interpolation=cv2.INTER_AREA)
    sigma = pitch * small_size[0] / width
    small = cv2.GaussianBlur(small, (0, 0), sigmaX=max(sigma, 0.5), borderType=cv2.BORDER_REFLECT)
    return cv2.resize(small, (width, height), interpolation=cv2.INTER_LINEAR), small


def _fully_lit(small, bright, pitch, shape):
    """Pixels whose whole neighbourhood (one pitch across) is brighter than the dark fraction.

    Lenses cut by a dark border or the sensor's edge are left out: their
    centres would be pulled inwards.
    """
    import cv2

    lit = (small > DARK_FRACTION * bright).astype(np.uint8)
    factor = shape[1] / small.shape[1]
    size = 2 * int(math.ceil(0.5 * pitch / factor)) + 1
    lit = cv2.erode(lit, np.ones((size, size), np.uint8), borderType=cv2.BORDER_CONSTANT, borderValue=0)
    return cv2.resize(lit, (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST).astype(bool)


def _parabola(left, mid, right):
    denom = left - 2.0 * mid + right
    return np.where(denom < 0, np.clip(0.5 * (left - right) / np.where(denom < 0, denom, -1.0), -0.5, 0.5), 0.0)


def find_peaks(grey, pitch, mosaic=False):
    """``(n, 2)`` rough (y, x) of the lit lenses, and the white image's bright level.

    Parameters
    ----------
    grey : ndarray, shape (H, W), float32
        White image (dark frame subtracted).
    pitch : float
        Approximate lens pitch in pixels.
    mosaic : bool
        ``grey`` is a Bayer mosaic: averaging 2 x 2 blocks (an even
        reduction) removes its pattern; below 14 px per lens it is filtered
        out at full resolution instead.

    Returns
    -------
    points : ndarray, shape (n, 2)
    bright : float
        The 99th percentile of the envelope (0 for a black image).
    """
    import cv2

    from .bayer import cfa_grey

    small, factor = _reduced(grey, pitch, even=mosaic)
    if mosaic and factor == 1:
        small = cfa_grey(grey)
    step = pitch / factor
    envelope, tiny = _envelope(small, step)
    bright = float(np.percentile(tiny, 99.0))
    if not bright > 0:
        return np.zeros((0, 2)), 0.0
    flat = small / np.maximum(envelope, 0.05 * bright)
    smooth = cv2.GaussianBlur(flat, (0, 0), sigmaX=max(step / 5.0, 0.8), borderType=cv2.BORDER_REFLECT)
    size = max(3, int(round(0.7 * step)) | 1)
    local_max = cv2.dilate(smooth, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size)))
    keep = (smooth >= local_max) & _fully_lit(tiny, bright, step, small.shape) & (smooth > 1.0)
    keep[:1, :] = keep[-1:, :] = False
    keep[:, :1] = keep[:, -1:] = False
    rows, cols = np.nonzero(keep)
    dy = _parabola(smooth[rows - 1, cols], smooth[rows, cols], smooth[rows + 1, cols])
    dx = _parabola(smooth[rows, cols - 1], smooth[rows, cols], smooth[rows, cols + 1])
    points = np.stack([rows + dy, cols + dx], axis=1) * factor + 0.5 * (factor - 1)
    return points, bright


def cell_faces(basis):
    """Unit normals ``(k, 2)`` and half-distances ``(k,)`` of a lattice cell's pairs of faces, and its circumradius.

    ``basis`` holds the row vector and the next-row vector as columns; the
    faces bisect the segments to the nearest lenses, in opposite pairs: 3
    pairs on a hexagonal lattice (both vectors and their difference), 2 on
    a rectangular one (the row vector and the row-to-row vector across it).
    """
    a1, a2 = basis[:, 0], basis[:, 1]
    hexagonal = abs(np.dot(a1, a2)) > 0.25 * np.dot(a1, a1)  # a2 half a pitch along the row
    vectors = [a1, a2, a2 - a1] if hexagonal else [a1, a2]
    lengths = np.array([np.hypot(*v) for v in vectors])
    normals = np.array([v / n for v, n in zip(vectors, lengths)])
    if hexagonal:
        radius = float(lengths.max()) / math.sqrt(3.0) * 1.1
    else:
        radius = 0.5 * math.hypot(lengths[0], lengths[1])
    return normals, 0.5 * lengths, radius + 0.5 * _RAMP


@njit(cache=True, inline="always")
def _membership(dy, dx, normals, half, ramp):
    inside = 1.0
    for k in range(normals.shape[0]):
        margin = half[k] - abs(dy * normals[k, 0] + dx * normals[k, 1])
        m = margin / ramp + 0.5
        if m < inside:
            inside = m
    return min(max(inside, 0.0), 1.0)


@njit(cache=True, inline="always")
def _pixel(image, y, x, cfa):
    """The image at ``(y, x)``, or its [1 2 1] x [1 2 1] / 16 average (a Bayer mosaic's grey) with ``cfa``."""
    if not cfa:
        return image[y, x]
    total = 0.0
    for dy in range(-1, 2):
        wy = 2.0 if dy == 0 else 1.0
        for dx in range(-1, 2):
            total += wy * (2.0 if dx == 0 else 1.0) * image[y + dy, x + dx]
    return total / 16.0


@njit(cache=True, parallel=True)
def _cell_centroids(image, centres, slopes, normals, half, radius, ramp, cfa, out, stats):
    height, width = image.shape
    side = 2 * int(np.ceil(radius)) + 2
    for i in prange(centres.shape[0]):
        cy = centres[i, 0]
        cx = centres[i, 1]
        stats[i, 0] = 0.0
        stats[i, 1] = 0.0
        out[i, 0] = cy
        out[i, 1] = cx
        y0 = int(np.floor(cy - radius))
        y1 = int(np.ceil(cy + radius))
        x0 = int(np.floor(cx - radius))
        x1 = int(np.ceil(cx + radius))
        if y0 < 1 or x0 < 1 or y1 >= height - 1 or x1 >= width - 1:
            continue
        gy = slopes[i, 0]
        gx = slopes[i, 1]
        members = np.empty(side * side)
        values = np.empty(side * side)
        offsets = np.empty((side * side, 2))
        n = 0
        top = -np.inf
        low = np.inf
        total = 0.0
        area = 0.0
        for y in range(y0, y1 + 1):
            dy = y - cy
            for x in range(x0, x1 + 1):
                dx = x - cx
                m = _membership(dy, dx, normals, half, ramp)
                if m <= 0.0:
                    continue
                tilt = 1.0 + gy * dy + gx * dx
                value = _pixel(image, y, x, cfa) / tilt if tilt > 0.05 else 0.0
                if m >= 1.0:
                    top = max(top, value)
                    low = min(low, value)
                total += m * value
                area += m
                members[n] = m
                values[n] = value
                offsets[n, 0] = dy
                offsets[n, 1] = dx
                n += 1
        if area <= 0.0 or not top > low:
            continue
        level = 0.5 * (top + low)
        sw = 0.0
        sy = 0.0
        sx = 0.0
        for k in range(n):
            w = members[k] * (values[k] - level)
            if w > 0.0:
                sw += w
                sy += w * offsets[k, 0]
                sx += w * offsets[k, 1]
        if sw <= 0.0:
            continue
        out[i, 0] = cy + sy / sw
        out[i, 1] = cx + sx / sw
        stats[i, 0] = total / area
        stats[i, 1] = (top - low) / max(abs(top), 1e-30)


def cell_centroids(grey, centres, basis, slopes=None, mosaic=False):
    """Sub-pixel centre of every lens inside its own cell (see the module notes).

    Parameters
    ----------
    grey : ndarray, shape (H, W), float32
        White image, in the coordinates of ``centres``.
    centres : ndarray, shape (n, 2)
        Predicted (y, x) centres (a fitted lattice); each lens' cell is
        centred there.
    basis : ndarray, shape (2, 2)
        Row vector and next-row vector (columns) of the lattice.
    slopes : ndarray, shape (n, 2), optional
        Relative slope (1/px) of the white level at each lens, divided out.
    mosaic : bool
        ``grey`` is a Bayer mosaic: its pattern is filtered out pixel by
        pixel (the [1 2 1] filter of :func:`~.bayer.cfa_grey`).

    Returns
    -------
    found : ndarray, shape (n, 2)
        Centroids (the prediction where a lens could not be measured).
    brightness : ndarray, shape (n,)
        Mean level of each cell (0 where the cell leaves the image).
    contrast : ndarray, shape (n,)
        ``(top - low) / top`` within each cell (0 where not measured).
    """
    centres = np.ascontiguousarray(centres, np.float64)
    slopes = np.zeros_like(centres) if slopes is None else np.ascontiguousarray(slopes, np.float64)
    normals, half, radius = cell_faces(np.asarray(basis, np.float64))
    found = np.empty_like(centres)
    stats = np.empty((len(centres), 2))
    _cell_centroids(np.ascontiguousarray(grey, np.float32), centres, slopes, np.ascontiguousarray(normals),
                    np.ascontiguousarray(half), float(radius), _RAMP, bool(mosaic), found, stats)
    return found, stats[:, 0], stats[:, 1]


def least_squares(design, target):
    """Least-squares coefficients of a tall, well-conditioned system, through its normal equations."""
    normal = design.T @ design
    return np.linalg.solve(normal + 1e-12 * np.trace(normal) * np.eye(len(normal)), design.T @ target)


class Brightness:
    """A smooth model of the lenses' brightness (the white image's vignetting): a robust cubic in log.

    ``log(brightness)`` of the lit lenses is fitted by a cubic polynomial
    over the image (:data:`~.grid.DISTORTION_TERMS`), outliers (lenses cut
    by a border, dust) rejected by their residual.

    Parameters
    ----------
    points : ndarray, shape (n, 2)
        Lens centres.
    brightness : ndarray, shape (n,)
        Their mean level (0 where unknown).
    lit : ndarray, shape (n,), bool
        Lenses to fit.
    shape : tuple
        The image (model) shape the polynomial is normalised over.
    """

    def __init__(self, points, brightness, lit, shape):
        self.shape = shape
        good = lit & (brightness > 0)
        self.coeffs = None
        if good.sum() < 20:
            return
        terms = distortion_terms(points[good], shape)
        target = np.log(brightness[good])
        keep = np.ones(len(target), bool)
        for _ in range(3):
            self.coeffs = least_squares(terms[keep], target[keep])
            error = np.abs(terms @ self.coeffs - target)
            keep = error <= max(4.0 * 1.4826 * float(np.median(error[keep])), 1e-3)

    def __call__(self, points):
        """Predicted brightness at ``points`` (0 without a model)."""
        if self.coeffs is None:
            return np.zeros(len(points))
        return np.exp(distortion_terms(points, self.shape) @ self.coeffs)

    def slopes(self, points):
        """Relative slope ``(n, 2)`` (1/px) of the brightness at ``points``: the gradient of its log."""
        points = np.asarray(points, np.float64)
        if self.coeffs is None:
            return np.zeros_like(points)
        eps = 0.5
        grad = np.empty_like(points)
        for axis in range(2):
            step = np.zeros(2)
            step[axis] = eps
            up = distortion_terms(points + step, self.shape) @ self.coeffs
            down = distortion_terms(points - step, self.shape) @ self.coeffs
            grad[:, axis] = (up - down) / (2 * eps)
        return grad
