"""Batch scale-out: serial jobs vs a dask LocalCluster of 1 and 2 worker processes.

    .venv/bin/python benchmarks/bench_batch.py [--inputs 8] [--repeats 3] [--task convert|reduce]

Writes ``benchmarks/results/batch_scaleout.md``. Every run converts (or
reduces) the same inputs into a fresh folder; the cluster is started once
per size and its start-up time is reported apart. Quote medians: this
machine is shared, so single timings are noisy.
"""

from __future__ import annotations

import argparse
import logging
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import napari_lfalias as lfa
from napari_lfalias import io_write
from napari_lfalias.batch import plan_batch, run_batch, run_job

RESULTS = Path(__file__).resolve().parent / "results" / "batch_scaleout.md"


def make_inputs(folder, count, n_views, size):
    rng = np.random.default_rng(0)
    paths = []
    for i in range(count):
        data = rng.random((n_views, n_views, size, size, 3), dtype=np.float32)
        path = folder / f"input{i}.tif"
        io_write.write_lightfield(path, lfa.LightField(data))
        paths.append(path)
    return paths


def timed(function):
    start = time.perf_counter()
    function()
    return time.perf_counter() - start


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--inputs", type=int, default=8)
    parser.add_argument("--views", type=int, default=9)
    parser.add_argument("--size", type=int, default=128)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--task", choices=("convert", "reduce"), default="convert")
    args = parser.parse_args(argv)
    from distributed import Client, LocalCluster

    options = {"fmt": "zarr"} if args.task == "convert" else {"slope": 1.0, "max_level": 2}
    work = Path(tempfile.mkdtemp(prefix="bench_batch_"))
    try:
        (work / "in").mkdir()
        inputs = make_inputs(work / "in", args.inputs, args.views, args.size)
        counter = iter(range(10**6))

        def fresh():
            return work / f"out{next(counter)}"

        def serial():
            out = fresh()
            out.mkdir()
            for job in plan_batch(inputs, out, args.task, **options):
                run_job(job)

        rows = [("serial (this process)", "-", statistics.median(timed(serial) for _ in range(args.repeats)))]
        for workers in (1, 2):
            start = time.perf_counter()
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                                   dashboard_address=None, silence_logs=logging.ERROR)
            client = Client(cluster)
            startup = time.perf_counter() - start
            seconds = [timed(lambda: run_batch(inputs, fresh(), args.task, client=client, **options))
                       for _ in range(args.repeats)]
            client.close()
            cluster.close()
            rows.append((f"LocalCluster, {workers} worker process(es)", f"{startup:.2f}", statistics.median(seconds)))
    finally:
        shutil.rmtree(work, ignore_errors=True)

    base = rows[0][2]
    lines = [
        "# Batch scale-out: serial vs dask LocalCluster",
        "",
        "Command: `" + " ".join([".venv/bin/python benchmarks/bench_batch.py", *(argv or sys.argv[1:])]) + "`",
        "",
        f"Task `{args.task}` of {args.inputs} light fields of {args.views} x {args.views} views, "
        f"{args.size} x {args.size} px, 3 channels (float32 light-field TIFF inputs"
        f"{', zarr outputs' if args.task == 'convert' else ''}). Median of {args.repeats} runs; "
        f"machine: {__import__('os').cpu_count()} cores, shared.",
        "",
        "| run | cluster start-up (s) | batch (s, median) | vs serial |",
        "|---|---|---|---|",
    ]
    lines += [f"| {name} | {startup} | {seconds:.2f} | {seconds / base:.2f}x |" for name, startup, seconds in rows]
    RESULTS.parent.mkdir(exist_ok=True)
    RESULTS.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
