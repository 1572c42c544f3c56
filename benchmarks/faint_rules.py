"""Variants of the default reduction's faint rule, judged on the dumps of ``replacement_rules.py``.

The faint rule (:data:`napari_lfalias.depth_guided.FAINT_FRACTION`) replaces
pixels whose cautious score is below ``T`` but above ``T/8`` and four times
the rendering's edge spread: the ghosts of a fine or dim texture. It gains
1-2.4 dB where aliased on every split, but where the rendering's own error
is above ``T/8`` (the naive refocus at 56-66 dB, the rendering below it with
the true disparity too) it replaces a speckle of pixels for the worse: most
of the slopes that end below the naive refocus on the random splits. Each
variant here keeps a pixel of the faint rule (one not connected to a flagged
pixel) only where:

- ``density``: at least ``share`` of the pixels in a ``window`` px square
  around it are faint too (a pattern, not a speckle);
- ``area``: its 8-connected region of replaced pixels holds ``area`` pixels;
- ``image share``: the faint pixels are at least ``share`` of the image;
- ``surface share``: at least ``share`` of its surface (the connected region
  of pixels whose estimated ghost spacing rounds to the same px) is faint;
- ``with flags``: the slope has a pixel connected to a flagged one (or, with
  ``share``, its faint pixels are at least that share of the image).

Choose on some splits' dumps and report on others::

    .venv/bin/python benchmarks/replacement_rules.py dump --split tune --out DUMPS/tune   # one folder a split
    .venv/bin/python benchmarks/faint_rules.py --choose DUMPS/tune DUMPS/fresh-ab \\
        --report DUMPS/holdout DUMPS/fresh-ac --out benchmarks/results/faint_rules.md
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from scipy import ndimage

from napari_lfalias import depth_guided

from _harness import kept_notes, table, write_report
from replacement_rules import judge

T = depth_guided.THRESHOLD
#: (name, keyword arguments of :func:`variant`) judged.
VARIANTS = [("default", {}), ("no faint rule", {"off": True})] + [
    (f"density {share:g} in {window} px", {"density": share, "window": window})
    for share, window in ((0.05, 15), (0.1, 9), (0.1, 15), (0.1, 21), (0.1, 31), (0.15, 15), (0.2, 9))] + [
    (f"area {area}", {"area": area}) for area in (4, 9, 25)] + [
    (f"image share {share:g}", {"image_share": share}) for share in (0.02, 0.05)] + [
    (f"surface share {share:g}", {"surface_share": share}) for share in (0.05, 0.1, 0.2)] + [
    ("with flags", {"with_flags": True})] + [
    (f"with flags or image share {share:g}", {"with_flags": True, "image_share": share}) for share in (0.05, 0.2)]


def faint_and_flagged(record):
    """The faint rule's pixels and those connected to a flagged pixel (the rest of the rule), as
    :func:`napari_lfalias.reduce.replaced_pixels` makes them with the package's constants."""
    from napari_lfalias.reduce import replaced_pixels

    score, spread = record["score"], record["spread"]
    everything = replaced_pixels(score, spread, T, record["faint_where"])
    flagged = replaced_pixels(score, spread, T, record["faint_where"], faint_fraction=np.inf)
    faint = ((score > np.float32(depth_guided.FAINT_FRACTION * T))
             & (np.float32(depth_guided.FAINT_MARGIN) * spread < score) & record["faint_where"])
    assert np.array_equal(everything, faint | flagged)
    return faint, flagged


def _large_regions(faint, flagged, area):
    """``faint`` less the 8-connected regions of ``faint | flagged`` under ``area`` pixels that touch no
    flagged pixel."""
    labels, count = ndimage.label(faint | flagged, structure=np.ones((3, 3), bool))
    keep = np.bincount(labels.ravel(), minlength=count + 1) >= area
    keep[np.unique(labels[flagged])] = True
    keep[0] = False
    return faint & keep[labels]


def variant(record, off=False, density=0.0, window=15, area=0, image_share=0.0, surface_share=0.0,
            with_flags=False, parts=None):
    """The pixels replaced under a variant of the faint rule (module notes); ``parts``: the record's
    :func:`faint_and_flagged`, where already made."""
    faint, flagged = faint_and_flagged(record) if parts is None else parts
    if off:
        return flagged
    if with_flags:
        enough = flagged.any() or (image_share and (faint & ~flagged).mean() >= image_share)
        return faint | flagged if enough else flagged
    if density:
        faint = faint & (ndimage.uniform_filter(faint.astype(np.float32), window) >= density)
    if area:
        faint = _large_regions(faint, flagged, area)
    if image_share and (faint & ~flagged).mean() < image_share:
        faint = faint & flagged
    if surface_share:
        ghost = np.round((record["disparity"] - record["slope"]) * float(record["spacing"])).astype(np.int64)
        surfaces = np.zeros(ghost.shape, np.int64)
        for value in np.unique(ghost):
            labels, count = ndimage.label(ghost == value)
            surfaces[labels > 0] = labels[labels > 0] + surfaces.max()
        pixels = np.bincount(surfaces.ravel())
        faint_pixels = np.bincount(surfaces.ravel(), weights=(faint & ~flagged).ravel().astype(np.float64),
                                   minlength=len(pixels))
        faint = faint & ((faint_pixels >= surface_share * pixels)[surfaces] | flagged)
    return faint | flagged


def judged(folders):
    """``{variant name: (n_slopes, 4) array}`` of :func:`replacement_rules.judge` over the dumps in ``folders``
    (each record's faint and flagged pixels made once for every variant)."""
    results = {name: [] for name, _ in VARIANTS}
    for path in (path for folder in folders for path in sorted(Path(folder).glob("*.npz"))):
        record = dict(np.load(path))
        parts = faint_and_flagged(record)
        for name, options in VARIANTS:
            results[name].append(judge(record, variant(record, **options, parts=parts)))
    if not results["default"]:
        raise SystemExit(f"no dumps (*.npz) in {', '.join(map(str, folders))}")
    return {name: np.array(rows) for name, rows in results.items()}


def rows_of(results):
    """Table rows: one per variant, its numbers over the slopes."""
    rows = []
    for name, a in results.items():
        rows.append([name, len(a), f"{np.nanmean(a[:, 1]):+.2f}", f"{np.nanmean(a[:, 0]):+.2f}",
                     f"{np.nanmin(a[:, 0]):+.2f}", f"{np.nanmin(a[:, 2]):+.2f}", int(np.sum(a[:, 0] < -0.1)),
                     int(np.sum(a[:, 2] < -0.1)), f"{np.mean(a[:, 3]):.3f}"])
    return rows


HEAD = ["variant", "slopes", "mean aliased", "mean all", "min all", "min clean", "below -0.1 all",
        "below -0.1 clean", "share replaced"]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--choose", nargs="+", type=Path, required=True, help="dump folders a variant is chosen on")
    parser.add_argument("--report", nargs="+", type=Path, required=True, help="dump folders it is reported on")
    parser.add_argument("--out", type=Path, default=None, help="write the report here (markdown)")
    args = parser.parse_args(argv)
    sections = []
    for role, folders in (("chosen on", args.choose), ("reported on", args.report)):
        each = [judged([folder]) for folder in folders]
        for folder, results in zip(folders, each):
            sections.append(f"### {role} {folder.name}\n\n" + table(HEAD, rows_of(results)))
            print(sections[-1], flush=True)
        if len(folders) > 1:  # the folders' slopes together: their rows, not judged again
            pooled = {name: np.concatenate([results[name] for results in each]) for name in each[0]}
            sections.append(f"### {role}: all of {', '.join(f.name for f in folders)}\n\n"
                            + table(HEAD, rows_of(pooled)))
            print(sections[-1], flush=True)
    if args.out is not None:
        intro = ("PSNR differences (dB) against the naive refocus, as `bench_accuracy.py` judges the default; the "
                 "dumps of `replacement_rules.py` (the rendering and the scores of every slope, made once).")
        write_report(args.out, "Variants of the faint rule", [intro] + sections
                     + ["## Notes (written by hand, kept when re-run)\n\n" + kept_notes(args.out)])


if __name__ == "__main__":
    main()
