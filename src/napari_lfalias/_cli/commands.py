"""The ``convert``, ``refocus``, ``detect`` and ``reduce`` subcommands.

``refocus --antialias`` and the default detection and reduction
(``method="depth"``) need the light field's disparity: it is estimated in a
stage of its own (steps on stderr), or read from ``--disparity FILE``
(written by ``lfalias depth``), which is checked before the input is
decoded.
"""

from __future__ import annotations

from pathlib import Path

from .. import io_write
from .._inputs import check_reduce_options, open_input, resolved_options, view_grid
from .._validate import finite_float
from ..errors import ParameterError
from .depth import alternative_of, confidence_of, estimate, read_disparity
from .outputs import check_outputs, image_suffix, preview_range, sibling, write_outputs
from .progress import Stages, StepProgress

__all__ = ["run_convert", "run_refocus", "run_detect", "run_reduce", "detect_options", "reduce_options",
           "thresholded_cv", "given_inputs", "open_lightfield"]


#: A PNG preview whose image stays below this (99.5th percentile) gets a note about --auto-contrast.
DIM = 0.25


def detect_options(args):
    """Keyword options of ``detect_aliasing`` from parsed arguments."""
    return {
        "gamma": args.gamma,
        "n_patterns": args.n,
        "threshold": args.threshold,
        "threshold_scale": args.threshold_scale,
        "method": args.method,
        "seed": args.seed,
        "preset": args.preset,
    }


def reduce_options(args):
    """Keyword options of ``reduce_aliasing`` from parsed arguments."""
    return {**detect_options(args), "max_level": args.levels, "solver": args.solver,
            "keep_in_focus": args.keep_in_focus}


def thresholded_cv(detection):
    """The map the threshold applies to: ``cv``, or ``angular_cv`` for ``threshold_scale="angular"``.

    Written as the Cv output, so that mid-grey in its PNG preview is the threshold.
    """
    return detection.angular_cv if detection.threshold_scale == "angular" else detection.cv


def given_inputs(args):
    """The files and folders the user gave a command (never written to)."""
    grid_file = args.grid if args.grid is not None and view_grid(args.grid) is None else None
    disparity = getattr(args, "disparity", None)
    extra = [disparity, confidence_of(disparity), alternative_of(disparity)] if disparity is not None else []
    return [args.input, args.white, args.dark, grid_file, *extra]


def open_lightfield(args, stages):
    """Decode ``args.input`` in the stage "load", its steps on stderr."""
    with stages("load"):
        progress = StepProgress("decoding", quiet=args.quiet)
        try:
            lf = open_input(args.input, white=args.white, dark=args.dark, grid=args.grid, nonfinite=args.nonfinite,
                            progress=progress)
        except BaseException:
            progress.close(failed=True)
            raise
        progress.close()
        return lf


def _image_range(image, args, stream):
    """The PNG range of an image output: [0, 1], or its percentiles with --auto-contrast.

    A PNG of a dim image (a fluorescence capture relative to its white
    image, say) would be nearly black at [0, 1]: say so, and how to fix it.
    """
    if args.auto_contrast:
        return preview_range(image)
    if image_suffix(args.out) == ".png":
        high = preview_range(image)[1]
        if high < DIM:
            stream.write(f"note: the image reaches {high:.3g} of [0, 1]; its PNG is dark "
                         "(--auto-contrast stretches it; a .tif keeps the values)\n")
    return None


def _report(written, stages, stream):
    for path in written:
        stream.write(f"wrote {path}\n")
    if not stages.quiet:
        stream.write(f"total {stages.total_seconds:.3f} s\n")


def run_convert(args, stream):
    """Decode an input and write its views as an ImageJ TIFF or a zarr store."""
    out = Path(args.out)
    outputs = [out] + ([Path(args.save_grid)] if args.save_grid else [])
    check_outputs(outputs, args.overwrite, given_inputs(args))
    stages = Stages(2, quiet=args.quiet, stream=stream)
    lf = open_lightfield(args, stages)
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


def _given_disparity(args, method):
    """``--disparity FILE`` read and checked (``None`` if not given), before anything is decoded.

    ``method`` is what will use it: ``"antialias"`` (refocus) or the
    resolved detection method, of which only ``"depth"`` uses a disparity.
    """
    if args.disparity is None:
        return None
    refuse_unless_rendered("--disparity", args, method)
    return read_disparity(args.disparity)


def refuse_unless_rendered(option, args, method):
    """A ParameterError naming ``option`` where ``method`` renders no disparity (a plain refocus, a Cv
    method), before anything is decoded."""
    if method == "refocus":
        raise ParameterError(f"{option} is used by --antialias (the plain refocus renders no disparity)")
    if method not in ("antialias", "depth"):
        chosen = f"--method {method}" if args.method is not None else f"--preset {args.preset} (method {method})"
        raise ParameterError(f"{option} is used by --method depth (the default); {chosen} detects from "
                             "the views alone")


def _declare_order(args, lf):
    """``--nearer`` put in ``lf.meta["nearer"]``, where every rendering of ``lf`` reads it
    (:func:`~napari_lfalias.depth_guided.occlusion_order`)."""
    if args.nearer is not None:
        lf.meta["nearer"] = args.nearer


def _start(args, stream, tags=(), method=None):
    """Check the outputs (``--out`` and its ``<name>_<tag>`` siblings), the options and ``--disparity``,
    then open the input.

    Everything that can be wrong with the command line fails here, before
    the (possibly long) decoding.

    Parameters
    ----------
    method : str, optional
        What the command computes: ``"refocus"``, ``"antialias"``, or a
        detection method; ``"antialias"`` and ``"depth"`` need a disparity.

    Returns
    -------
    outputs : list of Path
    stages : Stages
        The first ("load") done; one more ("disparity") where it is estimated.
    lf : LightField
    disparity : DisparityEstimate, ndarray or None
        The file's (shape checked) or, where ``method`` needs one, the
        estimate; otherwise ``None``.
    """
    image_suffix(args.out)
    out = Path(args.out)
    outputs = [out] + [sibling(out, tag) for tag in tags]
    check_outputs(outputs, args.overwrite, given_inputs(args))
    finite_float("slope", args.slope)
    given = _given_disparity(args, method)
    if args.nearer is not None:
        refuse_unless_rendered("--nearer", args, method)
    estimated = method in ("antialias", "depth") and given is None
    stages = Stages(3 + estimated, quiet=args.quiet, stream=stream)
    lf = open_lightfield(args, stages)
    _declare_order(args, lf)
    if given is not None:
        return outputs, stages, lf, given.for_views(lf.image_shape)
    if estimated:
        with stages("disparity"):
            return outputs, stages, lf, estimate(lf, quiet=args.quiet)
    return outputs, stages, lf, None


def _disparity_source(args):
    """What the metadata says of the disparity used: the file, or "estimated"."""
    return str(args.disparity) if args.disparity is not None else "estimated"


def _order_source(lf):
    """What the metadata says of the occlusion order: ``--nearer``'s or the loader's, else "judged"."""
    return lf.meta.get("nearer", "judged")


def run_refocus(args, stream):
    """Refocus on one slope (``--antialias``: as a dense aperture records it) and write the image."""
    outputs, stages, lf, disparity = _start(args, stream, method="antialias" if args.antialias else "refocus")
    metadata = {"slope": args.slope}
    with stages("refocus (dense aperture)" if args.antialias else "refocus"):
        if args.antialias:
            from ..render import antialiased_refocus

            image = antialiased_refocus(lf, args.slope, disparity)
            metadata.update(antialias=True, disparity=_disparity_source(args), nearer=_order_source(lf))
        else:
            from ..refocus import refocus

            image = refocus(lf, args.slope)
    with stages("write"):
        image_range = _image_range(image, args, stream)
        written = write_outputs([(outputs[0], "image", image)], metadata, args.overwrite, image_range)
    _report(written, stages, stream)
    return 0


def _detection_start(args, stream, tags, options):
    """:func:`_start` for detect and reduce: the resolved options, and the disparity passed as ``disparity=``."""
    check_reduce_options(args.slope, **options)  # names the option at fault, before resolving them
    resolved = resolved_options(**options)
    outputs, stages, lf, disparity = _start(args, stream, tags, method=resolved["method"])
    metadata = {"slope": args.slope, **resolved}
    if resolved["method"] == "depth":
        metadata.update(disparity=_disparity_source(args), nearer=_order_source(lf))
    return outputs, stages, lf, {**resolved, "disparity": disparity}, metadata


def run_detect(args, stream):
    """Detect angular aliasing at one slope; write the aliasing score (Cv for the Cv methods) and the mask."""
    outputs, stages, lf, options, metadata = _detection_start(args, stream, ["mask"], detect_options(args))
    from ..detect import detect_aliasing

    with stages("detect"):
        detection = detect_aliasing(lf, args.slope, **options)
    with stages("write"):
        written = write_outputs(
            [(outputs[0], "cv", thresholded_cv(detection)), (outputs[1], "mask", detection.mask)], metadata,
            args.overwrite,
        )
    stream.write(f"aliased pixels: {100.0 * float(detection.mask.mean()):.2f} %\n")
    _report(written, stages, stream)
    return 0


def run_reduce(args, stream):
    """Reduce angular aliasing at one slope; write the image, level map and the aliasing score (or Cv)."""
    outputs, stages, lf, options, metadata = _detection_start(args, stream, ["levels", "cv"], reduce_options(args))
    from ..reduce import reduce_aliasing

    with stages("reduce"):
        result = reduce_aliasing(lf, args.slope, **options)
    with stages("write"):
        image_range = _image_range(result.image, args, stream)
        items = [(outputs[0], "image", result.image), (outputs[1], "levels", result.level),
                 (outputs[2], "cv", thresholded_cv(result.detections[0]))]
        written = write_outputs(items, metadata, args.overwrite, image_range)
    stream.write(f"pixels above level 0: {100.0 * float((result.level > 0).mean()):.2f} %\n")
    _report(written, stages, stream)
    return 0
