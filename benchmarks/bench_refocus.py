"""Refocus, shifted stacks and view moments against the memory floor.

For an 8x8x512x512x3 float32 light field (random data, regular grid,
a slope with sub-pixel shifts) this times, in one run:

- the memory floor: one ``data.sum(axis=(0, 1))`` over the same array;
- ``refocus``, ``shift_views``, ``view_moments`` (on the luminance light
  field, as detection runs it) and ``ShiftedStack.mean`` with a view mask;
- the alternatives: ``scipy.ndimage.shift`` per view (order 1, and the
  default order 3 on a subset of the views, scaled up), OpenCV
  ``warpAffine`` per view (bilinear, 1/32-px fixed-point weights), and
  optionally the previous pure-numpy implementation from git;

and reports medians of ``--repeats`` runs, their ratio to the floor, the
peak memory each call allocates (tracemalloc) and the largest error of
each path against a float64 reference on the interior (where every
view's taps are inside the view). Numba compilation is done (and cached)
before timing.

Run::

    .venv/bin/python benchmarks/bench_refocus.py --out benchmarks/results/refocus.md
"""

from __future__ import annotations

import argparse
import importlib.util
import math
import os
import subprocess
import sys
import tempfile
import tracemalloc
from pathlib import Path

import numpy as np
import numba
from scipy import ndimage

import napari_lfalias as lfa
from napari_lfalias import LightField

from _harness import median_iqr, timings

ROOT = Path(__file__).resolve().parents[1]


def peak_bytes(func):
    tracemalloc.start()
    try:
        func()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def old_module(rev):
    """The ``refocus`` module as it was at git revision ``rev`` (for before/after numbers)."""
    source = subprocess.run(["git", "show", f"{rev}:src/napari_lfalias/refocus.py"], cwd=ROOT,
                            check=True, capture_output=True, text=True).stdout
    path = Path(tempfile.mkdtemp()) / "napari_lfalias" / "_old_refocus.py"
    path.parent.mkdir()
    path.write_text(source)
    spec = importlib.util.spec_from_file_location("napari_lfalias._old_refocus", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def ndimage_refocus(views, shifts, order):
    out = np.zeros(views.shape[1:], np.float32)
    for view, (dy, dx) in zip(views, shifts):
        out += ndimage.shift(view, (-dy, -dx, 0), order=order, mode="constant")
    return out / len(views)


def cv2_refocus(views, shifts):
    import cv2

    out = np.zeros(views.shape[1:], np.float32)
    for view, (dy, dx) in zip(views, shifts):
        # with WARP_INVERSE_MAP, dst(p) = src(M p): sample at p + (dx, dy)
        matrix = np.array([[1, 0, dx], [0, 1, dy]], np.float64)
        size = (view.shape[1], view.shape[0])
        out += cv2.warpAffine(view, matrix, size, flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                              borderMode=cv2.BORDER_CONSTANT)
    return out / len(views)


def reference64(views, shifts):
    """Float64 bilinear refocus (every view weighted 1): the accuracy reference on the interior."""
    out = np.zeros(views.shape[1:], np.float64)
    for view, (dy, dx) in zip(views, shifts):
        out += ndimage.shift(view.astype(np.float64), (-dy, -dx, 0), order=1, mode="constant")
    return out / len(views)


BEGIN, END = "<!-- table: written by bench_refocus.py -->", "<!-- end of table -->"


def write_table(path, table):
    """Put ``table`` between the markers of ``path`` (the rest of the file is kept), atomically."""
    text = path.read_text() if path.exists() else f"# Refocus benchmark\n\n{BEGIN}\n{END}\n"
    if BEGIN not in text or END not in text:
        text = f"{text.rstrip()}\n\n{BEGIN}\n{END}\n"
    head, rest = text.split(BEGIN, 1)
    tail = rest.split(END, 1)[1]
    tmp = path.with_suffix(".tmp")
    tmp.write_text(f"{head}{BEGIN}\n{table}\n{END}{tail}")
    os.replace(tmp, path)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--views", type=int, default=8)
    parser.add_argument("--size", type=int, default=512)
    parser.add_argument("--slope", type=float, default=1.37)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--old", default=None, help="git revision of the previous refocus.py to compare")
    parser.add_argument("--out", type=Path, default=None, help="write the Markdown table here")
    args = parser.parse_args(argv)

    rng = np.random.default_rng(0)
    data = rng.random((args.views, args.views, args.size, args.size, 3), dtype=np.float32)
    lf = LightField(data)
    lum = lf.luminance()
    views = lf.views()
    shifts = args.slope * lf.flat_positions()
    mask = (rng.random(lf.n_views) < 0.7).astype(np.float64)
    stack = lfa.shift_views(lf, args.slope)

    # compile (numba caches to disk) and warm up everything once
    lfa.refocus(lf, args.slope), lfa.view_moments(lum, args.slope), stack.mean(mask)

    margin = math.ceil(np.abs(shifts).max()) + 1
    inner = (slice(margin, -margin), slice(margin, -margin))
    truth = reference64(views, shifts)[inner]

    def error(image):
        return float(np.abs(image[inner] - truth).max())

    rows = []  # (name, seconds, peak bytes, max error or None)

    def measure(name, func, repeats=args.repeats, scale=1.0, err=None):
        seconds = median_iqr(timings(func, repeats, warmup=0))[0] * scale
        rows.append((name, seconds, peak_bytes(func), err))
        print(f"{name:58s} {seconds * 1e3:9.1f} ms", flush=True)

    measure("floor: data.sum(axis=(0, 1)), 3 channels", lambda: data.sum(axis=(0, 1)))
    measure("floor: luminance data.sum(axis=(0, 1)), 1 channel", lambda: lum.data.sum(axis=(0, 1)))
    measure(f"refocus (fused numba kernel, {numba.get_num_threads()} threads)", lambda: lfa.refocus(lf, args.slope),
            err=error(lfa.refocus(lf, args.slope)))
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    measure("refocus, one numba thread", lambda: lfa.refocus(lf, args.slope))
    measure("view_moments, luminance (C=1), one numba thread", lambda: lfa.view_moments(lum, args.slope))
    numba.set_num_threads(threads)
    measure("shift_views (stores n x Y x X x (C+1) float32)", lambda: lfa.shift_views(lf, args.slope))
    measure("ShiftedStack.mean(view mask)", lambda: stack.mean(mask))
    measure("view_moments, luminance (C=1)", lambda: lfa.view_moments(lum, args.slope))
    measure("view_moments, colour (C=3)", lambda: lfa.view_moments(lf, args.slope))
    measure("view_moments from a stored stack (C=3)", lambda: lfa.view_moments(lf, args.slope, stack=stack))
    measure("cv2.warpAffine per view, INTER_LINEAR (no border weights)", lambda: cv2_refocus(views, shifts),
            err=error(cv2_refocus(views, shifts)))
    measure("scipy.ndimage.shift per view, order=1", lambda: ndimage_refocus(views, shifts, 1),
            repeats=max(2, args.repeats // 3), err=error(ndimage_refocus(views, shifts, 1)))
    subset = slice(0, max(1, lf.n_views // 8))
    measure(f"scipy.ndimage.shift per view, order=3 ({lf.n_views // 8} views, scaled x8)",
            lambda: ndimage_refocus(views[subset], shifts[subset], 3), repeats=2, scale=lf.n_views / len(views[subset]))
    if args.old:
        old = old_module(args.old)
        measure(f"previous numpy refocus ({args.old})", lambda: old.refocus(lf, args.slope), repeats=3,
                err=error(old.refocus(lf, args.slope)))
        measure(f"previous numpy shift_views ({args.old})", lambda: old.shift_views(lf, args.slope), repeats=3)
        measure(f"previous numpy view_moments, luminance ({args.old})",
                lambda: old.view_moments(lum, args.slope), repeats=3)

    floor = rows[0][1]
    lines = [
        f"Light field {lf.shape} float32, slope {args.slope} (sub-pixel shifts), "
        f"median of {args.repeats} runs (fewer for the slow alternatives), one process.",
        "",
        "| operation | median (ms) | x floor (3-ch sum) | peak alloc (MiB) | max abs error vs float64 (interior) |",
        "|---|---:|---:|---:|---:|",
    ]
    for name, seconds, peak, err in rows:
        err_text = "" if err is None else f"{err:.1e}"
        lines.append(f"| {name} | {seconds * 1e3:.1f} | {seconds / floor:.2f} | {peak / 2**20:.1f} | {err_text} |")
    table = "\n".join(lines)
    print(table)
    if args.out:
        command = "python benchmarks/bench_refocus.py " + " ".join(argv if argv is not None else sys.argv[1:])
        write_table(args.out, f"Command: `{command}`\n\n{table}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
