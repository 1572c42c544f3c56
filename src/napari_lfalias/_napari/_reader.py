"""napari readers: camera-array folders, lenslet captures, Lytro files, saved light fields.

Each ``get_*_reader(path)`` is called by napari for every path that matches
the manifest's patterns, so it must decide fast and say ``None`` for
anything it does not handle: it looks only at file names, sizes and
headers, never at pixel data. Decoding happens in the returned reader
function, through :func:`napari_lfalias.load`.

A lenslet capture is decoded with its calibration:

- a white image beside it (a name with ``white``, ``radiometry`` or
  ``flat``; a dark frame with ``dark`` or ``black`` is used too), of the
  capture's size;
- or a grid model saved beside it (``*grid*.json`` / ``*calib*.json``
  written by ``lfalias convert --save-grid`` or the conversion widget),
  fitted on an image of the capture's size;
- or given: the capture opened together with its white (and dark) image,
  ``viewer.open([capture, white, dark], stack=True)``.

Readers say why they cannot read something that looks like theirs: a
folder of at least four images whose names do not lay out a full grid, or
one image large enough to be a lenslet capture (a single grey or colour
plane of at least :data:`MIN_CAPTURE_SIDE` pixels a side) with no usable
calibration beside it, is claimed, and reading it fails with the
library's own message (what is missing, what to do) in GUI words, shown
as a napari notification and raised. Files that cannot be ours (tiny
images, stacks, white or dark frames themselves) are declined at once, so
napari's own readers take them.
"""

from __future__ import annotations

import contextlib
import json
import os
import struct
from pathlib import Path

from ..errors import LightFieldError
from ._layers import lightfield_layer_data

__all__ = [
    "get_saved_lightfield_reader",
    "get_camera_array_reader",
    "get_lenslet_reader",
    "get_lytro_reader",
    "find_calibration_frames",
    "find_grid_file",
    "is_camera_array_folder",
    "ReadError",
    "MIN_CAPTURE_SIDE",
    "capture_name",
]

#: Fewest views that make a folder a light field.
_MIN_VIEWS = 4
#: Smallest side, in pixels, of an image that could be a raw lenslet capture (a few lenses of a few pixels).
MIN_CAPTURE_SIDE = 64

_IMAGE_SUFFIXES = {".tif", ".tiff", ".png", ".dng"}
_LYTRO_SUFFIXES = {".lfr", ".lfp", ".raw"}
_WHITE_WORDS = ("white", "radiometry", "flatfield", "flat")
_DARK_WORDS = ("darkframe", "dark", "black")
_GRID_WORDS = ("grid", "calib")
_LYTRO_MAGIC = b"\x89LFP"
#: A grid model JSON is small; larger ``.json`` files are not read.
_GRID_MAX_BYTES = 1 << 20


def _paths(path):
    """The paths napari passes, as a list of Path."""
    if isinstance(path, (list, tuple)):
        return [Path(os.fspath(p)) for p in path]
    return [Path(os.fspath(path))]


def _single_path(path):
    """The one path napari passes, or ``None`` for a list of several paths."""
    paths = _paths(path)
    return paths[0] if len(paths) == 1 else None


# -- camera arrays ------------------------------------------------------


def is_camera_array_folder(folder):
    """True if the names in ``folder`` lay out a full grid of at least 4 views.

    Uses the decoder's own naming rules
    (:func:`napari_lfalias.decoders.view_names.find_views`: HCI
    ``input_Cam*.png``, Stanford ``out_RR_CC_y_x.png``, ``*_RR_CC.*``),
    which read names only, never pixels.
    """
    from ..decoders.view_names import find_views
    from ..errors import LightFieldError

    try:
        layout = find_views(folder)
    except (LightFieldError, OSError):
        return False
    rows, cols = layout.grid_shape
    return rows * cols >= _MIN_VIEWS


def _holds_views(folder):
    """True if ``folder`` holds at least 4 view images (names checked, never pixels)."""
    from ..decoders.images import is_image_file

    try:
        count = 0
        for entry in os.scandir(folder):
            count += entry.is_file() and is_image_file(Path(entry.name))
            if count >= _MIN_VIEWS:
                return True
    except OSError:
        return False
    return False


def get_camera_array_reader(path):
    """Reader for a folder of views (HCI ``input_Cam*.png``, Stanford ``out_*``, ``*_RR_CC.*``).

    A folder of at least four images whose names do not lay out a full
    grid (a view missing, names without row and column) is claimed too:
    reading it fails with the decoder's message, which says what is wrong.
    Returns ``None`` for files, ``.zarr`` stores and folders with fewer images.
    """
    path = _single_path(path)
    if path is None or not path.is_dir() or path.suffix.lower() == ".zarr":
        return None
    if not (is_camera_array_folder(path) or _holds_views(path)):
        return None
    return _read_with(path, path.name, {})


# -- calibration beside a lenslet capture ------------------------------------


def _has_word(path, words):
    stem = path.stem.lower()
    return any(word in stem for word in words)


def _likeness(a, b):
    """How alike two file stems are: common prefix plus common suffix length."""
    a, b = a.stem.lower(), b.stem.lower()
    prefix = len(os.path.commonprefix([a, b]))
    suffix = len(os.path.commonprefix([a[::-1], b[::-1]]))
    return prefix + suffix


def _best_sibling(path, candidates):
    if not candidates:
        return None
    return max(candidates, key=lambda c: (_likeness(path, c), c.name))


def _siblings(path, suffixes):
    """Files beside ``path`` (not itself) with one of ``suffixes``."""
    try:
        entries = list(os.scandir(path.parent))
    except OSError:
        return []
    return [
        Path(entry.path)
        for entry in entries
        if entry.name != path.name
        and Path(entry.name).suffix.lower() in suffixes
        and entry.is_file()
    ]


def _is_calibration_frame(path):
    return _has_word(path, _WHITE_WORDS + _DARK_WORDS)


def find_calibration_frames(path):
    """Find the white (and dark) image beside a lenslet capture.

    A white image is a sibling of the same family (TIFF/PNG/DNG images, or
    Lytro files) whose name contains ``white``, ``radiometry`` or ``flat``;
    a dark frame one whose name contains ``dark`` or ``black``. When there
    are several, the one whose name is most like the capture's wins
    (``Radiometry_GUV1.tif`` for ``Lightfield_GUV1.tif``).

    Parameters
    ----------
    path : Path
        The raw lenslet image.

    Returns
    -------
    (white, dark) : tuple of Path, or None
        ``None`` when ``path`` is itself a white or dark frame, or has no
        white image beside it; ``dark`` is ``None`` when there is none.
    """
    path = Path(path)
    if _is_calibration_frame(path):
        return None
    family = _LYTRO_SUFFIXES if path.suffix.lower() in _LYTRO_SUFFIXES else _IMAGE_SUFFIXES
    siblings = _siblings(path, family)
    white = _best_sibling(path, [s for s in siblings if _has_word(s, _WHITE_WORDS)])
    if white is None:
        return None
    dark = _best_sibling(path, [s for s in siblings if _has_word(s, _DARK_WORDS)])
    return white, dark


def _grid_shape_of(path):
    """``image_shape`` of a saved grid model, or ``None`` if ``path`` is not one."""
    from ..decoders.grid import JSON_FORMAT

    try:
        if path.stat().st_size > _GRID_MAX_BYTES:
            return None
        data = json.loads(path.read_text())
    except (OSError, ValueError, UnicodeDecodeError):
        return None
    if not isinstance(data, dict) or data.get("format") != JSON_FORMAT:
        return None
    shape = data.get("image_shape")
    if not isinstance(shape, list) or len(shape) != 2:
        return None
    return tuple(int(v) for v in shape)


def find_grid_file(path, shape=None):
    """A lenslet grid model saved beside ``path`` (``*grid*.json``, ``*calib*.json``).

    Parameters
    ----------
    path : Path
        The raw lenslet image.
    shape : tuple of int, optional
        ``(rows, cols)`` of the capture: only a model fitted on an image of
        that size is returned.

    Returns
    -------
    Path or None
    """
    path = Path(path)
    candidates = [s for s in _siblings(path, {".json"}) if _has_word(s, _GRID_WORDS)]
    candidates = [c for c in candidates if (found := _grid_shape_of(c)) and (shape is None or found == shape)]
    return _best_sibling(path, candidates)


# -- image headers ------------------------------------------------------------


def _png_shape(path):
    with open(path, "rb") as handle:
        header = handle.read(24)
    if len(header) < 24 or header[:8] != b"\x89PNG\r\n\x1a\n" or header[12:16] != b"IHDR":
        return None
    width, height = struct.unpack(">II", header[16:24])
    return (height, width)


def _tiff_shape(path):
    import tifffile

    try:
        with tifffile.TiffFile(path) as tif:
            page = tif.pages[0]
            return tuple(page.shape[:2])
    except Exception:  # tifffile raises many kinds; an unreadable TIFF is not ours to claim
        return None


def _tiff_is_one_plane(path):
    """True if the TIFF holds one grey or colour plane (not a stack or hyperstack)."""
    import tifffile

    try:
        with tifffile.TiffFile(path) as tif:
            shape = tif.series[0].shape
    except Exception:  # an unreadable TIFF is not ours to claim
        return False
    return len(shape) == 2 or (len(shape) == 3 and shape[-1] in (3, 4))


def _image_shape(path):
    """(rows, cols) of an image read from its header only, or ``None`` if unknown."""
    suffix = path.suffix.lower()
    try:
        if suffix == ".png":
            return _png_shape(path)
        if suffix in (".tif", ".tiff"):
            return _tiff_shape(path)
    except OSError:
        return None
    return None


def _could_be_a_capture(path):
    """True if ``path`` looks like a raw lenslet capture from its header: one plane, large enough."""
    if path.suffix.lower() == ".dng":
        return True
    shape = _image_shape(path)
    if shape is None or min(shape) < MIN_CAPTURE_SIDE:
        return False
    return path.suffix.lower() == ".png" or _tiff_is_one_plane(path)


def _same_size(capture, frame):
    """True when the headers say ``frame`` has the size of ``capture`` (DNG: not checked here)."""
    if capture.suffix.lower() == ".dng" or frame.suffix.lower() == ".dng":
        return True
    shape = _image_shape(capture)
    return shape is not None and shape == _image_shape(frame)


# -- lenslet captures ---------------------------------------------------------


def _options(white=None, dark=None, grid=None):
    options = {"white": white} if white is not None else {}
    if dark is not None:
        options["dark"] = dark
    if grid is not None:
        options["grid"] = grid
    return options


def _beside(path):
    """Decoding options from the calibration beside a capture, or ``None`` without one."""
    frames = find_calibration_frames(path)
    if frames is not None and (path.suffix.lower() in _LYTRO_SUFFIXES or _same_size(path, frames[0])):
        return _options(*frames)
    if path.suffix.lower() in _LYTRO_SUFFIXES:
        grid = find_grid_file(path)
    else:
        shape = _image_shape(path)
        grid = None if shape is None and path.suffix.lower() != ".dng" else find_grid_file(path, shape)
    return None if grid is None else _options(grid=grid)


def _given(paths):
    """``(capture, options)`` for a capture opened with its white (and dark) image, else ``None``."""
    if len(paths) not in (2, 3) or any(p.suffix.lower() not in _IMAGE_SUFFIXES for p in paths):
        return None
    whites = [p for p in paths if _has_word(p, _WHITE_WORDS)]
    darks = [p for p in paths if p not in whites and _has_word(p, _DARK_WORDS)]
    captures = [p for p in paths if p not in whites and p not in darks]
    if len(whites) != 1 or len(darks) > 1 or len(captures) != 1:
        return None
    capture = captures[0]
    if not all(p.is_file() and _same_size(capture, p) for p in paths if p is not capture):
        return None
    return capture, _options(whites[0], darks[0] if darks else None)


def get_lenslet_reader(path):
    """Reader for a lenslet raw image with its calibration (see the module notes).

    An image with a usable white image or grid model beside it is decoded
    with them. One that could be a capture but has none (or only one of
    another size) is claimed too: reading it fails with the decoder's
    message (what is missing, how to give it). Returns ``None`` (fast:
    names and image headers only) for the white or dark frames
    themselves, for stacks, small images and files with unreadable
    headers, and for light fields saved by napari-lfalias (their own
    reader takes them).
    """
    paths = _paths(path)
    if len(paths) > 1:
        given = _given(paths)
        if given is None or _saved_header(given[0]) is not None:
            return None
        return _read_with(given[0], capture_name(given[0]), given[1])
    path = paths[0]
    if path.suffix.lower() not in _IMAGE_SUFFIXES or _is_calibration_frame(path) or not path.is_file():
        return None
    if _saved_header(path) is not None or _saved_output(path) is not None:
        return None
    options = _beside(path)
    if options is None and not _could_be_a_capture(path):
        return None
    return _read_with(path, capture_name(path), options or {})


def capture_name(path):
    """Layer name of a capture: its file name and folder (``light_field (antleg)``), so two differ."""
    folder = path.parent.name
    return f"{path.stem} ({folder})" if folder else path.stem


# -- light fields saved by napari-lfalias ---------------------------------------


def _saved_header(path):
    from ..io_write import is_lightfield_file

    return is_lightfield_file(path)


def _saved_output(path):
    from ._writer import output_file_header

    return output_file_header(path)


def get_saved_lightfield_reader(path):
    """Reader for light fields and widget outputs saved by napari-lfalias.

    Light fields written by ``napari_lfalias.io_write.write_lightfield``
    (ImageJ hyperstack TIFFs and ``.zarr`` stores with the napari-lfalias
    header) open as light-field layers; outputs saved from napari
    (:mod:`._writer`) open as the same kind of layer, with their
    parameters. Both are recognised from the file's metadata only. A
    light-field layer saved with napari's builtin TIFF writer (the views
    without their positions) opens on a regular grid, with a warning.
    """
    path = _single_path(path)
    if path is None or path.suffix.lower() not in (".tif", ".tiff", ".zarr"):
        return None
    if _saved_header(path) is not None:

        def read_saved(_path):
            from ..io_write import read_lightfield

            with _said(path):
                lf = read_lightfield(path, lazy=path.suffix.lower() == ".zarr")
            return [lightfield_layer_data(lf, path.stem)]

        return read_saved
    if _saved_output(path) is not None:

        def read_saved_output(_path):
            from ._writer import read_output

            with _said(path):
                return [read_output(path)]

        return read_saved_output
    if path.suffix.lower() in (".tif", ".tiff") and _plain_lightfield_stack(path):
        return _read_plain_stack
    return None


#: Most views per side of a light field saved as a plain stack; more is a stack of something else.
_MAX_PLAIN_VIEWS = 64


def _plain_lightfield_stack(path):
    """True for a light-field layer saved by napari's builtin TIFF writer (views kept, positions lost).

    That writer (tifffile, "shaped" JSON description, no ImageJ or OME
    header) keeps the layer's array: ``(U, V, Y, X)`` grey or
    ``(U, V, Y, X, 3)`` colour. It is taken for a light field when it has
    at least 4 views, at most :data:`_MAX_PLAIN_VIEWS` a side, each larger
    than the grid of views. Only the TIFF header is read.
    """
    import tifffile

    try:
        with tifffile.TiffFile(path) as tif:
            if not tif.is_shaped or tif.is_imagej or tif.is_ome or len(tif.series) != 1:
                return False
            shape = tuple(tif.series[0].shape)
    except Exception:  # noqa: BLE001 - an unreadable TIFF is not ours; napari's reader names the damage
        return False
    if not (len(shape) == 4 or (len(shape) == 5 and shape[4] == 3)):
        return False
    n_rows, n_cols, height, width = shape[:4]
    return (n_rows * n_cols >= _MIN_VIEWS and max(n_rows, n_cols) <= _MAX_PLAIN_VIEWS
            and min(height, width) > max(n_rows, n_cols))


def _read_plain_stack(path):
    """Open a plain TIFF stack of views on a regular grid, warning that its positions were not saved."""
    import warnings

    import tifffile

    from .. import LightField
    from ..errors import LightFieldWarning
    from ._controls import PLUGIN_MENU

    path = _single_path(path)
    with _said(path):
        lf = LightField(tifffile.imread(path))
    warnings.warn(LightFieldWarning(
        f"{path.name} holds the views of a light field but not their positions or metadata (napari's "
        f"builtin TIFF writer saved it): the views are taken as a regular grid, one step apart. To keep "
        f"them, save the light field with the file type '{PLUGIN_MENU} light field or aliasing output'"),
        stacklevel=2)
    return [lightfield_layer_data(lf, path.stem)]


# -- Lytro ----------------------------------------------------------------


def _lytro_sensor_bytes():
    """Byte sizes of the packed Lytro F01 and Illum sensor images (bare ``.raw`` files)."""
    from ..decoders import lytro

    return {camera["bytes"] for camera in (lytro._F01, lytro._ILLUM)}


def _is_lytro_file(path):
    try:
        if path.suffix.lower() == ".raw":
            return path.stat().st_size in _lytro_sensor_bytes()
        with open(path, "rb") as handle:
            return handle.read(len(_LYTRO_MAGIC)) == _LYTRO_MAGIC
    except OSError:
        return False


def get_lytro_reader(path):
    """Reader for Lytro ``.lfr`` / ``.lfp`` containers and bare sensor ``.raw`` files.

    Containers are recognised by their magic bytes, ``.raw`` files by the
    exact size of a packed F01 or Illum sensor. The file is claimed
    whether or not a white image (or grid model) lies beside it: decoding
    then uses it, or fails with a message that says what is missing (and a
    processed picture -- a refocus stack, a depth map -- fails saying so).
    """
    path = _single_path(path)
    if path is None or path.suffix.lower() not in _LYTRO_SUFFIXES or not path.is_file():
        return None
    if _is_calibration_frame(path) or not _is_lytro_file(path):
        return None
    return _read_with(path, capture_name(path), _beside(path) or {})


# -- the reader function ----------------------------------------------------


def _read_with(source, name, options):
    """A napari reader function that decodes ``source`` with ``lfa.load(source, **options)``.

    The function ignores the path napari hands it: ``source`` is what the
    reader was built for (the capture of a list with its white image).
    """

    def read_lightfield(_path):
        from .. import load
        from ._optics import attach_optics

        with _said(source):
            lf = load(source, **options)
        attach_optics(lf, source)
        return [lightfield_layer_data(lf, name)]

    return read_lightfield


class ReadError(LightFieldError):
    """A light field the plugin claimed could not be read; the message is the library's, in GUI words."""


@contextlib.contextmanager
def _said(source):
    """Turn a library error while reading ``source`` into a :class:`ReadError` the user is shown.

    napari wraps a reader's exception in its own "Tried opening with ...,
    but failed" when it chose the reader from the preferences, so the
    reason is also posted as a napari notification.
    """
    from napari.utils.notifications import show_error

    from ._controls import in_gui_words

    try:
        yield
    except LightFieldError as error:
        message = in_gui_words(str(error))
        show_error(f"napari-lfalias could not open {Path(source).name}: {message}")
        raise ReadError(message) from error
