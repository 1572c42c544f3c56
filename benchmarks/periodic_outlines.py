"""Where a periodic surface's outline decides its disparity: the default reduction with and without the rule.

The rendering moves a periodic surface a period towards the slope where its
views fit there as well as at its estimate (``DepthGuide._nearest_fits``);
inside the surface they do, at its outline they may not. Where the views
show the moved surface in front at its outline, as only its estimate has
it, the move is undone (``DepthGuide._fronts_kept``). This finds every slope
of the accuracy benchmark whose rendered disparity the rule changes, and
there measures the default reduction (``reduce_aliasing`` given the light
field's own estimate, as ``bench_accuracy.py`` runs it) with the rule and
without it: its gain in PSNR over the naive refocus overall, on the aliased
pixels and on the clean ones. A slope the rule does not change has the
same result either way, so the whole page need not be run again to see
what it does.

Run::

    .venv/bin/python benchmarks/periodic_outlines.py --out benchmarks/results/periodic_outlines.md \\
        [--splits tune,holdout,fresh-a]
"""

from __future__ import annotations

import argparse
import contextlib
import time

import numpy as np

import napari_lfalias as lfa
from napari_lfalias import metrics
from napari_lfalias.depth_guided import DepthGuide

from _harness import kept_notes, table, write_report
from accuracy_cases import FRESH_SEEDS, all_cases

#: Every split of the accuracy benchmark.
SPLITS = ["tune", "holdout", "real", "real-wider", *FRESH_SEEDS]


@contextlib.contextmanager
def rule(on):
    """The rule on (as the package has it) or off (moved periodic surfaces left moved) within the block."""
    kept = DepthGuide._fronts_kept
    if not on:
        DepthGuide._fronts_kept = lambda self, moved_to: moved_to
    try:
        yield
    finally:
        DepthGuide._fronts_kept = kept


def _gains(image, naive, reference, aliased):
    """The gain (dB) of ``image`` over ``naive`` against ``reference``: overall, aliased, clean (NaN: none)."""
    return [metrics.psnr(image, reference, mask=region) - metrics.psnr(naive, reference, mask=region)
            if region is None or region.any() else float("nan") for region in (None, aliased, ~aliased)]


def changed_slopes(split):
    """A row for each slope of ``split`` whose rendered disparity the rule changes, with both reductions' gains;
    and the number of slopes looked at."""
    rows, looked_at = [], 0
    for case in all_cases(split=split):
        estimate = lfa.estimate_disparity(case.lightfield)
        for slope in case.slopes:
            looked_at += 1
            rendered = {}
            for on in (False, True):
                with rule(on):
                    rendered[on] = DepthGuide(case.lightfield, estimate)._rendered_disparity(slope)
            if np.array_equal(rendered[False], rendered[True]):
                continue
            rows.append(compared(split, case, slope, rule, {False: estimate, True: estimate}))
    return rows, looked_at


def compared(split, case, slope, toggle, estimates):
    """The row of one slope: the default reduction's gains with the rule off and on (``toggle(on)``, a
    context manager; ``estimates[on]``, the disparity given to each)."""
    naive, reference = lfa.refocus(case.lightfield, slope), case.reference(slope)
    aliased = case.truth(slope, naive)
    row = {"split": split, "case": case.name.split(":")[0], "slope": slope, "aliased": float(aliased.mean())}
    for on in (False, True):
        with toggle(on):
            image = lfa.reduce_aliasing(case.lightfield, slope, disparity=estimates[on]).image
        row[on] = _gains(image, naive, reference, aliased)
    print(f"{split} {row['case']} {slope:+.2f}: without " + " / ".join(f"{v:+.2f}" for v in row[False])
          + " | with " + " / ".join(f"{v:+.2f}" for v in row[True]), flush=True)
    return row


def _cells(gains):
    return " / ".join("-" if not np.isfinite(value) else f"{value:+.2f}" for value in gains)


def summary(rows, looked_at, changes="the rendered disparity"):
    """The summary paragraph: on how many slopes the rule ``changes`` something and what it did on them."""
    if not rows:
        return f"The rule changes none of the {looked_at} slopes."
    before, after = (np.array([row[on] for row in rows]) for on in (False, True))
    has_aliased = np.isfinite(before[:, 1])
    return (f"The rule changes {changes} on {len(rows)} of {looked_at} slopes. Where aliased "
            f"({int(has_aliased.sum())} of them have aliased pixels): {np.nanmean(before[:, 1]):+.2f} -> "
            f"{np.nanmean(after[:, 1]):+.2f} dB over the naive refocus on average, at least +3 dB on "
            f"{int(np.sum(before[has_aliased, 1] >= 3))} -> {int(np.sum(after[has_aliased, 1] >= 3))}. The largest "
            f"loss overall: {np.min(after[:, 0] - before[:, 0]):+.3f} dB, on clean pixels "
            f"{np.nanmin(after[:, 2] - before[:, 2]):+.3f} dB. Below naive - 0.1 dB overall: "
            f"{int(np.sum(before[:, 0] < -0.1))} -> {int(np.sum(after[:, 0] < -0.1))}; on clean pixels: "
            f"{int(np.sum(np.nan_to_num(before[:, 2]) < -0.1))} -> {int(np.sum(np.nan_to_num(after[:, 2]) < -0.1))}.")


def per_slope(rows):
    """The changed slopes, the largest gain where aliased first."""
    ordered = sorted(rows, key=lambda row: -(np.nan_to_num(row[True][1]) - np.nan_to_num(row[False][1])))
    return table(("split", "case", "slope", "aliased", "without: all / aliased / clean", "with: all / aliased / clean"),
                 [(row["split"], row["case"], f"{row['slope']:+.2f}", f"{100 * row['aliased']:.1f} %",
                   _cells(row[False]), _cells(row[True])) for row in ordered])


def arguments(doc, out):
    """``--out`` (default ``out``) and ``--splits`` of a script whose docstring is ``doc``."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("--out", default=out)
    parser.add_argument("--splits", default=",".join(SPLITS), help="comma-separated splits (default: all)")
    return parser.parse_args()


def main():
    args = arguments(__doc__, "benchmarks/results/periodic_outlines.md")
    start = time.perf_counter()
    rows, looked_at = [], 0
    for split in args.splits.split(","):
        split_rows, split_looked_at = changed_slopes(split)
        rows += split_rows
        looked_at += split_looked_at
    sections = [f"Splits: {args.splits}; {time.perf_counter() - start:.0f} s. Gains in dB over the naive refocus "
                "(PSNR against the dense aperture), the default reduction with the light field's own estimate.",
                "## Summary", summary(rows, looked_at), "## Notes", kept_notes(args.out),
                "## Slopes the rule changes", per_slope(rows) if rows else "(none)"]
    write_report(args.out, "Where a periodic surface's outline decides its disparity", sections)


if __name__ == "__main__":
    main()
