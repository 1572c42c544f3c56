"""Output files of the command line: names, up-front checks, and image writers."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .. import io_write
from ..errors import OutputExistsError, ParameterError

__all__ = ["sibling", "check_outputs", "image_suffix", "write_outputs", "preview_range"]


def image_suffix(path):
    """Return the lower-case suffix of an image output, or raise a ParameterError."""
    suffix = Path(path).suffix.lower()
    if suffix not in io_write.IMAGE_SUFFIXES:
        raise ParameterError(f"{path}: the output must end in .png, .tif or .tiff (got {suffix or 'no suffix'!r})")
    return suffix


def sibling(path, tag):
    """``out.png`` -> ``out_<tag>.png``: a further output written beside ``path``."""
    path = Path(path)
    return path.with_name(f"{path.stem}_{tag}{path.suffix}")


def check_outputs(paths, overwrite):
    """Check every output before any work starts (no half-written result sets).

    Raises
    ------
    OutputExistsError
        Naming the first output that exists, unless ``overwrite``.
    ParameterError
        If an output folder does not exist.
    """
    existing = [Path(p) for p in paths if Path(p).exists()]
    if existing and not overwrite:
        more = f" (and {len(existing) - 1} more)" if len(existing) > 1 else ""
        raise OutputExistsError(f"{existing[0]}: output exists{more}; pass --overwrite to replace it")
    for path in paths:
        io_write.check_output(path, overwrite=True)


def preview_range(*images):
    """A shared (vmin, vmax) for PNG previews: 0.5 and 99.5 percentiles over ``images``."""
    values = np.concatenate([np.asarray(image, np.float32).ravel() for image in images])
    values = values[np.isfinite(values)]
    if values.size == 0:
        return 0.0, 1.0
    low, high = np.percentile(values, [0.5, 99.5])
    return float(low), float(max(high, low + 1e-6))


def write_outputs(items, metadata, overwrite, image_range=None):
    """Write ``[(path, kind, array), ...]``; ``kind`` picks the PNG scaling.

    Parameters
    ----------
    items : list of (Path, str, ndarray)
        ``kind`` is ``"image"`` (scaled by ``image_range``, default [0, 1]),
        ``"cv"`` (0 .. 2 * threshold, so the threshold is mid-grey),
        ``"mask"`` (0/255) or ``"levels"`` (0 .. max_level).
    metadata : dict
        Stored in every TIFF output (the parameters of the run).
    overwrite : bool
    image_range : (float, float), optional
        PNG range of ``"image"`` outputs.

    Returns
    -------
    list of Path
    """
    written = []
    for path, kind, array in items:
        if kind == "image":
            low, high = image_range or (0.0, 1.0)
            preview = {"vmin": low, "vmax": high}
        elif kind == "cv":
            preview = {"vmin": 0.0, "vmax": 2.0 * float(metadata.get("threshold", 0.02))}
        elif kind == "levels":
            preview = {"vmin": 0.0, "vmax": float(max(1, metadata.get("max_level", 3)))}
        elif kind == "mask":
            preview = {}
            array = np.asarray(array, bool)
        else:  # pragma: no cover - programming error
            raise ValueError(kind)
        written.append(io_write.write_image(path, array, {**metadata, "content": kind}, overwrite, **preview))
    return written
