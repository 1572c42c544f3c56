"""The demo's synthetic part: the paper's brick room, where aliasing is strong and the truth is known.

Focused on the cube (slope 4), the brick wall behind it (disparity -4) is
8 px per view step out of focus: the naive refocus shows it as overlapping
copies. Its dense-aperture reference (what an aperture without gaps
between the views records) is the ground truth; the pixels where the
naive refocus differs from it perceptibly are the truly aliased ones
(:func:`napari_lfalias.metrics.aliased_pixels`). The demo scores the naive
refocus, the reduction with the run's options (the default unless options
are given) and ``preset="paper"`` against it, over the image, the aliased
and the clean pixels.
"""

from __future__ import annotations

import numpy as np

from .. import io_write
from .colormap import colour_preview
from .depth import LABEL, estimate, write_disparity
from .outputs import montage, write_outputs

__all__ = ["ROOM_FILES", "SCENE", "SLOPE", "run_room", "psnr_table"]

#: The scene: 8 x 8 views of 256 px, the paper's set-up at half its size (seconds, not minutes).
SCENE = {"n_views": 8, "size": 256, "seed": 0}
#: Focused on the cube; the wall behind it aliases.
SLOPE = 4.0
#: Seed of the paper preset's Monte-Carlo patterns when ``--seed`` is not given (the same result every run).
PAPER_SEED = 0
#: Mean absolute error (over the colour channels) shown white in the overview's error panels.
ERROR_RANGE = 0.1
#: Files of this part.
ROOM_FILES = (
    "overview.png", "room_naive.png", "room_naive.tif", "room_reduced.png", "room_reduced.tif", "room_paper.png",
    "room_paper.tif", "room_reference.png", "room_reference.tif", "room_mask.png", "room_disparity.tif",
    "room_disparity_confidence.tif", "room_disparity_alternative.tif", "room_disparity.png",
)
REGIONS = ("image", "aliased", "clean")


def psnr_table(images, reference, truth):
    """PSNR (dB) of each image against ``reference`` over the image, the aliased and the clean pixels.

    Examples
    --------
    >>> ref = np.zeros((4, 4, 3), np.float32)
    >>> truth = np.zeros((4, 4), bool); truth[0] = True
    >>> table = psnr_table({"a": ref + 0.1}, ref, truth)
    >>> [round(v, 1) for v in table["a"].values()]
    [20.0, 20.0, 20.0]
    """
    from ..metrics import psnr

    masks = {"image": None, "aliased": truth, "clean": ~truth}
    return {name: {region: (psnr(image, reference, mask=mask) if mask is None or mask.any() else None)
                   for region, mask in masks.items()}
            for name, image in images.items()}


def _label(options, user_given):
    method, threshold = options["method"], options["threshold"]
    return f"reduced ({'' if user_given else 'default: '}{method}, T = {threshold:g})"


def _print(stream, labels, table, truth, detected):
    width = max(len(label) for label in labels.values()) + 2
    stream.write(f"  {'PSNR (dB) against the dense-aperture reference':<{width + 2}s}"
                 f"{'image':>8s}{'aliased':>9s}{'clean':>8s}\n")
    for key, label in labels.items():
        cells = "".join(f"{value:>{w}.2f}" if value is not None else f"{'-':>{w}s}"
                        for value, w in zip(table[key].values(), (8, 9, 8)))
        stream.write(f"    {label:<{width}s}{cells}\n")
    stream.write(f"  truly aliased: {100 * truth.mean():.1f} % of the pixels; detected: "
                 f"{100 * detected['reduced']:.1f} % (reduced), {100 * detected['paper']:.1f} % (paper)\n")


def _verdict(table):
    """One line: what each reduction gained where aliased and on the clean pixels."""
    def gain(key, region):
        value, naive = table[key][region], table["naive"][region]
        return None if value is None or naive is None else value - naive

    parts = []
    for key, name in (("reduced", "the reduction"), ("paper", "the paper's algorithm")):
        aliased, clean = gain(key, "aliased"), gain(key, "clean")
        if aliased is not None and clean is not None:
            parts.append(f"{name} {aliased:+.1f} dB where aliased, {clean:+.1f} dB on clean pixels")
    return "  against the naive refocus: " + "; ".join(parts) + "\n"


def run_room(options, user_given, seed, quiet, paths, overwrite, stages, stream):
    """Run the brick-room part; return its summary (written into summary.json by the caller).

    Parameters
    ----------
    options : dict
        Resolved reduction options of the run.
    user_given : bool
        Whether the user chose any of them (labels say "default" otherwise).
    seed : int or None
        ``--seed``: also the paper preset's seed (default :data:`PAPER_SEED`).
    quiet : bool
        No progress on stderr.
    paths : dict
        File name -> path, :data:`ROOM_FILES` among them.
    """
    from ..detect import AliasingDetector
    from ..metrics import aliased_pixels
    from ..presets import PRESETS
    from ..reduce import reduce_aliasing
    from ..refocus import refocus
    from ..synthetic import brick_room

    with stages("room: scene + dense-aperture reference"):
        scene = brick_room(**SCENE)
        lf = scene.lightfield
        reference = scene.reference(SLOPE, interpolation="bilinear")
    with stages("room: refocus"):
        naive = refocus(lf, SLOPE)
    with stages("room: disparity"):
        est = estimate(lf, quiet=quiet)
    detector = AliasingDetector(lf, disparity=est)
    with stages(f"room: reduce ({options['method']})"):
        reduced = reduce_aliasing(lf, SLOPE, **options, detector=detector)
    with stages("room: reduce (preset paper)"):
        paper = reduce_aliasing(lf, SLOPE, preset="paper", seed=PAPER_SEED if seed is None else seed)
    truth = aliased_pixels(naive, reference)
    images = {"naive": naive, "reduced": reduced.image, "paper": paper.image}
    table = psnr_table(images, reference, truth)
    detected = {"reduced": float(reduced.detections[0].mask.mean()), "paper": float(paper.detections[0].mask.mean())}
    labels = {"naive": "naive refocus", "reduced": _label(options, user_given),
              "paper": f"reduced (--preset paper: {PRESETS['paper']['method']}, T = {PRESETS['paper']['threshold']:g})"}
    with stages("room: write images"):
        _write(paths, images, reference, est, reduced.detections[0].mask, truth, table, user_given, overwrite)

    low, high = float(est.disparity.min()), float(est.disparity.max())
    stream.write(f"brick room (synthetic, the paper's Figure 6): {lf.grid_shape[0]} x {lf.grid_shape[1]} views of "
                 f"{lf.image_shape[0]} x {lf.image_shape[1]} px, focused on the cube (slope {SLOPE:g}); the brick "
                 "wall behind it aliases\n"
                 f"  disparity {low:+.3g} .. {high:+.3g} px per view step, median confidence "
                 f"{float(np.median(est.confidence)):.2f}\n")
    _print(stream, labels, table, truth, detected)
    stream.write(_verdict(table))
    return {
        "scene": "synthetic brick room (Xiao et al. 2014, Figure 6)", **SCENE, "slope": SLOPE,
        "views": list(lf.grid_shape), "view_size": list(lf.image_shape),
        "disparity": {"min": low, "max": high, "median_confidence": float(np.median(est.confidence))},
        "truly_aliased_fraction": float(truth.mean()), "detected_fraction": detected,
        "psnr": table, "labels": labels,
    }


def _write(paths, images, reference, est, mask, truth, table, user_given, overwrite):
    low, high = float(est.disparity.min()), float(est.disparity.max())
    metadata = {"scene": "synthetic brick room", **SCENE, "slope": SLOPE}
    items = [(paths[f"room_{name}.{suffix}"], "image", image)
             for name, image in {**images, "reference": reference}.items() for suffix in ("png", "tif")]
    write_outputs(items + [(paths["room_mask.png"], "mask", mask)], metadata, overwrite)
    write_disparity([paths["room_disparity.tif"], paths["room_disparity_confidence.tif"],
                     paths["room_disparity_alternative.tif"], paths["room_disparity.png"]], est, metadata, overwrite)

    def title(name, key):
        return f"{name} {table[key]['image']:.1f} dB"

    errors = {key: np.abs(image - reference).mean(axis=-1) for key, image in images.items()}
    rows = [
        [(title("naive", "naive"), "image", images["naive"]),
         (title("reduced" if user_given else "reduced (default)", "reduced"), "image", images["reduced"]),
         (title("paper preset", "paper"), "image", images["paper"]), ("dense-aperture reference", "image", reference),
         ("disparity (estimated)", "rgb", colour_preview(est.disparity, low, high, LABEL))],
        [(f"error of naive (white: {ERROR_RANGE:g})", "error", errors["naive"]),
         ("error of reduced", "error", errors["reduced"]), ("error of paper preset", "error", errors["paper"]),
         ("truly aliased", "mask", truth),
         ("detected (reduced)", "mask", mask)],
    ]
    io_write.write_png(paths["overview.png"], montage(rows, {"error_range": ERROR_RANGE}), overwrite)
