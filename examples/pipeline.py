"""A whole aliasing pipeline as a plain Python script, with figures.

    python examples/pipeline.py --out figures/                 # synthetic brick room
    python examples/pipeline.py --scene guv --out figures/     # the bundled GUV capture
    python examples/pipeline.py --napari                       # also show it all in napari

Steps: load a light field; sweep the focus over its disparity range (a lazy
dask stack, one slope per chunk); find how much of the image aliases at each
slope; detect (Algorithm 1) and reduce (Algorithm 2) at the slope where
aliasing is worst; measure against ground truth where there is one (the
brick room's dense-aperture reference); save figures (matplotlib, Agg) and
the numbers (``metrics.json``) into the output folder.

The same calls work on napari layer data: a light-field layer opened by the
plugin carries its LightField in ``layer.metadata["lightfield"]``, and any
``(U, V, Y, X[, C])`` image layer is one through ``lfa.LightField(layer.data)``
(:func:`lightfield_of_layer`); the results go back as layer-data tuples
(:func:`result_layers`, the focus sweep staying lazy: a dimension slider
that computes the slope on screen only)::

    lf = lightfield_of_layer(viewer.layers["views"])
    numbers, arrays = run("figures/", lightfield=lf)
    for data, kwargs, kind in result_layers(**arrays):
        getattr(viewer, f"add_{kind}")(data, **kwargs)
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

import napari_lfalias as lfa
from napari_lfalias import io_write
from napari_lfalias.detect import AliasingDetector
from napari_lfalias.sweep import aliasing_by_slope


def lightfield_of_layer(layer):
    """The LightField behind a napari layer: the plugin's own, or one made from the layer's data.

    Parameters
    ----------
    layer : napari.layers.Layer
        A light-field layer opened by the plugin (its LightField, with view
        positions and metadata, is in ``layer.metadata["lightfield"]``), or
        any image layer of shape ``(U, V, Y, X)`` or ``(U, V, Y, X, 3)``
        (a regular grid of views is assumed).
    """
    lf = layer.metadata.get("lightfield")
    return lf if isinstance(lf, lfa.LightField) else lfa.LightField(np.asarray(layer.data))


def result_layers(lightfield, sweep, detection, reduction):
    """The pipeline's arrays as napari layer-data tuples ``(data, kwargs, layer_type)``.

    The focus sweep stays a lazy dask array: napari shows it with a slider
    over the slopes and computes only the slope on screen.
    """
    grey = lightfield.n_channels == 1
    return [
        (sweep[..., 0] if grey else sweep, {"name": "focus sweep", "rgb": not grey}, "image"),
        (detection.cv, {"name": "Cv", "colormap": "magma", "blending": "additive"}, "image"),
        (detection.mask.astype(np.uint8), {"name": "aliased", "opacity": 0.45}, "labels"),
        (reduction.level, {"name": "level l*", "opacity": 0.45}, "labels"),
        (reduction.image[..., 0] if grey else reduction.image, {"name": "reduced", "rgb": not grey}, "image"),
    ]


def load_scene(name, size, n_views):
    """Return ``(light field, reference renderer or None, description)``."""
    if name == "brick":
        from napari_lfalias.synthetic import brick_room

        scene = brick_room(n_views=n_views, size=size, seed=0)
        return scene.lightfield, scene.reference, f"brick room, {n_views} x {n_views} views of {size} px"
    from napari_lfalias._paths import sample_data_dir

    folder = sample_data_dir() / "guv"
    lf = lfa.load(folder / "Lightfield_GUVExperim1.tif", white=folder / "Radiometry_GUVExperim1.tif",
                  dark=folder / "DarkFrame_GUVExperim1.tif")
    return lf, None, "GUV light-field microscope capture"


def as_display(image):
    """(Y, X, C) float -> something imshow shows: grey for one channel, clipped to [0, 1]."""
    image = np.clip(np.asarray(image), 0, 1)
    return image[..., 0] if image.shape[-1] == 1 else image


def save_figure(fig, out, name):
    path = out / name
    with io_write.atomic_output(path, overwrite=True) as tmp:
        fig.savefig(tmp, dpi=110, bbox_inches="tight", format="png")
    return path


def figure_sweep(plt, slopes, sweep, fractions, chosen):
    picks = np.unique(np.linspace(0, len(slopes) - 1, 5).round().astype(int))
    fig, axes = plt.subplots(1, len(picks) + 1, figsize=(3 * (len(picks) + 1), 3.2), layout="constrained")
    for ax, i in zip(axes, picks):
        ax.imshow(as_display(sweep[i].compute()), cmap="gray")
        ax.set_title(f"slope {slopes[i]:.2f}")
        ax.axis("off")
    axes[-1].plot(slopes, 100 * fractions, "o-")
    axes[-1].axvline(chosen, color="r", lw=1)
    axes[-1].set_xlabel("slope (px per view step)")
    axes[-1].set_ylabel("aliased pixels (%)")
    fig.suptitle("focus sweep (lazy dask stack) and the aliased fraction per slope")
    return fig


def figure_detection(plt, image, detection, threshold):
    fig, axes = plt.subplots(1, 3, figsize=(10, 3.6), layout="constrained")
    axes[0].imshow(as_display(image), cmap="gray")
    axes[0].set_title("refocused")
    shown = axes[1].imshow(detection.cv, cmap="magma", vmin=0, vmax=4 * threshold)
    fig.colorbar(shown, ax=axes[1], fraction=0.046)
    axes[1].set_title("Cv (Algorithm 1)")
    axes[2].imshow(as_display(image), cmap="gray")
    axes[2].imshow(np.ma.masked_where(~detection.mask, detection.mask), cmap="autumn", alpha=0.6)
    axes[2].set_title(f"aliased: Cv > {threshold}")
    for ax in axes:
        ax.axis("off")
    return fig


def figure_reduction(plt, image, result, reference):
    panels = [("refocused", as_display(image)), ("reduced (Algorithm 2)", as_display(result.image)),
              ("level l*", result.level)]
    if reference is not None:
        panels.append(("dense-aperture reference", as_display(reference)))
    fig, axes = plt.subplots(1, len(panels), figsize=(3.4 * len(panels), 3.6), layout="constrained")
    for ax, (title, data) in zip(axes, panels):
        ax.imshow(data, cmap="viridis" if title.startswith("level") else "gray")
        ax.set_title(title)
        ax.axis("off")
    return fig


def quality(image, reference):
    """PSNR and SSIM of ``image`` against ``reference``."""
    from napari_lfalias import metrics

    return {"psnr": float(metrics.psnr(image, reference)), "ssim": float(metrics.ssim(image, reference))}


def run(out, scene="brick", size=128, n_views=8, n_slopes=9, method="analytic", threshold=0.02, max_level=3,
        lightfield=None):
    """Run the pipeline; return the numbers written to ``metrics.json`` and the arrays behind them.

    ``lightfield`` (a LightField, from napari layer data for instance) replaces ``scene``.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    seconds = {}
    start = time.perf_counter()
    if lightfield is None:
        lf, reference_of, description = load_scene(scene, size, n_views)
    else:
        lf, reference_of, description = lightfield, None, f"a given light field, {lightfield.shape}"
    seconds["load"] = time.perf_counter() - start

    # A focus sweep: nothing is computed until a slice is asked for.
    start = time.perf_counter()
    detect_kw = {"gamma": 0.2, "threshold": threshold, "method": method, "seed": 0}
    # Slopes across the disparity range the views show (estimated from them).
    slopes, fractions = aliasing_by_slope(lf, n_slopes=n_slopes, **detect_kw)
    sweep = lfa.refocus_sweep(lf, slopes)
    chosen = float(slopes[int(np.argmax(fractions))])
    seconds["sweep"] = time.perf_counter() - start

    # One detector serves the detection and the reduction (its luminance, pyramid and shifted views).
    start = time.perf_counter()
    detector = AliasingDetector(lf)
    image = lfa.refocus(lf, chosen)
    detection = detector.detect(chosen, **detect_kw)
    seconds["detect"] = time.perf_counter() - start
    start = time.perf_counter()
    result = lfa.reduce_aliasing(lf, chosen, **detect_kw, max_level=max_level, detector=detector)
    seconds["reduce"] = time.perf_counter() - start

    reference = reference_of(chosen) if reference_of is not None else None
    numbers = {
        "scene": description,
        "slopes": slopes.tolist(),
        "aliased_fraction_per_slope": fractions.tolist(),
        "slope": chosen,
        "aliased_fraction": float(detection.mask.mean()),
        "fraction_above_level_0": float((result.level > 0).mean()),
        "seconds": seconds,
    }
    if reference is not None:
        numbers["refocus_vs_reference"] = quality(image, reference)
        numbers["reduced_vs_reference"] = quality(result.image, reference)

    figures = {
        "sweep.png": figure_sweep(plt, slopes, sweep, fractions, chosen),
        "detection.png": figure_detection(plt, image, detection, threshold),
        "reduction.png": figure_reduction(plt, image, result, reference),
    }
    for name, fig in figures.items():
        save_figure(fig, out, name)
        plt.close(fig)
    io_write.write_json(out / "metrics.json", numbers, overwrite=True)
    return numbers, {"lightfield": lf, "sweep": sweep, "detection": detection, "reduction": result}


def show_in_napari(arrays):
    """Put the pipeline's arrays into a napari viewer (the sweep stays lazy: a slider)."""
    import napari

    viewer = napari.Viewer()
    for data, kwargs, kind in result_layers(**arrays):
        getattr(viewer, f"add_{kind}")(data, **kwargs)
    napari.run()


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default="pipeline-figures", help="folder of the figures and metrics.json")
    parser.add_argument("--scene", choices=("brick", "guv"), default="brick")
    parser.add_argument("--size", type=int, default=128, help="brick room: view size in pixels")
    parser.add_argument("--views", type=int, default=8, help="brick room: views per side")
    parser.add_argument("--slopes", type=int, default=9, help="slopes in the sweep")
    parser.add_argument("--method", choices=("analytic", "monte_carlo"), default="analytic")
    parser.add_argument("--napari", action="store_true", help="show the results in napari at the end")
    args = parser.parse_args(argv)
    numbers, arrays = run(args.out, args.scene, args.size, args.views, args.slopes, args.method)
    print(json.dumps({k: v for k, v in numbers.items() if not isinstance(v, list)}, indent=2))
    print(f"figures and metrics.json in {args.out}/")
    if args.napari:
        show_in_napari(arrays)


if __name__ == "__main__":
    main()
