"""Accuracy of aliasing detection and reduction on data that looks like users' data.

For every case of :mod:`accuracy_cases` (layered synthetic scenes with
several kinds of texture, camera effects, and real HCI sub-grids) and every
slope: the ground truth of aliasing is where the sparse refocus differs from
the dense-aperture reference by more than 2 % relative luminance after a
1 px blur (:func:`napari_lfalias.metrics.aliased_pixels`; on synthetic
scenes both are evaluated exactly, see :mod:`accuracy_cases`). Each method's
image is scored by PSNR and SSIM over the image, the aliased and the clean
pixels; each detector by ROC AUC of its score and F1 of its mask; and the
time of each is measured.

Methods:

- ``naive``: :func:`napari_lfalias.refocus`;
- ``default``: :func:`napari_lfalias.reduce_aliasing` at its defaults
  (disparity-guided, ``method="depth"``);
- ``paper``: ``reduce_aliasing(preset="paper")`` (Algorithm 1 Monte Carlo,
  T = 0.02, Algorithm 2 as published);
- ``analytic T=...``: the exact Cv with Algorithm 2 at a lower threshold;
- ``rendering, estimated disparity``: :func:`napari_lfalias.antialiased_refocus`
  with the default's estimate, every pixel rendered (the issue "Beyond the
  paper"'s renderer as a user calls it);
- ``rendering, true disparity``: the dense-aperture renderer given the
  ground-truth disparity everywhere (the ceiling of the renderer).

Run::

    .venv/bin/python benchmarks/bench_accuracy.py --out benchmarks/results/accuracy.md

It takes about 2.2 hours in one process on two cores (19 slopes a minute),
under 1.9 with ``--workers 2`` (the cases shared between two processes of
this script; 26 a minute, stop 57).
Each case is kept as it is judged (``accuracy.md.progress`` beside the
report, ``.progress.K`` for worker ``K``); a run stopped part way continues
where it was with the same command and ``--resume``, and makes only the
cases it has not judged.

A sweep of the focus over the real sub-grids (``accuracy_real_sweep.md``)::

    .venv/bin/python benchmarks/bench_accuracy.py --cases hci --slopes -3 -2.5 -2 -1.5 -1 -0.5 0 0.5 1 1.5 2 2.5 \
        3 3.5 4 --out benchmarks/results/accuracy_real_sweep.md
"""

from __future__ import annotations

import argparse
import pickle
import subprocess
import sys
import time
import zlib
from pathlib import Path

import numpy as np

import napari_lfalias as lfa
from napari_lfalias import metrics

from _harness import detection_counts, kept_notes, pooled_f1, table, write_report
from accuracy_cases import all_cases

ANALYTIC_T = 0.005
#: Slopes with at least this share of their pixels aliased are summarised apart ("mean F1, >= 1 % aliased").
MANY_ALIASED = 0.01
POOLED_NOTE = (
    "The mean F1 weighs every slope alike: a slope with a handful of aliased pixels, or none (F1 is 1 only where "
    "nothing is flagged), counts as much as one with half its image aliased. The mean over the slopes at least "
    f"{MANY_ALIASED:.0%} aliased, and the pooled F1 (the pixels of every slope of the split counted together), say "
    "how much of the aliasing a user sees is found.")


def _timed(func):
    start = time.perf_counter()
    value = func()
    return value, time.perf_counter() - start


def _scores(image, reference, regions):
    out = {}
    for key, mask in regions.items():
        out[f"psnr {key}"] = out[f"ssim {key}"] = float("nan")
        if mask is None or mask.any():
            out[f"psnr {key}"] = metrics.psnr(image, reference, mask=mask)
            try:
                out[f"ssim {key}"] = metrics.ssim(image, reference, mask=mask)
            except lfa.ParameterError:  # the region lies within the SSIM window of the border
                pass
    return out


def _detection(score, mask, truth):
    out = {"auc": float("nan"), "f1": metrics.precision_recall_f1(mask, truth).f1,
           "counts": detection_counts(mask, truth)}
    if truth.any() and (~truth).any():
        out["auc"] = metrics.roc_auc(score, truth)
    return out


def evaluate(case, slope, images_dir=None):
    """All methods on one (case, slope); returns rows of numbers."""
    lf = case.lightfield
    reference = case.reference(slope).astype(np.float32)
    naive = lfa.refocus(lf, slope)
    truth = case.truth(slope, naive)
    regions = {"all": None, "aliased": truth, "clean": ~truth}
    results = {}
    # the disparity is estimated once per light field; its time is reported apart
    if "estimate" not in case.extra:
        case.extra["estimate"], case.extra["estimate_s"] = _timed(lambda: lfa.estimate_disparity(lf))
    res, seconds = _timed(lambda: lfa.reduce_aliasing(lf, slope, disparity=case.extra["estimate"]))
    results["default"] = (res.image, seconds, res.cv, res.detections[0].mask)
    res, seconds = _timed(lambda: lfa.reduce_aliasing(lf, slope, preset="paper", seed=0))
    results["paper"] = (res.image, seconds, res.cv, res.detections[0].mask)
    res, seconds = _timed(lambda: lfa.reduce_aliasing(lf, slope, method="analytic", threshold=ANALYTIC_T))
    results[f"analytic T={ANALYTIC_T}"] = (res.image, seconds, res.cv, res.detections[0].mask)
    rendering, seconds = _timed(lambda: lfa.antialiased_refocus(lf, slope, case.extra["estimate"]))
    results["rendering, estimated disparity"] = (rendering, seconds, None, None)
    if case.disparity is not None:
        rendering, seconds = _timed(lambda: lfa.antialiased_refocus(lf, slope, case.disparity))
        results["rendering, true disparity"] = (rendering, seconds, None, None)
    rows = []
    naive_scores = _scores(naive, reference, regions)
    no_detection = {"auc": float("nan"), "f1": float("nan"), "counts": None}
    rows.append({"method": "naive", **naive_scores, "seconds": 0.0, **no_detection})
    for name, (image, seconds, score, mask) in results.items():
        row = {"method": name, **_scores(image, reference, regions), "seconds": seconds}
        row.update(_detection(score, mask, truth) if score is not None else no_detection)
        rows.append(row)
    if images_dir is not None and (not case.split.startswith("fresh") or _default_loses(rows)):
        _save_images(images_dir, case, slope, naive, results["default"][0], reference, truth,
                     results["default"][3], case.extra["estimate"].disparity)
    return rows, float(truth.mean())


def _pooled_f1(items):
    """F1 of the detections of ``items`` taken together: their pixels counted over every slope."""
    counts = [i["counts"] for i in items if i["counts"] is not None]
    return f"{pooled_f1(counts):+.2f}" if counts else "-"


def _default_loses(rows, margin=0.1):
    """Whether the default is more than ``margin`` dB below the naive refocus overall or on the clean pixels
    (the random scenes' images are kept only then: 60 scenes' images would weigh some 100 MB)."""
    naive, default = rows[0], next(r for r in rows if r["method"] == "default")
    return any(default[k] < naive[k] - margin for k in ("psnr all", "psnr clean"))


def _save_images(folder, case, slope, naive, ours, reference, truth, mask, disparity):
    import imageio.v3 as iio

    folder.mkdir(parents=True, exist_ok=True)

    def grey(x):
        return np.repeat(np.clip(x, 0, 1)[..., None], 3, axis=-1)

    lo, hi = np.percentile(disparity, [1, 99])
    # red: missed, green: found, blue: flagged where nothing aliases
    masks = np.stack([truth & ~mask, truth & mask, mask & ~truth], axis=-1).astype(np.float32)
    top = np.concatenate([naive, ours, reference], axis=1)
    top = np.repeat(top, 3 // top.shape[-1], axis=-1)  # grey (lenslet) cases as RGB
    bottom = np.concatenate([masks, grey((disparity - lo) / max(hi - lo, 1e-6)),
                             grey(np.abs(ours - reference).max(-1) * 10)], axis=1)
    image = np.clip(np.concatenate([top, bottom], axis=0), 0, 1)
    signed = f"{slope:+.2f}".replace("+", "p").replace("-", "m")  # +4 and -4 get files of their own
    name = "".join(c if c.isalnum() else "_" for c in f"{case.name}_{signed}")[:80]
    path = folder / f"{name}.png"
    iio.imwrite(path, (image * 255).round().astype(np.uint8))
    return path


def _strong_aliasing_table(strong, goal=3.0):
    """How many slopes with aliased pixels gain ``goal`` dB there, by the default and by the true-disparity
    rendering (what the renderer reaches when the disparity is right)."""
    head = ["split", "slopes with aliased pixels", f"default >= +{goal:g} dB where aliased",
            f"true-disparity rendering >= +{goal:g} dB", "default, where the rendering reaches it",
            "default below naive - 0.1 dB where aliased"]
    body = []
    for split in dict.fromkeys(s for s, _, _ in strong):
        gains = np.array([(d, t) for s, d, t in strong if s == split], float)
        reached = gains[:, 1] >= goal
        body.append([split, str(len(gains)), str(int((gains[:, 0] >= goal).sum())), str(int(reached.sum())),
                     f"{int((gains[reached, 0] >= goal).sum())} of {int(reached.sum())}",
                     str(int((gains[:, 0] < -0.1).sum()))])
    return (f"Slopes where aliasing is, and the issue's +{goal:g} dB goal where aliased (a case without a true "
            "disparity counts as not reached by the rendering):\n\n" + table(head, body))


def _judge_case(case, slopes, images_dir):
    """Every method on ``case`` at ``slopes``: its report section, its summary items and its strong-aliasing
    gains, as one record (what an interrupted run keeps; see ``--resume``)."""
    lines = [f"### {case.name} ({case.split})", "", case.notes, ""]
    summary = []  # ((split, method), item) per slope and method
    strong = []  # (split, default's gain where aliased, the true-disparity rendering's) per slope with aliasing
    for slope in slopes:
        rows, share = evaluate(case, slope, images_dir)
        header = ["method", "PSNR all", "PSNR aliased", "PSNR clean", "SSIM all", "SSIM aliased", "SSIM clean",
                  "AUC", "F1", "s"]
        body = [[r["method"]] + [f"{r[k]:.2f}" for k in ("psnr all", "psnr aliased", "psnr clean", "ssim all",
                                                         "ssim aliased", "ssim clean", "auc", "f1", "seconds")]
                for r in rows]
        lines += [f"slope {slope:+.2f}: {share:.1%} aliased", "", table(header, body), ""]
        naive = rows[0]
        gains = {r["method"]: r["psnr aliased"] - naive["psnr aliased"] for r in rows[1:]}
        if share > 0:
            strong.append((case.split, gains["default"], gains.get("rendering, true disparity", float("nan"))))
        for r in rows[1:]:
            summary.append(((case.split, r["method"]),
                            {k: r[k] - naive[k] for k in ("psnr all", "psnr aliased", "psnr clean")}
                            | {"auc": r["auc"], "f1": r["f1"], "counts": r["counts"], "share": share}))
        print(case.name, slope, " | ".join(f"{r['method']}: {r['psnr all'] - naive['psnr all']:+.2f} "
                                            f"al {r['psnr aliased'] - naive['psnr aliased']:+.2f} "
                                            f"cl {r['psnr clean'] - naive['psnr clean']:+.2f} "
                                            f"auc {r['auc']:.2f} f1 {r['f1']:.2f}" for r in rows[1:]), flush=True)
    if "estimate_s" in case.extra:
        lines += [f"disparity estimated in {case.extra['estimate_s']:.2f} s", ""]
    return {"case": case.name, "section": "\n".join(lines), "summary": summary, "strong": strong}


def _progress_file(out, worker=None):
    """Where a run writing ``out`` keeps each judged case as it goes (removed when the run starts afresh);
    ``worker``: where worker ``worker`` of a ``--workers`` run keeps its own."""
    return out.with_name(out.name + ".progress" + ("" if worker is None else f".{worker}"))


def _records(path):
    """The records kept in the progress file ``path``, by case name (none if there is no such file)."""
    records = {}
    if path.exists():
        with path.open("rb") as progress:
            while True:
                try:
                    record = pickle.load(progress)
                except (EOFError, pickle.UnpicklingError):  # the end, or the case being written when stopped
                    break
                records[record["case"]] = record
    return records


def _resumed(out):
    """The cases an interrupted run writing ``out`` had judged, by name (none if it kept no progress)."""
    if out is None:
        raise SystemExit("--resume needs --out: the progress is kept beside the report")
    records = _records(_progress_file(out))
    print(f"resuming: {len(records)} cases already judged ({_progress_file(out)})", flush=True)
    return records


def _worker_share(worker):
    """``k`` of ``--worker k/n``, and which cases worker ``k`` judges: those whose name's CRC-32 is ``k`` modulo
    ``n``."""
    k, n = (int(part) for part in worker.split("/"))
    return k, lambda name: zlib.crc32(name.encode()) % n == k


def _run_workers(argv, args):
    """Judge the cases in ``args.workers`` processes of this script (``--worker k/n``, each resuming from the
    run's progress and keeping its own), then gather what they kept into the run's progress file."""
    out, n = args.out, args.workers
    resume = [] if args.resume else ["--resume"]
    # the last --workers given is the one argparse keeps: each worker runs as one process
    workers = [subprocess.Popen([sys.executable, __file__, *argv, *resume, "--workers", "1", "--worker", f"{k}/{n}"])
               for k in range(n)]
    failed = [k for k, worker in enumerate(workers) if worker.wait() != 0]
    with _progress_file(out).open("ab") as progress:
        for k in range(n):
            for record in _records(_progress_file(out, k)).values():
                pickle.dump(record, progress)
            _progress_file(out, k).unlink(missing_ok=True)
    if failed:
        raise SystemExit(f"workers {failed} failed; what every worker judged is kept: run again with --resume")


def _judge_the_rest(args, done, images_dir):
    """Judge the cases ``args`` asks for that ``done`` (records by name) lacks, adding each to ``done`` and to the
    progress file as it is judged; the names of every case asked for, in the benchmark's order. Only the cases
    judged are made (the random scenes; the fixed ones are made together)."""
    worker, mine = _worker_share(args.worker) if args.worker else (None, None)
    keep = _progress_file(args.out, worker) if args.out is not None else None
    if mine is not None and keep is not None:
        done |= _records(keep)
    order = []

    def wanted(name):
        if args.cases is not None and args.cases.lower() not in name.lower():
            return False
        if mine is not None and not mine(name):
            return False
        order.append(name)
        return name not in done

    for case in all_cases(args.size, split=args.split, named=wanted):
        done[case.name] = _judge_case(case, args.slopes or case.slopes, images_dir)
        if keep is not None:
            with keep.open("ab") as progress:
                pickle.dump(done[case.name], progress)
    return order


def main(argv=None):
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=256, help="view size of the synthetic scenes")
    parser.add_argument("--out", type=Path, default=None, help="write the report here (markdown)")
    parser.add_argument("--split", default=None,
                        help="only this split (tune, holdout, real, real-wider, fresh-a to fresh-af)")
    parser.add_argument("--cases", default=None, help="only cases whose name contains this (case-insensitive)")
    parser.add_argument("--slopes", type=float, nargs="+", default=None,
                        help="judge every case at these slopes instead of its own (a sweep of the focus; "
                             "no images are written)")
    parser.add_argument("--resume", action="store_true",
                        help="keep the cases an interrupted run of the same code judged (kept beside --out) "
                             "and judge only the rest")
    parser.add_argument("--workers", type=int, default=1,
                        help="judge the cases in this many processes (needs --out; each case takes one core "
                             "or so: about 26 slopes a minute on two cores against 19 for one)")
    parser.add_argument("--worker", default=None, help=argparse.SUPPRESS)  # k/n: one of those processes
    args = parser.parse_args(argv)
    if args.workers < 1:
        raise SystemExit(f"--workers must be at least 1, not {args.workers}")
    if args.workers > 1 and args.out is None:
        raise SystemExit("--workers needs --out: the workers keep what they judge beside the report")
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
    images_dir = None if args.out is None or args.slopes else args.out.parent / "accuracy"
    if images_dir is not None and not (args.split or args.cases or args.resume or args.worker):
        for stale in images_dir.glob("fresh_*.png"):  # a random scene's images are kept only while the
            stale.unlink()                            # default loses there
    if args.out is not None and not (args.resume or args.worker):
        for kept in (_progress_file(args.out), *args.out.parent.glob(_progress_file(args.out).name + ".*")):
            kept.unlink(missing_ok=True)
    if args.workers > 1:
        _run_workers(argv, args)
        args.resume = True
    done = _resumed(args.out) if args.resume else {}
    order = _judge_the_rest(args, done, images_dir)
    if args.worker:
        return
    records = [done[name] for name in order]
    sections = [r["section"] for r in records]
    summary = {}
    for record in records:
        for key, item in record["summary"]:
            summary.setdefault(key, []).append(item)
    strong = [s for r in records for s in r["strong"]]
    head = ["split", "method", "cases", "min dPSNR all", "min dPSNR clean", "mean dPSNR aliased", "min dPSNR aliased",
            "mean AUC", "mean F1", "min F1", f"mean F1, >= {MANY_ALIASED:.0%} aliased", "pooled F1"]
    rows = []
    for (split, method), items in summary.items():
        def col(key, fn, among=items):
            values = np.array([i[key] for i in among], float)
            values = values[np.isfinite(values)]
            return f"{fn(values):+.2f}" if values.size else "-"
        rows.append([split, method, str(len(items)), col("psnr all", np.min), col("psnr clean", np.min),
                     col("psnr aliased", np.mean), col("psnr aliased", np.min), col("auc", np.mean),
                     col("f1", np.mean), col("f1", np.min),
                     col("f1", np.mean, [i for i in items if i["share"] >= MANY_ALIASED]), _pooled_f1(items)])
    summary_md = ("## Summary (differences against the naive refocus, dB)\n\n" + table(head, rows) + "\n\n"
                  + POOLED_NOTE + "\n\n" + _strong_aliasing_table(strong))
    print(summary_md)
    if args.out is not None:
        notes = "## Notes (written by hand, kept when re-run)\n\n" + kept_notes(args.out)
        write_report(args.out, "Accuracy of aliasing detection and reduction", [summary_md, notes] + sections)
        _progress_file(args.out).unlink(missing_ok=True)


if __name__ == "__main__":
    main()
