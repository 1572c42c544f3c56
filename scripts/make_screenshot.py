"""Screenshot of the napari plugin at work, for the README: ``docs/screenshot.png``.

Opens the synthetic brick room (the paper's Figure 6) in a napari viewer,
docks the aliasing widget, focuses on the front of the cube (as in
Figure 6 b2) and waits for the refocused image and the aliasing mask of
the brick wall behind it (T = 0.01); then runs the reduction (Algorithm 2)
and saves the whole window in the widget's default layout: the refocused
image with the aliased pixels as a translucent mask, the reduced image
beside it, the level-map legend in the widget (the Cv layer stays hidden,
as it opens).

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
#: T for the picture: below the paper's 0.02. On 8 x 8 views at gamma = 0.2 the
#: Cv is 0.042 times the angular variation (see napari_lfalias.detect), so 0.02
#: flags only angular variations above ~48 % (a few pixels here); 0.01 flags the
#: brick wall behind the cube and leaves the cube in focus alone.
THRESHOLD = 0.01


def _cube_slope(lf, low, high):
    """Focus on the cube's front face (Figure 6 b2): the brick wall behind it aliases."""
    layers = lf.meta.get("layers_disparity") or {}
    slope = layers.get("cube_front", high)
    return float(np.clip(slope, low, high))


def make_screenshot(output=OUTPUT, size=384, overwrite=False):
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
    widget.threshold_slider.setValue(THRESHOLD)
    widget.focus_slider.setValue(slope)

    def ready(role):
        def check():
            if "failed" in widget.status.text():
                raise RuntimeError(widget.status.text())
            layer = find_output_layer(viewer, role)
            if layer is None:
                return False
            params = layer.metadata["lfalias_params"]
            return params["slope"] == widget.slope and not params.get("preview")

        return check

    run_event_loop_until(ready("mask"), timeout_s=120)
    widget.reduce()
    run_event_loop_until(ready("fused"), timeout_s=300)
    viewer.layers.selection.active = find_output_layer(viewer, "refocus")
    viewer.reset_view()
    deadline = time.perf_counter() + 0.5  # let the canvas draw the new view
    run_event_loop_until(lambda: time.perf_counter() > deadline)
    image = viewer.screenshot(canvas_only=False, flash=False)
    widget.shutdown()
    viewer.close()
    write_png(output, image, overwrite=overwrite)
    return output


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--output", type=Path, default=OUTPUT)
    parser.add_argument("--size", type=int, default=384, help="view size of the brick room")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing screenshot")
    args = parser.parse_args(argv)
    print(make_screenshot(args.output, args.size, args.overwrite))


if __name__ == "__main__":
    main()
