"""What weighing a vignette across each view's cell costs the dense-aperture renderer, and what it buys.

Under a calibrated vignette the renderer weighs each tap of a blurred
surface's box by the weights interpolated between the view and its
neighbours (``_render_kernels._across_cell``, stop 41); before, each view's
cell counted by its own sample's weight alone. Both are timed here in the
same run on one vignetted light field (the per-cell weighting by clearing
the shifted views' ``graded`` flag): the composite of the layers, and the
whole default reduction with the disparity estimated once beforehand. Their
accuracy with the true disparity is judged against the vignetted dense
aperture (``synthetic.camera.reference_through``).

Run::

    .venv/bin/python benchmarks/bench_vignette_render.py --out benchmarks/results/vignette_render.md
"""

from __future__ import annotations

import argparse

import napari_lfalias as lfa
from napari_lfalias import metrics, render
from napari_lfalias.render import SlopeRenderer
from napari_lfalias.synthetic import layered_scene
from napari_lfalias.synthetic.camera import capture, reference_through

from _harness import median_iqr, table, timings, write_report

CAMERA = {"vignetting": 0.8, "calibrated": True, "seed": 3}
SLOPE = 1.0


def _per_cell(composite):
    """``render._composite`` with each view's cell at its own sample's weight (``graded`` cleared)."""
    def wrapped(layers, *args, **kwargs):
        layers.stack.graded = False
        return composite(layers, *args, **kwargs)
    return wrapped


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=512, help="view size (default 512)")
    parser.add_argument("--views", type=int, default=8, help="views a side (default 8)")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", default="benchmarks/results/vignette_render.md")
    args = parser.parse_args(argv)
    scene = layered_scene([(4.0, "tiles", (0.2, 0.6, 0.2, 0.6)), (-3.0, "bricks", None)], n_views=args.views,
                          size=args.size, seed=3)
    lf = capture(scene.lightfield, **CAMERA)
    lf = lfa.LightField(lf.data, lf.positions, weights=lf.weights)  # no ground truth in meta
    reference = reference_through(scene, SLOPE, **CAMERA)
    naive = lfa.refocus(lf, SLOPE)
    estimate = lfa.estimate_disparity(lf)
    original = render._composite
    rows, seconds = [], {}
    for label, composite in (("across the cell (default)", original), ("per cell (before stop 41)", _per_cell(original))):
        render._composite = composite
        try:
            renderer = SlopeRenderer(lf, SLOPE)
            layers = renderer.layers(scene.disparity)
            composite_s = median_iqr(timings(lambda: renderer.composite(layers, trust=False), args.repeats))
            reduce_s = median_iqr(timings(lambda: lfa.reduce_aliasing(lf, SLOPE, disparity=estimate), args.repeats))
            psnr = metrics.psnr(renderer.composite(layers, trust=False).image, reference)
        finally:
            render._composite = original
        seconds[label] = (composite_s[0], reduce_s[0])
        rows.append([label, "%.3f ± %.3f" % composite_s, "%.3f ± %.3f" % reduce_s, f"{psnr:.2f}"])
    (c0, r0), (c1, r1) = seconds.values()
    setup = (f"Scene: tiles at +4 before bricks at -3, {args.views}x{args.views} views of {args.size} px, calibrated "
             f"vignetting {CAMERA['vignetting']}, slope {SLOPE}. Times: median ± IQR/2 of {args.repeats} (after one "
             f"untimed call), both ways in this run. Naive refocus against the vignetted dense aperture: "
             f"{metrics.psnr(naive, reference):.2f} dB.")
    results = table(["weights", "composite, s", "default reduction (disparity given), s",
                      "rendering, true disparity, PSNR dB"], rows)
    ratio = f"Ratio across / per cell: composite {c0 / c1:.2f}x, reduction {r0 / r1:.2f}x."
    path = write_report(args.out, "Weighing a vignette across each view's cell: cost and accuracy",
                        [setup, results, ratio])
    print(path.read_text())


if __name__ == "__main__":
    main()
