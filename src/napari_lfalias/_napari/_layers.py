"""Light-field layers and the widgets' output layers.

A light field is shown as one Image layer of the 4-D array with dims
``(u, v, y, x)`` (colour as ``rgb``); the :class:`~napari_lfalias.LightField`
itself rides along in ``layer.metadata["lightfield"]`` so that widgets get
the view positions and metadata back. The widgets' results are separate
layers tagged with ``layer.metadata["lfalias"] = <role>`` and updated in
place, so a focus change never piles up new layers.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "LIGHTFIELD_KEY",
    "ROLE_KEY",
    "SOURCE_KEY",
    "PARAMS_KEY",
    "ROLES",
    "lightfield_layer_data",
    "lightfield_of",
    "lightfield_layers",
    "find_output_layer",
    "show_output",
]

#: ``layer.metadata`` key of the LightField behind a light-field layer.
LIGHTFIELD_KEY = "lightfield"
#: ``layer.metadata`` key of an output layer's role.
ROLE_KEY = "lfalias"
#: ``layer.metadata`` key naming the light-field layer an output came from.
SOURCE_KEY = "lfalias_source"

#: ``layer.metadata`` key of the parameters an output was computed with.
PARAMS_KEY = "lfalias_params"

#: Colours of the aliasing mask (1 = aliased) and of the levels l* = 1..8 (0: transparent).
MASK_COLOURS = {None: "transparent", 0: "transparent", 1: "#ffcc00"}
LEVEL_COLOURS = {
    None: "transparent", 0: "transparent", 1: "#4fc3f7", 2: "#66bb6a", 3: "#ffa726",
    4: "#ef5350", 5: "#ab47bc", 6: "#8d6e63", 7: "#bdbdbd", 8: "#ffffff",
}

#: Output roles and how each is displayed.
ROLES = {
    "refocus": {"layer_type": "image", "kwargs": {}},
    "cv": {"layer_type": "image", "kwargs": {"colormap": "magma", "blending": "additive"}},
    "mask": {"layer_type": "labels", "kwargs": {"opacity": 0.6, "colormap": MASK_COLOURS}},
    "level": {"layer_type": "labels", "kwargs": {"opacity": 0.6, "colormap": LEVEL_COLOURS}},
    "fused": {"layer_type": "image", "kwargs": {}},
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
        light field under ``"lightfield"``.
    """
    rgb = lf.n_channels == 3
    data = lf.data if rgb else lf.data[..., 0]
    kwargs = {
        "name": name,
        "rgb": rgb,
        "metadata": {LIGHTFIELD_KEY: lf},
        "axis_labels": ("u", "v", "y", "x"),
        "contrast_limits": _display_range(lf),
    }
    return (data, kwargs, "image")


def lightfield_of(layer):
    """The LightField behind ``layer``, or ``None`` if it is not a light-field layer."""
    metadata = getattr(layer, "metadata", None) or {}
    return metadata.get(LIGHTFIELD_KEY)


def lightfield_layers(viewer):
    """The layers of ``viewer`` that hold a light field, in layer-list order."""
    return [layer for layer in viewer.layers if lightfield_of(layer) is not None]


def find_output_layer(viewer, role, source=None):
    """The output layer of ``role`` (made from the layer named ``source``), or ``None``."""
    for layer in viewer.layers:
        metadata = layer.metadata or {}
        if metadata.get(ROLE_KEY) != role:
            continue
        if source is None or metadata.get(SOURCE_KEY) == source:
            return layer
    return None


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
        Extra layer attributes (``contrast_limits``, ``name``, ...) applied on
        creation and on every update.

    Returns
    -------
    layer : napari.layers.Layer
        The updated (or new) layer. Its array belongs to the layer: an
        update is copied into it, so arrays passed in are never changed later.
    """
    spec = ROLES[role]
    layer = find_output_layer(viewer, role, source)
    expected = "labels" if spec["layer_type"] == "labels" else "image"
    if layer is not None and (
        layer._type_string != expected or layer.data.shape != data.shape
    ):
        viewer.layers.remove(layer)
        layer = None
    if layer is None:
        options = dict(spec["kwargs"])
        options.update(kwargs)
        options.setdefault("name", f"{role} [{source}]")
        options["metadata"] = {ROLE_KEY: role, SOURCE_KEY: source, PARAMS_KEY: params}
        # the layer owns its array, so later updates can be written into it
        data = np.array(data, copy=True)
        if expected == "labels":
            return viewer.add_labels(data, **options)
        return viewer.add_image(data, rgb=data.ndim == 3, **options)
    layer.metadata[PARAMS_KEY] = params
    for key, value in kwargs.items():
        if key != "name" and not np.array_equal(getattr(layer, key), value):
            setattr(layer, key, value)
    if isinstance(layer.data, np.ndarray) and layer.data.dtype == data.dtype:
        # writing into the layer's own array and refreshing costs half of
        # setting ``layer.data`` (no new-data bookkeeping)
        np.copyto(layer.data, data)
        layer.refresh()
    else:
        layer.data = np.array(data, copy=True)
    return layer
