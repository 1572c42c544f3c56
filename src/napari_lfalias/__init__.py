"""napari-lfalias: light-field decoding, refocusing, and angular-aliasing
detection and reduction (Xiao et al., CVPR 2014).

The public API (DESIGN section 3) is available from the package::

    import napari_lfalias as lfa
    lf = lfa.load(path)
    lfa.save(lf, "views.tif")          # what save writes, load reads back
    img = lfa.refocus(lf, slope)
    det = lfa.detect_aliasing(lf, slope)
    res = lfa.reduce_aliasing(lf, slope)

Submodules are imported on first use, so ``import napari_lfalias`` stays
cheap (the napari plugin and the command line start fast).
"""

import importlib

from .errors import CalibrationError, DecodeError, LightFieldError, OutputExistsError, ParameterError
from .lightfield import LightField, regular_positions

# Imported eagerly: the function shares its name with its module, and a lazy
# import of the module would shadow the function on the package.
from .refocus import ShiftedStack, refocus, shift_views, view_moments

__version__ = "0.1.0"

# public name -> submodule that defines it
_LAZY = {
    "load": "loading",
    "save": "loading",
    "detect_aliasing": "detect",
    "AliasingDetector": "detect",
    "Detection": "detect",
    "estimate_disparity": "disparity",
    "DisparityEstimate": "disparity",
    "antialiased_refocus": "render",
    "reduce_aliasing": "reduce",
    "Reduction": "reduce",
    "prefilter_refocus": "baselines",
    "depth_aware_refocus": "baselines",
    "refocus_sweep": "sweep",
}

_SUBMODULES = {
    "decoders", "synthetic", "metrics", "poisson", "detect", "reduce",
    "baselines", "refocus", "loading", "sweep", "pyramid", "io_read", "io_write", "disparity", "render",
    "depth_guided", "presets",
}

__all__ = [
    "LightField",
    "regular_positions",
    "LightFieldError",
    "ParameterError",
    "DecodeError",
    "CalibrationError",
    "OutputExistsError",
    "refocus",
    "shift_views",
    "view_moments",
    "ShiftedStack",
    *_LAZY,
]


def __getattr__(name):
    if name in _LAZY:
        module = importlib.import_module(f".{_LAZY[name]}", __name__)
        value = getattr(module, name)
        globals()[name] = value
        return value
    if name in _SUBMODULES:
        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__) | _SUBMODULES)
