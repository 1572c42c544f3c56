"""How a vignette's weight should vary across a view's cell of the aperture, on a one-dimensional model.

The dense-aperture renderer (``render.py``) stands each view for the cell
of the aperture around it. Under a calibrated vignette the rays of that
cell are weighed by the fall-off where they pass, and the renderer knows
the fall-off only at the views themselves (their sample weights). This
compares ways of filling in the weight between the views, on one axis of
the aperture at the image's centre, with the fall-off of the synthetic
camera (``synthetic.camera.vignetting_falloff``, strength 0.87) and a
cosine texture at several residual disparities and periods:

- ``constant``: each cell at its view's weight (the renderer before stop 41);
- ``linear``: the view's weight plus its slope from the neighbours'
  (central differences, one-sided at the grid's ends), the renderer's choice;
- ``quadratic``: a parabola through the view and its two neighbours (the
  three outermost at the ends);
- ``spline``: a natural cubic spline through all the views' weights;
- ``comb``: the views alone, as the naive refocus weighs them.

Each is judged by the largest error of the cell-integrated image value
over the texture's phase against the exactly weighted aperture integral.

Run::

    .venv/bin/python benchmarks/vignette_cell_weights.py --out benchmarks/results/vignette_cell_weights.md
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy.interpolate import CubicSpline

STRENGTH = 0.87
CASES = [(-4.5, 8.0), (5.8, 8.0), (1.4, 8.0), (3.0, 5.0)]  # (residual disparity px per view step, period px)
METHODS = ("constant", "linear", "quadratic", "spline", "comb")


def falloff(q, n_views):
    """The synthetic camera's fall-off on one axis of the aperture at the image's centre (``rho_p = 0``)."""
    radius = np.hypot(*(2 * [(n_views - 1) / 2]))  # the corner views' distance: the unit of rho_q
    return (1.0 + STRENGTH * (q / radius) ** 2) ** -2


def cell_weights(method, i, views, weights, q):
    """The weight ``method`` gives the points ``q`` of view ``i``'s cell."""
    n = len(views)
    if method == "constant":
        return np.full_like(q, weights[i])
    if method == "linear":
        lo, hi = max(i - 1, 0), min(i + 1, n - 1)
        return weights[i] + (weights[hi] - weights[lo]) / (views[hi] - views[lo]) * (q - views[i])
    if method == "quadratic":
        at = np.clip(np.arange(i - 1, i + 2), 0, n - 1) if 0 < i < n - 1 else (
            np.arange(3) if i == 0 else np.arange(n - 3, n))
        return np.polyval(np.polyfit(views[at], weights[at], 2), q)
    return CubicSpline(views, weights, bc_type="natural")(q)


def worst_errors(n_views, residual, period, phases=13, samples=4001):
    """The largest error over the texture's phase of each method."""
    views = np.arange(n_views) - (n_views - 1) / 2
    weights = falloff(views, n_views)
    aperture = np.linspace(views[0] - 0.5, views[-1] + 0.5, 25 * samples)
    worst = dict.fromkeys(METHODS, 0.0)
    for phase in np.linspace(0.0, 2 * np.pi, phases):
        def texture(q):
            return np.cos(2 * np.pi * residual * q / period + phase)

        exact = np.trapezoid(falloff(aperture, n_views) * texture(aperture), aperture) / np.trapezoid(
            falloff(aperture, n_views), aperture)
        for method in METHODS:
            if method == "comb":
                value = np.sum(weights * texture(views)) / weights.sum()
            else:
                num = den = 0.0
                for i, centre in enumerate(views):
                    q = np.linspace(centre - 0.5, centre + 0.5, samples)
                    w = cell_weights(method, i, views, weights, q)
                    num += np.trapezoid(w * texture(q), q)
                    den += np.trapezoid(w, q)
                value = num / den
            worst[method] = max(worst[method], abs(value - exact))
    return worst


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", help="write the table here (markdown)")
    args = parser.parse_args()
    lines = ["# A vignette's weight across a view's cell (one-dimensional model)", "",
             "Made by `.venv/bin/python benchmarks/vignette_cell_weights.py --out "
             "benchmarks/results/vignette_cell_weights.md` (see its docstring). Largest error of the",
             f"cell-integrated value of a unit cosine over its phase, fall-off strength {STRENGTH}.", "",
             "| views | residual (px/step) | period (px) | " + " | ".join(METHODS) + " |",
             "|---|---|---|" + "---|" * len(METHODS)]
    for n_views in (3, 5):
        for residual, period in CASES:
            worst = worst_errors(n_views, residual, period)
            lines.append(f"| {n_views} | {residual:+.1f} | {period:.0f} | "
                         + " | ".join(f"{worst[m]:.1e}" for m in METHODS) + " |")
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out:
        with open(args.out, "w") as f:
            f.write(text)


if __name__ == "__main__":
    main()
