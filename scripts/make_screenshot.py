"""Screenshot of the napari plugin at work, for the README: ``docs/screenshot.png``.

Opens the brick room sample (the paper's Figure 6: 8 x 8 views of
256 x 256 px, ``synthetic.brick_room(n_views=8, size=256, seed=0)``) in a
napari viewer, docks the aliasing widget with its defaults (the
dense-aperture method, T = 0.02), focuses on the front of the cube (as in
Figure 6 b2, slope 4: the brick wall behind it has copies 8 px apart and
its mortar lines stripe the refocus), waits for the disparity estimate and
presses "Reduce aliasing". The whole window is saved in the widget's
default layout: the striped naive refocus with the pixels the reduction
flagged as a translucent magenta mask, and the reduced image beside it
(the wall clean, the cube untouched); the Cv, disparity, level map and
anti-aliased layers stay hidden, as they open. It prints how far the two
images shown lie from the scene's dense-aperture reference (PSNR where the
naive refocus is aliased and elsewhere), the numbers docs/napari.md quotes.

Run (from the repository root)::

    xvfb-run -a -s "-screen 0 1600x1200x24" .venv/bin/python scripts/make_screenshot.py [--overwrite]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OUTPUT = ROOT / "docs" / "screenshot.png"


def _cube_slope(lf, low, high):
    """Focus on the cube's front face (Figure 6 b2): the brick wall behind it aliases."""
    layers = lf.meta.get("layers_disparity") or {}
    slope = layers.get("cube_front", high)
    return float(np.clip(slope, low, high))


def _quality(naive, reduced, size, slope):
    """PSNR (dB) of the naive and reduced images against the dense-aperture reference, where aliased
    and elsewhere (:func:`napari_lfalias.metrics.aliased_pixels`)."""
    from napari_lfalias import metrics
    from napari_lfalias.synthetic import brick_room

    reference = brick_room(n_views=8, size=size, seed=0).reference(slope)
    aliased = metrics.aliased_pixels(naive, reference)
    lines = [f"aliased pixels (ground truth): {aliased.mean():.1%}"]
    for name, image in (("naive refocus", naive), ("reduced", reduced)):
        psnr = [10 * np.log10(1.0 / np.mean((image[where] - reference[where]) ** 2)) for where in (aliased, ~aliased)]
        lines.append(f"{name}: PSNR {psnr[0]:.1f} dB where aliased, {psnr[1]:.1f} dB elsewhere")
    return "\n".join(lines)


def make_screenshot(output=OUTPUT, size=256, overwrite=False):
    """Render the screenshot and write it to ``output`` (atomically)."""
    import napari

    from napari_lfalias.io_write import write_png
    from napari_lfalias._napari._layers import find_output_layer
    from napari_lfalias._napari._qtwait import run_event_loop_until
    from napari_lfalias._napari._sample_data import brick_room
    from napari_lfalias._napari._widget import AliasingWidget

    viewer = napari.Viewer(show=True, title="napari-lfalias")
    viewer.window.resize(1400, 1000)
    data, kwargs, _ = brick_room(n_views=8, size=size)[0]
    viewer.add_image(data, **kwargs)
    widget = AliasingWidget(viewer)
    viewer.window.add_dock_widget(widget, name="Refocus and aliasing", area="right")
    lf = kwargs["metadata"]["lightfield"]
    slope = _cube_slope(lf, widget.focus_slider.minimum(), widget.focus_slider.maximum())
    widget.focus_slider.setValue(slope)

    def ready(role):
        def check():
            if "failed" in widget.status.text():
                raise RuntimeError(widget.status.text())
            layer = find_output_layer(viewer, role)
            if layer is None:
                return False
            params = layer.metadata["lfalias_params"]
            return params.get("slope", widget.slope) == widget.slope and not params.get("preview")

        return check

    run_event_loop_until(ready("mask"), timeout_s=120)
    run_event_loop_until(ready("disparity"), timeout_s=300)
    widget.reduce()  # the library's default method: dense aperture, from the disparity
    run_event_loop_until(ready("fused"), timeout_s=300)
    run_event_loop_until(lambda: not widget.jobs.busy(), timeout_s=60)
    viewer.layers.selection.active = find_output_layer(viewer, "refocus")
    viewer.reset_view()
    deadline = time.perf_counter() + 0.5  # let the canvas draw the new view
    run_event_loop_until(lambda: time.perf_counter() > deadline)
    image = viewer.screenshot(canvas_only=False, flash=False)
    print(_quality(find_output_layer(viewer, "refocus").data, find_output_layer(viewer, "fused").data, size, slope))
    widget.shutdown()
    viewer.close()
    write_png(output, image, overwrite=overwrite)
    return output


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--output", type=Path, default=OUTPUT)
    parser.add_argument("--size", type=int, default=256, help="view size of the brick room")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing screenshot")
    args = parser.parse_args(argv)
    print(make_screenshot(args.output, args.size, args.overwrite))


if __name__ == "__main__":
    main()
