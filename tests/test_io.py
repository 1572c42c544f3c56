"""What we write, we read; what is damaged is named; no window in which a write loses data."""

import json
import os
import resource
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import tifffile

import napari_lfalias as lfa
from napari_lfalias import _atomic, io_write
from napari_lfalias.cli import main
from napari_lfalias.errors import DecodeError, NonFiniteError, OutputExistsError, ParameterError

from _cli_scenes import plane_lightfield, temporaries, write_views_with_a_nan

LFALIAS = [sys.executable, "-m", "napari_lfalias.cli"]


@pytest.fixture
def weighted():
    lf = plane_lightfield(n=3, size=20, disparity=1, channels=3, seed=2)
    weights = np.random.default_rng(0).random(lf.data.shape[:4]).astype(np.float32)
    return lfa.LightField(lf.data, lf.positions + 0.25, {"source": "plane", "note": [1, 2]}, weights=weights)


# -- load / save --------------------------------------------------------------------------------------

def test_the_public_api_has_save_and_the_detector():
    from napari_lfalias.detect import AliasingDetector

    assert lfa.AliasingDetector is AliasingDetector
    assert {"save", "load", "AliasingDetector"} <= set(lfa.__all__)


@pytest.mark.parametrize("suffix", [".tif", ".zarr"])
def test_save_then_load_gives_back_the_light_field(tmp_path, weighted, suffix):
    path = lfa.save(weighted, tmp_path / f"views{suffix}")
    back = lfa.load(path)
    np.testing.assert_array_equal(back.data, weighted.data)
    np.testing.assert_array_equal(back.positions, weighted.positions)
    np.testing.assert_array_equal(back.weights, weighted.weights)
    assert back.meta["note"] == [1, 2] and back.meta["source"] == "plane"


def test_a_declared_occlusion_order_is_saved_with_the_light_field(tmp_path, weighted):
    declared = lfa.LightField(weighted.data, weighted.positions, {**weighted.meta, "nearer": "smaller"},
                              weights=weighted.weights)
    assert lfa.load(lfa.save(declared, tmp_path / "views.tif")).meta["nearer"] == "smaller"


def test_a_saved_lenslet_decode_keeps_its_grid_model(tmp_path):
    guv = Path(__file__).resolve().parents[1] / "sample_data" / "guv"
    lf = lfa.load(guv / "Lightfield_GUVExperim1.tif", white=guv / "Radiometry_GUVExperim1.tif")
    back = lfa.load(lfa.save(lf, tmp_path / "guv.zarr"))
    assert back.meta["grid"].to_json() == lf.meta["grid"].to_json()
    np.testing.assert_array_equal(back.weights, lf.weights)


def test_convert_output_loads_with_lfa_load(tmp_path, weighted):
    from napari_lfalias.cli import main

    source = lfa.save(weighted, tmp_path / "in.zarr")
    assert main(["convert", str(source), "-o", str(tmp_path / "views.tif"), "-q"]) == 0
    np.testing.assert_array_equal(lfa.load(tmp_path / "views.tif").data, weighted.data)


def test_lazy_zarr_reads_views_on_demand(tmp_path, weighted):
    lf = lfa.load(lfa.save(weighted, tmp_path / "views.zarr"), lazy=True)
    assert lf.is_lazy and lf.data.chunksize[:2] == (1, 1)
    np.testing.assert_array_equal(lf.compute().data, weighted.data)


def test_save_refuses_to_replace_and_options_that_do_not_apply(tmp_path, weighted):
    path = lfa.save(weighted, tmp_path / "views.tif")
    with pytest.raises(OutputExistsError, match="overwrite=True"):
        lfa.save(weighted, path)
    lfa.save(plane_lightfield(n=3, size=20), path, overwrite=True)
    assert lfa.load(path).n_channels == 1
    with pytest.raises(ParameterError, match="white do not apply"):
        lfa.load(path, white=path)
    with pytest.raises(ParameterError, match="LightField"):
        lfa.save(weighted.data, tmp_path / "x.tif")
    with pytest.raises(ParameterError, match=r"\.npy"):
        lfa.save(weighted, tmp_path / "x.npy")


def test_an_all_zero_view_is_stored_and_read_back(tmp_path):
    """zarr leaves out chunks equal to the fill value unless told: every view must be stored."""
    data = np.random.default_rng(1).random((2, 2, 8, 8, 1)).astype(np.float32)
    data[1, 0] = 0
    path = lfa.save(lfa.LightField(data), tmp_path / "views.zarr")
    assert (path / "views" / "c" / "1" / "0" / "0" / "0" / "0").is_file()
    np.testing.assert_array_equal(lfa.load(path).data, data)


def test_nonfinite_mask_is_kept_by_lazy_light_fields(tmp_path):
    import dask.array as da

    data = np.ones((2, 2, 4, 4, 1), np.float32)
    data[0, 1, 2, 3] = np.nan
    lazy = lfa.LightField(da.from_array(data, chunks=(1, 1, 4, 4, 1)), nonfinite="mask")
    computed = lazy.compute()
    assert computed.weights[0, 1, 2, 3] == 0 and computed.data[0, 1, 2, 3, 0] == 0
    np.testing.assert_array_equal(lfa.refocus(lazy, 0.0), np.ones((4, 4, 1), np.float32))
    with pytest.raises(NonFiniteError, match="nonfinite='mask'"):
        lfa.refocus(lfa.LightField(da.from_array(data)), 0.0)


def test_load_takes_the_nonfinite_option_its_error_advises(tmp_path):
    folder = write_views_with_a_nan(tmp_path / "views", grid=(2, 2), shape=(4, 5), at=(1, 0, 1, 1))
    with pytest.raises(NonFiniteError, match="nonfinite='mask'"):
        lfa.load(folder)
    lf = lfa.load(folder, nonfinite="mask")
    assert lf.weights[1, 0, 1, 1] == 0 and lf.weights.sum() == 4 * 20 - 1


def test_a_capture_with_nan_pixels_does_not_advise_an_option_captures_lack(tmp_path):
    guv = Path(__file__).resolve().parents[1] / "sample_data" / "guv"
    raw = tifffile.imread(guv / "Lightfield_GUVExperim1.tif").astype(np.float32)
    raw[100:104, 100:104] = np.nan
    tifffile.imwrite(tmp_path / "capture.tif", raw)
    with pytest.raises(DecodeError, match=r"capture\.tif: .*NaN or infinite") as caught:
        lfa.load(tmp_path / "capture.tif", white=guv / "Radiometry_GUVExperim1.tif")
    assert "nonfinite" not in str(caught.value)


# -- damaged files are named --------------------------------------------------------------------------

def _hyperstack(path, header, planes=1):
    stack = np.zeros((3, 3, planes, 20, 20), np.float32)
    tifffile.imwrite(path, stack, imagej=True, metadata={"axes": "TZCYX", "Info": json.dumps(header)})
    return path


@pytest.mark.parametrize(
    "edit, match",
    [
        (lambda h: h.pop("positions"), r"view positions.*found none"),
        (lambda h: h.update(shape=[3, 3, 20, 20]), r"shape \[3, 3, 20, 20\], not \(U, V, Y, X, C\)"),
        (lambda h: h.update(positions=[[[0, 0], [1]], [[0, 0]]]), r"positions.*ragged"),
        (lambda h: h.update(positions=[[0, 0]] * 9), r"positions.*shape \(9, 2\)"),
        (lambda h: h.update(version=99), r"format version 99.*update napari-lfalias"),
        (lambda h: h.update(has_weights="yes"), r"has_weights"),
        (lambda h: h.update(shape=[3, 3, 20, 20, 3]), r"holds 9 of the 27"),
    ],
)
def test_a_damaged_tiff_header_is_named(tmp_path, edit, match):
    header = io_write.lightfield_header(plane_lightfield(n=3, size=20))
    edit(header)
    path = _hyperstack(tmp_path / "views.tif", header)
    with pytest.raises(DecodeError, match=f"views.tif: .*{match}"):
        lfa.load(path)


def test_truncated_tiffs_are_named(tmp_path, weighted):
    path = lfa.save(weighted, tmp_path / "views.tif")
    raw = path.read_bytes()
    with tifffile.TiffFile(path) as tif:
        start = tif.series[0].dataoffset
    for cut, match in [(60, "cannot read the image"), (start + 100, "truncated"), (len(raw) // 2, "truncated")]:
        damaged = tmp_path / f"cut{cut}.tif"
        damaged.write_bytes(raw[:cut])
        with pytest.raises(DecodeError, match=f"cut{cut}.tif: .*{match}"):
            lfa.load(damaged)


@pytest.mark.parametrize("cut", [300, 5000])
def test_a_damaged_tiff_is_one_named_line_from_info_and_the_commands(tmp_path, weighted, cut, capsys, caplog):
    """``info`` decodes an image file rather than describing a damaged one; tifffile's own complaints stay quiet."""
    raw = lfa.save(weighted, tmp_path / "views.tif").read_bytes()
    damaged = tmp_path / "cut.tif"
    damaged.write_bytes(raw[:cut])
    for argv in (["info", str(damaged)], ["refocus", str(damaged), "--slope", "0", "-o", str(tmp_path / "r.tif")]):
        assert main(argv) == 1
        err = capsys.readouterr().err
        assert err.splitlines() == [err.strip()], err
        assert err.startswith(f"lfalias: error: {damaged}: ") and ("cannot read" in err or "truncated" in err), err
    assert [record.msg for record in caplog.records if record.name.startswith("tifffile")] == []
    assert sorted(path.name for path in tmp_path.iterdir()) == ["cut.tif", "views.tif"]


def test_results_written_by_the_commands_and_napari_are_named_not_decoded_as_captures(tmp_path, weighted, capsys):
    from napari_lfalias._napari._writer import output_header

    views = lfa.save(weighted, tmp_path / "views.tif")
    refocused = tmp_path / "refocused.tif"
    assert main(["refocus", str(views), "--slope", "0", "-o", str(refocused), "-q"]) == 0
    cv = io_write.write_tiff(tmp_path / "cv.tif", np.zeros((20, 20), np.float32),
                             output_header("cv", "views", {"slope": 0.0}))
    for path, kind in [(refocused, "image"), (cv, "cv")]:
        with pytest.raises(DecodeError, match=f"{path.name}: a result written by napari-lfalias \\('{kind}'"):
            lfa.load(path)
        assert main(["info", str(path)]) == 0
        out = capsys.readouterr().out
        assert f"napari-lfalias result ('{kind}', one image), not a light field" in out and "20 x 20" in out


@pytest.fixture
def store(tmp_path, weighted):
    return lfa.save(weighted, tmp_path / "views.zarr")


def test_a_missing_zarr_chunk_is_named_not_read_as_zeros(store):
    (store / "views" / "c" / "2" / "1" / "0" / "0" / "0").unlink()
    for lazy in (False, True):
        with pytest.raises(DecodeError, match=r"views\.zarr: 1 of 9 chunks of its 'views' array are missing "
                                              r"\(the first holds view \(2, 1\)\)"):
            lfa.load(store, lazy=lazy)


def test_a_truncated_zarr_chunk_is_named(store):
    chunk = store / "views" / "c" / "1" / "2" / "0" / "0" / "0"
    chunk.write_bytes(chunk.read_bytes()[:40])
    with pytest.raises(DecodeError, match=r"views\.zarr: view \(1, 2\) of its 'views' array cannot be read"):
        lfa.load(store)
    lazy = lfa.load(store, lazy=True)  # the damage shows when that view is read
    with pytest.raises(DecodeError, match=r"view \(1, 2\)"):
        lazy.compute()


@pytest.mark.parametrize("damage, match", [
    (lambda s: shutil.rmtree(s / "views"), "no 'views' array"),
    (lambda s: (s / "views" / "zarr.json").write_text("{"), "metadata of its 'views' array cannot be read"),
    (lambda s: shutil.rmtree(s / "weights"), "no 'weights' array"),
])
def test_a_zarr_store_missing_an_array_is_named(store, damage, match):
    damage(store)
    with pytest.raises(DecodeError, match=f"views.zarr: .*{match}"):
        lfa.load(store)


def test_a_foreign_zarr_store_is_named(tmp_path):
    import zarr

    zarr.open_group(str(tmp_path / "other.zarr"), mode="w").create_array("x", shape=(2,), dtype="f4")
    with pytest.raises(DecodeError, match="other.zarr: a zarr store without a napari-lfalias light-field header"):
        lfa.load(tmp_path / "other.zarr")


# -- atomic replacement and what killed writers leave ---------------------------------------------------

def _dead_pid():
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    return child.pid


def test_temporaries_of_dead_writers_are_removed_when_their_target_is_written_again(tmp_path, weighted):
    host = _atomic._host_tag()
    dead = tmp_path / f".views.tif.tmp-{host}-{_dead_pid()}-{'a' * 12}.tif"
    alive = tmp_path / f".views.tif.tmp-{host}-{os.getppid()}-{'b' * 12}.tif"
    elsewhere = tmp_path / f".views.tif.tmp-ffffff-{_dead_pid()}-{'c' * 12}.tif"
    other_target = tmp_path / f".other.tif.tmp-{host}-{_dead_pid()}-{'d' * 12}.tif"
    for path in (dead, alive, elsewhere, other_target):
        path.write_bytes(b"partial")
    lfa.save(weighted, tmp_path / "views.tif")
    assert not dead.exists()
    assert alive.exists() and elsewhere.exists() and other_target.exists()  # not known to be dead, or not this target


def test_a_backup_left_by_a_kill_between_two_renames_is_restored(tmp_path, weighted, monkeypatch):
    """Where folders cannot be exchanged, the old store is moved aside first; a kill then must not lose it."""
    target = lfa.save(weighted, tmp_path / "views.zarr")
    monkeypatch.setattr(_atomic, "_exchange", lambda a, b: False)
    real_rename = os.rename

    def killed_after_first(src, dst):
        real_rename(src, dst)
        raise KeyboardInterrupt  # the process dies between the two renames

    monkeypatch.setattr(os, "rename", killed_after_first)
    with pytest.raises(KeyboardInterrupt):
        lfa.save(plane_lightfield(n=3, size=20), target, overwrite=True)
    monkeypatch.setattr(os, "rename", real_rename)
    assert not target.exists() and [p.name for p in temporaries(tmp_path)][0].startswith(".views.zarr.tmp-old-")
    assert io_write.remove_temporaries(tmp_path) == []  # restored, not removed
    np.testing.assert_array_equal(lfa.load(target).data, weighted.data)
    assert temporaries(tmp_path) == []


def test_replacing_a_store_exchanges_it_atomically(tmp_path, weighted, monkeypatch):
    target = lfa.save(weighted, tmp_path / "views.zarr")
    swaps = []
    exchange = _atomic._exchange
    monkeypatch.setattr(_atomic, "_exchange", lambda a, b: swaps.append((a, b)) or exchange(a, b))
    monkeypatch.setattr(os, "rename", lambda *a: pytest.fail("a folder was moved aside: a window without it"))
    lfa.save(plane_lightfield(n=3, size=20), target, overwrite=True)
    assert swaps and swaps[0][1] == target
    assert lfa.load(target).n_channels == 1 and temporaries(tmp_path) == []


def _convert(args, **popen):
    return subprocess.Popen([*LFALIAS, "-q", "convert", *map(str, args)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, **popen)


@pytest.fixture(scope="module")
def big_store(tmp_path_factory):
    """A light field whose zarr write takes a while (random data does not compress)."""
    folder = tmp_path_factory.mktemp("big")
    data = np.random.default_rng(0).random((8, 8, 256, 256, 3)).astype(np.float32)
    return lfa.save(lfa.LightField(data), folder / "big.zarr")


def test_killed_overwrites_never_leave_the_output_missing(tmp_path, big_store):
    out = tmp_path / "out.zarr"
    assert _convert([big_store, "-o", out]).wait() == 0
    for delay in (0.6, 1.0, 1.4):
        child = _convert([big_store, "-o", out, "--overwrite"])
        time.sleep(delay)
        child.kill()
        child.wait()
        assert out.is_dir()
        assert lfa.load(out, lazy=True).shape == (8, 8, 256, 256, 3)
    assert _convert([big_store, "-o", out, "--overwrite"]).wait() == 0
    assert temporaries(tmp_path) == []  # the killed writers' temporaries went with the next write


def _when_writing(folder, child, timeout=60.0):
    """Wait until ``child`` has a temporary output under ``folder`` (its imports done, its write begun)."""
    end = time.monotonic() + timeout
    while not temporaries(folder) and child.poll() is None and time.monotonic() < end:
        time.sleep(0.01)


def test_ctrl_c_during_a_zarr_write_is_one_line_and_leaves_nothing(tmp_path, big_store):
    # Interrupted at fixed times after the start, a slow machine's child could still be importing (a
    # traceback from an import, not the write's handling): the delays count from the write's start.
    default_sigint = {"preexec_fn": lambda: signal.signal(signal.SIGINT, signal.SIG_DFL)}
    interrupted = 0
    for delay in (0.0, 0.03, 0.08):
        out = tmp_path / f"out{delay}.zarr"
        child = _convert([big_store, "-o", out], **default_sigint)
        _when_writing(tmp_path, child)
        time.sleep(delay)
        child.send_signal(signal.SIGINT)
        _, err = child.communicate()
        if child.returncode == 0:  # it finished first: nothing to see
            continue
        assert child.returncode == 130 and err == "lfalias: interrupted\n", err
        assert not out.exists() and temporaries(tmp_path) == []
        interrupted += 1
    assert interrupted  # else the writes were too quick to interrupt, and nothing was tested


def test_a_full_disk_during_a_zarr_write_is_one_line_naming_the_output(tmp_path, big_store):
    """RLIMIT_FSIZE stands in for a full disk: the write fails deep inside zarr's event loop."""
    def limit_file_size():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (200_000, 200_000))

    out = tmp_path / "out.zarr"
    child = _convert([big_store, "-o", out], preexec_fn=limit_file_size)
    _, err = child.communicate(timeout=120)
    assert child.returncode == 1
    assert err.startswith(f"lfalias: error: {out}: ") and len(err.splitlines()) == 1, err
    assert not out.exists() and temporaries(tmp_path) == []
