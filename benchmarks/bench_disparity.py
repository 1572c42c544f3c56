"""Disparity from the light field: HCI benchmark accuracy and time, against a naive plane sweep.

Measures :func:`napari_lfalias.estimate_disparity` as it stands (the
script runs whatever method is in the package):

- **Accuracy** with the HCI 4D light-field benchmark's own metrics
  (:func:`napari_lfalias.disparity.disparity_scores`: BadPix(0.07),
  BadPix(0.03), MSE x 100, a 15 px border ignored) on HCI antinous against
  its ``gt_disp_lowres.pfm`` (read by :func:`napari_lfalias.load`, sign
  turned to this package's convention), on the full 9x9 grid and the
  sparse sub-grids 5x5 (rows/cols 0,2,4,6,8) and 3x3 (1,4,7), which keep
  the views' positions, so every disparity is in pixels per unit of view
  position of the full grid. Also on the synthetic scenes of
  ``accuracy_cases.py`` (their ``disparity`` is the truth), with the share
  of pixels within 0.25 px and the median absolute error besides, as their
  disparities span several pixels.
- **Units.** A refocus check that the truth and the sub-grids agree in
  sign and scale: the angular variance of the pixels whose true disparity
  is near ``s`` is least when refocusing at ``s`` itself, not at ``-s`` or
  at ``s`` scaled by a sub-grid's step; and the least-squares line of the
  estimate against the truth.
- **Time**: median and IQR of repeated runs with the per-stage seconds the
  estimate reports (``params["seconds"]``), against the memory floor (one
  plain sum over the views, :func:`_harness.memory_floor`) and a naive
  plane sweep measured in the same run: winner-take-all of the luminance's
  angular variance over the estimator's slope grid (range and step), with
  a parabola through the winner and its neighbours and no aggregation.
- **Images** of the 9x9 and 3x3 estimates (estimate | truth | error |
  confidence) and where the bad pixels lie: near depth edges of the truth,
  on weak texture, at low confidence.

The HCI light field is given ``meta["disparity_range"]`` as
:func:`napari_lfalias.load` reads it (the range of the ground truth: what
the benchmark's ``parameters.cfg`` ``disp_min``/``disp_max`` say), but not
the ground truth itself; one more run searches the default range a folder
without metadata gets.

Notes written by hand between the markers ``<!-- notes -->`` and
``<!-- end of notes -->`` in the report are kept when it is written again.

Run::

    .venv/bin/python benchmarks/bench_disparity.py --out benchmarks/results/disparity.md
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import numpy as np
from scipy import ndimage

import napari_lfalias as lfa
from napari_lfalias.baselines import _depth_edges
from napari_lfalias.disparity import disparity_scores
from napari_lfalias.lightfield import REC709

from _harness import kept_notes, median_iqr, memory_floor, table, timings, write_report
from accuracy_cases import HCI, synthetic_cases

#: Pixels ignored along every edge (the HCI benchmark's border).
BORDER = 15
#: The goal of the issue on the full 9x9 grid: BadPix(0.07) (%), MSE x 100, seconds.
GOAL = {"badpix_0.07": 10.0, "mse_x100": 2.0, "seconds": 2.0}
#: HCI sub-grids: name -> rows/columns kept.
GRIDS = {"9x9": tuple(range(9)), "5x5": (0, 2, 4, 6, 8), "3x3": (1, 4, 7)}
#: A true disparity jump larger than this (px) between neighbours is a depth edge ...
EDGE_JUMP = 0.1
#: ... and pixels within this distance (px) of one are "near an edge".
EDGE_REACH = 3
#: A surface is steeply slanted where its disparity changes by more than this (px) per pixel.
STEEP_SLANT = 0.02
#: Standard deviation of the centre view's luminance (bright level 1) in a 5x5 window below which
#: a pixel counts as weak texture.
WEAK_TEXTURE = 0.01
#: Confidence at or above which a pixel counts as confident.
CONFIDENT = 0.5
#: Scale factors of the units check: the sign (-1) and the steps of the sub-grids (2, 3).
UNIT_FACTORS = (-1.0, 1 / 3, 1 / 2, 1.0, 2.0, 3.0)


# -- the baseline ------------------------------------------------------------------------------------

def slope_grid(low, high, step):
    """Slopes ``step`` apart, centred on ``[low, high]`` (as many as fit)."""
    count = int(math.floor((high - low) / step + 1e-9)) + 1
    return 0.5 * (low + high) + step * (np.arange(count) - 0.5 * (count - 1))


def estimator_slopes(lf, estimate):
    """The slope grid the estimator searched: its range, and its step (``params["step"]``, else half a
    pixel of motion of the outermost view)."""
    step = estimate.params.get("step") or 0.5 / float(np.abs(lf.flat_positions()).max())
    return slope_grid(*estimate.disparity_range, step)


def naive_sweep(lf, slopes):
    """Winner-take-all plane sweep: per pixel, the slope of least angular variance of the luminance.

    Every slope is one :func:`napari_lfalias.view_moments` pass; the winner
    is refined by a parabola through its neighbours' variances. No
    aggregation, no occlusion handling.

    Returns
    -------
    ndarray, shape (Y, X), float32
    """
    slopes = np.asarray(slopes, np.float64)
    lum = lf.luminance()
    cost = np.empty((len(slopes),) + lf.image_shape, np.float32)
    for j, slope in enumerate(slopes):
        moments = lfa.view_moments(lum, slope)
        cost[j] = np.where(moments.count >= 2, moments.variance[..., 0], np.inf)
    best = np.argmin(cost, axis=0)
    disparity = slopes[best]
    if len(slopes) >= 3:
        inner = np.clip(best, 1, len(slopes) - 2)
        c0, c1, c2 = (np.take_along_axis(cost, (inner + k)[None], 0)[0] for k in (-1, 0, 1))
        curvature = c0 - 2 * c1 + c2
        with np.errstate(invalid="ignore", divide="ignore"):
            offset = np.where(np.isfinite(curvature) & (curvature > 0), 0.5 * (c0 - c2) / curvature, 0.0)
        refined = slopes[inner] + np.clip(offset, -0.5, 0.5) * (slopes[1] - slopes[0])
        disparity = np.where(best == inner, refined, disparity)
    return disparity.astype(np.float32)


# -- scores -------------------------------------------------------------------------------------------

def scores(disparity, truth, border=BORDER):
    """The HCI scores plus the share within 0.25 px (%) and the median absolute error (px)."""
    out = disparity_scores(disparity, truth, border)
    inner = (slice(border, truth.shape[0] - border), slice(border, truth.shape[1] - border))
    error = np.abs(np.asarray(disparity, np.float64)[inner] - np.asarray(truth, np.float64)[inner])
    error = error[np.isfinite(error)]
    out["within_0.25"] = float(np.mean(error <= 0.25) * 100)
    out["median_abs"] = float(np.median(error))
    return out


def score_cells(s):
    return [f"{s['badpix_0.07']:.2f}", f"{s['badpix_0.03']:.2f}", f"{s['mse_x100']:.3f}",
            f"{s['within_0.25']:.1f}", f"{s['median_abs']:.3f}"]


SCORE_HEADER = ["BadPix(0.07) %", "BadPix(0.03) %", "MSE x100", "within 0.25 px %", "median abs err px"]


def seconds_cell(values):
    median, half_iqr = median_iqr(values)
    return f"{median:.2f} ± {half_iqr:.2f} (n={len(values)})"


def run_timed(func, repeats, warmup=0):
    """Wall seconds of ``repeats`` calls of ``func`` (harness timings), their CPU seconds (the process's,
    every thread), and every result ``func`` returned, warm-up calls first."""
    results, cpu = [], []

    def call():
        start = time.process_time()
        results.append(func())
        cpu.append(time.process_time() - start)

    seconds = timings(call, repeats, warmup)
    return seconds, np.array(cpu[warmup:]), results


def stage_seconds(estimates):
    """``{stage: [seconds of every run]}`` from the estimates' ``params["seconds"]``."""
    stages = {}
    for est in estimates:
        for stage, value in est.params.get("seconds", {}).items():
            stages.setdefault(stage, []).append(value)
    return stages


# -- the units check ------------------------------------------------------------------------------------

def unit_check(lf, truth, slope, factors=UNIT_FACTORS, tolerance=0.05, border=BORDER):
    """Angular variance of the luminance of the pixels whose true disparity is within ``tolerance`` of
    ``slope``, refocused at ``factor * slope`` for each factor.

    Returns ``({factor: median variance}, {factor: share of the pixels whose variance is least at that
    factor}, number of pixels)``. In the right sign and scale both single out factor 1. (The median, as
    the mean is dominated by the occlusion halos of a few pixels beside a silhouette.)
    """
    inner = np.zeros(truth.shape, bool)
    inner[border:truth.shape[0] - border, border:truth.shape[1] - border] = True
    near = inner & (np.abs(truth - slope) < tolerance)
    lum = lf.luminance()
    variance = np.stack([lfa.view_moments(lum, k * slope).variance[..., 0][near] for k in factors])
    least = np.bincount(np.argmin(variance, axis=0), minlength=len(factors)) / max(variance.shape[1], 1)
    return (dict(zip(factors, np.median(variance, axis=1).tolist())), dict(zip(factors, least.tolist())),
            int(near.sum()))


def line_fit(disparity, truth, border=BORDER):
    """Least-squares ``(a, b)`` of ``disparity ~ a * truth + b`` over the inner pixels."""
    inner = (slice(border, truth.shape[0] - border), slice(border, truth.shape[1] - border))
    a, b = np.polyfit(np.ravel(truth[inner]), np.ravel(disparity[inner]), 1)
    return float(a), float(b)


# -- where the errors are --------------------------------------------------------------------------------

def near_depth_edges(truth, jump=EDGE_JUMP, reach=EDGE_REACH):
    """Pixels within ``reach`` px of a jump of the true disparity larger than ``jump`` between neighbours."""
    return ndimage.distance_transform_edt(~_depth_edges(np.asarray(truth, np.float64), jump)) <= reach


def steep_slant(truth, slant=STEEP_SLANT):
    """Pixels where the true disparity changes by more than ``slant`` px per px (slanted surfaces)."""
    gy, gx = np.gradient(np.asarray(truth, np.float64))
    return np.hypot(gy, gx) > slant


def weak_texture(lf, threshold=WEAK_TEXTURE, size=5):
    """Pixels of the centre view whose luminance (scaled to a bright level of 1) varies little nearby."""
    positions = lf.flat_positions()
    centre = lf.views()[int(np.argmin(np.hypot(positions[:, 0], positions[:, 1])))]
    lum = centre[..., 0] if centre.shape[-1] == 1 else centre @ REC709
    lum = lum / max(float(np.percentile(lum, 99.5)), 1e-6)
    mean = ndimage.uniform_filter(lum, size)
    std = np.sqrt(np.maximum(ndimage.uniform_filter(lum * lum, size) - mean * mean, 0.0))
    return std < threshold


def error_regions(disparity, truth, regions, border=BORDER, bad=0.07):
    """Rows ``[region, share of pixels %, BadPix(bad) in it %, share of all bad pixels %, share of the
    squared error %]``."""
    inner = (slice(border, truth.shape[0] - border), slice(border, truth.shape[1] - border))
    error = np.asarray(disparity, np.float64)[inner] - np.asarray(truth, np.float64)[inner]
    is_bad = np.abs(error) > bad
    squared = error ** 2
    total_bad, total_squared = max(int(is_bad.sum()), 1), max(float(squared.sum()), 1e-300)
    rows = []
    for name, mask in regions.items():
        mask = mask[inner]
        rows.append([name, f"{mask.mean() * 100:.1f}", f"{is_bad[mask].mean() * 100 if mask.any() else 0:.1f}",
                     f"{is_bad[mask].sum() / total_bad * 100:.1f}", f"{squared[mask].sum() / total_squared * 100:.1f}"])
    return rows


def save_panels(path, disparity, truth, confidence, clip=0.2, gap=4):
    """Write estimate | truth | |error| (clipped at ``clip``) | confidence side by side as PNG."""
    import imageio.v3 as iio
    from matplotlib import colormaps

    low, high = np.nanpercentile(truth, [0.5, 99.5])

    def colour(values, cmap, lo, hi):
        scaled = np.clip((np.asarray(values, np.float64) - lo) / max(hi - lo, 1e-9), 0, 1)
        return colormaps[cmap](scaled)[..., :3]

    panels = [colour(disparity, "viridis", low, high), colour(truth, "viridis", low, high),
              colour(np.abs(disparity - truth), "magma", 0.0, clip), colour(confidence, "gray", 0.0, 1.0)]
    white = np.ones((truth.shape[0], gap, 3))
    row = np.concatenate([p for panel in panels for p in (panel, white)][:-1], axis=1)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    iio.imwrite(path, (row * 255).round().astype(np.uint8))
    return path, (float(low), float(high))


# -- the cases ------------------------------------------------------------------------------------------

def hci_grids(full):
    """The HCI light fields of :data:`GRIDS`, with the disparity range a loader gives but not the truth."""
    out = {}
    for name, keep in GRIDS.items():
        sub = full.subset(list(keep), list(keep))
        out[name] = lfa.LightField(sub.data, sub.positions, {"source": f"hci_antinous {name}",
                                                             "disparity_range": full.meta["disparity_range"]})
    return out


def evaluate(name, lf, truth, repeats, warmup=0, naive_repeats=1):
    """Estimate and naive sweep on one light field: scores, seconds, the last estimate."""
    seconds, cpu, estimates = run_timed(lambda: lfa.estimate_disparity(lf), repeats, warmup)
    est = estimates[-1]
    slopes = estimator_slopes(lf, est)
    naive_seconds, naive_cpu, naive = run_timed(lambda: naive_sweep(lf, slopes), naive_repeats)
    print(f"{name}: estimate {np.median(seconds):.2f} s, naive {np.median(naive_seconds):.2f} s "
          f"({len(slopes)} slopes)", flush=True)
    return {"name": name, "lf": lf, "estimate": est, "seconds": seconds, "cpu": cpu, "naive_cpu": naive_cpu,
            "stages": stage_seconds(estimates[warmup:]),
            "naive": naive[-1], "naive_seconds": naive_seconds, "n_slopes": len(slopes),
            "scores": scores(est.disparity, truth), "naive_scores": scores(naive[-1], truth)}


def accuracy_rows(results, floor=None):
    """Rows of the accuracy table: the estimate and the naive sweep of every result."""
    rows = []
    for r in results:
        for method, key, seconds in (("estimate_disparity", "scores", r["seconds"]),
                                     ("naive sweep (WTA variance)", "naive_scores", r["naive_seconds"])):
            ratio = [] if floor is None else [f"{np.median(seconds) / floor:.1f}"]
            rows.append([r["name"], method] + score_cells(r[key]) + [seconds_cell(seconds)] + ratio)
    return rows


def goal_line(result):
    s, seconds = result["scores"], float(np.median(result["seconds"]))
    checks = [("BadPix(0.07)", s["badpix_0.07"], GOAL["badpix_0.07"], "%"),
              ("MSE x 100", s["mse_x100"], GOAL["mse_x100"], ""),
              ("time", seconds, GOAL["seconds"], " s")]
    parts = [f"{label} {value:.2f}{unit} {'<=' if value <= limit else '>'} {limit:g}{unit}"
             for label, value, limit, unit in checks]
    met = all(value <= limit for _, value, limit, _ in checks)
    return f"**Goal of issue 12 on the full 9x9 grid: {'MET' if met else 'NOT MET'}** ({'; '.join(parts)})."


def load_line():
    return "1/5/15-min load average " + ", ".join(f"{v:.2f}" for v in os.getloadavg())


# -- report ---------------------------------------------------------------------------------------------

def hci_results(full, repeats):
    """Estimate and naive sweep on every HCI grid (the 9x9 timed ``repeats`` times after a warm-up), the
    memory floor, and the load around the 9x9 timing."""
    truth = full.meta["disparity"]
    grids = hci_grids(full)
    floor_seconds = memory_floor(full.data, repeats)
    load = [load_line()]
    results = [evaluate("9x9", grids["9x9"], truth, repeats, warmup=1, naive_repeats=3)]
    load.append(load_line())
    for name in ("5x5", "3x3"):
        results.append(evaluate(name, grids[name], truth, max(3, repeats // 2), warmup=1))
    bare = lfa.LightField(full.data, full.positions, {"source": "hci_antinous, no metadata"})
    results.append(evaluate("9x9, no range given", bare, truth, 1))
    return results, floor_seconds, load


def hci_accuracy_md(results, full, floor):
    first, bare = results[0], results[-1]

    def rounded(pair):
        return tuple(round(v, 3) for v in pair)

    header = ["grid", "method"] + SCORE_HEADER + ["seconds (median ± IQR/2)", "x floor"]
    return "\n".join([
        "## HCI antinous (HCI benchmark metrics, 15 px border)", "",
        f"Searched range {rounded(first['estimate'].disparity_range)} px per view step (the ground truth's range "
        f"{rounded(full.meta['disparity_range'])} as `lfa.load` gives it, widened by the estimator); 'no range "
        f"given': {rounded(bare['estimate'].disparity_range)}. The naive sweep searches the same slopes "
        f"({first['n_slopes']} on 9x9). x floor: median time over the memory floor of the full 9x9 "
        f"({floor * 1e3:.0f} ms: one `data.sum(axis=(0, 1))` over 9x9x512x512x3 float32).", "",
        table(header, accuracy_rows(results, floor))])


def timing_md(result, floor_seconds, load):
    floor = float(np.median(floor_seconds))

    def ratio(values):
        return f"{np.median(values) / floor:.1f}"

    rows = [["memory floor: one sum over the views", seconds_cell(floor_seconds), "1.0", ""],
            ["estimate_disparity, total", seconds_cell(result["seconds"]), ratio(result["seconds"]),
             f"{np.median(result['cpu']):.2f}"]]
    rows += [[f"stage: {stage}", seconds_cell(values), ratio(values), ""]
             for stage, values in result["stages"].items()]
    rows.append([f"naive sweep, {result['n_slopes']} slopes", seconds_cell(result["naive_seconds"]),
                 ratio(result["naive_seconds"]), f"{np.median(result['naive_cpu']):.2f}"])
    params = {k: v for k, v in result["estimate"].params.items() if k != "seconds"}
    return "\n".join([
        "## Time, full 9x9x512x512x3", "",
        f"After one warm-up call (numba kernels compiled and cached). Load before timing: {load[0]}; after: "
        f"{load[1]} (2 shared cores: other developers' jobs run at the same time, so the spread and the medians "
        "move with the load; the CPU seconds of the process, every thread, move less). Estimate parameters: "
        f"`{params}`.", "",
        table(["what", "wall seconds (median ± IQR/2)", "x floor", "CPU seconds, all threads (median)"], rows)])


def units_md(full, results):
    truth = full.meta["disparity"]
    rows = []
    for name, lf in hci_grids(full).items():
        for q in (10, 90):
            slope = float(np.percentile(truth, q))
            medians, least, count = unit_check(lf, truth, slope)
            rows.append([name, f"{slope:+.3f} ({count} px)"]
                        + [f"{medians[k]:.1e} ({least[k] * 100:.0f} %)" for k in UNIT_FACTORS]
                        + [f"{max(least, key=least.get):g}"])
    fits = [[r["name"], *(f"{v:.3f}" for v in line_fit(r["estimate"].disparity, truth))] for r in results]
    return "\n".join([
        "## Units and sign", "",
        "Angular variance (luminance) of the pixels whose true disparity is within 0.05 px of s (the 10th and "
        "90th percentiles of the truth), refocused at k * s: its median over those pixels, and in brackets the "
        "share of them whose variance is least at that k. Both must single out k = 1 on every grid, if the "
        "truth (negated HCI `gt_disp_lowres.pfm`) and the sub-grids (positions kept) are in px per unit of view "
        "position of the full grid. k = -1 is the other sign; k = 2, 3 (1/2, 1/3) the units of a sub-grid's own "
        "step.", "",
        table(["grid", "s (pixels near it)"] + [f"k = {k:.3g}" for k in UNIT_FACTORS] + ["most pixels least at k"],
              rows),
        "", "Least-squares line estimate = a * truth + b (inner pixels):", "",
        table(["grid", "a", "b"], fits)])


def error_region_masks(lf, truth, confidence):
    """Named masks of where errors may gather: depth edges, slanted surfaces, weak texture, low confidence."""
    edges = near_depth_edges(truth)
    weak = weak_texture(lf)
    confident = confidence >= CONFIDENT
    return {f"within {EDGE_REACH} px of a depth edge (jump > {EDGE_JUMP} px)": edges,
            "away from depth edges": ~edges,
            f"steep slant away from edges (> {STEEP_SLANT} px/px)": steep_slant(truth) & ~edges,
            f"weak texture (5x5 std < {WEAK_TEXTURE})": weak, "textured": ~weak,
            f"confidence >= {CONFIDENT}": confident, f"confidence < {CONFIDENT}": ~confident}


def images_md(results, truth, out_dir):
    parts = ["## Images", "",
             "Each PNG, left to right: estimate | ground truth (both viridis, over the truth's 0.5-99.5 % range "
             "below) | |estimate - truth| (magma, black 0, clipped at 0.2 px) | confidence (black 0, white 1).", ""]
    for result in results:
        est = result["estimate"]
        path, (low, high) = save_panels(out_dir / f"disparity_{result['name']}.png", est.disparity, truth,
                                        est.confidence)
        regions = error_region_masks(result["lf"], truth, est.confidence)
        parts += [f"### {result['name']} (colour range {low:+.2f} .. {high:+.2f} px)", "",
                  f"![{result['name']}: estimate, truth, error, confidence]({path.name})", "",
                  table(["region (inner pixels)", "share of pixels %", "BadPix(0.07) in it %",
                         "share of all bad pixels %", "share of the squared error (MSE) %"],
                        error_regions(est.disparity, truth, regions)), ""]
    return "\n".join(parts)


def hci_sections(full, repeats, out_dir):
    """The report's HCI sections and the 9x9 result."""
    results, floor_seconds, load = hci_results(full, repeats)
    by_name = {r["name"]: r for r in results}
    sections = [hci_accuracy_md(results, full, float(np.median(floor_seconds))),
                timing_md(by_name["9x9"], floor_seconds, load),
                units_md(full, [by_name[name] for name in GRIDS]),
                images_md([by_name["9x9"], by_name["3x3"]], full.meta["disparity"], out_dir)]
    return sections, by_name["9x9"]


def synthetic_section(size, repeats, out_dir):
    """The synthetic cases' table; panels of the cases the estimate gets grossly wrong (most pixels off by
    more than 0.25 px)."""
    results, splits, pictures = [], {}, []
    for case in synthetic_cases(size):
        truth = np.asarray(case.disparity, np.float64)
        result = evaluate(case.name, case.lightfield, truth, repeats)
        splits[case.name] = case.split
        results.append(result)
        if result["scores"]["within_0.25"] < 50:
            est = result["estimate"]
            slug = "".join(c if c.isalnum() else "_" for c in case.name)[:40].strip("_")
            path, (low, high) = save_panels(out_dir / f"disparity_synthetic_{slug}.png", est.disparity, truth,
                                            est.confidence)
            pictures += [f"{case.name} (colour range {low:+.2f} .. {high:+.2f} px; truth layers at "
                         f"{sorted(set(np.round(np.unique(truth), 2).tolist()))[:6]}, estimate median "
                         f"{float(np.median(est.disparity)):+.2f}):", "", f"![{case.name}]({path.name})", ""]
    header = ["case", "method"] + SCORE_HEADER + ["seconds (median ± IQR/2)"]
    rows = [[f"{row[0]} ({splits[row[0]]})"] + row[1:] for row in accuracy_rows(results)]
    mean = {key: np.mean([r[key]["badpix_0.07"] for r in results]) for key in ("scores", "naive_scores")}
    parts = [
        f"## Synthetic scenes of accuracy_cases.py ({size} px, default search range)", "",
        "Truth: the scene's `disparity`. Same metrics and 15 px border. Mean BadPix(0.07) over the cases: "
        f"estimate {mean['scores']:.2f} %, naive sweep {mean['naive_scores']:.2f} %.", "",
        table(header, rows), ""]
    if pictures:
        parts += ["Cases the estimate gets grossly wrong (panels as above):", ""] + pictures
    return "\n".join(parts)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5, help="timed runs on the full 9x9 (fewer on small cases)")
    parser.add_argument("--size", type=int, default=256, help="view size of the synthetic scenes")
    parser.add_argument("--no-synthetic", action="store_true", help="HCI antinous only")
    parser.add_argument("--out", type=Path, default=None, help="write the report (and PNGs beside it) here")
    args = parser.parse_args(argv)
    if not HCI.exists():
        sys.exit(f"HCI antinous not found at {HCI}")
    out_dir = (args.out or Path("benchmarks/results/disparity.md")).parent
    sections, full_result = hci_sections(lfa.load(HCI), args.repeats, out_dir)
    if not args.no_synthetic:
        sections.append(synthetic_section(args.size, max(1, args.repeats // 2), out_dir))
    print(goal_line(full_result))
    if args.out is not None:
        notes = kept_notes(args.out)
        write_report(args.out, "Disparity estimation: HCI benchmark accuracy and time",
                     [goal_line(full_result), "## Notes (written by hand, kept when re-run)\n\n" + notes]
                     + sections)
    else:
        print("\n\n".join(sections))


if __name__ == "__main__":
    main()
