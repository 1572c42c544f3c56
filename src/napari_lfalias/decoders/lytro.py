"""Lytro files: raw sensor data of the F01 and Illum cameras, through imageio's Lytro plugin.

An ``.lfp``/``.lfr`` file is a container: a header, then sections, each a
16-byte marker (``\\x89LFM``: JSON, ``\\x89LFC``: content) with a big-endian
length, an 80-byte ``sha1-...`` name, and the payload. The first JSON
section is a table of contents; its frame's ``imageRef`` names the raw
sensor section. *Processed* pictures written by Lytro Desktop (refocus
stacks, depth maps) keep the table of contents but not the raw section:
those are refused with a :class:`~napari_lfalias.errors.DecodeError`
saying so, before the pixels are handed to imageio.

A plain ``.raw`` is the bare packed sensor (12-bit 3280 x 3280 for the F01,
10-bit 5368 x 7728 for the Illum) with an optional ``.json``/``.txt``
metadata file beside it (read by imageio).

The metadata give the black and white levels per Bayer channel, the Bayer
layout (``mosaic.upperLeftPixel``) and, when present, the lens and pixel
pitch, the microlens rotation, and the camera's zoom and focus steps and
serial number (which pick a white image from a folder of them, see
:mod:`.white_images`): they land in ``SensorImage.meta``.
"""

from __future__ import annotations

import json
import struct
from collections import namedtuple
from pathlib import Path

import numpy as np

from ..errors import DecodeError

__all__ = ["read_lytro", "scan_container", "LytroSection", "camera_settings", "frame_metadata"]

_FILE_MAGIC = b"\x89LFP"
_SECTION_MAGIC = (b"\x89LFM", b"\x89LFC")
_SECTION_HEADER = 16
_SHA1_FIELD = 80
#: Packed raw sizes in bytes, and the imageio format that unpacks them.
_F01 = {"bytes": 3280 * 3280 * 3 // 2, "bits": 12, "format": "LYTRO-F01-RAW", "camera": "Lytro F01"}
_ILLUM = {"bytes": 5368 * 7728 * 5 // 4, "bits": 10, "format": "LYTRO-ILLUM-RAW", "camera": "Lytro Illum"}
_CONTAINER_FORMAT = {".lfp": "LYTRO-LFP", ".lfr": "LYTRO-LFR"}
#: Bayer layout from the metadata's upper-left pixel; and each layout's 2x2 channel names.
_UPPER_LEFT = {"r": "RGGB", "b": "BGGR", "gr": "GRBG", "gb": "GBRG"}
_TILE_NAMES = {
    "RGGB": (("r", "gr"), ("gb", "b")),
    "BGGR": (("b", "gb"), ("gr", "r")),
    "GRBG": (("gr", "r"), ("b", "gb")),
    "GBRG": (("gb", "b"), ("r", "gr")),
}
_DEFAULT_LAYOUT = {"Lytro F01": "BGGR", "Lytro Illum": "GRBG"}


#: One container section: kind ("json" or "content"), sha1 name, payload offset and size in bytes.
LytroSection = namedtuple("LytroSection", "kind sha1 offset size")


def scan_container(path, data):
    """The sections of a Lytro container held in ``data`` (bytes).

    Raises
    ------
    DecodeError
        If the header is wrong or a section runs past the end of the file.
    """
    if data[:4] != _FILE_MAGIC or len(data) < 16:
        raise DecodeError(f"{path}: not a Lytro LFP/LFR container (no \\x89LFP header)")
    sections = []
    pos = 16
    while True:
        start = data.find(b"\x89LF", pos)
        if start < 0:
            break
        magic = data[start:start + 4]
        if magic not in _SECTION_MAGIC:
            pos = start + 4
            continue
        if start + _SECTION_HEADER + _SHA1_FIELD > len(data):
            raise DecodeError(f"{path}: truncated Lytro file (a section header is cut off at byte {start})")
        size = struct.unpack(">i", data[start + 12:start + 16])[0]
        name = data[start + 16:start + 16 + _SHA1_FIELD].split(b"\0", 1)[0].decode("ascii", "replace")
        offset = start + _SECTION_HEADER + _SHA1_FIELD
        if size < 0 or offset + size > len(data):
            raise DecodeError(
                f"{path}: truncated Lytro file (section {name or '?'} needs {size} bytes from byte {offset}, "
                f"the file has {len(data)})"
            )
        sections.append(LytroSection("json" if magic == b"\x89LFM" else "content", name, offset, size))
        pos = offset + size
    return sections


def _table_of_contents(path, data, sections):
    if not sections or sections[0].kind != "json":
        raise DecodeError(f"{path}: a Lytro container without its table of contents")
    first = sections[0]
    try:
        return json.loads(data[first.offset:first.offset + first.size].decode("utf-8"))
    except ValueError as exc:
        raise DecodeError(f"{path}: the Lytro table of contents is not valid JSON ({exc})") from exc


def _frame_reference(toc):
    frames = (toc.get("picture") or {}).get("frameArray") or toc.get("frames") or []
    if not frames:
        return None
    return (frames[0].get("frame") or {}).get("imageRef")


def _processed_contents(toc):
    picture = toc.get("picture") or {}
    kinds = []
    for entry in picture.get("accelerationArray") or []:
        kind = str(entry.get("type", "")).rsplit(".", 1)[-1]
        if kind:
            kinds.append(kind)
    return kinds


def _check_raw_container(path, data):
    """The camera model of a container holding raw sensor data; DecodeError for processed pictures."""
    sections = scan_container(path, data)
    toc = _table_of_contents(path, data, sections)
    ref = _frame_reference(toc)
    by_name = {s.sha1: s for s in sections}
    section = by_name.get(ref)
    if section is None:
        kinds = _processed_contents(toc)
        what = f" ({', '.join(kinds)})" if kinds else ""
        raise DecodeError(
            f"{path}: a processed Lytro picture{what} without the raw sensor image: its frame "
            f"{ref or '(none)'} is not in the file. Lytro Desktop's refocus stacks and depth maps cannot "
            "be decoded into a light field; use the camera's original raw LFP/LFR (or its .raw + .json)"
        )
    for camera in (_F01, _ILLUM):
        if section.size == camera["bytes"]:
            return camera
    raise DecodeError(
        f"{path}: the Lytro frame holds {section.size} bytes, not a packed F01 ({_F01['bytes']}) or Illum "
        f"({_ILLUM['bytes']}) raw sensor image"
    )


def _raw_camera(path, size):
    for camera in (_F01, _ILLUM):
        if size == camera["bytes"]:
            return camera
    raise DecodeError(
        f"{path}: a .raw file of {size} bytes is neither a Lytro F01 ({_F01['bytes']} bytes) nor an Illum "
        f"({_ILLUM['bytes']} bytes) packed sensor image; the file may be truncated"
    )


def _channel_maps(layout, levels, default):
    """``(2, 2)`` per-pixel values of a per-channel level dict (``{"r": .., "gr": .., ...}``)."""
    names = _TILE_NAMES[layout]
    tile = np.full((2, 2), float(default))
    if isinstance(levels, dict):
        for i in range(2):
            for j in range(2):
                value = levels.get(names[i][j])
                if isinstance(value, (int, float)):
                    tile[i, j] = float(value)
    elif isinstance(levels, (int, float)):
        tile[:] = float(levels)
    return tile


def _dig(meta, *keys):
    for key in keys:
        if not isinstance(meta, dict):
            return None
        meta = meta.get(key)
    return meta


def frame_metadata(meta):
    """The frame's ``(metadata, privateMetadata)`` of a Lytro metadata dict, in any of its layouts.

    imageio gives a container's as ``{"metadata": ..., "privateMetadata": ...}``;
    the camera's white-image files (``MOD_0000.TXT``) and Lytro's ``.json``
    beside a ``.raw`` nest them in ``master.picture.frameArray[0].frame``.
    """
    if not isinstance(meta, dict):
        return {}, {}
    frames = _dig(meta, "master", "picture", "frameArray")
    if isinstance(frames, list) and frames and isinstance(frames[0], dict):
        frame = frames[0].get("frame") or {}
        return frame.get("metadata") or {}, frame.get("privateMetadata") or {}
    return meta.get("metadata", meta) or {}, meta.get("privateMetadata") or {}


def camera_settings(meta):
    """Zoom and focus steps, serial number, model and exposure from Lytro metadata (missing ones left out).

    Examples
    --------
    >>> camera_settings({"metadata": {"devices": {"lens": {"zoomStep": 12, "focusStep": -340}}},
    ...                  "privateMetadata": {"camera": {"serialNumber": "B5143"}}})
    {'zoom_step': 12.0, 'focus_step': -340.0, 'serial': 'B5143'}
    """
    frame, private = frame_metadata(meta)
    found = {}
    for key, value in (("zoom_step", _dig(frame, "devices", "lens", "zoomStep")),
                       ("focus_step", _dig(frame, "devices", "lens", "focusStep")),
                       ("exposure_s", _dig(frame, "devices", "shutter", "frameExposureDuration"))):
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            found[key] = float(value)
    serial = _dig(private, "camera", "serialNumber")
    if serial is not None:
        found["serial"] = str(serial)
    model = _dig(frame, "camera", "model")
    if model is not None:
        found["camera_model"] = str(model)
    return found


def _facts(meta, camera):
    """Layout, level tiles, optics and camera settings from the Lytro metadata (missing entries get defaults)."""
    settings = camera_settings(meta)
    meta = frame_metadata(meta)[0]
    raw_details = _dig(meta, "image", "rawDetails") or {}
    upper_left = str(_dig(raw_details, "mosaic", "upperLeftPixel") or "").lower()
    layout = _UPPER_LEFT.get(upper_left, _DEFAULT_LAYOUT[camera["camera"]])
    full = 2 ** camera["bits"] - 1
    black = _channel_maps(layout, _dig(raw_details, "pixelFormat", "black"), 0)
    white = _channel_maps(layout, _dig(raw_details, "pixelFormat", "white"), full)
    facts = {"camera": camera["camera"], "bits": camera["bits"], "bayer_upper_left": upper_left or None,
             "black_level": black.tolist(), "white_level": white.tolist()}
    mla = _dig(meta, "devices", "mla") or {}
    sensor = _dig(meta, "devices", "sensor") or {}
    for key, value in (("lens_pitch_m", mla.get("lensPitch")), ("mla_rotation_rad", mla.get("rotation")),
                       ("pixel_pitch_m", sensor.get("pixelPitch"))):
        if isinstance(value, (int, float)):
            facts[key] = float(value)
    if "lens_pitch_m" in facts and facts.get("pixel_pitch_m"):
        facts["lens_pitch_px"] = facts["lens_pitch_m"] / facts["pixel_pitch_m"]
    facts.update(settings)
    return layout, black, white, full, facts


def _read_with_imageio(path, fmt):
    import imageio.v2 as iio

    try:
        with iio.get_reader(str(path), format=fmt) as reader:
            image = np.asarray(reader.get_data(0), np.float64)
            meta = reader.get_meta_data()
    except Exception as exc:  # imageio raises RuntimeError, ValueError, struct.error, ...
        detail = str(exc) or type(exc).__name__
        raise DecodeError(f"{path}: imageio's Lytro plugin cannot read the file ({detail})") from exc
    return image, meta


def read_lytro(path):
    """Read the raw Bayer sensor image of a Lytro LFP/LFR/RAW file.

    Parameters
    ----------
    path : str or Path
        An ``.lfp`` (F01) or ``.lfr`` (Illum) container, or a bare ``.raw``.

    Returns
    -------
    SensorImage
        Black level removed, white level 1, ``bayer`` set from the metadata.

    Raises
    ------
    DecodeError
        For processed pictures (refocus stacks, depth maps), truncated files
        and sizes that are not a Lytro sensor.

    Examples
    --------
    >>> import os, tempfile
    >>> path = os.path.join(tempfile.mkdtemp(), "IMG_0001.raw")
    >>> with open(path, "wb") as handle:
    ...     _ = handle.write(bytes(100))
    >>> try:
    ...     read_lytro(path)
    ... except DecodeError as error:
    ...     print(str(error).split(": ", 1)[1][:40])
    a .raw file of 100 bytes is neither a Ly
    """
    from .sensor import SensorImage

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".raw":
        camera = _raw_camera(path, path.stat().st_size)
        fmt = camera["format"]
    else:
        try:
            data = path.read_bytes()
        except OSError as exc:
            raise DecodeError(f"{path}: cannot read the file ({exc.strerror})") from exc
        camera = _check_raw_container(path, data)
        fmt = _CONTAINER_FORMAT.get(suffix, "LYTRO-LFR" if camera is _ILLUM else "LYTRO-LFP")
    image, meta = _read_with_imageio(path, fmt)
    layout, black, white, full, facts = _facts(meta, camera)
    height, width = image.shape
    reps = ((height + 1) // 2, (width + 1) // 2)
    black_map = np.tile(black, reps)[:height, :width]
    white_map = np.tile(white, reps)[:height, :width]
    data = np.clip((image * full - black_map) / np.maximum(white_map - black_map, 1.0), 0.0, None)
    return SensorImage(data.astype(np.float32), layout, path, f"{camera['camera']} raw ({suffix})", facts)
