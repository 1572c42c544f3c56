"""Dark subtraction, division by the white image, and what a real sensor adds: clipping, bad frames.

``(raw - dark) / (white - dark)`` undoes the vignetting of the main lens and
the fall-off under every microlens; the white image relative to its bright
level is each sample's validity (weight), and pixels below ``min_weight``
are dropped. A Bayer mosaic is divided channel by channel and demosaiced
afterwards, so the lens rims do not leak colour into the views. With the
microlens grid (as the decoder has it) the demosaicing stays inside each
lens and uses lit pixels only (:mod:`.lens_demosaicing`). Without it,
OpenCV's edge-aware method is used, and every dropped pixel of the mosaic
first takes the validity-weighted mean of its lit neighbours of the same
colour (two pixels away): that demosaicing interpolates each colour from
pixels around, and zeros in the gaps between microlenses would darken the
views at the lens rims (by up to 13 % in the red and blue of a rectangular
grid's diagonal views). The dropped pixels keep weight 0.

Saturation
----------
A sensor clips bright light at its full well. A clipped raw value ``S`` becomes
``(S - dark) / (white - dark)`` after the division, which differs from view
to view with the white image under each lens (a clipped sky is 1.15 in the
centre of a lens and 1.6 in a vignetted corner view): disagreement between
views that is not in the scene, and that the aliasing detector would flag.
Every value at or above the level a clipped sample has where the white
image is brightest, ``ceiling = (S - dark) / bright``, channel by channel,
is therefore set to that ceiling: it is all the capture can say about that
light ("at least this bright") in every view, so clipped views agree. Those
samples are marked: their validity is multiplied by
:data:`CLIPPED_WEIGHT`, so wherever unclipped views see the same point
they count more. ``S`` is the capture's maximum when it is a plateau (at
least 16 pixels, and one in 100 000, sit exactly on it: a sensor clips to
one code value); ``saturation=`` gives it explicitly (raw units, before
the dark frame) or turns it off (``saturation=False``).

Bad frames
----------
A dark frame that leaves nothing of the capture (the capture itself, by
mistake) is a :class:`~napari_lfalias.errors.DarkFrameError`; a colour
white image for a grey capture, and NaN or infinite pixels in any frame,
are :class:`~napari_lfalias.errors.WhiteImageError` /
:class:`~napari_lfalias.errors.DecodeError`, each naming the file.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ..errors import CalibrationError, DarkFrameError, DecodeError, ParameterError, WhiteImageError

__all__ = ["devignette", "divide_by_white", "channel_levels", "saturation_level", "check_frames", "check_finite",
           "CLIPPED_WEIGHT"]

#: Validity factor of a clipped sample (its value is a lower bound).
CLIPPED_WEIGHT = 0.5
#: The white level is this percentile of the white image (robust to hot pixels).
WHITE_PERCENTILE = 99.5
#: A clipping plateau holds at least this many pixels, and this fraction of them.
_PLATEAU = (16, 1e-5)
#: Pixels looked at for the white image's percentile (an even subsample of large sensors).
_PERCENTILE_SAMPLES = 1 << 18


def _frame(image):
    """The frame's data as float32 ``(H, W, C)`` (a view, never a copy of a user's array unless needed)."""
    data = np.asarray(image.data, np.float32)
    return data[..., None] if data.ndim == 2 else data


def check_finite(image, what):
    """A :class:`~napari_lfalias.errors.WhiteImageError` (white) or DecodeError naming the frame with NaN/Inf pixels."""
    data = np.asarray(image.data)
    total = float(np.sum(data, dtype=np.float64))
    if np.isfinite(total):
        return
    bad = int(np.count_nonzero(~np.isfinite(data)))
    error = WhiteImageError if what == "white" else DecodeError
    raise error(
        f"{what}={image.label()}: {bad} pixel(s) are NaN or infinite; a {_NAMES[what]} must hold finite "
        "numbers: repair or replace the file"
    )


_NAMES = {"raw": "lenslet capture", "white": "white image", "dark": "dark frame"}


def check_frames(raw, white, dark):
    """Named errors for frames that cannot go together (before any pixel work).

    Raises
    ------
    WhiteImageError
        A colour white image for a grey (or Bayer mosaic) capture, or a
        white image with NaN/Inf pixels.
    DecodeError
        NaN/Inf pixels in the capture or the dark frame.
    """
    if white is not None:
        if white.data.ndim == 3 and raw.data.ndim == 2:
            kind = f"a Bayer mosaic ({raw.bayer})" if raw.bayer else "grey"
            raise WhiteImageError(
                f"white={white.label()}: a colour (H, W, 3) white image for the {kind} capture {raw.label()}; "
                "the white image must be recorded like the capture (the same camera mode and file type): "
                "use the camera's raw white image, or convert this one to grey"
            )
        check_finite(white, "white")
    check_finite(raw, "raw")
    if dark is not None:
        check_finite(dark, "dark")


def _sample(plane):
    """An even subsample (a strided view) of a 2-D plane, about :data:`_PERCENTILE_SAMPLES` values."""
    step = max(1, int(np.sqrt(plane.size / _PERCENTILE_SAMPLES)))
    return plane[::step, ::step]


def channel_levels(white, dark, bayer):
    """Bright level (99.5th percentile) of each colour channel of ``white - dark``: (3,) or (1,).

    A Bayer mosaic (``bayer``) gives its R, G and B pixels' levels, a colour
    image its channels', a grey image one level. Measured on an even
    subsample.
    """
    from .bayer import channel_index

    data = _frame(white)
    dark_data = None if dark is None else _frame(dark)

    def plane(rows, cols, c):
        values = _sample(data[rows, cols, c]).astype(np.float64)
        if dark_data is not None:
            values -= _sample(dark_data[rows, cols, min(c, dark_data.shape[2] - 1)])
        return values.ravel()

    if data.shape[2] == 1 and bayer is not None:
        tile = channel_index(bayer, (2, 2))
        return np.array([np.percentile(np.concatenate([plane(slice(r, None, 2), slice(c, None, 2), 0)
                                                       for r, c in zip(*np.nonzero(tile == k))]), WHITE_PERCENTILE)
                         for k in range(3)])
    return np.array([np.percentile(plane(slice(None), slice(None), c), WHITE_PERCENTILE)
                     for c in range(data.shape[2])])


def saturation_level(raw, saturation="auto"):
    """The raw clipping level ``S`` (raw units), or ``None`` when nothing is clipped.

    Examples
    --------
    >>> from napari_lfalias.decoders.sensor import as_sensor_image
    >>> image = np.linspace(0, 2, 10000, dtype=np.float32).reshape(100, 100)
    >>> saturation_level(as_sensor_image(np.minimum(image, 1.5)))
    1.5
    >>> saturation_level(as_sensor_image(image)) is None
    True
    """
    if saturation is False or saturation is None:
        return None
    if saturation != "auto":
        if isinstance(saturation, bool) or not isinstance(saturation, (int, float)) or not np.isfinite(saturation) \
                or saturation <= 0:
            raise ParameterError(
                f"saturation must be 'auto', False or the raw clipping level (a positive number), got {saturation!r}"
            )
        return float(saturation)
    data = np.asarray(raw.data)
    top = float(data.max())
    count = int(np.count_nonzero(data == top))
    if top > 0 and count >= max(_PLATEAU[0], _PLATEAU[1] * data.size):
        return top
    return None


@njit(cache=True, parallel=True)
def _divide(raw, white, dark, has_dark, tile, is_mosaic, levels, min_weight, ceiling, clip_at,
            out, valid, clipped, positive, row_max):
    """One pass: the ratio ``(raw - dark) / (white - dark)``, the validity, the clipped pixels.

    Channel ``k`` of a pixel (its Bayer colour, or its own channel) has the
    white level ``levels[k]``: validity is ``(white - dark) / levels[k]`` in
    [0, 1] (a colour pixel's is its channels' mean), 0 below ``min_weight``,
    where the ratio is 0 too.
    """
    height, width, n_in = raw.shape
    n_white = white.shape[2]
    n_dark = dark.shape[2]
    for y in prange(height):
        count = 0
        top = 0.0
        for x in range(width):
            hit = False
            weight = 0.0
            for c in range(n_in):
                k = tile[y & 1, x & 1] if is_mosaic else c
                d = 0.0
                if has_dark:
                    if n_dark == n_in:
                        d = dark[y, x, c]
                    else:
                        for j in range(n_dark):
                            d += dark[y, x, j]
                        d /= n_dark
                level = white[y, x, min(c, n_white - 1)] - d
                relative = min(level / levels[k], 1.0)
                signal = raw[y, x, c] - d
                value = 0.0
                if relative >= min_weight:
                    value = max(signal / level, 0.0)
                    weight += relative
                    if signal > 0.0:
                        count += 1
                if raw[y, x, c] >= clip_at or value >= ceiling[k]:
                    value = ceiling[k]
                    hit = True
                out[y, x, c] = value
                top = max(top, value)
            weight /= n_in
            valid[y, x] = weight if weight >= min_weight else 0.0
            clipped[y, x] = hit
        positive[y] = count
        row_max[y] = top


@njit(cache=True, parallel=True)
def _fill_dropped(mosaic, valid):
    """In place: every pixel of weight 0 gets the weighted mean of its same-colour neighbours of weight > 0.

    The neighbours are the eight at offsets of 0 or 2 on each axis (same
    Bayer colour); a pixel none of which is lit keeps its value. Only
    dropped pixels are written and only lit ones read, so rows run in parallel.
    """
    height, width = mosaic.shape
    for y in prange(height):
        for x in range(width):
            if valid[y, x] > 0.0:
                continue
            total = 0.0
            weight = 0.0
            for dy in (-2, 0, 2):
                yy = y + dy
                if yy < 0 or yy >= height:
                    continue
                for dx in (-2, 0, 2):
                    xx = x + dx
                    if xx < 0 or xx >= width:
                        continue
                    w = valid[yy, xx]
                    if w > 0.0:
                        total += w * mosaic[yy, xx]
                        weight += w
            if weight > 0.0:
                mosaic[y, x] = total / weight


@njit(cache=True, parallel=True)
def _clamp_channels(image, limits):
    """In place: channel ``c`` of every pixel at most ``limits[c]``."""
    for y in prange(image.shape[0]):
        for x in range(image.shape[1]):
            for c in range(image.shape[2]):
                if image[y, x, c] > limits[c]:
                    image[y, x, c] = limits[c]


def divide_by_white(raw, white=None, dark=None, min_weight=0.05, saturation="auto", grid=None):
    """:func:`devignette`, with a demosaiced Bayer image kept in 16 bits: ``(image, valid, scale)``.

    With the capture's microlens ``grid`` a Bayer mosaic is demosaiced lens
    by lens (:func:`.lens_demosaicing.demosaic_in_lenses`: no colour from
    the neighbouring lens); without it, by OpenCV.

    ``image * scale`` is the ratio; ``image`` is float32 (``scale`` 1) for
    grey and colour captures, and the 16-bit output of the demosaicing for
    a Bayer mosaic (half the memory of float32 on a large sensor, and one
    pass fewer; the slicing reads it as it is).
    """
    from .bayer import channel_index, demosaic16
    from .lens_demosaicing import demosaic_in_lenses

    check_frames(raw, white, dark)
    signal = _frame(raw)
    height, width, n_in = signal.shape
    mosaic = raw.bayer is not None and n_in == 1
    n_levels = 3 if mosaic else n_in
    clip = saturation_level(raw, saturation)
    if white is None:
        white_data = np.broadcast_to(np.ones((1, 1, 1), np.float32), (height, width, 1))
        levels, floor = np.ones(n_levels), 0.0
    else:
        white_data = _frame(white)
        levels = channel_levels(white, dark, raw.bayer if mosaic else None)
        if not np.all(levels > 0):
            raise CalibrationError(f"{white.label()}: the white image is dark everywhere (after the dark frame)")
        if len(levels) != n_levels:  # a grey white image for a colour capture
            levels = np.full(n_levels, levels.mean())
        floor = min_weight
    dark_data = np.zeros((1, 1, 1), np.float32) if dark is None else _frame(dark)
    ceiling = np.full(n_levels, np.inf)
    if clip is not None:
        dark_level = 0.0 if dark is None else float(np.median(_sample(dark_data[..., 0])))
        ceiling = (clip - dark_level) / np.maximum(levels, 1e-12)
    tile = channel_index(raw.bayer, (2, 2)).astype(np.int64) if mosaic else np.zeros((2, 2), np.int64)
    ratio = np.empty(signal.shape, np.float32)
    valid = np.empty((height, width), np.float32)
    clipped = np.empty((height, width), np.bool_)
    positive = np.empty(height, np.int64)
    row_max = np.empty(height, np.float64)
    _divide(signal, white_data, dark_data, dark is not None, tile, mosaic, np.asarray(levels, np.float64),
            float(floor), np.asarray(ceiling, np.float64), np.inf if clip is None else clip,
            ratio, valid, clipped, positive, row_max)
    if dark is not None and positive.sum() == 0:
        raise DarkFrameError(
            f"dark={dark.label()}: subtracting it from the capture {raw.label()} leaves nothing (no lit pixel "
            "is brighter than the dark frame): is it the capture itself? Pass the frame recorded with the lens "
            "capped, or no dark frame"
        )
    scale = 1.0
    if mosaic:
        # both before clipped samples' weights are lowered: they are lit
        if grid is not None:
            image, scale = demosaic_in_lenses(ratio[..., 0], valid, raw.bayer, grid, float(row_max.max()))
        else:
            if white is not None:
                _fill_dropped(ratio[..., 0], valid)
            image, scale = demosaic16(ratio[..., 0], raw.bayer, float(row_max.max()))
        del ratio
        if clip is not None:  # the demosaicing may overshoot the ceiling
            _clamp_channels(image, np.floor(ceiling / scale + 0.5).astype(np.float64))
            clipped = _dilate(clipped)
    else:
        image = ratio
    if clip is not None:
        valid[clipped] *= np.float32(CLIPPED_WEIGHT)
    return image, valid, scale


def devignette(raw, white=None, dark=None, min_weight=0.05, saturation="auto"):
    """Dark-subtract and divide by the white image; clip saturated light; demosaic a Bayer mosaic afterwards.

    Parameters
    ----------
    raw, white, dark : SensorImage
        The capture, its white image (or ``None``: no devignetting), and an
        optional dark frame, all of one size.
    min_weight : float
        Pixels whose white level is below this fraction of their channel's
        bright level are dropped (value and weight 0).
    saturation : "auto", float or False
        Raw clipping level (see the module notes).

    Returns
    -------
    image : ndarray, shape (H, W, C), float32
        ``(raw - dark) / (white - dark)``, negative values clipped to 0,
        clipped light set to the ceiling.
    valid : ndarray, shape (H, W), float32
        ``(white - dark)`` relative to its channel's white level (99.5th
        percentile), clipped to [0, 1], times :data:`CLIPPED_WEIGHT` where
        the capture is clipped.

    Raises
    ------
    DarkFrameError
        If the dark frame leaves nothing of the capture.
    WhiteImageError, DecodeError
        See :func:`check_frames`.

    Examples
    --------
    >>> from napari_lfalias.decoders.sensor import as_sensor_image
    >>> white = as_sensor_image(np.array([[0.8, 0.4], [0.01, 0.8]], np.float32))
    >>> raw = as_sensor_image(np.array([[0.4, 0.1], [0.01, 0.8]], np.float32))
    >>> image, valid = devignette(raw, white)
    >>> image[..., 0].round(2).tolist(), valid.round(2).tolist()
    ([[0.5, 0.25], [0.0, 1.0]], [[1.0, 0.5], [0.0, 1.0]])
    """
    image, valid, scale = divide_by_white(raw, white, dark, min_weight, saturation)
    if image.dtype != np.float32:
        image = np.multiply(image, np.float32(scale), dtype=np.float32)
    return image, valid


def _dilate(mask):
    """A 3 x 3 dilation (the demosaic spreads each clipped pixel to its neighbours)."""
    import cv2

    return cv2.dilate(mask.view(np.uint8), np.ones((3, 3), np.uint8)).view(np.bool_)
