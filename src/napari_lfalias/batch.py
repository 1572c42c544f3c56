"""Scale-out: conversions and reductions of many inputs as dask distributed tasks.

Each input is one task. A task writes its outputs atomically and then a
*done marker* (``<out>/.lfalias-batch/<name>.<task>.json``) holding a key
of the input (path, size, modification time) and of the options; a re-run
skips the inputs whose marker matches and whose outputs are all there. A
worker lost mid-task loses nothing: the scheduler runs the task again on
another worker, and the temporary file the lost worker was writing is
removed when the batch ends (no partial file ever stands under a final
name).

One batch at a time per output folder: temporaries left in it are removed
at the start and at the end of a run.

Examples
--------
>>> from napari_lfalias.batch import run_batch                  # doctest: +SKIP
>>> report = run_batch(["a.tif", "b.tif"], "views/", task="convert",
...                    white="white.tif", workers=2)             # doctest: +SKIP
>>> report.done, report.skipped                                 # doctest: +SKIP
"""

from __future__ import annotations

import hashlib
import logging
import json
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

from . import io_write
from .errors import LightFieldError, OutputExistsError, ParameterError

__all__ = ["TASKS", "Job", "BatchReport", "plan_batch", "run_job", "run_batch", "local_client"]

#: What a batch can do with each input.
TASKS = ("convert", "reduce")
MARKER_DIR = ".lfalias-batch"


@dataclass(frozen=True)
class Job:
    """One input and what to do with it.

    Attributes
    ----------
    source : str
        The input (file or folder).
    task : str
        ``"convert"`` or ``"reduce"``.
    outputs : tuple of str
        The files (or zarr folders) the task writes.
    marker : str
        The done marker, written after the outputs.
    key : str
        Hash of the input's identity and of the options.
    options : dict
        Lenslet options (``white``, ``dark``, ``grid`` as JSON text) and,
        for reductions, the parameters of :func:`reduce_aliasing`.
    """

    source: str
    task: str
    outputs: tuple
    marker: str
    key: str
    options: dict = field(hash=False)

    def is_done(self):
        """True when the marker matches this job and every output exists."""
        try:
            marker = json.loads(Path(self.marker).read_text())
        except (OSError, ValueError):
            return False
        return marker.get("key") == self.key and all(Path(p).exists() for p in self.outputs)


@dataclass
class BatchReport:
    """What a batch did: outputs written, inputs skipped, inputs that failed."""

    done: list = field(default_factory=list)
    skipped: list = field(default_factory=list)
    failed: dict = field(default_factory=dict)
    seconds: float = 0.0

    @property
    def ok(self):
        return not self.failed


def _input_identity(path):
    """Size and modification time of a file, or of every file in a folder."""
    path = Path(path)
    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    return [(str(p.relative_to(path)) if path.is_dir() else p.name, p.stat().st_size, p.stat().st_mtime_ns)
            for p in files]


def _job_key(source, task, options):
    identity = {"source": str(Path(source).resolve()), "files": _input_identity(source),
                "task": task, "options": options}
    return hashlib.sha256(json.dumps(identity, sort_keys=True, default=str).encode()).hexdigest()


def _output_names(source, task, out_dir, fmt):
    stem = Path(source).name
    for suffix in (".tif", ".tiff", ".zarr", ".png"):
        if stem.lower().endswith(suffix):
            stem = stem[: -len(suffix)]
    if task == "convert":
        return stem, (out_dir / f"{stem}.{fmt}",)
    return stem, (out_dir / f"{stem}_reduced.tif", out_dir / f"{stem}_levels.tif", out_dir / f"{stem}_reduced.png")


def _reduce_options(slope, detect_kw):
    if slope is None:
        raise ParameterError("--task reduce needs --slope (the disparity in focus)")
    from ._validate import finite_float

    return {"slope": finite_float("slope", slope), **detect_kw}


def plan_batch(inputs, out_dir, task="convert", fmt="tif", overwrite=False, lenslet=None, slope=None, **detect_kw):
    """Make the jobs of a batch and check them before anything runs.

    Parameters
    ----------
    inputs : sequence of str or Path
        The inputs.
    out_dir : str or Path
        Output folder (created).
    task : {"convert", "reduce"}
    fmt : {"tif", "zarr"}
        Light-field format of conversions.
    overwrite : bool
        Allow replacing outputs that exist without a marker of this batch.
    lenslet : dict, optional
        ``white``, ``dark`` (paths) and ``grid`` (a GridModel's JSON text).
    slope : float, optional
        Needed by ``task="reduce"``.
    **detect_kw
        ``gamma``, ``n_patterns``, ``threshold``, ``method``, ``seed``,
        ``max_level`` of a reduction.

    Returns
    -------
    list of Job

    Raises
    ------
    ParameterError
        For no inputs, a missing input, two inputs with the same output name,
        or a missing slope.
    OutputExistsError
        If an output exists that no earlier run of a batch wrote, and
        ``overwrite`` is false.
    """
    from ._validate import one_of

    one_of("task", task, TASKS)
    one_of("format", fmt, ("tif", "zarr"))
    if not inputs:
        raise ParameterError("no inputs given")
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise ParameterError(f"{out_dir}: --out must be a folder")
    options = {**(lenslet or {})}
    if task == "reduce":
        options.update(_reduce_options(slope, detect_kw))
    jobs, names = [], {}
    for source in inputs:
        source = Path(source)
        if not source.exists():
            raise ParameterError(f"{source}: no such input file or folder")
        stem, outputs = _output_names(source, task, out_dir, fmt)
        if stem in names:
            raise ParameterError(f"{source} and {names[stem]} would both write {outputs[0].name}; rename one")
        names[stem] = source
        marker = out_dir / MARKER_DIR / f"{stem}.{task}.json"
        key = _job_key(source, task, options)
        jobs.append(Job(str(source), task, tuple(str(p) for p in outputs), str(marker), key, options))
    if not overwrite:
        for job in jobs:
            ours = Path(job.marker).exists()
            clash = next((p for p in job.outputs if Path(p).exists()), None)
            if clash and not ours:
                raise OutputExistsError(f"{clash}: output exists and no batch wrote it; pass --overwrite to replace it")
    return jobs


def _write_marker(job, state, extra=None):
    Path(job.marker).parent.mkdir(parents=True, exist_ok=True)
    record = {"key": job.key, "state": state, "source": job.source, "outputs": list(job.outputs), **(extra or {})}
    io_write.write_json(job.marker, record, overwrite=True)


def _open_job_input(job):
    from ._inputs import open_input

    grid = job.options.get("grid")
    if grid:
        from .decoders.lenslet import GridModel

        grid = GridModel.from_json(grid)
    return open_input(job.source, white=job.options.get("white"), dark=job.options.get("dark"), grid=grid)


def _run_reduce(job, lf):
    from .reduce import reduce_aliasing

    params = {k: job.options[k] for k in ("gamma", "n_patterns", "threshold", "method", "seed", "max_level")
              if k in job.options}
    result = reduce_aliasing(lf, job.options["slope"], **params)
    metadata = {"source": job.source, "slope": job.options["slope"], **params}
    image_out, levels_out, preview_out = job.outputs
    io_write.write_image(image_out, result.image, metadata, overwrite=True)
    io_write.write_image(levels_out, result.level.astype("uint8"), metadata, overwrite=True)
    io_write.write_image(preview_out, result.image, overwrite=True)


def run_job(job):
    """Run one job (on a worker); return ``(source, status, detail)``.

    ``status`` is ``"done"``, ``"skipped"`` or ``"failed"`` (a
    :class:`LightFieldError`: bad input, not worth retrying; its one-line
    message is ``detail``). Other errors propagate, so dask retries the
    task.
    """
    if job.is_done():
        return job.source, "skipped", ""
    start = time.perf_counter()
    _write_marker(job, "running", {"host": os.uname().nodename, "pid": os.getpid()})
    try:
        lf = _open_job_input(job)
        if job.task == "convert":
            io_write.write_lightfield(job.outputs[0], lf, overwrite=True)
        else:
            _run_reduce(job, lf)
    except LightFieldError as exc:
        return job.source, "failed", " ".join(str(exc).split())
    seconds = time.perf_counter() - start
    _write_marker(job, "done", {"seconds": seconds, "host": os.uname().nodename, "pid": os.getpid()})
    return job.source, "done", f"{seconds:.3f} s"


def local_client(workers=None):
    """A dask ``Client`` on a new local cluster of single-threaded worker processes (127.0.0.1)."""
    from distributed import Client, LocalCluster

    workers = workers or min(4, os.cpu_count() or 1)
    if workers < 1:
        raise ParameterError(f"workers must be >= 1, got {workers}")
    # Task failures are reported by run_batch; the workers' own logs would repeat them.
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                           dashboard_address=None, silence_logs=logging.CRITICAL)
    return Client(cluster)


def _clean(out_dir):
    for folder in (out_dir, out_dir / MARKER_DIR):
        if folder.is_dir():
            io_write.remove_temporaries(folder)


def _calibrated_grid(lenslet, first_input):
    """Calibrate once for the whole batch; the tasks get the grid model as JSON."""
    if not lenslet.get("white") or lenslet.get("grid"):
        return lenslet
    from ._inputs import open_input

    lf = open_input(first_input, white=lenslet["white"], dark=lenslet.get("dark"))
    grid = lf.meta.get("grid")
    return {**lenslet, "grid": grid.to_json()} if hasattr(grid, "to_json") else lenslet


def run_batch(inputs, out_dir, task="convert", *, scheduler=None, workers=None, client=None, fmt="tif",
              overwrite=False, white=None, dark=None, grid=None, slope=None, retries=2, progress=None,
              **detect_kw):
    """Convert or reduce many inputs as dask tasks.

    Parameters
    ----------
    inputs : sequence of str or Path
        Folders of views, lenslet captures (with ``white``), or light fields
        written by ``lfalias convert``.
    out_dir : str or Path
        Output folder, created if missing.
    task : {"convert", "reduce"}
    scheduler : str, optional
        Address of a running dask scheduler (``tcp://host:8786``). Default:
        a local cluster of ``workers`` processes on 127.0.0.1.
    workers : int, optional
        Size of the local cluster (default: CPU count, at most 4).
    client : distributed.Client, optional
        Use this client (and its cluster) instead.
    fmt : {"tif", "zarr"}
        Light-field format of conversions.
    overwrite : bool
        Replace outputs that exist but were not written by a batch.
    white, dark : str or Path, optional
        Lenslet white and dark frames (shared by every input).
    grid : GridModel or str or Path, optional
        Lenslet grid model (or its JSON file). Without it, the grid is
        calibrated once from ``white`` and shared by every task.
    slope : float, optional
        The slope of ``task="reduce"``.
    retries : int
        Times a task that raised an unexpected error is run again.
    progress : callable, optional
        Called with ``(source, status, detail)`` as each task ends.
    **detect_kw
        ``gamma``, ``n_patterns``, ``threshold``, ``method``, ``seed``,
        ``max_level`` of a reduction.

    Returns
    -------
    BatchReport
    """
    from ._inputs import lenslet_options

    start = time.perf_counter()
    lenslet = {k: str(Path(v).resolve()) for k, v in (("white", white), ("dark", dark)) if v is not None}
    if grid is not None:
        lenslet["grid"] = lenslet_options(grid=grid)["grid"].to_json()
    out_dir = Path(out_dir)
    jobs = plan_batch(inputs, out_dir, task, fmt, overwrite, lenslet, slope, **detect_kw)
    out_dir.mkdir(parents=True, exist_ok=True)
    _clean(out_dir)
    report = BatchReport()
    todo = []
    for job in jobs:
        if job.is_done():
            report.skipped.append(job.source)
            if progress:
                progress(job.source, "skipped", "")
        else:
            todo.append(job)
    if todo:
        if lenslet.get("white") and not lenslet.get("grid"):
            shared = _calibrated_grid(lenslet, todo[0].source)
            todo = [Job(j.source, j.task, j.outputs, j.marker, j.key, {**j.options, **shared}) for j in todo]
        _run_jobs(todo, report, scheduler, workers, client, retries, progress)
    _clean(out_dir)
    report.seconds = time.perf_counter() - start
    return report


def _run_jobs(jobs, report, scheduler, workers, client, retries, progress):
    from distributed import Client, as_completed

    own = client is None
    if own:
        client = Client(scheduler) if scheduler else local_client(workers)
    try:
        futures = client.map(run_job, jobs, retries=retries, pure=False)
        sources = {future.key: job.source for future, job in zip(futures, jobs)}
        for future in as_completed(futures):
            try:
                source, status, detail = future.result()
            except Exception as exc:  # noqa: BLE001 - retries spent, or workers lost too often
                source, status, detail = sources[future.key], "failed", f"{type(exc).__name__}: {exc}"
            if status == "failed":
                report.failed[source] = detail
            elif status == "skipped":
                report.skipped.append(source)
            else:
                report.done.append(source)
            if progress:
                progress(source, status, detail)
    finally:
        if own:
            cluster = client.cluster
            client.close()
            if cluster is not None and not scheduler:
                cluster.close()
