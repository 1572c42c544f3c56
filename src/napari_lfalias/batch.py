"""Scale-out: conversions and reductions of many inputs as dask distributed tasks.

Each input is one task. A task writes its outputs atomically and then a
*done marker* (``<out>/.lfalias-batch/<name>.<task>.json``) holding a key
of the input (path, size, modification time) and of the options, and the
size of every output file; a re-run skips the inputs whose marker matches
and whose outputs are all there at the sizes recorded (a truncated or
replaced output is done again). A worker lost mid-task loses nothing: the
scheduler runs the task again on another worker, and the temporary file
the lost worker was writing is removed when the batch ends (no partial
file ever stands under a final name).

When one input kills its workers again and again, dask gives up on it
(``KilledWorker``), and on the inputs that were queued on those workers
too, although they never ran: the marker says whether a task started, so
those are submitted again and only the input that ran is reported. An
input that does not exist fails alone, as an unreadable one does.

One batch at a time per output folder: temporaries left in it are removed
at the start and at the end of a run.

Examples
--------
Convert two lenslet captures on a local cluster of two workers (it needs
the captures and their white image; ``tests/test_batch.py`` runs this on
real files)::

    from napari_lfalias.batch import run_batch

    report = run_batch(["a.tif", "b.tif"], "views/", task="convert", white="white.tif", workers=2)
    print(report.done, report.skipped)
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import logging
import json
import os
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path

from . import io_write
from ._inputs import check_reduce_options
from .errors import LightFieldError, OutputExistsError, ParameterError

__all__ = ["TASKS", "REDUCE_OPTIONS", "Job", "BatchReport", "plan_batch", "run_job", "run_batch", "local_client",
           "kernel_thread_budget"]

#: What a batch can do with each input.
TASKS = ("convert", "reduce")
#: Keyword options of :func:`~napari_lfalias.reduce_aliasing` a reduction batch passes on.
REDUCE_OPTIONS = ("gamma", "n_patterns", "threshold", "threshold_scale", "method", "seed", "max_level", "solver",
                  "keep_in_focus", "nearer", "preset")
MARKER_DIR = ".lfalias-batch"


@dataclass(frozen=True)
class Job:
    """One input and what to do with it.

    Attributes
    ----------
    source : str
        The input (file or folder), absolute, so that workers on other
        machines (sharing the file system) find it.
    task : str
        ``"convert"`` or ``"reduce"``.
    outputs : tuple of str
        The files (or zarr folders) the task writes, absolute.
    marker : str
        The done marker, written after the outputs.
    key : str
        Hash of the input's identity and of the options.
    options : dict
        Lenslet options (``white``, ``dark``, ``grid`` as JSON text) and,
        for reductions, the parameters of :func:`reduce_aliasing`.
    label : str
        The input as the user gave it (what reports and messages show).
    attempt : str
        Which submission of the job this is (written to the marker when the
        task starts, so that the batch can tell a task that never ran).
    """

    source: str
    task: str
    outputs: tuple
    marker: str
    key: str
    options: dict = field(hash=False)
    label: str = ""
    attempt: str = ""

    def _marker(self):
        try:
            marker = json.loads(Path(self.marker).read_text())
        except (OSError, ValueError):
            return {}
        return marker if isinstance(marker, dict) else {}

    def is_done(self):
        """True when the marker says this job (same key) finished, and every output is there as written.

        A marker left in state ``"running"`` (a task killed between two of its
        outputs) never counts, even when older outputs stand under every name;
        nor does an output whose size differs from the one the marker
        recorded (truncated, or replaced by something else).
        """
        marker = self._marker()
        return (marker.get("key") == self.key and marker.get("state") == "done"
                and marker.get("sizes") == {p: _output_size(p) for p in self.outputs})

    def started(self):
        """True when the marker shows that this submission (:attr:`attempt`) of the job began."""
        return bool(self.attempt) and self._marker().get("attempt") == self.attempt


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


def _output_size(path):
    """The size of an output file, or of every file of an output folder (a zarr store); None if missing."""
    path = Path(path)
    if path.is_dir():
        return {str(p.relative_to(path)): p.stat().st_size for p in sorted(path.rglob("*")) if p.is_file()}
    return path.stat().st_size if path.is_file() else None


def _input_identity(path):
    """Size and modification time of a file, or of every file in a folder."""
    path = Path(path)
    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    return [(str(p.relative_to(path)) if path.is_dir() else p.name, p.stat().st_size, p.stat().st_mtime_ns)
            for p in files]


def _job_key(source, task, options):
    frames = {name: _input_identity(options[name]) for name in ("white", "dark") if options.get(name)}
    identity = {"source": str(Path(source).resolve()), "files": _input_identity(source), "frames": frames,
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
        raise ParameterError("task='reduce' needs slope= (the disparity in focus)")
    from ._validate import finite_float

    unknown = sorted(set(detect_kw) - set(REDUCE_OPTIONS))
    if unknown:
        raise ParameterError(f"unknown reduction option(s) {', '.join(unknown)}; accepted: {', '.join(REDUCE_OPTIONS)}")
    slope = finite_float("slope", slope)
    # Checked here, once, rather than once per input on the workers.
    check_reduce_options(slope, **detect_kw)
    return {"slope": slope, **detect_kw}


def plan_batch(inputs, out_dir, task="convert", fmt="tif", overwrite=False, lenslet=None, slope=None, *,
               skip_missing=False, **detect_kw):
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
        How to open the inputs: ``white``, ``dark`` (paths), ``grid`` (a
        GridModel's JSON text) and ``nonfinite``.
    slope : float, optional
        Needed by ``task="reduce"``.
    skip_missing : bool
        Leave inputs that do not exist out of the plan (:func:`run_batch`
        reports them as failed) instead of refusing the batch.
    **detect_kw
        Options of :func:`~napari_lfalias.reduce_aliasing` (``REDUCE_OPTIONS``:
        ``gamma``, ``n_patterns``, ``threshold``, ``threshold_scale``,
        ``method``, ``seed``, ``max_level``, ``solver``, ``keep_in_focus``).

    Returns
    -------
    list of Job

    Raises
    ------
    ParameterError
        For no inputs, a missing input, two inputs with the same output name,
        an output that is an input or lies in an input folder, or a bad option.
    OutputExistsError
        If an output exists that no earlier run of a batch wrote, and
        ``overwrite`` is false.
    """
    from ._validate import one_of

    one_of("task", task, TASKS)
    one_of("format", fmt, ("tif", "zarr"))
    if not inputs:
        raise ParameterError("no inputs given")
    out_dir = Path(out_dir).absolute()
    if out_dir.exists() and not out_dir.is_dir():
        raise ParameterError(f"{out_dir}: out_dir must be a folder")
    options = {**(lenslet or {})}
    if task == "reduce":
        options.update(_reduce_options(slope, detect_kw))
    elif slope is not None or detect_kw:
        given = sorted(detect_kw) + (["slope"] if slope is not None else [])
        raise ParameterError(f"{', '.join(given)}: reduction options apply to task='reduce' only")
    jobs, names = [], {}
    for given in inputs:
        if not Path(given).exists():
            if skip_missing:
                continue
            raise ParameterError(f"{given}: no such input file or folder")
        source = Path(given).absolute()
        stem, outputs = _output_names(source, task, out_dir, fmt)
        if stem in names:
            raise ParameterError(f"{given} and {names[stem]} would both write {outputs[0].name}; rename one")
        names[stem] = given
        marker = out_dir / MARKER_DIR / f"{stem}.{task}.json"
        key = _job_key(source, task, options)
        jobs.append(Job(str(source), task, tuple(str(p) for p in outputs), str(marker), key, options, str(given)))
    given = [*inputs, *(options.get(name) for name in ("white", "dark"))]
    io_write.check_not_inputs([out_dir / MARKER_DIR, *(p for job in jobs for p in job.outputs)], given)
    if not overwrite:
        for job in jobs:
            ours = Path(job.marker).exists()
            clash = next((p for p in job.outputs if Path(p).exists()), None)
            if clash and not ours:
                raise OutputExistsError(f"{clash}: output exists and no batch wrote it; pass overwrite=True to replace it")
    return jobs


def _write_marker(job, state, extra=None):
    Path(job.marker).parent.mkdir(parents=True, exist_ok=True)
    record = {"key": job.key, "state": state, "source": job.source, "outputs": list(job.outputs),
              "attempt": job.attempt, **(extra or {})}
    io_write.write_json(job.marker, record, overwrite=True)


def _open_job_input(job):
    from ._inputs import open_input

    grid = job.options.get("grid")
    if isinstance(grid, str):  # a lenslet grid model, as JSON
        from .decoders.lenslet import GridModel

        grid = GridModel.from_json(grid)
    elif grid is not None:  # a view grid (U, V)
        grid = tuple(grid)
    return open_input(job.source, white=job.options.get("white"), dark=job.options.get("dark"), grid=grid,
                      nonfinite=job.options.get("nonfinite"))


def _run_reduce(job, lf):
    from .reduce import reduce_aliasing

    params = {k: job.options[k] for k in REDUCE_OPTIONS if k in job.options}
    result = reduce_aliasing(lf, job.options["slope"], **params)
    metadata = {"source": job.source, "slope": job.options["slope"], **params}
    image_out, levels_out, preview_out = job.outputs
    io_write.write_image(image_out, result.image, metadata, overwrite=True)
    io_write.write_image(levels_out, result.level.astype("uint8"), metadata, overwrite=True)
    io_write.write_image(preview_out, result.image, overwrite=True)


def kernel_thread_budget(client):
    """Threads the compiled kernels of one task may use, per worker address.

    dask already runs one task per worker thread; kernels that also use
    every core oversubscribe the machine (2 single-threaded workers on 2
    cores ran reductions 4x slower than serially). Each worker's tasks get
    the cores of its host divided by the task threads of every worker on
    that host, at least 1.

    Returns
    -------
    dict
        Worker address -> number of threads.
    """
    from distributed.comm import get_address_host

    def probe(dask_worker):
        return dask_worker.state.nthreads, os.cpu_count() or 1

    info = client.run(probe)
    threads_on_host = {}
    for address, (nthreads, _) in info.items():
        host = get_address_host(address)
        threads_on_host[host] = threads_on_host.get(host, 0) + nthreads
    return {address: max(1, cores // threads_on_host[get_address_host(address)])
            for address, (_, cores) in info.items()}


@contextlib.contextmanager
def _kernel_threads(budget):
    """Limit the compiled kernels of this task to its share of the worker's host (see above)."""
    try:
        from distributed import get_worker

        address = get_worker().address
    except (ImportError, ValueError):  # not on a dask worker: this process's own settings
        address = None
    if not budget or address is None:
        yield
        return
    import numba

    before = numba.get_num_threads()
    numba.set_num_threads(max(1, min(budget.get(address, 1), numba.config.NUMBA_NUM_THREADS)))
    try:
        yield
    finally:
        numba.set_num_threads(before)


def run_job(job, kernel_threads=None):
    """Run one job (on a worker); return ``(label, status, detail)``.

    ``status`` is ``"done"``, ``"skipped"`` or ``"failed"`` (a
    :class:`LightFieldError`: bad input, not worth retrying; its one-line
    message is ``detail``). Other errors propagate, so dask retries the
    task. ``kernel_threads`` is a :func:`kernel_thread_budget`.
    """
    if job.is_done():
        return job.label, "skipped", ""
    start = time.perf_counter()
    _write_marker(job, "running", {"host": os.uname().nodename, "pid": os.getpid()})
    try:
        with _kernel_threads(kernel_threads):
            lf = _open_job_input(job)
            if job.task == "convert":
                io_write.write_lightfield(job.outputs[0], lf, overwrite=True)
            else:
                _run_reduce(job, lf)
    except LightFieldError as exc:
        return job.label, "failed", " ".join(str(exc).split())
    seconds = time.perf_counter() - start
    _write_marker(job, "done", {"seconds": seconds, "host": os.uname().nodename, "pid": os.getpid(),
                                "sizes": {p: _output_size(p) for p in job.outputs}})
    return job.label, "done", f"{seconds:.3f} s"


def local_client(workers=None):
    """A dask ``Client`` on a new local cluster of single-threaded worker processes (127.0.0.1)."""
    from distributed import Client, LocalCluster

    from ._validate import integer_at_least

    workers = min(4, os.cpu_count() or 1) if workers is None else integer_at_least("workers", workers, 1)
    # Task failures are reported by run_batch; the workers' own logs would repeat them. The
    # scheduler's HTTP endpoint takes any free port: 8787 may be taken by another cluster.
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                           dashboard_address=":0", silence_logs=logging.CRITICAL)
    return Client(cluster)


def _clean(out_dir):
    for folder in (out_dir, out_dir / MARKER_DIR):
        if folder.is_dir():
            io_write.remove_temporaries(folder)


def _calibrated_grid(lenslet):
    """Calibrate the white image once for the whole batch; the tasks get the grid model as JSON."""
    from .decoders.lenslet import calibrate

    return {**lenslet, "grid": calibrate(lenslet["white"], lenslet.get("dark")).to_json()}


def run_batch(inputs, out_dir, task="convert", *, scheduler=None, workers=None, client=None, fmt="tif",
              overwrite=False, white=None, dark=None, grid=None, slope=None, retries=2, progress=None,
              connect_timeout=30.0, nonfinite=None, **detect_kw):
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
        Called with ``(input, status, detail)`` as each task ends
        (``status``: ``"done"``, ``"skipped"`` or ``"failed"``).
    connect_timeout : float
        Seconds to wait for the ``scheduler`` to answer.
    nonfinite : {"raise", "mask"}, optional
        NaN or Inf samples of an input: it fails (default), or they get
        weight 0 (:func:`napari_lfalias.load`).
    **detect_kw
        Options of :func:`~napari_lfalias.reduce_aliasing` (``REDUCE_OPTIONS``).

    Returns
    -------
    BatchReport
        Inputs (as given) done, skipped and failed (with their one-line errors).

    Raises
    ------
    ParameterError
        For bad options or inputs (see :func:`plan_batch`), missing white or
        dark frames, or a scheduler that cannot be reached; nothing has run.
    OutputExistsError
        See :func:`plan_batch`.
    """
    from ._inputs import lenslet_options

    start = time.perf_counter()
    if client is not None and (scheduler or workers):
        raise ParameterError("give a client, or a scheduler address or a number of local workers, not both")
    if scheduler and workers:
        raise ParameterError(f"workers= sizes the local cluster; the scheduler at {scheduler} has its own workers")
    if workers is not None:
        from ._validate import integer_at_least

        integer_at_least("workers", workers, 1)
    lenslet = {}
    if nonfinite is not None:
        from ._validate import one_of
        from .lightfield import NONFINITE

        lenslet["nonfinite"] = one_of("nonfinite", nonfinite, NONFINITE)
    for name, frame in (("white", white), ("dark", dark)):
        if frame is not None:
            if not Path(frame).is_file():
                raise ParameterError(f"{frame}: no such {name} frame ({name}=)")
            lenslet[name] = str(Path(frame).resolve())
    if grid is not None:
        grid = lenslet_options(grid=grid)["grid"]
        lenslet["grid"] = list(grid) if isinstance(grid, tuple) else grid.to_json()
    out_dir = Path(out_dir)
    jobs = plan_batch(inputs, out_dir, task, fmt, overwrite, lenslet, slope, skip_missing=True, **detect_kw)
    out_dir.mkdir(parents=True, exist_ok=True)
    _clean(out_dir)
    report = BatchReport()
    for given in inputs:
        if not Path(given).exists():
            report.failed[str(given)] = f"{given}: no such input file or folder"
            if progress:
                progress(str(given), "failed", report.failed[str(given)])
    todo = []
    for job in jobs:
        if job.is_done():
            report.skipped.append(job.label)
            if progress:
                progress(job.label, "skipped", "")
        else:
            todo.append(job)
    if todo:
        if lenslet.get("white") and not lenslet.get("grid"):
            shared = _calibrated_grid(lenslet)
            todo = [dataclasses.replace(job, options={**job.options, **shared}) for job in todo]
        _run_jobs(todo, report, scheduler, workers, client, retries, progress, connect_timeout)
    _clean(out_dir)
    report.seconds = time.perf_counter() - start
    return report


def _connect(scheduler, timeout):
    from distributed import Client

    try:
        return Client(scheduler, timeout=timeout)
    except (OSError, ValueError) as exc:  # refused, timed out (TimeoutError is an OSError), bad address
        reason = " ".join(str(exc).split()) or type(exc).__name__
        raise ParameterError(f"scheduler={scheduler}: cannot reach a dask scheduler there ({reason})") from exc


#: Times a task that never started is submitted again after dask gave up on it (``KilledWorker``).
RESUBMITS = 3


def _attempt(job):
    return dataclasses.replace(job, attempt=uuid.uuid4().hex)


def _lost(exc):
    """The one-line report of a task dask gave up on."""
    detail = " ".join(str(exc).split()) or type(exc).__name__
    if type(exc).__name__ == "KilledWorker":
        return ("the workers running it died every time (out of memory, or a crash while reading it?); "
                f"dask gave up on it ({detail})")
    return f"{type(exc).__name__}: {detail}"


def _run_jobs(jobs, report, scheduler, workers, client, retries, progress, connect_timeout):
    from distributed import as_completed

    own = client is None
    if own:
        client = _connect(scheduler, connect_timeout) if scheduler else local_client(workers)
    try:
        budget = kernel_thread_budget(client)
        jobs = [_attempt(job) for job in jobs]
        futures = client.map(run_job, jobs, kernel_threads=budget, retries=retries, pure=False)
        running = {future.key: job for future, job in zip(futures, jobs)}
        resubmitted = dict.fromkeys((job.label for job in jobs), 0)
        pending = as_completed(futures)
        for future in pending:
            job = running.pop(future.key)
            try:
                source, status, detail = future.result()
            except Exception as exc:  # noqa: BLE001 - retries spent, or workers lost too often
                if not job.started() and resubmitted[job.label] < RESUBMITS:
                    # Blamed for deaths on the worker it was queued on: it never ran. Again.
                    resubmitted[job.label] += 1
                    job = _attempt(job)
                    again = client.submit(run_job, job, kernel_threads=budget, retries=retries, pure=False)
                    running[again.key] = job
                    pending.add(again)
                    continue
                source, status, detail = job.label, "failed", _lost(exc)
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
