"""Decoders: camera-array folders and lenslet (plenoptic) captures to a LightField.

- :mod:`.camera_array` -- folders of views (HCI, Stanford, indexed names).
- :mod:`.sensor` -- raw sensor readers (TIFF, PNG, camera raw, Lytro).
- :mod:`.lenslet` -- white-image calibration (:func:`calibrate`,
  :class:`GridModel`) and microlens-to-pinhole slicing.
"""

import importlib

_LAZY = {
    "load_camera_array": "camera_array",
    "calibrate": "lenslet",
    "GridModel": "lenslet",
    "load_lenslet": "lenslet",
    "decode_lenslet": "lenslet",
    "read_sensor": "sensor",
}

__all__ = list(_LAZY)


def __getattr__(name):
    if name in _LAZY:
        module = importlib.import_module(f".{_LAZY[name]}", __name__)
        return getattr(module, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
