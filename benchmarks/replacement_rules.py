"""Compare rules for which pixels the default reduction replaces, without re-running the benchmark.

The accuracy benchmark (``bench_accuracy.py``) takes most of an hour; a
rule of the default reduction (``reduce.replaced_pixels``: thresholds of
the cautious score against the rendering's edge spread) changes only
which pixels take a rendering that is the same under every rule. So the
rendering, the scores and what the rule reads are made once per slope
and written to a folder (``dump``), and any set of the rule's parameters
is then judged in seconds on those files (``evaluate``), against the
naive refocus, as the benchmark judges the default: PSNR overall, where
aliased and on the clean pixels. Choose on some splits' dumps, report on
others (``bench_accuracy.py`` for the numbers that count).

Run::

    .venv/bin/python benchmarks/replacement_rules.py dump --split tune --out /tmp/rules/tune
    .venv/bin/python benchmarks/replacement_rules.py evaluate /tmp/rules/tune \\
        --faint-fraction 0.125 0.25 --faint-margin 4

``evaluate --check`` first verifies that the package's own constants give
back the default reduction's images exactly (the dump holds them).
"""

from __future__ import annotations

import argparse
import itertools
from pathlib import Path

import numpy as np

import napari_lfalias as lfa
from napari_lfalias import depth_guided, metrics
from napari_lfalias.baselines import view_spacing
from napari_lfalias.depth_guided import DepthGuide
from napari_lfalias.reduce import replaced_pixels

#: What ``evaluate`` varies, with the package's values as defaults.
PARAMETERS = {"replace_fraction": "REPLACE_FRACTION", "faint_fraction": "FAINT_FRACTION",
              "faint_margin": "FAINT_MARGIN"}


def dump_slope(lf, slope, reference, truth, estimate, path):
    """Write what :func:`replaced_pixels` reads at ``slope`` and what judging it needs to ``path`` (npz)."""
    detector = lfa.AliasingDetector(lf, disparity=estimate)
    result = lfa.reduce_aliasing(lf, slope, detector=detector)
    guide = detector.guide
    np.savez_compressed(path, slope=slope, disparity=estimate.disparity, spacing=view_spacing(lf.positions),
                        reference=reference.astype(np.float32), truth=truth, naive=result.refocused,
                        default=result.image, rendering=guide.scored_rendering(slope).image,
                        score=guide.cautious_scores(slope), spread=guide.edge_spread(slope),
                        faint_where=guide.faint_where(slope))


def dump(splits, out, size=256):
    """Dump every slope of the benchmark's cases of ``splits`` into ``out`` (one npz per slope, skipping
    those already there, so that an interrupted dump resumes)."""
    from accuracy_cases import all_cases

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    for split in splits:
        for case in all_cases(size=size, split=split):
            estimate = None
            for slope in case.slopes:
                path = out / f"{_file_name(case.name)}_{slope:+.2f}.npz"
                if path.exists():
                    continue
                estimate = lfa.estimate_disparity(case.lightfield) if estimate is None else estimate
                naive = lfa.refocus(case.lightfield, slope)
                dump_slope(case.lightfield, slope, case.reference(slope), case.truth(slope, naive), estimate,
                           path)
                print(f"{path.name}", flush=True)


def _file_name(name):
    return "".join(c if c.isalnum() else "_" for c in name)


def judge(record, mask):
    """PSNR differences (dB) against the naive refocus overall, where aliased and on the clean pixels
    (NaN where a region is empty) of the image the rule's ``mask`` makes, and the share it replaces."""
    image = DepthGuide.blend(record["naive"], record["rendering"], mask)
    truth = record["truth"]
    out = []
    for region in (None, truth, ~truth):
        if region is not None and not region.any():
            out.append(np.nan)
            continue
        out.append(metrics.psnr(image, record["reference"], mask=region)
                   - metrics.psnr(record["naive"], record["reference"], mask=region))
    return out + [float(mask.mean())]


def rule_mask(record, threshold=depth_guided.THRESHOLD, **parameters):
    """The pixels :func:`replaced_pixels` replaces in ``record`` with ``parameters`` (package defaults
    for those not given)."""
    return replaced_pixels(record["score"], record["spread"], threshold, record["faint_where"], **parameters)


def evaluate(folders, grid, check=False):
    """Rows ``(parameters, results (n_slopes, 4))`` for every combination of ``grid`` (name -> values)."""
    records = [dict(np.load(path)) for folder in folders for path in sorted(Path(folder).glob("*.npz"))]
    if not records:
        raise SystemExit(f"no dumps (*.npz) in {', '.join(map(str, folders))}")
    if check:
        for record in records:
            image = DepthGuide.blend(record["naive"], record["rendering"], rule_mask(record))
            if not np.array_equal(image, record["default"]):
                raise SystemExit("the package's rule does not give back the dumped default images: dump again")
    names = list(grid)
    rows = []
    for values in itertools.product(*(grid[name] for name in names)):
        parameters = dict(zip(names, values))
        rows.append((parameters, np.array([judge(r, rule_mask(r, **parameters)) for r in records])))
    return rows


def report(rows):
    """A markdown table of :func:`evaluate`'s rows."""
    lines = ["| rule | slopes | min all | min clean | mean aliased | mean all | below -0.1 all | below -0.1 clean "
             "| >= +3 aliased | share replaced |", "|" + "---|" * 10]
    for parameters, a in rows:
        name = ", ".join(f"{k} {v:g}" for k, v in parameters.items())
        lines.append(f"| {name} | {len(a)} | {np.nanmin(a[:, 0]):+.2f} | {np.nanmin(a[:, 2]):+.2f} "
                     f"| {np.nanmean(a[:, 1]):+.2f} | {np.nanmean(a[:, 0]):+.2f} | {int(np.sum(a[:, 0] < -0.1))} "
                     f"| {int(np.sum(a[:, 2] < -0.1))} | {int(np.sum(a[:, 1] >= 3))} | {np.mean(a[:, 3]):.3f} |")
    return "\n".join(lines)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True)
    make = commands.add_parser("dump", help="render and score every slope of some splits once")
    make.add_argument("--split", nargs="+", required=True, help="benchmark splits (tune, holdout, fresh-a, ...)")
    make.add_argument("--out", required=True, type=Path)
    make.add_argument("--size", type=int, default=256)
    judge_ = commands.add_parser("evaluate", help="judge rules on dumped slopes")
    judge_.add_argument("folders", nargs="+", type=Path)
    for name, constant in PARAMETERS.items():
        judge_.add_argument("--" + name.replace("_", "-"), type=float, nargs="+",
                            default=[getattr(depth_guided, constant)])
    judge_.add_argument("--check", action="store_true", help="first verify the dumps against the package")
    args = parser.parse_args(argv)
    if args.command == "dump":
        dump(args.split, args.out, args.size)
    else:
        print(report(evaluate(args.folders, {name: getattr(args, name) for name in PARAMETERS}, args.check)))


if __name__ == "__main__":
    main()
