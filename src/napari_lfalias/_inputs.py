"""Open any input of the command line and of batch runs as a LightField.

A light field written by :mod:`napari_lfalias.io_write` (``lfalias
convert``) is read back directly; anything else goes through
:func:`napari_lfalias.load` with the lenslet options that were given.
"""

from __future__ import annotations

from pathlib import Path

from .errors import CalibrationError, DecodeError

__all__ = ["open_input", "read_grid", "lenslet_options", "check_reduce_options"]


def read_grid(path):
    """Read a lenslet grid model saved as JSON (``GridModel.to_json``).

    Raises
    ------
    CalibrationError
        If the file is missing or is not a grid model.
    """
    from .decoders.lenslet import GridModel

    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise CalibrationError(f"{path}: cannot read the grid model ({exc.strerror})") from exc
    try:
        return GridModel.from_json(text)
    except CalibrationError:
        raise
    except (ValueError, KeyError, TypeError) as exc:
        raise CalibrationError(f"{path}: not a lenslet grid model JSON ({exc})") from exc


def lenslet_options(white=None, dark=None, grid=None):
    """The keyword options of :func:`napari_lfalias.load` for a lenslet capture.

    ``grid`` may be a GridModel or the path of its JSON.
    """
    options = {}
    if white is not None:
        options["white"] = white
    if dark is not None:
        options["dark"] = dark
    if grid is not None:
        options["grid"] = read_grid(grid) if isinstance(grid, (str, Path)) else grid
    return options


def open_input(path, white=None, dark=None, grid=None, progress=None):
    """Open ``path`` (views folder, lenslet capture, or a converted light field).

    Parameters
    ----------
    path : str or Path
        A folder of views, a lenslet raw image (with ``white``), or a
        ``.tif``/``.zarr`` light field written by ``lfalias convert``.
    white, dark : str or Path, optional
        White (flat-field) and dark frames of a lenslet capture.
    grid : GridModel or str or Path, optional
        A calibrated grid model (or its JSON file) to skip calibration.
    progress : callable, optional
        ``progress(done, total, step)`` while a lenslet capture decodes.

    Returns
    -------
    LightField

    Raises
    ------
    DecodeError, CalibrationError
        If the input cannot be read; the message names the file.
    """
    from . import io_write
    from .loading import load

    path = Path(path)
    if not path.exists():
        raise DecodeError(f"{path}: no such file or folder")
    if io_write.is_lightfield_file(path) is not None:
        if white is not None or dark is not None or grid is not None:
            raise DecodeError(
                f"{path}: already a decoded light field; --white, --dark and --grid do not apply"
            )
        return io_write.read_lightfield(path)
    options = lenslet_options(white, dark, grid)
    if progress is not None and path.is_file():
        options["progress"] = progress
    return load(path, **options)


def check_reduce_options(slope, **options):
    """Check the options of a detection or reduction before any long work starts.

    The core checks its parameters where it uses them (after a light field
    is decoded, or on a worker); this runs those same checks at once, on a
    tiny light field, so a bad ``gamma`` fails in milliseconds and in one
    place.

    Parameters
    ----------
    slope : float
    **options
        Keyword options of :func:`napari_lfalias.reduce_aliasing`
        (those of :func:`napari_lfalias.detect_aliasing` among them).

    Raises
    ------
    ParameterError
        Naming the parameter at fault.
    """
    import numpy as np

    from .lightfield import LightField
    from .reduce import reduce_aliasing

    reduce_aliasing(LightField(np.zeros((2, 2, 4, 4, 1), np.float32)), slope, **options)
