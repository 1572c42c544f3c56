"""What the aliasing widget says: its method names, tooltips and explanatory lines (no Qt here)."""

from __future__ import annotations

import numpy as np

from ._layers import LEVEL_COLOURS

__all__ = ["METHODS", "ORDERS", "TOOLTIPS", "order_text", "level_legend", "threshold_meaning", "mask_description",
           "disparity_summary", "stage_text"]

#: The method combo's entries: what the user reads -> the library's ``method`` (the first is the
#: library's default).
METHODS = {
    "dense aperture (disparity)": "depth",
    "exact Cv (analytic)": "analytic",
    "Monte Carlo Cv (the paper)": "monte_carlo",
}

#: The occlusion-order combo's fixed entries: what the user reads -> the library's ``nearer`` (the
#: entry of ``"auto"`` says what it resolves to: :func:`order_text`).
ORDERS = {
    "larger disparity in front": "larger",
    "smaller disparity in front": "smaller",
}


def order_text(declared, judged=None, slope=None):
    """The occlusion-order combo's ``"auto"`` entry for a light field whose ``meta["nearer"]`` is ``declared``;
    without a declared order, what a reduction at ``slope`` ``judged`` where it has. Short enough to show
    whole in the combo at the dock's width (the row's tooltip says the rest).

    Examples
    --------
    >>> order_text("smaller"), order_text(None)
    ('declared: smaller in front', 'judged from the views')
    >>> order_text(None, judged="larger", slope=4.0)
    'judged: larger in front (at 4.00)'
    """
    if declared is not None:
        return f"declared: {declared} in front"
    if judged is None:
        return "judged from the views"
    return f"judged: {judged} in front (at {slope:.2f})"


#: What each control means (measured numbers from benchmarks/results/detection.md and accuracy.md).
TOOLTIPS = {
    "layer": "The light-field layer to work on (any layer opened by this plugin's readers or samples).",
    "focus": "Disparity brought into focus, in pixels per view step: a scene point that moves this "
             "much between neighbouring views is sharp in the refocused image. The range comes from "
             "the data's disparities, else from its geometry.",
    "gamma": "Relaxation \u03b3 of Algorithm 1 (not the display gamma of a layer): each random "
             "sampling pattern keeps between (1 - \u03b3) n and n of the n views. A larger \u03b3 "
             "raises every Cv: Cv = \u221ac \u00d7 (spread of the views / their mean), "
             "\u221ac = 0.041 for 8 x 8 views at \u03b3 = 0.2, 0.079 at \u03b3 = 0.5.",
    "n": "Patterns N of the Monte-Carlo estimate (the paper's method only; the exact method is its "
         "N \u2192 \u221e limit). Measured on 8 x 8 views: the Monte-Carlo Cv deviates 26 % from the "
         "exact Cv at N = 10, 7 % at N = 100.",
    "threshold": "The live mask flags a pixel where its Cv exceeds T. The line below says what T means "
                 "for this light field. Measured against ground truth (the naive refocus 2 % off the "
                 "dense-aperture image): a Cv threshold between 0.001 and 0.004 finds visible aliasing "
                 "best (F1 0.49-0.96); the paper's T = 0.02 finds little of it on 8 x 8 views "
                 "(F1 0.01-0.02). With the dense-aperture method, Reduce aliasing replaces the pixels "
                 "whose refocus is predicted to differ by more than T (relative luminance) from what a "
                 "dense aperture records: 0.02 is the paper's smallest perceivable difference. "
                 "Type a value or drag (logarithmic).",
    "method": "How Reduce aliasing finds and removes aliasing. dense aperture (disparity), the "
              "library's default and the best measured: the light field's disparity (estimated once "
              "per light field, in the background) predicts what a dense aperture would record; the "
              "pixels where the refocus differs from it take that rendering, every other pixel stays "
              "the refocus exactly. The live mask meanwhile shows the exact Cv (one pass per focus "
              "change). exact Cv (analytic): the Cv the paper's estimate tends to for N \u2192 \u221e, "
              "in one pass, no sampling noise; Reduce aliasing runs the paper's Algorithm 2. "
              "Monte Carlo Cv (the paper): N random patterns, seeded, and Algorithm 2 with the paper's "
              "plain Poisson fusion: at the default controls, the paper as published (preset='paper').",
    "mask": "Which detection the magenta mask over the refocused image shows now: the live Cv "
            "(exact, or Monte Carlo when that method is chosen) as the focus moves, or after Reduce "
            "aliasing with the dense-aperture method the pixels it found aliased (their predicted error "
            "against a dense aperture exceeds T; it replaced those its rendering is sure of, and their "
            "fringe: the level layer shows which), until the focus moves.",
    "disparity": "The light field's disparity (pixels per view step), estimated once per light field "
                 "in the background for the dense-aperture method, in five stages; Cancel stops it "
                 "between two of them (Reduce aliasing starts it again). Shown in the hidden layer "
                 "'disparity [...]' (colormap and colorbar).",
    "nearer": "Dense-aperture method only: which surface is in front where one hides another, by its "
              "disparity. A light field whose source knows its camera declares it (an HCI folder or "
              "a lenslet capture: smaller in front; lf.meta['nearer'] in Python); otherwise it is "
              "judged from the views at the depth edges, which they cannot always tell (wrong on 8 of "
              "320 random scenes, benchmarks/results/accuracy.md). Where you know your camera's order, "
              "choose it: a wrong order blurs the in-focus surface along a defocused occluder's outline.",
    "level": "Coarsest pyramid level of the reduction (Algorithm 2; Cv methods only): an aliased pixel "
             "is replaced by the first level, up to this one, where it is no longer aliased; level l "
             "blurs over about 2^l pixels.",
    "seed": "Seed of the Monte-Carlo patterns: the same seed gives the API's detect_aliasing(..., "
            "seed=...) result exactly.",
    "keep": "Cv methods only: reduce only the occluder where a defocused object partly hides an "
            "in-focus surface, and keep that surface sharp (beyond the paper; measured: +5.5 dB there "
            "at T = 0.005, up to 1.5 dB lost over the image at T = 0.02). The dense-aperture method "
            "does this by itself.",
    "live": "Recompute as the controls move; off: only Detect does.",
    "detect": "Refocus and detect aliasing with the current settings.",
    "reduce": "Reduce the aliasing with the chosen method: the reduced image appears beside the "
              "refocused one (with the dense-aperture method, the anti-aliased rendering too, in a "
              "hidden layer).",
    "cancel": "Stop the running computation; its result is dropped.",
    "depth": "Where the calibration allows it: the distance (camera arrays with HCI parameters) or the "
             "axial position (light-field microscopes) of the plane in focus.",
    "beside": "Show the reduced image (and its level map) beside the refocused image; "
              "off: over it, to compare by toggling.",
}


def level_legend(highest):
    """The level map's legend: a swatch of each level's colour up to ``highest``.

    Examples
    --------
    >>> "level l blurs over ~2^l px" in level_legend(2)
    True
    """
    swatches = " ".join(
        f'<span style="color:{LEVEL_COLOURS[level]}">\u25a0</span> {level}' for level in range(1, highest + 1)
    )
    return f"level map (a layer beside the refocused image): {swatches} (level l blurs over ~2^l px)"


def threshold_meaning(n_views, gamma, threshold, guided):
    """What T means for a light field of ``n_views`` views: the spread of the views the Cv flags
    (Cv = sqrt(c) x spread), and with the dense-aperture method (``guided``) what the reduction replaces.

    Examples
    --------
    >>> threshold_meaning(64, 0.2, 0.01, guided=False)
    'aliased where the views spread by more than 24% of their mean (64 views, γ = 0.2: Cv = 0.041 × spread)'
    >>> threshold_meaning(64, 0.2, 0.02, guided=True)
    'live mask: views spread > 48% of their mean (64 views, γ = 0.2); Reduce aliasing: predicted error > 2.0%'
    """
    from ..detect import variance_factors

    root_c = float(np.sqrt(variance_factors(n_views, gamma)[n_views]))
    spread = threshold / root_c if root_c > 0 else float("inf")
    if not guided:
        return (f"aliased where the views spread by more than {spread:.0%} of their mean ({n_views} views, "
                f"\u03b3 = {gamma:g}: Cv = {root_c:.3f} \u00d7 spread)")
    return (f"live mask: views spread > {spread:.0%} of their mean ({n_views} views, \u03b3 = {gamma:g}); "
            f"Reduce aliasing: predicted error > {threshold:.1%}")


def mask_description(method, slope=None, n_patterns=None):
    """Which detection the mask shows: a live Cv ``method``, or ``"depth"`` (a reduction's, at ``slope``).

    Examples
    --------
    >>> mask_description("analytic")
    'exact Cv > T (live)'
    >>> mask_description("depth", 4.0)
    'pixels Reduce aliasing flagged at focus 4.00 (predicted error > T)'
    """
    if method == "analytic":
        return "exact Cv > T (live)"
    if method == "monte_carlo":
        return f"Monte-Carlo Cv > T ({n_patterns} patterns)"
    return f"pixels Reduce aliasing flagged at focus {slope:.2f} (predicted error > T)"


def disparity_summary(estimate):
    """One line on a finished disparity estimate.

    Examples
    --------
    >>> from types import SimpleNamespace
    >>> d = np.linspace(-4, 4, 100, dtype=np.float32).reshape(10, 10)
    >>> est = SimpleNamespace(disparity=d, confidence=np.full_like(d, 0.8), params={"seconds": {"sweep": 0.5}})
    >>> disparity_summary(est)
    'ready (0.5 s): -3.9 .. 3.9 px per view, median confidence 0.8'
    """
    low, high = np.percentile(estimate.disparity, [1, 99])
    confidence = float(np.median(estimate.confidence))
    seconds = sum(estimate.params.get("seconds", {}).values())
    return f"ready ({seconds:.2g} s): {low:.2g} .. {high:.2g} px per view, median confidence {confidence:.2g}"


def stage_text(done, total, stage):
    """The disparity line while the estimate runs (``stage``: what the last step did).

    Examples
    --------
    >>> stage_text(3, 5, "sweep")
    'estimating: 3/5 stages done (sweep)'
    """
    return f"estimating: {done}/{total} stages done ({stage})"
