"""napari writers: light fields, and the aliasing widget's outputs with their parameters.

**File > Save Selected Layer(s)...** offers these for one layer (choose the
*Light fields* file type):

- a light-field layer is written by
  :func:`napari_lfalias.io_write.write_lightfield` (an ImageJ hyperstack
  ``.tif`` or a ``.zarr`` store, with its view positions, weights and
  metadata), which the plugin's readers (and ``io_write.read_lightfield``) open again;
- an output of the aliasing widget (refocused image, Cv, mask, level map,
  reduced image) is written as a float (or integer) TIFF whose JSON
  description holds its role, the light-field layer it came from, the
  parameters it was computed with and where its pixels lie; the plugin's
  reader opens it again as the same kind of layer (:func:`read_output`).

Files are written atomically. napari's save dialog asks before replacing a
file; the file a light field was read from is never replaced.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import LightFieldError, ParameterError
from ._layers import FILE_KEY, LIGHTFIELD_KEY, PARAMS_KEY, ROLE_KEY, ROLES, SOURCE_KEY

__all__ = ["write_layer", "read_output", "output_header", "output_file_header", "OUTPUT_FORMAT"]

#: Marker of the output files written here.
OUTPUT_FORMAT = "napari-lfalias output"
OUTPUT_VERSION = 1
_OUTPUT_SUFFIXES = (".tif", ".tiff")


def _never_the_source(path, lf):
    source = lf.meta.get("source")
    if source is not None and Path(source).resolve() == Path(path).resolve():
        raise ParameterError(
            f"{path}: this is the file the light field was read from; choose another name "
            "(a saved light field never replaces its source)"
        )


def _calibration(meta):
    return {key: [float(v) for v in meta[key][-2:]] for key in ("scale", "translate") if key in meta}


def _units(meta):
    units = meta.get("units")
    return [str(unit) for unit in units[-2:]] if units is not None else None


def write_layer(path, data, meta):
    """Write one napari layer: a light field, or an output of the aliasing widget.

    napari's single-layer writer contract: ``data`` is the layer's data,
    ``meta`` its attributes (``meta["metadata"]`` holds the LightField or
    the output's role and parameters).

    Returns
    -------
    list of str
        The file written.

    Raises
    ------
    LightFieldError
        For a layer that is neither, or a suffix that cannot hold it.
    """
    from ..io_write import write_lightfield, write_tiff

    path = Path(path)
    metadata = meta.get("metadata") or {}
    lf = metadata.get(LIGHTFIELD_KEY)
    if lf is not None:
        _never_the_source(path, lf)
        return [str(write_lightfield(path, lf, overwrite=True))]
    role = metadata.get(ROLE_KEY)
    if role not in ROLES:
        raise ParameterError(
            f"layer {meta.get('name')!r} is neither a light field nor an output of the aliasing widget; "
            "save it with napari's own writer (another file type in the save dialog)"
        )
    if path.suffix.lower() not in _OUTPUT_SUFFIXES:
        raise ParameterError(f"{path}: an output is saved as .tif or .tiff (exact values and parameters)")
    header = output_header(role, metadata.get(SOURCE_KEY), metadata.get(PARAMS_KEY), meta)
    return [str(write_tiff(path, np.asarray(data), metadata=header, overwrite=True))]


def output_header(role, source, params, meta=None):
    """The JSON description of a saved output: role, source layer, parameters, where its pixels lie.

    (:func:`~napari_lfalias.io_write.write_tiff` turns the values into JSON types.)
    """
    meta = meta or {}
    return {
        "format": OUTPUT_FORMAT,
        "version": OUTPUT_VERSION,
        "role": role,
        "source": source,
        "params": params or {},
        "name": meta.get("name"),
        **_calibration(meta),
        "units": _units(meta),
    }


def output_file_header(path):
    """The header of an output TIFF written here, or ``None`` (from the TIFF's description only)."""
    import tifffile

    path = Path(path)
    if path.suffix.lower() not in _OUTPUT_SUFFIXES or not path.is_file():
        return None
    try:
        with tifffile.TiffFile(path) as tif:
            header = tif.shaped_metadata[0] if tif.shaped_metadata else None
    except Exception:  # noqa: BLE001 - an unreadable TIFF is not ours
        return None
    if not isinstance(header, dict) or header.get("format") != OUTPUT_FORMAT or header.get("role") not in ROLES:
        return None
    return header


def read_output(path):
    """The layer-data tuple of an output saved by :func:`write_layer`.

    The layer is the same kind as the one saved (labels for the mask and
    level map), shown by the same rules, with ``metadata["lfalias"]``,
    ``["lfalias_source"]`` and ``["lfalias_params"]`` as they were, and
    ``["lfalias_file"]`` naming the file (the widget never writes over such
    a layer).

    Raises
    ------
    LightFieldError
        If ``path`` is not an output written here.
    """
    import tifffile

    header = output_file_header(path)
    if header is None:
        raise LightFieldError(f"{path}: not an output saved by napari-lfalias")
    data = tifffile.imread(path)
    spec = ROLES[header["role"]]
    kwargs = dict(spec.kwargs)
    kwargs.update(
        name=header.get("name") or Path(path).stem,
        metadata={ROLE_KEY: header["role"], SOURCE_KEY: header.get("source"),
                  PARAMS_KEY: header.get("params"), FILE_KEY: str(path)},
    )
    for key in ("scale", "translate"):
        if header.get(key):
            kwargs[key] = tuple(header[key])
    if header.get("units"):
        kwargs["units"] = tuple(header["units"])
    if spec.layer_type == "image":
        kwargs["rgb"] = data.ndim == 3 and data.shape[-1] in (3, 4)
    return (data, kwargs, spec.layer_type)
