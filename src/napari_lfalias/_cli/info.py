"""The ``info`` subcommand: what a file or folder holds."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .. import io_read, io_write
from .._inputs import open_input
from ..errors import DecodeError

__all__ = ["run_info", "describe"]


def _image_facts(path):
    """Shape and dtype of a plain image file, without decoding it as a light field.

    A view-image file is decoded (within the memory budget), so that a
    truncated or damaged one is named here rather than described. What
    imageio cannot describe (a Lytro container, a camera raw) is read as a
    lenslet sensor image, whose reader says what is wrong with it (a
    processed Lytro picture has no raw image).
    """
    import imageio.v3 as iio

    from ..decoders.images import decode_image, is_image_file
    from ..decoders.sensor import read_sensor

    if is_image_file(path):
        pixels = decode_image(path)
        shape = pixels.shape if pixels.shape[-1] == 3 else pixels.shape[:2]
        return {"image_shape": list(shape), "dtype": str(pixels.dtype)}
    try:
        props = iio.improps(path)
    except Exception:  # noqa: BLE001 - imageio raises many kinds for unreadable files
        sensor = read_sensor(path)
        return {"image_shape": list(sensor.shape), "dtype": str(np.asarray(sensor).dtype), "bayer": sensor.bayer}
    return {"image_shape": list(props.shape), "dtype": str(props.dtype)}


def _grid_facts(grid):
    if grid is None:
        return None
    if hasattr(grid, "to_json"):
        return json.loads(grid.to_json())
    return grid if isinstance(grid, dict) else str(grid)


def _disparity_facts(lf):
    from ..sweep import disparity_range

    low, high, source = disparity_range(lf)
    if source == "estimated":
        source = "estimated (5th-95th percentile of photo-consistent slopes)"
    return {"min": low, "max": high, "from": source}


def describe(path, white=None, dark=None, grid=None, nonfinite=None):
    """Return the facts about ``path`` as a dict (what ``lfalias info --json`` prints)."""
    path = Path(path)
    if not path.exists():
        raise DecodeError(f"{path}: no such file or folder")
    header = io_write.is_lightfield_file(path)
    facts = {"path": str(path)}
    if header is not None:
        facts["format"] = f"{io_write.FORMAT_NAME} ({'zarr store' if path.suffix.lower() == '.zarr' else 'ImageJ TIFF'})"
    elif path.is_dir():
        facts["format"] = "folder of views (camera array)"
    elif (kind := io_read.output_image_kind(path)) is not None:
        facts["format"] = f"napari-lfalias result ({kind!r}, one image), not a light field"
        facts.update(_image_facts(path))
        return facts
    elif white is None and grid is None:
        facts["format"] = "image file (a lenslet capture needs --white to decode)"
        facts.update(_image_facts(path))
        return facts
    else:
        facts["format"] = "lenslet capture"
    lf = open_input(path, white=white, dark=dark, grid=grid, nonfinite=nonfinite)
    source_format = lf.meta.get("format")
    if source_format:
        facts["source format"] = source_format
    facts["views"] = f"{lf.grid_shape[0]} x {lf.grid_shape[1]}"
    missing = lf.meta.get("missing_views")
    if missing:
        facts["missing views"] = f"{len(missing)} of {lf.n_views} (weight 0): {', '.join(missing[:4])}" + (
            f" and {len(missing) - 4} more" if len(missing) > 4 else "")
    facts["view size"] = f"{lf.image_shape[0]} x {lf.image_shape[1]} px, {lf.n_channels} channel(s)"
    span = np.ptp(lf.flat_positions(), axis=0)
    facts["aperture"] = f"{span[0]:g} x {span[1]:g} grid steps (y, x)"
    facts["sample weights"] = "yes" if lf.weights is not None else "no"
    grid_facts = _grid_facts(lf.meta.get("grid"))
    if grid_facts is not None:
        facts["grid"] = grid_facts
    facts["disparity"] = _disparity_facts(lf)
    declared = lf.meta.get("nearer")
    facts["nearer"] = (f"{declared} disparities in front (declared)" if declared is not None else
                       "judged from the views at the depth edges (not declared; refocus, detect, reduce --nearer)")
    return facts


def _print(facts, stream):
    for key, value in facts.items():
        if key == "disparity":
            value = f"{value['min']:.3g} .. {value['max']:.3g} px per view step ({value['from']})"
        elif key == "grid" and isinstance(value, dict):
            value = ", ".join(f"{k}={v}" for k, v in value.items() if not isinstance(v, (list, dict)))
        elif isinstance(value, list):
            value = " x ".join(str(v) for v in value)
        stream.write(f"{key + ':':<16s}{value}\n")


def run_info(args, stream):
    """Print what ``args.input`` holds."""
    facts = describe(args.input, args.white, args.dark, args.grid, args.nonfinite)
    if args.json:
        stream.write(json.dumps(facts, indent=2, default=str) + "\n")
    else:
        _print(facts, stream)
    return 0
