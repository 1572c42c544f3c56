"""How much of the accuracy benchmark's aliasing no method can find: checker walls a period off.

A light field of the accuracy benchmark whose covering layer, the wall
behind everything, is a checkerboard (the holdout's "noise over a
checkerboard, 3x3", and the fresh scenes drawn so) gives the same views,
to a fraction of a camera's noise (:data:`SAME_VIEWS_ATOL`), with that
wall moved by a whole period of its texture per view step: every view's
image of it moves by whole periods, and the layers in front hide the same
pixels. The light field is the same; what a dense aperture records is not
(the wall blurred by a different amount), nor which pixels of the naive
refocus are aliased. No method that reads the views can tell those scenes
apart, so a pixel aliased in one of them and not in another cannot be
found but by chance.

For each such light field (the holdout's and about one fresh scene in
eleven) this finds the shifts that leave the views the same (up to two
periods either way; :data:`PERIODS`), and at each of its slopes compares
three truths: the benchmark's (aliased in the scene as drawn), the
aliasing every one of those scenes shows ("determinable"), and the rest
("ambiguous": aliased in some of them only). The default detection
(``reduce_aliasing`` with the light field's own estimate, as
``bench_accuracy.py`` runs it) is scored against the benchmark's truth and
against the determinable one with the ambiguous pixels left out; the
default reduction's gain in PSNR on the aliased pixels likewise.

Run::

    .venv/bin/python benchmarks/periodic_ambiguity.py --out benchmarks/results/periodic_ambiguity.md \\
        [--splits fresh-a,fresh-b] [--images benchmarks/results/periodic_ambiguity.png]
"""

from __future__ import annotations

import argparse
import functools
import itertools
import time

import numpy as np

import napari_lfalias as lfa
from napari_lfalias import metrics

from _harness import detection_counts, kept_notes, pooled_f1, table, write_report
from accuracy_cases import FRESH_SEEDS, checkerboard_case, fresh_case, fresh_draw
from bench_accuracy import MANY_ALIASED

#: A checker's period along each axis is two cells; the benchmark's cells are 3 to 6 px
#: (``napari_lfalias.synthetic.TEXTURES["checker"]``), so these are the shifts (px per view step) tried first.
CHECKER_PERIODS = (6.0, 8.0, 10.0, 12.0)
#: Whole periods either way a wall is moved to (each kept only where the views stay the same: the seam of
#: the texture, outside every view as drawn, may come into view further out).
PERIODS = (-2, -1, 1, 2)
#: Views this close (in units of the white level) are the same: the float32 rounding of a texture evaluated at
#: another disparity (the holdout's checkerboard moved by a period: 5e-7 at most), carried through a camera's
#: effects (fresh scene 1204, Bayer mosaic and over-exposure: 1.0e-3), is a fraction of the benchmark's read
#: noise alone (1e-3 to 5e-3), where a shift that is not a period changes them by 0.1 or more.
SAME_VIEWS_ATOL = 2e-3


def views_differ(case, other):
    """How much two cases' light fields differ: the largest difference of their samples, inf where their
    weights differ."""
    a, b = case.lightfield, other.lightfield
    same_weights = (a.weights is None and b.weights is None) or (
        a.weights is not None and b.weights is not None and np.array_equal(a.weights, b.weights))
    return float(np.abs(np.asarray(a.data) - np.asarray(b.data)).max()) if same_weights else float("inf")


def same_views(case, other):
    """Whether two cases' light fields hold the same samples (to :data:`SAME_VIEWS_ATOL`) and weights."""
    return views_differ(case, other) <= SAME_VIEWS_ATOL


def alias_worlds(case, moved):
    """The cases whose views equal ``case``'s: its covering checker wall moved by :data:`PERIODS` periods
    (``moved(shift)``: the case with the wall moved by ``shift``), the period the first of
    :data:`CHECKER_PERIODS` that leaves the views as they are (none: ``[]``)."""
    for period in CHECKER_PERIODS:
        one = moved(period)
        if same_views(case, one):
            break
    else:
        return []
    worlds = []
    for count in PERIODS:
        other = one if count == 1 else moved(count * period)
        if same_views(case, other):
            worlds.append(other)
    return worlds


def checker_wall_cases(splits):
    """``(case, moved)`` (as :func:`alias_worlds` takes them) of the holdout's checkerboard and of every scene
    of the fresh ``splits`` whose covering layer is a checker wall."""
    yield checkerboard_case(), functools.partial(checkerboard_case, 256)
    for split in splits:
        for seed in FRESH_SEEDS[split]:
            if fresh_draw(seed).layers[-1][1] == "checker":
                yield fresh_case(seed, split), functools.partial(fresh_case, seed, split, 256)


def _psnr_gain(image, naive, reference, where):
    if not where.any():
        return float("nan")
    return metrics.psnr(image, reference, mask=where) - metrics.psnr(naive, reference, mask=where)


def judge_case(case, moved):
    """Rows of one case (one per slope), or ``[]`` where its covering wall has no alias (:func:`alias_worlds`)."""
    worlds = alias_worlds(case, moved)
    if not worlds:
        return []
    lf = case.lightfield
    estimate = lfa.estimate_disparity(lf)
    differ = max(views_differ(case, world) for world in worlds)
    rows = []
    for slope in case.slopes:
        naive = lfa.refocus(lf, slope)
        truth = case.truth(slope, naive)
        others = [world.truth(slope, naive) for world in worlds]
        determinable = np.logical_and.reduce([truth] + others)
        clean_everywhere = ~np.logical_or.reduce([truth] + others)
        ambiguous = ~(determinable | clean_everywhere)
        result = lfa.reduce_aliasing(lf, slope, disparity=estimate)
        mask, reference = result.detections[0].mask, case.reference(slope)
        known = ~ambiguous
        plain = metrics.precision_recall_f1(mask, truth)
        judged = metrics.precision_recall_f1(mask[known], determinable[known])
        rows.append({
            "case": case.name, "split": case.split, "slope": slope,
            "worlds": ", ".join(world.name.rsplit(" ", 1)[-1] for world in worlds),
            "differ": differ,
            "aliased": float(truth.mean()), "determinable": float(determinable.mean()),
            "unfindable": float((truth & ~determinable).mean()),
            "ambiguous": float(ambiguous.mean()), "plain": plain, "judged": judged,
            "counts": [detection_counts(mask, truth), detection_counts(mask[known], determinable[known])],
            "gain": (_psnr_gain(result.image, naive, reference, truth),
                     _psnr_gain(result.image, naive, reference, determinable)),
            "images": (naive, reference, worlds[int(np.argmin([other.mean() for other in others]))].reference(slope),
                       result.image, truth, determinable, mask),
        })
    return rows


def summary(rows):
    """The summary table: the holdout's case and the fresh scenes, over every slope and over the slopes at
    least :data:`MANY_ALIASED` aliased."""
    out = []
    groups = [("holdout", [r for r in rows if r["split"] == "holdout"]),
              ("fresh", [r for r in rows if r["split"] != "holdout"])]
    for (group, members), many in itertools.product(groups, (False, True)):
        chosen = [r for r in members if r["aliased"] >= MANY_ALIASED] if many else members
        if not chosen:
            continue
        label = f"{group}, " + (f"slopes >= {MANY_ALIASED:.0%} aliased" if many else "every slope")
        out.append([label, len(chosen), *(f"{np.mean([r[key] for r in chosen]):.3f}"
                                          for key in ("aliased", "determinable", "ambiguous", "unfindable")),
                    *(f"{np.mean([getattr(r[truth], score) for r in chosen]):.2f}"
                      for score in ("recall", "f1") for truth in ("plain", "judged")),
                    *(f"{pooled_f1([r['counts'][which] for r in chosen]):.2f}" for which in (0, 1))])
    return table(["slopes", "n", "aliased", "determinable", "ambiguous", "aliased, not determinable", "recall",
                  "recall, determinable", "mean F1", "mean F1, determinable", "pooled F1", "pooled F1, determinable"],
                 out)


def per_slope(rows):
    return table(["scene", "slope", "same views with the wall at", "views differ by", "aliased", "determinable",
                  "ambiguous", "aliased, not determinable", "F1", "F1, determinable", "dPSNR aliased",
                  "dPSNR determinable"],
                 [[r["case"], f"{r['slope']:+.1f}", r["worlds"], f"{r['differ']:.1e}", f"{r['aliased']:.3f}",
                   f"{r['determinable']:.3f}",
                   f"{r['ambiguous']:.3f}", f"{r['unfindable']:.3f}", f"{r['plain'].f1:.2f}", f"{r['judged'].f1:.2f}",
                   f"{r['gain'][0]:+.2f}", f"{r['gain'][1]:+.2f}"] for r in rows])


def save_panels(path, row):
    """One slope as a PNG: the naive refocus, the dense aperture of the scene as drawn and of the alias scene
    least aliased, the default reduction; below, the truth, the determinable truth and the detection."""
    from PIL import Image

    naive, reference, alias_reference, reduced, truth, determinable, mask = row["images"]

    def rgb(image):
        return (np.clip(image, 0, 1) * 255).astype(np.uint8)

    def grey(flags):
        return np.repeat((flags * 255).astype(np.uint8)[..., None], 3, axis=-1)

    top = np.concatenate([rgb(naive), rgb(reference), rgb(alias_reference), rgb(reduced)], axis=1)
    bottom = np.concatenate([grey(truth), grey(determinable), grey(mask), np.zeros_like(rgb(naive))], axis=1)
    Image.fromarray(np.concatenate([top, bottom], axis=0)).save(path)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="benchmarks/results/periodic_ambiguity.md")
    parser.add_argument("--splits", default=",".join(FRESH_SEEDS), help="comma-separated fresh splits")
    parser.add_argument("--images", help="PNG of the slope with the largest share aliased as drawn and not "
                                         "determinable")
    args = parser.parse_args()
    rows, worst, start = [], None, time.perf_counter()
    splits = args.splits.split(",")
    for split in splits:
        if split not in FRESH_SEEDS:
            parser.error(f"--splits: {split!r} is not a fresh split ({', '.join(FRESH_SEEDS)})")
    for case, moved in checker_wall_cases(splits):
        for row in judge_case(case, moved):
            rows.append(row)
            print(f"{row['case'][:50]:50s} {row['slope']:+.1f} aliased {row['aliased']:.3f} determinable "
                  f"{row['determinable']:.3f} ambiguous {row['ambiguous']:.3f} F1 {row['plain'].f1:.2f} -> "
                  f"{row['judged'].f1:.2f}", flush=True)
            if args.images is None or (worst is not None and worst["unfindable"] >= row["unfindable"]):
                del row["images"]  # only the slope to be drawn keeps its images
            else:
                if worst is not None:
                    del worst["images"]
                worst = row
    if not rows:
        raise SystemExit("no scene of these splits has a checker wall with a period alias")
    sections = [f"{len({r['case'] for r in rows})} light fields, {len(rows)} slopes, "
                f"{time.perf_counter() - start:.0f} s.", "## Summary", summary(rows), "## Notes", kept_notes(args.out),
                "## Per slope", per_slope(rows)]
    if worst is not None:
        save_panels(args.images, worst)
        sections.insert(3, f"![{worst['case']} at {worst['slope']:+.1f}: naive, dense aperture as drawn, dense "
                           f"aperture with the wall a period off (same views), default; truth, determinable truth, "
                           f"detection]({args.images.rsplit('/', 1)[-1]})")
    write_report(args.out, "Aliasing no method can find: checker walls a period off", sections)


if __name__ == "__main__":
    main()
