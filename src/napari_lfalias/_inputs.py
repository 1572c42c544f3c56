"""Open any input of the command line and of batch runs as a LightField.

Everything goes through :func:`napari_lfalias.load`; this module turns the
command line's values (``--grid 9x9`` or ``--grid GRID.json``) into its
options.
"""

from __future__ import annotations

import re
from pathlib import Path

from .errors import CalibrationError

__all__ = ["open_input", "read_grid", "view_grid", "lenslet_options", "check_reduce_options", "resolved_options"]

_VIEW_GRID = re.compile(r"^\s*(\d+)\s*[xX]\s*(\d+)\s*$")


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


def view_grid(text):
    """``"9x9"`` -> ``(9, 9)``; ``None`` for anything else (a grid model's JSON file, say).

    Examples
    --------
    >>> view_grid("3x11"), view_grid("grid.json")
    ((3, 11), None)
    """
    match = _VIEW_GRID.match(str(text))
    return (int(match[1]), int(match[2])) if match else None


def lenslet_options(white=None, dark=None, grid=None):
    """The keyword options of :func:`napari_lfalias.load` for ``white``, ``dark`` and ``grid``.

    ``grid`` may be a view grid (``(U, V)`` or ``"UxV"``, for folders of
    views), a GridModel, or the path of a grid model's JSON (lenslet captures).
    """
    options = {}
    if white is not None:
        options["white"] = white
    if dark is not None:
        options["dark"] = dark
    if grid is not None:
        if isinstance(grid, (str, Path)) and view_grid(grid) is not None:
            grid = view_grid(grid)
        elif isinstance(grid, (str, Path)):
            grid = read_grid(grid)
        options["grid"] = grid
    return options


def open_input(path, white=None, dark=None, grid=None, nonfinite=None, progress=None):
    """Open ``path`` (views folder, lenslet capture, or a saved light field) with :func:`napari_lfalias.load`.

    Parameters
    ----------
    path : str or Path
        A folder of views, a lenslet raw image (with ``white``), or a
        ``.tif``/``.zarr`` light field written by ``lfalias convert``.
    white, dark : str or Path, optional
        White (flat-field) and dark frames of a lenslet capture.
    grid : tuple, str, Path or GridModel, optional
        ``(U, V)`` or ``"UxV"``: the view grid of a folder; a grid model
        (or its JSON file) of a lenslet capture, to skip calibration.
    nonfinite : {"raise", "mask"}, optional
        What to do with NaN or Inf samples.
    progress : callable, optional
        ``progress(done, total, step)`` while a lenslet capture decodes.

    Returns
    -------
    LightField

    Raises
    ------
    DecodeError, CalibrationError, ParameterError
        If the input cannot be read, or an option does not apply to it; the
        message names the file or option.
    """
    from .io_read import is_lightfield_file
    from .loading import load

    options = lenslet_options(white, dark, grid)
    if nonfinite is not None:
        options["nonfinite"] = nonfinite
    if progress is not None and Path(path).is_file() and is_lightfield_file(path) is None:
        options["progress"] = progress
    return load(path, **options)


def resolved_options(**options):
    """The options as the library will use them: every ``None`` replaced by the preset's or the default.

    Examples
    --------
    >>> resolved_options(method=None, threshold=None, max_level=None)["method"]
    'depth'
    """
    from .reduce import reduction_options

    given = {k: v for k, v in options.items() if k in _REDUCE_OPTIONS}
    detection, max_level, screen = reduction_options(**given)
    out = dict(options)
    out.update({k: v for k, v in detection.items() if k in options or k == "method"})
    if "max_level" in options:
        out["max_level"] = max_level
    if "screen" in options:
        out["screen"] = screen
    return out


#: Keyword options of :func:`napari_lfalias.reduce.reduction_options`.
_REDUCE_OPTIONS = {"preset", "method", "threshold", "gamma", "n_patterns", "seed", "threshold_scale", "max_level",
                   "solver", "screen", "keep_in_focus"}


def check_reduce_options(slope, **options):
    """Check the options of a detection or reduction before any long work starts.

    The core checks its parameters where it uses them (after a light field
    is decoded, or on a worker); this runs those same checks at once, so a
    bad ``gamma`` fails in milliseconds and in one place.

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
    from . import _validate
    from .detect import LUMINANCE_MODES
    from .errors import ParameterError
    from .reduce import reduction_options

    _validate.finite_float("slope", slope)
    options = dict(options)
    if "luminance" in options:
        _validate.one_of("luminance", options.pop("luminance"), LUMINANCE_MODES)
    if "dark_floor" in options:
        _validate.non_negative_float("dark_floor", options.pop("dark_floor"))
    if "nearer" in options:
        from .depth_guided import NEARER

        _validate.one_of("nearer", options.pop("nearer"), NEARER)
    unknown = sorted(set(options) - _REDUCE_OPTIONS)
    if unknown:
        raise ParameterError(f"unknown option(s) {', '.join(unknown)} of a reduction; known: "
                             f"{', '.join(sorted(_REDUCE_OPTIONS))}")
    reduction_options(**options)
