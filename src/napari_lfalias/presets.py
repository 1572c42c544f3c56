"""Default parameters of detection and reduction, and the paper's algorithm exactly as published.

Two sets of defaults:

``preset=None`` (the project's defaults, chosen by measurement)
    ``method="depth"``: the disparity-guided detection and dense-aperture
    rendering of :mod:`napari_lfalias.depth_guided`, ``T = 0.02`` (relative
    luminance error against what a dense aperture records). For the Cv
    methods, their measured best ``T`` (:data:`METHOD_THRESHOLDS`).
``preset="paper"`` (Xiao et al. 2014 as published)
    Monte-Carlo Cv (Algorithm 1, Eq. 7) with ``gamma = 0.2``, ``N = 100``,
    ``T = 0.02``; Algorithm 2 with ``max_level = 3``, Eq. 8 as written
    (pixels still aliased on the coarsest level take it) and the plain
    Poisson fusion of Perez et al. (no screening).

A parameter given explicitly always wins over the preset.
``benchmarks/results/accuracy.md`` measures both.
"""

from __future__ import annotations

from . import _validate

__all__ = ["PRESETS", "METHOD_THRESHOLDS", "INTERACTIVE_METHOD", "resolve", "detection_options"]

#: The parameters each preset sets (the rest keep their function defaults).
PRESETS = {
    None: {"method": "depth"},
    "paper": {"method": "monte_carlo", "threshold": 0.02, "gamma": 0.2, "n_patterns": 100, "max_level": 3,
              "screen": 0.0},
}

#: Default threshold of each detection method when no preset sets one (measured, see the module notes).
METHOD_THRESHOLDS = {"depth": 0.02, "analytic": 0.02, "monte_carlo": 0.02}
#: The method of per-slope work that must be quick (sweeps over many slopes, a live focus slider):
#: the exact Cv, one pass over the views per slope (the default method renders a dense aperture).
INTERACTIVE_METHOD = "analytic"
#: Detection methods (see :mod:`napari_lfalias.detect`).
METHODS = ("depth", "analytic", "monte_carlo")
#: Scales a threshold may be stated on (see :mod:`napari_lfalias.detect`).
THRESHOLD_SCALES = ("cv", "angular")
#: Defaults of the Cv methods' own parameters when no preset sets them.
GAMMA = 0.2
N_PATTERNS = 100


def resolve(preset, **given):
    """Fill the parameters left at ``None`` in ``given`` from ``preset`` and the method's defaults.

    Parameters
    ----------
    preset : {None, "paper"}
    **given
        Parameters as the caller passed them (``None``: not given).

    Returns
    -------
    dict
        ``given`` with every ``None`` the preset or the method default
        sets replaced; ``threshold`` always set when ``method`` is.

    Examples
    --------
    >>> resolve("paper", method=None, threshold=None)
    {'method': 'monte_carlo', 'threshold': 0.02}
    >>> resolve(None, method="analytic", threshold=None)["method"]
    'analytic'
    """
    _validate.one_of("preset", preset, tuple(PRESETS))
    out = dict(given)
    for name, value in PRESETS[preset].items():
        if name in out and out[name] is None:
            out[name] = value
    if "threshold" in out and out["threshold"] is None and out.get("method") in METHOD_THRESHOLDS:
        out["threshold"] = METHOD_THRESHOLDS[out["method"]]
    return out


def detection_options(preset=None, *, method=None, threshold=None, gamma=None, n_patterns=None, seed=None,
                      threshold_scale="cv"):
    """Every detection parameter resolved (preset, method defaults) and checked, whatever the method.

    Returns
    -------
    dict
        ``method``, ``threshold``, ``gamma``, ``n_patterns``, ``seed``,
        ``threshold_scale``.

    Raises
    ------
    ParameterError
        Naming the parameter out of range.

    Examples
    --------
    >>> detection_options()["method"], detection_options(preset="paper")["method"]
    ('depth', 'monte_carlo')
    """
    chosen = resolve(preset, method=method, threshold=threshold, gamma=gamma, n_patterns=n_patterns)
    method = _validate.one_of("method", chosen["method"], METHODS)
    threshold = _validate.positive_float("threshold", chosen["threshold"])
    gamma = _validate.in_open_interval("gamma", GAMMA if chosen["gamma"] is None else chosen["gamma"], 0.0, 1.0)
    n_patterns = _validate.integer_at_least("n_patterns", N_PATTERNS if chosen["n_patterns"] is None
                                            else chosen["n_patterns"], 2)
    if seed is not None:
        seed = _validate.integer_at_least("seed", seed, 0)
    _validate.one_of("threshold_scale", threshold_scale, THRESHOLD_SCALES)
    return {"method": method, "threshold": threshold, "gamma": gamma, "n_patterns": n_patterns, "seed": seed,
            "threshold_scale": threshold_scale}
