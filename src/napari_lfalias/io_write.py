"""Atomic writers: light fields (ImageJ TIFF, zarr), images (TIFF, PNG previews).

Every writer goes through :func:`atomic_output`: the data are written to a
temporary name beside the target (``.<name>.tmp-<host>-<pid>-<random><suffix>``)
and moved into place (:mod:`napari_lfalias._atomic`: a folder is exchanged
atomically), so a crash, a kill or a full disk never leaves a half-written
file under the final name, and never leaves the final name missing. The
temporaries of killed writers are removed the next time their target is
written. An existing output is replaced only with ``overwrite=True``;
otherwise :class:`OutputExistsError`.

A light field written by :func:`write_lightfield` (:func:`napari_lfalias.save`)
reads back with :func:`napari_lfalias.load` with its view positions, sample
weights and metadata (the lenslet grid model as JSON among them); the two
formats and their checks are described in :mod:`napari_lfalias.io_read`.
A zarr write interrupted by Ctrl-C stops after the view in flight and
removes its temporary store before the interrupt goes on.
"""

from __future__ import annotations

import contextlib
import json
import shutil
import threading
from pathlib import Path

import numpy as np

from . import _atomic, _budget, _validate
from ._budget import describe_bytes
from .errors import OutputExistsError, ParameterError
from .io_read import (  # the readers of what is written here, re-exported
    FORMAT_NAME,
    FORMAT_VERSION,
    LIGHTFIELD_SUFFIXES,
    is_lightfield_file,
    read_lightfield,
    require_zarr,
)

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

#: Part of every temporary name (see :func:`is_temporary`).
TEMP_MARK = _atomic.TEMP_MARK

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
        raise OutputExistsError(f"{path}: output exists; pass overwrite=True to replace it")
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


def is_temporary(path):
    """True if ``path`` is a temporary name made by :func:`atomic_output`."""
    return _atomic.is_temporary(path)


def remove_temporaries(folder):
    """Remove every temporary in ``folder`` left by writers that were killed.

    Only call it when no writer is running in ``folder``; a backup of an
    output whose replacement was cut short is put back, not removed.
    :func:`atomic_output` itself removes the temporaries of dead writers of
    its own target whenever it runs.

    Returns
    -------
    list of Path
        What was removed.
    """
    return _atomic.remove_all(folder)


def _short_write(exc, path):
    """Say what a write that stopped short without an error number means (numpy's ``tofile``)."""
    try:
        free = shutil.disk_usage(path.parent).free
    except OSError:
        return str(exc)
    return f"the write stopped short ({exc}); {describe_bytes(free)} left on its disk"


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
    _atomic.remove_stale(path.parent, path.name)
    tmp = _atomic.temporary_name(path)
    try:
        yield tmp
        if not tmp.exists():
            raise RuntimeError(f"the writer of {path} wrote nothing")
        if path.exists() and not overwrite:
            raise OutputExistsError(f"{path}: output appeared while writing; pass overwrite=True to replace it")
        _atomic.replace(tmp, path)
    except OSError as exc:
        if exc.filename is None:  # a full disk deep in a writer names no file: name the output
            raise OSError(exc.errno, exc.strerror or _short_write(exc, path), str(path)) from exc
        raise
    finally:
        if tmp.exists() or tmp.is_symlink():
            _atomic.discard(tmp)


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
    zoom = _validate.integer_at_least("zoom", zoom, 1)
    if zoom > 1:
        _budget.check(np.asarray(pixels).nbytes * zoom**2, f"zoom={zoom}: the enlarged preview")
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


def _stop_cleanly(work):
    """Run ``work(stop)`` in a thread; on Ctrl-C set ``stop``, wait for it to end, then re-raise.

    zarr writes on its own event-loop thread: an interrupt that unwinds the
    caller while chunks are in flight leaves them writing into a temporary
    store that is being removed (and asyncio complaining at exit). ``work``
    checks ``stop`` between views, so the wait is at most one view.
    """
    stop, done = threading.Event(), threading.Event()
    failure = []

    def run():
        try:
            work(stop)
        except BaseException as exc:  # noqa: BLE001 - handed to the caller's thread
            failure.append(exc)
        finally:
            done.set()

    # Waited on through an Event: an interrupted Thread.join can mark a running thread stopped.
    thread = threading.Thread(target=run, name="lfalias-zarr-writer", daemon=True)
    interrupted = None
    try:
        thread.start()
    except KeyboardInterrupt as exc:  # start() waits for the thread to run: Ctrl-C can land there too
        interrupted = exc
        stop.set()
        if thread.ident is None:  # it never started: nothing to wait for
            done.set()
    while not done.is_set():
        try:
            done.wait(0.05)
        except KeyboardInterrupt as exc:
            interrupted = exc
            stop.set()
    if interrupted is not None:
        raise interrupted
    if failure:
        raise failure[0]


def _write_zarr(path, lf, header, overwrite):
    zarr = require_zarr()
    data = np.asarray(lf.data, np.float32)
    arrays = [("views", data)] + ([("weights", lf.weights.astype(np.float32))] if lf.weights is not None else [])

    def write(tmp, stop):
        group = zarr.open_group(str(tmp), mode="w")
        for name, array in arrays:
            # Every chunk stored, zeros too: a missing chunk then always means damage (io_read).
            stored = group.create_array(name, shape=array.shape, dtype="float32", chunks=(1, 1) + array.shape[2:],
                                        config={"write_empty_chunks": True})
            for u, v in np.ndindex(*array.shape[:2]):  # one chunk per call: nothing left in flight
                if stop.is_set():
                    return
                stored[u, v] = array[u, v]
        group.attrs.update({"lfalias": header})

    with atomic_output(path, overwrite) as tmp:
        _stop_cleanly(lambda stop: write(tmp, stop))
    return path

