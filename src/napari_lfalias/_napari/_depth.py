"""Metric depth of a focus slope, where the light field's calibration allows it."""

from __future__ import annotations

import math

__all__ = ["depth_of_slope", "depth_label"]

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


def depth_label(lf, slope):
    """Text for the depth of the focus plane (``""`` when it is unknown)."""
    depth = depth_of_slope(lf, slope)
    if depth is None:
        return ""
    return f"depth {depth:.3g} m"
