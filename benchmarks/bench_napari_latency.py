"""Latency of a focus change in the napari widget, in a real (Xvfb) viewer.

For an 8x8x512x512x3 light field (the synthetic brick room of the paper's
Figure 6), the focus slider of the aliasing widget is set to a new slope and
the Qt event loop is run until both the refocused-image layer and the
exact-Cv layer hold the result for that slope; the time from setting the
slider to that moment is one sample. The same run also times what the
core API takes for the same outputs, outside the viewer, on the same
slopes: ``refocus`` then ``AliasingDetector.detect`` on a warm detector (what
the widget's worker calls), and ``refocus`` then a one-shot
``detect_aliasing`` (what a script would call).

Run (from the repository root)::

    xvfb-run -a .venv/bin/python benchmarks/bench_napari_latency.py

Results go to ``benchmarks/results/napari_latency.md``.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results" / "napari_latency.md"
COMMAND = "xvfb-run -a .venv/bin/python benchmarks/bench_napari_latency.py"


#: The baseline doing what the widget's worker does.
WARM = "core `refocus` + warm `AliasingDetector(skip_flat=False).detect` (the widget's calls)"

HCI_SCENE = Path(__file__).resolve().parents[2] / "shared" / "lf_data" / "hci_antinous"


def _scene(n_views, size, which):
    """The light field to time: the synthetic brick room, or n x n views of HCI antinous."""
    if which == "brick_room":
        from napari_lfalias.synthetic import brick_room

        scene = brick_room(n_views=n_views, size=size, seed=0)
        return scene.lightfield, "synthetic brick room (Figure 6)"
    import napari_lfalias as lfa

    lf = lfa.load(HCI_SCENE).subset(slice(0, n_views), slice(0, n_views))
    crop = (slice(None), slice(None), slice(0, size), slice(0, size))
    lf = lfa.LightField(lf.data[crop], lf.positions - lf.positions.mean(axis=(0, 1)), lf.meta)
    return lf, f"HCI antinous, the top-left {n_views} x {n_views} views (real data)"


class _UpdateClock:
    """Time stamps of the widget's output updates, and of the canvas draws."""

    def __init__(self, viewer, widget):
        self.updated = {}
        self.drawn = []
        widget.outputs_updated.connect(self._on_output)
        viewer.window._qt_viewer.canvas._scene_canvas.events.draw.connect(
            lambda event: self.drawn.append(time.perf_counter())
        )

    def _on_output(self, role, params):
        self.updated[(role, params.get("slope"))] = time.perf_counter()

    def both_updated(self, slope):
        times = [self.updated.get((role, slope)) for role in ("refocus", "cv")]
        return None if None in times else max(times)


def _updated(viewer, slope):
    from napari_lfalias._napari._layers import find_output_layer

    def check():
        for role in ("refocus", "cv"):
            layer = find_output_layer(viewer, role)
            if layer is None or layer.metadata.get("lfalias_params", {}).get("slope") != slope:
                return False
        return True

    return check


def _median_ms(values):
    return 1e3 * statistics.median(values)


def _api_baseline(lf, slopes):
    """Seconds per slope of the core API for the widget's outputs.

    Returns ``{label: [seconds, ...]}``: ``refocus`` + ``detect`` of a warm
    ``AliasingDetector`` made as the widget's session makes it
    (``skip_flat=False``; its luminance made before timing), and
    ``refocus`` + a one-shot ``detect_aliasing``.
    """
    import napari_lfalias as lfa
    from napari_lfalias.detect import AliasingDetector

    detector = AliasingDetector(lf, skip_flat=False)
    detector.detect(slopes[0] + 0.5)  # warm: luminance, tile ranges, compiled kernels
    runs = {
        WARM: lambda s: (lfa.refocus(lf, s), detector.detect(s)),
        "core `refocus` alone": lambda s: lfa.refocus(lf, s),
        "core warm `AliasingDetector.detect` alone (luminance moments + Cv)": lambda s: detector.detect(s),
        "core `refocus` + one-shot `detect_aliasing(method='analytic')`": lambda s: (
            lfa.refocus(lf, s), lfa.detect_aliasing(lf, s, method="analytic")),
    }
    times, cpu = {}, {}
    for label, call in runs.items():
        times[label], cpu[label] = [], []
        for slope in slopes:
            start, start_cpu = time.perf_counter(), time.process_time()
            call(slope)
            times[label].append(time.perf_counter() - start)
            cpu[label].append(time.process_time() - start_cpu)
    return times, cpu


def _time_widget(lf, slopes, pause):
    """Focus-change latencies of the widget in a fresh viewer."""
    import napari

    from napari_lfalias._napari._layers import lightfield_layer_data
    from napari_lfalias._napari._qtwait import run_event_loop_until
    from napari_lfalias._napari._widget import AliasingWidget

    viewer = napari.Viewer(show=True)
    data, kwargs, _ = lightfield_layer_data(lf, "lf")
    viewer.add_image(data, **kwargs)
    widget = AliasingWidget(viewer)
    viewer.window.add_dock_widget(widget, name="aliasing")
    start = time.perf_counter()
    run_event_loop_until(_updated(viewer, widget.slope), timeout_s=120)
    first = time.perf_counter() - start
    clock = _UpdateClock(viewer, widget)
    latencies, until_drawn, cpu = [], [], []
    for slope in slopes:
        if slope == widget.slope:
            slope = round(slope + 0.01, 2)
        clock.drawn.clear()
        begin, begin_cpu = time.perf_counter(), time.process_time()
        widget.focus_slider.setValue(slope)
        target = widget.slope
        # the time stamps come from the widget's signal, so the loop can check
        # rarely (a 1 ms timer would take the GIL from the worker 1000 times a second)
        run_event_loop_until(lambda: clock.both_updated(target) is not None, interval_ms=25)
        done = clock.both_updated(target)
        cpu.append(time.process_time() - begin_cpu)  # up to the check that saw it (<= 25 ms later)
        latencies.append(done - begin)
        run_event_loop_until(lambda: any(t > done for t in clock.drawn), timeout_s=5, interval_ms=25)
        until_drawn.append(min(t for t in clock.drawn if t > done) - begin)
        rest = time.perf_counter() + pause  # the idle time between two slider moves
        run_event_loop_until(lambda: time.perf_counter() > rest, interval_ms=25)
    widget.shutdown()
    viewer.close()
    return {"first": first, "latencies": latencies, "until_drawn": until_drawn, "cpu": cpu}


def run(n_views, size, repeats, api_repeats, pause=0.2, which="brick_room"):
    from napari_lfalias._napari._session import focus_range

    load_before = os.getloadavg()[0]
    lf, scene = _scene(n_views, size, which)
    low, high = focus_range(lf)
    # distinct slopes (0.01 px grid), never the one on screen, so no cache helps
    rng = np.random.default_rng(1)
    slopes = [round(float(s), 2) for s in rng.uniform(low, high, repeats)]
    widget = _time_widget(lf, slopes, pause)
    return {
        "scene": scene,
        "shape": lf.shape,
        "widget": widget,
        "api": _api_baseline(lf, slopes[:api_repeats]),
        "slopes": (low, high),
        "load": (load_before, os.getloadavg()[0]),
    }


def _row(label, values_ms):
    values = np.asarray(values_ms)
    return (
        f"| {label} | {values.size} | {np.median(values):.1f} | {np.percentile(values, 10):.1f} "
        f"| {np.percentile(values, 90):.1f} | {values.max():.1f} |"
    )


def _report(result, args):
    widget = result["widget"]
    lat = np.array(widget["latencies"]) * 1e3
    median = float(np.median(lat))
    api_times, api_cpu = result["api"]
    baselines = {label: np.array(times) * 1e3 for label, times in api_times.items()}
    cpu = np.array(widget["cpu"]) * 1e3
    cores = os.cpu_count() or 1
    lines = [
        "# napari widget: latency of a focus change",
        "",
        f"Command: `{COMMAND}`"
        + (f" (with `{' '.join(sys.argv[1:])}`)" if sys.argv[1:] else ""),
        "",
        f"- Light field: {result['scene']}, shape {tuple(result['shape'])} (U, V, Y, X, C), float32",
        f"- Machine: {platform.machine()}, {os.cpu_count()} logical CPUs (shared with other jobs), "
        f"Python {platform.python_version()}, Xvfb display (software OpenGL); 1-minute load "
        f"average {result['load'][0]:.2f} before, {result['load'][1]:.2f} after. Other jobs share "
        f"the {cores} cores: wall-clock times grow with the load, the CPU-time rows (this process, "
        "all its threads) do not",
        f"- Focus range of the slider: {result['slopes'][0]:.2f} .. {result['slopes'][1]:.2f} px; "
        f"{lat.size} random slopes on its 0.01 px grid, the same for every row",
        "- One sample: set the focus slider to a new slope and run the Qt event loop (a "
        "`QEventLoop`, no busy wait) until the `refocus` and `cv` layers both hold that slope's "
        "result (time stamp: the widget's `outputs_updated` signal, emitted once a layer's "
        "data are in place and refreshed); \"until drawn\" goes on to the next canvas draw. "
        f"Between two samples the event loop runs idle for {args.pause} s, as between two "
        "moves of a user's slider.",
        "",
        "| measure | samples | median (ms) | p10 (ms) | p90 (ms) | max (ms) |",
        "|---|---|---|---|---|---|",
        _row("widget: focus change -> refocus + exact Cv + mask layers updated", lat),
        _row("widget: ... until the canvas has drawn it", np.array(widget["until_drawn"]) * 1e3),
    ] + [
        _row(f"baseline outside the viewer: {label}", times) for label, times in baselines.items()
    ] + [
        _row("CPU time (all threads) of the widget's focus change", cpu),
    ] + [
        _row(f"CPU time (all threads) of the baseline {label}", np.array(times) * 1e3)
        for label, times in api_cpu.items()
    ] + [
        "",
        f"- Target: median <= 100 ms: **{'met' if median <= 100 else 'NOT met'}** ({median:.1f} ms).",
    ] + [
        f"- Widget median / ({label}) median: {median / float(np.median(times)):.2f}"
        for label, times in baselines.items() if "alone" not in label
    ] + [
        f"- Of the widget's median, the core's own calls (warm baseline) take "
        f"{float(np.median(baselines[WARM])):.0f} ms and the viewer "
        f"{median - float(np.median(baselines[WARM])):.0f} ms (signals, copies, layer refreshes)."
    ] + [
        f"- Unloaded estimate: the widget's median CPU time over the {cores} cores the kernels "
        f"run on, {float(np.median(cpu)) / cores:.0f} ms, is about what a focus change would take "
        "on an idle machine (a lower bound: not every step runs on every core).",
        f"- First update after the widget opened (detector made, luminance and tile ranges "
        f"made once per layer, first kernel calls): {1e3 * widget['first']:.0f} ms",
        "",
        "The widget's focus job (a worker thread) calls the core: `refocus(lf, slope)`, then "
        "`AliasingDetector.detect(slope)` on the session's detector (one per layer, "
        "`skip_flat=False`, the luminance made once); the GUI thread copies both into the "
        "layers' own arrays and refreshes them together (one redraw of the software-OpenGL "
        "canvas, about 40 ms of CPU here). Baselines are timed in the same run, outside the "
        "viewer, on the same slopes, after the widget (so the widget's thread pool is idle). "
        "The difference between the widget's CPU time and the warm baseline's is the viewer's "
        "share: layer refreshes, the canvas draw, and the benchmark's 25 ms event-loop checks.",
        "",
    ]
    text = "\n".join(lines)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=out.parent, suffix=".tmp")
    with os.fdopen(fd, "w") as handle:
        handle.write(text)
    os.replace(tmp, out)
    print(text)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--views", type=int, default=8, help="views per side (default 8)")
    parser.add_argument("--size", type=int, default=512, help="view width and height (default 512)")
    parser.add_argument("--repeats", type=int, default=30, help="focus changes timed (default 30)")
    parser.add_argument("--api-repeats", type=int, default=5, help="API baseline runs (default 5)")
    parser.add_argument("--scene", choices=("brick_room", "hci"), default="brick_room",
                        help="the synthetic brick room (default) or the real HCI antinous views")
    parser.add_argument("--pause", type=float, default=0.2,
                        help="idle event-loop time between two focus changes, s (default 0.2)")
    parser.add_argument("--out", type=Path, default=RESULTS, help=f"the report (default {RESULTS.name} in results/)")
    args = parser.parse_args(argv)
    result = run(args.views, args.size, args.repeats, args.api_repeats, args.pause, args.scene)
    _report(result, args)


if __name__ == "__main__":
    main()
