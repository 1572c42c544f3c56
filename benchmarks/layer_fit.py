"""What a layered fit of the light field could render: two layers fitted to the views, then a dense aperture.

The renderer (:mod:`napari_lfalias.render`) counts every view's sample whole
to one surface. Along a defocused occluder's soft outline that costs it 1.5
to 34 dB against the naive refocus (``outline_error.py``). This measures, on
two-layer scenes with the true disparity, a model that keeps the mix:

    V_u(p) = P(p - r_f q_u) + (1 - a(p - r_f q_u)) G(p - r_b q_u)

``V_u`` view ``u``'s samples shifted for the slope, ``q_u`` its position,
``r_f``, ``r_b`` the residual disparities of the occluder and the
background, ``P = a O`` the occluder premultiplied by its share ``a`` and
``G`` the background, each in its own frame. ``P`` and ``a`` (near the
occluder's outline; 1 and the samples inside it, 0 outside) and ``G`` are
fitted by alternating least squares, the occluder's mask in the disparity
map the prior of ``a`` (weight :data:`PRIOR`); then the dense aperture is
ray-traced through them, :data:`OVERSAMPLE` squared points of every view's
cell. Resampling is cubic (bilinear taps blurred the fine textures by 5-9 dB
where both layers are defocused).

A prototype: two layers, the true disparity, no vignetting, scipy's
``map_coordinates`` (tens of seconds a scene). Judged within the inner
image (12 px off the edge: the prototype does nothing about the edge) on
the band within 6 px of the depth edge, everywhere, and where aliased.

Run::

    .venv/bin/python benchmarks/layer_fit.py --out benchmarks/results/layer_fit.md
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
from scipy import ndimage

import napari_lfalias as lfa
from napari_lfalias import metrics
from napari_lfalias.baselines import view_spacing
from napari_lfalias.refocus import shift_views
from napari_lfalias.synthetic import layered_scene

from _harness import kept_notes, table, write_report
from outline_error import error_image, outline_band

#: How far (px) from the occluder's edge in the disparity map its share is fitted (beyond: 0 or 1).
NEAR_PX = 8.0
#: Weight of the prior share (the disparity map's mask) against the views' evidence.
PRIOR = 1e-3
ITERATIONS = 8
#: Aperture points per view cell and axis when ray-tracing the dense aperture.
OVERSAMPLE = 6
#: Judged this far (px) from the image's edge.
MARGIN = 12
#: (occluder texture, background texture, views per side, occluder and background disparity, slope)
CASES = [
    ("noise", "stripes", 3, 1.6, -2.0, -2.0),
    ("smooth", "stripes", 3, 1.6, -2.0, -2.0),
    ("noise", "stripes", 3, 1.6, -2.0, -1.0),
    ("fine", "bricks", 3, 3.0, -2.0, -2.0),
    ("fine", "bricks", 3, 3.0, -2.0, 0.5),
    ("bricks", "noise", 5, 3.0, -2.0, -2.0),
    ("bricks", "noise", 5, 3.0, -2.0, 3.0),
    ("lines", "tiles", 4, -4.0, 3.0, 3.0),
    ("lines", "tiles", 4, -4.0, 3.0, -1.0),
]
SEEDS = range(3)


def shifted(image, dy, dx, order=3):
    """``image`` (Y, X[, C]) sampled at ``(y + dy, x + dx)``, the nearest edge value beyond it; with ``order`` 3,
    ``image`` holds the cubic spline's coefficients (:func:`splined`), made once for its many shifts."""
    grid = np.mgrid[0:image.shape[0], 0:image.shape[1]].astype(np.float64)
    where = [grid[0] + dy, grid[1] + dx]

    def one(plane):
        return ndimage.map_coordinates(plane, where, order=order, mode="nearest", prefilter=False)

    return one(image) if image.ndim == 2 else np.stack([one(image[..., c]) for c in range(image.shape[-1])], axis=-1)


def splined(image):
    """The cubic spline coefficients of ``image`` (Y, X[, C]) that :func:`shifted` samples."""
    if image.ndim == 2:
        return ndimage.spline_filter(image, order=3, mode="nearest")
    return np.stack([ndimage.spline_filter(image[..., c], order=3, mode="nearest")
                     for c in range(image.shape[-1])], axis=-1)


def _background_start(values, weights, positions, near, r_front, r_back):
    """``G`` from the samples whose occluder point lies clear of ``near``, in the background's frame (where
    none does, the nearest that is)."""
    total = np.zeros(values.shape[1:])
    count = np.zeros(values.shape[1:3])
    for u, (qy, qx) in enumerate(positions):
        clear = (shifted(near.astype(np.float64), -r_front * qy, -r_front * qx, order=0) < 0.5) * weights[u]
        total += shifted(splined(clear[..., None] * values[u]), r_back * qy, r_back * qx)
        count += shifted(splined(clear), r_back * qy, r_back * qx)
    known = count > 1e-6
    background = total / np.maximum(count, 1e-9)[..., None]
    nearest = ndimage.distance_transform_edt(~known, return_distances=False, return_indices=True)
    return background[nearest[0], nearest[1]]


def _fit_occluder(values, weights, positions, background, prior_share, fitted, r_front, r_back):
    """``(P, a)``: each occluder point's samples regressed on the background behind them in each view
    (``values``, ``weights``: the views' spline coefficients, ``background``: ``G``'s)."""
    seen = np.stack([shifted(values[u], r_front * qy, r_front * qx) for u, (qy, qx) in enumerate(positions)])
    weight = np.stack([shifted(weights[u], r_front * qy, r_front * qx) for u, (qy, qx) in enumerate(positions)])
    behind = np.stack([shifted(background, (r_front - r_back) * qy, (r_front - r_back) * qx)
                       for qy, qx in positions])
    total = np.maximum(weight.sum(0), 1e-9)
    mean_seen = (weight[..., None] * seen).sum(0) / total[..., None]
    mean_behind = (weight[..., None] * behind).sum(0) / total[..., None]
    covariance = (weight * ((seen - mean_seen) * (behind - mean_behind)).sum(-1)).sum(0) / total
    variance = (weight * ((behind - mean_behind) ** 2).sum(-1)).sum(0) / total
    prior = 1.0 - prior_share
    through = np.clip((covariance + PRIOR * prior) / (variance + PRIOR), 0.0, 1.0)  # 1 - a
    through = np.where(fitted, through, prior)
    premultiplied = np.where((prior_share > 0.5)[..., None] | fitted[..., None],
                             mean_seen - through[..., None] * mean_behind, 0.0)
    return premultiplied, 1.0 - through


def _fit_background(values, weights, positions, premultiplied, share, previous, r_front, r_back):
    """``G``: each background point's samples less the occluder's part, over the share the occluder leaves
    (every array but ``previous``: spline coefficients)."""
    total = np.zeros(values.shape[1:])
    count = np.zeros(values.shape[1:3])
    for u, (qy, qx) in enumerate(positions):
        dy, dx = (r_back - r_front) * qy, (r_back - r_front) * qx
        weight = shifted(weights[u], r_back * qy, r_back * qx)
        through = 1.0 - shifted(share, dy, dx)
        total += (weight * through)[..., None] * (shifted(values[u], r_back * qy, r_back * qx)
                                                  - shifted(premultiplied, dy, dx))
        count += weight * through * through
    seen = count > 0.05
    return np.where(seen[..., None], total / np.maximum(count, 1e-9)[..., None], previous)


def layered_rendering(lf, slope, disparity, front, back):
    """The dense aperture at ``slope`` through the two layers fitted to ``lf`` (module notes)."""
    r_front, r_back = front - slope, back - slope
    positions = lf.flat_positions().astype(np.float64)
    spacing = view_spacing(lf.positions)
    pad = int(math.ceil(max(abs(r_front), abs(r_back)) * np.abs(positions).max() + abs(r_front) * spacing)) + 10
    stack = shift_views(lf, slope, pad)
    values, weights = stack.values.astype(np.float64), stack.weights.astype(np.float64)
    prior_share = np.pad(np.isclose(disparity, front), pad, mode="edge").astype(np.float64)
    near = ndimage.distance_transform_edt(prior_share < 0.5) <= NEAR_PX
    fitted = near & (ndimage.distance_transform_edt(prior_share > 0.5) <= NEAR_PX)
    background = _background_start(values, weights, positions, near, r_front, r_back)
    values, weights = np.stack([splined(v) for v in values]), np.stack([splined(w) for w in weights])
    for _ in range(ITERATIONS):
        premultiplied, share = _fit_occluder(values, weights, positions, splined(background), prior_share, fitted,
                                             r_front, r_back)
        background = _fit_background(values, weights, positions, splined(premultiplied), splined(share), background,
                                     r_front, r_back)
    premultiplied, share, background = splined(premultiplied), splined(share), splined(background)
    image = np.zeros(values.shape[1:])
    steps = ((np.arange(OVERSAMPLE) + 0.5) / OVERSAMPLE - 0.5) * spacing
    for qy0, qx0 in positions:
        for qy in qy0 + steps:
            for qx in qx0 + steps:
                through = 1.0 - shifted(share, -r_front * qy, -r_front * qx)
                image += (shifted(premultiplied, -r_front * qy, -r_front * qx)
                          + through[..., None] * shifted(background, -r_back * qy, -r_back * qx))
    image /= len(positions) * OVERSAMPLE ** 2
    return image[pad:-pad, pad:-pad].astype(np.float32)


def judged(case, seed):
    """PSNR (dB) of the naive refocus, the renderer and the layered fit (true disparity each) in the band, the
    inner image and where aliased (NaN where under 20 px are), the aliased share, and the images."""
    front_texture, back_texture, n_views, front, back, slope = case
    scene = layered_scene([(front, front_texture, (0.25, 0.75, 0.25, 0.75)), (back, back_texture, None)],
                          n_views=n_views, size=96, seed=seed)
    lf, reference = scene.lightfield, scene.reference(slope, interpolation="exact")
    images = (lfa.refocus(lf, slope), lfa.antialiased_refocus(lf, slope, scene.disparity),
              layered_rendering(lf, slope, scene.disparity, front, back))
    inner = np.zeros(reference.shape[:2], bool)
    inner[MARGIN:-MARGIN, MARGIN:-MARGIN] = True
    band = outline_band(scene.disparity, 6) & inner
    aliased = metrics.aliased_pixels(images[0], reference) & inner
    psnr = [metrics.psnr(image, reference, mask=region) if region.sum() >= 20 else np.nan
            for region in (band, inner, aliased) for image in images]
    return psnr + [float(aliased.mean())], images + (reference,)


def save_images(path, images, gain=20.0):
    """Naive, renderer, layered fit and reference (top), the first three's errors times ``gain`` (bottom)."""
    import imageio.v3 as iio

    reference = images[-1]
    crop = (slice(MARGIN, -MARGIN), slice(MARGIN, -MARGIN))

    top = np.concatenate([np.clip(image[crop], 0, 1) for image in images], axis=1)
    bottom = np.concatenate([np.clip(error_image(image, reference, gain)[crop], 0, 1) for image in images[:-1]]
                            + [np.zeros_like(reference[crop])], axis=1)
    picture = np.repeat(np.repeat(np.concatenate([top, bottom], axis=0), 2, 0), 2, 1)
    iio.imwrite(path, (picture * 255).round().astype(np.uint8))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=None, help="write the report here (markdown)")
    args = parser.parse_args(argv)
    rows, shown = [], None
    for case in CASES:
        results = []
        for seed in SEEDS:
            numbers, images = judged(case, seed)
            results.append(numbers)
            if case == CASES[3] and seed == SEEDS[0]:
                shown = images
        mean = np.nanmean(np.array(results, float), axis=0)
        front_texture, back_texture, n_views, front, back, slope = case
        rows.append([f"{front_texture} {front:+.1f} / {back_texture} {back:+.1f}", f"{n_views}x{n_views}",
                     f"{slope:+.1f}"] + ["-" if np.isnan(v) else f"{v:.1f}" for v in mean[:9]] + [f"{mean[9]:.1%}"])
        print(*rows[-1], flush=True)
    head = ["occluder / background", "views", "slope", "band: naive", "renderer", "layers", "inner: naive",
            "renderer", "layers", "aliased: naive", "renderer", "layers", "aliased"]
    summary = (f"## PSNR (dB) against the dense reference, true disparity, mean of seeds {SEEDS.start}-"
               f"{SEEDS.stop - 1} (96 px scenes; band: within 6 px of the depth edge)\n\n" + table(head, rows))
    print(summary)
    if args.out is not None:
        picture = args.out.with_suffix(".png")
        save_images(picture, shown)
        front_texture, back_texture, n_views, front, back, slope = CASES[3]
        caption = (f"![naive, renderer, layered fit, reference; errors x20]({picture.name}) ({front_texture} "
                   f"{front:+.1f} over {back_texture} {back:+.1f}, {n_views}x{n_views} views, slope {slope:+.1f}, "
                   f"seed {SEEDS.start}; top: naive, renderer, layered fit, reference; bottom: their errors x20)")
        sections = [summary, caption, "## Notes (written by hand, kept when re-run)\n\n" + kept_notes(args.out)]
        write_report(args.out, "A layered fit of the light field against the renderer (prototype)", sections)


if __name__ == "__main__":
    main()
