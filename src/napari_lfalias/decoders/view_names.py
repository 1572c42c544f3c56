"""Which file is which view: the naming layouts of camera-array folders.

Layouts, tried in this order:

``hci``
    HCI 4D benchmark ``input_CamNNN.png``, ``NNN = row * V + col``.
``stanford``
    Stanford archive ``out_RR_CC_<y>_<x>[_].png``; the two numbers are the
    camera coordinates, from which the view positions are derived.
``list``
    Any images, in natural sort order, row-major, when ``grid=(U, V)`` is
    given.
``indexed``
    Names whose stem ends with two integer groups (``scene_03_04.png``,
    ``view_3_4.tif``): row and column, 0- or 1-based.

A grid may be partial: the HCI training scenes are often handed around as
33 of their 81 views (the cross, the diagonals and the centre 3x3). The
views the names place on the grid are kept at their true positions; the
missing ones are ``None`` in :attr:`ViewLayout.paths` (the loader gives
them weight 0). The grid is what the names imply (the largest row and
column), ``num_cams_x``/``num_cams_y`` of an HCI ``parameters.cfg``, or
``grid=(U, V)``.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import _validate
from ..errors import DecodeError, ParameterError
from .images import IMAGE_SUFFIXES, is_image_file

__all__ = ["ViewLayout", "find_views", "natural_key", "stanford_positions"]

_HCI_NAME = re.compile(r"^input_Cam(\d+)$", re.IGNORECASE)
_NUMBER = r"(-?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?)"
_STANFORD_NAME = re.compile(rf"^out_(\d+)_(\d+)_{_NUMBER}_{_NUMBER}_?$", re.IGNORECASE)
_INTEGER = re.compile(r"\d+")
#: How many names an error message lists before "and N more".
_NAMES_SHOWN = 8


@dataclass
class ViewLayout:
    """The view files of a folder arranged on their grid.

    Attributes
    ----------
    paths : list of list of Path or None
        ``paths[u][v]`` is the file of view ``(u, v)``, ``None`` for a view
        missing from the folder.
    format : str
        ``"hci"``, ``"stanford"``, ``"indexed"`` or ``"list"``.
    positions : ndarray, shape (U, V, 2), or None
        View positions when the names carry them (Stanford), else ``None``
        (a regular grid).
    meta : dict
        What the layout tells about the views (index base, ignored files,
        how positions were derived).
    """

    paths: list
    format: str
    positions: np.ndarray | None = None
    meta: dict = field(default_factory=dict)

    @property
    def grid_shape(self):
        return len(self.paths), len(self.paths[0])

    def flat_paths(self):
        """The files row-major over ``(u, v)`` (``None`` for a missing view)."""
        return [path for row in self.paths for path in row]

    @property
    def missing(self):
        """``(u, v)`` of every view missing from the folder, row-major."""
        return [(u, v) for u, row in enumerate(self.paths) for v, path in enumerate(row) if path is None]


def natural_key(name):
    """Sort key that orders embedded numbers by value (``v2`` before ``v10``)."""
    return [int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", str(name))]


def _shown(items):
    items = [str(item) for item in items]
    more = len(items) - _NAMES_SHOWN
    text = ", ".join(items[:_NAMES_SHOWN])
    return f"{text} and {more} more" if more > 0 else text


def _list_images(folder):
    try:
        entries = [Path(entry.path) for entry in os.scandir(folder) if entry.is_file()]
    except OSError as exc:
        raise DecodeError(f"{folder}: cannot list the folder ({exc.strerror})") from exc
    if not entries:
        raise DecodeError(f"{folder}: the folder is empty; point to a folder of view images")
    images = sorted((path for path in entries if is_image_file(path)), key=lambda p: natural_key(p.name))
    if not images:
        suffixes = ", ".join(sorted(IMAGE_SUFFIXES))
        raise DecodeError(
            f"{folder}: no view images ({suffixes}) in the folder (found {_shown(p.name for p in entries)}); "
            "point to the folder that holds the views"
        )
    return images


def _check_grid(grid):
    if grid is None:
        return None
    if isinstance(grid, (str, bytes)) or not hasattr(grid, "__len__") or len(grid) != 2:
        raise ParameterError(f"grid must be a pair (U, V) of view rows and columns, got {grid!r}")
    return tuple(_validate.integer_at_least(name, n, 1) for name, n in zip(("grid[0]", "grid[1]"), grid))


def _assemble(entries, folder, grid_shape, label):
    """Place ``(row, col, path)`` entries (0-based) on a ``grid_shape`` grid.

    ``label(row, col)`` names a view in messages the way the files do.

    Returns
    -------
    paths : list of list of Path or None
    meta : dict
        ``"missing_views"`` (labels, row-major) when views are missing.
    """
    n_rows, n_cols = grid_shape
    paths = [[None] * n_cols for _ in range(n_rows)]
    duplicates, outside = [], []
    for row, col, path in entries:
        if not (0 <= row < n_rows and 0 <= col < n_cols):
            outside.append(path.name)
        elif paths[row][col] is not None:
            duplicates.append(f"{paths[row][col].name} and {path.name}")
        else:
            paths[row][col] = path
    if duplicates:
        raise DecodeError(
            f"{folder}: several files for the same view: {_shown(duplicates)}; keep one file per view"
        )
    if outside:
        raise DecodeError(
            f"{folder}: views outside the {n_rows}x{n_cols} grid: {_shown(outside)}; "
            "check grid=(U, V) or remove them"
        )
    missing = [label(u, v) for u in range(n_rows) for v in range(n_cols) if paths[u][v] is None]
    return paths, ({"missing_views": missing} if missing else {})


def _hci_grid(folder):
    """``(U, V)`` from ``num_cams_y``/``num_cams_x`` of the folder's ``parameters.cfg``, if it says."""
    from .hci import PARAMETERS_NAME, read_parameters_cfg

    cfg = Path(folder) / PARAMETERS_NAME
    if not cfg.is_file():
        return None
    params = read_parameters_cfg(cfg)
    counts = params.get("num_cams_y"), params.get("num_cams_x")
    if all(isinstance(n, float) and n >= 1 and n == int(n) for n in counts):
        return int(counts[0]), int(counts[1])
    return None


def _hci_layout(folder, matches, grid):
    indices = {path: int(match.group(1)) for path, match in matches}
    given = grid is not None
    grid = grid or _hci_grid(folder)
    if grid is None:
        side = math.isqrt(max(indices.values())) + 1  # ceil(sqrt(max + 1)): a square grid
        grid = (side, side)
    n_rows, n_cols = grid
    beyond = sorted((path for path, index in indices.items() if index >= n_rows * n_cols), key=indices.get)
    if beyond:
        source = "grid=" + str(tuple(grid)) if given else f"{folder / 'parameters.cfg'}"
        raise DecodeError(
            f"{folder}: {_shown(p.name for p in beyond)} number views beyond the {n_rows * n_cols} of the "
            f"{n_rows}x{n_cols} grid of {source}; HCI names number the views row by row, so the largest "
            f"number sets the grid: leave grid out (missing views get weight 0), or fix it"
        )
    entries = [(index // n_cols, index % n_cols, path) for path, index in indices.items()]
    width = max(3, len(str(n_rows * n_cols - 1)))

    def label(u, v):
        return f"input_Cam{u * n_cols + v:0{width}d}.png"

    paths, meta = _assemble(entries, folder, grid, label)
    return ViewLayout(paths, "hci", meta=meta)


def stanford_positions(coords):
    """View positions from the camera coordinates in Stanford file names.

    Parameters
    ----------
    coords : ndarray, shape (U, V, 2)
        The two numbers of each name, in name order, on the ``RR_CC`` grid.

    Returns
    -------
    positions : ndarray, shape (U, V, 2)
        ``(y, x)`` in units of the median spacing of adjacent views, centred
        on 0, increasing with the row and column indices.
    info : dict
        ``"position_step"`` (the spacing in name units), ``"position_signs"``
        and ``"name_axes"`` (``"yx"``, or ``"xy"`` when the first number
        follows the columns).

    Raises
    ------
    DecodeError
        If every view has the same coordinates.

    Examples
    --------
    >>> import numpy as np
    >>> coords = np.array([[[0.0, 10.0], [0.0, 12.0]], [[-2.0, 10.0], [-2.0, 12.0]]])
    >>> stanford_positions(coords)[0][..., 0].tolist()
    [[-0.5, -0.5], [0.5, 0.5]]
    """
    coords = np.asarray(coords, np.float64)
    row_diff = np.diff(coords, axis=0)
    col_diff = np.diff(coords, axis=1)

    def median_abs(diff, k):
        return float(np.median(np.abs(diff[..., k]))) if diff.size else 0.0

    swap = median_abs(row_diff, 1) + median_abs(col_diff, 0) > median_abs(row_diff, 0) + median_abs(col_diff, 1)
    order = [1, 0] if swap else [0, 1]
    yx, row_diff, col_diff = coords[..., order], row_diff[..., order], col_diff[..., order]
    steps = np.concatenate([np.abs(row_diff[..., 0]).ravel(), np.abs(col_diff[..., 1]).ravel()])
    info = {"name_axes": "xy" if swap else "yx"}
    if steps.size == 0:  # a single view
        info.update(position_step=1.0, position_signs=(1, 1))
        return np.zeros_like(coords), info
    step = float(np.median(steps))
    if step <= 0:
        raise DecodeError("every view has the same camera coordinates in its name; cannot place the views")
    signs = tuple(
        -1 if diff.size and np.median(diff[..., k]) < 0 else 1 for k, diff in ((0, row_diff), (1, col_diff))
    )
    positions = (yx - yx.mean(axis=(0, 1))) / step * np.array(signs, np.float64)
    info.update(position_step=step, position_signs=signs)
    return positions, info


def _stanford_layout(folder, matches, grid):
    entries, numbers = [], {}
    for path, match in matches:
        row, col = int(match.group(1)), int(match.group(2))
        entries.append((row, col, path))
        numbers[path] = (float(match.group(3)), float(match.group(4)))
    grid_shape = _indexed_shape(entries, grid, folder)
    paths, missing = _assemble(entries, folder, grid_shape, lambda u, v: f"out_{u:02d}_{v:02d}_*.png")
    coords = _fill_missing_coords(paths, numbers)
    positions, info = stanford_positions(coords)
    info.update(missing)
    info["camera_coordinates"] = coords
    info["positions_note"] = (
        "from the camera coordinates in the file names: divided by the median spacing of adjacent "
        "views, centred on 0, signs chosen so that positions increase with RR and CC"
    )
    return ViewLayout(paths, "stanford", positions, info)


def _fill_missing_coords(paths, numbers):
    """Camera coordinates on the grid; a missing view's from the affine fit of the others to (row, col)."""
    n_rows, n_cols = len(paths), len(paths[0])
    coords = np.full((n_rows, n_cols, 2), np.nan)
    for u, row in enumerate(paths):
        for v, path in enumerate(row):
            if path is not None:
                coords[u, v] = numbers[path]
    present = ~np.isnan(coords[..., 0])
    if not present.all():
        rows, cols = np.indices((n_rows, n_cols))
        design = np.stack([rows, cols, np.ones_like(rows)], axis=-1).astype(np.float64)
        fit = np.linalg.lstsq(design[present], coords[present], rcond=None)[0]
        coords[~present] = design[~present] @ fit
    return coords


def _indexed_shape(entries, grid, folder):
    shape = (max(e[0] for e in entries) + 1, max(e[1] for e in entries) + 1)
    if grid is not None and tuple(grid) != shape:
        raise ParameterError(
            f"grid={tuple(grid)} does not match the {shape[0]}x{shape[1]} views named in {folder}; "
            "leave grid out or fix it"
        )
    return shape


def _indexed_layout(folder, images):
    entries, ignored = [], []
    for path in images:
        groups = _INTEGER.findall(path.stem)
        if len(groups) >= 2:
            entries.append((int(groups[-2]), int(groups[-1]), path))
        else:
            ignored.append(path)
    if not entries:
        raise DecodeError(
            f"{folder}: cannot tell the view rows and columns from names like {_shown(p.name for p in images[:3])}; "
            "name the views *_RR_CC.png, or pass grid=(U, V) to read them in sorted order row-major"
        )
    base = min(min(e[0] for e in entries), min(e[1] for e in entries))
    entries = [(row - base, col - base, path) for row, col, path in entries]
    grid_shape = _indexed_shape(entries, None, folder)
    example = entries[0][2]

    def label(u, v):
        return f"row {u + base}, column {v + base} (like {example.name})"

    paths, missing = _assemble(entries, folder, grid_shape, label)
    meta = {"index_base": base, **missing}
    if ignored:
        meta["ignored_files"] = [str(path) for path in ignored]
    return ViewLayout(paths, "indexed", meta=meta)


def _list_layout(folder, images, grid):
    n_rows, n_cols = grid
    if len(images) != n_rows * n_cols:
        raise DecodeError(
            f"{folder}: grid={grid} needs {n_rows * n_cols} views but the folder holds {len(images)} images "
            f"({_shown(p.name for p in images)}); fix grid or the folder"
        )
    paths = [images[u * n_cols:(u + 1) * n_cols] for u in range(n_rows)]
    return ViewLayout(paths, "list")


def _matching(images, pattern):
    return [(path, match) for path in images if (match := pattern.match(path.stem))]


def find_views(folder, grid=None):
    """Arrange the view images of ``folder`` on their grid.

    Parameters
    ----------
    folder : Path
        A folder of view images.
    grid : (int, int), optional
        ``(U, V)``. Required for names that carry no indices (the images are
        then taken in natural sort order, row-major); for HCI names it sets
        a non-square grid (default: ``parameters.cfg``'s camera counts, else
        the square the largest number implies); for Stanford names it must
        match the indices.

    Returns
    -------
    ViewLayout

    Raises
    ------
    DecodeError
        Empty folder, no images, a duplicate view, a view beyond the grid.
    ParameterError
        A malformed ``grid``, or one that contradicts the names.

    Examples
    --------
    >>> import numpy as np, imageio.v3 as iio, tempfile
    >>> from pathlib import Path
    >>> folder = Path(tempfile.mkdtemp())
    >>> for u in range(2):
    ...     for v in range(3):
    ...         iio.imwrite(folder / f"view_{u}_{v}.png", np.zeros((4, 4), np.uint8))
    >>> layout = find_views(folder)
    >>> layout.format, layout.grid_shape
    ('indexed', (2, 3))
    """
    folder = Path(folder)
    grid = _check_grid(grid)
    images = _list_images(folder)
    hci = _matching(images, _HCI_NAME)
    if hci:
        return _hci_layout(folder, hci, grid)
    stanford = _matching(images, _STANFORD_NAME)
    if stanford:
        return _stanford_layout(folder, stanford, grid)
    if grid is not None:
        return _list_layout(folder, images, grid)
    return _indexed_layout(folder, images)
