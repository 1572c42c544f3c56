"""A folder of white images, one chosen per capture by the camera's zoom and focus.

A Lytro owner has the camera's calibration files, not one white image per
capture: white images recorded through a diffuser at many zoom and focus
settings (``MOD_0000.RAW`` with its ``MOD_0000.TXT``). As Dansereau's
LFToolbox does (``LFSelectFromDatabase``), the white image for a capture is
the one of the same camera (serial number) nearest in zoom step, then, among
those, nearest in focus step; ties go to the longer exposure (the F01 stores
two per setting), then to the file name.

Settings are read from each file's metadata: a Lytro container's own, or a
``.json``/``.txt`` beside the image with the same stem (Lytro's layout,
``master.picture.frameArray[0].frame``, or a plain
``{"zoom_step": 5, "focus_step": 120, "serial": "A1"}``). A capture's come
from its Lytro metadata or such a file beside it. Files without settings
are not candidates.

The grid fitted to each white image is cached, in memory and on disk (a
JSON per white image under ``$NAPARI_LFALIAS_CACHE`` or
``~/.cache/napari-lfalias/grids``, keyed by the file's path, size and
modification time and the calibration options), so a folder of captures
calibrates each white image once.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import WhiteImageError

__all__ = ["WhiteImage", "WhiteImageFolder", "settings_beside", "capture_settings", "grid_cache_dir"]

#: Image files that can be white images.
_IMAGE_SUFFIXES = {".raw", ".lfr", ".lfp", ".tif", ".tiff", ".png", ".dng"}
_SIDECARS = (".json", ".txt", ".JSON", ".TXT")
_CACHE_FORMAT = 1


@dataclass(frozen=True)
class WhiteImage:
    """One white image and the camera settings it was recorded with."""

    path: Path
    zoom_step: float | None = None
    focus_step: float | None = None
    serial: str | None = None
    exposure_s: float | None = None
    extra: dict = field(default_factory=dict, compare=False)

    def describe(self):
        """``name (zoom 5, focus 120)`` for messages."""
        return f"{self.path.name} (zoom {_number(self.zoom_step)}, focus {_number(self.focus_step)})"


def _number(value):
    return "?" if value is None else f"{value:g}"


def _from_dict(meta):
    """Settings of a metadata dict: Lytro's layouts or plain keys."""
    from .lytro import camera_settings

    if not isinstance(meta, dict):
        return {}
    found = camera_settings(meta)
    for key in ("zoom_step", "focus_step", "exposure_s"):
        value = meta.get(key)
        if key not in found and isinstance(value, (int, float)) and not isinstance(value, bool):
            found[key] = float(value)
    if "serial" not in found and meta.get("serial") is not None:
        found["serial"] = str(meta["serial"])
    return found


def settings_beside(path):
    """Camera settings from the ``.json``/``.txt`` beside an image (same stem), or ``{}``."""
    path = Path(path)
    for suffix in _SIDECARS:
        sidecar = path.with_suffix(suffix)
        if sidecar.is_file() and sidecar != path:
            try:
                return _from_dict(json.loads(sidecar.read_text(errors="replace")))
            except (OSError, ValueError):
                return {}
    return {}


def _container_settings(path):
    """Settings of a Lytro LFR/LFP container (its frame metadata sections), or ``{}``."""
    from .lytro import scan_container

    try:
        data = Path(path).read_bytes()
        sections = scan_container(path, data)
    except (OSError, ValueError):
        return {}
    merged = {}
    for section in sections:
        if section.kind != "json":
            continue
        try:
            part = json.loads(data[section.offset:section.offset + section.size].decode("utf-8"))
        except ValueError:
            continue
        if isinstance(part, dict):
            for key in ("devices", "camera"):
                if key in part:
                    merged.setdefault("metadata", {})[key] = part[key]
            if "camera" in part and "serialNumber" in (part.get("camera") or {}):
                merged.setdefault("privateMetadata", {})["camera"] = part["camera"]
    return _from_dict(merged) if merged else {}


def capture_settings(image):
    """Zoom, focus and serial of a capture (a SensorImage): its own metadata, else a file beside it."""
    found = {k: image.meta[k] for k in ("zoom_step", "focus_step", "serial", "exposure_s") if k in image.meta}
    if image.path is not None:
        for key, value in settings_beside(image.path).items():
            found.setdefault(key, value)
    return found


def _settings_of(path):
    found = settings_beside(path)
    if not found and path.suffix.lower() in (".lfr", ".lfp"):
        found = _container_settings(path)
    return found


def grid_cache_dir():
    """The folder of cached grid fits (``$NAPARI_LFALIAS_CACHE``/grids, else ``~/.cache/napari-lfalias/grids``)."""
    root = os.environ.get("NAPARI_LFALIAS_CACHE")
    base = Path(root) if root else Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "napari-lfalias"
    return base / "grids"


class WhiteImageFolder:
    """The white images of a folder (searched recursively) with their camera settings.

    Parameters
    ----------
    folder : str or Path

    Raises
    ------
    WhiteImageError
        If the folder holds no image with zoom and focus settings.

    Examples
    --------
    >>> import json, tempfile, numpy as np, tifffile
    >>> from pathlib import Path
    >>> folder = Path(tempfile.mkdtemp())
    >>> for name, zoom, focus in (("w1", 1, 100), ("w2", 5, 100), ("w3", 5, 300)):
    ...     tifffile.imwrite(folder / f"{name}.tif", np.zeros((4, 4), np.uint16))
    ...     _ = (folder / f"{name}.json").write_text(json.dumps({"zoom_step": zoom, "focus_step": focus}))
    >>> whites = WhiteImageFolder(folder)
    >>> whites.choose({"zoom_step": 4, "focus_step": 250}).path.name
    'w3.tif'
    """

    def __init__(self, folder):
        self.folder = Path(folder)
        if not self.folder.is_dir():
            raise WhiteImageError(f"white={self.folder}: not a folder of white images")
        self.images = []
        self.without_settings = []
        for path in sorted(p for p in self.folder.rglob("*") if p.suffix.lower() in _IMAGE_SUFFIXES and p.is_file()):
            found = _settings_of(path)
            if "zoom_step" in found and "focus_step" in found:
                self.images.append(WhiteImage(path, found["zoom_step"], found["focus_step"], found.get("serial"),
                                              found.get("exposure_s"), found))
            else:
                self.without_settings.append(path)
        if not self.images:
            extra = f" ({len(self.without_settings)} image(s) without them)" if self.without_settings else ""
            raise WhiteImageError(
                f"white={self.folder}: no white image with zoom and focus settings in this folder{extra}; "
                "each needs its camera metadata (a Lytro .TXT/.json beside the .RAW, or a .json with zoom_step "
                "and focus_step); or pass white= one white image file"
            )
        self._grids = {}

    def choose(self, settings, label="the capture"):
        """The white image for a capture's ``settings`` (serial, then zoom, then focus).

        Raises
        ------
        WhiteImageError
            If the capture has no zoom/focus settings, or no white image
            belongs to its camera.
        """
        if "zoom_step" not in settings or "focus_step" not in settings:
            raise WhiteImageError(
                f"{label}: no zoom and focus settings in its metadata, so no white image of {self.folder} can be "
                "chosen for it; pass white= one white image file (or put a .json with zoom_step and focus_step "
                "beside the capture)"
            )
        candidates = self.images
        serial = settings.get("serial")
        if serial is not None and any(image.serial is not None for image in candidates):
            candidates = [image for image in candidates if image.serial == serial]
            if not candidates:
                serials = sorted({image.serial for image in self.images if image.serial is not None})
                raise WhiteImageError(
                    f"{label}: taken by camera {serial}, but the white images of {self.folder} are of "
                    f"{', '.join(serials)}; use that camera's white images (its calibration files)"
                )
        zoom, focus = float(settings["zoom_step"]), float(settings["focus_step"])
        return min(candidates, key=lambda image: (abs(image.zoom_step - zoom), abs(image.focus_step - focus),
                                                  -(image.exposure_s or 0.0), image.path.name))

    def grid(self, image, calibrate_options, dark=None, pixels=None):
        """The grid fitted to ``image`` (a :class:`WhiteImage`), from the cache when it holds it.

        ``pixels`` (its SensorImage, when already read) saves reading it again.
        """
        from .calibration import calibrate

        source = image.path if pixels is None else pixels
        key = _cache_key(image.path, dark, calibrate_options)
        if key is None:  # a dark frame given as an array: nothing to key a cache on
            return calibrate(source, dark, **calibrate_options)
        if key in self._grids:
            return self._grids[key]
        grid = _read_cached(key)
        if grid is None:
            grid = calibrate(source, dark, **calibrate_options)
            _write_cached(key, grid)
        self._grids[key] = grid
        return grid


def _stat_key(path):
    path = Path(path).resolve()
    stat = path.stat()
    return [str(path), stat.st_size, stat.st_mtime_ns]


def _cache_key(path, dark, options):
    parts = {"format": _CACHE_FORMAT, "white": _stat_key(path), "options": sorted(options.items())}
    if dark is not None:
        dark_path = dark if isinstance(dark, (str, Path)) else getattr(dark, "path", None)
        if dark_path is None:
            return None
        parts["dark"] = _stat_key(dark_path)
    text = json.dumps(parts, sort_keys=True, default=str)
    return hashlib.sha1(text.encode()).hexdigest()


def _read_cached(key):
    from .grid import GridModel

    path = grid_cache_dir() / f"{key}.json"
    try:
        return GridModel.from_json(path.read_text())
    except (OSError, ValueError):
        return None


def _write_cached(key, grid):
    """Write the grid atomically; a cache that cannot be written is skipped (it only saves time)."""
    folder = grid_cache_dir()
    temporary = None
    try:
        folder.mkdir(parents=True, exist_ok=True)
        handle, temporary = tempfile.mkstemp(dir=folder, prefix=f".{key}.", suffix=".tmp")
        with os.fdopen(handle, "w") as stream:
            stream.write(grid.to_json())
        os.replace(temporary, folder / f"{key}.json")
    except OSError:
        if temporary is not None:
            Path(temporary).unlink(missing_ok=True)
