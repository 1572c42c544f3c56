"""Lenslet (plenoptic) captures to a :class:`~napari_lfalias.LightField`.

The steps, after Dansereau's LFToolbox (``LFDecodeLensletImageSimple``),
with one resampling instead of its three:

1. read the raw, white and dark images (:mod:`.sensor`);
2. fit the microlens grid to the white image unless a grid is given
   (:func:`~.calibration.calibrate`);
3. subtract the dark frame and divide by the white image (devignetting);
   the white image, relative to its bright level, is each pixel's
   validity weight, and pixels below ``min_weight`` are dropped; a Bayer
   mosaic is demosaiced after this division (OpenCV edge-aware), so the
   lens rims do not leak colour into the views;
4. slice (:mod:`.slicing`): every microlens is a pixel of every view, every
   pixel under a microlens a view, rotation removed and hexagonal rows
   resampled to square pixels in the same interpolation.

Sign convention of the view positions
-------------------------------------
View ``(u, v)`` samples each microlens at offset
``positions[u, v] * step`` pixels from its centre (``step`` = 1 px: one
view per sensor pixel), along the grid's axes in the image's orientation
(y down, x right). Because the microlens images the main-lens aperture
upside down, and the sensor's readout turns the main lens' image upright,
this offset *is* the position on the aperture in the image's axes: a
lenslet light field follows DESIGN section 2 like a camera array does.
Points on the plane imaged onto the microlenses have disparity 0; points
nearer the camera have ``d < 0`` and farther ones ``d > 0`` (nearer is
more negative, as in a camera array), and ``refocus(lf, d)`` brings the
points of disparity ``d`` into focus. The synthetic round trip
(``tests/test_lenslet_roundtrip.py``) checks the sign with a scene of known
disparity.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .. import _validate
from ..errors import CalibrationError, DecodeError, ParameterError
from ..lightfield import LightField, regular_positions
from .calibration import calibrate
from .grid import GridModel
from .sensor import as_sensor_image, read_sensor

__all__ = ["calibrate", "GridModel", "load_lenslet", "decode_lenslet", "devignette"]

_OPTIONS = ("bayer", "n_views", "outside", "min_weight", "trim", "kind", "pitch")
#: The white level is this percentile of the white image (robust to hot pixels).
_WHITE_PERCENTILE = 99.5


def _check_same_size(image, reference, what):
    if image.shape != reference.shape:
        raise DecodeError(
            f"{image.label()}: the {what} is {image.shape[1]} x {image.shape[0]} px but the capture "
            f"{reference.label()} is {reference.shape[1]} x {reference.shape[0]} px; use frames taken with the "
            "same camera settings and size"
        )


def _needs_white(label):
    return DecodeError(
        f"{label}: a lenslet capture needs a white image of the lenslet array to find the lenses and "
        "devignette: pass white=... (lfalias: --white), or grid=... from an earlier calibration"
    )


def _grey(data):
    return data.mean(axis=-1) if data.ndim == 3 else data


def devignette(raw, white=None, dark=None, min_weight=0.05):
    """Dark-subtract and divide by the white image; demosaic a Bayer mosaic afterwards.

    Parameters
    ----------
    raw, white, dark : SensorImage
        The capture, its white image (or ``None``: no devignetting), and an
        optional dark frame, all of one size.
    min_weight : float
        Pixels whose white level is below this fraction of the bright
        level are dropped (value and weight 0).

    Returns
    -------
    image : ndarray, shape (H, W, C), float32
        ``(raw - dark) / (white - dark)``, negative values clipped to 0.
    valid : ndarray, shape (H, W), float32
        ``(white - dark)`` relative to the white level, clipped to [0, 1].

    Examples
    --------
    >>> import numpy as np
    >>> from napari_lfalias.decoders.sensor import as_sensor_image
    >>> white = as_sensor_image(np.array([[0.8, 0.4], [0.01, 0.8]], np.float32))
    >>> raw = as_sensor_image(np.array([[0.4, 0.1], [0.01, 0.8]], np.float32))
    >>> image, valid = devignette(raw, white)
    >>> image[..., 0].round(2).tolist(), valid.round(2).tolist()
    ([[0.5, 0.25], [0.0, 1.0]], [[1.0, 0.5], [0.0, 1.0]])
    """
    from .bayer import cfa_grey, demosaic

    signal = np.asarray(raw.data, np.float32)
    dark_data = None if dark is None else np.asarray(dark.data, np.float32)
    if dark_data is not None:
        if dark_data.ndim == 3 and signal.ndim == 2:
            dark_data = dark_data.mean(axis=-1)
        signal = signal - (dark_data if dark_data.ndim == signal.ndim else dark_data[..., None])
    if white is None:
        valid = np.ones(signal.shape[:2], np.float32)
        ratio = np.clip(signal, 0.0, None)
    else:
        level = np.asarray(white.data, np.float32)
        if dark_data is not None:
            level = level - (dark_data if dark_data.ndim == level.ndim else
                             (dark_data.mean(axis=-1) if dark_data.ndim == 3 else dark_data[..., None]))
        grey_level = cfa_grey(level) if (white.bayer is not None and level.ndim == 2) else _grey(level)
        bright = float(np.percentile(grey_level, _WHITE_PERCENTILE))
        if not bright > 0:
            raise CalibrationError(f"{white.label()}: the white image is dark everywhere (after the dark frame)")
        valid = np.clip(grey_level / bright, 0.0, 1.0).astype(np.float32)
        valid[valid < min_weight] = 0.0
        if level.ndim == 2 and signal.ndim == 3:
            level = level[..., None]
        floor = np.float32(min_weight * bright)
        ratio = np.where(level > floor, signal / np.maximum(level, floor), np.float32(0.0))
        ratio = np.clip(ratio, 0.0, None)
    if raw.bayer is not None and ratio.ndim == 2:
        ratio = demosaic(ratio, raw.bayer)
    if ratio.ndim == 2:
        ratio = ratio[..., None]
    return np.ascontiguousarray(ratio, np.float32), np.ascontiguousarray(valid, np.float32)


def _view_count(grid, n_views, outside):
    radius = grid.pitch / 2.0
    if n_views is not None:
        return _validate.integer_at_least("n_views", n_views, 1)
    if outside == "crop":
        half = int(math.floor(radius / math.sqrt(2.0) + 1e-9))
    else:
        half = int(math.floor(radius - 1e-9))
    return 2 * max(half, 0) + 1


def _trim_window(weights, min_weight):
    """Bounding box (y0, y1, x0, x1) of the output pixels that any view sees with weight >= min_weight."""
    seen = weights.max(axis=(0, 1)) >= min_weight
    rows, cols = np.nonzero(seen.any(axis=1))[0], np.nonzero(seen.any(axis=0))[0]
    if rows.size == 0:
        return None
    return int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1


def _as_grid(grid, shape, label):
    if grid is None:
        return None
    if isinstance(grid, (str, Path)) and Path(grid).suffix.lower() == ".json":
        from .._inputs import read_grid

        grid = read_grid(grid)
    elif isinstance(grid, str):
        grid = GridModel.from_json(grid)
    elif isinstance(grid, dict):
        grid = GridModel.from_dict(grid)
    if not isinstance(grid, GridModel):
        raise ParameterError(
            f"grid must be a lenslet GridModel (or its JSON), got {type(grid).__name__}; "
            "grid=(U, V) applies to folders of views only"
        )
    if tuple(grid.image_shape) != tuple(shape):
        raise CalibrationError(
            f"{label}: the grid model was fitted on a {grid.image_shape[1]} x {grid.image_shape[0]} px image, "
            f"the capture is {shape[1]} x {shape[0]} px; calibrate again on this camera's white image"
        )
    return grid


def decode_lenslet(raw, white=None, dark=None, grid=None, *, bayer=None, n_views=None, outside="weight",
                   min_weight=0.05, trim=True, kind="auto", pitch=None):
    """Decode a lenslet image into a 4-D light field.

    Parameters
    ----------
    raw : str, Path, ndarray or SensorImage
        The lenslet capture: ``(H, W)`` grey or Bayer mosaic, or
        ``(H, W, 3)`` colour. Arrays are read, never modified.
    white : str, Path, ndarray or SensorImage, optional
        White image of the same size: devignetting, validity weights and
        (without ``grid``) calibration. Needed unless ``grid`` is given.
    dark : str, Path, ndarray or SensorImage, optional
        Dark frame subtracted from ``raw`` and ``white``.
    grid : GridModel or str, optional
        A calibrated grid (or its JSON text or ``.json`` file); default:
        :func:`calibrate` on ``white``.
    bayer : str, optional
        Bayer layout of grey mosaic files/arrays (``"RGGB"``, ...); camera
        raw and Lytro files carry their own.
    n_views : int, optional
        Views per side; default: every whole pixel within the lens disc,
        ``2 * floor(pitch / 2) + 1`` (``outside="weight"``).
    outside : {"weight", "crop"}
        Views whose sample lies outside the microlens disc (radius
        ``pitch / 2``) are kept with weight 0 (``"weight"``), or the view
        grid is cropped to the largest square inside the disc (``"crop"``).
    min_weight : float
        Samples whose white level is below this fraction of the bright
        level get weight 0.
    trim : bool
        Drop border rows and columns of lenses that no view sees (dark
        borders, lenses off the sensor).
    kind, pitch
        Passed to :func:`calibrate` when ``grid`` is not given.

    Returns
    -------
    LightField
        ``data`` (U, V, Y, X, C) float32 relative to the white image,
        ``weights`` the validity of every sample, ``positions`` as in the
        module notes; ``meta["grid"]`` is the GridModel, ``meta["view_step_px"]``
        the pixels between views, ``meta["lens_window"]`` the rows and
        columns of the grid's output kept by ``trim``.

    Raises
    ------
    DecodeError
        Unreadable files, or frames of different sizes (the message names
        the file).
    CalibrationError
        No lens grid in the white image, or a grid fitted on another size.

    Examples
    --------
    >>> from napari_lfalias.synthetic import render_lenslet, textured_plane
    >>> capture = render_lenslet(textured_plane(n_views=1, size=64), shape=(160, 160), pitch=9.3)
    >>> lf = decode_lenslet(capture.raw, capture.white)
    >>> lf.grid_shape, lf.meta["grid"].kind
    ((9, 9), 'rectangular')
    """
    _validate.one_of("outside", outside, ("weight", "crop"))
    min_weight = _validate.in_open_interval("min_weight", min_weight, 0.0, 1.0)
    raw_image = as_sensor_image(raw, bayer=bayer, name="raw")
    white_image = None if white is None else as_sensor_image(white, bayer=bayer, name="white")
    dark_image = None if dark is None else as_sensor_image(dark, name="dark")
    label = raw_image.label()
    if white_image is None and grid is None:
        raise _needs_white(label)
    for image, what in ((white_image, "white image"), (dark_image, "dark frame")):
        if image is not None:
            _check_same_size(image, raw_image, what)
    model = _as_grid(grid, raw_image.shape, label)
    if model is None:
        model = calibrate(white_image, dark_image, kind=kind, pitch=pitch)
    image, valid = devignette(raw_image, white_image, dark_image, min_weight)
    if model.transposed:
        image, valid = np.ascontiguousarray(image.transpose(1, 0, 2)), np.ascontiguousarray(valid.T)
    count = _view_count(model, n_views, outside)
    q = np.arange(count) - (count - 1) / 2.0
    view_on = np.hypot(q[:, None], q[None, :]) <= model.pitch / 2.0
    from .slicing import slice_views

    data, weights = slice_views(image, valid, model, count, view_on)
    if model.transposed:
        data, weights = data.transpose(1, 0, 3, 2, 4), weights.transpose(1, 0, 3, 2)
    window = (0, data.shape[2], 0, data.shape[3])
    if trim:
        window = _trim_window(weights, min_weight)
        if window is None:
            raise DecodeError(f"{label}: no lens of the grid is lit in the white image; nothing to decode")
        y0, y1, x0, x1 = window
        data, weights = data[:, :, y0:y1, x0:x1], weights[:, :, y0:y1, x0:x1]
    weights = np.where(weights >= min_weight, weights, np.float32(0.0))
    data = np.ascontiguousarray(np.where(weights[..., None] > 0, data, np.float32(0.0)))
    meta = {
        "source": raw_image.label(),
        "format": f"lenslet {raw_image.format}" + (f", Bayer {raw_image.bayer}" if raw_image.bayer else ""),
        "grid": model,
        "view_step_px": 1.0,
        "lens_window": list(window),
        "white": None if white_image is None else white_image.label(),
        "dark": None if dark_image is None else dark_image.label(),
    }
    if raw_image.meta:
        meta["sensor"] = dict(raw_image.meta)
    return LightField(data, regular_positions(count, count), meta, weights=np.ascontiguousarray(weights))


def load_lenslet(path, white=None, dark=None, grid=None, **options):
    """Read and decode a lenslet capture file (``lfa.load`` calls this for image files).

    Parameters
    ----------
    path : str or Path
        The raw lenslet image: TIFF, PNG, camera raw / DNG, Lytro LFR/LFP/RAW.
    white, dark : str, Path, ndarray or SensorImage, optional
        White image and dark frame (see :func:`decode_lenslet`).
    grid : GridModel, str or Path, optional
        A saved grid model (object, JSON text or ``.json`` file).
    **options
        ``bayer``, ``n_views``, ``outside``, ``min_weight``, ``trim``,
        ``kind``, ``pitch`` of :func:`decode_lenslet`.

    Returns
    -------
    LightField

    Raises
    ------
    DecodeError, CalibrationError, ParameterError
        Naming the file or option at fault.

    Examples
    --------
    >>> import tempfile, os
    >>> from napari_lfalias.synthetic import render_lenslet, textured_plane
    >>> folder = tempfile.mkdtemp()
    >>> files = render_lenslet(textured_plane(n_views=1, size=64), shape=(160, 160), pitch=9.3).write(folder)
    >>> lf = load_lenslet(files["raw"], white=files["white"])
    >>> lf.meta["format"]
    'lenslet TIFF'
    """
    unknown = sorted(set(options) - set(_OPTIONS))
    if unknown:
        raise ParameterError(
            f"unknown option(s) for a lenslet capture: {', '.join(unknown)}; accepted: {', '.join(_OPTIONS)}"
        )
    bayer = options.pop("bayer", None)
    raw = read_sensor(path, bayer=bayer)
    if white is None and grid is None:
        raise _needs_white(path)
    white_image = None if white is None else as_sensor_image(white, bayer=bayer, name="white")
    dark_image = None if dark is None else as_sensor_image(dark, name="dark")
    return decode_lenslet(raw, white_image, dark_image, grid, **options)

