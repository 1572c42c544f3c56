"""Where the renderer loses to the naive refocus: the outline of a defocused occluder, with the true disparity.

fresh 3006 (stop 57's unseen split, fresh-ab) is below the naive refocus at
its defaults because the rendering is, even with the true disparity, along
the outline of a defocused square over an in-focus wall. This measures that
error apart, on two-layer scenes (a textured square at +1.6 in front of a
wall at -2.0): the PSNR of the rendering with the true disparity and of the
naive refocus in the band within :data:`BAND_PX` of the depth edge, by the
square's texture, the wall's, the views per side, the slope (the wall in
focus, or both defocused) and the softness of the square's outline (the
synthetic scenes' mask cut-off, :data:`napari_lfalias.synthetic.scenes.MASK_CUTOFF`:
the lower, the softer; 0.18 is the scenes' own).

Run::

    .venv/bin/python benchmarks/outline_error.py --out benchmarks/results/outline_error.md
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
from pathlib import Path

import numpy as np
from scipy import ndimage

import napari_lfalias as lfa
from napari_lfalias import metrics
from napari_lfalias.synthetic import layered_scene, scenes

from _harness import kept_notes, table, write_report

#: How far (px) from the depth edge the band of the outline reaches.
BAND_PX = 6
FRONT, BACK = 1.6, -2.0
SEEDS = range(3)


def outline_band(disparity, px):
    """``(Y, X)`` bool: the pixels within ``px`` of a depth edge of ``disparity``."""
    return ndimage.binary_dilation(ndimage.morphological_gradient(disparity, size=3) > 0.5, iterations=px)


def error_image(image, reference, gain):
    """``image``'s largest channel error against ``reference`` times ``gain``, as grey RGB (unclipped)."""
    return np.repeat(np.abs(image - reference).max(-1, keepdims=True) * gain, 3, -1)


@contextlib.contextmanager
def mask_cutoff(cutoff):
    """The synthetic scenes' outlines at ``cutoff`` (cycles/px) while inside."""
    kept = scenes.MASK_CUTOFF
    scenes.MASK_CUTOFF = cutoff
    try:
        yield
    finally:
        scenes.MASK_CUTOFF = kept


def band_psnr(front, back, n_views, slope, cutoff):
    """Mean over :data:`SEEDS` of the PSNR (dB) in the outline's band of the rendering with the true disparity,
    and of the naive refocus, and the images of the first seed ``(naive, rendering, reference, band)``."""
    values, first = [], None
    for seed in SEEDS:
        with mask_cutoff(cutoff):
            scene = layered_scene([(FRONT, front, (0.25, 0.75, 0.25, 0.75)), (BACK, back, None)], n_views=n_views,
                                  size=96, seed=seed)
            reference = scene.reference(slope, interpolation="exact")
        naive = lfa.refocus(scene.lightfield, slope)
        rendering = lfa.antialiased_refocus(scene.lightfield, slope, scene.disparity)
        band = outline_band(scene.disparity, BAND_PX)
        values.append((metrics.psnr(rendering, reference, mask=band), metrics.psnr(naive, reference, mask=band)))
        first = first or (naive, rendering, reference, band)
    return np.mean(values, axis=0), first


def save_errors(path, images, gain=50.0):
    """The first seed's naive refocus, rendering and reference (top), the first two's errors times ``gain`` and
    the band (bottom), around the square's top left corner, 4x."""
    import imageio.v3 as iio

    naive, rendering, reference, band = images
    crop = (slice(20, 76), slice(8, 48))

    def big(image):
        return np.repeat(np.repeat(np.clip(image[crop], 0, 1), 4, 0), 4, 1)

    top = np.concatenate([big(naive), big(rendering), big(reference)], axis=1)
    shown_band = np.repeat(band[..., None], 3, -1).astype(np.float32)
    bottom = np.concatenate([big(error_image(naive, reference, gain)), big(error_image(rendering, reference, gain)),
                             big(shown_band)], axis=1)
    iio.imwrite(path, (np.concatenate([top, bottom], axis=0) * 255).round().astype(np.uint8))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=None, help="write the report here (markdown)")
    args = parser.parse_args(argv)
    rows, shown = [], None
    grid = itertools.product(("noise", "smooth"), ("stripes", "flat"), (3, 5), (BACK, -1.0), (0.18, 0.05, 0.25))
    for front, back, n_views, slope, cutoff in grid:
        (rendered, naive), images = band_psnr(front, back, n_views, slope, cutoff)
        if (front, back, n_views, slope, cutoff) == ("noise", "stripes", 3, BACK, 0.18):
            shown = images
        rows.append([front, back, f"{n_views}x{n_views}", f"{slope:+.1f}", f"{cutoff:.2f}", f"{rendered:.1f}",
                     f"{naive:.1f}", f"{rendered - naive:+.1f}"])
        print(*rows[-1], flush=True)
    head = ["square", "wall", "views", "slope", "mask cut-off", "rendering, band (dB)", "naive, band (dB)",
            "difference"]
    summary = (f"## The band within {BAND_PX} px of the square's outline (true disparity; mean of seeds "
               f"{SEEDS.start}-{SEEDS.stop - 1}; square at {FRONT:+.1f}, wall at {BACK:+.1f}; 96 px)\n\n"
               + table(head, rows))
    print(summary)
    if args.out is not None:
        picture = args.out.with_suffix(".png")
        save_errors(picture, shown)
        caption = (f"![naive, rendering, reference; the errors x50 of the first two, and the band]({picture.name}) "
                   f"(noise square over stripes, 3x3 views, slope {BACK:+.1f}, seed 0, the square's top left corner)")
        sections = [summary, caption,
                    "## Notes (written by hand, kept when re-run)\n\n" + kept_notes(args.out)]
        write_report(args.out, "The renderer's error along a defocused occluder's outline", sections)


if __name__ == "__main__":
    main()
