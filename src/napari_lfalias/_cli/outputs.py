"""Output files of the command line: names, up-front checks, and image writers."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .. import io_write
from ..errors import OutputExistsError, ParameterError

__all__ = ["sibling", "check_outputs", "image_suffix", "write_outputs", "preview_range", "preview_settings", "montage"]


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


def check_outputs(paths, overwrite, inputs=()):
    """Check every output before any work starts (no half-written result sets).

    Parameters
    ----------
    paths : iterable of str or Path
        The outputs.
    overwrite : bool
        Whether existing outputs may be replaced.
    inputs : iterable of str or Path or None
        What the user gave (input, white, dark, grid): never replaced, not even with ``overwrite``.

    Raises
    ------
    OutputExistsError
        Naming the first output that exists, unless ``overwrite``.
    ParameterError
        If an output folder does not exist, or an output is an input or lies in an input folder.
    """
    paths = list(paths)
    io_write.check_not_inputs(paths, inputs)
    existing = [Path(p) for p in paths if Path(p).exists()]
    if existing and not overwrite:
        more = f" (and {len(existing) - 1} more)" if len(existing) > 1 else ""
        raise OutputExistsError(f"{existing[0]}: output exists{more}; pass --overwrite to replace it")
    for path in paths:
        io_write.check_output(path, overwrite=True)


def preview_settings(kind, metadata, image_range=None):
    """``vmin``/``vmax`` of the PNG preview of a ``kind`` of output (see :func:`write_outputs`)."""
    if kind == "image":
        low, high = image_range or (0.0, 1.0)
        return {"vmin": low, "vmax": high}
    if kind == "cv":
        return {"vmin": 0.0, "vmax": 2.0 * float(metadata.get("threshold", 0.02))}
    if kind == "levels":
        return {"vmin": 0.0, "vmax": float(max(1, metadata.get("max_level", 3)))}
    if kind == "mask":
        return {}
    raise ValueError(f"unknown kind of output {kind!r}")  # pragma: no cover - programming error


def preview_range(*images):
    """A shared (vmin, vmax) for PNG previews: 0.5 and 99.5 percentiles over ``images``."""
    values = np.concatenate([np.asarray(image, np.float32).ravel() for image in images])
    values = values[np.isfinite(values)]
    if values.size == 0:
        return 0.0, 1.0
    low, high = np.percentile(values, [0.5, 99.5])
    return float(low), float(max(high, low + 1e-6))


def write_outputs(items, metadata, overwrite, image_range=None, zoom=1):
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
    zoom : int
        Whole-number enlargement of PNG previews (nearest neighbour).

    Returns
    -------
    list of Path
    """
    written = []
    for path, kind, array in items:
        preview = preview_settings(kind, metadata, image_range)
        if kind == "mask":
            array = np.asarray(array, bool)
        if Path(path).suffix.lower() == ".png":
            preview["zoom"] = zoom
        written.append(io_write.write_image(path, array, {**metadata, "content": kind}, overwrite, **preview))
    return written


#: Height of the title strip above each panel of a :func:`montage`, in pixels.
LABEL_HEIGHT = 22
GAP = 6


def montage(panels, metadata, image_range=None, zoom=1):
    """One RGB picture of titled panels side by side (the demo's overview).

    Parameters
    ----------
    panels : list of (str, str, ndarray)
        ``(title, kind, array)``; ``kind`` as in :func:`write_outputs`.
        Every array has the same ``(Y, X)``.
    metadata : dict
        ``threshold`` and ``max_level`` scale the Cv and level panels.
    image_range : (float, float), optional
        Range of the ``"image"`` panels.
    zoom : int
        Whole-number enlargement, nearest neighbour.

    Returns
    -------
    ndarray, shape (H, W, 3), uint8
    """
    import cv2

    tiles = []
    for title, kind, array in panels:
        array = np.asarray(array, bool) if kind == "mask" else np.asarray(array)
        pixels = io_write.to_preview(array, **preview_settings(kind, metadata, image_range))
        if pixels.ndim == 2:
            pixels = np.repeat(pixels[..., None], 3, axis=-1)
        pixels = np.repeat(np.repeat(pixels, zoom, axis=0), zoom, axis=1)
        strip = np.full((LABEL_HEIGHT, pixels.shape[1], 3), 255, np.uint8)
        cv2.putText(strip, title, (4, LABEL_HEIGHT - 7), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
        tiles.append(np.concatenate([strip, pixels]))
    gap = np.full((tiles[0].shape[0], GAP, 3), 255, np.uint8)
    row = [tiles[0]]
    for tile in tiles[1:]:
        row += [gap, tile]
    return np.concatenate(row, axis=1)
