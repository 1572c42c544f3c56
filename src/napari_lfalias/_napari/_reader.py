"""napari readers: camera-array folders, lenslet captures, Lytro files.

Each ``get_*_reader(path)`` is called by napari for every path that matches
the manifest's patterns, so it must decide fast and say ``None`` for
anything it does not handle: it looks only at file names and file headers,
never at pixel data. Decoding happens in the returned reader function,
through :func:`napari_lfalias.load`.
"""

from __future__ import annotations

import os
import struct
from pathlib import Path

from ._layers import lightfield_layer_data

__all__ = [
    "get_saved_lightfield_reader",
    "get_camera_array_reader",
    "get_lenslet_reader",
    "get_lytro_reader",
    "find_calibration_frames",
    "is_camera_array_folder",
]

#: Fewest views that make a folder a light field.
_MIN_VIEWS = 4

_LENSLET_SUFFIXES = {".tif", ".tiff", ".png", ".dng"}
_WHITE_WORDS = ("white", "radiometry", "flatfield", "flat")
_DARK_WORDS = ("darkframe", "dark", "black")
_LYTRO_MAGIC = b"\x89LFP"


def _single_path(path):
    """The one path napari passes, or ``None`` for a list of several paths."""
    if isinstance(path, (list, tuple)):
        if len(path) != 1:
            return None
        path = path[0]
    return Path(os.fspath(path))


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


def get_camera_array_reader(path):
    """Reader for a folder of views (HCI ``input_Cam*.png``, Stanford ``out_*``, ``*_RR_CC.*``).

    Returns ``None`` for files and for folders without such view files.
    """
    path = _single_path(path)
    if path is None or not path.is_dir() or not is_camera_array_folder(path):
        return None
    return _read_with(path.name, {})


# -- lenslet captures -----------------------------------------------------


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


def find_calibration_frames(path):
    """Find the white (and dark) image beside a lenslet raw image.

    A white image is a sibling image file whose name contains ``white``,
    ``radiometry`` or ``flat``; a dark frame one whose name contains
    ``dark`` or ``black``. When there are several, the one whose name is
    most like the raw image's wins (``Radiometry_GUV1.tif`` for
    ``Lightfield_GUV1.tif``).

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
    if _has_word(path, _WHITE_WORDS + _DARK_WORDS):
        return None
    try:
        siblings = [
            Path(entry.path)
            for entry in os.scandir(path.parent)
            if entry.is_file() and Path(entry.name).suffix.lower() in _LENSLET_SUFFIXES
        ]
    except OSError:
        return None
    siblings = [s for s in siblings if s.name != path.name]
    white = _best_sibling(path, [s for s in siblings if _has_word(s, _WHITE_WORDS)])
    if white is None:
        return None
    dark = _best_sibling(path, [s for s in siblings if _has_word(s, _DARK_WORDS)])
    return white, dark


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
    except Exception:  # not a readable TIFF: not ours to claim
        return None


def _image_shape(path):
    """(rows, cols) of an image read from its header only, or ``None`` if unknown."""
    suffix = path.suffix.lower()
    if suffix == ".png":
        return _png_shape(path)
    if suffix in (".tif", ".tiff"):
        return _tiff_shape(path)
    return None


def get_lenslet_reader(path):
    """Reader for a lenslet raw image with a white image beside it.

    Returns ``None`` (fast: names and image headers only) for the white or
    dark frames themselves, for images with no white image beside them,
    and for images whose size differs from the white image's.
    """
    path = _single_path(path)
    if path is None or path.suffix.lower() not in _LENSLET_SUFFIXES or not path.is_file():
        return None
    frames = find_calibration_frames(path)
    if frames is None or _saved_header(path) is not None:
        return None
    white, dark = frames
    if path.suffix.lower() != ".dng":
        shape = _image_shape(path)
        if shape is None or shape != _image_shape(white):
            return None
    options = {"white": white}
    if dark is not None:
        options["dark"] = dark
    return _read_with(path.stem, options)


# -- light fields saved by napari-lfalias ---------------------------------------


def _saved_header(path):
    from ..io_write import is_lightfield_file

    return is_lightfield_file(path)


def get_saved_lightfield_reader(path):
    """Reader for light fields written by ``napari_lfalias.io_write.write_lightfield``.

    ImageJ hyperstack TIFFs and ``.zarr`` stores are claimed only when they
    carry the napari-lfalias header (checked from the file's metadata).
    """
    path = _single_path(path)
    if path is None or path.suffix.lower() not in (".tif", ".tiff", ".zarr"):
        return None
    if _saved_header(path) is None:
        return None

    def read_saved(path):
        from ..io_write import read_lightfield

        path = _single_path(path)
        lf = read_lightfield(path, lazy=path.suffix.lower() == ".zarr")
        return [lightfield_layer_data(lf, path.stem)]

    return read_saved


# -- Lytro ----------------------------------------------------------------


def get_lytro_reader(path):
    """Reader for Lytro ``.lfr`` / ``.lfp`` containers (checked by their magic bytes)."""
    path = _single_path(path)
    if path is None or path.suffix.lower() not in (".lfr", ".lfp") or not path.is_file():
        return None
    try:
        with open(path, "rb") as handle:
            magic = handle.read(len(_LYTRO_MAGIC))
    except OSError:
        return None
    if magic != _LYTRO_MAGIC:
        return None
    return _read_with(path.stem, {})


# -- the reader function ----------------------------------------------------


def _read_with(name, options):
    """A napari reader function that decodes its path with ``lfa.load(path, **options)``."""

    def read_lightfield(path):
        from .. import load

        path = _single_path(path)
        lf = load(path, **options)
        return [lightfield_layer_data(lf, name)]

    return read_lightfield
