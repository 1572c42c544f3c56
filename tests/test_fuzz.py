"""Fuzzing the loaders, the public API and the command line (hypothesis, bounded in time).

Whatever comes in, the answer is a valid result or a named error (a
``LightFieldError``), never another exception; the command line exits 0,
1 or 2 with no traceback, and writes nothing when it fails. The examples
are derived from a fixed seed (``derandomize``), so a run repeats; each
test draws a bounded number of them (40; ``LFALIAS_FUZZ_EXAMPLES=N`` draws
N fresh ones), and the memory budget is small so that a hostile size is
refused rather than allocated.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import os
import shutil
import tempfile
import warnings
from pathlib import Path

import numpy as np
import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

import napari_lfalias as lfa  # noqa: E402
from napari_lfalias import io_write  # noqa: E402
from napari_lfalias.cli import main  # noqa: E402
from napari_lfalias.errors import LightFieldError, LightFieldWarning  # noqa: E402

from _cli_scenes import plane_lightfield, temporaries, write_views_folder  # noqa: E402

#: ``LFALIAS_FUZZ_EXAMPLES=500`` digs deeper, with fresh random examples each run.
_DEEPER = int(os.environ.get("LFALIAS_FUZZ_EXAMPLES", "0"))
FUZZ = settings(max_examples=_DEEPER or 40, deadline=None, derandomize=not _DEEPER, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])


@pytest.fixture(autouse=True)
def small_budget(monkeypatch):
    """Hostile sizes are refused against 256 MiB instead of being allocated."""
    monkeypatch.setenv("LFALIAS_MEMORY_BUDGET", "256M")


@pytest.fixture(scope="module")
def valid(tmp_path_factory):
    """Small valid inputs of every kind, written once."""
    folder = tmp_path_factory.mktemp("valid")
    lf = plane_lightfield(n=3, size=16, disparity=1, seed=3)
    weighted = lfa.LightField(lf.data, lf.positions, weights=np.full(lf.data.shape[:4], 0.5, np.float32))
    files = {
        "tif": io_write.write_lightfield(folder / "views.tif", weighted),
        "zarr": io_write.write_lightfield(folder / "views.zarr", weighted),
        "folder": write_views_folder(folder / "views", lf),
    }
    files["png"] = sorted(files["folder"].glob("*.png"))[0]
    return files


def _load_checked(path, **options):
    """Load ``path``; a light field that comes back must be a valid one."""
    try:
        lf = lfa.load(path, **options)
        if lf.is_lazy:
            lf = lf.compute()
    except LightFieldError:
        return None
    assert lf.data.dtype == np.float32 and lf.data.ndim == 5 and lf.data.shape[-1] in (1, 3)
    assert np.isfinite(lf.data).all() and lf.positions.shape == lf.grid_shape + (2,)
    if lf.weights is not None:
        assert lf.weights.shape == lf.shape[:4] and lf.weights.min() >= 0 and lf.weights.max() <= 1
    return lf


def _scratch():
    return Path(tempfile.mkdtemp(prefix="lfalias-fuzz-"))


# -- loaders --------------------------------------------------------------------------------------------

_MUTATION = st.one_of(
    st.tuples(st.just("truncate"), st.floats(0, 1)),
    st.tuples(st.just("flip"), st.lists(st.tuples(st.floats(0, 1), st.integers(1, 255)), min_size=1, max_size=8)),
    st.tuples(st.just("insert"), st.floats(0, 1), st.binary(min_size=1, max_size=64)),
)


def _mutate(raw, mutation):
    kind = mutation[0]
    if kind == "truncate":
        return raw[: int(mutation[1] * len(raw))]
    if kind == "flip":
        data = bytearray(raw)
        for where, bits in mutation[1]:
            index = min(int(where * len(data)), len(data) - 1)
            data[index] ^= bits
        return bytes(data)
    where = int(mutation[1] * len(raw))
    return raw[:where] + mutation[2] + raw[where:]


@FUZZ
@given(kind=st.sampled_from(["tif", "png"]), mutation=_MUTATION)
def test_damaged_files_load_or_fail_by_name(valid, kind, mutation):
    folder = _scratch()
    try:
        path = folder / valid[kind].name
        path.write_bytes(_mutate(valid[kind].read_bytes(), mutation))
        _load_checked(path)  # a lenslet-looking image without white=: a named error
        if kind == "png":  # the damaged view in a folder of good ones
            views = folder / "views"
            shutil.copytree(valid["folder"], views)
            shutil.copy(path, views / path.name)
            for lazy in (False, True):
                _load_checked(views, lazy=lazy)
    finally:
        shutil.rmtree(folder)


@FUZZ
@given(suffix=st.sampled_from([".tif", ".png", ".jpg", ".bmp", ".lfp", ".dng", ".json", ""]),
       raw=st.binary(max_size=512))
def test_random_bytes_are_refused_by_name(suffix, raw):
    folder = _scratch()
    try:
        path = folder / f"capture{suffix}"
        path.write_bytes(raw)
        assert _load_checked(path) is None
        assert _load_checked(path, white=path) is None
    finally:
        shutil.rmtree(folder)


_JSON_VALUE = st.recursive(
    st.one_of(st.none(), st.booleans(), st.integers(-5, 10**12), st.floats(allow_nan=False), st.text(max_size=8)),
    lambda inner: st.one_of(st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=6), inner, max_size=3)),
    max_leaves=12,
)


@FUZZ
@given(
    edits=st.dictionaries(st.sampled_from(["shape", "positions", "has_weights", "version", "meta", "format"]),
                          _JSON_VALUE, max_size=3),
    drop=st.lists(st.sampled_from(["shape", "positions", "has_weights", "version", "meta"]), max_size=2),
    store=st.sampled_from(["tif", "zarr"]),
)
def test_edited_headers_load_or_fail_by_name(valid, edits, drop, store):
    folder = _scratch()
    try:
        target = folder / valid[store].name
        header = io_write.lightfield_header(lfa.load(valid[store]))
        header.update(edits)
        for key in drop:
            header.pop(key, None)
        if store == "zarr":
            import zarr

            shutil.copytree(valid[store], target)
            zarr.open_group(str(target), mode="r+").attrs.update({"lfalias": header})
        else:
            import tifffile

            stack = tifffile.imread(valid[store])
            tifffile.imwrite(target, stack, imagej=True, metadata={"axes": "TZCYX", "Info": json.dumps(header)})
        for lazy in (False, True):
            _load_checked(target, lazy=lazy)
    finally:
        shutil.rmtree(folder)


@FUZZ
@given(damage=st.lists(st.tuples(st.sampled_from(["delete", "truncate", "garbage"]), st.integers(0, 10**6)),
                       min_size=1, max_size=3),
       lazy=st.booleans())
def test_damaged_zarr_stores_fail_by_name(valid, damage, lazy):
    folder = _scratch()
    try:
        store = shutil.copytree(valid["zarr"], folder / "views.zarr")
        files = sorted(p for p in store.rglob("*") if p.is_file())
        for kind, index in damage:
            path = files[index % len(files)]
            if not path.exists():
                continue
            if kind == "delete":
                path.unlink()
            elif kind == "truncate":
                path.write_bytes(path.read_bytes()[: len(path.read_bytes()) // 2])
            else:
                path.write_bytes(b"\x00garbage" * 3)
        # Every change above damages the store: it must never read as data.
        assert _load_checked(store, lazy=lazy) is None
    finally:
        shutil.rmtree(folder)


@FUZZ
@given(present=st.sets(st.tuples(st.integers(0, 3), st.integers(0, 3)), min_size=1, max_size=16),
       grid=st.one_of(st.none(), st.tuples(st.integers(-1, 5), st.integers(-1, 5)), st.text(max_size=4)),
       naming=st.sampled_from(["hci", "indexed"]))
def test_partial_folders_load_missing_views_at_weight_0(present, grid, naming):
    import imageio.v3 as iio

    folder = _scratch()
    try:
        for u, v in present:
            name = f"input_Cam{u * 4 + v:03d}.png" if naming == "hci" else f"view_{u}_{v}.png"
            iio.imwrite(folder / name, np.full((6, 5), 10 * u + v + 1, np.uint8))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", LightFieldWarning)
            lf = _load_checked(folder, grid=grid) if grid is not None else _load_checked(folder)
        if lf is None:
            return
        seen = lf.weights is None or lf.weights.reshape(lf.n_views, -1).max(axis=1) > 0
        seen = np.broadcast_to(seen, (lf.n_views,))
        assert int(seen.sum()) == len(present)
        # Every present view holds its own pixels; every missing one is 0 with weight 0.
        flat = lf.data.reshape(lf.n_views, -1)
        assert np.all(flat[~seen] == 0) and np.all(flat[seen].max(axis=1) > 0)
    finally:
        shutil.rmtree(folder)


@FUZZ
@given(width=st.integers(1, 2**31 - 1), height=st.integers(1, 2**31 - 1), colour=st.sampled_from([0, 2, 6]))
def test_png_headers_that_declare_huge_images_are_refused_before_decoding(width, height, colour):
    import zlib

    def chunk(kind, body):
        return len(body).to_bytes(4, "big") + kind + body + zlib.crc32(kind + body).to_bytes(4, "big")

    ihdr = width.to_bytes(4, "big") + height.to_bytes(4, "big") + bytes([8, colour, 0, 0, 0])
    raw = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 64)) + chunk(b"IEND", b"")
    folder = _scratch()
    try:
        (folder / "view_0_0.png").write_bytes(raw)
        (folder / "view_0_1.png").write_bytes(raw)
        _load_checked(folder)
    finally:
        shutil.rmtree(folder)


# -- the public API -------------------------------------------------------------------------------------

_NUMBER = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(-(2**70), 2**70),
    st.sampled_from([0, 1, -1, 0.5, 2, 1e-30, 1e30, True]),
)
_ANYTHING = st.one_of(_NUMBER, st.none(), st.text(max_size=5), st.lists(st.integers(0, 3), max_size=3))


@st.composite
def _lightfields(draw):
    n_rows, n_cols = draw(st.integers(1, 3)), draw(st.integers(1, 3))
    height, width = draw(st.integers(1, 12)), draw(st.integers(1, 12))
    channels = draw(st.sampled_from([1, 3]))
    scale = draw(st.sampled_from([1.0, 1e-30, 1e30, 0.0]))
    rng = np.random.default_rng(draw(st.integers(0, 3)))
    data = (rng.random((n_rows, n_cols, height, width, channels)) * scale).astype(np.float32)
    weights = None
    if draw(st.booleans()):
        weights = (rng.random(data.shape[:4]) > draw(st.floats(0, 1))).astype(np.float32)
    return lfa.LightField(data, weights=weights)


@FUZZ
@given(data=st.one_of(_ANYTHING, st.builds(np.zeros, st.lists(st.integers(0, 4), max_size=6))),
       positions=_ANYTHING, weights=_ANYTHING, nonfinite=_ANYTHING)
def test_lightfield_rejects_what_it_cannot_hold_by_name(data, positions, weights, nonfinite):
    kwargs = {"positions": positions, "weights": weights, "nonfinite": nonfinite}
    with contextlib.suppress(LightFieldError):
        lf = lfa.LightField(data, **kwargs)
        assert lf.data.dtype == np.float32 and lf.data.ndim == 5


@FUZZ
@given(lf=_lightfields(), slope=_NUMBER,
       options=st.dictionaries(st.sampled_from(["gamma", "n_patterns", "threshold", "seed", "method",
                                                "threshold_scale", "level", "dark_floor", "skip_flat"]),
                               _ANYTHING, max_size=3),
       monte_carlo=st.booleans())
def test_refocus_and_detection_give_a_result_or_a_named_error(lf, slope, options, monte_carlo):
    if monte_carlo:
        options.setdefault("method", "monte_carlo")
    with contextlib.suppress(LightFieldError):
        image = lfa.refocus(lf, slope)
        assert image.shape == lf.image_shape + (lf.n_channels,) and np.isfinite(image).all()
    with contextlib.suppress(LightFieldError):
        det = lfa.detect_aliasing(lf, slope, **options)
        assert np.isfinite(det.cv).all() and det.cv.min() >= 0 and det.mask.dtype == bool


@FUZZ
@given(lf=_lightfields(), slope=_NUMBER,
       options=st.dictionaries(st.sampled_from(["max_level", "solver", "screen", "keep_in_focus", "threshold"]),
                               _ANYTHING, max_size=2))
def test_reduction_gives_a_result_or_a_named_error(lf, slope, options):
    with contextlib.suppress(LightFieldError):
        res = lfa.reduce_aliasing(lf, slope, **options)
        assert res.image.shape == lf.image_shape + (lf.n_channels,) and np.isfinite(res.image).all()


@FUZZ
@given(lf=_lightfields(), name=st.text(min_size=1, max_size=12), suffix=st.sampled_from([".tif", ".zarr", ".png", ""]),
       overwrite=_ANYTHING)
def test_save_writes_what_load_reads_or_writes_nothing(lf, name, suffix, overwrite):
    folder = _scratch()
    try:
        path = folder / (name.replace("/", "_").replace("\0", "_") + suffix)
        try:
            written = lfa.save(lf, path, overwrite=overwrite)
        except (LightFieldError, OSError):  # an unwritable name is the system's to refuse
            assert sorted(folder.iterdir()) == []
            return
        back = lfa.load(written)
        np.testing.assert_array_equal(back.data, lf.data)
        assert temporaries(folder) == []
    finally:
        shutil.rmtree(folder)


# -- the command line -----------------------------------------------------------------------------------

_HOSTILE = st.one_of(
    st.sampled_from(["-1e-3", "1e400", "nan", "-inf", "abc", "", "300", "9x9", "0x3", "-1", "1e30"]),
    st.floats(allow_nan=False, allow_infinity=False).map(repr),
    st.integers(-(10**12), 10**12).map(str),
)
#: Each option with values a user would give; one time in four, a hostile one instead.
_PLAUSIBLE = {
    "--slope": ["0", "-1e-3", "1", "-0.5", "2", "1e30", "-1e12"],
    "--gamma": ["0.2", "0.5", "0.01", "0.99"],
    "--n": ["2", "10", "100"],
    "--threshold": ["0.02", "0.005", "1e-9", "10"],
    "--threshold-scale": ["cv", "angular"],
    "--method": ["analytic", "monte_carlo"],
    "--seed": ["0", "1", "123"],
    "--levels": ["0", "1", "3", "16"],
    "--solver": ["auto", "lu", "multigrid", "dct"],
    "--grid": ["3x3", "9x9", "2x2", "1x9"],
    "--nonfinite": ["raise", "mask"],
    "--white": ["{input4}", "{input5}", "{input0}"],
    "--dark": ["{input4}", "{input5}"],
}
_INPUT = ["--white", "--dark", "--grid", "--nonfinite"]
_DETECT = ["--gamma", "--n", "--threshold", "--threshold-scale", "--method", "--seed"]
_COMMANDS = {  # options, flags, output suffixes
    "convert": (_INPUT, ["--overwrite"], [".tif", ".zarr", ".png"]),
    "refocus": (_INPUT, ["--overwrite", "--auto-contrast"], [".png", ".tif", ".zarr"]),
    "detect": (_INPUT + _DETECT, ["--overwrite"], [".png", ".tif"]),
    "reduce": (_INPUT + _DETECT + ["--levels", "--solver"], ["--overwrite", "--keep-in-focus", "--auto-contrast"],
               [".png", ".tif"]),
    "info": (_INPUT, ["--json"], []),
}


@st.composite
def _command_lines(draw):
    command = draw(st.sampled_from(sorted(_COMMANDS)))
    options, flags, suffixes = _COMMANDS[command]
    argv = [command, "{input%d}" % draw(st.integers(0, 5))]
    if command in ("refocus", "detect", "reduce") and draw(st.integers(0, 9)) > 0:  # else: it is missing
        argv += ["--slope", draw(st.sampled_from(_PLAUSIBLE["--slope"]))]
    for option in draw(st.lists(st.sampled_from(options), max_size=4, unique=True)):
        hostile = draw(st.integers(0, 3)) == 0
        argv += [option, draw(_HOSTILE if hostile else st.sampled_from(_PLAUSIBLE[option]))]
    argv += draw(st.lists(st.sampled_from(flags + ["-q"]), max_size=2, unique=True))
    if suffixes:
        argv += ["-o", "{out}/result" + draw(st.sampled_from(suffixes))]
    return argv


@pytest.fixture(scope="module")
def cli_inputs(valid, tmp_path_factory):
    folder = tmp_path_factory.mktemp("inputs")
    garbage = folder / "garbage.tif"
    garbage.write_bytes(b"II*\0garbage")
    partial = shutil.copytree(valid["folder"], folder / "partial")
    sorted(partial.glob("*.png"))[4].unlink()
    return [str(valid["tif"]), str(valid["zarr"]), str(valid["folder"]), str(partial), str(garbage),
            str(folder / "missing.tif")]


@FUZZ
@given(argv=_command_lines())
def test_command_lines_exit_cleanly_and_write_nothing_when_they_fail(cli_inputs, argv):
    out = _scratch()
    try:
        names = {"{out}": str(out), **{"{input%d}" % i: path for i, path in enumerate(cli_inputs)}}
        for key, value in names.items():
            argv = [arg.replace(key, value) for arg in argv]
        stdout, stderr = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
            status = main(argv)
        err = stderr.getvalue()
        hypothesis.event(f"{argv[0]} exit {status}")
        assert status in (0, 1, 2), (argv, status, err)
        assert "Traceback" not in err, (argv, err)
        if status == 1:
            lines = [line for line in err.splitlines() if not line.startswith("lfalias: warning: ")]
            assert len(lines) == 1 and lines[0].startswith("lfalias: error: "), (argv, err)
        if status != 0:
            assert list(out.iterdir()) == [], (argv, err)
        assert temporaries(out) == []
    finally:
        shutil.rmtree(out)


def test_the_fuzz_budget_is_small():
    """The suite's own guard: the budget the fixtures set is what the library sees."""
    from napari_lfalias._budget import memory_budget

    assert memory_budget()[0] == 256 * 2**20 and math.isfinite(memory_budget()[0])
