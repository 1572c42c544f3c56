"""Where the coarse level loses a texture: the estimate, and the default reduction, with and without the rule.

The estimator sweeps every slope on a coarse pyramid level and, at full
resolution, only the slopes the coarse estimate around each tile allows.
Fine stripes or checkers near the coarse level's Nyquist rate leave its
cost flat there, so the sure pixels around set the tile's slopes, and a
surface at another depth was never tried (fresh 2613, 2211). A tile where
the coarse level keeps under :data:`~napari_lfalias.disparity.LOST_TEXTURE_KEPT`
of such a texture's variance sweeps every slope, and a slope beyond its
neighbours' wins only where the views clearly prefer it
(``disparity._clearly_beyond``). This finds every case of the accuracy
benchmark whose estimate the rule changes, and at each of its slopes
measures the default reduction given each estimate (as ``bench_accuracy.py``
runs it); the estimate's time with and without the rule is reported too. A
case the rule does not change has the same results either way.

Run::

    .venv/bin/python benchmarks/lost_texture.py --out benchmarks/results/lost_texture.md \\
        [--splits tune,holdout,fresh-a]
"""

from __future__ import annotations

import contextlib
import time

import numpy as np

import napari_lfalias as lfa
from napari_lfalias import disparity

from _harness import kept_notes, median_iqr, table, write_report
from accuracy_cases import all_cases
from periodic_outlines import arguments, compared, per_slope, summary


@contextlib.contextmanager
def rule(on):
    """The rule on (as the package has it) or off (no tile sweeps beyond what the coarse estimate allows)."""
    kept = disparity.LOST_TEXTURE_SHARE
    if not on:
        disparity.LOST_TEXTURE_SHARE = np.inf
    try:
        yield
    finally:
        disparity.LOST_TEXTURE_SHARE = kept


def timed_estimate(lf):
    start = time.perf_counter()
    estimate = lfa.estimate_disparity(lf)
    return estimate, time.perf_counter() - start


def changed_cases(split):
    """Rows for each slope of each case of ``split`` whose estimate the rule changes; the changed cases'
    estimate times and share of pixels moved by more than 0.5 px; and the number of cases and slopes."""
    rows, cases, n_cases, n_slopes = [], [], 0, 0
    for case in all_cases(split=split):
        n_cases += 1
        n_slopes += len(case.slopes)
        estimates, seconds = {}, {}
        for on in (True, False):
            with rule(on):
                estimates[on], seconds[on] = timed_estimate(case.lightfield)
        if np.array_equal(estimates[False].disparity, estimates[True].disparity):
            continue
        moved = np.abs(estimates[True].disparity - estimates[False].disparity) > 0.5
        record = {"split": split, "case": case.name.split(":")[0], "seconds": seconds, "moved": float(moved.mean())}
        if case.disparity is not None:
            record["off"] = {on: float(np.mean(np.abs(estimates[on].disparity - case.disparity) > 0.5))
                             for on in (False, True)}
        cases.append(record)
        rows += [compared(split, case, slope, rule, estimates) for slope in case.slopes]
    return rows, cases, n_cases, n_slopes


def case_table(cases):
    return table(("split", "case", "pixels moved > 0.5 px", "off the truth by > 0.5 px: without -> with",
                  "estimate s: without -> with"),
                 [(c["split"], c["case"], f"{100 * c['moved']:.1f} %",
                   f"{100 * c['off'][False]:.1f} -> {100 * c['off'][True]:.1f} %" if "off" in c else "-",
                   f"{c['seconds'][False]:.2f} -> {c['seconds'][True]:.2f}") for c in cases])


def main():
    args = arguments(__doc__, "benchmarks/results/lost_texture.md")
    start = time.perf_counter()
    rows, cases, n_cases, n_slopes = [], [], 0, 0
    for split in args.splits.split(","):
        split_rows, split_cases, split_n_cases, split_n_slopes = changed_cases(split)
        rows += split_rows
        cases += split_cases
        n_cases += split_n_cases
        n_slopes += split_n_slopes
    ratio = [c["seconds"][True] / c["seconds"][False] for c in cases]
    sections = [f"Splits: {args.splits}; {time.perf_counter() - start:.0f} s. Gains in dB over the naive refocus "
                "(PSNR against the dense aperture), the default reduction given each estimate.",
                "## Summary",
                f"The rule changes the estimate of {len(cases)} of {n_cases} cases"
                + (" (the estimate's time with the rule over without, median ± IQR/2: {:.2f} ± {:.2f})."
                   .format(*median_iqr(ratio)) if cases else ".")
                + " " + summary(rows, n_slopes, changes="the estimate the reduction is given"),
                "## Notes", kept_notes(args.out),
                "## Cases the rule changes", case_table(cases) if cases else "(none)",
                "## Slopes of those cases", per_slope(rows) if rows else "(none)"]
    write_report(args.out, "Where the coarse level loses a texture", sections)


if __name__ == "__main__":
    main()
