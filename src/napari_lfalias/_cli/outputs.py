"""Output files of the command line: names, up-front checks, and image writers."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .. import io_write
from ..errors import OutputExistsError, ParameterError

__all__ = ["sibling", "check_outputs", "image_suffix", "write_outputs", "preview_range", "preview_settings", "montage",
           "preview_zoom", "PREVIEW_SIZE"]

#: PNG previews are enlarged (nearest neighbour) to at least this many pixels on their longest side.
PREVIEW_SIZE = 256


def preview_zoom(shape):
    """The whole-number enlargement that brings an image of ``shape`` (Y, X) to :data:`PREVIEW_SIZE` px.

    Examples
    --------
    >>> preview_zoom((28, 28)), preview_zoom((512, 300))
    (10, 1)
    """
    return max(1, -(-PREVIEW_SIZE // max(shape[:2])))


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
    if kind == "error":
        return {"vmin": 0.0, "vmax": float(metadata.get("error_range", 0.2))}
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
        ``"mask"`` (0/255), ``"levels"`` (0 .. max_level) or ``"error"``
        (0 .. ``metadata["error_range"]``, default 0.2).
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
WHITE = 255


def _panel(title, kind, array, metadata, image_range, zoom):
    """One titled tile: the preview of ``array`` (or ``array`` itself for ``kind="rgb"``) under its title."""
    import cv2

    if kind == "rgb":  # already coloured (and enlarged): a colour preview with its legend
        pixels = np.asarray(array, np.uint8)
    else:
        array = np.asarray(array, bool) if kind == "mask" else np.asarray(array)
        pixels = io_write.to_preview(array, **preview_settings(kind, metadata, image_range))
        if pixels.ndim == 2:
            pixels = np.repeat(pixels[..., None], 3, axis=-1)
        pixels = np.repeat(np.repeat(pixels, zoom, axis=0), zoom, axis=1)
    strip = np.full((LABEL_HEIGHT, pixels.shape[1], 3), WHITE, np.uint8)
    cv2.putText(strip, title, (4, LABEL_HEIGHT - 7), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    return np.concatenate([strip, pixels])


def _pad(tile, height, width):
    out = np.full((height, width, 3), WHITE, np.uint8)
    out[:tile.shape[0], :tile.shape[1]] = tile
    return out


def montage(panels, metadata, image_range=None, zoom=1):
    """One RGB picture of titled panels, in a row or in rows (the demo's overviews).

    Parameters
    ----------
    panels : list of (str, str, ndarray), or a list of such lists (rows)
        ``(title, kind, array)``; ``kind`` as in :func:`write_outputs`, or
        ``"rgb"`` for a uint8 picture shown as it is (not enlarged). Tiles
        of unequal size are padded with white.
    metadata : dict
        ``threshold`` and ``max_level`` scale the Cv and level panels.
    image_range : (float, float), optional
        Range of the ``"image"`` panels.
    zoom : int
        Whole-number enlargement of the other panels, nearest neighbour.

    Returns
    -------
    ndarray, shape (H, W, 3), uint8

    Examples
    --------
    >>> tiles = [("a", "image", np.zeros((4, 4))), ("b", "mask", np.ones((4, 4), bool))]
    >>> montage([tiles, tiles[:1]], {}, zoom=2).shape
    (66, 22, 3)
    """
    rows = panels if panels and isinstance(panels[0], list) else [panels]
    tiles = [[_panel(*panel, metadata, image_range, zoom) for panel in row] for row in rows]
    height = max(tile.shape[0] for row in tiles for tile in row)
    width = max(tile.shape[1] for row in tiles for tile in row)
    gap = np.full((height, GAP, 3), WHITE, np.uint8)
    lines = []
    for row in tiles:
        line = [_pad(row[0], height, width)]
        for tile in row[1:]:
            line += [gap, _pad(tile, height, width)]
        lines.append(np.concatenate(line, axis=1))
    full = max(line.shape[1] for line in lines)
    lines = [_pad(line, height, full) for line in lines]
    between = np.full((GAP, full, 3), WHITE, np.uint8)
    out = [lines[0]]
    for line in lines[1:]:
        out += [between, line]
    return np.concatenate(out)
