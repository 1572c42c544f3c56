"""Aliasing reduction (Algorithm 2) against the paper's baselines, and its speed.

The accuracy table is the paper's Figure 6 experiment, measured:

- the synthetic brick room (8x8 views, 512 px, as in the paper), focused
  on the cube and on the back wall; reference: the dense-aperture refocus
  (same bilinear interpolation, so only the angular sampling differs);
- HCI antinous: a sparse subset of its 9x9 views as input (3x3 or 5x5,
  ``--hci-step``), the refocus of all 81 views as reference, focused on
  the near and the far end of its ground-truth disparities.

Rows: naive refocus, prefiltering (Levoy-Hanrahan), depth-aware rendering
with the ground-truth disparity (Yu et al.), and ours (exact and
Monte-Carlo detection, at the paper's T = 0.02 and at a lower T), plus
ours with the plain (unscreened) Poisson fusion of the paper as an
ablation, and ours keeping the in-focus layer (``keep_in_focus=True``,
:mod:`napari_lfalias.in_focus`). Two ceiling rows measure Algorithm 2 with a
perfect detector: the renderings and fusion of
:func:`~napari_lfalias.reduce.fuse_levels` on the level map the ground-truth
disparity implies (:func:`~napari_lfalias.reduce.levels_from_disparity`),
everywhere and on the truly aliased pixels only. Columns: PSNR and SSIM against the reference over the whole
image, the in-focus region (``|d - slope|`` times the view spacing below
0.5 px: a point moves less than half a pixel between neighbouring views) and
the aliased region (where the naive refocus differs from the reference by
more than 2 %), and the in-focus pixels that are not aliased (where
"sharpness kept" is measured: an in-focus background partly hidden by a
defocused occluder is both in focus and aliased); the mean and variance of the gradient differences (the
paper's Figure 6, rows 4-5); run time.

Run::

    .venv/bin/python benchmarks/bench_reduce.py --out benchmarks/results/reduction.md
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import napari_lfalias as lfa
from napari_lfalias import metrics
from napari_lfalias.baselines import view_spacing
from napari_lfalias.reduce import fuse_levels, levels_from_disparity
from napari_lfalias.synthetic import brick_room

from _harness import aliasing_truth, kept_notes, median_iqr, memory_floor, table, timings, write_report

HCI = Path(__file__).resolve().parents[2] / "shared" / "lf_data" / "hci_antinous"
LOW_T = 0.005


def methods(lf, slope, disparity, aliased, estimate):
    """Name -> function returning the refocused image (``estimate``: the light field's disparity,
    estimated once: its time is in the speed section)."""
    truth = levels_from_disparity(disparity, slope, view_spacing(lf.positions))
    analytic = dict(method="analytic")
    return {
        "naive refocus": lambda: lfa.refocus(lf, slope),
        "prefilter (Levoy-Hanrahan, true disparity range)": lambda: lfa.prefilter_refocus(
            lf, slope, disparity_range=(float(disparity.min()), float(disparity.max()))),
        "depth-aware (ground-truth disparity)": lambda: lfa.depth_aware_refocus(lf, slope, disparity),
        "default: dense-aperture rendering where aliased (estimated disparity), T=0.02": lambda: lfa.reduce_aliasing(
            lf, slope, disparity=estimate).image,
        "antialiased_refocus (estimated disparity), every pixel": lambda: lfa.antialiased_refocus(lf, slope, estimate),
        "paper preset (Monte Carlo Cv, T=0.02, Algorithm 2)": lambda: lfa.reduce_aliasing(
            lf, slope, preset="paper", seed=0).image,
        "Algorithm 2, exact Cv, T=0.02": lambda: lfa.reduce_aliasing(lf, slope, **analytic).image,
        f"Algorithm 2, exact Cv, T={LOW_T}": lambda: lfa.reduce_aliasing(lf, slope, threshold=LOW_T, **analytic).image,
        f"Algorithm 2, Monte Carlo N=100, T={LOW_T}": lambda: lfa.reduce_aliasing(
            lf, slope, threshold=LOW_T, method="monte_carlo", seed=0).image,
        f"Algorithm 2, plain Poisson (screen 0), T={LOW_T}": lambda: lfa.reduce_aliasing(
            lf, slope, threshold=LOW_T, screen=0.0, **analytic).image,
        f"Algorithm 2, in-focus layer kept, T={LOW_T}": lambda: lfa.reduce_aliasing(
            lf, slope, threshold=LOW_T, keep_in_focus=True, **analytic).image,
        "ceiling of Algorithm 2: the ground-truth level map": lambda: fuse_levels(lfa.refocus(lf, slope), truth),
        "ceiling of Algorithm 2: the same, on the truly aliased pixels only": lambda: fuse_levels(
            lfa.refocus(lf, slope), np.where(aliased, truth, 0)),
    }


def region_scores(image, reference, regions):
    row = []
    for measure in (metrics.psnr, metrics.ssim):
        for mask in regions.values():
            row.append(f"{measure(image, reference, mask=mask):.2f}" if mask is None or mask.any() else "-")
    gradient = metrics.gradient_difference(image, reference)
    row += [f"{gradient.mean:.4f}", f"{gradient.variance:.5f}"]
    return row


def evaluate(name, lf, slope, reference, disparity, repeats, images):
    naive = lfa.refocus(lf, slope)
    # in focus: a point moves less than half a pixel between neighbouring views
    in_focus = np.abs(disparity - slope) * view_spacing(lf.positions) < 0.5
    aliased = aliasing_truth(naive, reference)
    regions = {"all": None, "in focus": in_focus, "in focus, not aliased": in_focus & ~aliased, "aliased": aliased}
    rows = []
    plain = lfa.LightField(lf.data, lf.positions, {"source": name}, weights=lf.weights)  # no truth in meta
    estimate = lfa.estimate_disparity(plain)
    for label, render in methods(plain, slope, disparity, aliased, estimate).items():
        image = render()
        median, _ = median_iqr(timings(render, repeats, warmup=0))
        rows.append([label] + region_scores(image, reference, regions) + [f"{median * 1e3:.0f}"])
        images[label] = image
    images["reference"] = reference
    share = {key: (1.0 if mask is None else float(mask.mean())) for key, mask in regions.items()}
    header = (["method"] + [f"PSNR {k} ({share[k]:.0%})" for k in regions] + [f"SSIM {k}" for k in regions]
              + ["grad. diff. mean", "grad. diff. var", "ms"])
    return f"### {name}\n\n" + table(header, rows)


def mosaic(images, path, size=256):
    """Side by side: the methods and the reference, each shrunk to ``size`` px wide."""
    import imageio.v3 as iio

    tiles = []
    for image in images.values():
        step = max(1, image.shape[1] // size)
        tiles.append(np.clip(image[::step, ::step], 0, 1))
    iio.imwrite(path, (np.concatenate(tiles, axis=1) * 255).round().astype(np.uint8))
    return " | ".join(images)


def hci_cases(step):
    lf = lfa.load(HCI)
    disparity = lf.meta["disparity"]
    keep = list(range(0, lf.grid_shape[0], step))
    sparse = lf.subset(keep, keep)
    cases = {}
    for label, q in (("near", 90), ("far", 10)):
        slope = float(np.percentile(disparity, q))
        cases[f"HCI antinous, {len(keep)}x{len(keep)} of 9x9 views, {label} focus (slope {slope:.2f})"] = (
            sparse, slope, lfa.refocus(lf, slope), disparity)
    return cases


def speed(size, repeats):
    """Section 2: the reductions of 8x8xsize x size x3, against the memory floor."""
    scene = brick_room(n_views=8, size=size, seed=0)
    lf = lfa.LightField(scene.lightfield.data, scene.lightfield.positions, {"source": "brick room"})
    floor, _ = median_iqr(memory_floor(lf.data, repeats))
    rows = [["floor: data.sum(axis=(0, 1))", f"{floor * 1e3:.1f}", "1.0", ""]]
    estimate = lfa.estimate_disparity(lf)
    t, t_iqr = median_iqr(timings(lambda: lfa.estimate_disparity(lf), repeats, warmup=0))
    rows.append(["estimate_disparity (once per light field)", f"{t * 1e3:.0f} ± {t_iqr * 1e3:.0f}", f"{t / floor:.1f}",
                 ""])
    for slope in (4.0, -4.0):
        detector = lfa.AliasingDetector(lf, disparity=estimate)
        runs = {
            "default (depth), disparity given": lambda: lfa.reduce_aliasing(lf, slope, disparity=estimate),
            "default (depth), detector kept (a new slope)": lambda: lfa.reduce_aliasing(
                lf, slope, detector=detector),
            "antialiased_refocus, disparity given": lambda: lfa.antialiased_refocus(lf, slope, estimate),
            "Algorithm 2, exact Cv, T=0.02": lambda: lfa.reduce_aliasing(lf, slope, method="analytic"),
            f"Algorithm 2, exact Cv, T={LOW_T}": lambda: lfa.reduce_aliasing(lf, slope, method="analytic",
                                                                            threshold=LOW_T),
        }
        for label, run in runs.items():
            result = run()
            if "detector kept" in label:  # what a slider move costs: the per-slope caches are cold
                t_all = []
                for _ in range(repeats):
                    detector.guide._keep(None)
                    t_all.append(timings(run, 1, warmup=0)[0])
                t, t_iqr = median_iqr(t_all)
            else:
                t, t_iqr = median_iqr(timings(run, repeats))
            share = "" if isinstance(result, np.ndarray) else f"{(result.level > 0).mean():.1%}"
            rows.append([f"{label}, slope {slope:g}", f"{t * 1e3:.0f} ± {t_iqr * 1e3:.0f}", f"{t / floor:.1f}", share])
    return table(["run", "median ms ± IQR/2", "x floor", "pixels changed"], rows)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=512, help="view size of the brick room (default 512)")
    parser.add_argument("--hci-step", type=int, default=4, help="keep every STEP-th HCI view row/column (4: 3x3)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", default="benchmarks/results/reduction.md")
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)

    scene = brick_room(n_views=8, size=args.size, seed=0)
    cases = {f"brick room 8x8, {args.size} px, {label} in focus (slope {slope:g})": (
        scene.lightfield, slope, scene.reference(slope, interpolation="bilinear"), scene.disparity)
        for label, slope in (("cube", 4.0), ("back wall", -4.0))}
    if HCI.is_dir():
        cases.update(hci_cases(args.hci_step))
    sections = []
    for i, (name, (lf, slope, reference, disparity)) in enumerate(cases.items()):
        print(name, flush=True)
        images = {}
        sections.append(evaluate(name, lf, slope, reference, disparity, args.repeats, images))
        picture = out.with_name(f"{out.stem}_{i}.png")
        order = mosaic(images, picture)
        sections.append(f"Left to right: {order}.\n\n![{name}]({picture.name})")
    print("speed", flush=True)
    sections.append(f"## Speed (8x8x{args.size}x{args.size}x3, median of {args.repeats})\n\n"
                    + speed(args.size, args.repeats))
    sections.append("## Notes (written by hand, kept when re-run)\n\n" + kept_notes(out))
    write_report(out, "Aliasing reduction against the baselines (the paper's Figure 6, measured)",
                 ["## Accuracy"] + sections)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
