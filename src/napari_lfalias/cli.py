"""The ``lfalias`` command: decode, refocus, detect and reduce angular aliasing.

Exit status: 0 on success, 2 for a usage error (argparse), 1 for an input
or parameter error (a one-line ``lfalias: error: ...`` on stderr, no
traceback), 130 when interrupted.
"""

from __future__ import annotations

import argparse
import os
import sys

from .errors import LightFieldError

__all__ = ["main", "build_parser"]

EXAMPLES = """\
examples:
  lfalias demo                                   # the bundled GUV capture, end to end
  lfalias info capture.tif --white white.tif     # what a file or folder holds
  lfalias convert capture.tif --white white.tif --dark dark.tif -o views.tif
  lfalias refocus views.tif --slope 0.5 -o refocus.png
  lfalias detect views.tif --slope 0.5 -o cv.tif          # + cv_mask.tif
  lfalias reduce scene_folder/ --slope 1.5 --levels 3 -o reduced.png
  lfalias batch raw/*.tif --white white.tif --task convert --out views/ --workers 2

A lenslet capture needs --white (and optionally --dark and --grid GRID.json
from `lfalias convert --save-grid`); folders of views and files written by
`lfalias convert` need nothing else. Outputs are never replaced unless
--overwrite is given, and are written atomically.
"""


def _add_input(parser):
    parser.add_argument("input", help="folder of views, lenslet raw image, or a .tif/.zarr from `lfalias convert`")
    lenslet = parser.add_argument_group("lenslet capture")
    lenslet.add_argument("--white", metavar="FILE", help="white (flat-field) image of the lenslet array")
    lenslet.add_argument("--dark", metavar="FILE", help="dark frame subtracted from capture and white")
    lenslet.add_argument("--grid", metavar="JSON", help="grid model from `convert --save-grid` (skips calibration)")


def _add_output(parser, what):
    parser.add_argument("-o", "--out", required=True, metavar="FILE", help=what)
    parser.add_argument("--overwrite", action="store_true", help="replace existing outputs")


def _add_slope(parser, required=True):
    parser.add_argument(
        "--slope", type=float, required=required, help="disparity in focus, pixels per unit of view position"
    )


def add_detection_options(parser):
    """The options of Algorithm 1 (shared by detect, reduce, batch and demo)."""
    group = parser.add_argument_group("aliasing detection (Algorithm 1)")
    group.add_argument("--gamma", type=float, default=0.2, help="relaxation: fraction of views dropped at most (default 0.2)")
    group.add_argument("--n", type=int, default=100, metavar="N", help="number of random sampling patterns (default 100)")
    group.add_argument("--threshold", type=float, default=0.02, metavar="T", help="Cv above T is aliased (default 0.02)")
    group.add_argument(
        "--method", choices=("analytic", "monte_carlo"), default="analytic",
        help="exact expected Cv or the paper's Monte-Carlo estimate (default analytic)",
    )
    group.add_argument("--seed", type=int, default=None, help="seed of the Monte-Carlo patterns")


def _add_levels(parser):
    parser.add_argument("--levels", type=int, default=3, metavar="L", help="highest pyramid level of Algorithm 2 (default 3)")


def _add_contrast(parser):
    parser.add_argument(
        "--auto-contrast", action="store_true",
        help="PNG previews span the 0.5-99.5 percentiles instead of [0, 1]",
    )


def build_parser():
    """Return the ``lfalias`` argument parser."""
    parser = argparse.ArgumentParser(
        prog="lfalias",
        description="Light-field decoding, refocusing, and angular-aliasing detection and reduction "
        "(Xiao et al., CVPR 2014).",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    from . import __version__

    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    parser.add_argument("-q", "--quiet", action="store_true", help="print no timings or progress")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    def command(name, help_text, example):
        sub = commands.add_parser(
            name, help=help_text, description=help_text, epilog=f"example:\n  {example}",
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
        # Also accepted after the command; SUPPRESS keeps `lfalias -q CMD` from being reset.
        sub.add_argument("-q", "--quiet", action="store_true", default=argparse.SUPPRESS,
                         help="print no timings or progress")
        return sub

    sub = command("convert", "decode a capture into views: ImageJ hyperstack TIFF or zarr store",
                  "lfalias convert capture.tif --white white.tif --dark dark.tif -o views.tif --save-grid grid.json")
    _add_input(sub)
    _add_output(sub, "output .tif/.tiff (ImageJ hyperstack, axes TZCYX = U V C Y X) or .zarr")
    sub.add_argument("--save-grid", metavar="JSON", help="also write the calibrated lenslet grid model")

    # name, help, example, output help, detection options, --levels, --auto-contrast
    image_commands = [
        ("refocus", "shift-and-add refocus on one slope", "lfalias refocus views.tif --slope 0.5 -o refocus.png",
         "image: .png (8-bit preview) or .tif (float32)", False, False, True),
        ("detect", "detect angular aliasing (Algorithm 1): Cv map and mask",
         "lfalias detect views.tif --slope 0.5 --method monte_carlo --seed 1 -o cv.png",
         "Cv map: .png (threshold at mid-grey) or .tif (float32); the mask goes to <name>_mask", True, False, False),
        ("reduce", "reduce angular aliasing (Algorithm 2): multi-level gradient-domain fusion",
         "lfalias reduce views.tif --slope 0.5 --levels 3 -o reduced.png",
         "fused image: .png or .tif; level map and Cv map go to <name>_levels and <name>_cv", True, True, True),
    ]
    for name, help_text, example, out_help, detection, levels, contrast in image_commands:
        sub = command(name, help_text, example)
        _add_input(sub)
        _add_slope(sub)
        _add_output(sub, out_help)
        if detection:
            add_detection_options(sub)
        if levels:
            _add_levels(sub)
        if contrast:
            _add_contrast(sub)

    sub = command("info", "say what a file or folder holds: format, grid, views, disparity range",
                  "lfalias info capture.tif --white white.tif")
    _add_input(sub)
    sub.add_argument("--json", action="store_true", help="print the facts as JSON")

    sub = command("demo", "run the whole pipeline on the bundled GUV capture and time each stage",
                  "lfalias demo --out lfalias-demo --overwrite")
    sub.add_argument("-o", "--out", default="lfalias-demo", metavar="DIR", help="output folder (default ./lfalias-demo)")
    sub.add_argument("--overwrite", action="store_true", help="replace the files of an earlier run")
    _add_slope(sub, required=False)
    add_detection_options(sub)
    _add_levels(sub)

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
    lenslet = sub.add_argument_group("lenslet capture")
    lenslet.add_argument("--white", metavar="FILE")
    lenslet.add_argument("--dark", metavar="FILE")
    lenslet.add_argument("--grid", metavar="JSON")
    _add_slope(sub, required=False)
    add_detection_options(sub)
    _add_levels(sub)
    return parser


def _dispatch(args, stream):
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
        return _dispatch(args, sys.stdout)
    except LightFieldError as exc:
        sys.stderr.write(f"lfalias: error: {_one_line(exc)}\n")
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


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
