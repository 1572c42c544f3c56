"""The ``lfalias`` command: decode, refocus, detect and reduce angular aliasing.

Exit status: 0 on success, 2 for a usage error (argparse), 1 for an input
or parameter error (a one-line ``lfalias: error: ...`` on stderr, no
traceback), 130 when interrupted.
"""

from __future__ import annotations

import argparse
import os
import re
import sys
import textwrap
import warnings

from .errors import LightFieldError, LightFieldWarning

__all__ = ["main", "build_parser"]

EXAMPLES = """\
examples:
  lfalias demo                             # a real capture end to end; the paper's brick room vs its truth
  lfalias info capture.tif --white white.tif                   # what a file or folder holds
  lfalias convert capture.tif --white white.tif --dark dark.tif -o views.tif
  lfalias depth views.tif -o depth.tif                         # + depth_confidence.tif, _alternative.tif, .png
  lfalias refocus views.tif --slope 0.5 -o refocus.png
  lfalias refocus views.tif --slope 0.5 --antialias --disparity depth.tif -o dense.png
  lfalias detect views.tif --slope 0.5 -o score.tif            # + score_mask.tif
  lfalias reduce views.tif --slope 0.5 --disparity depth.tif -o reduced.png
  lfalias reduce views.tif --slope 0.5 --preset paper --seed 0 -o paper.png
  lfalias batch raw/*.tif --white white.tif --task convert --out views/ --workers 2
  lfalias batch views/*.tif --task reduce --slope 0.5 --out reduced/ --scheduler tcp://10.0.0.5:8786

A lenslet capture needs --white (and optionally --dark and --grid GRID.json
from `lfalias convert --save-grid`); folders of views and files written by
`lfalias convert` need nothing else (--grid 9x9 names the grid of a folder
whose names do not, or one with views missing). Outputs are never replaced
unless --overwrite is given, and are written atomically.
"""


#: A negative number, with an exponent or not, is a value and not an option: ``--slope -1e-3``
#: (argparse's own pattern misses exponents). ``-inf`` and ``-nan`` too, so that they get the
#: core's "must be finite" rather than "expected one argument".
_NEGATIVE_NUMBER = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$|^-(inf|nan)$", re.IGNORECASE)

#: Python parameters named in library messages -> the flags of this command line.
FLAGS = {
    "white": "--white", "dark": "--dark", "grid": "--grid", "nonfinite": "--nonfinite", "overwrite": "--overwrite",
    "slope": "--slope", "gamma": "--gamma", "n_patterns": "--n", "threshold": "--threshold",
    "threshold_scale": "--threshold-scale", "method": "--method", "preset": "--preset", "seed": "--seed", "max_level": "--levels",
    "solver": "--solver", "keep_in_focus": "--keep-in-focus", "workers": "--workers", "scheduler": "--scheduler",
    "fmt": "--format", "task": "--task", "disparity_range": "--range",
}
_NAMES = "|".join(sorted(FLAGS, key=len, reverse=True))
_ASSIGNED = re.compile(rf"(?<![\w.'`-])(?P<name>{_NAMES})=(?P<value>\(U, V\)|'[^']*'|\"[^\"]*\"|[^\s,;)]+)?")
_SUBJECT = re.compile(rf"(?P<lead>^|; |\()(?P<name>{_NAMES})(?= must\b|:| \()")


def as_flags(message):
    """Say a library message in this command line's terms: ``overwrite=True`` -> ``--overwrite``.

    Examples
    --------
    >>> as_flags("x.tif: output exists; pass overwrite=True to replace it")
    'x.tif: output exists; pass --overwrite to replace it'
    >>> as_flags("n_patterns must be an integer >= 2, got 1")
    '--n must be an integer >= 2, got 1'
    >>> as_flags("pass grid=(U, V) or nonfinite='mask'")
    'pass --grid UxV or --nonfinite mask'
    >>> as_flags("task='reduce' needs slope= (the disparity in focus)")
    '--task reduce needs --slope (the disparity in focus)'
    >>> as_flags("disparity_range (-300.0, -200.0) lies beyond +-36.6 px per view step")
    '--range (-300.0, -200.0) lies beyond +-36.6 px per view step'
    """
    def assigned(match):
        flag, value = FLAGS[match["name"]], match["value"]
        if value in (None, "True"):
            return flag
        if value == "(U, V)":
            return f"{flag} UxV"
        return f"{flag} {value.strip(chr(39) + chr(34))}"

    message = _ASSIGNED.sub(assigned, message)
    return _SUBJECT.sub(lambda match: match["lead"] + FLAGS[match["name"]], message)


def _add_input(parser):
    parser.add_argument("input", help="folder of views, lenslet raw image, or a .tif/.zarr from `lfalias convert`")
    _add_lenslet_options(parser)


def _add_lenslet_options(parser):
    lenslet = parser.add_argument_group("input")
    lenslet.add_argument("--white", metavar="FILE", help="white (flat-field) image of the lenslet array, or a folder "
                         "of them (one is chosen by the capture's zoom and focus)")
    lenslet.add_argument("--dark", metavar="FILE", help="dark frame subtracted from capture and white")
    lenslet.add_argument(
        "--grid", metavar="UxV|JSON",
        help="a folder of views: its grid, e.g. 9x9 (views missing from it get weight 0); a lenslet capture: "
        "the grid model from `convert --save-grid` (skips calibration)",
    )
    lenslet.add_argument(
        "--nonfinite", choices=NONFINITE, default=None,
        help="NaN or Inf samples: refuse the input (default), or give them weight 0",
    )


def _add_output(parser, what):
    parser.add_argument("-o", "--out", required=True, metavar="FILE", help=what)
    parser.add_argument("--overwrite", action="store_true", help="replace existing outputs")


def _add_slope(parser, required=True):
    parser.add_argument(
        "--slope", type=float, required=required, help="disparity in focus, pixels per unit of view position"
    )


#: Choices of the numeric core, repeated here so ``lfalias --help`` does not import it
#: (tests/test_cli.py checks they match ``detect.METHODS``, ``detect.THRESHOLD_SCALES``, ``reduce.SOLVERS``,
#: ``depth_guided.NEARER`` and ``lightfield.NONFINITE``).
METHODS = ("depth", "analytic", "monte_carlo")
THRESHOLD_SCALES = ("cv", "angular")
PRESETS = ("paper",)
SOLVERS = ("auto", "lu", "multigrid", "dct")
NEARER = ("larger", "smaller")
NONFINITE = ("raise", "mask")


def add_detection_options(parser, threshold=None, threshold_scale="cv"):
    """Add the options of the aliasing detection (shared by detect, reduce, batch and demo).

    Parameters
    ----------
    parser : argparse.ArgumentParser
    threshold, threshold_scale
        Defaults of ``--threshold`` (``None``: the method's own default)
        and ``--threshold-scale``.
    """
    group = parser.add_argument_group("aliasing detection")
    group.add_argument(
        "--method", choices=METHODS, default=None,
        help="depth: where the refocus differs from what a dense aperture records, predicted from the light "
        "field's own disparity (default); analytic / monte_carlo: the paper's Cv (Algorithm 1), exact or "
        "estimated from random view patterns",
    )
    group.add_argument(
        "--preset", choices=PRESETS, default=None,
        help="paper: Xiao et al. (2014) as published (Monte-Carlo Cv, gamma 0.2, N 100, T 0.02, Algorithm 2 "
        "with plain Poisson fusion); options given explicitly still win",
    )
    group.add_argument("--threshold", type=float, default=threshold, metavar="T",
                       help="depth: relative luminance difference from the dense aperture that counts as aliased "
                       "(default 0.02); Cv methods: a pixel is aliased where its Cv exceeds T (default 0.02)")
    group.add_argument("--gamma", type=float, default=None,
                       help="Cv methods: relaxation, fraction of views dropped at most (default 0.2)")
    group.add_argument("--n", type=int, default=None, metavar="N",
                       help="monte_carlo: number of random sampling patterns (default 100)")
    group.add_argument(
        "--threshold-scale", choices=THRESHOLD_SCALES, default=threshold_scale,
        help="Cv methods: cv: T applies to the paper's Cv, which shrinks as views are added (T = 0.02 on 8 x 8 "
        "views flags what T = 0.034 does on 5 x 5 and T = 0.011 on 15 x 15); angular: T applies to the angular "
        "Cv (std / mean of the shifted views), the same for any number of views: T = 0.48 is the paper's "
        f"0.02 on 8 x 8 (default {threshold_scale})",
    )
    group.add_argument("--seed", type=int, default=None, help="seed of the Monte-Carlo patterns")


def _add_reduction_options(parser):
    group = parser.add_argument_group("aliasing reduction")
    group.add_argument("--levels", type=int, default=None, metavar="L",
                       help="Cv methods: highest pyramid level of Algorithm 2 (default 3)")
    group.add_argument(
        "--solver", choices=SOLVERS, default="auto",
        help="Cv methods: Poisson solver of the gradient-domain fusion: auto (exact, keeps every pixel of level 0), "
        "lu (sparse direct), multigrid, dct (fastest; may move pixels outside the fused region) (default auto)",
    )
    group.add_argument(
        "--keep-in-focus", action="store_true",
        help="Cv methods: keep the in-focus surface sharp where a defocused occluder partly hides it (beyond "
        "the paper; pays off at low thresholds such as 0.005)",
    )


def _add_disparity(parser, used_by):
    parser.add_argument(
        "--disparity", metavar="FILE",
        help=f"{used_by}: the disparity TIFF written by `lfalias depth` from the same input (its confidence "
        "beside it is read too) instead of estimating it again",
    )
    _add_nearer(parser, used_by)


def _add_nearer(parser, used_by):
    parser.add_argument(
        "--nearer", choices=NEARER, default=None,
        help=f"{used_by}: which disparities are in front where surfaces occlude each other, if you know your "
        "camera's geometry (default: what the input's loader knows, e.g. smaller for an HCI folder, else "
        "judged from the views at the depth edges, which cannot always tell)",
    )


def _add_contrast(parser):
    parser.add_argument(
        "--auto-contrast", action="store_true",
        help="PNG previews span the 0.5-99.5 percentiles instead of [0, 1]",
    )


def build_parser():
    """Return the ``lfalias`` argument parser."""
    parser = argparse.ArgumentParser(
        prog="lfalias",
        description=textwrap.fill("Light-field decoding, refocusing, and angular-aliasing detection and "
                                  "reduction (Xiao et al., CVPR 2014).", 79),
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    from . import __version__

    parser._negative_number_matcher = _NEGATIVE_NUMBER
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    parser.add_argument("-q", "--quiet", action="store_true", help="print no timings or progress")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    def command(name, help_text, example, more=""):
        sub = commands.add_parser(
            name, help=help_text, description=textwrap.fill(help_text + more, 79),
            epilog=f"example:\n  {example}",
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
        sub._negative_number_matcher = _NEGATIVE_NUMBER
        # Also accepted after the command; SUPPRESS keeps `lfalias -q CMD` from being reset.
        sub.add_argument("-q", "--quiet", action="store_true", default=argparse.SUPPRESS,
                         help="print no timings or progress")
        return sub

    sub = command("convert", "decode a capture into views: ImageJ hyperstack TIFF or zarr store",
                  "lfalias convert capture.tif --white white.tif --dark dark.tif -o views.tif --save-grid grid.json")
    _add_input(sub)
    _add_output(sub, "output .tif/.tiff (ImageJ hyperstack, axes TZCYX = U V C Y X) or .zarr")
    sub.add_argument("--save-grid", metavar="JSON", help="also write the calibrated lenslet grid model")

    sub = command("depth", "estimate the disparity of every pixel from the light field itself",
                  "lfalias depth views.tif -o depth.tif --range -2 2",
                  ": a float32 TIFF (pixels per view step; refocus --slope D brings a pixel of disparity D into "
                  "focus), its confidence in [0, 1] beside it (<name>_confidence.tif), the second fit of a "
                  "periodic texture where there is one (<name>_alternative.tif) and a coloured preview "
                  "with a colour bar (<name>.png). --disparity FILE of refocus, detect and reduce reuses it.")
    _add_input(sub)
    _add_output(sub, "disparity: .tif or .tiff (float32, the settings in its metadata)")
    sub.add_argument("--range", nargs=2, type=float, metavar=("LOW", "HIGH"),
                     help="disparities to search, px per view step (default: the input's own range where it "
                     "states one, else up to 10 %% of the view size of motion of the outermost view either way)")

    # name, help, example, output help, detection options, --levels, --auto-contrast
    image_commands = [
        ("refocus", "shift-and-add refocus on one slope; --antialias: what a dense aperture records",
         "lfalias refocus views.tif --slope 0.5 --antialias -o refocus.png",
         "image: .png (8-bit preview) or .tif (float32)", False, False, True),
        ("detect", "detect angular aliasing: aliasing score (or Cv) and mask",
         "lfalias detect views.tif --slope 0.5 -o score.png",
         "the map T applies to (default method: the aliasing score; Cv methods: Cv, or the angular Cv with "
         "--threshold-scale angular): .png (T at mid-grey) or .tif (float32); the mask goes to <name>_mask",
         True, False, False),
        ("reduce", "reduce angular aliasing: the aliased pixels as a dense aperture records them (default), "
         "or Algorithm 2's multi-level fusion (Cv methods, --preset paper)",
         "lfalias reduce views.tif --slope 0.5 -o reduced.png",
         "reduced image: .png or .tif; level map and score (or Cv) go to <name>_levels and <name>_cv",
         True, True, True),
    ]
    for name, help_text, example, out_help, detection, levels, contrast in image_commands:
        sub = command(name, help_text, example)
        _add_input(sub)
        _add_slope(sub)
        _add_output(sub, out_help)
        if name == "refocus":
            sub.add_argument("--antialias", action="store_true",
                             help="render what a dense aperture records (each surface's copies joined into "
                             "its true blur) from the light field's disparity; in-focus pixels stay the refocus")
            _add_disparity(sub, "--antialias")
        if detection:
            add_detection_options(sub)
            _add_disparity(sub, "--method depth (the default)")
        if levels:
            _add_reduction_options(sub)
        if contrast:
            _add_contrast(sub)

    sub = command("info", "say what a file or folder holds: format, grid, views, disparity range",
                  "lfalias info capture.tif --white white.tif")
    _add_input(sub)
    sub.add_argument("--json", action="store_true", help="print the facts as JSON")

    sub = command(
        "demo", "run the whole pipeline on the bundled GUV capture, then on the paper's brick room, where aliasing "
        "is strong and the dense-aperture truth is known; time each stage",
        "lfalias demo --out lfalias-demo --overwrite",
        ". Without --slope it sweeps the capture's disparity and shows its most aliased slope; the brick room is "
        "focused on its cube (slope 4), its reduction (the default, or the options given) and --preset paper "
        "scored against the truth. Start with overview.png.",
    )
    sub.add_argument("-o", "--out", default="lfalias-demo", metavar="DIR", help="output folder (default ./lfalias-demo)")
    sub.add_argument("--overwrite", action="store_true", help="replace the files of an earlier run")
    sub.add_argument("--slope", type=float, default=None,
                     help="slope of the GUV capture, px per view step (default: the most aliased of a sweep)")
    add_detection_options(sub)
    _add_reduction_options(sub)

    from .batch import TASKS

    sub = command("batch", "convert or reduce many inputs as dask tasks (local cluster or a scheduler)",
                  "lfalias batch raw/*.tif --white white.tif --task convert --out views/ --workers 2")
    sub.add_argument("inputs", nargs="+", metavar="INPUT", help="inputs, as for the other commands")
    sub.add_argument("--out", required=True, metavar="DIR", help="output folder (created)")
    sub.add_argument("--task", choices=TASKS, default="convert", help="what to do with each input (default convert)")
    sub.add_argument("--scheduler", metavar="ADDRESS", help="dask scheduler, e.g. tcp://10.0.0.5:8786 (default: a local cluster)")
    sub.add_argument("--workers", type=int, default=None, metavar="N", help="workers of the local cluster (default: CPU count, at most 4)")
    sub.add_argument("--format", choices=("tif", "zarr"), default="tif", help="light-field format of --task convert")
    sub.add_argument("--overwrite", action="store_true", help="redo and replace outputs that are not this batch's own")
    _add_lenslet_options(sub)
    _add_slope(sub, required=False)
    add_detection_options(sub)
    _add_reduction_options(sub)
    _add_nearer(sub, "--task reduce with --method depth (the default)")
    return parser


def _dispatch(args, stream):
    if args.command == "depth":
        from ._cli.depth import run_depth

        return run_depth(args, stream)
    if args.command in ("convert", "refocus", "detect", "reduce"):
        from ._cli import commands

        return getattr(commands, f"run_{args.command}")(args, stream)
    if args.command == "info":
        from ._cli.info import run_info

        return run_info(args, stream)
    if args.command == "demo":
        from ._cli.demo import run_demo

        return run_demo(args, stream)
    from ._cli.batch_command import run_batch_command

    return run_batch_command(args, stream)


def main(argv=None):
    """Run ``lfalias`` with ``argv`` (default ``sys.argv[1:]``); return the exit status."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version (0) and usage errors (2)
        return int(exc.code or 0)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("always", LightFieldWarning)
            warnings.showwarning = _one_line_warnings(warnings.showwarning)
            return _dispatch(args, sys.stdout)
    except LightFieldError as exc:
        sys.stderr.write(f"lfalias: error: {as_flags(_one_line(exc))}\n")
        return 1
    except BrokenPipeError:  # `lfalias info ... | head`: the reader left, nothing to report
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 0
    except OSError as exc:  # disk full, permission denied, ...
        where = f"{exc.filename}: " if exc.filename else ""
        sys.stderr.write(f"lfalias: error: {where}{exc.strerror or exc}\n")
        return 1
    except ImportError as exc:  # an optional dependency or a part of the package is missing
        sys.stderr.write(f"lfalias: error: {args.command} needs {exc.name or exc}, which this installation lacks\n")
        return 1
    except KeyboardInterrupt:
        sys.stderr.write("lfalias: interrupted\n")
        return 130


def _one_line(exc):
    return " ".join(str(exc).split())


def _one_line_warnings(show):
    """A ``warnings.showwarning`` that prints ours as one line (``lfalias: warning: ...``), others with ``show``."""
    def show_warning(message, category, *args, **kwargs):
        if issubclass(category, LightFieldWarning):
            sys.stderr.write(f"lfalias: warning: {as_flags(_one_line(message))}\n")
        else:
            show(message, category, *args, **kwargs)

    return show_warning


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
