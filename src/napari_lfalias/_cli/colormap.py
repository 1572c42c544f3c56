"""Coloured previews of a map of values (disparity), with a colour bar that says what the colours mean.

The colour map is this package's own: viridis's colours at 0, 1/4, 1/2, 3/4
and 1 (the palette of van der Walt and Smith's matplotlib default), joined
by straight lines in Oklab (Ottosson 2020), a space where equal steps look
equally different, so lightness rises steadily from dark violet to yellow
and the map reads the same in grey. matplotlib is not a dependency of the
package; this table needs none.
"""

from __future__ import annotations

import numpy as np

__all__ = ["COLORMAP", "colorize", "colorbar", "colour_preview"]

#: sRGB anchors (0-255) at equal steps from low to high.
ANCHORS = ((68, 1, 84), (59, 82, 139), (33, 145, 140), (94, 201, 98), (253, 231, 37))
#: Entries of the table.
ENTRIES = 256

# Linear sRGB -> LMS and cube-rooted LMS -> Oklab, and their inverses (Ottosson's definition of Oklab).
_RGB_TO_LMS = np.array([[0.4122214708, 0.5363325363, 0.0514459929],
                        [0.2119034982, 0.6806995451, 0.1073969566],
                        [0.0883024619, 0.2817188376, 0.6299787005]])
_LMS_TO_LAB = np.array([[0.2104542553, 0.7936177850, -0.0040720468],
                        [1.9779984951, -2.4285922050, 0.4505937099],
                        [0.0259040371, 0.7827717662, -0.8086757660]])


def _linear(srgb):
    return np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4)


def _encoded(linear):
    linear = np.clip(linear, 0.0, 1.0)
    return np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * linear ** (1 / 2.4) - 0.055)


def _to_oklab(srgb):
    return np.cbrt(_linear(srgb) @ _RGB_TO_LMS.T) @ _LMS_TO_LAB.T


def _from_oklab(lab):
    return _encoded((lab @ np.linalg.inv(_LMS_TO_LAB).T) ** 3 @ np.linalg.inv(_RGB_TO_LMS).T)


def _table():
    lab = _to_oklab(np.asarray(ANCHORS, np.float64) / 255.0)
    where = np.linspace(0.0, len(ANCHORS) - 1, ENTRIES)
    joined = np.stack([np.interp(where, np.arange(len(ANCHORS)), lab[:, k]) for k in range(3)], axis=-1)
    return np.round(_from_oklab(joined) * 255).astype(np.uint8)


#: The colour map, ``(ENTRIES, 3)`` uint8 sRGB from low to high.
COLORMAP = _table()


def colorize(values, low, high):
    """Colour ``values`` by :data:`COLORMAP`, ``low`` -> first colour, ``high`` -> last (clipped).

    Parameters
    ----------
    values : array_like, shape (Y, X)
    low, high : float
        The values of the ends of the map (``high <= low``: every value
        gets the middle colour).

    Returns
    -------
    ndarray, shape (Y, X, 3), uint8

    Examples
    --------
    >>> pixels = colorize([[0.0, 0.5, 1.0]], 0.0, 1.0)
    >>> pixels.shape, pixels[0, 0].tolist(), pixels[0, 2].tolist()
    ((1, 3, 3), [68, 1, 84], [253, 231, 37])
    """
    values = np.asarray(values, np.float64)
    if high > low:
        scaled = (np.nan_to_num(values, nan=low) - low) / (high - low)
    else:
        scaled = np.full(values.shape, 0.5)
    index = np.round(np.clip(scaled, 0.0, 1.0) * (ENTRIES - 1)).astype(np.intp)
    return COLORMAP[index]


#: Height (px) of the colour strip of a :func:`colorbar`, and of its text line.
BAR_HEIGHT = 10
TEXT_HEIGHT = 16


def colorbar(width, low, high, label):
    """A legend ``width`` pixels wide: the colour strip from ``low`` to ``high`` and the values at its ends.

    Examples
    --------
    >>> bar = colorbar(200, -4.0, 4.0, "disparity")
    >>> bar.shape, bar.dtype.name
    ((30, 200, 3), 'uint8')
    """
    import cv2

    margin = 4
    strip = np.linspace(low, high, max(1, width - 2 * margin))[None, :].repeat(BAR_HEIGHT, axis=0)
    out = np.full((BAR_HEIGHT + TEXT_HEIGHT + margin, width, 3), 255, np.uint8)
    out[margin // 2: margin // 2 + BAR_HEIGHT, margin: margin + strip.shape[1]] = colorize(strip, low, high)
    font, scale, baseline = cv2.FONT_HERSHEY_SIMPLEX, 0.38, out.shape[0] - 5
    left, right = f"{low:.3g}", f"{high:.3g}"
    right_width = cv2.getTextSize(right, font, scale, 1)[0][0]
    label_width = cv2.getTextSize(label, font, scale, 1)[0][0]
    for text, x in ((left, margin), (right, width - margin - right_width)):
        cv2.putText(out, text, (x, baseline), font, scale, (0, 0, 0), 1, cv2.LINE_AA)
    free = width - 2 * margin - right_width - cv2.getTextSize(left, font, scale, 1)[0][0]
    if label_width + 8 <= free:  # the label between the two values, where it fits
        cv2.putText(out, label, ((width - label_width) // 2, baseline), font, scale, (90, 90, 90), 1, cv2.LINE_AA)
    return out


def colour_preview(values, low, high, label, zoom=1):
    """``values`` coloured (:func:`colorize`), enlarged ``zoom`` times, with a :func:`colorbar` under it.

    Returns
    -------
    ndarray, shape (zoom * Y + bar height, zoom * X, 3), uint8

    Examples
    --------
    >>> colour_preview(np.zeros((20, 30)), -1.0, 1.0, "disparity", zoom=2).shape
    (70, 60, 3)
    """
    pixels = colorize(values, low, high)
    pixels = np.repeat(np.repeat(pixels, zoom, axis=0), zoom, axis=1)
    return np.concatenate([pixels, colorbar(pixels.shape[1], low, high, label)])
