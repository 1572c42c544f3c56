"""``load`` and ``save``: one entry point for every light-field source, and its inverse.

Whatever :func:`save` (or ``lfalias convert``) writes, :func:`load` reads
back with its view positions, sample weights and metadata.
"""

from __future__ import annotations

from pathlib import Path

from .errors import DecodeError, NonFiniteError, ParameterError

__all__ = ["load", "save"]

#: File suffixes of Lytro containers (read through imageio's Lytro plugin).
LYTRO_SUFFIXES = {".lfr", ".lfp", ".raw"}
#: Options of :func:`load` for a light field written by :func:`save`.
_SAVED_OPTIONS = ("lazy", "nonfinite")


def _load_saved(path, options):
    from .io_read import read_lightfield

    unknown = sorted(set(options) - set(_SAVED_OPTIONS))
    if unknown:
        raise ParameterError(
            f"{path}: a light field saved by napari-lfalias is already decoded; {', '.join(unknown)} do not "
            f"apply (accepted: {', '.join(_SAVED_OPTIONS)})"
        )
    return read_lightfield(path, **options)


def load(path, **options):
    """Load a light field: a saved one, a folder of views, or a lenslet capture.

    Parameters
    ----------
    path : str or Path
        - a ``.tif``/``.zarr`` light field written by :func:`save` or
          ``lfalias convert`` (options: ``lazy``, ``nonfinite``): see
          :func:`napari_lfalias.io_read.read_lightfield`;
        - a folder of views (HCI benchmark ``input_CamNNN.png``, Stanford
          ``out_RR_CC_y_x.png``, names with row/column indices, or a plain
          sorted list with ``grid=(U, V)``; views missing from the grid get
          weight 0; black borders, clearly vignetted views and clipped
          light get the weights a calibrated camera would give them,
          ``artefacts=False`` keeps the files' values): see
          :func:`napari_lfalias.decoders.camera_array.load_camera_array`;
        - a lenslet raw image (TIFF, PNG, camera raw, DNG) with
          ``white=...``, or a Lytro LFR/LFP/RAW file: see
          :func:`napari_lfalias.decoders.lenslet.load_lenslet`.
    **options
        Passed to the reader (``grid``, ``lazy``, ``nonfinite``,
        ``artefacts``, ``white``, ``dark``, ...).

    Returns
    -------
    LightField

    Raises
    ------
    DecodeError
        If the path does not exist, is not a recognised light-field source,
        or is damaged (the message names the file).
    ParameterError
        For an option the source does not take.

    Examples
    --------
    >>> import numpy as np, tempfile, os
    >>> import napari_lfalias as lfa
    >>> path = os.path.join(tempfile.mkdtemp(), "views.tif")
    >>> _ = lfa.save(lfa.LightField(np.zeros((3, 3, 8, 8, 1), np.float32)), path)
    >>> lfa.load(path).shape
    (3, 3, 8, 8, 1)
    """
    from .io_read import is_lightfield_file, is_zarr_store, output_image_kind

    path = Path(path)
    if not path.exists():
        raise DecodeError(f"{path}: no such file or folder")
    if is_lightfield_file(path) is not None:
        return _load_saved(path, options)
    if is_zarr_store(path):
        raise DecodeError(
            f"{path}: a zarr store without a napari-lfalias light-field header (its attributes lack 'lfalias', "
            "or cannot be read); napari_lfalias.save writes one"
        )
    if path.is_dir():
        from .decoders.camera_array import load_camera_array

        return load_camera_array(path, **options)
    kind = output_image_kind(path)
    if kind is not None:
        raise DecodeError(
            f"{path}: a result written by napari-lfalias ({kind!r}, one image), not a light field: read it with "
            "tifffile.imread, or open it in napari; load the light field it was computed from"
        )
    from .decoders.lenslet import load_lenslet

    try:
        return load_lenslet(path, **options)
    except NonFiniteError as exc:  # its advice (nonfinite=) is for arrays, folders and saved files
        raise DecodeError(
            f"{path}: the decoded light field holds NaN or Inf samples; they come from NaN or Inf pixels of "
            "the capture, white or dark image: replace those pixels"
        ) from exc


def save(lf, path, overwrite=False):
    """Write a light field that :func:`load` reads back: an ImageJ TIFF or a zarr store.

    The data, view positions, sample weights and metadata (a lenslet grid
    model among them) are kept. The file is written to a temporary name
    beside ``path`` and moved into place when complete, so a crash or a
    full disk never leaves a partial file under ``path``.

    Parameters
    ----------
    lf : LightField
        A lazy light field is computed first.
    path : str or Path
        ``.tif``/``.tiff``: an ImageJ hyperstack (axes TZCYX = U V C Y X,
        float32; it opens in Fiji). ``.zarr``: a zarr store, one view per
        chunk (needs the ``[dask]`` extra).
    overwrite : bool
        Replace an existing ``path``; otherwise :class:`OutputExistsError`.

    Returns
    -------
    Path

    Raises
    ------
    ParameterError
        For something that is not a LightField, or an unsupported suffix.
    OutputExistsError
        If ``path`` exists and ``overwrite`` is false.

    Examples
    --------
    >>> import numpy as np, tempfile, os
    >>> import napari_lfalias as lfa
    >>> lf = lfa.LightField(np.random.default_rng(0).random((2, 2, 4, 4, 3), np.float32))
    >>> path = lfa.save(lf, os.path.join(tempfile.mkdtemp(), "views.tif"))
    >>> back = lfa.load(path)
    >>> bool((back.data == lf.data).all()), back.positions.tolist() == lf.positions.tolist()
    (True, True)
    """
    from . import _validate
    from .io_write import write_lightfield
    from .lightfield import LightField

    if not isinstance(lf, LightField):
        raise ParameterError(f"lf must be a napari_lfalias.LightField, got {type(lf).__name__}")
    if not isinstance(path, (str, Path)):
        raise ParameterError(f"path must be a file name (str or Path), got {type(path).__name__}")
    _validate.boolean("overwrite", overwrite)
    return write_lightfield(path, lf, overwrite=overwrite)
