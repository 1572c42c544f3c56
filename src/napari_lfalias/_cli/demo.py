"""The ``demo`` subcommand: a real capture end to end, and a scene where aliasing is strong and known.

1. The bundled GUV capture (:mod:`.demo_guv`): decode, disparity, a sweep
   for the most aliased slope (or ``--slope``), refocus, detect, reduce,
   with the time of each stage and what was found.
2. The paper's brick room (:mod:`.demo_room`), focused on its cube: the
   naive refocus, the reduction (the default, or the run's options) and
   ``preset="paper"``, each scored against the dense-aperture reference
   over the image, the aliased and the clean pixels; ``overview.png`` shows
   them side by side with their errors, the detected and the truly aliased
   pixels, and the estimated disparity.

Without the lenslet decoder or the bundled capture, part 1 is left out and
the run says so. Every file is checked before any work starts.
"""

from __future__ import annotations

import time
from pathlib import Path

from .. import io_write
from .._inputs import check_reduce_options, resolved_options
from ..errors import ParameterError
from .commands import detect_options, reduce_options
from .demo_guv import GUV_OUTPUTS, guv_files, run_guv
from .demo_room import ROOM_FILES, run_room
from .outputs import check_outputs
from .progress import Stages

__all__ = ["run_demo", "demo_files", "DEMO_FILES"]

#: Every file a full run writes into its folder.
DEMO_FILES = ROOM_FILES + GUV_OUTPUTS + ("summary.json",)


def _lenslet_decoder_available():
    try:
        from ..decoders import lenslet  # noqa: F401
    except ImportError:
        return False
    return True


def _guv_or_why():
    """The GUV files, or ``None`` and why they cannot be used."""
    files = guv_files()
    if files is None:
        return None, "the bundled GUV sample is missing"
    if not _lenslet_decoder_available():
        return None, "the lenslet decoder is not installed"
    return files, None


def demo_files(with_guv):
    """The files a run writes: :data:`DEMO_FILES`, less the GUV part's without it."""
    return tuple(name for name in DEMO_FILES if with_guv or name not in GUV_OUTPUTS)


#: Options that change the reduction from the default (their argparse defaults mean "not given").
_CHOICES = ("method", "preset", "threshold", "gamma", "n", "seed", "levels")


def _user_given(args):
    return any(getattr(args, name) is not None for name in _CHOICES) or args.threshold_scale != "cv" \
        or args.solver != "auto" or args.keep_in_focus


def run_demo(args, stream):
    """Run ``lfalias demo``: return 0, having written :func:`demo_files` into ``args.out``."""
    started = time.perf_counter()
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ParameterError(f"{out}: --out must be a folder")
    files, why = _guv_or_why()
    paths = {name: out / name for name in demo_files(files is not None)}
    if out.is_dir():
        check_outputs(paths.values(), args.overwrite)
    options, detection = reduce_options(args), detect_options(args)
    check_reduce_options(0.0 if args.slope is None else args.slope, **options)
    options, detection = resolved_options(**options), resolved_options(**detection)

    n_guv = 0 if files is None else 6 + (args.slope is None)
    stages = Stages(n_guv + 6, quiet=args.quiet, stream=stream)
    out.mkdir(parents=True, exist_ok=True)
    summary = {"options": options}
    if files is None:
        stream.write(f"note: {why}; showing the synthetic brick room only\n")
    else:
        summary["guv"] = run_guv(files, args.slope, options, detection, args.quiet, paths, args.overwrite, stages,
                                 stream)
    summary["brick_room"] = run_room(options, _user_given(args), args.seed, args.quiet, paths, args.overwrite,
                                     stages, stream)
    summary["seconds"] = dict(stages.seconds)
    # Everything since the command started: the stages, and loading the compiled kernels on first use.
    summary["seconds"]["all (wall)"] = time.perf_counter() - started
    io_write.write_json(paths["summary.json"], summary, overwrite=args.overwrite)
    timing = "" if args.quiet else (f"total {stages.total_seconds:.2f} s in the stages, "
                                     f"{time.perf_counter() - started:.2f} s in all; ")
    stream.write(f"{timing}{len(paths)} files in {out}/ (start with overview.png)\n")
    return 0
