"""Synthetic light fields with exact ground truth (disparity, dense-aperture reference).

>>> from napari_lfalias.synthetic import brick_room
>>> scene = brick_room(n_views=3, size=32, seed=0)
>>> scene.lightfield.shape
(3, 3, 32, 32, 3)
"""

from .lenslet import LensletCapture, SceneRadiance, render_lenslet
from .scenes import TEXTURES, Plane, SyntheticScene, brick_room, layered_scene, textured_plane, textureless_plane

__all__ = [
    "Plane", "SyntheticScene", "brick_room", "textured_plane", "textureless_plane", "layered_scene", "TEXTURES",
    "LensletCapture", "SceneRadiance", "render_lenslet",
]
