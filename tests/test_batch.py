"""Batch conversions and reductions on a real dask LocalCluster (2 worker processes)."""

import contextlib
import json
import logging
import os
import signal
import threading
import time
from pathlib import Path

import numpy as np
import pytest

distributed = pytest.importorskip("distributed")

from napari_lfalias import io_write  # noqa: E402
from napari_lfalias.batch import MARKER_DIR, kernel_thread_budget, plan_batch, run_batch, run_job  # noqa: E402
from napari_lfalias.cli import main  # noqa: E402
from napari_lfalias.errors import OutputExistsError, ParameterError  # noqa: E402

from _cli_scenes import plane_lightfield, temporaries, write_views_folder, write_views_with_a_nan  # noqa: E402


@pytest.fixture(scope="module")
def client():
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                       dashboard_address=":0", silence_logs=logging.ERROR)
    client = distributed.Client(cluster)
    yield client
    client.close()
    cluster.close()


def write_inputs(folder, count, **kw):
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for i in range(count):
        path = folder / f"scene{i}.tif"
        io_write.write_lightfield(path, plane_lightfield(disparity=i % 3 - 1, seed=i, **kw))
        paths.append(path)
    return paths


def run_serially(inputs, out_dir, task, **kw):
    """The reference: every job run in this process, one after another."""
    out_dir.mkdir()
    for job in plan_batch(inputs, out_dir, task, **kw):
        assert run_job(job)[1] == "done"
    return out_dir


def assert_same_lightfields(folder_a, folder_b, names):
    for name in names:
        a, b = io_write.read_lightfield(folder_a / name), io_write.read_lightfield(folder_b / name)
        np.testing.assert_array_equal(a.data, b.data)
        np.testing.assert_array_equal(a.positions, b.positions)


def test_convert_batch_matches_the_serial_result(client, tmp_path):
    inputs = write_inputs(tmp_path / "in", 4)
    report = run_batch(inputs, tmp_path / "out", "convert", client=client, fmt="zarr")
    assert sorted(report.done) == sorted(map(str, inputs)) and report.ok
    serial = run_serially(inputs, tmp_path / "serial", "convert", fmt="zarr")
    names = [f"scene{i}.zarr" for i in range(4)]
    assert_same_lightfields(tmp_path / "out", serial, names)
    # ... and both hold the inputs' views.
    for i, name in enumerate(names):
        np.testing.assert_array_equal(io_write.read_lightfield(tmp_path / "out" / name).data,
                                      io_write.read_lightfield(inputs[i]).data)
    assert temporaries(tmp_path) == []


def test_convert_batch_of_view_folders(client, tmp_path):
    import napari_lfalias as lfa

    folders = [write_views_folder(tmp_path / "in" / f"scene{i}", plane_lightfield(disparity=i - 1, seed=i))
               for i in range(3)]
    report = run_batch(folders, tmp_path / "out", "convert", client=client)
    assert len(report.done) == 3
    for i, folder in enumerate(folders):
        converted = io_write.read_lightfield(tmp_path / "out" / f"scene{i}.tif")
        expected = lfa.load(folder)
        np.testing.assert_array_equal(converted.data, expected.data)
        np.testing.assert_array_equal(converted.positions, expected.positions)
    # A new view in one folder changes its key: only that folder is converted again.
    lf = plane_lightfield(disparity=1, seed=0)
    (folders[0] / "view_00_00.png").unlink()
    write_views_folder(tmp_path / "tmp_views", lf)
    (tmp_path / "tmp_views" / "view_00_00.png").rename(folders[0] / "view_00_00.png")
    again = run_batch(folders, tmp_path / "out", "convert", client=client)
    assert again.done == [str(folders[0])] and len(again.skipped) == 2


def test_a_rerun_skips_finished_outputs_and_redoes_changed_inputs(client, tmp_path):
    inputs = write_inputs(tmp_path / "in", 3)
    out = tmp_path / "out"
    run_batch(inputs, out, "convert", client=client)
    stamps = {p.name: p.stat().st_mtime_ns for p in out.glob("*.tif")}
    again = run_batch(inputs, out, "convert", client=client)
    assert again.done == [] and sorted(again.skipped) == sorted(map(str, inputs))
    assert {p.name: p.stat().st_mtime_ns for p in out.glob("*.tif")} == stamps
    # A changed input is converted again; the others are still skipped.
    changed = plane_lightfield(disparity=2, seed=99)
    io_write.write_lightfield(inputs[1], changed, overwrite=True)
    third = run_batch(inputs, out, "convert", client=client)
    assert third.done == [str(inputs[1])] and len(third.skipped) == 2
    np.testing.assert_array_equal(io_write.read_lightfield(out / "scene1.tif").data, changed.data)


def test_outputs_no_batch_wrote_are_kept_unless_overwrite(client, tmp_path):
    inputs = write_inputs(tmp_path / "in", 2)
    out = tmp_path / "out"
    out.mkdir()
    (out / "scene0.tif").write_bytes(b"precious")
    with pytest.raises(OutputExistsError, match="scene0.tif"):
        run_batch(inputs, out, "convert", client=client)
    assert (out / "scene0.tif").read_bytes() == b"precious"
    assert not (out / "scene1.tif").exists()
    report = run_batch(inputs, out, "convert", client=client, overwrite=True)
    assert len(report.done) == 2
    assert io_write.is_lightfield_file(out / "scene0.tif")


@pytest.mark.parametrize("extra", [{}, {"threshold_scale": "angular", "threshold": 0.4, "solver": "dct"}])
def test_reduce_batch_matches_the_serial_result_and_the_api(client, tmp_path, extra):
    import tifffile

    import napari_lfalias as lfa

    inputs = write_inputs(tmp_path / "in", 3, size=40)
    options = {"gamma": 0.2, "threshold": 0.02, "max_level": 2, "method": "analytic", **extra}
    report = run_batch(inputs, tmp_path / "out", "reduce", client=client, slope=0.0, **options)
    assert len(report.done) == 3
    serial = run_serially(inputs, tmp_path / "serial", "reduce", slope=0.0, **options)
    for i in range(3):
        for name in (f"scene{i}_reduced.tif", f"scene{i}_levels.tif"):
            np.testing.assert_array_equal(tifffile.imread(tmp_path / "out" / name), tifffile.imread(serial / name))
        assert (tmp_path / "out" / f"scene{i}_reduced.png").stat().st_size > 0
        expected = lfa.reduce_aliasing(io_write.read_lightfield(inputs[i]), 0.0, **options)
        np.testing.assert_array_equal(tifffile.imread(tmp_path / "out" / f"scene{i}_reduced.tif"),
                                      expected.image[..., 0])
        np.testing.assert_array_equal(tifffile.imread(tmp_path / "out" / f"scene{i}_levels.tif"), expected.level)
    # Scenes 0 and 2 are planes off slope 0: something was fused there.
    assert tifffile.imread(tmp_path / "out" / "scene0_levels.tif").max() > 0


def _kill_a_running_worker(client, markers, killed, deadline):
    """Kill (SIGKILL) the worker process that runs a task, as soon as one is seen running."""
    pids = set(client.run(os.getpid).values())
    while time.monotonic() < deadline and not killed:
        for marker in markers.glob("*.json"):
            if io_write.is_temporary(marker):
                continue  # a marker being written atomically, not a marker
            try:
                record = json.loads(marker.read_text())
            except (OSError, ValueError):
                continue
            if record["state"] == "running" and record["pid"] in pids:
                time.sleep(0.05)  # let it get into its work
                os.kill(record["pid"], signal.SIGKILL)
                killed.append((marker.name, record["pid"]))
                return
        time.sleep(0.005)


def test_a_worker_killed_mid_run_loses_nothing_and_leaves_no_partial_file(client, tmp_path):
    inputs = write_inputs(tmp_path / "in", 8, n=7, size=128, channels=3)
    out = tmp_path / "out"
    killed = []
    killer = threading.Thread(target=_kill_a_running_worker,
                              args=(client, out / MARKER_DIR, killed, time.monotonic() + 60))
    killer.start()
    report = run_batch(inputs, out, "convert", client=client, fmt="zarr")
    killer.join()
    assert killed, "no task was seen running: nothing was killed"
    assert report.ok and len(report.done) == 8
    serial = run_serially(inputs, tmp_path / "serial", "convert", fmt="zarr")
    assert_same_lightfields(out, serial, [f"scene{i}.zarr" for i in range(8)])
    assert temporaries(tmp_path) == []
    # The killed task was run again, by another process, to the end.
    marker_name, pid = killed[0]
    record = json.loads((out / MARKER_DIR / marker_name).read_text())
    assert record["state"] == "done" and record["pid"] != pid


def test_cli_batch_on_a_given_scheduler(client, tmp_path, capsys):
    inputs = write_inputs(tmp_path / "in", 2)
    out = tmp_path / "out"
    argv = ["batch", *map(str, inputs), "--out", str(out), "--scheduler", client.scheduler.address, "-q"]
    assert main(argv) == 0
    assert "2 done, 0 skipped" in capsys.readouterr().out
    assert main(argv) == 0
    assert "0 done, 2 skipped" in capsys.readouterr().out
    for i, path in enumerate(inputs):
        np.testing.assert_array_equal(io_write.read_lightfield(out / f"scene{i}.tif").data,
                                      io_write.read_lightfield(path).data)


def test_cli_batch_reduces_with_the_options_of_reduce_and_a_declared_occlusion_order(client, tmp_path, capsys):
    import tifffile

    import napari_lfalias as lfa
    from napari_lfalias.synthetic import brick_room

    lf = brick_room(n_views=3, size=48, seed=0).lightfield  # the cube (+4) before the wall (-4)
    path = tmp_path / "room.tif"
    io_write.write_lightfield(path, lf)
    base = ["batch", str(path), "--task", "reduce", "--slope", "4", "--scheduler", client.scheduler.address, "-q"]
    images = {}
    for nearer in ("smaller", "larger"):
        out = tmp_path / nearer
        assert main(base + ["--out", str(out), "--nearer", nearer]) == 0
        images[nearer] = tifffile.imread(out / "room_reduced.tif")
        assert tifffile.TiffFile(out / "room_reduced.tif").shaped_metadata[0]["nearer"] == nearer
        np.testing.assert_array_equal(images[nearer], lfa.reduce_aliasing(lf, 4.0, nearer=nearer).image)
    assert not np.array_equal(images["smaller"], images["larger"])
    # the paper's algorithm, as docs/cli.md runs it
    assert main(base + ["--out", str(tmp_path / "paper"), "--preset", "paper", "--seed", "0"]) == 0
    np.testing.assert_array_equal(tifffile.imread(tmp_path / "paper" / "room_reduced.tif"),
                                  lfa.reduce_aliasing(lf, 4.0, preset="paper", seed=0).image)
    capsys.readouterr()
    refused = ((["--task", "convert"], "--task reduce"),
               (["--task", "reduce", "--method", "analytic"], "--method depth"))
    for extra, words in refused:
        argv = ["batch", str(path), "--slope", "4", "--out", str(tmp_path / "x"), "--nearer", "larger", *extra]
        assert main(argv) != 0
        err = capsys.readouterr().err
        assert "--nearer is used by" in err and words in err and "Traceback" not in err
        assert not (tmp_path / "x").exists()


def test_cli_batch_passes_nonfinite_to_every_input(client, tmp_path, capsys):
    folder = write_views_with_a_nan(tmp_path / "views", grid=(3, 3), shape=(16, 20), at=(1, 2, 4, 5))
    base = ["batch", str(folder), "--scheduler", client.scheduler.address, "-q"]
    assert main(base + ["--out", str(tmp_path / "refused")]) == 1
    assert "NaN/Inf samples" in (err := capsys.readouterr().err) and "--nonfinite mask" in err
    assert main(base + ["--out", str(tmp_path / "masked"), "--nonfinite", "mask"]) == 0
    lf = io_write.read_lightfield(tmp_path / "masked" / "views.tif")
    assert lf.weights[1, 2, 4, 5] == 0 and lf.weights.sum() == 9 * 16 * 20 - 1
    with pytest.raises(ParameterError, match="nonfinite must be one of"):
        run_batch([folder], tmp_path / "bad", client=client, nonfinite="zero")


def test_cli_batch_reports_a_bad_input_and_converts_the_rest(client, tmp_path, capsys):
    inputs = write_inputs(tmp_path / "in", 2)
    bad = tmp_path / "in" / "broken.tif"
    bad.write_bytes(b"not a tiff at all")
    argv = ["batch", *map(str, inputs), str(bad), "--out", str(tmp_path / "out"),
            "--scheduler", client.scheduler.address, "-q"]
    assert main(argv) == 1
    captured = capsys.readouterr()
    assert "2 done, 0 skipped (already done), 1 failed" in captured.out
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("lfalias: error: ") and "broken.tif" in lines[0]
    assert (tmp_path / "out" / "scene0.tif").exists() and not (tmp_path / "out" / "broken.tif").exists()


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"task": "reduce"}, "needs slope="),
        ({"task": "sharpen"}, "task"),
        ({"fmt": "h5"}, "format"),
        ({"task": "reduce", "slope": 0.0, "gamma": 1.5}, "gamma"),
        ({"task": "reduce", "slope": 0.0, "solver": "magic"}, "solver"),
        ({"task": "reduce", "slope": 0.0, "colour": "red"}, "colour"),
        ({"task": "convert", "slope": 0.5}, "task='reduce' only"),
        ({"task": "reduce", "slope": 0.0, "nearer": "front"}, "nearer"),
    ],
)
def test_plan_rejects_bad_batches(tmp_path, kwargs, match):
    inputs = write_inputs(tmp_path / "in", 1)
    with pytest.raises(ParameterError, match=match):
        plan_batch(inputs, tmp_path / "out", **kwargs)


def test_plan_rejects_missing_inputs_and_clashing_names(tmp_path):
    inputs = write_inputs(tmp_path / "in", 1)
    with pytest.raises(ParameterError, match="no such input"):
        plan_batch([tmp_path / "nope.tif"], tmp_path / "out")
    twin = tmp_path / "other" / "scene0.tif"
    twin.parent.mkdir()
    twin.write_bytes(inputs[0].read_bytes())
    with pytest.raises(ParameterError, match="both write scene0.tif"):
        plan_batch([inputs[0], twin], tmp_path / "out")
    assert not Path(tmp_path / "out").exists()


def test_a_task_killed_between_its_outputs_is_redone(client, tmp_path):
    """A marker left "running" never counts as done, even with every output name taken by older files."""
    import tifffile

    inputs = write_inputs(tmp_path / "in", 1, size=40)
    out = tmp_path / "out"
    options = {"slope": 0.0, "max_level": 2}
    run_batch(inputs, out, "reduce", client=client, **options)
    # The input changes; a re-run is killed after writing the first of its three outputs.
    changed = plane_lightfield(disparity=2, seed=42, size=40)
    io_write.write_lightfield(inputs[0], changed, overwrite=True)
    [job] = plan_batch(inputs, out, "reduce", **options)
    (out / MARKER_DIR / Path(job.marker).name).write_text(json.dumps({"key": job.key, "state": "running"}))
    assert not job.is_done() and all(Path(p).exists() for p in job.outputs)
    report = run_batch(inputs, out, "reduce", client=client, **options)
    assert report.done == [str(inputs[0])]
    import napari_lfalias as lfa

    expected = lfa.reduce_aliasing(changed, 0.0, max_level=2)
    np.testing.assert_array_equal(tifffile.imread(out / "scene0_levels.tif"), expected.level)


def test_jobs_use_absolute_paths_and_report_inputs_as_given(tmp_path, monkeypatch):
    write_inputs(tmp_path / "in", 2)
    monkeypatch.chdir(tmp_path)
    jobs = plan_batch(["in/scene0.tif", "in/scene1.tif"], "out", "convert")
    assert [job.label for job in jobs] == ["in/scene0.tif", "in/scene1.tif"]
    for job in jobs:
        assert Path(job.source).is_absolute() and Path(job.source).exists()
        assert all(Path(p).is_absolute() and Path(p).parent == tmp_path / "out" for p in job.outputs)
    report = run_batch(["in/scene0.tif"], "out", "convert", workers=1)
    assert report.done == ["in/scene0.tif"]
    assert io_write.is_lightfield_file(tmp_path / "out" / "scene0.tif")


def test_an_unreachable_scheduler_is_a_clear_error(tmp_path):
    inputs = write_inputs(tmp_path / "in", 1)
    with pytest.raises(ParameterError, match="cannot reach a dask scheduler"):
        run_batch(inputs, tmp_path / "out", "convert", scheduler="tcp://127.0.0.1:1", connect_timeout=1)
    assert list((tmp_path / "out").iterdir()) == []


def test_missing_white_frame_is_a_clear_error(tmp_path):
    inputs = write_inputs(tmp_path / "in", 1)
    with pytest.raises(ParameterError, match="nowhite.tif: no such white frame"):
        run_batch(inputs, tmp_path / "out", "convert", white=tmp_path / "nowhite.tif")


def test_lenslet_captures_are_calibrated_once_and_decoded_as_in_serial(client, lf_data, tmp_path, monkeypatch):
    """Two copies of the real GUV capture: the batch calibrates the white image once and ships the grid."""
    import shutil

    import napari_lfalias as lfa
    from napari_lfalias.decoders import calibration

    folder = lf_data / "napari_lf_guv"
    raw, white, dark = (folder / f"{p}_GUVExperim1.tif" for p in ("Lightfield", "Radiometry", "DarkFrame"))
    inputs = []
    for name in ("first.tif", "second.tif"):
        shutil.copy(raw, tmp_path / name)
        inputs.append(tmp_path / name)
    calls = []
    original = calibration.calibrate

    def counting(*args, **kwargs):
        calls.append(args)
        return original(*args, **kwargs)

    monkeypatch.setattr("napari_lfalias.decoders.lenslet.calibrate", counting)
    report = run_batch(inputs, tmp_path / "out", "convert", client=client, white=white, dark=dark)
    assert report.ok and len(report.done) == 2
    assert len(calls) == 1  # here, once; the workers got the grid model
    expected = lfa.load(raw, white=white, dark=dark)
    for name in ("first.tif", "second.tif"):
        converted = io_write.read_lightfield(tmp_path / "out" / name)
        np.testing.assert_array_equal(converted.data, expected.data)
        np.testing.assert_array_equal(converted.weights, expected.weights)
        assert converted.meta["grid"] == expected.meta["grid"]


@pytest.mark.parametrize(
    "kwargs, match",
    [({"workers": 0}, "workers must be"), ({"workers": 2, "scheduler": "tcp://127.0.0.1:1"}, "own workers")],
)
def test_bad_cluster_options_fail_before_anything_runs(tmp_path, kwargs, match):
    inputs = write_inputs(tmp_path / "in", 1)
    with pytest.raises(ParameterError, match=match):
        run_batch(inputs, tmp_path / "out", "convert", **kwargs)
    assert not (tmp_path / "out").exists()


def test_a_batch_never_replaces_its_inputs(tmp_path):
    inputs = write_inputs(tmp_path / "in", 2)
    before = inputs[0].read_bytes()
    with pytest.raises(ParameterError, match="is an input"):
        run_batch(inputs, tmp_path / "in", "convert", overwrite=True)
    assert inputs[0].read_bytes() == before and not (tmp_path / "in" / MARKER_DIR).exists()


def _threads_in_a_task(budget):
    import numba

    from napari_lfalias.batch import _kernel_threads

    with _kernel_threads(budget):
        return numba.get_num_threads()


def test_tasks_share_the_cores_of_their_host(client):
    """2 single-threaded workers on one host: each task's kernels get half the cores, not all of them."""
    budget = kernel_thread_budget(client)
    assert set(budget) == set(client.scheduler_info()["workers"])
    assert set(budget.values()) == {max(1, (os.cpu_count() or 1) // 2)}
    assert client.submit(_threads_in_a_task, {address: 1 for address in budget}, pure=False).result() == 1
    # Outside a worker (a serial run) nothing is limited.
    import numba

    assert _threads_in_a_task({"tcp://elsewhere:1": 1}) == numba.get_num_threads()


def _kill_whoever_runs(marker, pids, stop, killed):
    """Kill (SIGKILL) every worker process seen running the job of ``marker``, until ``stop``."""
    while not stop.is_set():
        try:
            record = json.loads(marker.read_text())
        except (OSError, ValueError):
            record = {}
        if record.get("state") == "running" and record.get("pid") in pids and record["pid"] not in killed:
            time.sleep(0.05)
            with contextlib.suppress(ProcessLookupError):
                os.kill(record["pid"], signal.SIGKILL)
            killed.append(record["pid"])
        time.sleep(0.005)


def test_an_input_that_kills_its_worker_fails_alone_and_the_inputs_queued_behind_it_are_retried(tmp_path):
    """dask blames every task queued on a dying worker; those that never started are run again."""
    import dask

    inputs = write_inputs(tmp_path / "in", 6, size=96)
    poison = inputs[0]
    out = tmp_path / "out"
    # One death is enough for dask to give up on every task the worker held (queued ones too).
    with dask.config.set({"distributed.scheduler.allowed-failures": 0}):
        cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                           dashboard_address=":0", silence_logs=logging.CRITICAL)
    own = distributed.Client(cluster)
    stop, killed = threading.Event(), []
    try:
        pids = set(own.run(os.getpid).values())
        killer = threading.Thread(target=_kill_whoever_runs,
                                  args=(out / MARKER_DIR / "scene0.convert.json", pids, stop, killed))
        killer.start()
        report = run_batch(inputs, out, "convert", client=own)
    finally:
        stop.set()
        own.close()
        cluster.close()
    assert killed, "the poisoned input was never seen running"
    assert list(report.failed) == [str(poison)], report.failed
    assert "died" in report.failed[str(poison)]
    assert sorted(report.done) == sorted(map(str, inputs[1:]))
    for path in inputs[1:]:
        np.testing.assert_array_equal(io_write.read_lightfield(out / path.name).data,
                                      io_write.read_lightfield(path).data)


def test_a_nonexistent_input_fails_alone(client, tmp_path, capsys):
    inputs = write_inputs(tmp_path / "in", 2)
    missing = tmp_path / "in" / "gone.tif"
    report = run_batch([inputs[0], missing, inputs[1]], tmp_path / "out", "convert", client=client)
    assert list(report.failed) == [str(missing)] and "no such input" in report.failed[str(missing)]
    assert sorted(report.done) == sorted(map(str, inputs))
    argv = ["batch", str(missing), str(inputs[0]), "--out", str(tmp_path / "out2"),
            "--scheduler", client.scheduler.address, "-q"]
    assert main(argv) == 1
    captured = capsys.readouterr()
    assert "1 done, 0 skipped (already done), 1 failed" in captured.out
    assert captured.err.strip().splitlines() == [f"lfalias: error: {missing}: no such input file or folder"]


@pytest.mark.parametrize("fmt", ["tif", "zarr"])
def test_a_truncated_output_is_done_again_on_resume(client, tmp_path, fmt):
    inputs = write_inputs(tmp_path / "in", 2)
    out = tmp_path / "out"
    assert len(run_batch(inputs, out, "convert", client=client, fmt=fmt).done) == 2
    target = out / f"scene1.{fmt}"
    damaged = target if fmt == "tif" else next(p for p in sorted((target / "views").rglob("*")) if p.is_file())
    damaged.write_bytes(damaged.read_bytes()[:100])
    report = run_batch(inputs, out, "convert", client=client, fmt=fmt)
    assert report.skipped == [str(inputs[0])] and report.done == [str(inputs[1])]
    np.testing.assert_array_equal(io_write.read_lightfield(target).data, io_write.read_lightfield(inputs[1]).data)
