"""The ``lfalias`` command line, run in-process through ``main`` and once as a real console script."""

import json
import subprocess
import sys
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
import tifffile

import napari_lfalias as lfa
from napari_lfalias import io_write
from napari_lfalias.cli import main

from _cli_scenes import temporaries, write_plane

SUBCOMMANDS = ["convert", "refocus", "detect", "reduce", "info", "demo", "batch"]


@pytest.fixture
def plane(tmp_path):
    """A 5 x 5 plane light field at disparity 1, written as a light-field TIFF."""
    return write_plane(tmp_path / "plane.tif", disparity=1)


def run(capsys, *argv):
    """Run ``lfalias argv``; return (exit status, stdout, stderr)."""
    status = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return status, out, err


def assert_one_line_error(err, *words):
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("lfalias: error: ")
    assert "Traceback" not in err
    for word in words:
        assert word in lines[0]


# -- help and usage ------------------------------------------------------------


def test_help_lists_every_subcommand_and_examples(capsys):
    status, out, _ = run(capsys, "--help")
    assert status == 0
    for name in SUBCOMMANDS:
        assert name in out
    assert "examples:" in out and "lfalias demo" in out


@pytest.mark.parametrize("name", SUBCOMMANDS)
def test_subcommand_help_has_an_example(capsys, name):
    status, out, _ = run(capsys, name, "--help")
    assert status == 0
    assert f"lfalias {name}" in out.split("example:")[1]


@pytest.mark.parametrize(
    "argv",
    [[], ["frobnicate"], ["refocus", "x.tif", "--slope", "one", "-o", "a.png"], ["refocus", "x.tif", "-o", "a.png"]],
)
def test_usage_errors_exit_2(capsys, argv):
    status, _, err = run(capsys, *argv)
    assert status == 2
    assert "usage: lfalias" in err


# -- refocus ---------------------------------------------------------------------


def test_refocus_tiff_matches_the_api_and_is_sharp_at_the_plane(capsys, plane, tmp_path):
    path, lf = plane
    out = tmp_path / "r.tif"
    status, stdout, _ = run(capsys, "refocus", path, "--slope", 1, "-o", out)
    assert status == 0
    assert f"wrote {out}" in stdout
    image = tifffile.imread(out)
    np.testing.assert_array_equal(image, lfa.refocus(lf, 1.0)[..., 0])
    # In focus on the plane: the interior is the centre view itself.
    centre = lf.data[2, 2, 4:-4, 4:-4, 0]
    np.testing.assert_allclose(image[4:-4, 4:-4], centre, atol=1e-6)
    assert tifffile.TiffFile(out).shaped_metadata[0]["slope"] == 1.0


def test_refocus_and_info_on_a_folder_of_views(capsys, tmp_path):
    from _cli_scenes import plane_lightfield, write_views_folder

    folder = write_views_folder(tmp_path / "views", plane_lightfield(disparity=-1, seed=5))
    out = tmp_path / "r.tif"
    assert run(capsys, "refocus", folder, "--slope", -1, "-o", out)[0] == 0
    np.testing.assert_array_equal(tifffile.imread(out), lfa.refocus(lfa.load(folder), -1.0)[..., 0])
    status, stdout, _ = run(capsys, "info", folder)
    assert status == 0
    assert "folder of views" in stdout and "5 x 5" in stdout
    assert "-1 .. -1 px per view step (estimated" in stdout


def test_refocus_png_is_an_8bit_preview(capsys, plane, tmp_path):
    path, lf = plane
    out = tmp_path / "r.png"
    assert run(capsys, "refocus", path, "--slope", 0, "-o", out)[0] == 0
    pixels = iio.imread(out)
    assert pixels.dtype == np.uint8 and pixels.shape == lf.image_shape
    expected = np.round(np.clip(lfa.refocus(lf, 0.0)[..., 0], 0, 1) * 255)
    assert np.abs(pixels.astype(float) - expected).max() <= 1


def test_a_dark_png_gets_a_note_and_auto_contrast_stretches_it(capsys, tmp_path):
    from _cli_scenes import plane_lightfield

    lf = plane_lightfield(seed=3)
    dim = lfa.LightField(lf.data * 0.05, lf.positions)
    io_write.write_lightfield(tmp_path / "dim.tif", dim)
    status, stdout, _ = run(capsys, "refocus", tmp_path / "dim.tif", "--slope", 1, "-o", tmp_path / "a.png")
    assert status == 0 and "note: the image reaches 0.0" in stdout and "PNG is dark (--auto-contrast" in stdout
    assert iio.imread(tmp_path / "a.png").max() <= 13
    status, stdout, _ = run(capsys, "refocus", tmp_path / "dim.tif", "--slope", 1, "-o", tmp_path / "b.png",
                            "--auto-contrast")
    assert status == 0 and "note:" not in stdout
    stretched = iio.imread(tmp_path / "b.png")
    assert stretched.min() == 0 and stretched.max() == 255
    # A TIFF keeps the values: no note.
    status, stdout, _ = run(capsys, "refocus", tmp_path / "dim.tif", "--slope", 1, "-o", tmp_path / "c.tif")
    assert status == 0 and "note:" not in stdout


def test_refuses_to_overwrite_then_overwrites_when_asked(capsys, plane, tmp_path):
    path, lf = plane
    out = tmp_path / "r.tif"
    assert run(capsys, "refocus", path, "--slope", 1, "-o", out)[0] == 0
    before = out.read_bytes()
    status, _, err = run(capsys, "refocus", path, "--slope", -1, "-o", out)
    assert status == 1
    assert_one_line_error(err, str(out), "--overwrite")
    assert out.read_bytes() == before
    assert run(capsys, "refocus", path, "--slope", -1, "-o", out, "--overwrite")[0] == 0
    np.testing.assert_array_equal(tifffile.imread(out), lfa.refocus(lf, -1.0)[..., 0])
    assert temporaries(tmp_path) == []


@pytest.mark.parametrize(
    "argv, words",
    [
        (["refocus", "missing.tif", "--slope", 1, "-o", "{tmp}/a.png"], ["missing.tif", "no such file"]),
        (["refocus", "{plane}", "--slope", 1, "-o", "{tmp}/a.jpg"], ["a.jpg", ".png"]),
        (["refocus", "{plane}", "--slope", 1, "-o", "{tmp}/nofolder/a.png"], ["nofolder", "does not exist"]),
        (["refocus", "{plane}", "--slope", "nan", "-o", "{tmp}/a.png"], ["slope", "finite"]),
        (["convert", "{plane}", "-o", "{tmp}/views.h5"], ["views.h5", ".zarr"]),
        (["info", "{tmp}/not_an_image.tif"], ["not_an_image.tif"]),
    ],
)
def test_bad_input_is_a_one_line_error_with_exit_1(capsys, plane, tmp_path, argv, words):
    (tmp_path / "not_an_image.tif").write_bytes(b"this is not a TIFF")
    argv = [str(a).format(tmp=tmp_path, plane=plane[0]) for a in argv]
    status, _, err = run(capsys, *argv)
    assert status == 1
    assert_one_line_error(err, *words)
    assert not (tmp_path / "a.png").exists()


def test_overwrite_never_replaces_an_input(capsys, plane, tmp_path):
    from _cli_scenes import plane_lightfield, write_views_folder

    path, _ = plane
    before = path.read_bytes()
    status, _, err = run(capsys, "convert", path, "-o", path, "--overwrite")
    assert status == 1
    assert_one_line_error(err, "plane.tif", "is an input")
    assert path.read_bytes() == before
    folder = write_views_folder(tmp_path / "views", plane_lightfield())
    status, _, err = run(capsys, "refocus", folder, "--slope", 0, "-o", folder / "r.png", "--overwrite")
    assert status == 1
    assert_one_line_error(err, "inside the input folder")
    assert sorted(p.name for p in folder.iterdir())[-1] == "view_04_04.png" and len(list(folder.iterdir())) == 25


def test_a_failed_write_leaves_no_partial_file(capsys, plane, tmp_path, monkeypatch):
    path, _ = plane
    out = tmp_path / "r.tif"

    def disk_full(file, *args, **kwargs):
        Path(file).write_bytes(b"II*\x00partial")
        raise OSError(28, "No space left on device", str(file))

    monkeypatch.setattr(tifffile, "imwrite", disk_full)
    status, _, err = run(capsys, "refocus", path, "--slope", 1, "-o", out)
    assert status == 1
    assert_one_line_error(err, "No space left on device")
    assert not out.exists()
    assert temporaries(tmp_path) == []


# -- detect and reduce -------------------------------------------------------------


def test_detect_writes_the_cv_map_and_mask_of_the_api(capsys, plane, tmp_path):
    path, lf = plane
    out = tmp_path / "cv.tif"
    argv = ["--gamma", 0.3, "--n", 20, "--threshold", 0.02, "--method", "monte_carlo", "--seed", 4]
    status, stdout, _ = run(capsys, "detect", path, "--slope", 0, "-o", out, *argv)
    assert status == 0
    expected = lfa.detect_aliasing(lf, 0.0, gamma=0.3, n_patterns=20, threshold=0.02, method="monte_carlo", seed=4)
    np.testing.assert_array_equal(tifffile.imread(out), expected.cv)
    np.testing.assert_array_equal(tifffile.imread(tmp_path / "cv_mask.tif").astype(bool), expected.mask)
    assert f"aliased pixels: {100 * expected.mask.mean():.2f} %" in stdout
    metadata = tifffile.TiffFile(out).shaped_metadata[0]
    assert metadata["n_patterns"] == 20 and metadata["method"] == "monte_carlo"
    # Off the plane the random texture aliases; on it nothing does.
    assert expected.mask.mean() > 0.5
    assert run(capsys, "detect", path, "--slope", 1, "-o", tmp_path / "on.png")[0] == 0
    assert iio.imread(tmp_path / "on_mask.png")[4:-4, 4:-4].max() == 0


def test_reduce_writes_the_image_levels_and_cv_of_the_api(capsys, plane, tmp_path):
    path, lf = plane
    out = tmp_path / "reduced.tif"
    status, _, _ = run(capsys, "reduce", path, "--slope", 0, "--levels", 2, "--method", "analytic", "-o", out)
    assert status == 0
    expected = lfa.reduce_aliasing(lf, 0.0, max_level=2, method="analytic")
    np.testing.assert_array_equal(tifffile.imread(out), expected.image[..., 0])
    np.testing.assert_array_equal(tifffile.imread(tmp_path / "reduced_levels.tif"), expected.level)
    np.testing.assert_array_equal(tifffile.imread(tmp_path / "reduced_cv.tif"), expected.cv)
    argv = ["--method", "analytic", "-o", tmp_path / "reduced.png", "--auto-contrast"]
    assert run(capsys, "reduce", path, "--slope", 0, *argv)[0] == 0
    assert iio.imread(tmp_path / "reduced_levels.png").max() > 0


def test_threshold_scale_and_solver_reach_the_api(capsys, plane, tmp_path):
    path, lf = plane
    out = tmp_path / "a.tif"
    angular = ["--threshold-scale", "angular", "--threshold", 0.4, "--method", "analytic"]
    assert run(capsys, "detect", path, "--slope", 0, "-o", out, *angular)[0] == 0
    expected = lfa.detect_aliasing(lf, 0.0, threshold=0.4, threshold_scale="angular", method="analytic")
    # The Cv output is the map T applies to: here the angular Cv.
    np.testing.assert_array_equal(tifffile.imread(out), expected.angular_cv)
    np.testing.assert_array_equal(tifffile.imread(tmp_path / "a_mask.tif").astype(bool), expected.mask)
    assert tifffile.TiffFile(out).shaped_metadata[0]["threshold_scale"] == "angular"
    # T = 0.4 flags most of the off-focus texture on the angular scale and nothing on the paper's.
    assert expected.mask.mean() > 0.5
    assert not lfa.detect_aliasing(lf, 0.0, threshold=0.4, method="analytic").mask.any()

    out = tmp_path / "r.tif"
    assert run(capsys, "reduce", path, "--slope", 0, "-o", out, *angular, "--solver", "dct", "--levels", 2)[0] == 0
    expected = lfa.reduce_aliasing(lf, 0.0, threshold=0.4, threshold_scale="angular", solver="dct", max_level=2, method="analytic")
    np.testing.assert_array_equal(tifffile.imread(out), expected.image[..., 0])
    np.testing.assert_array_equal(tifffile.imread(tmp_path / "r_levels.tif"), expected.level)
    np.testing.assert_array_equal(tifffile.imread(tmp_path / "r_cv.tif"), expected.detections[0].angular_cv)
    assert tifffile.TiffFile(out).shaped_metadata[0]["solver"] == "dct"


def test_option_choices_match_the_core():
    from napari_lfalias import cli, detect, reduce

    assert cli.METHODS == detect.METHODS
    assert cli.THRESHOLD_SCALES == detect.THRESHOLD_SCALES
    assert cli.SOLVERS == reduce.SOLVERS


def test_bad_options_fail_before_the_input_is_read(capsys, plane, tmp_path, monkeypatch):
    from napari_lfalias._cli import commands

    def no_reading(*args):
        raise AssertionError("read the input before checking the options")

    monkeypatch.setattr(commands, "_open", no_reading)
    for name in ("detect", "reduce"):
        status, _, err = run(capsys, name, plane[0], "--slope", 0, "-o", tmp_path / "x.tif", "--gamma", 0)
        assert status == 1
        assert_one_line_error(err, "gamma")
    for name in ("refocus", "detect", "reduce"):
        status, _, err = run(capsys, name, plane[0], "--slope", "inf", "-o", tmp_path / "x.tif")
        assert status == 1
        assert_one_line_error(err, "slope", "finite")


@pytest.mark.parametrize(
    "option, value, word",
    [("--gamma", 1.5, "--gamma must"), ("--n", 1, "--n must"), ("--threshold", -1, "--threshold must"), ("--levels", -1, "--levels must")],
)
def test_out_of_range_detection_options_are_one_line_errors(capsys, plane, tmp_path, option, value, word):
    status, _, err = run(capsys, "reduce", plane[0], "--slope", 0, "-o", tmp_path / "r.png", option, value)
    assert status == 1
    assert_one_line_error(err, word)
    assert list(tmp_path.glob("r*.png")) == []


# -- convert and info ------------------------------------------------------------


@pytest.mark.parametrize("suffix", [".tif", ".zarr"])
def test_convert_round_trips_views_positions_and_metadata(capsys, plane, tmp_path, suffix):
    path, lf = plane
    out = tmp_path / f"views{suffix}"
    status, stdout, _ = run(capsys, "convert", path, "-o", out)
    assert status == 0
    assert "5 x 5 views of 48 x 48 px" in stdout
    back = io_write.read_lightfield(out)
    np.testing.assert_array_equal(back.data, lf.data)
    np.testing.assert_array_equal(back.positions, lf.positions)
    assert back.meta["disparity_range"] == [1, 1]
    assert run(capsys, "convert", path, "-o", out)[0] == 1
    # Replacing works for a zarr folder too, and leaves no old copy behind.
    other = write_plane(tmp_path / "other.tif", disparity=2, seed=7)[1]
    assert run(capsys, "convert", tmp_path / "other.tif", "-o", out, "--overwrite")[0] == 0
    np.testing.assert_array_equal(io_write.read_lightfield(out).data, other.data)
    assert temporaries(tmp_path) == []


def test_converted_tiff_is_an_imagej_hyperstack(capsys, plane, tmp_path):
    path, lf = plane
    out = tmp_path / "views.tif"
    assert run(capsys, "convert", path, "-o", out)[0] == 0
    with tifffile.TiffFile(out) as tif:
        assert tif.is_imagej
        assert tif.series[0].axes == "TZYX"  # U, V, Y, X (ImageJ drops the single channel)
        header = json.loads(tif.imagej_metadata["Info"])
        assert tif.imagej_metadata["Labels"][7] == "u=1 v=2 c0"
    assert header["shape"] == [5, 5, 48, 48, 1]
    assert np.array(header["positions"]).shape == (5, 5, 2)


def test_info_reports_format_views_and_disparity(capsys, plane):
    path, _ = plane
    status, out, _ = run(capsys, "info", path)
    assert status == 0
    assert "napari-lfalias light field (ImageJ TIFF)" in out
    assert "5 x 5" in out and "48 x 48 px" in out
    status, out, _ = run(capsys, "info", path, "--json")
    facts = json.loads(out)
    assert facts["disparity"] == {"min": 1.0, "max": 1.0, "from": "metadata"}


def test_info_estimates_the_disparity_of_a_scene_without_metadata(capsys, tmp_path):
    from _cli_scenes import plane_lightfield

    lf = plane_lightfield(disparity=-2, seed=3)
    lf.meta.clear()
    io_write.write_lightfield(tmp_path / "p.tif", lf)
    status, out, _ = run(capsys, "info", tmp_path / "p.tif", "--json")
    assert status == 0
    disparity = json.loads(out)["disparity"]
    assert disparity["from"].startswith("estimated")
    assert disparity["min"] == pytest.approx(-2) and disparity["max"] == pytest.approx(-2)


def test_info_on_a_plain_image_asks_for_a_white_image(capsys, tmp_path):
    iio.imwrite(tmp_path / "raw.png", np.zeros((20, 30), np.uint16))
    status, out, _ = run(capsys, "info", tmp_path / "raw.png")
    assert status == 0
    assert "--white" in out and "20 x 30" in out


# -- the console script ------------------------------------------------------------


def _console_script():
    script = Path(sys.executable).with_name("lfalias")
    if not script.exists():
        pytest.skip(f"no lfalias console script beside {sys.executable}")
    return script


def test_console_script_runs_and_fails_cleanly(plane, tmp_path):
    script = _console_script()
    path, lf = plane
    out = tmp_path / "r.tif"
    done = subprocess.run([script, "refocus", path, "--slope", "1", "-o", out], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    np.testing.assert_array_equal(tifffile.imread(out), lfa.refocus(lf, 1.0)[..., 0])
    again = subprocess.run([script, "refocus", path, "--slope", "1", "-o", out], capture_output=True, text=True,
                           timeout=120)
    assert again.returncode == 1
    assert_one_line_error(again.stderr, "output exists")


# -- lenslet captures and the demo (real GUV microscope capture) -------------------------


@pytest.fixture
def guv(lf_data):
    folder = lf_data / "napari_lf_guv"
    return {key: folder / f"{prefix}_GUVExperim1.tif"
            for key, prefix in (("raw", "Lightfield"), ("white", "Radiometry"), ("dark", "DarkFrame"))}


def test_convert_a_lenslet_capture_and_reuse_its_grid(capsys, guv, tmp_path):
    views, grid = tmp_path / "guv.tif", tmp_path / "grid.json"
    status, out, err = run(capsys, "convert", guv["raw"], "--white", guv["white"], "--dark", guv["dark"],
                           "-o", views, "--save-grid", grid)
    assert status == 0, err
    decoded = lfa.load(guv["raw"], white=guv["white"], dark=guv["dark"])
    back = io_write.read_lightfield(views)
    np.testing.assert_array_equal(back.data, decoded.data)
    np.testing.assert_array_equal(back.positions, decoded.positions)
    # The saved grid decodes the capture without calibrating again, to the same views.
    from napari_lfalias.decoders.lenslet import GridModel

    model = GridModel.from_json(grid.read_text())
    again = lfa.load(guv["raw"], white=guv["white"], dark=guv["dark"], grid=model)
    np.testing.assert_allclose(again.data, decoded.data, atol=1e-6)
    status, out, _ = run(capsys, "info", views)
    assert status == 0 and "grid:" in out
    status, out, _ = run(capsys, "info", guv["raw"], "--white", guv["white"], "--dark", guv["dark"])
    assert status == 0 and "lenslet capture" in out and "grid:" in out
    # The vesicle spans depths on both sides of the lenslet plane (an estimate that counted the
    # samples outside the lenses, or stepped 0.25 px per view step, found 0 .. 0 here).
    status, out, _ = run(capsys, "info", views, "--json")
    disparity = json.loads(out)["disparity"]
    assert disparity["from"].startswith("estimated")
    assert -1 < disparity["min"] < -0.2 and 0 < disparity["max"] < 0.5


def test_a_lenslet_capture_without_white_is_a_clear_error(capsys, guv, tmp_path):
    status, _, err = run(capsys, "refocus", guv["raw"], "--slope", 0, "-o", tmp_path / "r.png")
    assert status == 1
    assert_one_line_error(err, "Lightfield_GUVExperim1.tif")
    assert not (tmp_path / "r.png").exists()


def test_demo_runs_the_bundled_capture_end_to_end(capsys, tmp_path):
    from napari_lfalias._cli.demo import DEMO_FILES, guv_files

    assert guv_files() is not None, "the bundled GUV sample (sample_data/guv) is missing"
    out = tmp_path / "demo"
    status, stdout, err = run(capsys, "demo", "--out", out)
    assert status == 0, err
    assert "GUV" in stdout and "note:" not in stdout and "15 x 15 views" in stdout
    for stage in ("decode", "sweep", "refocus", "detect", "reduce", "write"):
        assert stage in stdout
    assert sorted(p.name for p in out.iterdir()) == sorted(DEMO_FILES)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["method"] == "depth" and summary["threshold"] == 0.02
    assert set(summary["seconds"]) >= {"load + decode GUV capture", "refocus", "all (wall)"}
    # The slope shown is the most aliased one of the sweep, and it does alias.
    candidates = summary["slope_candidates"]
    assert summary["slope"] == candidates["slopes"][int(np.argmax(candidates["aliased_fractions"]))]
    assert summary["aliased_fraction"] == pytest.approx(max(candidates["aliased_fractions"]))
    assert 0 < summary["aliased_fraction"] < 1
    refocused, reduced = tifffile.imread(out / "refocus.tif"), tifffile.imread(out / "reduced.tif")
    levels = tifffile.imread(out / "levels.tif")
    assert reduced.shape == refocused.shape == levels.shape == tuple(summary["view_size"])
    assert np.isfinite(reduced).all()
    # Algorithm 2 changes the aliased pixels only: level-0 pixels keep the refocus exactly.
    assert levels.max() > 0
    np.testing.assert_array_equal(reduced[levels == 0], refocused[levels == 0])
    assert np.abs(reduced - refocused)[levels > 0].max() > 0
    # The previews are enlarged so that 28 x 28 px views can be seen.
    zoom = summary["preview_zoom"]
    assert zoom > 1 and iio.imread(out / "refocus.png").shape == (28 * zoom, 28 * zoom)
    overview = iio.imread(out / "overview.png")
    assert overview.shape[0] > 28 * zoom and overview.shape[1] > 6 * 28 * zoom and overview.std() > 10
    # A second run keeps the first run's files unless asked.
    before = (out / "reduced.tif").read_bytes()
    status, _, err = run(capsys, "demo", "--out", out)
    assert status == 1
    assert_one_line_error(err, "--overwrite")
    assert (out / "reduced.tif").read_bytes() == before
    status, stdout, _ = run(capsys, "demo", "--out", out, "--overwrite", "-q", "--slope", "-0.25",
                            "--threshold-scale", "cv", "--threshold", "0.011")
    assert status == 0 and "[1/" not in stdout and " s in all" not in stdout and f"{len(DEMO_FILES)} files in" in stdout
    summary = json.loads((out / "summary.json").read_text())
    assert summary["slope"] == -0.25 and "slope_candidates" not in summary
    assert temporaries(out) == []


@pytest.mark.parametrize("missing", ["sample", "decoder"])
def test_demo_falls_back_to_the_synthetic_scene_and_says_so(capsys, tmp_path, monkeypatch, missing):
    from napari_lfalias._cli import demo

    if missing == "sample":
        monkeypatch.setattr(demo, "guv_files", lambda: None)
    else:
        monkeypatch.setattr(demo, "_lenslet_decoder_available", lambda: False)
    status, stdout, err = run(capsys, "demo", "--out", tmp_path / "demo")
    assert status == 0, err
    why = "the bundled GUV sample is missing" if missing == "sample" else "the lenslet decoder is not installed"
    assert f"note: {why}" in stdout and "brick room" in stdout
    summary = json.loads((tmp_path / "demo" / "summary.json").read_text())
    assert summary["views"] == [8, 8] and summary["aliased_fraction"] > 0
    assert (tmp_path / "demo" / "overview.png").exists()


def test_demo_checks_its_options_before_decoding(capsys, tmp_path, monkeypatch):
    from napari_lfalias._cli import demo

    def no_decoding(*args):
        raise AssertionError("decoded before the options were checked")

    monkeypatch.setattr(demo, "_load_scene", no_decoding)
    status, _, err = run(capsys, "demo", "--out", tmp_path / "demo", "--gamma", 1.5)
    assert status == 1
    assert_one_line_error(err, "gamma")
    assert not (tmp_path / "demo").exists()
    (tmp_path / "file").write_text("")
    status, _, err = run(capsys, "demo", "--out", tmp_path / "file")
    assert status == 1
    assert_one_line_error(err, "must be a folder")


def test_keep_in_focus_reaches_the_api(capsys, tmp_path):
    """Focused on the brick room's wall, the flag keeps the wall around the defocused cube: the outputs differ."""
    from napari_lfalias.synthetic import brick_room

    lf = brick_room(n_views=8, size=64, seed=0).lightfield
    path = tmp_path / "room.tif"
    io_write.write_lightfield(path, lf)
    out = tmp_path / "k.tif"
    argv = ["reduce", path, "--slope", -4, "--threshold", 0.005, "--method", "analytic", "-o", out]
    assert run(capsys, *argv, "--keep-in-focus")[0] == 0
    expected = lfa.reduce_aliasing(lf, -4.0, threshold=0.005, keep_in_focus=True, method="analytic")
    np.testing.assert_allclose(tifffile.imread(out), expected.image, atol=1e-6)
    assert not np.allclose(expected.image, lfa.reduce_aliasing(lf, -4.0, threshold=0.005, method="analytic").image, atol=1e-3)
