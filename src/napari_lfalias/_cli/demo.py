"""The ``demo`` subcommand: the whole pipeline on the bundled GUV capture.

Decode the lenslet capture (calibrating its grid from the white image),
refocus, detect angular aliasing, reduce it, and write every image into one
folder, timing each stage.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .. import io_write
from ..errors import LightFieldError
from .commands import detect_options
from .outputs import check_outputs, preview_range, write_outputs
from .progress import Stages

__all__ = ["run_demo", "guv_files", "DEMO_FILES"]

#: Files the demo writes into its folder.
DEMO_FILES = (
    "lightfield.tif", "centre_view.png", "refocus.png", "refocus.tif", "cv.png", "cv.tif", "mask.png",
    "levels.png", "reduced.png", "reduced.tif", "summary.json",
)

GUV_FILES = {
    "raw": "Lightfield_GUVExperim1.tif",
    "white": "Radiometry_GUVExperim1.tif",
    "dark": "DarkFrame_GUVExperim1.tif",
}
#: Slopes tried when no --slope is given (the demo shows the most aliased one).
N_CANDIDATES = 9


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


def run_demo(args, stream):
    """Run ``lfalias demo``."""
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise LightFieldError(f"{out}: --out must be a folder")
    out.mkdir(parents=True, exist_ok=True)
    paths = {name: out / name for name in DEMO_FILES}
    check_outputs(paths.values(), args.overwrite)

    stages = Stages(5 + (args.slope is None), quiet=args.quiet, stream=stream)
    lf, description = _load_scene(stages, stream)
    options = detect_options(args)
    slope, candidates = args.slope, None
    if slope is None:
        from ..sweep import aliasing_by_slope

        with stages("choose slope (mask sweep)"):
            slopes, fractions = aliasing_by_slope(lf, n_slopes=N_CANDIDATES, **options)
            slope = float(slopes[int(np.argmax(fractions))])
            candidates = {"slopes": slopes.tolist(), "aliased_fractions": fractions.tolist()}
    stream.write(f"scene: {description}\n"
                 f"       {lf.grid_shape[0]} x {lf.grid_shape[1]} views of {lf.image_shape[0]} x {lf.image_shape[1]} px, "
                 f"slope {slope:g}\n")

    from ..detect import detect_aliasing
    from ..reduce import reduce_aliasing
    from ..refocus import refocus

    with stages("refocus"):
        image = refocus(lf, slope)
    with stages(f"detect aliasing ({args.method})"):
        detection = detect_aliasing(lf, slope, **options)
    with stages(f"reduce aliasing (levels <= {args.levels})"):
        result = reduce_aliasing(lf, slope, **options, max_level=args.levels)
    with stages("write images"):
        metadata = {"scene": description, "slope": slope, **options, "max_level": args.levels}
        image_range = preview_range(image, result.image)
        centre = lf.data[lf.grid_shape[0] // 2, lf.grid_shape[1] // 2]
        write_outputs(
            [(paths["centre_view.png"], "image", np.asarray(centre)),
             (paths["refocus.png"], "image", image), (paths["refocus.tif"], "image", image),
             (paths["reduced.png"], "image", result.image), (paths["reduced.tif"], "image", result.image),
             (paths["cv.png"], "cv", detection.cv), (paths["cv.tif"], "cv", detection.cv),
             (paths["mask.png"], "mask", detection.mask), (paths["levels.png"], "levels", result.level)],
            metadata, args.overwrite, image_range,
        )
        io_write.write_lightfield(paths["lightfield.tif"], lf, overwrite=args.overwrite)
        summary = {
            **metadata,
            "views": list(lf.grid_shape), "view_size": list(lf.image_shape),
            "aliased_fraction": float(detection.mask.mean()),
            "fraction_above_level_0": float((result.level > 0).mean()),
            "seconds": dict(stages.seconds),
        }
        if candidates:
            summary["slope_candidates"] = candidates
        io_write.write_json(paths["summary.json"], summary, overwrite=args.overwrite)
    stream.write(f"aliased pixels: {100 * summary['aliased_fraction']:.2f} %, "
                 f"fused from a coarser level: {100 * summary['fraction_above_level_0']:.2f} %\n")
    stream.write(f"total {stages.total_seconds:.2f} s; {len(DEMO_FILES)} files in {out}/\n")
    return 0
