"""Metric depth of a focus slope, where the light field's calibration allows it.

- Camera arrays with HCI parameters (or a decoder's ``depth_of_disparity``):
  the distance of the plane in focus, in metres.
- Light-field microscopes (optics in ``lf.meta["microscope"]``, see
  :mod:`._optics`): the axial offset of the plane in focus from the native
  object plane, in micrometres.
"""

from __future__ import annotations

import math

from ._optics import MICROSCOPE_KEY

__all__ = ["depth_of_slope", "microscope_offset_um", "depth_label"]

#: HCI ``parameters.cfg`` values needed to turn disparity into depth.
_HCI_KEYS = ("baseline_mm", "focal_length_mm", "focus_distance_m", "sensor_size_mm")


def _flatten(params):
    """``parameters.cfg`` values, whether kept flat or by section (``intrinsics``, ...)."""
    flat = {}
    for key, value in params.items():
        if isinstance(value, dict):
            flat.update(value)
        else:
            flat[key] = value
    return flat


def _hci_parameters(meta):
    for key in ("hci", "hci_parameters", "parameters"):
        params = meta.get(key)
        if isinstance(params, dict):
            params = _flatten(params)
            if all(k in params for k in _HCI_KEYS):
                return params
    return None


def depth_of_slope(lf, slope):
    """Depth in metres of the plane in focus at ``slope``, or ``None`` if unknown.

    Uses, in order, a callable ``lf.meta["depth_of_disparity"]`` set by the
    decoder, or HCI benchmark parameters (``parameters.cfg``, as the
    camera-array decoder keeps them in ``lf.meta["hci"]``). For a shifted-sensor camera array with
    baseline ``b``, focal length ``f``, sensor width ``s`` over ``W`` pixels
    and focus distance ``D``, a point at depth ``Z`` moves
    ``d = (b f W / s) (1/D - 1/Z)`` pixels per view step (positive behind
    the focus plane under this package's convention), so
    ``Z = 1 / (1/D - d s / (b f W))``.

    Returns
    -------
    float or None
        ``None`` when the metadata carry no calibration, or the plane lies
        at or beyond infinity.
    """
    meta = lf.meta
    convert = meta.get("depth_of_disparity")
    if callable(convert):
        return float(convert(slope))
    params = _hci_parameters(meta)
    if params is None:
        return None
    width_px = float(params.get("width", params.get("image_resolution_x_px", lf.image_shape[1])))
    scale = (
        float(params["baseline_mm"]) * float(params["focal_length_mm"]) * width_px
        / float(params["sensor_size_mm"])
    )  # b f W / s, in mm x pixels
    inverse_depth = 1.0 / float(params["focus_distance_m"]) - slope * 1e3 / scale
    if inverse_depth <= 0 or not math.isfinite(inverse_depth):
        return None
    return 1.0 / inverse_depth


def _lens_geometry(lf, optics):
    """``(pitch_px, row_step / pitch)`` of the lens grid (fitted, else from the optics)."""
    grid = lf.meta.get("grid")
    pitch = getattr(grid, "pitch", None)
    row_step = getattr(grid, "row_step", None)
    if pitch and row_step:
        return float(pitch), float(row_step) / float(pitch)
    return optics["ulens_pitch_um"] / optics["pixel_size_um"], 1.0


def microscope_offset_um(lf, slope):
    """Axial offset in micrometres of the plane in focus at ``slope`` (light-field microscope).

    The microlenses sit at the native image plane, so each decoded pixel
    is one lens, ``s = pitch_um (row_step / pitch) / M`` micrometres in the
    specimen, and the ``r = pitch_px / (2 view_step)`` views from a lens'
    centre to its rim span the objective's aperture, ``n sin(theta) = NA``
    at the rim. A point at axial offset ``z`` moves ``z tan(theta)`` in the
    specimen between views; paraxially (``tan ~ sin``) that is
    ``d = z NA / (n r s)`` decoded pixels per view step, so
    ``z = d n r s / NA``. Positive ``z`` lies beyond the native plane, away
    from the objective (the lenslet decoder's sign: nearer the main lens is
    ``d < 0``). The paraxial step holds near the aperture's centre; at NA
    1.2 in water the outer views tilt more than it assumes.

    Returns
    -------
    float or None
        ``None`` without microscope optics in ``lf.meta``.
    """
    optics = lf.meta.get(MICROSCOPE_KEY)
    if not isinstance(optics, dict):
        return None
    try:
        pitch_px, ratio = _lens_geometry(lf, optics)
        step = float(lf.meta.get("view_step_px", 1.0))
        views_per_radius = pitch_px / (2.0 * step)
        specimen_px_um = optics["ulens_pitch_um"] * ratio / optics["magnification"]
        z = slope * optics["medium_index"] * views_per_radius * specimen_px_um / optics["na"]
    except (KeyError, TypeError, ValueError, ZeroDivisionError):
        return None
    return float(z) if math.isfinite(z) else None


def depth_label(lf, slope):
    """Text for the depth of the focus plane (``""`` when it is unknown)."""
    offset = microscope_offset_um(lf, slope)
    if offset is not None:
        return f"z \u2248 {offset:+.3g} \u00b5m from the native object plane"
    depth = depth_of_slope(lf, slope)
    if depth is None:
        return ""
    return f"depth {depth:.3g} m"
