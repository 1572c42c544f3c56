"""Where the default reduction spends its time: per-stage timings of ``reduce_aliasing(lf, slope, disparity=est)``.

The brick room (8x8 views, 512 px, as in ``bench_reduce.py``), its disparity
estimated once and given, so that every run is what a new slope costs
without a detector kept. Each stage is timed exclusive of the stages it
calls (a stage's own time, not its children's), so the rows add up to the
whole call; "rest" is what no stage covers. A stage the code under test
does not have is left out, so the script times older source trees too
(``PYTHONPATH=<tree>/src``).

Run::

    .venv/bin/python benchmarks/profile_reduce.py [--repeats 3] [--estimate est.pkl] \
        [--function antialiased_refocus]

``--estimate`` keeps the estimate in a pickle (made when missing): the
estimate takes a second, the scene most of a minute. ``--function
antialiased_refocus`` times the renderer alone (every pixel rendered, the
same estimate given) instead of the default reduction.
"""

from __future__ import annotations

import argparse
import functools
import importlib
import inspect
import os
import pickle
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

import napari_lfalias as lfa
from napari_lfalias.synthetic import brick_room

from _harness import median_iqr, table

#: ``(module, attribute path, stage)``: what is timed, and the stage it counts to.
STAGES = [
    ("refocus", "refocus", "naive refocus"),
    ("lightfield", "LightField.luminance", "luminance"),
    ("disparity", "FocusTest.__init__", "focus test: features"),
    ("disparity", "FocusTest.__call__", "focus test: sweep"),
    ("baselines", "_larger_is_nearer", "occlusion order"),
    ("refocus", "view_moments", "angular cv"),
    ("depth_guided", "ghosts_reaching", "windows: ghosts reaching"),
    ("depth_guided", "_Windows.__init__", "windows: bounds"),
    ("depth_guided", "_Windows.means", "window means"),
    ("depth_guided", "_Windows.with_mean_of", "window means"),
    ("depth_guided", "moved_edges", "moved edges"),
    ("depth_guided", "predicted_error", "predicted error"),
    ("metrics", "_blurred_luminance", "predicted error"),
    ("metrics", "_relative_difference", "predicted error"),
    ("depth_guided", "DepthGuide.scores", "scores (arithmetic)"),
    ("depth_guided", "DepthGuide.edge_renderings", "edge renderings (setup)"),
    ("render", "shift_views", "shifted views"),
    ("render", "SlopeRenderer.layers", "layers (python)"),
    ("_render_kernels", "view_bins", "view bins (warp)"),
    ("_render_kernels", "in_focus_colour", "in-focus fill"),
    ("_render_kernels", "in_focus_colour_near", "in-focus fill"),
    ("render", "Layers.differs_from", "differs from"),
    ("render", "SlopeRenderer.composite", "composite (python)"),
    ("_render_kernels", "composite_views", "composite kernel"),
    ("_matting", "matted", "matting (python)"),
    ("_matting", "fit_band", "matting: fit"),
    ("_matting", "fill_zone", "matting: backgrounds"),
    ("_matting", "box_band", "matting: boxes"),
    ("reduce", "_replaced", "replaced: score and fringe"),
    ("depth_guided", "DepthGuide.blend_weight", "blend"),
    ("depth_guided", "DepthGuide.blend", "blend"),
    ("reduce", "levels_from_disparity", "level map"),
]


def _now():
    """Wall and CPU seconds (the CPU time of every thread of the process: on a shared machine it moves less)."""
    return np.array([time.perf_counter(), time.process_time()])


class StageClock:
    """Exclusive wall and CPU time per stage: a stage's time less that of the timed stages it calls."""

    def __init__(self):
        self.totals = defaultdict(lambda: np.zeros(2))
        self._stack = []  # [label, start, children's time]

    def wrap(self, func, label):
        @functools.wraps(func)
        def timed(*args, **kwargs):
            self._stack.append([label, _now(), np.zeros(2)])
            try:
                return func(*args, **kwargs)
            finally:
                label_, start, children = self._stack.pop()
                elapsed = _now() - start
                self.totals[label_] += elapsed - children
                if self._stack:
                    self._stack[-1][2] += elapsed

        return timed

    def install(self):
        """Wrap every stage of :data:`STAGES` the package has (for good: this is a profiling run)."""
        for module_name, path, label in STAGES:
            try:
                module = importlib.import_module(f"napari_lfalias.{module_name}")
            except ModuleNotFoundError:  # an older tree
                continue
            *owners, name = path.split(".")
            owner = module
            for part in owners:
                owner = getattr(owner, part, None)
            if owner is None or not hasattr(owner, name):
                continue
            timed = self.wrap(getattr(owner, name), label)
            if isinstance(inspect.getattr_static(owner, name), staticmethod):
                timed = staticmethod(timed)
            setattr(owner, name, timed)
        # modules that imported a stage by name at import time call their own reference
        render = importlib.import_module("napari_lfalias.render")
        render.refocus = importlib.import_module("napari_lfalias.refocus").refocus
        if hasattr(render, "matted"):
            render.matted = importlib.import_module("napari_lfalias._matting").matted


def scene_and_estimate(estimate_path, size, n_views):
    scene = brick_room(n_views=n_views, size=size, seed=0)
    lf = lfa.LightField(scene.lightfield.data, scene.lightfield.positions)
    if estimate_path is not None and Path(estimate_path).exists():
        with open(estimate_path, "rb") as file:
            return lf, pickle.load(file)
    estimate = lfa.estimate_disparity(lf)
    if estimate_path is not None:
        with open(estimate_path, "wb") as file:
            pickle.dump(estimate, file)
    return lf, estimate


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--size", type=int, default=512)
    parser.add_argument("--views", type=int, default=8)
    parser.add_argument("--slopes", type=float, nargs="+", default=[4.0, -4.0])
    parser.add_argument("--estimate", help="pickle of the estimate (made when missing)")
    parser.add_argument("--function", choices=("reduce_aliasing", "antialiased_refocus"), default="reduce_aliasing",
                        help="the call to time (both with the estimate given)")
    args = parser.parse_args()
    call = getattr(lfa, args.function)
    lf, estimate = scene_and_estimate(args.estimate, args.size, args.views)
    clock = StageClock()
    clock.install()
    print(f"{args.function}, napari_lfalias from {Path(lfa.__file__).parent}; "
          f"{args.views}x{args.views}x{args.size}x{args.size}x3")
    for slope in args.slopes:
        call(lf, slope, disparity=estimate)  # numba compiles, caches warm
        per_run, loads = [], []
        for _ in range(args.repeats):
            clock.totals.clear()
            start = _now()
            call(lf, slope, disparity=estimate)
            whole = _now() - start
            loads.append(os.getloadavg()[0])
            run = dict(clock.totals)
            run["rest"] = whole - sum(run.values())
            run["**whole call**"] = whole
            per_run.append(run)
        zero = np.zeros(2)
        labels = sorted({label for run in per_run for label in run},
                        key=lambda k: (k.startswith("**"), -np.median([run.get(k, zero)[0] for run in per_run])))
        rows = []
        for label in labels:
            cells = [median_iqr([1e3 * run.get(label, zero)[j] for run in per_run]) for j in (0, 1)]
            rows.append([label] + [f"{median:.0f} ± {half_iqr:.0f}" for median, half_iqr in cells])
        print(f"\nslope {slope:+g}: {args.repeats} runs, 1-min load {min(loads):.2f}-{max(loads):.2f}")
        print(table(("stage", "wall ms, median ± IQR/2", "CPU ms (all threads)"), rows))


if __name__ == "__main__":
    main()
