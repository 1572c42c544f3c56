"""Light-field layers and the widgets' output layers, and the rules that lay them out.

A light field is shown as one Image layer of the 4-D array with dims
``(u, v, y, x)`` (colour as ``rgb``); the :class:`~napari_lfalias.LightField`
itself rides along in ``layer.metadata["lightfield"]`` so that widgets get
the view positions and metadata back. Where the metadata say where the
pixels lie (a lenslet decode: one pixel per microlens; micrometres with
microscope optics), the layer carries that ``scale``, ``translate`` and
``units`` (:func:`~._optics.spatial_calibration`).

The widgets' results are separate layers tagged with
``layer.metadata["lfalias"] = <role>`` and updated in place, so a focus
change never piles up new layers. How each role is shown is one table,
:data:`ROLES` (:class:`Role`): every output inherits the light field's
spatial calibration and sits either over the refocused image (``"over"``)
or in the panel beside it (``"beside"``, for a side-by-side compare);
values the eye must read off (Cv, disparity) get a colormap, a colorbar
and contrast limits that follow the data until the user sets their own;
class maps (mask, level map) are translucent labels over their image.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "LIGHTFIELD_KEY",
    "ROLE_KEY",
    "SOURCE_KEY",
    "PARAMS_KEY",
    "FILE_KEY",
    "Role",
    "ROLES",
    "MASK_COLOURS",
    "LEVEL_COLOURS",
    "lightfield_layer_data",
    "lightfield_of",
    "lightfield_layers",
    "find_output_layer",
    "output_layers",
    "show_output",
    "adaptive_limits",
    "placement",
]

#: ``layer.metadata`` key of the LightField behind a light-field layer.
LIGHTFIELD_KEY = "lightfield"
#: ``layer.metadata`` key of an output layer's role.
ROLE_KEY = "lfalias"
#: ``layer.metadata`` key naming the light-field layer an output came from.
SOURCE_KEY = "lfalias_source"
#: ``layer.metadata`` key of the parameters an output was computed with.
PARAMS_KEY = "lfalias_params"
#: ``layer.metadata`` key of the file an output was opened from (such layers are never updated).
FILE_KEY = "lfalias_file"
#: ``layer.metadata`` key of the contrast limits last set automatically.
_AUTO_KEY = "lfalias_auto_contrast"

#: Colours of the aliasing mask (1 = aliased) and of the levels l* = 1..8 (0: transparent).
MASK_COLOURS = {None: "transparent", 0: "transparent", 1: "#ff00ff"}
LEVEL_COLOURS = {
    None: "transparent", 0: "transparent", 1: "#4fc3f7", 2: "#66bb6a", 3: "#ffa726",
    4: "#ef5350", 5: "#ab47bc", 6: "#8d6e63", 7: "#bdbdbd", 8: "#ffffff",
}
#: Values the adaptive contrast limits are taken from (a regular subsample of larger maps).
ADAPTIVE_SAMPLES = 65536
#: Gap between the refocused image and the panel beside it, as a fraction of the image width.
PANEL_GAP = 0.04


@dataclass(frozen=True)
class Role:
    """How the output layers of one role are shown.

    Attributes
    ----------
    layer_type : {"image", "labels"}
    place : {"over", "beside"}
        Over the refocused image, or in the panel beside it (when the
        widget compares side by side; else over it too).
    visible : bool
        Shown when the layer is made (the user's choice is kept afterwards).
    contrast : {"source", "adaptive", None}
        The light field's display range (images of the scene), limits that
        follow each new result (maps of a quantity), or none (labels).
    colorbar : bool
        Draw a colorbar for the layer's colormap.
    title : str
        What the layer shows, for its name.
    kwargs : dict
        Further layer attributes (colormap, opacity, blending).
    """

    layer_type: str
    place: str
    visible: bool
    contrast: str | None
    colorbar: bool
    title: str
    kwargs: dict = field(default_factory=dict)


#: Output roles and how each is displayed. Depth and anti-aliased layers
#: (DESIGN section 3: ``estimate_disparity``, ``antialiased_refocus``) follow
#: the same rules: a disparity map is a quantity (colormap, colorbar,
#: contrast from its own range) over the refocus, hidden like the Cv until
#: asked for; an anti-aliased rendering is an image beside the refocus, in
#: the reduced image's place and hidden under it (toggle it to compare: the
#: reduced image keeps the naive refocus wherever nothing is predicted to alias).
ROLES = {
    "refocus": Role("image", "over", True, "source", False, "refocused"),
    "cv": Role("image", "over", False, "adaptive", True, "Cv",
               {"colormap": "magma", "blending": "translucent_no_depth", "opacity": 1.0}),
    "mask": Role("labels", "over", True, None, False, "aliased pixels",
                 {"opacity": 0.4, "colormap": MASK_COLOURS}),
    "fused": Role("image", "beside", True, "source", False, "reduced"),
    "level": Role("labels", "beside", False, None, False, "level map",
                  {"opacity": 0.6, "colormap": LEVEL_COLOURS}),
    "disparity": Role("image", "over", False, "adaptive", True, "disparity",
                      {"colormap": "turbo", "blending": "translucent_no_depth", "opacity": 1.0}),
    "antialiased": Role("image", "beside", False, "source", False, "anti-aliased"),
}


def _display_range(lf):
    """Contrast limits from the centre view (cheap even for a lazy light field)."""
    n_rows, n_cols = lf.grid_shape
    centre = lf.data[n_rows // 2, n_cols // 2]
    centre = np.asarray(centre.compute() if hasattr(centre, "compute") else centre)
    low, high = np.percentile(centre, [0.5, 99.8])
    if not high > low:
        high = low + 1.0
    return [float(low), float(high)]


def lightfield_layer_data(lf, name):
    """Return the napari layer-data tuple that shows ``lf`` as a 4-D Image layer.

    Parameters
    ----------
    lf : LightField
        The light field.
    name : str
        Layer name.

    Returns
    -------
    tuple
        ``(data, kwargs, "image")``: ``data`` is ``(U, V, Y, X, 3)`` (rgb)
        or ``(U, V, Y, X)`` (one channel), ``kwargs["metadata"]`` holds the
        light field under ``"lightfield"``; ``scale``, ``translate`` and
        ``units`` place its pixels where the metadata say they lie.
    """
    from ._optics import spatial_calibration

    rgb = lf.n_channels == 3
    data = lf.data if rgb else lf.data[..., 0]
    where = spatial_calibration(lf)
    kwargs = {
        "name": name,
        "rgb": rgb,
        "metadata": {LIGHTFIELD_KEY: lf},
        "axis_labels": ("u", "v", "y", "x"),
        "contrast_limits": _display_range(lf),
        "scale": (1.0, 1.0) + tuple(where.scale),
        "translate": (0.0, 0.0) + tuple(where.translate),
        "units": ("pixel", "pixel", where.unit, where.unit),
    }
    return (data, kwargs, "image")


def lightfield_of(layer):
    """The LightField behind ``layer``, or ``None`` if it is not a light-field layer."""
    metadata = getattr(layer, "metadata", None) or {}
    return metadata.get(LIGHTFIELD_KEY)


def lightfield_layers(viewer):
    """The layers of ``viewer`` that hold a light field, in layer-list order."""
    return [layer for layer in viewer.layers if lightfield_of(layer) is not None]


def output_layers(viewer, source=None):
    """The live output layers of ``viewer`` (made from the layer named ``source``)."""
    found = []
    for layer in viewer.layers:
        metadata = layer.metadata or {}
        if metadata.get(ROLE_KEY) not in ROLES or metadata.get(FILE_KEY):
            continue
        if source is None or metadata.get(SOURCE_KEY) == source:
            found.append(layer)
    return found


def find_output_layer(viewer, role, source=None):
    """The output layer of ``role`` (made from the layer named ``source``), or ``None``.

    Layers opened from saved files are never returned: the widget does not
    write over them.
    """
    for layer in output_layers(viewer, source):
        if layer.metadata.get(ROLE_KEY) == role:
            return layer
    return None


def adaptive_limits(data, at_least=0.0, from_zero=True):
    """Contrast limits that follow ``data``: up to its 99.5th percentile (and at least ``at_least``).

    Percentiles of a 2-D map are taken on a regular subsample of at most
    :data:`ADAPTIVE_SAMPLES` values (display limits need no more).

    Parameters
    ----------
    data : ndarray
        The map (Cv, disparity).
    at_least : float
        Smallest upper limit (for a Cv: twice the threshold, so T sits in
        the lower half of the colour range).
    from_zero : bool
        Start at 0 (a Cv), else at the 0.5th percentile (a disparity).

    Returns
    -------
    list of float

    Examples
    --------
    >>> adaptive_limits(np.linspace(0, 0.1, 1001), at_least=0.02)
    [0.0, 0.0995]
    """
    data = np.asarray(data)
    step = max(1, int(np.sqrt(data.size / ADAPTIVE_SAMPLES)))  # percentiles of a regular subsample
    finite = np.asarray(data[::step, ::step] if data.ndim == 2 else data, np.float64)
    finite = finite[np.isfinite(finite)]
    if finite.size == 0:
        return [0.0, max(at_least, 1.0)]
    low, high = (float(v) for v in np.percentile(finite, [0.5, 99.5]))
    low = 0.0 if from_zero else low
    high = max(high, at_least, low + 1e-6)
    return [round(low, 6), round(high, 6)]


def placement(source_layer, role, beside=True):
    """``scale``, ``translate`` and ``units`` of an output of ``role`` made from ``source_layer``.

    Outputs inherit the light field's spatial calibration (its last two
    axes); a ``"beside"`` role is moved right by the image's width and a
    small gap when ``beside``.

    Returns
    -------
    dict
    """
    scale = tuple(float(v) for v in source_layer.scale[-2:])
    translate = [float(v) for v in source_layer.translate[-2:]]
    units = tuple(str(u) for u in source_layer.units[-2:])
    if beside and ROLES[role].place == "beside":
        width = source_layer.data.shape[-2 if source_layer.rgb else -1]
        translate[1] += width * scale[1] * (1.0 + PANEL_GAP)
    return {"scale": scale, "translate": tuple(translate), "units": units}


def _auto_contrast(layer, limits):
    """Set ``limits`` unless the user chose the layer's contrast since the last automatic setting."""
    last = layer.metadata.get(_AUTO_KEY)
    if last is not None and not np.allclose(layer.contrast_limits, last):
        return  # the user's own limits stay
    layer.contrast_limits = limits
    layer.metadata[_AUTO_KEY] = list(layer.contrast_limits)


def show_output(viewer, role, data, source, params=None, **kwargs):
    """Put ``data`` into the output layer of ``role``, adding the layer the first time.

    Parameters
    ----------
    viewer : napari.Viewer
    role : str
        One of :data:`ROLES`.
    data : ndarray
        ``(Y, X)`` or ``(Y, X, 3)`` for images; ``(Y, X)`` integers for labels.
    source : str
        Name of the light-field layer the output was computed from.
    params : dict, optional
        What the data were computed with, stored in
        ``layer.metadata["lfalias_params"]``.
    **kwargs
        Extra layer attributes (``contrast_limits``, ``name``, ``scale``,
        ...) applied on creation and on every update; for an
        ``"adaptive"`` role ``contrast_limits`` follow each update until the
        user sets the layer's own.

    Returns
    -------
    layer : napari.layers.Layer
        The updated (or new) layer. Its array belongs to the layer: an
        update is copied into it, so arrays passed in are never changed later.
    """
    spec = ROLES[role]
    layer = find_output_layer(viewer, role, source)
    expected = spec.layer_type
    if layer is not None and (layer._type_string != expected or layer.data.shape != data.shape):
        viewer.layers.remove(layer)
        layer = None
    adaptive = spec.contrast == "adaptive" and "contrast_limits" in kwargs
    limits = kwargs.pop("contrast_limits") if adaptive else None
    if layer is None:
        options = dict(spec.kwargs)
        options.update(kwargs)
        options.setdefault("name", f"{spec.title} [{source}]")
        options.setdefault("visible", spec.visible)
        options["metadata"] = {ROLE_KEY: role, SOURCE_KEY: source, PARAMS_KEY: params}
        # the layer owns its array, so later updates can be written into it
        data = np.array(data, copy=True)
        if expected == "labels":
            layer = viewer.add_labels(data, **options)
        else:
            layer = viewer.add_image(data, rgb=data.ndim == 3, **options)
            layer.colorbar.visible = spec.colorbar
        if adaptive:
            _auto_contrast(layer, limits)
        return layer
    layer.metadata[PARAMS_KEY] = params
    for key, value in kwargs.items():
        if key != "name" and not _same(key, getattr(layer, key), value):
            setattr(layer, key, value)
    if adaptive:
        _auto_contrast(layer, limits)
    if isinstance(layer.data, np.ndarray) and layer.data.dtype == data.dtype:
        # writing into the layer's own array and refreshing costs half of
        # setting ``layer.data`` (no new-data bookkeeping)
        np.copyto(layer.data, data)
        layer.refresh()
    else:
        layer.data = np.array(data, copy=True)
    return layer


def _same(key, current, value):
    if key == "units":
        return tuple(str(u) for u in current) == tuple(str(u) for u in value)
    try:
        return bool(np.array_equal(np.asarray(current, dtype=object), np.asarray(value, dtype=object)))
    except (TypeError, ValueError):
        return current == value
