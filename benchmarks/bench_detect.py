"""Aliasing detection (Algorithm 1) against ground truth, and its run time against its error.

Ground truth: on the synthetic scenes of :mod:`napari_lfalias.synthetic`
the dense-aperture reference refocus is known exactly. Computed with the
same bilinear interpolation as the naive refocus, it differs from it only
by the angular sampling; a pixel is *aliased* where the luminance of the
naive refocus differs from the reference's by more than ``PERCEPTIBLE``
(2 %, the paper's "minimal intensity of perceivable aliasing") of the
reference luminance (floored at 1 % of the peak, as Cv is).

What is measured (``--out`` writes the markdown report and a plot):

1. ROC AUC of Cv and precision / recall / F1 of the mask, for the exact
   Cv and for Monte Carlo at N = 10 .. 200 (mean and std over seeds), on
   the brick room (8x8 views) focused on the cube and on the wall.
2. The same over gamma = 0.05 .. 0.5 (the paper's Figure 9).
3. The threshold: the T of best F1 on each scene and array size, stated on
   Cv (the paper's scale) and on the angular coefficient of variation
   (``threshold_scale="angular"``), and the false-positive rate on the
   textureless plane.
4. Run time on 8x8x512x512x3, as a ratio to the memory floor of the same
   run, against the error: the mean relative deviation of the
   Monte-Carlo Cv from the exact Cv, and 1 - F1 against ground truth;
   and the time saved by skipping flat tiles on the textureless plane.

Run::

    .venv/bin/python benchmarks/bench_detect.py --out benchmarks/results/detection.md
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

import napari_lfalias as lfa
from napari_lfalias import metrics
from napari_lfalias.detect import AliasingDetector, variance_factors
from napari_lfalias.synthetic import brick_room, textureless_plane

from _harness import PERCEPTIBLE, aliasing_truth, median_iqr, memory_floor, table, timings, write_report

N_VALUES = (10, 20, 50, 100, 150, 200)
GAMMAS = (0.05, 0.1, 0.2, 0.3, 0.4, 0.5)
THRESHOLDS = np.geomspace(1e-3, 3.0, 60)
#: The aperture every array spans: 7 view steps of the paper's 8x8 array, at 4 px of disparity per step.
APERTURE_PX = 28.0


def ground_truth(scene, slope):
    """Aliased pixels: naive refocus vs the dense-aperture reference, same bilinear interpolation."""
    return aliasing_truth(lfa.refocus(scene.lightfield, slope), scene.reference(slope, interpolation="bilinear"))


def room_scene(n_views, size, seed=0):
    """The brick room spanning the same aperture with ``n_views`` per side (disparities scaled)."""
    per_step = APERTURE_PX / (n_views - 1) / 2
    return brick_room(n_views=n_views, size=size, seed=seed, wall_disparity=-2 * per_step,
                      cube_disparity=2 * per_step)


def scores(cv, mask, truth):
    p, r, f1 = metrics.precision_recall_f1(mask, truth)
    return {"auc": metrics.roc_auc(cv, truth), "precision": p, "recall": r, "f1": f1}


def mean_std(values):
    values = np.asarray(values, np.float64)
    return f"{values.mean():.3f} ± {values.std():.3f}"


def accuracy_by_n(cases, seeds):
    """Section 1: exact and Monte Carlo at every N, on every case."""
    rows = []
    for name, (scene, slope, truth) in cases.items():
        detector = AliasingDetector(scene.lightfield, skip_flat=False)
        exact = detector.detect(slope)
        s = scores(exact.cv, exact.mask, truth)
        rows.append([name, "exact", f"{s['auc']:.3f}", f"{s['precision']:.3f}", f"{s['recall']:.3f}",
                     f"{s['f1']:.3f}", "0"])
        for n_patterns in N_VALUES:
            runs = [detector.detect(slope, n_patterns=n_patterns, method="monte_carlo", seed=seed)
                    for seed in range(seeds)]
            per_seed = [scores(r.cv, r.mask, truth) for r in runs]
            textured = exact.cv > 1e-3
            deviation = [np.mean(np.abs(r.cv[textured] - exact.cv[textured]) / exact.cv[textured]) for r in runs]
            rows.append([name, f"MC N={n_patterns}"] + [mean_std([p[k] for p in per_seed])
                                                       for k in ("auc", "precision", "recall", "f1")]
                        + [mean_std(deviation)])
    header = ["scene", "method", "ROC AUC", "precision", "recall", "F1", "mean rel. deviation from exact Cv"]
    return table(header, rows)


def accuracy_by_gamma(cases, seeds):
    """Section 2: precision and recall over gamma (false negatives at small gamma, false positives at large)."""
    rows = []
    for name, (scene, slope, truth) in cases.items():
        detector = AliasingDetector(scene.lightfield, skip_flat=False)
        for gamma in GAMMAS:
            exact = detector.detect(slope, gamma=gamma)
            s = scores(exact.cv, exact.mask, truth)
            mc = [detector.detect(slope, gamma=gamma, method="monte_carlo", seed=seed) for seed in range(seeds)]
            mc_scores = [scores(r.cv, r.mask, truth) for r in mc]
            rows.append([name, gamma, f"{exact.mask.mean():.3f}", f"{s['precision']:.3f}", f"{s['recall']:.3f}",
                         f"{s['f1']:.3f}", mean_std([m["f1"] for m in mc_scores]),
                         f"{math.sqrt(variance_factors(scene.lightfield.n_views, gamma)[-1]):.4f}"])
    header = ["scene", "gamma", "flagged (exact)", "precision (exact)", "recall (exact)", "F1 (exact)",
              "F1 (MC N=100)", "sqrt(c) = Cv / angular Cv"]
    return table(header, rows)


def best_thresholds(size):
    """Section 3: the T of best F1 per array size, on both threshold scales."""
    rows = []
    best = {"cv": [], "angular": []}  # of the cases with at least 1 % aliased pixels
    for n_views in (5, 8, 12):
        scene = room_scene(n_views, size)
        per_step = APERTURE_PX / (n_views - 1) / 2
        for label, slope in (("cube in focus", 2 * per_step), ("wall in focus", -2 * per_step)):
            truth = ground_truth(scene, slope)
            detection = lfa.detect_aliasing(scene.lightfield, slope, skip_flat=False)
            row = [f"{n_views}x{n_views}", label, f"{truth.mean():.3f}"]
            for scale, values in (("cv", detection.cv), ("angular", detection.angular_cv)):
                f1 = [metrics.precision_recall_f1(values > t, truth).f1 for t in THRESHOLDS]
                i = int(np.argmax(f1))
                if truth.mean() >= 0.01:  # an (almost) empty truth has no meaningful best threshold
                    best[scale].append(THRESHOLDS[i])
                paper = metrics.precision_recall_f1(values > 0.02, truth).f1 if scale == "cv" else None
                row += [f"{THRESHOLDS[i]:.4f}", f"{f1[i]:.3f}"] + ([f"{paper:.3f}"] if paper is not None else [])
            rows.append(row)
    header = ["array", "focus", "aliased (truth)", "best T on Cv", "F1 there", "F1 at the paper's T=0.02",
              "best T on angular Cv", "F1 there"]
    spread = {scale: float(np.std(np.log(values))) for scale, values in best.items()}
    return table(header, rows), best, spread


def false_positives(size, threshold_angular):
    """Section 3b: pixels flagged where the ground truth has no aliasing, on the textureless plane."""
    scene = textureless_plane(n_views=8, size=size, seed=0)
    rows = []
    for slope in (0.0, 2.0, 1.0):
        truth = ground_truth(scene, slope)
        for label, kwargs in (("exact, T=0.02 on Cv", {}),
                              ("MC N=100, T=0.02 on Cv", {"method": "monte_carlo", "seed": 0}),
                              (f"exact, T={threshold_angular:.3g} angular",
                               {"threshold": threshold_angular, "threshold_scale": "angular"})):
            det = lfa.detect_aliasing(scene.lightfield, slope, **kwargs)
            negatives = ~truth
            rows.append([slope, label, f"{truth.mean():.4f}", f"{(det.mask & negatives).sum() / negatives.sum():.4f}",
                         f"{(det.mask & truth).sum() / max(truth.sum(), 1):.3f}"])
    return table(["slope", "detection", "aliased (truth)", "false-positive rate", "recall"], rows)


def run_time(size, n_views, repeats, seeds):
    """Section 4: time as a ratio to the memory floor against the error, and the saving of skipped tiles."""
    scene = brick_room(n_views=n_views, size=size, seed=0)
    lf = scene.lightfield
    slope = scene.layers_disparity["cube_front"]
    truth = ground_truth(scene, slope)
    floor, floor_iqr = median_iqr(memory_floor(lf.data, repeats))
    exact = lfa.detect_aliasing(lf, slope)
    points, rows = [], []
    t, t_iqr = median_iqr(timings(lambda: lfa.detect_aliasing(lf, slope), repeats))
    f1 = metrics.precision_recall_f1(exact.mask, truth).f1
    auc = metrics.roc_auc(exact.cv, truth)
    rows.append(["floor: data.sum(axis=(0, 1))", f"{floor * 1e3:.1f} ± {floor_iqr * 1e3:.1f}", "1.00", "", "", ""])
    rows.append(["exact (analytic)", f"{t * 1e3:.1f} ± {t_iqr * 1e3:.1f}", f"{t / floor:.2f}", "0",
                 f"{1 - auc:.3f}", f"{1 - f1:.3f}"])
    points.append(("exact", t / floor, 0.0, 1 - auc))
    textured = exact.cv > 1e-3
    for n_patterns in N_VALUES:
        kwargs = dict(method="monte_carlo", n_patterns=n_patterns)
        t, t_iqr = median_iqr(timings(lambda: lfa.detect_aliasing(lf, slope, seed=0, **kwargs), repeats))
        runs = [lfa.detect_aliasing(lf, slope, seed=seed, **kwargs) for seed in range(seeds)]
        deviation = [np.mean(np.abs(r.cv[textured] - exact.cv[textured]) / exact.cv[textured]) for r in runs]
        miss = [1 - metrics.precision_recall_f1(r.mask, truth).f1 for r in runs]
        ranking = [1 - metrics.roc_auc(r.cv, truth) for r in runs]
        rows.append([f"Monte Carlo N={n_patterns}", f"{t * 1e3:.1f} ± {t_iqr * 1e3:.1f}", f"{t / floor:.2f}",
                     mean_std(deviation), mean_std(ranking), mean_std(miss)])
        points.append((f"N={n_patterns}", t / floor, float(np.mean(deviation)), float(np.mean(ranking))))
    speed = table(["detection", "median ms ± IQR/2", "x floor", "mean rel. deviation from exact Cv",
                   "1 - ROC AUC vs truth", "1 - F1 vs truth (T=0.02)"], rows)

    flat = textureless_plane(n_views=n_views, size=size, seed=0).lightfield
    skip_rows = []
    for method in ("analytic", "monte_carlo"):
        for skip in (True, False):
            kwargs = dict(method=method, seed=0, skip_flat=skip)
            t, t_iqr = median_iqr(timings(lambda: lfa.detect_aliasing(flat, 2.0, **kwargs), repeats))
            evaluated = lfa.detect_aliasing(flat, 2.0, **kwargs).evaluated.mean()
            skip_rows.append([method, "on" if skip else "off", f"{evaluated:.3f}", f"{t * 1e3:.1f} ± {t_iqr * 1e3:.1f}"])
    skipping = table(["method", "skip flat tiles", "pixels evaluated", "median ms ± IQR/2"], skip_rows)
    return speed, skipping, points, lf.shape


def plot(points, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for label, ratio, deviation, miss in points:
        axes[0].scatter(ratio, deviation, color="C1" if label == "exact" else "C0")
        axes[0].annotate(label, (ratio, deviation), textcoords="offset points", xytext=(4, 4))
        axes[1].scatter(ratio, miss, color="C1" if label == "exact" else "C0")
        axes[1].annotate(label, (ratio, miss), textcoords="offset points", xytext=(4, 4))
    axes[0].set(xlabel="run time / memory floor", ylabel="mean relative deviation from exact Cv", xscale="log")
    axes[1].set(xlabel="run time / memory floor", ylabel="1 - ROC AUC of Cv against ground truth", xscale="log")
    fig.suptitle("Aliasing detection: run time against error (8x8x512x512x3 brick room, cube in focus)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=512, help="view size of the timed scene (default 512)")
    parser.add_argument("--accuracy-size", type=int, default=256, help="view size of the accuracy sweeps")
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--seeds", type=int, default=5, help="Monte-Carlo seeds per setting")
    parser.add_argument("--out", default="benchmarks/results/detection.md")
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)

    room = room_scene(8, args.accuracy_size)
    cases = {f"brick room 8x8, {label}": (room, slope, ground_truth(room, slope))
             for label, slope in (("cube in focus", 4.0), ("wall in focus", -4.0))}
    print("accuracy by N ...", flush=True)
    by_n = accuracy_by_n(cases, args.seeds)
    print("accuracy by gamma ...", flush=True)
    by_gamma = accuracy_by_gamma(cases, args.seeds)
    print("thresholds ...", flush=True)
    thresholds, best, spread = best_thresholds(args.accuracy_size)
    angular_default = float(np.exp(np.mean(np.log(best["angular"]))))
    fp = false_positives(args.accuracy_size, angular_default)
    print("run time ...", flush=True)
    speed, skipping, points, shape = run_time(args.size, 8, args.repeats, args.seeds)
    plot_path = out.with_suffix(".png")
    plot(points, plot_path)

    sections = [
        "Ground truth: a pixel is aliased where the luminance of the naive refocus differs from the "
        f"dense-aperture reference (same bilinear interpolation) by more than {PERCEPTIBLE:.0%} "
        "(relative, floored at 1 % of the peak). Scenes: the synthetic brick room of the paper's Figure 6 "
        f"({args.accuracy_size} px views for the sweeps); every array spans the same aperture "
        f"({APERTURE_PX:g} px of parallax between the outer views on each plane).",
        f"## 1. Accuracy against N (gamma = 0.2, T = 0.02 on Cv; mean ± std over {args.seeds} seeds)\n\n{by_n}",
        f"## 2. Accuracy against gamma (N = 100, T = 0.02 on Cv)\n\n{by_gamma}",
        "## 3. Which threshold finds the ground-truth aliasing best\n\n" + thresholds + "\n\n"
        f"Spread of the best thresholds across arrays and focal planes with at least 1 % aliased pixels "
        f"(std of log T): "
        f"on Cv {spread['cv']:.2f}, on angular Cv {spread['angular']:.2f}. "
        f"Geometric mean of the best angular thresholds: {angular_default:.3f}.",
        f"### False positives on the textureless plane (8x8)\n\n{fp}",
        f"## 4. Run time against error ({'x'.join(map(str, shape))} float32, cube in focus; "
        f"median of {args.repeats} runs)\n\n{speed}\n\n![run time against error]({plot_path.name})",
        f"### Skipping flat tiles (textureless plane, 8x8x{args.size}x{args.size}x3, slope 2)\n\n{skipping}",
    ]
    write_report(out, "Aliasing detection: accuracy against ground truth, run time against error", sections)
    print(f"wrote {out} and {plot_path}")


if __name__ == "__main__":
    main()
