"""Atomic writers: light fields (ImageJ TIFF, zarr), images (TIFF, PNG previews).

Every writer goes through :func:`atomic_output`: the data are written to a
temporary name beside the target (``.<name>.tmp-<random><suffix>``) and moved
into place with :func:`os.replace`, so a crash, a kill or a full disk never
leaves a half-written file under the final name. An existing output is
replaced only with ``overwrite=True``; otherwise :class:`OutputExistsError`.

A light field written by :func:`write_lightfield` reads back with
:func:`read_lightfield` with its view positions, sample weights and
metadata (the lenslet grid model as JSON among them):

- ``.tif``/``.tiff``: an ImageJ hyperstack, axes ``TZCYX`` = (U, V, C, Y, X),
  float32, one page per view and channel; the JSON header is the ImageJ
  ``Info`` property. Sample weights, when present, are one more channel.
- ``.zarr``: a zarr group with a ``views`` array (U, V, Y, X, C) chunked one
  view per chunk, an optional ``weights`` array, and the JSON in its
  attributes.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import uuid
from pathlib import Path

import numpy as np

from .errors import DecodeError, OutputExistsError, ParameterError

__all__ = [
    "FORMAT_NAME",
    "TEMP_MARK",
    "atomic_output",
    "check_output",
    "check_not_inputs",
    "is_temporary",
    "remove_temporaries",
    "write_tiff",
    "write_png",
    "write_image",
    "write_json",
    "to_preview",
    "write_lightfield",
    "read_lightfield",
    "lightfield_header",
    "is_lightfield_file",
]

#: Marker of the light-field files this module writes.
FORMAT_NAME = "napari-lfalias light field"
FORMAT_VERSION = 1
#: Part of every temporary name (see :func:`is_temporary`).
TEMP_MARK = ".tmp-"

LIGHTFIELD_SUFFIXES = {".tif", ".tiff", ".zarr"}
IMAGE_SUFFIXES = {".tif", ".tiff", ".png"}


# -- atomic replacement -----------------------------------------------------


def check_output(path, overwrite=False):
    """Raise :class:`OutputExistsError` if ``path`` exists and ``overwrite`` is false.

    Parameters
    ----------
    path : str or Path
        The output about to be written.
    overwrite : bool
        Whether an existing output may be replaced.

    Returns
    -------
    Path
    """
    path = Path(path)
    if path.exists() and not overwrite:
        raise OutputExistsError(f"{path}: output exists; pass --overwrite (overwrite=True) to replace it")
    if not path.parent.is_dir():
        raise ParameterError(f"{path}: the output folder {path.parent} does not exist; create it first")
    return path


def check_not_inputs(outputs, inputs):
    """Raise :class:`ParameterError` if an output would replace an input or write into an input folder.

    ``--overwrite`` replaces outputs, never what the user gave: a light field
    converted onto itself, or a refocus written into its folder of views
    (which would then hold one image too many), is refused.

    Parameters
    ----------
    outputs : iterable of str or Path
    inputs : iterable of str or Path or None
        Input files and folders (``None`` entries are ignored).
    """
    sources = [(given, Path(given).resolve()) for given in inputs if given is not None]
    for output in outputs:
        target = Path(output).resolve()
        for given, source in sources:
            if target == source:
                raise ParameterError(f"{output}: this is an input; write the output under another name")
            if source in target.parents:
                raise ParameterError(f"{output}: inside the input folder {given}; write the output elsewhere")


def _temporary_name(path):
    return path.with_name(f".{path.name}{TEMP_MARK}{uuid.uuid4().hex[:12]}{path.suffix}")


def is_temporary(path):
    """True if ``path`` is a temporary name made by :func:`atomic_output`."""
    name = Path(path).name
    return name.startswith(".") and TEMP_MARK in name


def remove_temporaries(folder):
    """Remove temporaries left in ``folder`` by writers that were killed.

    Only call it when no writer is running in ``folder``.

    Returns
    -------
    list of Path
        What was removed.
    """
    removed = []
    for path in Path(folder).iterdir():
        if is_temporary(path):
            _remove(path)
            removed.append(path)
    return removed


def _remove(path):
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()


def _replace(tmp, path):
    """Move ``tmp`` onto ``path``; a folder target is moved aside first."""
    if path.is_dir() and not path.is_symlink():
        # os.replace cannot replace a non-empty folder: move the old one aside.
        old = path.with_name(f".{path.name}{TEMP_MARK}old-{uuid.uuid4().hex[:12]}")
        os.replace(path, old)
        os.replace(tmp, path)
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.replace(tmp, path)


@contextlib.contextmanager
def atomic_output(path, overwrite=False):
    """Context manager yielding a temporary path that becomes ``path`` on success.

    Parameters
    ----------
    path : str or Path
        The final output (a file, or a folder such as a zarr store).
    overwrite : bool
        Replace an existing ``path``; otherwise raise
        :class:`OutputExistsError` before anything is written.

    Yields
    ------
    Path
        A fresh name in the same folder, with the same suffix (so writers
        that pick a format from the suffix still do). Write there; if the
        block raises, the temporary is removed and ``path`` is untouched.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> out = pathlib.Path(tempfile.mkdtemp()) / "a.txt"
    >>> with atomic_output(out) as tmp:
    ...     _ = tmp.write_text("hello")
    >>> out.read_text()
    'hello'
    """
    path = check_output(path, overwrite)
    tmp = _temporary_name(path)
    try:
        yield tmp
        if not tmp.exists():
            raise RuntimeError(f"the writer of {path} wrote nothing")
        if path.exists() and not overwrite:
            raise OutputExistsError(f"{path}: output appeared while writing; pass --overwrite to replace it")
        _replace(tmp, path)
    finally:
        if tmp.exists():
            _remove(tmp)


# -- JSON ---------------------------------------------------------------------


def _jsonable(value, max_items=4096):
    """Convert metadata to JSON types; big arrays become a shape note, unknown objects are dropped."""
    if value is None or isinstance(value, (bool, int, float, str)):
        if isinstance(value, float) and not np.isfinite(value):
            return None
        return value
    if isinstance(value, np.generic):
        return _jsonable(value.item())
    if isinstance(value, Path):
        return str(value)
    if hasattr(value, "to_json"):
        return {"__json__": type(value).__name__, "value": json.loads(value.to_json())}
    if isinstance(value, np.ndarray):
        if value.size > max_items:
            return {"__array__": "omitted", "shape": list(value.shape), "dtype": str(value.dtype)}
        return _jsonable(value.tolist())
    if isinstance(value, dict):
        out = {}
        for key, item in value.items():
            converted = _jsonable(item)
            if converted is not _DROP:
                out[str(key)] = converted
        return out
    if isinstance(value, (list, tuple)):
        return [item for item in (_jsonable(v) for v in value) if item is not _DROP]
    return _DROP


_DROP = object()


def write_json(path, obj, overwrite=False):
    """Write ``obj`` as JSON, atomically (an object with ``to_json()`` writes that)."""
    text = obj.to_json() if hasattr(obj, "to_json") else json.dumps(_jsonable(obj), indent=2)
    with atomic_output(path, overwrite) as tmp:
        tmp.write_text(text + "\n")
    return Path(path)


# -- images -------------------------------------------------------------------


def _image_array(image, name="image"):
    image = np.asarray(image)
    if image.ndim == 3 and image.shape[-1] == 1:
        image = image[..., 0]
    if image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[-1] not in (3, 4)):
        raise ParameterError(f"{name} must be (Y, X), (Y, X, 1) or (Y, X, 3); got shape {image.shape}")
    return image


def to_preview(image, vmin=0.0, vmax=1.0, auto_contrast=False):
    """Map an image to 8-bit for a PNG preview.

    Parameters
    ----------
    image : ndarray, shape (Y, X[, C])
        The image (float, bool or integer).
    vmin, vmax : float
        The values mapped to 0 and 255 (ignored for bool images).
    auto_contrast : bool
        Map the 0.5 and 99.5 percentiles instead of ``vmin, vmax``.

    Returns
    -------
    ndarray of uint8
    """
    image = _image_array(image)
    if image.dtype == np.bool_:
        return image.astype(np.uint8) * 255
    image = image.astype(np.float32)
    if auto_contrast:
        finite = image[np.isfinite(image)]
        if finite.size:
            vmin, vmax = (float(v) for v in np.percentile(finite, [0.5, 99.5]))
    if not vmax > vmin:
        vmax = vmin + 1.0
    scaled = (np.nan_to_num(image, nan=vmin) - vmin) / (vmax - vmin)
    return np.round(np.clip(scaled, 0, 1) * 255).astype(np.uint8)


def write_png(path, image, overwrite=False, zoom=1, **preview):
    """Write an 8-bit PNG preview of ``image`` atomically (see :func:`to_preview`).

    Parameters
    ----------
    path : str or Path
    image : ndarray, shape (Y, X[, C])
        uint8 pixels are written as they are; anything else through
        :func:`to_preview` with ``**preview``.
    overwrite : bool
    zoom : int
        Enlarge by this whole factor, nearest neighbour (every pixel a
        visible block), for views too small to look at.
    """
    import imageio.v3 as iio

    pixels = image if np.asarray(image).dtype == np.uint8 else to_preview(image, **preview)
    zoom = int(zoom)
    if zoom < 1:
        raise ParameterError(f"zoom must be a whole number >= 1, got {zoom}")
    if zoom > 1:
        pixels = np.repeat(np.repeat(pixels, zoom, axis=0), zoom, axis=1)
    with atomic_output(path, overwrite) as tmp:
        iio.imwrite(tmp, pixels, extension=".png")
    return Path(path)


def write_tiff(path, data, metadata=None, overwrite=False, **tiff_kw):
    """Write ``data`` to a TIFF atomically, with JSON ``metadata`` in its description.

    Parameters
    ----------
    path : str or Path
        The output file.
    data : ndarray
        The pixels; float data are kept in full precision.
    metadata : dict, optional
        Stored as JSON by tifffile (read back with
        ``tifffile.TiffFile(path).shaped_metadata``).
    overwrite : bool
        Replace an existing file.
    **tiff_kw
        Passed to :func:`tifffile.imwrite` (``imagej``, ``photometric``, ...).
    """
    import tifffile

    data = np.asarray(data)
    if data.dtype == np.bool_:
        data = data.astype(np.uint8)
    if not tiff_kw.get("imagej"):
        tiff_kw.setdefault("metadata", _jsonable(metadata or {}))
    if data.ndim == 3 and data.shape[-1] == 3 and not tiff_kw.get("imagej"):
        tiff_kw.setdefault("photometric", "rgb")
    with atomic_output(path, overwrite) as tmp:
        tifffile.imwrite(tmp, data, **tiff_kw)
    return Path(path)


def write_image(path, image, metadata=None, overwrite=False, **preview):
    """Write an image as a float TIFF or an 8-bit PNG preview, by the suffix of ``path``.

    Parameters
    ----------
    path : str or Path
        ``.tif``/``.tiff`` (exact values and ``metadata``) or ``.png``.
    image : ndarray, shape (Y, X[, C])
    metadata : dict, optional
        Stored in a TIFF; ignored for PNG.
    overwrite : bool
    **preview
        ``vmin``, ``vmax``, ``auto_contrast`` of :func:`to_preview` and
        ``zoom`` of :func:`write_png` (PNG only).
    """
    path = Path(path)
    suffix = path.suffix.lower()
    image = _image_array(image)
    if suffix in (".tif", ".tiff"):
        return write_tiff(path, image, metadata, overwrite)
    if suffix == ".png":
        return write_png(path, image, overwrite, **preview)
    raise ParameterError(f"{path}: unsupported image suffix {path.suffix!r}; use .png, .tif or .tiff")


# -- light fields -----------------------------------------------------------


def lightfield_header(lf):
    """The JSON header stored with a light field: shape, positions, metadata."""
    return {
        "format": FORMAT_NAME,
        "version": FORMAT_VERSION,
        "shape": list(lf.shape),
        "positions": lf.positions.tolist(),
        "has_weights": lf.weights is not None,
        "meta": _jsonable(lf.meta),
    }


def write_lightfield(path, lf, overwrite=False):
    """Write a light field to an ImageJ hyperstack TIFF or a zarr store, atomically.

    Parameters
    ----------
    path : str or Path
        ``.tif``/``.tiff`` or ``.zarr`` (see the module docstring).
    lf : LightField
    overwrite : bool
        Replace an existing output.

    Returns
    -------
    Path

    Raises
    ------
    ParameterError
        For an unsupported suffix.
    OutputExistsError
        If ``path`` exists and ``overwrite`` is false.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in LIGHTFIELD_SUFFIXES:
        raise ParameterError(
            f"{path}: cannot write a light field as {path.suffix!r}; use .tif, .tiff or .zarr"
        )
    if lf.is_lazy:
        lf = lf.compute()
    header = lightfield_header(lf)
    if suffix == ".zarr":
        return _write_zarr(path, lf, header, overwrite)
    return _write_hyperstack(path, lf, header, overwrite)


def _write_hyperstack(path, lf, header, overwrite):
    import tifffile

    data = np.asarray(lf.data, np.float32)
    n_rows, n_cols = lf.grid_shape
    channels = [f"c{c}" for c in range(lf.n_channels)]
    if lf.weights is not None:
        data = np.concatenate([data, lf.weights[..., None].astype(np.float32)], axis=-1)
        channels.append("weight")
    stack = np.ascontiguousarray(np.moveaxis(data, -1, 2))  # (U, V, C, Y, X)
    labels = [f"u={u} v={v} {c}" for u in range(n_rows) for v in range(n_cols) for c in channels]
    metadata = {"axes": "TZCYX", "Info": json.dumps(header), "Labels": labels}
    with atomic_output(path, overwrite) as tmp:
        tifffile.imwrite(tmp, stack, imagej=True, metadata=metadata)
    return path


def _require_zarr():
    try:
        import zarr
    except ImportError as exc:  # pragma: no cover - depends on the installation
        raise ParameterError(
            "writing or reading .zarr needs zarr: pip install 'napari-lfalias[dask]'"
        ) from exc
    return zarr


def _write_zarr(path, lf, header, overwrite):
    zarr = _require_zarr()
    data = np.asarray(lf.data, np.float32)
    with atomic_output(path, overwrite) as tmp:
        group = zarr.open_group(str(tmp), mode="w")
        views = group.create_array("views", shape=data.shape, dtype="float32", chunks=(1, 1) + data.shape[2:])
        views[...] = data
        if lf.weights is not None:
            weights = group.create_array(
                "weights", shape=lf.weights.shape, dtype="float32", chunks=(1, 1) + lf.weights.shape[2:]
            )
            weights[...] = lf.weights
        group.attrs.update({"lfalias": header})
    return path


def _hyperstack_header(path):
    import tifffile

    try:
        with tifffile.TiffFile(path) as tif:
            info = (tif.imagej_metadata or {}).get("Info")
    except (OSError, ValueError, tifffile.TiffFileError):
        return None
    if not info:
        return None
    try:
        header = json.loads(info)
    except ValueError:
        return None
    return header if isinstance(header, dict) and header.get("format") == FORMAT_NAME else None


def _zarr_header(path):
    if not (Path(path) / "zarr.json").exists() and not (Path(path) / ".zgroup").exists():
        return None
    zarr = _require_zarr()
    try:
        header = dict(zarr.open_group(str(path), mode="r").attrs).get("lfalias")
    except Exception:  # noqa: BLE001 - any unreadable store is "not ours"
        return None
    return header if isinstance(header, dict) and header.get("format") == FORMAT_NAME else None


def is_lightfield_file(path):
    """Return the JSON header if ``path`` is a light field written here, else ``None``."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".zarr" and path.is_dir():
        return _zarr_header(path)
    if suffix in (".tif", ".tiff") and path.is_file():
        return _hyperstack_header(path)
    return None


def _restore_meta(meta):
    """Turn ``{"__json__": "GridModel", ...}`` entries back into objects where possible."""
    out = {}
    for key, value in (meta or {}).items():
        if isinstance(value, dict) and value.get("__json__") == "GridModel":
            try:
                from .decoders.lenslet import GridModel

                value = GridModel.from_json(json.dumps(value["value"]))
            except (ImportError, AttributeError):
                value = value["value"]
        out[key] = value
    return out


def read_lightfield(path, lazy=False):
    """Read a light field written by :func:`write_lightfield`.

    Parameters
    ----------
    path : str or Path
        A ``.tif``/``.tiff`` hyperstack or a ``.zarr`` store.
    lazy : bool
        For zarr: keep the views as a dask array read on demand.

    Returns
    -------
    LightField

    Raises
    ------
    DecodeError
        If ``path`` is not a light field written by napari-lfalias.
    """
    from .lightfield import LightField

    path = Path(path)
    header = is_lightfield_file(path)
    if header is None:
        raise DecodeError(
            f"{path}: not a light field written by napari-lfalias (`lfalias convert` makes one)"
        )
    if path.suffix.lower() == ".zarr":
        zarr = _require_zarr()
        group = zarr.open_group(str(path), mode="r")
        if lazy:
            import dask.array as da

            data = da.from_zarr(group["views"])
        else:
            data = group["views"][...]
        weights = group["weights"][...] if "weights" in group else None
    else:
        import tifffile

        n_rows, n_cols, height, width, n_channels = header["shape"]
        planes = n_channels + bool(header["has_weights"])
        pixels = tifffile.imread(path)  # ImageJ drops axes of length 1: reshape, never trust ndim
        if pixels.size != n_rows * n_cols * planes * height * width:
            raise DecodeError(f"{path}: header says shape {header['shape']}, the file holds {pixels.shape}")
        stack = np.moveaxis(pixels.reshape(n_rows, n_cols, planes, height, width), 2, -1)
        weights = stack[..., -1] if header["has_weights"] else None
        data = stack[..., :-1] if header["has_weights"] else stack
    if list(data.shape) != header["shape"]:
        raise DecodeError(f"{path}: header says shape {header['shape']}, the data have {list(data.shape)}")
    meta = _restore_meta(header.get("meta"))
    meta.setdefault("source", str(path))
    return LightField(data, np.asarray(header["positions"]), meta, weights=weights)
