"""Microscope optics beside a lenslet capture, for metric depth.

napari-LF keeps the optics of a light-field microscope capture in a JSON
file ``metadata.txt`` beside it (section ``"calibrate"``: microlens pitch
and pixel size in micrometres, objective magnification and NA, medium
index); the Stanford / napari-LF example folders also carry a ``README``
with a "SUMMARY OF OPTICAL PARAMETERS" (``pitch 100 um``, ``na 1.2``, ...).
When either is there, :func:`attach_optics` copies those numbers into
``lf.meta["microscope"]``, where :func:`~._depth.depth_of_slope` turns a
focus slope into an axial position.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

__all__ = [
    "MICROSCOPE_KEY",
    "read_microscope_optics",
    "attach_optics",
    "Calibration",
    "spatial_calibration",
    "sensor_calibration",
]

#: ``lf.meta`` key of the microscope optics.
MICROSCOPE_KEY = "microscope"
#: File napari-LF writes beside a capture.
METADATA_NAME = "metadata.txt"
#: README summary names -> ours.
_SUMMARY_FIELDS = {
    "pitch": "ulens_pitch_um",
    "pixel-size": "pixel_size_um",
    "magnification": "magnification",
    "na": "na",
    "medium-index": "medium_index",
}
_SUMMARY_TITLE = "SUMMARY OF OPTICAL PARAMETERS"
#: napari-LF names -> ours.
_FIELDS = {
    "ulens_pitch": "ulens_pitch_um",
    "pixel_size": "pixel_size_um",
    "objective_magnification": "magnification",
    "objective_na": "na",
    "medium_index": "medium_index",
}
#: Largest metadata file read (napari-LF's are a few kB).
_MAX_BYTES = 1 << 20


def _text(path):
    try:
        if not path.is_file() or path.stat().st_size > _MAX_BYTES:
            return None
        return path.read_text()
    except (OSError, UnicodeDecodeError):
        return None


def _checked(values, fields):
    """``{ours: float}`` when every field is a positive finite number, else ``None``."""
    optics = {}
    for theirs, ours in fields.items():
        value = values.get(theirs)
        if isinstance(value, str):
            try:
                value = float(value.rstrip("xX"))
            except ValueError:
                return None
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return None
        if not (math.isfinite(value) and value > 0):
            return None
        optics[ours] = float(value)
    return optics


def _from_metadata(folder):
    text = _text(Path(folder) / METADATA_NAME)
    try:
        section = json.loads(text).get("calibrate") if text else None
    except (ValueError, AttributeError):
        return None
    return _checked(section, _FIELDS) if isinstance(section, dict) else None


def _from_readme(folder):
    for path in sorted(Path(folder).glob("README*")):
        text = _text(path)
        if not text or _SUMMARY_TITLE not in text:
            continue
        values = {}
        for line in text.split(_SUMMARY_TITLE, 1)[1].splitlines():
            words = line.split()
            if len(words) >= 2 and words[0].lower() in _SUMMARY_FIELDS:
                values.setdefault(words[0].lower(), words[1])
        optics = _checked(values, _SUMMARY_FIELDS)
        if optics is not None:
            return optics
    return None


def read_microscope_optics(folder):
    """The microscope optics described beside a capture in ``folder``, or ``None``.

    Parameters
    ----------
    folder : Path
        Folder of the capture.

    Returns
    -------
    dict or None
        ``ulens_pitch_um``, ``pixel_size_um`` (at the sensor, after any
        relay), ``magnification``, ``na``, ``medium_index`` (positive
        finite numbers), from napari-LF's ``metadata.txt`` or else a
        ``README*`` summary; ``None`` when neither gives all five.
    """
    return _from_metadata(folder) or _from_readme(folder)


def attach_optics(lf, capture):
    """Put the optics found beside ``capture`` into ``lf.meta["microscope"]`` (if any).

    Only lenslet decodes (``lf.meta["grid"]`` set) get them; a light field
    that already has optics keeps its own.

    Returns
    -------
    LightField
        ``lf`` itself.
    """
    if lf.meta.get("grid") is None or MICROSCOPE_KEY in lf.meta:
        return lf
    capture = Path(capture)
    optics = read_microscope_optics(capture if capture.is_dir() else capture.parent)
    if optics is not None:
        lf.meta[MICROSCOPE_KEY] = optics
    return lf


# -- where the pixels lie ----------------------------------------------------------


@dataclass(frozen=True)
class Calibration:
    """Where an image's pixels lie: napari's ``scale``, ``translate`` and ``units`` of its (y, x) axes.

    Attributes
    ----------
    scale : tuple of float
        Size of a pixel along y and x.
    translate : tuple of float
        Position of pixel (0, 0)'s centre.
    unit : str
        ``"um"`` (micrometres in the specimen) or ``"pixel"`` (sensor pixels).
    """

    scale: tuple = (1.0, 1.0)
    translate: tuple = (0.0, 0.0)
    unit: str = "pixel"

    @property
    def physical(self):
        """True when the unit is a length, not a pixel count."""
        return self.unit != "pixel"


def _specimen_um_per_sensor_px(optics):
    return optics["pixel_size_um"] / optics["magnification"]


def sensor_calibration(optics):
    """Calibration of a raw sensor image (a white image): micrometres in the specimen, or pixels.

    Parameters
    ----------
    optics : dict or None
        Microscope optics (:func:`read_microscope_optics`).

    Returns
    -------
    Calibration
    """
    if not isinstance(optics, dict):
        return Calibration()
    step = _specimen_um_per_sensor_px(optics)
    return Calibration((step, step), (0.0, 0.0), "um")


def spatial_calibration(lf):
    """Where the decoded pixels of ``lf`` lie, as far as its metadata tell.

    A lenslet decode has one pixel per microlens: its pixels are one lens
    pitch apart (a row step along y), and pixel (0, 0) is lens (0, 0), so
    the light field lies exactly over the sensor image it was decoded from.
    With microscope optics the unit is micrometres in the specimen (the
    sensor pixel size over the magnification), else sensor pixels. Other
    light fields: one unit per pixel, at the origin.

    Returns
    -------
    Calibration

    Examples
    --------
    >>> import numpy as np
    >>> from napari_lfalias import LightField
    >>> spatial_calibration(LightField(np.zeros((2, 2, 4, 4, 1), np.float32)))
    Calibration(scale=(1.0, 1.0), translate=(0.0, 0.0), unit='pixel')
    """
    grid = lf.meta.get("grid")
    pitch = getattr(grid, "pitch", None)
    if not pitch:
        return Calibration()
    step_y, step_x = float(grid.row_step), float(pitch)
    if getattr(grid, "transposed", False):
        step_y, step_x = step_x, step_y
    origin = tuple(float(v) for v in grid.centres[0])
    optics = lf.meta.get(MICROSCOPE_KEY)
    if isinstance(optics, dict):
        um = _specimen_um_per_sensor_px(optics)
        return Calibration((step_y * um, step_x * um), (origin[0] * um, origin[1] * um), "um")
    return Calibration((step_y, step_x), origin, "pixel")
