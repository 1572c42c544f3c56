"""The ``depth`` subcommand, and the disparity maps it writes read back (``--disparity FILE``).

``lfalias depth INPUT -o depth.tif`` writes four files: ``depth.tif`` (the
disparity, float32, pixels per view step, with the settings in its TIFF
metadata), ``depth_confidence.tif`` beside it (float32 in [0, 1]),
``depth_alternative.tif`` (the second fit of a periodic texture where there
is one, the disparity itself elsewhere) and ``depth.png`` (a coloured preview
with a colour bar of the range). Given back with ``--disparity depth.tif``,
the maps beside it make the same
:class:`~napari_lfalias.disparity.DisparityEstimate` as the run that wrote
them; a disparity TIFF from elsewhere (no confidence beside it) is trusted
everywhere (confidence 1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import _budget, io_write
from ..errors import DecodeError, ParameterError
from .colormap import colour_preview
from .outputs import check_outputs, preview_zoom, sibling
from .progress import Stages, StepProgress

__all__ = ["run_depth", "depth_outputs", "check_range", "estimate", "DisparityFile", "read_disparity",
           "confidence_of", "alternative_of", "write_disparity", "LABEL"]

#: The colour bar's caption.
LABEL = "px per view step"
#: The confidence file's tag: ``depth.tif`` -> ``depth_confidence.tif``.
CONFIDENCE = "confidence"
#: The alternative's tag: ``depth.tif`` -> ``depth_alternative.tif``.
ALTERNATIVE = "alternative"


def confidence_of(path):
    """The confidence file beside a disparity TIFF: ``depth.tif`` -> ``depth_confidence.tif``."""
    return sibling(path, CONFIDENCE)


def alternative_of(path):
    """The alternative file beside a disparity TIFF: ``depth.tif`` -> ``depth_alternative.tif``."""
    return sibling(path, ALTERNATIVE)


def depth_outputs(out):
    """``depth.tif`` -> ``[depth.tif, depth_confidence.tif, depth_alternative.tif, depth.png]``; only .tif/.tiff
    is accepted.

    Examples
    --------
    >>> [p.name for p in depth_outputs("out/d.tif")]
    ['d.tif', 'd_confidence.tif', 'd_alternative.tif', 'd.png']
    """
    out = Path(out)
    if out.suffix.lower() not in (".tif", ".tiff"):
        raise ParameterError(f"{out}: --out must end in .tif or .tiff (the float disparity; its PNG preview "
                             f"is written beside it as {out.stem}.png)")
    return [out, confidence_of(out), alternative_of(out), out.with_suffix(".png")]


def check_range(values):
    """``--range LOW HIGH`` as ``(low, high)`` (``None`` if not given), checked.

    Examples
    --------
    >>> check_range([-2.0, 3.0]), check_range(None)
    ((-2.0, 3.0), None)
    """
    if values is None:
        return None
    low, high = (float(v) for v in values)
    if not (math.isfinite(low) and math.isfinite(high)) or low > high:
        raise ParameterError(f"--range must be two finite numbers LOW <= HIGH, got {low:g} {high:g}")
    return low, high


def estimate(lf, disparity_range=None, quiet=False):
    """:func:`~napari_lfalias.estimate_disparity` of ``lf`` with its stages shown on stderr."""
    from ..disparity import estimate_disparity

    progress = StepProgress("disparity", quiet=quiet)
    try:
        result = estimate_disparity(lf, disparity_range, progress=progress)
    except BaseException:
        progress.close(failed=True)
        raise
    progress.close()
    return result


def _summary(est):
    low, high = float(est.disparity.min()), float(est.disparity.max())
    return (f"disparity {low:+.3g} .. {high:+.3g} px per view step (searched {est.disparity_range[0]:+.3g} .. "
            f"{est.disparity_range[1]:+.3g}), median confidence {float(np.median(est.confidence)):.2f}")


def write_disparity(paths, est, metadata, overwrite):
    """Write the disparity TIFF, its confidence, its alternative and the coloured PNG (``paths`` from
    :func:`depth_outputs`)."""
    tif, confidence, alternative, png = paths
    settings = {**metadata, "disparity_range": list(est.disparity_range), "radius": est.params.get("radius"),
                "units": "pixels per unit of view position", "confidence_file": Path(confidence).name}
    low, high = float(est.disparity.min()), float(est.disparity.max())
    return [
        io_write.write_tiff(tif, est.disparity.astype(np.float32), {**settings, "content": "disparity"}, overwrite),
        io_write.write_tiff(confidence, est.confidence.astype(np.float32), {**settings, "content": "confidence"},
                            overwrite),
        io_write.write_tiff(alternative, _alternative_or_disparity(est), {**settings, "content": "alternative"},
                            overwrite),
        io_write.write_png(png, colour_preview(est.disparity, low, high, LABEL, preview_zoom(est.disparity.shape)),
                           overwrite),
    ]


def _alternative_or_disparity(est):
    """The estimate's alternative where it has one, its disparity elsewhere (a finite map, float32)."""
    alternative = est.alternative if est.alternative is not None else est.disparity
    return np.where(np.isfinite(alternative), alternative, est.disparity).astype(np.float32)


def run_depth(args, stream):
    """Estimate the disparity of ``args.input``; write it, its confidence and a coloured preview."""
    from .commands import given_inputs, open_lightfield

    disparity_range = check_range(args.range)
    outputs = depth_outputs(args.out)
    check_outputs(outputs, args.overwrite, given_inputs(args))
    stages = Stages(3, quiet=args.quiet, stream=stream)
    lf = open_lightfield(args, stages)
    with stages("disparity"):
        est = estimate(lf, disparity_range, args.quiet)
    with stages("write"):
        written = write_disparity(outputs, est, {"input": str(args.input), "fill": True}, args.overwrite)
    stream.write(_summary(est) + "\n")
    for path in written:
        stream.write(f"wrote {path}\n")
    if not args.quiet:
        stream.write(f"total {stages.total_seconds:.3f} s\n")
    return 0


# -- reading them back -----------------------------------------------------------------------


@dataclass(frozen=True)
class DisparityFile:
    """A disparity map read from a file (``--disparity``), with its confidence where one lies beside it."""

    path: Path
    disparity: np.ndarray
    confidence: np.ndarray | None
    metadata: dict
    alternative: np.ndarray | None = None

    def for_views(self, shape):
        """The map for light fields of views ``shape`` (Y, X): a DisparityEstimate, or the bare map.

        Raises
        ------
        ParameterError
            If the map's shape is not ``shape``.
        """
        from ..disparity import DisparityEstimate

        if self.disparity.shape != tuple(shape):
            got, want = (" x ".join(map(str, s)) for s in (self.disparity.shape, shape))
            raise ParameterError(f"{self.path}: a disparity map of {got} px, but the views are {want} px; make "
                                 "it from this input with `lfalias depth`")
        if self.confidence is None:
            return self.disparity
        searched = self.metadata.get("disparity_range")
        searched = tuple(float(v) for v in searched) if searched else (float(self.disparity.min()),
                                                                         float(self.disparity.max()))
        alternative = None
        if self.alternative is not None:
            alternative = np.where(self.alternative != self.disparity, self.alternative, np.nan).astype(np.float32)
        return DisparityEstimate(self.disparity, self.confidence, searched, {"file": str(self.path)}, alternative)


def _read_map(path, what):
    """A finite (Y, X) float32 map and the TIFF's JSON metadata; a DecodeError or ParameterError naming it."""
    import tifffile

    from ..io_read import _quiet_tifffile

    path = Path(path)
    if not path.is_file():
        raise DecodeError(f"{path}: no such file (--disparity takes a disparity TIFF from `lfalias depth`)")
    try:
        with _quiet_tifffile(), tifffile.TiffFile(path) as tif:
            series = tif.series[0]
            _budget.check(math.prod(series.shape) * 4, f"{path}: the {what}", DecodeError)
            data = series.asarray()
            metadata = (tif.shaped_metadata or [{}])[0] if tif.is_shaped else {}
    except DecodeError:
        raise
    except Exception as exc:  # noqa: BLE001 - tifffile raises many kinds for files it cannot read
        raise DecodeError(f"{path}: not a readable TIFF ({exc.__class__.__name__}); --disparity takes the .tif "
                          "written by `lfalias depth`") from exc
    data = np.asarray(data)
    if data.ndim != 2 or data.dtype == np.bool_ or not np.issubdtype(data.dtype, np.number):
        raise ParameterError(f"{path}: the {what} must be one (Y, X) plane of numbers, got shape {data.shape} "
                             f"of {data.dtype}")
    if not np.isfinite(data).all():
        raise ParameterError(f"{path}: the {what} holds NaN or Inf values; fill them first")
    return data.astype(np.float32), dict(metadata)


def _map_beside(path, disparity, beside, what):
    """The map in the file ``beside`` the disparity TIFF ``path``, checked to have the disparity's shape;
    ``None`` where there is no such file."""
    if not beside.is_file():
        return None
    values, _ = _read_map(beside, what)
    if values.shape != disparity.shape:
        raise ParameterError(f"{beside}: its shape {values.shape} is not the disparity's {disparity.shape} "
                             f"({path.name}); write both again with `lfalias depth`")
    return values


def read_disparity(path):
    """Read a disparity TIFF (``lfalias depth``), and its confidence and alternative if ``<name>_confidence.tif``
    and ``<name>_alternative.tif`` lie beside it.

    Everything but the shape (which needs the light field) is checked here,
    before any input is decoded.

    Returns
    -------
    DisparityFile

    Raises
    ------
    DecodeError
        If a file is missing or not a TIFF.
    ParameterError
        If a map is not one finite plane, a map beside it has another shape, or the confidence is not in
        [0, 1].
    """
    path = Path(path)
    disparity, metadata = _read_map(path, "disparity map")
    confidence_path = confidence_of(path)
    confidence = _map_beside(path, disparity, confidence_path, "confidence map")
    if confidence is not None and (confidence.min() < 0 or confidence.max() > 1):
        raise ParameterError(f"{confidence_path}: a confidence must lie in [0, 1], got "
                             f"{confidence.min():.3g} .. {confidence.max():.3g}")
    alternative = None
    if confidence is not None:
        alternative = _map_beside(path, disparity, alternative_of(path), "alternative map")
    return DisparityFile(path, disparity, confidence, metadata, alternative)
