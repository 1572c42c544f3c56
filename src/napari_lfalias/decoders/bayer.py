"""Bayer colour-filter mosaics: pattern names, demosaicing, a CFA-free grey image.

Demosaicing uses OpenCV's edge-aware method (``COLOR_Bayer*2RGB_EA``) on
16-bit data. The lenslet decoder divides the mosaic by the white mosaic
first (as LFToolbox does), so the demosaicing sees a devignetted image
without the dark rims between microlenses, and demosaics lens by lens
(:mod:`.lens_demosaicing`) where it knows the microlens grid.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ..errors import ParameterError

__all__ = ["BAYER_PATTERNS", "bayer_pattern", "channel_index", "demosaic", "demosaic16", "cfa_grey", "mosaic"]

#: The four 2x2 Bayer layouts, named by their top-left 2x2 block read row by row.
BAYER_PATTERNS = ("RGGB", "BGGR", "GRBG", "GBRG")
#: OpenCV's names count from the second row and column: RGGB is "BayerBG".
_OPENCV_CODE = {"RGGB": "BG", "BGGR": "RG", "GRBG": "GB", "GBRG": "GR"}
_CHANNEL = {"R": 0, "G": 1, "B": 2}
_SCALE = 65535.0


def bayer_pattern(pattern, name="bayer"):
    """Return ``pattern`` as one of :data:`BAYER_PATTERNS` (case-insensitive), or ``None``.

    Raises
    ------
    ParameterError
        If it is not a Bayer layout.
    """
    if pattern is None:
        return None
    text = str(pattern).upper().replace(",", "").replace(":", "").replace(" ", "")
    if text not in BAYER_PATTERNS:
        raise ParameterError(f"{name} must be one of {', '.join(BAYER_PATTERNS)} or None, got {pattern!r}")
    return text


def channel_index(pattern, shape):
    """``(H, W)`` int array: the colour (0 R, 1 G, 2 B) of every pixel of a mosaic."""
    pattern = bayer_pattern(pattern)
    tile = np.array([[_CHANNEL[pattern[0]], _CHANNEL[pattern[1]]],
                     [_CHANNEL[pattern[2]], _CHANNEL[pattern[3]]]])
    height, width = shape
    reps = ((height + 1) // 2, (width + 1) // 2)
    return np.tile(tile, reps)[:height, :width]


def mosaic(rgb, pattern):
    """Sample an ``(H, W, 3)`` image through a Bayer filter: ``(H, W)``, one channel per pixel.

    Examples
    --------
    >>> import numpy as np
    >>> rgb = np.zeros((2, 2, 3)); rgb[..., 0] = 1.0
    >>> mosaic(rgb, "RGGB").tolist()
    [[1.0, 0.0], [0.0, 0.0]]
    """
    rgb = np.asarray(rgb)
    index = channel_index(pattern, rgb.shape[:2])
    return np.take_along_axis(rgb, index[..., None], axis=2)[..., 0]


def demosaic(raw, pattern):
    """Demosaic a Bayer mosaic with OpenCV's edge-aware interpolation.

    Parameters
    ----------
    raw : ndarray, shape (H, W)
        Linear mosaic values, nominally in [0, 1] (values above 1 are kept
        up to the largest value, which sets the 16-bit scale).
    pattern : str
        One of :data:`BAYER_PATTERNS`.

    Returns
    -------
    rgb : ndarray, shape (H, W, 3), float32

    Examples
    --------
    >>> import numpy as np
    >>> rgb = np.ones((8, 8, 3)) * [0.8, 0.5, 0.2]
    >>> [round(float(c), 3) for c in demosaic(mosaic(rgb, "GRBG"), "GRBG")[4, 4]]
    [0.8, 0.5, 0.2]
    """
    rgb16, step = demosaic16(raw, pattern)
    out = np.empty(rgb16.shape, np.float32)
    _dequantise(rgb16, step, out)
    return out


def demosaic16(raw, pattern, top=None):
    """:func:`demosaic` kept in 16 bits: ``(rgb16, step)`` with ``rgb16 * step`` the colour image.

    ``top`` is the mosaic's maximum when known (else it is computed); the
    16-bit scale spans ``[0, max(top, 1)]``.
    """
    import cv2

    pattern = bayer_pattern(pattern)
    raw = np.asarray(raw, np.float32)
    if raw.ndim != 2 or min(raw.shape) < 2:
        raise ParameterError(f"a Bayer mosaic must be a 2-D image of at least 2 x 2, got shape {raw.shape}")
    top = (float(raw.max()) if raw.size else 1.0) if top is None else float(top)
    scale = _SCALE / max(top, 1.0)
    quantised = np.empty(raw.shape, np.uint16)
    _quantise(raw, scale, quantised)
    code = getattr(cv2, f"COLOR_Bayer{_OPENCV_CODE[pattern]}2RGB_EA")
    return cv2.cvtColor(quantised, code), 1.0 / scale


@njit(cache=True, parallel=True)
def _quantise(raw, scale, out):
    """``out = round(raw * scale)`` clipped to 16 bits (one pass, no temporaries: large sensors)."""
    for y in prange(raw.shape[0]):
        for x in range(raw.shape[1]):
            value = raw[y, x] * scale + 0.5
            out[y, x] = 0 if value < 0.0 else (65535 if value > 65535.0 else int(value))


@njit(cache=True, parallel=True)
def _dequantise(rgb16, inv_scale, out):
    for y in prange(rgb16.shape[0]):
        for x in range(rgb16.shape[1]):
            for c in range(rgb16.shape[2]):
                out[y, x, c] = rgb16[y, x, c] * inv_scale


def cfa_grey(raw):
    """A grey image free of the 2-pixel Bayer modulation: the [1 2 1]/4 filter on both axes.

    The filter is symmetric (no shift of the image) and has zero response
    at the mosaic's Nyquist frequency, so lens centres can be found on it.
    """
    import cv2

    kernel = np.array([0.25, 0.5, 0.25], np.float32)
    return cv2.sepFilter2D(np.asarray(raw, np.float32), -1, kernel, kernel, borderType=cv2.BORDER_REFLECT)
