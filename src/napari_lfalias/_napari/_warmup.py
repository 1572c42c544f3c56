"""The numeric kernels, made ready in the background when the plugin activates.

The core's numba kernels are compiled on their first call and cached next
to the code; later sessions load them from the cache in a fraction of a
second each. Without this module the first focus change would do that
work itself: 20 s or more on a fresh install, while the widget looked idle.
:func:`start` runs every kernel the widgets use once, on a tiny light
field, in a background thread: napari calls it when the plugin activates
(``on_activate`` in the manifest), and the widgets call it when they open.
:func:`state` tells the widgets what is happening, so they can say it.

A call that takes more than :data:`COMPILING_AFTER_S` is compiling (loading
from the cache takes about a tenth of that); :func:`state` then reads
``"compiling"``.
"""

from __future__ import annotations

import atexit
import threading
import time

__all__ = ["start", "state", "wait", "activate", "COMPILING_AFTER_S", "STEPS"]

#: A kernel call taking longer than this (seconds) is compiling, not loading from the cache.
COMPILING_AFTER_S = 1.0

_lock = threading.Lock()
_thread = None
_done = threading.Event()
_stop = threading.Event()
_current = {"step": None, "since": None}
_compiled = []  # steps that took longer than COMPILING_AFTER_S
_failed = []


def _tiny_lightfield():
    import numpy as np

    from ..lightfield import LightField

    rng = np.random.default_rng(0)
    return LightField(rng.random((3, 3, 24, 24, 3), dtype=np.float32))


def _refocus(lf):
    from ..refocus import refocus

    refocus(lf, 0.5)


def _detect(lf):
    from ..detect import AliasingDetector, detect_aliasing

    detector = AliasingDetector(lf, skip_flat=False)  # as the widget's session makes it
    detector.detect(0.5, method="analytic")  # the live Cv (presets.INTERACTIVE_METHOD)
    detector.detect(0.5, method="analytic", level=1)  # previews and the reduction's levels
    detector.detect(0.5, method="monte_carlo", n_patterns=4, seed=0)
    detect_aliasing(lf, 0.5, threshold=0.5, method="analytic")  # flat tiles skipped: the tiled moments


def _pyramid(lf):
    from ..pyramid import lightfield_pyramid

    lightfield_pyramid(lf, 1)


def _fusion(lf):
    import numpy as np

    from ..poisson import fuse_gradients

    base = lf.data[0, 0]
    labels = np.zeros(base.shape[:2], np.int32)
    labels[8:16, 8:16] = 1
    fuse_gradients(base, [base * 0.5], labels, screen=0.25)


def _disparity(lf):
    """The disparity estimate and the dense-aperture rendering (the default method's reduction)."""
    import numpy as np

    from ..disparity import estimate_disparity
    from ..lightfield import LightField
    from ..render import antialiased_refocus

    # 192 px a side: the estimate's coarse-to-fine path runs too (one coarse level)
    small = LightField(np.random.default_rng(1).random((3, 3, 192, 192, 3), dtype=np.float32))
    estimate = estimate_disparity(small, disparity_range=(-1.0, 1.0))
    antialiased_refocus(small, 0.5, estimate)


#: What is made ready, in order: (name, function of the tiny light field).
STEPS = (
    ("refocus", _refocus),
    ("aliasing detection", _detect),
    ("pyramid", _pyramid),
    ("gradient-domain fusion", _fusion),
    ("disparity estimate and dense-aperture rendering", _disparity),
)


def _run():
    try:
        lf = _tiny_lightfield()
        for name, step in STEPS:
            if _stop.is_set():
                return
            _current.update(step=name, since=time.perf_counter())
            began = time.perf_counter()
            try:
                step(lf)
            except Exception as error:  # noqa: BLE001 - a failed warm-up only costs the first use its time
                _failed.append((name, error))
            if time.perf_counter() - began > COMPILING_AFTER_S:
                _compiled.append(name)
    finally:
        _current.update(step=None, since=None)
        _done.set()


def start():
    """Start making the kernels ready in a background thread (once per process; later calls do nothing).

    Returns
    -------
    threading.Thread
    """
    global _thread
    with _lock:
        if _thread is None:
            _thread = threading.Thread(target=_run, name="napari-lfalias kernel warm-up", daemon=True)
            _thread.start()
        return _thread


def activate(context=None):
    """npe2's ``on_activate`` hook: start the warm-up when napari first uses the plugin."""
    start()


def state():
    """What the warm-up is doing.

    Returns
    -------
    str
        ``"idle"`` (not started), ``"loading"`` (a step is running, so far
        no longer than a cache load), ``"compiling"`` (the running step
        takes longer: numba compiles it), or ``"ready"``.
    """
    if _done.is_set():
        return "ready"
    if _thread is None:
        return "idle"
    since = _current["since"]
    if since is not None and time.perf_counter() - since > COMPILING_AFTER_S:
        return "compiling"
    return "compiling" if _compiled else "loading"


def wait(timeout_s=None):
    """Block until the warm-up has finished (True) or ``timeout_s`` passed (False)."""
    return _done.wait(timeout_s)


def _stop_at_exit():
    _stop.set()
    if _thread is not None:
        _thread.join(timeout=5.0)  # a step being compiled ends soon; the next one is not started


atexit.register(_stop_at_exit)
