"""The ``demo`` subcommand: the whole pipeline on the bundled GUV capture.

Decode the lenslet capture (calibrating its grid from the white image),
estimate its disparity range and sweep the focus across it to find where it
aliases most (unless ``--slope`` is given), refocus there, detect angular aliasing
(Algorithm 1), reduce it (Algorithm 2), and write every image into one
folder, timing each stage. Without the lenslet decoder or the bundled
capture it runs on a small synthetic scene and says so.

The threshold is stated on the angular scale by default (``T = 0.5``): the
paper's Cv shrinks as views are added (:mod:`napari_lfalias.detect`), and
this capture has 15 x 15 views, where the paper's ``T = 0.02`` (chosen for
about 8 x 8 views) would flag nothing.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from .. import io_write
from .._inputs import check_reduce_options, resolved_options
from ..errors import ParameterError
from .commands import detect_options, reduce_options, thresholded_cv
from .outputs import check_outputs, montage, preview_range, write_outputs
from .progress import Progress, Stages

__all__ = ["run_demo", "guv_files", "candidate_slopes", "DEMO_FILES"]

#: Files the demo writes into its folder.
DEMO_FILES = (
    "lightfield.tif", "overview.png", "centre_view.png", "refocus.png", "refocus.tif", "cv.png", "cv.tif",
    "mask.png", "levels.png", "levels.tif", "reduced.png", "reduced.tif", "summary.json",
)

GUV_FILES = {
    "raw": "Lightfield_GUVExperim1.tif",
    "white": "Radiometry_GUVExperim1.tif",
    "dark": "DarkFrame_GUVExperim1.tif",
}
#: Slopes tried when no --slope is given (the demo shows the most aliased one).
N_CANDIDATES = 9
#: PNG previews are enlarged (nearest neighbour) to at least this many pixels on their longest side.
PREVIEW_SIZE = 256


def guv_files():
    """Paths of the bundled GUV capture, white and dark frames, or ``None`` if missing."""
    from .._paths import sample_data_dir

    try:
        folder = sample_data_dir() / "guv"
    except FileNotFoundError:
        return None
    files = {key: folder / name for key, name in GUV_FILES.items()}
    return files if all(p.is_file() for p in files.values()) else None


def _lenslet_decoder_available():
    try:
        from ..decoders import lenslet  # noqa: F401
    except ImportError:
        return False
    return True


def _load_scene(stages, stream):
    """Decode the GUV capture; without a decoder or sample, a small synthetic scene."""
    files = guv_files()
    if files is not None and _lenslet_decoder_available():
        from ..loading import load

        with stages("load + decode GUV capture"):
            lf = load(files["raw"], white=files["white"], dark=files["dark"])
        return lf, "GUV light-field microscope capture (bundled sample)"
    why = "the bundled GUV sample is missing" if files is None else "the lenslet decoder is not installed"
    stream.write(f"note: {why}; running on the synthetic brick room (small) instead\n")
    from ..synthetic import brick_room

    with stages("synthesise brick room"):
        scene = brick_room(n_views=8, size=128, seed=0)
    return scene.lightfield, "synthetic brick room, 8 x 8 views of 128 px"


def candidate_slopes(lf):
    """``N_CANDIDATES`` slopes across the scene's disparity range, and where the range comes from.

    The range is the scene's own (:func:`~napari_lfalias.sweep.disparity_range`):
    focused at one end of it, the rest of the scene is out of focus, which is
    where angular aliasing shows. A scene with no depth spread (a flat one, or
    one without texture) is swept ``SLOPE_PAD`` either side of its slope instead.
    """
    from ..sweep import SLOPE_PAD, disparity_range

    low, high, source = disparity_range(lf)
    if high - low < 2 * SLOPE_PAD / (N_CANDIDATES - 1):
        low, high = low - SLOPE_PAD, high + SLOPE_PAD
    return np.linspace(low, high, N_CANDIDATES), source


def _choose_slope(lf, detector, options, stages, quiet, stream):
    """The most aliased of the candidate slopes (:func:`candidate_slopes`)."""
    from ..sweep import aliasing_by_slope

    with stages("disparity range"):
        slopes, source = candidate_slopes(lf)
    stream.write(f"disparity range: {slopes[0]:+.3g} .. {slopes[-1]:+.3g} px per view step ({source})\n")
    bar = Progress(len(slopes), "slope sweep", quiet=quiet)
    with stages("aliasing sweep"):
        slopes, fractions = aliasing_by_slope(lf, slopes, progress=lambda _: bar.update(), detector=detector,
                                              **options)
    bar.close()
    stream.write("aliased pixels by slope: " + ", ".join(
        f"{s:+.3g}: {100 * f:.1f} %" for s, f in zip(slopes, fractions)) + "\n")
    return float(slopes[int(np.argmax(fractions))]), {"slopes": slopes.tolist(), "aliased_fractions": fractions.tolist(),
                                                       "range_from": source}


def run_demo(args, stream):
    """Run ``lfalias demo``: return 0, having written ``DEMO_FILES`` into ``args.out``."""
    started = time.perf_counter()
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ParameterError(f"{out}: --out must be a folder")
    paths = {name: out / name for name in DEMO_FILES}
    if out.is_dir():
        check_outputs(paths.values(), args.overwrite)

    options = reduce_options(args)
    detection_only = detect_options(args)
    check_reduce_options(0.0 if args.slope is None else args.slope, **options)
    options, detection_only = resolved_options(**options), resolved_options(**detection_only)
    chosen = options
    stages = Stages(5 + 2 * (args.slope is None), quiet=args.quiet, stream=stream)
    lf, description = _load_scene(stages, stream)
    from ..detect import AliasingDetector

    detector = AliasingDetector(lf)  # shared by the sweep, the detection and the reduction
    slope, candidates = args.slope, None
    if slope is None:
        slope, candidates = _choose_slope(lf, detector, detection_only, stages, args.quiet, stream)
    stream.write(f"scene: {description}\n"
                 f"       {lf.grid_shape[0]} x {lf.grid_shape[1]} views of {lf.image_shape[0]} x {lf.image_shape[1]} px, "
                 f"slope {slope:.4g}, method {chosen['method']}, T = {chosen['threshold']:g}\n")

    from ..reduce import reduce_aliasing
    from ..refocus import refocus

    with stages("refocus"):
        image = refocus(lf, slope)
    with stages(f"detect aliasing ({chosen['method']})"):
        detection = detector.detect(slope, **detection_only)
    with stages("reduce aliasing"):
        result = reduce_aliasing(lf, slope, **options, detector=detector)
    with stages("write images"):
        out.mkdir(parents=True, exist_ok=True)
        metadata = {"scene": description, "slope": slope, **options}
        image_range = preview_range(image, result.image)
        zoom = max(1, math.ceil(PREVIEW_SIZE / max(lf.image_shape)))
        centre = np.asarray(lf.data[lf.grid_shape[0] // 2, lf.grid_shape[1] // 2])
        cv = thresholded_cv(detection)
        panels = [("centre view", "image", centre), ("refocus", "image", image),
                  ("aliasing score" if chosen["method"] == "depth" else
                   f"{'angular ' if args.threshold_scale == 'angular' else ''}Cv", "cv", cv),
                  ("aliased", "mask", detection.mask), ("level l*", "levels", result.level),
                  ("reduced", "image", result.image)]
        write_outputs(
            [(paths["centre_view.png"], "image", centre),
             (paths["refocus.png"], "image", image), (paths["refocus.tif"], "image", image),
             (paths["reduced.png"], "image", result.image), (paths["reduced.tif"], "image", result.image),
             (paths["cv.png"], "cv", cv), (paths["cv.tif"], "cv", cv),
             (paths["mask.png"], "mask", detection.mask),
             (paths["levels.png"], "levels", result.level), (paths["levels.tif"], "levels", result.level)],
            metadata, args.overwrite, image_range, zoom=zoom,
        )
        io_write.write_png(paths["overview.png"], montage(panels, metadata, image_range, zoom), args.overwrite)
        io_write.write_lightfield(paths["lightfield.tif"], lf, overwrite=args.overwrite)
        summary = {
            **metadata,
            "views": list(lf.grid_shape), "view_size": list(lf.image_shape),
            "aliased_fraction": float(detection.mask.mean()),
            "fraction_above_level_0": float((result.level > 0).mean()),
            "largest_change": float(np.abs(result.image - result.refocused).max()),
            "preview_zoom": zoom,
            "seconds": dict(stages.seconds),
        }
        # Everything since the command started: the stages, and loading the compiled kernels on first use.
        summary["seconds"]["all (wall)"] = time.perf_counter() - started
        if candidates:
            summary["slope_candidates"] = candidates
        io_write.write_json(paths["summary.json"], summary, overwrite=args.overwrite)
    stream.write(f"aliased pixels: {100 * summary['aliased_fraction']:.2f} %, "
                 f"fused from a coarser level: {100 * summary['fraction_above_level_0']:.2f} %\n")
    timing = "" if args.quiet else (f"total {stages.total_seconds:.2f} s in the stages, "
                                     f"{time.perf_counter() - started:.2f} s in all; ")
    stream.write(f"{timing}{len(DEMO_FILES)} files in {out}/ (start with overview.png)\n")
    return 0
