"""Camera-array folders (one image per view) to a :class:`LightField`.

The naming layouts (HCI benchmark, Stanford archive, ``*_RR_CC`` indices,
a plain list with ``grid=(U, V)``) are recognised by
:mod:`.view_names`; images are read by :mod:`.images`; HCI metadata and
ground-truth disparity by :mod:`.hci`.
"""

from __future__ import annotations

import math
import warnings
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from .. import _budget, _validate
from ..errors import DecodeError, LightFieldWarning, ParameterError
from ..lightfield import LightField
from .artefacts import correct_artefacts, summarise_view
from .hci import hci_metadata
from .images import decode_image, image_header, to_unit_float
from .view_names import find_views

__all__ = ["load_camera_array"]

#: Reader threads: OpenCV and tifffile decode with the GIL released.
_READ_THREADS = 2
_ACCEPTED = ("grid", "lazy", "progress", "nonfinite", "artefacts")


def _describe(shape):
    height, width, channels = shape
    return f"{width}x{height} {'grey' if channels == 1 else 'RGB'}"


def _check_view(path, shape, first_path, first_shape):
    if tuple(shape) == tuple(first_shape):
        return
    if tuple(shape[:2]) == tuple(first_shape[:2]):
        what = "all views must be grey, or all colour: convert them to one kind"
    else:
        what = "all views must have the same size: crop or resize them"
    raise DecodeError(
        f"{path}: a {_describe(shape)} view, but {first_path.name} is {_describe(first_shape)}; {what}"
    )


def _read_view(path, first_path, first_shape, out=None, summarise=None):
    """The view as float32 in [0, 1] (into ``out`` if given), and ``summarise(view, native)`` if given."""
    native = decode_image(path)
    _check_view(path, native.shape, first_path, first_shape)
    image = to_unit_float(native, out)
    return image, (None if summarise is None else summarise(image, native))


def _first_present(paths):
    return next(path for path in paths if path is not None)


def _check_size(paths, grid_shape, first_shape):
    """Refuse, from the first view's header, a light field beyond the memory budget (image bombs)."""
    n_bytes = math.prod(grid_shape) * math.prod(first_shape) * 4
    if any(path is None for path in paths):
        n_bytes += math.prod(grid_shape) * math.prod(first_shape[:2]) * 4  # the weights
    height, width, channels = first_shape
    _budget.check(n_bytes, f"{_first_present(paths)}: {len(paths)} views of {width} x {height} x {channels} "
                           "float32 (the size its header gives)", DecodeError)


def _read_eager(paths, grid_shape, progress, summarise=None):
    """The views ``(U, V, Y, X, C)``, and ``summarise(view, native)`` of each (``None`` for a missing one) if given."""
    first_path = _first_present(paths)
    first_shape = image_header(first_path)
    _check_size(paths, grid_shape, first_shape)
    data = np.zeros(tuple(grid_shape) + tuple(first_shape), np.float32)
    flat = data.reshape((-1,) + tuple(first_shape))
    present = [i for i, path in enumerate(paths) if path is not None]
    summaries = [None] * len(paths)

    def read_into(i):  # in a reader thread: the view is summarised while it is in the cache
        _, summaries[i] = _read_view(paths[i], first_path, first_shape, flat[i], summarise)

    with ThreadPoolExecutor(_READ_THREADS) as pool:
        futures = [pool.submit(read_into, i) for i in present]
        try:
            for done, future in enumerate(futures, start=1):
                future.result()  # re-raises the first failure, in view order
                if progress is not None:
                    progress(done, len(present))
        except BaseException:
            for future in futures:
                future.cancel()
            raise
    return data, summaries


def _read_lazy(paths, grid_shape, progress):
    try:
        import dask.array as da
        from dask.base import tokenize
    except ImportError as exc:
        raise ParameterError("lazy=True needs dask: pip install 'napari-lfalias[dask]'") from exc
    first_path = _first_present(paths)
    first_shape = image_header(first_path)
    _check_size(paths, grid_shape, first_shape)
    present = [path for path in paths if path is not None]
    for done, path in enumerate(present, start=1):
        _check_view(path, image_header(path), first_path, first_shape)
        if progress is not None:
            progress(done, len(present))
    n_cols = grid_shape[1]

    def read_block(block_info=None):
        u, v = block_info[None]["chunk-location"][:2]
        path = paths[u * n_cols + v]
        if path is None:  # a view missing from the folder: weight 0
            return np.zeros((1, 1) + tuple(first_shape), np.float32)
        return _read_view(path, first_path, first_shape)[0][None, None]

    stamps = [(str(p), p.stat().st_mtime_ns, p.stat().st_size) if p is not None else None for p in paths]
    chunks = tuple((1,) * n for n in grid_shape) + tuple((n,) for n in first_shape)
    return da.map_blocks(
        read_block,
        chunks=chunks,
        dtype=np.float32,
        meta=np.empty((0,) * 5, np.float32),
        name="camera-array-" + tokenize(stamps),
    )


def _missing_view_weights(layout, image_shape):
    """Sample weights ``(U, V, Y, X)``: 0 for the views missing from the folder; ``None`` if none is."""
    if not layout.missing:
        return None
    weights = np.ones(layout.grid_shape + tuple(image_shape), np.float32)
    for u, v in layout.missing:
        weights[u, v] = 0
    return weights


def _warn_missing(folder, layout):
    labels = layout.meta["missing_views"]
    shown = ", ".join(labels[:4]) + (f" and {len(labels) - 4} more" if len(labels) > 4 else "")
    n_rows, n_cols = layout.grid_shape
    warnings.warn(
        f"{folder}: {len(labels)} of the {n_rows * n_cols} views of the {n_rows}x{n_cols} grid are missing "
        f"({shown}); they are kept at their positions with weight 0",
        LightFieldWarning, stacklevel=3,
    )


def _examine_artefacts(artefacts, lazy):
    """Whether to look for black borders, vignetting and clipped light (``artefacts=None``: when eager)."""
    if artefacts is None:
        return not lazy
    _validate.boolean("artefacts", artefacts)
    if artefacts and lazy:
        raise ParameterError(
            "artefacts=True needs every view read at load time, which lazy=True avoids: load eagerly "
            "(lazy=False), or pass artefacts=False"
        )
    return bool(artefacts)


def load_camera_array(folder, *, grid=None, lazy=False, progress=None, nonfinite="raise", artefacts=None,
                      **options):
    """Load a folder of views (one image file per view) as a light field.

    Parameters
    ----------
    folder : str or Path
        The folder. Recognised names: HCI benchmark ``input_CamNNN.png``
        (``NNN = row * V + col``; ``parameters.cfg`` and
        ``gt_disp_lowres.pfm`` beside them are read), Stanford archive
        ``out_RR_CC_<y>_<x>_.png`` (positions from the coordinates), or any
        names whose stem ends with two integer groups, row then column,
        0- or 1-based (``scene_03_04.png``, ``view_3_4.tif``).
    grid : (int, int), optional
        ``(U, V)``: read every image of the folder in natural sort order,
        row-major, as a ``U x V`` grid (for names without indices).
    lazy : bool
        Return a light field whose data is a dask array read view by view
        on demand (one chunk per view). Sizes are checked from the file
        headers now; a broken file raises ``DecodeError`` when computed.
    progress : callable, optional
        Called as ``progress(done, total)`` after each view is read (eager)
        or checked (lazy).
    nonfinite : {"raise", "mask"}
        NaN or Inf samples (float TIFF views): refuse them, or give them
        weight 0 (see :class:`~napari_lfalias.LightField`).
    artefacts : bool, optional
        Look for what a real camera leaves in exported views
        (:mod:`~napari_lfalias.decoders.artefacts`): black borders get
        weight 0; clearly vignetted views (a plenoptic camera's dark
        corner views) are divided by their fall-off relative to the
        brightest view, which becomes their weight; clipped light is set
        to one level in every view at half weight. ``None`` (default): when the
        views are read now (not with ``lazy=True``); ``False``: the views
        exactly as the files hold them.

    Returns
    -------
    LightField
        ``data`` (U, V, Y, X, C) float32 in [0, 1] (8- and 16-bit images
        scaled by 255 and 65535; alpha dropped). ``meta`` holds ``"source"``,
        ``"format"`` (``"hci"``, ``"stanford"``, ``"indexed"``, ``"list"``),
        ``"files"`` (row-major, ``None`` for a missing view), and for HCI
        ``"hci"`` (the parameters), ``"disparity"`` (ground truth in this
        package's sign) and ``"disparity_range"``.

        With ``artefacts``, ``weights`` holds what was found and
        ``meta["artefacts"]`` reports it (absent when nothing was: the
        light field is then exactly the files' values).

        Views missing from a partial grid (the HCI training scenes are
        often handed around as 33 of their 81 views) keep their positions
        and get weight 0 in ``weights`` (zeros in ``data``); ``meta["missing_views"]``
        names them and a :class:`~napari_lfalias.errors.LightFieldWarning` says so.

    Raises
    ------
    DecodeError
        An empty folder, a folder without images, a duplicate view or one
        beyond the grid, views of mixed sizes or of mixed grey and colour,
        an unreadable or truncated file, or views whose decoded size (from
        their headers) exceeds the memory budget.
    ParameterError
        An unknown option, a malformed ``grid``, or ``artefacts=True``
        with ``lazy=True``.

    Examples
    --------
    >>> import numpy as np, imageio.v3 as iio, tempfile
    >>> from pathlib import Path
    >>> folder = Path(tempfile.mkdtemp())
    >>> for u in range(3):
    ...     for v in range(3):
    ...         iio.imwrite(folder / f"scene_{u + 1}_{v + 1}.png", np.zeros((8, 10, 3), np.uint8))
    >>> lf = load_camera_array(folder)
    >>> lf.shape, lf.meta["format"]
    ((3, 3, 8, 10, 3), 'indexed')
    """
    if options:
        names = ", ".join(sorted(options))
        raise ParameterError(
            f"unknown option(s) for a camera-array folder: {names}; accepted: {', '.join(_ACCEPTED)}"
        )
    _validate.boolean("lazy", lazy)
    if progress is not None and not callable(progress):
        raise ParameterError(f"progress must be a callable progress(done, total), got {progress!r}")
    folder = Path(folder)
    if not folder.is_dir():
        raise DecodeError(f"{folder}: not a folder; pass the folder that holds the view images")
    layout = find_views(folder, grid)
    paths = layout.flat_paths()
    examine = _examine_artefacts(artefacts, lazy)
    if lazy:
        data = _read_lazy(paths, layout.grid_shape, progress)
    else:
        data, summaries = _read_eager(paths, layout.grid_shape, progress, summarise_view if examine else None)
    meta = {"source": str(folder), "format": layout.format,
            "files": [str(p) if p is not None else None for p in paths]}
    meta.update(layout.meta)
    if layout.format == "hci":
        meta.update(hci_metadata(folder, layout.grid_shape, data.shape[2:4]))
    weights = _missing_view_weights(layout, data.shape[2:4])
    if layout.missing:
        _warn_missing(folder, layout)
    if examine:
        weights, found = correct_artefacts(data, summaries, weights, source=str(folder))
        if found:
            meta["artefacts"] = found
    return LightField(data, layout.positions, meta, weights=weights, nonfinite=nonfinite)
