"""Lenslet (plenoptic) captures to a :class:`~napari_lfalias.LightField`.

The steps, after Dansereau's LFToolbox (``LFDecodeLensletImageSimple``),
with one resampling instead of its three:

1. read the raw, white and dark images (:mod:`.sensor`); ``white=`` may be a
   folder of white images, one chosen by the capture's zoom and focus
   (:mod:`.white_images`);
2. fit the microlens grid to the white image unless a grid is given
   (:func:`~.calibration.calibrate`; cached per white image of a folder);
3. subtract the dark frame and divide by the white image, clipping
   saturated light so that every view agrees on it (:mod:`.devignetting`);
   the white image, relative to its bright level, is each pixel's validity
   weight, and pixels below ``min_weight`` are dropped; a Bayer mosaic is
   demosaiced after this division, lens by lens with the grid
   (:mod:`.lens_demosaicing`), so neither the lens rims nor the neighbouring
   lens leak colour into the views;
4. slice (:mod:`.slicing`): every microlens is a pixel of every view, every
   pixel under a microlens a view, rotation removed and hexagonal rows
   resampled to square pixels in the same interpolation; only the output
   pixels some view sees are computed (``trim``).

:func:`decode_steps` is the same work as a generator that says which step
comes next (the napari widget shows it); ``progress=`` of
:func:`decode_lenslet` and :func:`load_lenslet` is called with the same
``(done, total, step)`` (the command line prints it).

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

So a decoded light field declares its occlusion order,
``meta["nearer"] = "smaller"`` (:func:`~napari_lfalias.depth_guided.occlusion_order`),
and every rendering of it puts the smaller disparity in front. This holds
for every plenoptic camera whose microlenses sit at the main lens' image
plane, whatever way its sensor is read out: a point nearer than the plane
in focus converges behind the microlenses, so the ray from aperture
position ``a`` crosses them ``k a`` from where the central ray does
(``k > 0``), while the microlens images aperture position ``a`` at pixel
offset ``-c a`` (``c > 0``: a lens inverts). The point therefore moves
``-(k / c)`` times the offset: ``d < 0``. A rotation or mirror of the
sensor's readout turns the move and the offset alike, so their ratio keeps
its sign.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .. import _validate
from ..errors import CalibrationError, DecodeError, ParameterError
from ..lightfield import LightField, regular_positions
from .calibration import calibrate
from .devignetting import devignette, divide_by_white
from .grid import GridModel
from .sensor import as_sensor_image, read_sensor

__all__ = ["calibrate", "GridModel", "load_lenslet", "decode_lenslet", "decode_steps", "load_lenslet_steps",
           "devignette"]

_OPTIONS = ("bayer", "n_views", "outside", "min_weight", "trim", "kind", "pitch", "saturation", "progress")
#: Blocks of lens rows the slicing is split into (one progress step each).
_SLICE_BLOCKS = 8


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


def _view_count(grid, n_views, outside):
    radius = grid.pitch / 2.0
    if n_views is not None:
        return _validate.integer_at_least("n_views", n_views, 1)
    if outside == "crop":
        half = int(math.floor(radius / math.sqrt(2.0) + 1e-9))
    else:
        half = int(math.floor(radius - 1e-9))
    return 2 * max(half, 0) + 1


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


def _is_white_folder(white):
    from .white_images import WhiteImageFolder

    return isinstance(white, WhiteImageFolder) or (isinstance(white, (str, Path)) and Path(white).is_dir())


def _white_from_folder(white, raw_image, dark_image, grid, bayer, calibrate_options):
    """The white image a folder holds for this capture, its grid (cached) unless one is given, and the choice."""
    from .white_images import WhiteImageFolder, capture_settings

    folder = white if isinstance(white, WhiteImageFolder) else WhiteImageFolder(white)
    choice = folder.choose(capture_settings(raw_image), raw_image.label())
    white_image = as_sensor_image(choice.path, bayer=bayer, name="white")
    _check_same_size(white_image, raw_image, "white image")
    if grid is None:
        grid = folder.grid(choice, calibrate_options, dark_image, white_image)
    return white_image, grid, choice


def _run(steps, progress):
    """Drive a step generator, reporting ``(done, total, step)`` to ``progress``; returns its result."""
    while True:
        try:
            step = next(steps)
        except StopIteration as stop:
            return stop.value
        if progress is not None:
            progress(*step)


def decode_steps(raw, white=None, dark=None, grid=None, *, bayer=None, n_views=None, outside="weight",
                 min_weight=0.05, trim=True, kind="auto", pitch=None, saturation="auto"):
    """:func:`decode_lenslet` as a generator: yields ``(done, total, step)`` before each step, returns the LightField.

    Examples
    --------
    >>> from napari_lfalias.synthetic import render_lenslet, textured_plane
    >>> capture = render_lenslet(textured_plane(n_views=1, size=64), shape=(160, 160), pitch=9.3)
    >>> steps = decode_steps(capture.raw, capture.white)
    >>> next(steps)
    (0, 11, 'calibrating the microlens grid')
    """
    _validate.one_of("outside", outside, ("weight", "crop"))
    min_weight = _validate.in_open_interval("min_weight", min_weight, 0.0, 1.0)
    trim = _validate.boolean("trim", trim)
    raw_image = as_sensor_image(raw, bayer=bayer, name="raw")
    dark_image = None if dark is None else as_sensor_image(dark, name="dark")
    label = raw_image.label()
    if white is None and grid is None:
        raise _needs_white(label)
    if dark_image is not None:
        _check_same_size(dark_image, raw_image, "dark frame")
    model = _as_grid(grid, raw_image.shape, label)
    options = {"kind": kind, "pitch": pitch, "bayer": bayer}
    choice = None
    total = 2 + _SLICE_BLOCKS + (1 if model is None else 0)
    done = 0
    if white is not None and _is_white_folder(white):
        yield done, total, "choosing the white image" + (" and fitting its grid" if model is None else "")
        done += 1 if model is None else 0  # the step counted for the calibration
        white_image, model, choice = _white_from_folder(white, raw_image, dark_image, model, bayer, options)
    else:
        white_image = None if white is None else as_sensor_image(white, bayer=bayer, name="white")
        if white_image is not None:
            _check_same_size(white_image, raw_image, "white image")
    if model is None:
        yield done, total, "calibrating the microlens grid"
        done += 1
        model = calibrate(white_image, dark_image, **options)
    yield done, total, "dividing by the white image"
    done += 1
    image, valid, scale = divide_by_white(raw_image, white_image, dark_image, min_weight, saturation, model)
    count = _view_count(model, n_views, outside)
    q = np.arange(count) - (count - 1) / 2.0
    view_on = np.hypot(q[:, None], q[None, :]) <= model.pitch / 2.0
    from .slicing import Slicer

    slicer = Slicer(image, valid, model, count, view_on, min_weight=min_weight, scale=scale)
    yield done, total, "finding the lenses any view sees"
    done += 1
    window = slicer.window() if trim else (0, slicer.shape[0], 0, slicer.shape[1])
    if window is None:
        raise DecodeError(f"{label}: no lens of the grid is lit in the white image; nothing to decode")
    data, weights = slicer.allocate(window)
    for block in np.array_split(np.arange(window[0], window[1]), _SLICE_BLOCKS):
        yield done, total, f"slicing views (lens rows {block[0] if block.size else window[1]}-" \
                           f"{block[-1] + 1 if block.size else window[1]} of {slicer.shape[0]})"
        done += 1
        if block.size:
            slicer.fill(window, block, data, weights)
    del image, valid, slicer
    yield done, total, "done"
    y0, y1, x0, x1 = window
    lens_window = [x0, x1, y0, y1] if model.transposed else [y0, y1, x0, x1]
    meta = {
        "source": raw_image.label(),
        "format": f"lenslet {raw_image.format}" + (f", Bayer {raw_image.bayer}" if raw_image.bayer else ""),
        "grid": model,
        "view_step_px": 1.0,
        "lens_window": lens_window,
        "nearer": "smaller",  # the optics' order (module notes)
        "white": None if white_image is None else white_image.label(),
        "dark": None if dark_image is None else dark_image.label(),
    }
    if choice is not None:
        meta["white_choice"] = {"path": str(choice.path), **choice.extra}
    if raw_image.meta:
        meta["sensor"] = dict(raw_image.meta)
    return LightField._derived(data, regular_positions(count, count), meta, weights)


def decode_lenslet(raw, white=None, dark=None, grid=None, *, bayer=None, n_views=None, outside="weight",
                   min_weight=0.05, trim=True, kind="auto", pitch=None, saturation="auto", progress=None):
    """Decode a lenslet image into a 4-D light field.

    Parameters
    ----------
    raw : str, Path, ndarray or SensorImage
        The lenslet capture: ``(H, W)`` grey or Bayer mosaic, or
        ``(H, W, 3)`` colour. Arrays are read, never modified.
    white : str, Path, ndarray, SensorImage or WhiteImageFolder, optional
        White image of the same size: devignetting, validity weights and
        (without ``grid``) calibration; or a folder of white images, from
        which the one nearest the capture's zoom and focus is chosen
        (:mod:`~napari_lfalias.decoders.white_images`). Needed unless
        ``grid`` is given.
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
    saturation : "auto", float or False
        The sensor's clipping level in raw units: clipped light is set to
        one ceiling in every view and its weight halved (see
        :mod:`~napari_lfalias.decoders.devignetting`); ``"auto"`` finds a
        clipping plateau at the capture's maximum; ``False`` turns it off.
    progress : callable, optional
        Called with ``(done, total, step)`` before each step.

    Returns
    -------
    LightField
        ``data`` (U, V, Y, X, C) float32 relative to the white image,
        ``weights`` the validity of every sample, ``positions`` as in the
        module notes; ``meta["grid"]`` is the GridModel, ``meta["view_step_px"]``
        the pixels between views, ``meta["lens_window"]`` the rows and
        columns of the grid's output kept by ``trim``, ``meta["white_choice"]``
        the white image chosen from a folder and its settings,
        ``meta["nearer"]`` the occlusion order, ``"smaller"`` (module notes).

    Raises
    ------
    DecodeError
        Unreadable files, or frames of different sizes (the message names
        the file); :class:`~napari_lfalias.errors.DarkFrameError` for a dark
        frame that leaves nothing of the capture;
        :class:`~napari_lfalias.errors.WhiteImageError` for a colour white
        image of a grey capture, NaN pixels, or a folder with no white
        image for the capture's camera.
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
    steps = decode_steps(raw, white, dark, grid, bayer=bayer, n_views=n_views, outside=outside,
                         min_weight=min_weight, trim=trim, kind=kind, pitch=pitch, saturation=saturation)
    return _run(steps, progress)


def load_lenslet_steps(path, white=None, dark=None, grid=None, **options):
    """:func:`load_lenslet` as a generator of ``(done, total, step)`` (see :func:`decode_steps`)."""
    unknown = sorted(set(options) - set(_OPTIONS) | ({"progress"} & set(options)))
    if unknown:
        raise ParameterError(
            f"unknown option(s) for a lenslet capture: {', '.join(unknown)}; accepted: {', '.join(_OPTIONS)}"
        )
    bayer = options.pop("bayer", None)
    yield 0, 1, "reading the capture"
    raw = read_sensor(path, bayer=bayer)  # first: a file that is no capture says so, white or not
    if white is None and grid is None:
        raise _needs_white(path)
    if white is not None and not _is_white_folder(white):
        white = as_sensor_image(white, bayer=bayer, name="white")
    dark_image = None if dark is None else as_sensor_image(dark, name="dark")
    return (yield from decode_steps(raw, white, dark_image, grid, bayer=bayer, **options))


def load_lenslet(path, white=None, dark=None, grid=None, **options):
    """Read and decode a lenslet capture file (``lfa.load`` calls this for image files).

    Parameters
    ----------
    path : str or Path
        The raw lenslet image: TIFF, PNG, camera raw / DNG, Lytro LFR/LFP/RAW.
    white : str, Path, ndarray or SensorImage, optional
        White image, or a folder of white images (see :func:`decode_lenslet`).
    dark : str, Path, ndarray or SensorImage, optional
        Dark frame.
    grid : GridModel, str or Path, optional
        A saved grid model (object, JSON text or ``.json`` file).
    **options
        ``bayer``, ``n_views``, ``outside``, ``min_weight``, ``trim``,
        ``kind``, ``pitch``, ``saturation``, ``progress`` of :func:`decode_lenslet`.

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
    progress = options.pop("progress", None)
    return _run(load_lenslet_steps(path, white, dark, grid, **options), progress)
