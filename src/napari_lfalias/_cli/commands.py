"""The ``convert``, ``refocus``, ``detect`` and ``reduce`` subcommands."""

from __future__ import annotations

from pathlib import Path

from .. import io_write
from .._inputs import open_input
from ..errors import ParameterError
from .outputs import check_outputs, image_suffix, preview_range, sibling, write_outputs
from .progress import Stages

__all__ = ["run_convert", "run_refocus", "run_detect", "run_reduce", "detect_options"]


def detect_options(args):
    """Keyword options of ``detect_aliasing`` from parsed arguments."""
    return {
        "gamma": args.gamma,
        "n_patterns": args.n,
        "threshold": args.threshold,
        "method": args.method,
        "seed": args.seed,
    }


def _open(args, stages):
    with stages("load"):
        return open_input(args.input, white=args.white, dark=args.dark, grid=args.grid)


def _report(written, stages, stream):
    for path in written:
        stream.write(f"wrote {path}\n")
    if not stages.quiet:
        stream.write(f"total {stages.total_seconds:.3f} s\n")


def run_convert(args, stream):
    """Decode an input and write its views as an ImageJ TIFF or a zarr store."""
    out = Path(args.out)
    outputs = [out] + ([Path(args.save_grid)] if args.save_grid else [])
    check_outputs(outputs, args.overwrite)
    stages = Stages(2, quiet=args.quiet, stream=stream)
    lf = _open(args, stages)
    grid = lf.meta.get("grid")
    if args.save_grid and not hasattr(grid, "to_json"):
        raise ParameterError(f"{args.input}: --save-grid needs a lenslet capture; this input has no grid model")
    with stages("write"):
        written = [io_write.write_lightfield(out, lf, overwrite=args.overwrite)]
        if args.save_grid:
            written.append(io_write.write_json(args.save_grid, grid, args.overwrite))
    stream.write(f"{lf.grid_shape[0]} x {lf.grid_shape[1]} views of {lf.image_shape[0]} x {lf.image_shape[1]} px, "
                 f"{lf.n_channels} channel(s)\n")
    _report(written, stages, stream)
    return 0


def run_refocus(args, stream):
    """Refocus on one slope and write the image."""
    image_suffix(args.out)
    check_outputs([args.out], args.overwrite)
    stages = Stages(3, quiet=args.quiet, stream=stream)
    lf = _open(args, stages)
    from ..refocus import refocus

    with stages("refocus"):
        image = refocus(lf, args.slope)
    with stages("write"):
        image_range = preview_range(image) if args.auto_contrast else None
        written = write_outputs([(Path(args.out), "image", image)], {"slope": args.slope}, args.overwrite, image_range)
    _report(written, stages, stream)
    return 0


def run_detect(args, stream):
    """Detect angular aliasing at one slope; write the Cv map and the mask."""
    image_suffix(args.out)
    out = Path(args.out)
    outputs = [out, sibling(out, "mask")]
    check_outputs(outputs, args.overwrite)
    stages = Stages(3, quiet=args.quiet, stream=stream)
    lf = _open(args, stages)
    from ..detect import detect_aliasing

    options = detect_options(args)
    with stages("detect"):
        detection = detect_aliasing(lf, args.slope, **options)
    with stages("write"):
        metadata = {"slope": args.slope, **options}
        written = write_outputs(
            [(outputs[0], "cv", detection.cv), (outputs[1], "mask", detection.mask)], metadata, args.overwrite
        )
    stream.write(f"aliased pixels: {100.0 * float(detection.mask.mean()):.2f} %\n")
    _report(written, stages, stream)
    return 0


def run_reduce(args, stream):
    """Reduce angular aliasing at one slope; write the image, level map and Cv map."""
    image_suffix(args.out)
    out = Path(args.out)
    outputs = [out, sibling(out, "levels"), sibling(out, "cv")]
    check_outputs(outputs, args.overwrite)
    stages = Stages(3, quiet=args.quiet, stream=stream)
    lf = _open(args, stages)
    from ..reduce import reduce_aliasing

    options = {**detect_options(args), "max_level": args.levels}
    with stages("reduce"):
        result = reduce_aliasing(lf, args.slope, **options)
    with stages("write"):
        image_range = preview_range(result.image) if args.auto_contrast else None
        items = [(outputs[0], "image", result.image), (outputs[1], "levels", result.level), (outputs[2], "cv", result.cv)]
        written = write_outputs(items, {"slope": args.slope, **options}, args.overwrite, image_range)
    stream.write(f"pixels above level 0: {100.0 * float((result.level > 0).mean()):.2f} %\n")
    _report(written, stages, stream)
    return 0
