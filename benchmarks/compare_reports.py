"""Two accuracy reports of the same cases compared slope by slope: a change measured on every slope it touches.

``bench_accuracy.py`` run from two trees (before and after a change, each
``PYTHONPATH=<tree>/src``) writes two reports; this prints, for the default
reduction and the renderer with the estimated disparity, the mean gain over
the naive refocus before and after (overall, where aliased, on clean pixels),
how many slopes fall below naive - 0.1 dB, and every slope that moved by
more than ``--margin`` dB.

Run::

    python benchmarks/compare_reports.py before.md after.md [--margin 0.3]
"""

from __future__ import annotations

import argparse
import re

import numpy as np

#: The rows of a slope's table this reads, and the prefix of their gains' keys (``"default all"``, ...).
METHODS = {"default": "default ", "rendering, estimated disparity": "rendering "}
PARTS = ("all", "aliased", "clean")


def slopes_of(path):
    """``{(case, slope): {"share": %, "default all": dB, ...}}``: each method's gain over the naive refocus."""
    out, case, slope, share, table = {}, None, None, None, {}
    for line in open(path).read().splitlines():
        if line.startswith("### "):
            case = line[4:]
        found = re.match(r"slope ([-+0-9.]+): ([0-9.]+)% aliased", line)
        if found:
            slope, share, table = float(found.group(1)), float(found.group(2)), {}
        found = re.match(r"\| (naive|default|rendering, estimated disparity) \| (.*)", line)
        if found and case is not None:
            table[found.group(1)] = [float(v) for v in found.group(2).strip(" |").split(" | ")[:3]]
            if all(name in table for name in ("naive", *METHODS)):
                row = {"share": share}
                for method, prefix in METHODS.items():
                    for part, value, naive in zip(PARTS, table[method], table["naive"]):
                        row[prefix + part] = value - naive
                out[(case, slope)] = row
                table = {}
    return out


def summary(rows, prefix):
    """Mean gains and the slopes below naive - 0.1 dB of one method (``prefix``: its keys')."""
    get = {part: np.array([r[f"{prefix}{part}"] for r in rows], float) for part in PARTS}
    aliased = get["aliased"][np.isfinite(get["aliased"])]
    return (f"overall {np.nanmean(get['all']):+.2f}, where aliased {aliased.mean():+.2f}, clean "
            f"{np.nanmean(get['clean']):+.2f} dB; below naive - 0.1 dB: {int((get['all'] < -0.1).sum())} overall, "
            f"{int((get['clean'] < -0.1).sum())} on clean pixels (least {np.nanmin(get['all']):+.2f} / "
            f"{np.nanmin(get['clean']):+.2f})")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("before", help="the report before the change")
    parser.add_argument("after", help="the report after it")
    parser.add_argument("--margin", type=float, default=0.3, help="list the slopes that moved by more (dB)")
    args = parser.parse_args(argv)
    before, after = slopes_of(args.before), slopes_of(args.after)
    keys = [key for key in before if key in after]
    print(f"{len(keys)} slopes in both reports")
    for method, prefix in METHODS.items():
        print(f"- {method}: before {summary([before[k] for k in keys], prefix)}")
        print(f"  after {summary([after[k] for k in keys], prefix)}")
    print(f"\nSlopes whose default moved by more than {args.margin:g} dB (overall / where aliased / clean):\n")
    print("| case | slope | aliased | before | after |\n|---|---|---|---|---|")
    for key in keys:
        old, new = before[key], after[key]
        moved = [abs(new[f"default {p}"] - old[f"default {p}"]) for p in PARTS]
        if any(np.isfinite(m) and m > args.margin for m in moved):
            cells = [" / ".join(f"{r[f'default {p}']:+.2f}" for p in PARTS) for r in (old, new)]
            print(f"| {key[0]} | {key[1]:+.2f} | {old['share']:.1f} % | {cells[0]} | {cells[1]} |")


if __name__ == "__main__":
    main()
