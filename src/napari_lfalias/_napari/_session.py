"""The widget's computations for one light field, with their caches (no Qt here).

What is cached follows DESIGN section 4: the views shifted for the current
slope are kept, so changing gamma, N, the method or the seed re-detects
from the same stack; the last detection is kept, so changing T only
re-thresholds its Cv. Each computation is a generator that yields
``(done, total)`` between its steps, so a worker running it can report
progress and stop early when it is cancelled.
"""

from __future__ import annotations

from dataclasses import dataclass

from ._preview import LivePreview

__all__ = ["DetectionParams", "AliasingSession", "focus_range"]

#: Focus range used when the data carry no disparities, in pixels per view step.
DEFAULT_FOCUS_RANGE = (-2.0, 2.0)


@dataclass(frozen=True)
class DetectionParams:
    """Parameters of Algorithm 1 (and 2), as the widget's controls hold them."""

    gamma: float = 0.2
    n_patterns: int = 100
    threshold: float = 0.02
    method: str = "analytic"
    seed: int = 0
    max_level: int = 3

    def detection_key(self, slope):
        """What a Cv depends on (everything but the threshold and the level)."""
        seed = self.seed if self.method == "monte_carlo" else None
        n_patterns = self.n_patterns if self.method == "monte_carlo" else None
        return (float(slope), self.gamma, n_patterns, self.method, seed)


def _finite_range(values):
    import numpy as np

    values = np.asarray(values, dtype=np.float64)
    values = values[np.isfinite(values)]
    if values.size == 0:
        return None
    return float(values.min()), float(values.max())


def focus_range(lf):
    """The slope range a focus control should span for ``lf``.

    Uses ``lf.meta["disparity_range"]`` when the decoder set it, else the
    range of a ground-truth disparity map in the metadata (``"disparity"``,
    ``"gt_disparity"``), padded by 10 %; else +/-2 px.

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
        return DEFAULT_FOCUS_RANGE
    return span


class AliasingSession:
    """Refocus, detection and reduction of one light field, with caches.

    Parameters
    ----------
    lf : LightField
        The light field (a lazy one is read into memory once, by the first job).
    """

    def __init__(self, lf):
        self._lf = lf
        self._preview = None  # LivePreview, built in the first focus job
        self._stack = None  # ShiftedStack for one slope
        self._detection = None  # (key, Detection)

    @property
    def lf(self):
        """The light field, in memory (a lazy one is read on first use, in a worker)."""
        if self._lf.is_lazy:
            self._lf = self._lf.compute()
        return self._lf

    def close(self):
        """Free the caches (the live path's padded views among them)."""
        self._preview = self._stack = self._detection = None

    # -- caches -------------------------------------------------------------
    def cached_stack(self, slope):
        """The shifted stack for ``slope`` if it is cached, else ``None``."""
        stack = self._stack
        if stack is not None and stack.slope == float(slope):
            return stack
        return None

    def stack(self, slope):
        """The views shifted for ``slope`` (computed once per slope)."""
        from .. import shift_views

        stack = self.cached_stack(slope)
        if stack is None:
            stack = shift_views(self.lf, float(slope))
            self._stack = stack
        return stack

    def cached_detection(self, slope, params):
        """The detection for ``slope`` and ``params``, re-thresholded to ``params.threshold``.

        Returns ``None`` when no detection with the same Cv is cached.
        """
        cached = self._detection
        if cached is None or cached[0] != params.detection_key(slope):
            return None
        detection = cached[1]
        if detection.threshold != params.threshold:
            detection = detection.rethreshold(params.threshold)
            self._detection = (cached[0], detection)
        return detection

    # -- computations (generators yielding (done, total)) --------------------
    def _live_preview(self):
        """The fast refocus of this light field, built on first use (``None`` if unsupported)."""
        if self._preview is None and LivePreview.supports(self.lf):
            self._preview = LivePreview(self.lf)
        return self._preview

    def focus(self, slope, params, with_detection=True):
        """Refocus on ``slope`` and, if asked, detect aliasing there.

        The exact method runs on the fast live path (:mod:`._preview`);
        Monte Carlo and weighted light fields go through the core's shifted
        stack. Yields ``(done, total)``; returns ``(image, detection or None)``.
        """
        exact = with_detection and params.method == "analytic"
        if not with_detection or exact:
            if self._preview is None:
                yield (0, 2)
            preview = self._live_preview()
            if preview is not None:
                yield (1, 2)
                image, moments = preview.compute(float(slope))
                if not exact:
                    return image, None
                detection = self.cached_detection(slope, params)
                if detection is None:
                    detection = exact_detection(moments, params)
                    self._detection = (params.detection_key(slope), detection)
                return image, detection
        return (yield from self._focus_from_stack(slope, params, with_detection))

    def _focus_from_stack(self, slope, params, with_detection):
        from .. import detect_aliasing

        total = 3 if with_detection else 2
        stack = self.stack(slope)
        yield (1, total)
        image = stack.mean()
        if not with_detection:
            return image, None
        yield (2, total)
        detection = self.cached_detection(slope, params)
        if detection is None:
            detection = detect_aliasing(
                self.lf,
                float(slope),
                gamma=params.gamma,
                n_patterns=params.n_patterns,
                threshold=params.threshold,
                method=params.method,
                seed=params.seed,
                stack=stack,
            )
            self._detection = (params.detection_key(slope), detection)
        return image, detection

    def detect(self, slope, params):
        """Detect aliasing at ``slope`` (reusing the shifted stack).

        Yields ``(done, total)``; returns the Detection.
        """
        image, detection = yield from self.focus(slope, params, with_detection=True)
        return detection

    def reduce(self, slope, params):
        """Reduce aliasing at ``slope`` (Algorithm 2).

        Yields ``(done, total)``; returns the Reduction.
        """
        from .. import reduce_aliasing

        yield (0, 1)
        reduction = reduce_aliasing(
            self.lf,
            float(slope),
            gamma=params.gamma,
            n_patterns=params.n_patterns,
            threshold=params.threshold,
            max_level=params.max_level,
            method=params.method,
            seed=params.seed,
        )
        yield (1, 1)
        return reduction
