"""Sensor readers: one lenslet image (TIFF, PNG, camera raw / DNG, Lytro) as linear floats.

:func:`read_sensor` returns a :class:`SensorImage`: the pixels as float32,
black level removed and scaled so the white level is 1 (camera raw,
Lytro), or divided by the integer dtype's maximum (TIFF, PNG), plus the
Bayer layout when the pixels are a colour mosaic. Nothing is demosaiced,
brightened or gamma-corrected here: the lenslet decoder devignettes the
mosaic first and demosaics afterwards.

- TIFF and PNG go through :func:`napari_lfalias.decoders.images.read_image`
  (tifffile, OpenCV); a grey image may be declared a mosaic with
  ``bayer="RGGB"`` (or another layout).
- Camera raw and DNG go through rawpy (LibRaw): ``raw_image_visible``,
  the per-channel black levels and the white level, the 2x2 colour layout.
- Lytro ``.lfr``/``.lfp``/``.raw`` go through imageio's Lytro plugin
  (:mod:`.lytro`).

Every failure is a :class:`~napari_lfalias.errors.DecodeError` naming the
file and the reason.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import DecodeError, ParameterError
from .bayer import BAYER_PATTERNS, bayer_pattern

__all__ = ["SensorImage", "read_sensor", "as_sensor_image", "CAMERA_RAW_SUFFIXES"]

#: Suffixes read with rawpy (LibRaw).
CAMERA_RAW_SUFFIXES = {
    ".dng", ".cr2", ".cr3", ".crw", ".nef", ".nrw", ".arw", ".srf", ".sr2", ".orf", ".rw2", ".raf",
    ".pef", ".srw", ".3fr", ".erf", ".kdc", ".mrw", ".rwl", ".iiq", ".mef", ".mos", ".x3f",
}
_IMAGE_SUFFIXES = {".tif", ".tiff", ".png"}
_LYTRO_SUFFIXES = {".lfr", ".lfp", ".raw"}


@dataclass
class SensorImage:
    """One sensor image with what is known about it.

    Attributes
    ----------
    data : ndarray, shape (H, W) or (H, W, 3), float32
        Linear pixel values, black level removed, nominally in [0, 1].
    bayer : str or None
        The 2x2 Bayer layout (``"RGGB"``, ...) when ``data`` is a colour
        mosaic, else ``None``.
    path : Path or None
        The file it was read from.
    format : str
        A short description of the file format.
    meta : dict
        Facts from the file (levels, pixel and lens pitch, ...).
    """

    data: np.ndarray
    bayer: str | None = None
    path: Path | None = None
    format: str = "array"
    meta: dict = field(default_factory=dict)

    def __array__(self, dtype=None, copy=None):
        return self.data if dtype is None else self.data.astype(dtype)

    @property
    def shape(self):
        """``(H, W)`` of the sensor."""
        return tuple(self.data.shape[:2])

    @property
    def name(self):
        """The file name for messages (or ``"array"``)."""
        return self.path.name if self.path is not None else "array"

    def label(self):
        """The path for messages (or a description of an array)."""
        return str(self.path) if self.path is not None else f"array of shape {self.data.shape}"


def _read_image_file(path, bayer):
    from .images import read_image

    image = read_image(path)  # (H, W, C) in [0, 1]; DecodeError naming the file on failure
    data = image[..., 0] if image.shape[2] == 1 else image
    if bayer is not None and data.ndim == 3:
        raise DecodeError(f"{path}: bayer={bayer!r} was given, but the image is already colour (RGB)")
    kind = "TIFF" if path.suffix.lower() in (".tif", ".tiff") else "PNG"
    return SensorImage(np.ascontiguousarray(data), bayer, path, kind, {})


def _rawpy_pattern(raw, path):
    pattern = raw.raw_pattern
    desc = raw.color_desc.decode("ascii", "replace") if isinstance(raw.color_desc, bytes) else str(raw.color_desc)
    if pattern is None or np.asarray(pattern).shape != (2, 2):
        shape = None if pattern is None else np.asarray(pattern).shape
        raise DecodeError(
            f"{path}: the sensor's colour filter is not a 2x2 Bayer mosaic (pattern shape {shape}); "
            "X-Trans and linear (demosaiced) raw files are not supported: export a TIFF instead"
        )
    letters = "".join(desc[int(i)] for i in np.asarray(pattern).ravel()).replace("g", "G")
    letters = letters.upper()
    if letters not in BAYER_PATTERNS:
        raise DecodeError(f"{path}: unsupported colour filter layout {letters!r} (colours {desc!r})")
    return letters


def _read_camera_raw(path):
    try:
        import rawpy
    except ImportError as exc:
        raise DecodeError(
            f"{path}: reading camera raw and DNG files needs rawpy: pip install 'napari-lfalias[raw]'"
        ) from exc
    try:
        with rawpy.imread(str(path)) as raw:
            image = np.array(raw.raw_image_visible, dtype=np.float32)
            colours = np.array(raw.raw_colors_visible)
            black = np.asarray(raw.black_level_per_channel, np.float32)
            white = float(raw.white_level)
            pattern = _rawpy_pattern(raw, path)
            desc = raw.color_desc.decode("ascii", "replace")
    except DecodeError:
        raise
    except Exception as exc:  # LibRaw's own error types
        detail = str(exc) or type(exc).__name__
        raise DecodeError(
            f"{path}: cannot read the camera raw file ({detail}); it may be truncated, or a format LibRaw "
            "does not know"
        ) from exc
    black_map = black[np.clip(colours, 0, len(black) - 1)]
    span = np.maximum(white - black_map, 1.0)
    data = np.clip((image - black_map) / span, 0.0, None).astype(np.float32)
    meta = {"black_level": black.tolist(), "white_level": white, "colour_description": desc}
    kind = "DNG" if path.suffix.lower() == ".dng" else "camera raw"
    return SensorImage(data, pattern, path, kind, meta)


def _sniff(path):
    try:
        with open(path, "rb") as handle:
            return handle.read(8)
    except OSError as exc:
        raise DecodeError(f"{path}: cannot open the file ({exc.strerror})") from exc


def read_sensor(path, bayer=None):
    """Read one lenslet sensor image.

    Parameters
    ----------
    path : str or Path
        TIFF, PNG, camera raw / DNG (rawpy), or Lytro LFR/LFP/RAW.
    bayer : str, optional
        Declare a grey TIFF/PNG a Bayer mosaic with this 2x2 layout
        (``"RGGB"``, ``"BGGR"``, ``"GRBG"``, ``"GBRG"``). Camera raw and
        Lytro files carry their own layout.

    Returns
    -------
    SensorImage
        ``np.asarray(image)`` gives the pixels.

    Raises
    ------
    DecodeError
        If the file is missing, truncated, of an unsupported kind, or (for
        Lytro) holds no raw sensor image.

    Examples
    --------
    >>> import numpy as np, tifffile, tempfile, os
    >>> path = os.path.join(tempfile.mkdtemp(), "white.tif")
    >>> tifffile.imwrite(path, np.full((4, 6), 65535, np.uint16))
    >>> image = read_sensor(path)
    >>> image.shape, float(np.asarray(image).max()), image.bayer
    ((4, 6), 1.0, None)
    """
    path = Path(path)
    bayer = bayer_pattern(bayer)
    if not path.is_file():
        raise DecodeError(f"{path}: no such file" if not path.exists() else f"{path}: not a file")
    magic = _sniff(path)
    suffix = path.suffix.lower()
    if magic.startswith(b"\x89LFP") or suffix in _LYTRO_SUFFIXES:
        from .lytro import read_lytro

        return read_lytro(path)
    if suffix in CAMERA_RAW_SUFFIXES:
        if bayer is not None:
            raise ParameterError(f"bayer: {path.name} is a camera raw file, which carries its own Bayer layout")
        return _read_camera_raw(path)
    if suffix in _IMAGE_SUFFIXES:
        return _read_image_file(path, bayer)
    raise DecodeError(
        f"{path}: unsupported file type {suffix or '(no suffix)'!r}; a lenslet capture must be TIFF, PNG, "
        "camera raw or DNG, or a Lytro LFR/LFP/RAW file"
    )


def as_sensor_image(image, bayer=None, name="image"):
    """A :class:`SensorImage` from a path, an array or a SensorImage (arrays are not copied).

    Parameters
    ----------
    image : str, Path, ndarray or SensorImage
        The sensor image.
    bayer : str, optional
        Bayer layout of a grey mosaic (overrides nothing already known).
    name : str
        The parameter's name, for messages.
    """
    if isinstance(image, SensorImage):
        if bayer is not None and image.bayer is None:
            return SensorImage(image.data, bayer_pattern(bayer), image.path, image.format, image.meta)
        return image
    if isinstance(image, (str, Path)):
        return read_sensor(image, bayer=bayer)
    try:
        array = np.asarray(image)
    except Exception as exc:
        raise ParameterError(f"{name} must be a file path or an image array, got {type(image).__name__}") from exc
    if array.ndim == 3 and array.shape[2] == 1:
        array = array[..., 0]
    if array.ndim not in (2, 3) or (array.ndim == 3 and array.shape[2] != 3) or min(array.shape[:2]) < 1:
        raise ParameterError(f"{name} must be an (H, W) or (H, W, 3) image, got shape {array.shape}")
    if not np.issubdtype(array.dtype, np.number) or np.issubdtype(array.dtype, np.complexfloating):
        raise ParameterError(f"{name} must hold real numbers, got dtype {array.dtype}")
    if np.issubdtype(array.dtype, np.integer):
        array = array.astype(np.float32) / np.float32(np.iinfo(array.dtype).max)
    if not np.all(np.isfinite(array)):
        raise ParameterError(f"{name} holds NaN or Inf values")
    bayer = bayer_pattern(bayer, name="bayer")
    if bayer is not None and array.ndim == 3:
        raise ParameterError(f"bayer={bayer!r} was given, but {name} is already a colour (H, W, 3) image")
    return SensorImage(np.asarray(array, np.float32), bayer, None, "array", {})
