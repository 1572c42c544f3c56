"""Read the light fields napari-lfalias writes, and refuse damaged ones by name.

:func:`napari_lfalias.save` (and ``lfalias convert``) writes two formats,
both holding a JSON *header* (shape, view positions, whether sample
weights follow, metadata):

- ``.tif``/``.tiff``: an ImageJ hyperstack, axes ``TZCYX`` = (U, V, C, Y, X),
  float32; the header is the ImageJ ``Info`` property; sample weights,
  when present, are one more channel.
- ``.zarr``: a zarr group with a ``views`` array (U, V, Y, X, C), one view
  per chunk, an optional ``weights`` array, the header in its attributes.

Nothing damaged reads as data: a header that is incomplete or disagrees
with the data, a truncated TIFF, a zarr store with a missing or
undecodable chunk (which zarr itself would read as zeros, or fail on
deep in a codec) each raise a :class:`~napari_lfalias.errors.DecodeError`
naming the file, and the view where there is one. Sizes are checked
against the memory budget (:mod:`napari_lfalias._budget`) before anything
is allocated.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import numbers
import os
from pathlib import Path

import numpy as np

from . import _budget
from .errors import DecodeError, ParameterError

__all__ = ["FORMAT_NAME", "FORMAT_VERSION", "LIGHTFIELD_SUFFIXES", "is_lightfield_file", "is_zarr_store",
           "output_image_kind", "read_lightfield", "require_zarr"]

#: Marker of the light-field files napari-lfalias writes.
FORMAT_NAME = "napari-lfalias light field"
FORMAT_VERSION = 1
LIGHTFIELD_SUFFIXES = {".tif", ".tiff", ".zarr"}
_REWRITE = "write it again (napari_lfalias.save, or lfalias convert from the capture)"


def require_zarr():
    """The zarr module, or a ParameterError saying how to install it."""
    try:
        import zarr
    except ImportError as exc:  # pragma: no cover - depends on the installation
        raise ParameterError("writing or reading .zarr needs zarr: pip install 'napari-lfalias[dask]'") from exc
    return zarr


@contextlib.contextmanager
def _quiet_tifffile():
    """Keep tifffile's complaints about damaged files off stderr: the DecodeError says it once."""
    logger = logging.getLogger("tifffile")
    level = logger.level
    logger.setLevel(logging.CRITICAL)
    try:
        yield
    finally:
        logger.setLevel(level)


# -- recognising our files ----------------------------------------------------------------------

def _ours(header):
    return isinstance(header, dict) and header.get("format") == FORMAT_NAME


def _hyperstack_header(path):
    import tifffile

    try:
        with _quiet_tifffile(), tifffile.TiffFile(path) as tif:
            info = (tif.imagej_metadata or {}).get("Info")
    except Exception:  # noqa: BLE001 - an unreadable TIFF is "not ours"; the image reader names the damage
        return None
    if not isinstance(info, str) or not info:
        return None
    try:
        header = json.loads(info)
    except ValueError:
        # Ours, but the header is cut or edited: say so rather than "not a light field".
        return {"format": FORMAT_NAME} if FORMAT_NAME in info else None
    return header if _ours(header) else None


def is_zarr_store(path):
    """True for a folder holding zarr group or array metadata (v2 or v3)."""
    path = Path(path)
    return path.is_dir() and any((path / name).is_file() for name in ("zarr.json", ".zgroup", ".zarray"))


def _zarr_header(path):
    if not is_zarr_store(path):
        return None
    zarr = require_zarr()
    try:
        header = dict(zarr.open_group(str(path), mode="r").attrs).get("lfalias")
    except Exception:  # noqa: BLE001 - any unreadable store is "not ours"
        return None
    return header if _ours(header) else None


def is_lightfield_file(path):
    """Return the JSON header if ``path`` is a light field written here, else ``None``.

    The header is returned as found: :func:`read_lightfield` checks it.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".zarr" and path.is_dir():
        return _zarr_header(path)
    if suffix in (".tif", ".tiff") and path.is_file():
        return _hyperstack_header(path)
    return None


def output_image_kind(path):
    """What a one-image TIFF written by napari-lfalias holds (``"image"``, ``"cv"``, ``"mask"``...), else ``None``.

    The commands (``lfalias refocus``, ``detect``, ``reduce``, ``depth``)
    record it as ``content`` in the TIFF's JSON description, the napari
    writer as ``role``. Such a file is a result, not a light field.

    Examples
    --------
    >>> import numpy as np, tempfile, os
    >>> from napari_lfalias import io_write
    >>> path = io_write.write_tiff(os.path.join(tempfile.mkdtemp(), "cv.tif"), np.zeros((4, 4), np.float32),
    ...                            {"content": "cv"})
    >>> output_image_kind(path)
    'cv'
    """
    import tifffile

    from ._napari._writer import OUTPUT_FORMAT

    path = Path(path)
    if path.suffix.lower() not in (".tif", ".tiff") or not path.is_file():
        return None
    try:
        with _quiet_tifffile(), tifffile.TiffFile(path) as tif:
            header = tif.shaped_metadata[0] if tif.shaped_metadata else None
    except Exception:  # noqa: BLE001 - an unreadable TIFF is not ours; its reader names the damage
        return None
    if not isinstance(header, dict):
        return None
    kind = header.get("role") if header.get("format") == OUTPUT_FORMAT else header.get("content")
    return kind if isinstance(kind, str) else None


# -- the header -------------------------------------------------------------------------------------

def _damaged(path, what):
    return DecodeError(f"{path}: {what}; the light-field file is damaged: {_REWRITE}")


def _checked_header(path, header):
    """``(shape, positions, has_weights, meta)`` from a header, or a DecodeError saying what is wrong."""
    version = header.get("version", FORMAT_VERSION)
    if not isinstance(version, int) or version > FORMAT_VERSION:
        raise DecodeError(f"{path}: written in light-field format version {version!r}, newer than this "
                          f"napari-lfalias reads ({FORMAT_VERSION}); update napari-lfalias")
    shape = header.get("shape")
    if (not isinstance(shape, list) or len(shape) != 5
            or not all(isinstance(n, numbers.Integral) and not isinstance(n, bool) and n >= 1 for n in shape)
            or shape[4] not in (1, 3)):
        raise _damaged(path, f"its header gives shape {shape!r}, not (U, V, Y, X, C) with C = 1 or 3")
    shape = tuple(int(n) for n in shape)
    try:
        positions = np.asarray(header.get("positions"), np.float64)
    except (TypeError, ValueError):
        positions = None
    if positions is None or positions.shape != shape[:2] + (2,) or not np.all(np.isfinite(positions)):
        found = "none" if header.get("positions") is None else (
            "ragged or not numbers" if positions is None else f"shape {positions.shape}")
        raise _damaged(path, f"its header's view positions must be finite numbers of shape "
                             f"{shape[:2] + (2,)}; found {found}")
    has_weights = header.get("has_weights", False)
    if not isinstance(has_weights, bool):
        raise _damaged(path, f"its header's has_weights is {has_weights!r}, not true or false")
    meta = header.get("meta") or {}
    if not isinstance(meta, dict):
        raise _damaged(path, "its header's meta is not a JSON object")
    planes = shape[4] + has_weights
    _budget.check(math.prod(shape[:4]) * planes * 4,
                  f"{path}: the {' x '.join(map(str, shape))} light field", DecodeError)
    return shape, positions, has_weights, meta


def _restore_meta(meta):
    """Turn ``{"__json__": "GridModel", ...}`` entries back into objects where possible."""
    out = {}
    for key, value in meta.items():
        if isinstance(value, dict) and value.get("__json__") == "GridModel":
            try:
                from .decoders.lenslet import GridModel

                value = GridModel.from_json(json.dumps(value["value"]))
            except Exception:  # noqa: BLE001 - a grid model that no longer parses stays JSON
                value = value.get("value")
        out[key] = value
    return out


# -- TIFF --------------------------------------------------------------------------------------------

def _read_hyperstack(path, shape, has_weights):
    import tifffile

    n_rows, n_cols, height, width, n_channels = shape
    planes = n_channels + has_weights
    expected = n_rows * n_cols * planes
    try:
        with _quiet_tifffile(), tifffile.TiffFile(path) as tif:
            series = tif.series[0]
            found = math.prod(series.shape) // (height * width) if series.shape[-2:] == (height, width) else None
            if found != expected:
                raise DecodeError(
                    f"{path}: holds {found if found is not None else 'images of another size'} of the {expected} "
                    f"{height} x {width} images its header promises; the file is truncated or damaged: {_REWRITE}"
                )
            offset = series.dataoffset
            if offset is not None and os.path.getsize(path) < offset + expected * height * width * 4:
                raise DecodeError(f"{path}: the file is truncated (its images end early): {_REWRITE}")
            pixels = series.asarray()
    except DecodeError:
        raise
    except Exception as exc:  # noqa: BLE001 - tifffile's error types for damaged files vary
        raise _damaged(path, f"its images cannot be read ({' '.join(str(exc).split()) or type(exc).__name__})") from exc
    stack = np.moveaxis(np.asarray(pixels, np.float32).reshape(n_rows, n_cols, planes, height, width), 2, -1)
    weights = np.ascontiguousarray(stack[..., -1]) if has_weights else None
    data = stack[..., :n_channels]
    return data, weights


# -- zarr --------------------------------------------------------------------------------------------

def _zarr_array(path, group, name, shape):
    try:
        array = group[name] if name in group else None
    except Exception as exc:  # noqa: BLE001 - damaged array metadata raises JSON, KeyError, ValueError, ...
        raise _damaged(path, f"the metadata of its {name!r} array cannot be read ({exc})") from exc
    if array is None or not hasattr(array, "cdata_shape"):
        raise _damaged(path, f"the store has no {name!r} array")
    if tuple(array.shape) != tuple(shape) or not np.issubdtype(np.dtype(str(array.dtype)), np.floating):
        raise _damaged(path, f"its {name!r} array is {array.dtype} {tuple(array.shape)}, the header says "
                             f"float {tuple(shape)}")
    return array


def _view_of_chunk(array, coords):
    """The view ``(u, v)`` a chunk of a (U, V, ...) array starts at."""
    return tuple(int(c) * int(n) for c, n in zip(coords[:2], array.chunks[:2]))


def _check_chunks(path, array, name):
    """Every chunk of ``array`` must be stored: zarr reads a missing chunk as zeros, silently."""
    folder = Path(path) / name
    missing = [coords for coords in np.ndindex(*array.cdata_shape)
               if not (folder / array.metadata.encode_chunk_key(coords)).is_file()]
    if missing:
        u, v = _view_of_chunk(array, missing[0])
        raise DecodeError(
            f"{path}: {len(missing)} of {array.nchunks} chunks of its {name!r} array are missing (the first "
            f"holds view ({u}, {v})); zarr would read them as zeros. The store is incomplete or damaged: {_REWRITE}"
        )


def _read_view(path, array, name, u, v):
    try:
        return array[u, v]
    except Exception as exc:  # noqa: BLE001 - codec errors (a truncated Zstd chunk) have many types
        detail = " ".join(str(exc).split()) or type(exc).__name__
        raise DecodeError(f"{path}: view ({u}, {v}) of its {name!r} array cannot be read ({detail}); "
                          f"the store is damaged: {_REWRITE}") from exc


def _read_all(path, array, name):
    out = np.empty(array.shape, np.float32)
    for u, v in np.ndindex(*array.shape[:2]):
        out[u, v] = _read_view(path, array, name, u, v)
    return out


def _read_lazy(path, array, name):
    import dask.array as da
    from dask.base import tokenize

    def read_block(block_info=None):
        u, v = block_info[None]["chunk-location"][:2]
        return np.asarray(_read_view(path, array, name, u, v), np.float32)[None, None]

    stamp = [(p.name, p.stat().st_mtime_ns, p.stat().st_size) for p in (Path(path) / name).rglob("*") if p.is_file()]
    chunks = tuple((1,) * n for n in array.shape[:2]) + tuple((n,) for n in array.shape[2:])
    return da.map_blocks(read_block, chunks=chunks, dtype=np.float32, meta=np.empty((0,) * array.ndim, np.float32),
                         name=f"lfalias-zarr-{tokenize(str(path), name, stamp)}")


def _read_zarr(path, shape, has_weights, lazy):
    zarr = require_zarr()
    try:
        group = zarr.open_group(str(path), mode="r")
    except Exception as exc:  # noqa: BLE001 - damaged metadata raises many types
        raise _damaged(path, f"the store cannot be opened ({exc})") from exc
    views = _zarr_array(path, group, "views", shape)
    _check_chunks(path, views, "views")
    weights = None
    if has_weights:
        weights_array = _zarr_array(path, group, "weights", shape[:4])
        _check_chunks(path, weights_array, "weights")
        weights = _read_all(path, weights_array, "weights")
    data = _read_lazy(path, views, "views") if lazy else _read_all(path, views, "views")
    return data, weights


def read_lightfield(path, lazy=False, nonfinite="raise"):
    """Read a light field written by :func:`napari_lfalias.save` (``lfalias convert``).

    Prefer :func:`napari_lfalias.load`, which calls this for these files.

    Parameters
    ----------
    path : str or Path
        A ``.tif``/``.tiff`` hyperstack or a ``.zarr`` store.
    lazy : bool
        For zarr: keep the views as a dask array read view by view on
        demand (every chunk is checked to be there now; a damaged one
        raises when computed).
    nonfinite : {"raise", "mask"}
        NaN or Inf samples: refuse them, or give them zero weight (see
        :class:`~napari_lfalias.LightField`).

    Returns
    -------
    LightField

    Raises
    ------
    DecodeError
        If ``path`` is not a light field written by napari-lfalias, or is
        damaged (the message names the file, and the view where it can).

    Examples
    --------
    >>> import numpy as np, tempfile, os
    >>> import napari_lfalias as lfa
    >>> path = os.path.join(tempfile.mkdtemp(), "views.tif")
    >>> _ = lfa.save(lfa.LightField(np.ones((2, 3, 4, 5, 1), np.float32)), path)
    >>> read_lightfield(path).shape
    (2, 3, 4, 5, 1)
    """
    from . import _validate
    from .lightfield import LightField

    path = Path(path)
    _validate.boolean("lazy", lazy)
    header = is_lightfield_file(path)
    if header is None:
        raise DecodeError(f"{path}: not a light field written by napari-lfalias (napari_lfalias.save writes one)")
    shape, positions, has_weights, meta = _checked_header(path, header)
    if path.suffix.lower() == ".zarr":
        data, weights = _read_zarr(path, shape, has_weights, lazy)
    else:
        data, weights = _read_hyperstack(path, shape, has_weights)
    if weights is not None and (not np.all(np.isfinite(weights)) or weights.min() < 0 or weights.max() > 1):
        raise _damaged(path, "its sample weights are not all in [0, 1]")
    meta = _restore_meta(meta)
    meta.setdefault("source", str(path))
    return LightField(data, positions, meta, weights=weights, nonfinite=nonfinite)
