"""The demo's real part: the bundled GUV light-field microscope capture, end to end.

Decode the lenslet capture (calibrating its grid from the white image),
estimate its disparity, sweep the focus across the disparity it spans to
find where it aliases most (unless ``--slope`` is given), refocus there,
detect and reduce aliasing, and say what was found: with 15 x 15 views and
a shallow vesicle, the copies of a surface in a refocus lie less than a
pixel apart at any slope across the scene, so little or nothing aliases
and the reduction leaves the refocus (nearly) as it was.
"""

from __future__ import annotations

import numpy as np

from .. import io_write
from .colormap import colour_preview
from .commands import thresholded_cv
from .depth import LABEL, estimate, write_disparity
from .outputs import montage, preview_range, preview_zoom, write_outputs
from .progress import Progress

__all__ = ["GUV_FILES", "GUV_OUTPUTS", "N_CANDIDATES", "guv_files", "candidate_slopes", "run_guv"]

GUV_FILES = {
    "raw": "Lightfield_GUVExperim1.tif",
    "white": "Radiometry_GUVExperim1.tif",
    "dark": "DarkFrame_GUVExperim1.tif",
}
#: Files of this part.
GUV_OUTPUTS = (
    "guv_overview.png", "guv_lightfield.tif", "guv_centre_view.png", "guv_refocus.png", "guv_refocus.tif",
    "guv_score.png", "guv_score.tif", "guv_mask.png", "guv_reduced.png", "guv_reduced.tif", "guv_levels.tif",
    "guv_disparity.tif", "guv_disparity_confidence.tif", "guv_disparity_alternative.tif", "guv_disparity.png",
)
#: Slopes tried when no --slope is given (the demo shows the most aliased one).
N_CANDIDATES = 9
#: Percentiles of the estimated disparity that the sweep spans (the far and near surfaces, outliers left out).
SPAN = (2.0, 98.0)
#: Copies of a surface closer than this (px) merge into a smooth blur: they cannot alias.
MERGED_PX = 1.0


def guv_files():
    """Paths of the bundled GUV capture, white and dark frames, or ``None`` if missing."""
    from .._paths import sample_data_dir

    try:
        folder = sample_data_dir() / "guv"
    except FileNotFoundError:
        return None
    files = {key: folder / name for key, name in GUV_FILES.items()}
    return files if all(p.is_file() for p in files.values()) else None


def candidate_slopes(disparity):
    """``N_CANDIDATES`` slopes across the disparity the scene spans (:data:`SPAN` percentiles).

    Focused at one end of it, the rest of the scene is out of focus, which
    is where angular aliasing shows. A scene with no depth spread is swept
    ``SLOPE_PAD`` either side of its disparity instead.

    Examples
    --------
    >>> candidate_slopes(np.linspace(-1, 1, 100)).round(2).tolist()[:3]
    [-0.96, -0.72, -0.48]
    """
    from ..sweep import SLOPE_PAD

    low, high = (float(v) for v in np.percentile(disparity, SPAN))
    if high - low < 2 * SLOPE_PAD / (N_CANDIDATES - 1):
        low, high = low - SLOPE_PAD, high + SLOPE_PAD
    return np.linspace(low, high, N_CANDIDATES)


def _choose_slope(detector, slopes, options, quiet, stream):
    """The most aliased of ``slopes``: the largest aliased share, ties broken by the mean score
    (how near the threshold the scene comes)."""
    bar = Progress(len(slopes), "slope sweep", quiet=quiet)
    fractions, scores = [], []
    for slope in slopes:
        detection = detector.detect(float(slope), **options)
        fractions.append(float(detection.mask.mean()))
        scores.append(float(np.mean(thresholded_cv(detection))))
        bar.update()
    bar.close()
    stream.write("  aliased pixels by slope: " + ", ".join(
        f"{s:+.3g}: {100 * f:.1f} %" for s, f in zip(slopes, fractions)) + "\n")
    best = max(range(len(slopes)), key=lambda i: (fractions[i], scores[i]))
    return float(slopes[best]), {"slopes": [float(s) for s in slopes], "aliased_fractions": fractions,
                                 "mean_scores": scores}


def _found(aliased, changed, largest, spacing):
    """What the run found, in a sentence (shares of the pixels, the largest change, the copies' spacing)."""
    apart = f"copies of a surface lie at most {spacing:.2f} px apart in this refocus"
    if spacing < MERGED_PX:
        apart += f" (below {MERGED_PX:g} px they merge into a smooth blur)"
    if aliased == 0:
        return f"  found: no aliasing; {apart}; the reduction returns the refocus unchanged\n"
    return (f"  found: {100 * aliased:.2f} % of the pixels aliased; {apart}; the reduction changed "
            f"{100 * changed:.2f} % of the pixels, by {largest:.3g} at most\n")


def run_guv(files, slope, options, detection_options, quiet, paths, overwrite, stages, stream):
    """Run the GUV part; return its summary (written into summary.json by the caller).

    Parameters
    ----------
    files : dict
        ``raw``, ``white``, ``dark`` (:func:`guv_files`).
    slope : float or None
        ``--slope``; ``None`` sweeps (:func:`candidate_slopes`).
    options, detection_options : dict
        Resolved reduction and detection options.
    paths : dict
        File name -> path, :data:`GUV_OUTPUTS` among them.
    """
    from ..baselines import view_spacing
    from ..detect import AliasingDetector
    from ..loading import load
    from ..reduce import reduce_aliasing
    from ..refocus import refocus

    with stages("GUV: load + decode"):
        lf = load(files["raw"], white=files["white"], dark=files["dark"])
    with stages("GUV: disparity"):
        est = estimate(lf, quiet=quiet)
    low, high = float(est.disparity.min()), float(est.disparity.max())
    stream.write(f"GUV light-field microscope capture (bundled sample): {lf.grid_shape[0]} x {lf.grid_shape[1]} views "
                 f"of {lf.image_shape[0]} x {lf.image_shape[1]} px\n"
                 f"  disparity {low:+.3g} .. {high:+.3g} px per view step, median confidence "
                 f"{float(np.median(est.confidence)):.2f}\n")
    detector = AliasingDetector(lf, disparity=est)  # shared by the sweep, the detection and the reduction
    candidates = None
    if slope is None:
        with stages("GUV: aliasing sweep"):
            slope, candidates = _choose_slope(detector, candidate_slopes(est.disparity), detection_options, quiet,
                                              stream)
    with stages("GUV: refocus"):
        image = refocus(lf, slope)
    with stages(f"GUV: detect ({detection_options['method']})"):
        detection = detector.detect(slope, **detection_options)
    with stages("GUV: reduce"):
        result = reduce_aliasing(lf, slope, **options, detector=detector)
    with stages("GUV: write images"):
        zoom = preview_zoom(lf.image_shape)
        metadata = {"scene": "GUV capture", "slope": slope, **options}
        _write(paths, lf, est, image, detection, result, metadata, zoom, overwrite)

    spacing = float(np.abs(est.disparity - slope).max()) * view_spacing(lf.positions)
    aliased = float(detection.mask.mean())
    changed = np.abs(result.image - image).max(axis=-1) > 0
    largest = float(np.abs(result.image - image).max())
    chosen = "the most aliased of the sweep" if candidates else "--slope"
    stream.write(f"  at slope {slope:+.3g} ({chosen}): {detection_options['method']}, "
                 f"T = {detection_options['threshold']:g}\n")
    stream.write(_found(aliased, float(changed.mean()), largest, spacing))
    summary = {
        "scene": "GUV light-field microscope capture (bundled sample)", "slope": slope,
        "views": list(lf.grid_shape), "view_size": list(lf.image_shape),
        "disparity": {"min": low, "max": high, "median_confidence": float(np.median(est.confidence))},
        "largest_copy_spacing_px": spacing, "aliased_fraction": aliased, "changed_fraction": float(changed.mean()),
        "largest_change": largest, "preview_zoom": zoom,
    }
    if candidates:
        summary["slope_candidates"] = candidates
    return summary


def _write(paths, lf, est, image, detection, result, metadata, zoom, overwrite):
    image_range = preview_range(image, result.image)
    centre = np.asarray(lf.data[lf.grid_shape[0] // 2, lf.grid_shape[1] // 2])
    score = thresholded_cv(detection)
    write_outputs(
        [(paths["guv_centre_view.png"], "image", centre),
         (paths["guv_refocus.png"], "image", image), (paths["guv_refocus.tif"], "image", image),
         (paths["guv_reduced.png"], "image", result.image), (paths["guv_reduced.tif"], "image", result.image),
         (paths["guv_score.png"], "cv", score), (paths["guv_score.tif"], "cv", score),
         (paths["guv_mask.png"], "mask", detection.mask), (paths["guv_levels.tif"], "levels", result.level)],
        metadata, overwrite, image_range, zoom=zoom,
    )
    write_disparity([paths["guv_disparity.tif"], paths["guv_disparity_confidence.tif"],
                     paths["guv_disparity_alternative.tif"], paths["guv_disparity.png"]],
                    est, {"scene": metadata["scene"]}, overwrite)
    low, high = float(est.disparity.min()), float(est.disparity.max())
    score_title = "aliasing score" if metadata["method"] == "depth" else "Cv"
    panels = [("centre view", "image", centre),
              ("disparity", "rgb", colour_preview(est.disparity, low, high, LABEL, zoom)),
              ("refocus", "image", image), (score_title, "cv", score),
              ("aliased", "mask", detection.mask), ("reduced", "image", result.image)]
    io_write.write_png(paths["guv_overview.png"], montage(panels, metadata, image_range, zoom), overwrite)
    io_write.write_lightfield(paths["guv_lightfield.tif"], lf, overwrite=overwrite)
