"""Read one view image (PNG, TIFF, JPEG, BMP) as float32 in [0, 1].

PNG, JPEG and BMP are decoded with OpenCV when it is installed: it is
faster than imageio's Pillow plugin on the HCI views
(``benchmarks/results/camera_array.md``) and, unlike Pillow, keeps the full
precision of 16-bit colour PNGs. Without OpenCV, imageio reads them, and a
16-bit colour PNG is refused rather than silently cut to 8 bits. TIFF goes
through tifffile. Any failure
(missing file, unknown format, truncated data) becomes a
:class:`~napari_lfalias.errors.DecodeError` naming the file.

The size an image declares in its header is checked against the memory
budget (:mod:`napari_lfalias._budget`) before its pixels are decoded: a
small PNG or TIFF that declares a huge image (an image bomb) is refused
without allocating it.
"""

from __future__ import annotations

import contextlib
import math
import warnings
from pathlib import Path

import numpy as np

from .. import _budget
from ..errors import DecodeError

__all__ = ["IMAGE_SUFFIXES", "read_image", "decode_image", "to_unit_float", "image_header", "is_image_file"]

#: File suffixes read as views (lower case).
IMAGE_SUFFIXES = {".png", ".tif", ".tiff", ".jpg", ".jpeg", ".bmp"}
_TIFF_SUFFIXES = {".tif", ".tiff"}
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: PNG IHDR colour types without colour (grey, grey + alpha).
_PNG_GREY_TYPES = {0, 4}


def is_image_file(path):
    """True if ``path`` has a view-image suffix and is not a hidden file."""
    path = Path(path)
    return path.suffix.lower() in IMAGE_SUFFIXES and not path.name.startswith(".")


def _unreadable(path, exc):
    detail = getattr(exc, "strerror", None) or str(exc) or type(exc).__name__
    return DecodeError(
        f"{path}: cannot read the image ({detail}); the file may be truncated or corrupt, "
        "or not an image: replace it, or move it out of the folder"
    )


def _channels_last(array, path, grey=False):
    """``(Y, X, C)`` with C = 1 or 3: alpha dropped, grey + alpha kept grey."""
    if array.ndim == 2:
        return array[..., None]
    if array.ndim != 3:
        raise DecodeError(f"{path}: expected a 2-D image, got an array of shape {array.shape}")
    n = array.shape[2]
    if grey or n in (1, 2):
        return array[..., :1]
    if n in (3, 4):
        return array[..., :3]
    raise DecodeError(f"{path}: unsupported number of channels ({n}); save it as grey or RGB")


def to_unit_float(array, out=None):
    """float32 scaled by the integer dtype's maximum (floats and booleans kept as they are), into ``out`` if given.

    Examples
    --------
    >>> to_unit_float(np.array([0, 51, 255], np.uint8)).tolist()
    [0.0, 0.20000000298023224, 1.0]
    """
    if out is None:
        out = np.empty(array.shape, np.float32)
    if np.issubdtype(array.dtype, np.integer):  # one pass; the same float32 division as astype then divide
        return np.divide(array, np.float32(np.iinfo(array.dtype).max), out=out, dtype=np.float32)
    out[...] = array
    return out


def _check_decoded_size(path, shape, itemsize):
    """Refuse an image whose decoded pixels (and their float32 copy) exceed the memory budget."""
    n_pixels = math.prod(int(n) for n in shape)
    described = " x ".join(str(int(n)) for n in shape)
    _budget.check(n_pixels * (int(itemsize) + 4), f"{path}: its header declares a {described} image, whose pixels",
                  DecodeError)


def _png_header_shape(raw):
    """``((height, width, samples), bytes per sample)`` from a PNG's IHDR, or None if it has none."""
    if raw[:8].tobytes() != _PNG_SIGNATURE or raw.size < 26 or raw[12:16].tobytes() != b"IHDR":
        return None
    width = int.from_bytes(raw[16:20].tobytes(), "big")
    height = int.from_bytes(raw[20:24].tobytes(), "big")
    samples = {0: 1, 2: 3, 3: 3, 4: 2, 6: 4}.get(int(raw[25]), 4)
    return (height, width, samples), 2 if raw[24] == 16 else 1


@contextlib.contextmanager
def _pillow_header(path):
    """``PIL.Image.open`` for the header only; its bomb warning is ours to give (the budget)."""
    from PIL import Image

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", Image.DecompressionBombWarning)
        with Image.open(path) as image:
            yield image


def _read_tiff(path):
    import tifffile

    from ..io_read import _quiet_tifffile

    with _quiet_tifffile(), tifffile.TiffFile(path) as tif:
        page = tif.pages[0]
        _check_decoded_size(path, page.shape, page.dtype.itemsize if page.dtype is not None else 8)
        array = page.asarray()
        axes = page.axes
    if axes.startswith("S") and array.ndim == 3:  # planar RGB
        array = np.moveaxis(array, 0, -1)
    return array


def _looks_complete(raw):
    """False for a PNG or JPEG cut short (no end marker near the end).

    Such files go to imageio, which says "truncated", instead of OpenCV,
    whose codecs print their complaints to stderr.
    """
    head, tail = raw[:8].tobytes(), raw[-64:].tobytes()
    if head == _PNG_SIGNATURE:
        return b"IEND" in tail
    if head[:2] == b"\xff\xd8":
        return b"\xff\xd9" in tail
    return True


def _opencv():
    try:
        import cv2
    except ImportError:
        return None
    return cv2


def _is_16bit_colour_png(raw):
    return raw[:8].tobytes() == _PNG_SIGNATURE and raw.size > 25 and raw[24] == 16 and raw[25] in (2, 6)


def _decode_png_jpeg(path):
    """Decode with OpenCV; fall back to imageio, which decodes or says why not."""
    raw = np.fromfile(path, np.uint8)
    declared = _png_header_shape(raw)
    if declared is not None:
        _check_decoded_size(path, *declared)
    else:  # JPEG, BMP: the size from the header, through Pillow
        with _pillow_header(path) as image:
            width, height = image.size
            _check_decoded_size(path, (height, width, len(image.getbands())), 2)
    grey = raw[:8].tobytes() == _PNG_SIGNATURE and raw.size > 25 and raw[25] in _PNG_GREY_TYPES
    cv2 = _opencv()
    if cv2 is not None and _looks_complete(raw):
        array = cv2.imdecode(raw, cv2.IMREAD_UNCHANGED)
        if array is not None:
            if array.ndim == 3 and array.shape[2] in (3, 4):  # BGR(A) -> RGB, alpha dropped; contiguous
                array = cv2.cvtColor(array, cv2.COLOR_BGR2RGB if array.shape[2] == 3 else cv2.COLOR_BGRA2RGB)
            return array, grey
    if cv2 is None and _is_16bit_colour_png(raw):
        raise DecodeError(
            f"{path}: a 16-bit colour PNG; reading it at full precision needs OpenCV: "
            "pip install opencv-python-headless"
        )
    import imageio.v3 as iio

    return iio.imread(path), grey


def _read_native(path):
    """The decoded pixels in their own dtype, plus whether they are grey."""
    path = Path(path)
    if path.suffix.lower() in _TIFF_SUFFIXES:
        return _read_tiff(path), False
    return _decode_png_jpeg(path)


def decode_image(path):
    """One view as its file holds it: ``(Y, X, C)``, ``C`` = 1 or 3, in the file's own dtype.

    :func:`read_image` is this through :func:`to_unit_float`; a loader
    that looks at the pixels before converting them (the largest code
    value of an 8-bit view is 4x faster to find than the largest float)
    calls the two itself.

    Raises
    ------
    DecodeError
        As :func:`read_image`.
    """
    try:
        array, grey = _read_native(path)
    except DecodeError:
        raise
    except Exception as exc:  # every reader has its own exception types
        raise _unreadable(path, exc) from exc
    return _channels_last(np.asarray(array), path, grey)


def read_image(path):
    """Read one view as float32 ``(Y, X, C)``, ``C`` = 1 (grey) or 3 (RGB).

    Integer pixels are divided by their dtype's maximum (255 for 8-bit,
    65535 for 16-bit), so values lie in [0, 1]; an alpha channel is dropped.

    Parameters
    ----------
    path : str or Path
        A PNG, TIFF, JPEG or BMP file.

    Returns
    -------
    image : ndarray, shape (Y, X, C), float32

    Raises
    ------
    DecodeError
        If the file cannot be read, is truncated, or is not a 2-D grey or
        colour image.

    Examples
    --------
    >>> import numpy as np, imageio.v3 as iio, tempfile, os
    >>> path = os.path.join(tempfile.mkdtemp(), "view.png")
    >>> iio.imwrite(path, np.full((4, 5), 255, np.uint8))
    >>> img = read_image(path)
    >>> img.shape, float(img.max())
    ((4, 5, 1), 1.0)
    """
    return to_unit_float(decode_image(path))


def _pil_channels(image):
    if image.mode == "P":
        return 3  # palettes are expanded to RGB
    colour = {"R", "G", "B", "C", "Y", "Cb", "Cr"}
    return 3 if colour.intersection(image.getbands()) else 1


def image_header(path):
    """``(Y, X, C)`` of a view from its header, without decoding the pixels.

    Parameters
    ----------
    path : str or Path
        A PNG, TIFF, JPEG or BMP file.

    Returns
    -------
    shape : tuple of int
        Height, width and channels (1 or 3) as :func:`read_image` returns them.

    Raises
    ------
    DecodeError
        If the header cannot be read.
    """
    path = Path(path)
    try:
        if path.suffix.lower() in _TIFF_SUFFIXES:
            import tifffile

            from ..io_read import _quiet_tifffile

            with _quiet_tifffile(), tifffile.TiffFile(path) as tif:
                page = tif.pages[0]
                shape = dict(zip(page.axes, page.shape))
            samples = shape.get("S", 1)
            return shape["Y"], shape["X"], 3 if samples >= 3 else 1
        declared = _png_header_shape(np.fromfile(path, np.uint8, count=26))
        if declared is not None:
            (height, width, samples), _ = declared
            return height, width, 1 if samples <= 2 else 3
        with _pillow_header(path) as image:
            width, height = image.size
            return height, width, _pil_channels(image)
    except Exception as exc:
        raise _unreadable(path, exc) from exc
