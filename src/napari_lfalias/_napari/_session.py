"""The widget's computations for one light field, with their caches (no Qt here).

A session holds one :class:`~napari_lfalias.detect.AliasingDetector` per
light field, so the widget gets exactly what :func:`~napari_lfalias.detect_aliasing`
gives (the dark floor, the hypergeometric border factors) and reuses what
the detector keeps: the luminance and its pyramid (once per light field),
the moments and shifted stacks of the last slope (a new gamma, N or seed
does not shift the views again). The last detection is kept too, so a new
threshold only re-thresholds it (:meth:`Detection.rethreshold`).

The detector is made with ``skip_flat=False``. With the core's default,
tiles that provably cannot reach ``T`` are not computed and read 0: a Cv
*map* would show them as perfectly consistent, and lowering ``T`` below the
threshold they were skipped at would need a new detection. With every Cv
computed, the Cv layer is the true Cv everywhere (equal to
``detect_aliasing(..., skip_flat=False)``, and to the default wherever the
default evaluates), and moving ``T`` never recomputes anything. The cost
is nil on textured scenes (no tile is flat) and small elsewhere.

Each computation is a generator that yields ``(done, total)`` between its
steps (and, when the Cv has to wait for the detector, a
:class:`~._jobs.Partial` refocused image), so a worker running it reports
progress and stops at the next yield when it is cancelled. The detector
is not thread-safe: a job takes the session's lock around every call into
it, and waits for the lock by yielding, so a job queued behind a
reduction can still be stopped. Nothing is yielded while the lock is
held: a reduction takes it for each of its stages and gives it back
between them, so a job stopped (or never resumed) at a yield holds no
lock, and a focus change detects between two stages of a reduction.

The disparity-guided method (the library's default, ``"depth"``) needs the
light field's disparity: :meth:`AliasingSession.disparity` estimates it
once, stage by stage (:func:`~napari_lfalias.disparity.iter_estimate_disparity`),
without the lock (it reads only the views), and hands it to the detector
(:meth:`~napari_lfalias.detect.AliasingDetector.use_disparity`). The live
Cv stays on :attr:`DetectionParams.live_method`, the exact Cv, whatever the
method: one pass per focus change.
"""

from __future__ import annotations

import contextlib
import math
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from ._jobs import Partial

__all__ = ["DetectionParams", "AliasingSession", "Preview", "Reduced", "focus_range", "library_defaults",
           "CV_METHODS"]

#: The methods whose Cv the live mask can show; any other method (the default, ``"depth"``) keeps
#: the live mask on :data:`~napari_lfalias.presets.INTERACTIVE_METHOD` and uses the disparity only
#: when reducing.
CV_METHODS = ("analytic", "monte_carlo")

#: Largest focus slope, in pixels per view step, when the data carry no disparities.
DEFAULT_MAX_SLOPE = 2.0
#: Without disparities, the extreme views shift by at most this fraction of the image.
MAX_SHIFT_FRACTION = 0.25
#: How long a job waits for the detector before yielding again (seconds).
LOCK_POLL_S = 0.02
#: Samples (views x pixels) from which a focus change shows a coarse preview first:
#: 8 x 8 x 354 x 354 and larger (the full computation takes 60 ms or more there).
PREVIEW_MIN_SAMPLES = 8_000_000
#: Most samples (views x pixels) a preview works on: its pyramid level is the first at or below
#: it (level 2, a quarter of the resolution, for 9 x 9 x 512 x 512), so it takes ~15 ms.
PREVIEW_SAMPLES = 1_500_000
#: Time a preview should take (seconds): slower (a loaded machine), the next one is one level coarser.
PREVIEW_BUDGET_S = 0.025
#: Smallest side (pixels) of a preview level.
PREVIEW_MIN_SIDE = 32
#: Pause between the preview and the full-resolution work (seconds): a drag of the focus
#: slider moves on within it, and only the preview of each position is computed.
PREVIEW_PAUSE_S = 0.06


@dataclass(frozen=True)
class Preview:
    """A focus change's first result: a coarse pyramid level, enlarged to full size (nearest pixel).

    Attributes
    ----------
    image : ndarray, shape (Y, X, C)
        The refocused views of the level.
    cv, mask : ndarray, shape (Y, X), or None
        The exact Cv of the level and its mask (``None`` while the detector is busy).
    level : int
        The pyramid level (each of its pixels is a ``2**level`` square block).
    shown : threading.Event
        Set by the GUI once the preview is on screen.
    """

    image: np.ndarray
    cv: np.ndarray | None
    mask: np.ndarray | None
    level: int = 1
    shown: threading.Event = field(default_factory=threading.Event, compare=False)


def _enlarge(image, shape, level):
    """``image`` of pyramid ``level`` enlarged to ``shape`` (each pixel a ``2**level`` square block)."""
    factor = 2**level
    big = np.repeat(np.repeat(image, factor, axis=0), factor, axis=1)
    return np.ascontiguousarray(big[: shape[0], : shape[1]])


def _one_more_stage(stages):
    """``stages`` (yielding ``(done, total)``) with one more stage counted in each total; closing it
    closes ``stages``."""
    try:
        while True:
            try:
                done, total = next(stages)
            except StopIteration as end:
                return end.value
            yield done, total + 1
    finally:
        stages.close()


def _pause(seconds, step, until=None, longest_s=1.0):
    """Yield ``step`` for ``seconds`` (in 5 ms sleeps), so that a stop request takes effect meanwhile.

    With ``until`` (a ``threading.Event``), go on pausing until it is set
    too, for at most ``longest_s``.
    """
    began = time.perf_counter()
    while True:
        waited = time.perf_counter() - began
        if waited >= longest_s or (waited >= seconds and (until is None or until.is_set())):
            return
        time.sleep(0.005)
        yield step


#: Parameters of ``reduce_aliasing`` the widget has controls for (their defaults are the library's).
LIBRARY_PARAMETERS = ("gamma", "n_patterns", "threshold", "method", "max_level", "keep_in_focus", "nearer")
#: The widget's seed: the library's default (``None``) draws new patterns on every call, which a
#: spin box cannot show; seed 0 makes the widget repeat the API's ``seed=0`` result.
WIDGET_SEED = 0


def library_defaults():
    """The library's defaults of the parameters the widget controls (from ``reduce_aliasing``'s signature).

    Read, never copied, so a change of the library's defaults reaches the widget.

    Examples
    --------
    >>> sorted(library_defaults())
    ['gamma', 'keep_in_focus', 'max_level', 'method', 'n_patterns', 'nearer', 'threshold']
    """
    import inspect

    from ..reduce import reduce_aliasing, reduction_options

    signature = inspect.signature(reduce_aliasing).parameters
    defaults = {name: signature[name].default for name in LIBRARY_PARAMETERS}
    detection, max_level, _ = reduction_options()  # what the library puts for the parameters left at None
    resolved = {**detection, "max_level": max_level}
    return {name: resolved[name] if value is None else value for name, value in defaults.items()}


def _library_default(name):
    return field(default_factory=lambda: library_defaults()[name])


@dataclass(frozen=True)
class DetectionParams:
    """Parameters of the detection and reduction, as the widget's controls hold them.

    Defaults are the library's (:func:`library_defaults`); the seed is
    :data:`WIDGET_SEED`. ``method`` is the one "Reduce aliasing" uses; the
    live Cv and mask use :attr:`live_method`.

    Examples
    --------
    >>> params = DetectionParams(method="depth", threshold=0.02)
    >>> params.live_method, params.reduce_kwargs()
    ('analytic', {'threshold': 0.02, 'method': 'depth', 'nearer': 'auto'})
    """

    gamma: float = _library_default("gamma")
    n_patterns: int = _library_default("n_patterns")
    threshold: float = _library_default("threshold")
    method: str = _library_default("method")
    seed: int = WIDGET_SEED
    max_level: int = _library_default("max_level")
    keep_in_focus: bool = _library_default("keep_in_focus")
    nearer: str = _library_default("nearer")

    @property
    def live_method(self):
        """The method of the live Cv and mask: ``method`` if it is a Cv method, else
        :data:`~napari_lfalias.presets.INTERACTIVE_METHOD` (one pass per focus change)."""
        from ..presets import INTERACTIVE_METHOD

        return self.method if self.method in CV_METHODS else INTERACTIVE_METHOD

    def detect_kwargs(self):
        """Keyword arguments of the live detection (``detect_aliasing`` with :attr:`live_method`)."""
        return {
            "gamma": self.gamma,
            "n_patterns": self.n_patterns,
            "threshold": self.threshold,
            "method": self.live_method,
            "seed": self.seed,
        }

    def reduce_kwargs(self):
        """Keyword arguments of ``reduce_aliasing``: those its ``method`` uses (the disparity comes apart).

        The Monte-Carlo method reduces as the paper did (``preset="paper"``:
        Algorithm 2 with the plain Poisson fusion); the values of the
        controls win over the preset's, so at their defaults it is
        ``reduce_aliasing(lf, slope, preset="paper", seed=seed)``.
        """
        if self.method in CV_METHODS:
            paper = {"preset": "paper"} if self.method == "monte_carlo" else {}
            return {**self.detect_kwargs(), "max_level": self.max_level, "keep_in_focus": self.keep_in_focus,
                    **paper}
        return {"threshold": self.threshold, "method": self.method, "nearer": self.nearer}

    def detection_key(self, slope):
        """What a live Cv depends on (everything but the threshold and the pyramid depth)."""
        monte_carlo = self.live_method == "monte_carlo"
        return (
            float(slope),
            self.gamma,
            self.n_patterns if monte_carlo else None,
            self.live_method,
            self.seed if monte_carlo else None,
        )


def _finite_range(values):
    values = np.asarray(values, dtype=np.float64)
    values = values[np.isfinite(values)]
    if values.size == 0:
        return None
    return float(values.min()), float(values.max())


def _geometric_range(lf):
    """+/- the slope at which the outermost view shifts by a quarter of the image (at most 2 px)."""
    reach = float(np.abs(lf.positions).max(initial=0.0))
    limit = DEFAULT_MAX_SLOPE
    if reach > 0:
        limit = min(limit, MAX_SHIFT_FRACTION * min(lf.image_shape) / reach)
    limit = max(round(limit, 2), 0.01)
    return (-limit, limit)


def focus_range(lf):
    """The slope range a focus control should span for ``lf``.

    Uses ``lf.meta["disparity_range"]`` when the decoder set it, else the
    range of a ground-truth disparity map in the metadata (``"disparity"``,
    ``"gt_disparity"``), padded by 10 %. Without either: +/- the slope at
    which the outermost view moves by a quarter of the image, at most 2 px
    per view step (+/- 1 px for the 15 x 15 views of 28 x 28 px of the GUV
    capture).

    Returns
    -------
    (low, high) : tuple of float
    """
    meta = lf.meta
    span = None
    if meta.get("disparity_range") is not None:
        span = _finite_range(meta["disparity_range"])
    else:
        for key in ("disparity", "gt_disparity", "disparity_gt"):
            if meta.get(key) is not None:
                span = _finite_range(meta[key])
                break
        if span is not None:
            pad = 0.1 * max(span[1] - span[0], 0.5)
            span = (span[0] - pad, span[1] + pad)
    if span is None or not span[1] > span[0]:
        return _geometric_range(lf)
    return span


@dataclass(frozen=True)
class Reduced:
    """The result of :meth:`AliasingSession.reduce`.

    Attributes
    ----------
    reduction : Reduction
        What ``reduce_aliasing`` returns.
    antialiased : ndarray (Y, X, C) or None
        With the disparity-guided method: the dense-aperture rendering at
        the same slope (``antialiased_refocus(lf, slope, disparity)``),
        which the reduction made anyway; ``None`` with a Cv method.
    larger_first : bool or None
        With the disparity-guided method and the occlusion order judged from
        the views (``nearer="auto"``, none declared): whether the reduction
        put the larger disparities in front; ``None`` otherwise.
    """

    reduction: object
    antialiased: np.ndarray | None = None
    larger_first: bool | None = None


class AliasingSession:
    """Refocus, detection and reduction of one light field, with caches.

    Parameters
    ----------
    lf : LightField
        The light field (a lazy one is read into memory once, by the first
        job, in its worker thread).
    """

    def __init__(self, lf):
        self._source = lf
        self._detector = None
        self._lock = threading.Lock()
        self._last = None  # (detection key, Detection)
        self._estimate = None  # the light field's DisparityEstimate, once computed
        self._pyramid = None  # the light field's pyramid down to the coarsest preview level
        self._coarser = 0  # 1 while previews on the base level take longer than their budget
        self._previews = 0  # previews made at the current level
        self._streak = 0  # previews in a row that ask for the other level

    @property
    def source_lf(self):
        """The light field as given (lazy ones stay lazy): for its metadata and shape."""
        return self._source

    @property
    def detector(self):
        """The session's AliasingDetector, or ``None`` before the first job made it."""
        return self._detector

    @property
    def estimate(self):
        """The light field's :class:`~napari_lfalias.disparity.DisparityEstimate`, or ``None`` before
        :meth:`disparity` has made it."""
        return self._estimate

    def close(self):
        """Drop the detector, the disparity and the kept detection (a running job keeps its own reference)."""
        self._detector = None
        self._last = None
        self._estimate = None
        self._pyramid = None

    # -- the kept detection ----------------------------------------------------
    def detection(self, slope, params):
        """The kept detection for ``slope`` and ``params``, at ``params.threshold``.

        Returns ``None`` when no detection with the same Cv is kept (or,
        with a detector that skips flat tiles, when the threshold was
        lowered below the one they were skipped at: detect again then). A
        new threshold re-thresholds the kept Cv without recomputing it.
        """
        from ..errors import ParameterError

        kept = self._last
        key = params.detection_key(slope)
        if kept is None or kept[0] != key:
            return None
        detection = kept[1]
        if detection.threshold != params.threshold:
            try:
                detection = detection.rethreshold(params.threshold)
            except ParameterError:
                return None
            self._last = (key, detection)
        return detection

    # -- the detector and its lock ---------------------------------------------
    def _wait(self, step):
        """Take the lock, yielding ``step`` while another job holds it."""
        while not self._lock.acquire(timeout=LOCK_POLL_S):
            yield step

    def _locked(self, step, work):
        """Run ``work()`` holding the lock (taken by yielding ``step``); return its result."""
        yield from self._wait(step)
        try:
            return work()
        finally:
            self._lock.release()

    def _make_detector(self):
        from ..detect import AliasingDetector

        if self._detector is None:
            self._detector = AliasingDetector(self._source, skip_flat=False)
        return self._detector

    def _ready(self, step):
        """The detector, made on first use (reading a lazy light field)."""
        detector = self._detector
        if detector is None:
            detector = yield from self._locked(step, self._make_detector)
        return detector

    def _detect(self, detector, slope, params):
        """Detection at ``slope`` (the lock is held): the kept one, or a new one."""
        detection = self.detection(slope, params)
        if detection is None:
            detection = detector.detect(slope, **params.detect_kwargs())
            self._last = (params.detection_key(slope), detection)
        return detection

    # -- computations (generators yielding (done, total)) ----------------------
    def _job(self, work):
        """The generator of one job: make the detector, then return ``work(detector)`` run under the lock."""
        detector = yield from self._ready((0, 2))
        yield (1, 2)
        return (yield from self._locked((1, 2), lambda: work(detector)))

    def focus(self, slope, params, detect=True):
        """Refocus on ``slope`` and, if asked, detect aliasing there.

        Returns a job that yields ``(done, total)`` steps and returns
        ``(image, detection)``: the refocused image ``(Y, X, C)`` and the
        Detection (``None`` without ``detect``).

        Early results come as :class:`~._jobs.Partial` values:

        - a :class:`Preview` first, for a light field large enough
          (:meth:`previews`): the refocus and Cv of a coarse pyramid level
          (:meth:`preview_level`), shown at full size;
          the job then pauses :data:`PREVIEW_PAUSE_S`, and until the GUI has
          shown it (``Preview.shown``), so that a newer focus change stops it
          before the full-resolution work, whose kernels would keep the GUI
          thread from drawing;
        - the refocused image alone, when the detector is busy (a reduction
          runs): the refocus needs no lock, the Cv waits for the detector.

        Otherwise image and detection come together, so the viewer updates
        (and redraws) once per focus change.
        """
        from .. import refocus

        slope = float(slope)
        detector = yield from self._ready((0, 2))
        if self.previews():
            preview = self._preview(detector, slope, params if detect else None)
            yield Partial(preview)
            # the full-resolution kernels hold the GIL: start them once the preview is on screen
            yield from _pause(PREVIEW_PAUSE_S, (1, 2), until=preview.shown)
        image = refocus(detector.lf, slope)
        if not detect:
            return image, None
        if not self._lock.acquire(blocking=False):
            yield Partial(image)
            yield from self._wait((1, 2))
        try:
            detection = self._detect(detector, slope, params)
        finally:
            self._lock.release()
        return image, detection

    def _samples(self):
        lf = self._source
        return lf.n_views * lf.image_shape[0] * lf.image_shape[1]

    def previews(self):
        """True if a focus change shows a coarse preview first (light fields of at least
        :data:`PREVIEW_MIN_SAMPLES` samples per channel)."""
        return self._samples() >= PREVIEW_MIN_SAMPLES

    def preview_level(self):
        """The pyramid level previews are computed on.

        The first level with at most :data:`PREVIEW_SAMPLES` samples; one
        coarser once two previews in a row there took longer than
        :data:`PREVIEW_BUDGET_S` (a loaded machine), back once two took less
        than a fifth of it.
        """
        return self._base_level() + self._coarser

    def _base_level(self):
        return max(1, math.ceil(math.log(self._samples() / PREVIEW_SAMPLES, 4)))

    def _preview(self, detector, slope, params):
        """The :class:`Preview` at ``slope``: a coarse refocus (and Cv, when the detector is free)."""
        from .. import refocus
        from ..pyramid import lightfield_pyramid

        level = self.preview_level()
        if self._pyramid is None:
            self._pyramid = lightfield_pyramid(detector.lf, self._base_level() + 1)
        began = time.perf_counter()  # (made once: the pyramid is not what a preview costs)
        shape = detector.lf.image_shape
        image = _enlarge(refocus(self._pyramid[level], slope / 2**level), shape, level)
        if params is None or not self._lock.acquire(blocking=False):
            return Preview(image, None, None, level)
        try:
            coarse = detector.detect(slope, level=level, **params.detect_kwargs())
        finally:
            self._lock.release()
        self._adapt(time.perf_counter() - began, min(shape) >> (self._base_level() + 1))
        return Preview(image, _enlarge(coarse.cv, shape, level), _enlarge(coarse.mask, shape, level), level)

    def _adapt(self, seconds, coarser_side):
        """Go one level coarser after two previews over their budget in a row; back after two quick ones.

        The first preview of a level is not counted: it makes that level's caches.
        """
        self._previews += 1
        if self._previews == 1:
            return
        if self._coarser == 0:
            slow = seconds > PREVIEW_BUDGET_S and coarser_side >= PREVIEW_MIN_SIDE
        else:
            slow = seconds < PREVIEW_BUDGET_S / 5  # "slow" to change back: quick at the coarser level
        self._streak = self._streak + 1 if slow else 0
        if self._streak >= 2:
            self._coarser, self._streak, self._previews = 1 - self._coarser, 0, 0

    def detect(self, slope, params):
        """Detect aliasing at ``slope`` (reusing the detector's shifted views).

        Returns a job that yields ``(done, total)`` and returns the Detection.
        """
        slope = float(slope)
        return self._job(lambda detector: self._detect(detector, slope, params))

    def disparity(self):
        """Estimate the light field's disparity, once, and hand it to the detector.

        Returns a job that yields ``(done, total, stage)`` after each stage
        of :func:`~napari_lfalias.disparity.iter_estimate_disparity` (so
        stopping it stops the estimate between two stages) and returns the
        :class:`~napari_lfalias.disparity.DisparityEstimate`, equal to
        ``estimate_disparity(lf)``. The estimate is kept: later calls
        return it at once. The detector is free meanwhile (the estimate
        needs only the views), so focus changes go on detecting.
        """
        detector = yield from self._ready((0, 5, "reading the light field"))
        return (yield from self._disparity_of(detector))

    def _disparity_of(self, detector):
        if self._estimate is None:
            from ..disparity import iter_estimate_disparity

            estimate = yield from iter_estimate_disparity(detector.lf)  # closed with this job
            yield from self._locked((5, 5, "handing it to the detector"),
                                    lambda: detector.use_disparity(estimate))
            self._estimate = estimate
        return self._estimate

    def reduce(self, slope, params):
        """Reduce aliasing at ``slope`` with the session's detector and ``params.method``.

        Returns a job that yields ``(done, total)`` after each stage of the
        reduction (:func:`~napari_lfalias.reduce.iter_reduce_aliasing`) and
        returns a :class:`Reduced`; stopping the job stops the reduction at
        the next stage. With the disparity-guided method the session's
        disparity is used (estimated first, with its stages, if
        :meth:`disparity` has not made it yet), so the reduction is
        ``reduce_aliasing(lf, slope, disparity=estimate_disparity(lf))``; it
        comes first as a :class:`~._jobs.Partial` ``Reduced``, then one
        more stage renders ``antialiased_refocus(lf, slope, estimate)`` (the
        public function, whatever the reduction's own rendering does).
        """
        from ..reduce import iter_reduce_aliasing
        from ..render import antialiased_refocus

        slope = float(slope)
        detector = yield from self._ready((0, 2))
        guided = params.method not in CV_METHODS
        if guided:
            estimate = yield from self._disparity_of(detector)
            yield from self._locked((0, 2), lambda: detector.use_nearer(params.nearer))
        # the core's own steps: progress per stage, and a quit() takes effect between two of them
        stages = iter_reduce_aliasing(detector.source, slope, detector=detector, **params.reduce_kwargs())
        if not guided:
            return Reduced((yield from self._stepwise(stages, (0, 2))))
        reduction = yield from self._stepwise(_one_more_stage(stages), (0, 2))
        judged = yield from self._locked((1, 2), lambda: None if detector.nearer != "auto"
                                         else detector.guide.larger_first(slope))  # made by the reduction
        yield Partial(Reduced(reduction, larger_first=judged))
        # needs only the views: the detector stays free for focus changes
        return Reduced(reduction, antialiased_refocus(detector.lf, slope, estimate, nearer=params.nearer), judged)

    def _stepwise(self, stages, waiting):
        """Run the generator ``stages`` one step at a time under the lock, free between steps.

        The lock is taken (by yielding ``waiting``) for each step and given
        back before its progress is yielded, so a focus change can detect
        between two stages of a reduction, and a job stopped at a yield
        holds nothing. Closing this generator closes ``stages``.
        """
        with contextlib.closing(stages):
            while True:
                yield from self._wait(waiting)
                try:
                    step = next(stages)
                except StopIteration as done:
                    return done.value
                finally:
                    self._lock.release()
                yield step
                waiting = step if isinstance(step, tuple) else waiting
