"""The ``batch`` subcommand: many inputs as dask tasks."""

from __future__ import annotations

import sys
from pathlib import Path

from .._inputs import resolved_options
from ..cli import as_flags
from ..errors import ParameterError
from .commands import reduce_options, refuse_unless_rendered
from .progress import Progress

__all__ = ["run_batch_command"]


def run_batch_command(args, stream):
    """Run ``lfalias batch``; exit status 1 when any input failed."""
    from ..batch import run_batch

    reduction = reduce_options(args) if args.task == "reduce" else {}
    if args.nearer is not None:
        if args.task != "reduce":
            raise ParameterError("--nearer is used by --task reduce (a conversion renders nothing)")
        refuse_unless_rendered("--nearer", args, resolved_options(**reduction)["method"])
        reduction["nearer"] = args.nearer
    bar = Progress(len(args.inputs), f"batch {args.task}", quiet=args.quiet)
    failures = []

    def progress(source, status, detail):
        bar.update()
        if status == "failed":  # the detail names the input itself where it comes from a reader
            named = detail.startswith((source, str(Path(source).absolute())))
            failures.append(as_flags(detail if named else f"{source}: {detail}"))

    report = run_batch(
        args.inputs, args.out, args.task, scheduler=args.scheduler, workers=args.workers, fmt=args.format,
        overwrite=args.overwrite, white=args.white, dark=args.dark, grid=args.grid, slope=args.slope,
        nonfinite=args.nonfinite, progress=progress, **reduction,
    )
    bar.close()
    stream.write(f"{len(report.done)} done, {len(report.skipped)} skipped (already done), "
                 f"{len(report.failed)} failed in {report.seconds:.1f} s -> {args.out}\n")
    for line in failures:
        sys.stderr.write(f"lfalias: error: {line}\n")
    return 0 if report.ok else 1
