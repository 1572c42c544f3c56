"""napari sample data: the synthetic brick room and the bundled GUV capture."""

from __future__ import annotations

from ._layers import lightfield_layer_data

__all__ = ["brick_room", "guv_capture", "GUV_FILES"]

#: The bundled GUV light-field microscope capture (napari-LF, BSD-3).
GUV_FILES = {
    "raw": "Lightfield_GUVExperim1.tif",
    "white": "Radiometry_GUVExperim1.tif",
    "dark": "DarkFrame_GUVExperim1.tif",
}


def brick_room(n_views=8, size=256, seed=0):
    """The brick room of Xiao et al. (2014), Figure 6, as a light-field layer.

    A brick wall at disparity -4 behind a tiled cube at +4, 8 x 8 views:
    focused on the cube (slope 4), the wall's copies lie 8 px apart and
    its mortar lines stripe the refocus; "Reduce aliasing" with the
    default (dense-aperture) method removes the stripes and keeps the cube
    exactly. 256 x 256 px views keep the disparity estimate (once per light
    field) under a few seconds.

    Parameters
    ----------
    n_views : int
        Views per side of the camera grid.
    size : int
        Width and height of each view in pixels.
    seed : int
        Seed of the procedural textures.

    Returns
    -------
    list of tuple
        One layer-data tuple: the ``(U, V, Y, X, 3)`` light field, its
        LightField (with ground-truth disparity in its metadata) in
        ``metadata["lightfield"]``.
    """
    from ..synthetic import brick_room as make_scene

    scene = make_scene(n_views=n_views, size=size, seed=seed)
    return [lightfield_layer_data(scene.lightfield, "brick room")]


def guv_capture():
    """The GUV light-field microscope capture, decoded to a 4-D light field.

    The raw lenslet image is calibrated with its radiometry (white) and
    dark frames and sliced into views by
    :func:`napari_lfalias.decoders.lenslet.load_lenslet`; the microscope
    optics of its ``metadata.txt`` go into ``meta["microscope"]`` (the
    widget then shows the axial position of the focus plane).

    Returns
    -------
    list of tuple
        One layer-data tuple of the decoded light field.
    """
    from .. import load
    from .._paths import sample_data_dir
    from ._optics import attach_optics

    folder = sample_data_dir() / "guv"
    raw = folder / GUV_FILES["raw"]
    lf = load(raw, white=folder / GUV_FILES["white"], dark=folder / GUV_FILES["dark"])
    return [lightfield_layer_data(attach_optics(lf, raw), "GUV capture")]
