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

SUBCOMMANDS = ["convert", "depth", "refocus", "detect", "reduce", "info", "demo", "batch"]


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


def test_nearer_declares_the_occlusion_order_to_every_rendering(capsys, room, depth, tmp_path):
    from napari_lfalias._cli.depth import read_disparity

    path, scene = room
    lf = scene.lightfield
    estimate = read_disparity(depth).for_views(lf.image_shape)
    out = tmp_path / "r.tif"
    assert run(capsys, "reduce", path, "--slope", 4, "--disparity", depth, "--nearer", "smaller", "-o", out,
               "-q")[0] == 0
    expected = lfa.reduce_aliasing(lfa.LightField(lf.data, lf.positions, {"nearer": "smaller"}), 4.0,
                                   disparity=estimate)
    np.testing.assert_array_equal(tifffile.imread(out), expected.image)
    assert not np.array_equal(expected.image, lfa.reduce_aliasing(lf, 4.0, disparity=estimate).image)  # judged: larger
    assert tifffile.TiffFile(out).shaped_metadata[0]["nearer"] == "smaller"
    out = tmp_path / "a.tif"
    assert run(capsys, "refocus", path, "--slope", 4, "--antialias", "--disparity", depth, "--nearer", "smaller",
               "-o", out, "-q")[0] == 0
    np.testing.assert_array_equal(tifffile.imread(out),
                                  lfa.antialiased_refocus(lf, 4.0, estimate, nearer="smaller"))
    status, _, err = run(capsys, "refocus", path, "--slope", 4, "--nearer", "larger", "-o", tmp_path / "p.png")
    assert status != 0 and "--nearer is used by --antialias" in err
    status, _, err = run(capsys, "reduce", path, "--slope", 4, "--method", "analytic", "--nearer", "larger",
                         "-o", tmp_path / "c.png")
    assert status != 0 and "--nearer is used by --method depth" in err


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
    from napari_lfalias import cli, depth_guided, detect, lightfield, reduce

    assert cli.METHODS == detect.METHODS
    assert cli.THRESHOLD_SCALES == detect.THRESHOLD_SCALES
    assert cli.SOLVERS == reduce.SOLVERS
    assert ("auto",) + cli.NEARER == depth_guided.NEARER
    assert cli.NONFINITE == lightfield.NONFINITE


def test_bad_options_fail_before_the_input_is_read(capsys, plane, tmp_path, monkeypatch):
    from napari_lfalias._cli import commands

    def no_reading(*args):
        raise AssertionError("read the input before checking the options")

    monkeypatch.setattr(commands, "open_lightfield", no_reading)
    for name in ("detect", "reduce"):
        status, _, err = run(capsys, name, plane[0], "--slope", 0, "-o", tmp_path / "x.tif", "--gamma", 0)
        assert status == 1
        assert_one_line_error(err, "gamma")
    for name in ("refocus", "detect", "reduce"):
        status, _, err = run(capsys, name, plane[0], "--slope", "inf", "-o", tmp_path / "x.tif")
        assert status == 1
        assert_one_line_error(err, "slope", "finite")
    assert list(tmp_path.glob("x*")) == []


@pytest.mark.parametrize(
    "option, value, word",
    [("--gamma", 1.5, "--gamma must"), ("--n", 1, "--n must"), ("--threshold", -1, "--threshold must"), ("--levels", -1, "--levels must")],
)
def test_out_of_range_detection_options_are_one_line_errors(capsys, plane, tmp_path, option, value, word):
    status, _, err = run(capsys, "reduce", plane[0], "--slope", 0, "-o", tmp_path / "r.png", option, value)
    assert status == 1
    assert_one_line_error(err, word)
    assert list(tmp_path.glob("r*.png")) == []


# -- depth, --antialias and --disparity ------------------------------------------------------


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    """The brick room (8 x 8 views of 64 px, wall at disparity -4, cube at +4) as a light-field TIFF."""
    from napari_lfalias.synthetic import brick_room

    scene = brick_room(n_views=8, size=64, seed=0)
    path = tmp_path_factory.mktemp("room") / "room.tif"
    io_write.write_lightfield(path, scene.lightfield)
    return path, scene


@pytest.fixture(scope="module")
def depth(room, tmp_path_factory):
    """``lfalias depth room.tif -o depth.tif`` run once: (path, stdout)."""
    out = tmp_path_factory.mktemp("depth") / "depth.tif"
    assert main(["depth", str(room[0]), "-o", str(out), "-q"]) == 0
    return out


def test_depth_writes_the_estimate_of_the_api_with_its_confidence_and_settings(capsys, room, tmp_path):
    path, scene = room
    out = tmp_path / "d.tif"
    status, stdout, err = run(capsys, "depth", path, "-o", out)
    assert status == 0, err
    expected = lfa.estimate_disparity(scene.lightfield)
    disparity, confidence = tifffile.imread(out), tifffile.imread(tmp_path / "d_confidence.tif")
    assert disparity.dtype == confidence.dtype == np.float32
    np.testing.assert_array_equal(disparity, expected.disparity)
    np.testing.assert_array_equal(confidence, expected.confidence)
    alternative = tifffile.imread(tmp_path / "d_alternative.tif")
    np.testing.assert_array_equal(alternative, np.where(np.isfinite(expected.alternative), expected.alternative,
                                                        expected.disparity))
    assert (alternative != disparity).any()  # the brick wall is periodic: a second fit a period away somewhere
    # read back, it is the estimate's alternative again
    from napari_lfalias._cli.depth import read_disparity
    again = read_disparity(out).for_views(disparity.shape)
    np.testing.assert_array_equal(again.alternative, expected.alternative)
    # The estimate itself is right: the wall at -4 and the cube at +4, away from the cube's edges.
    assert np.median(disparity[:8]) == pytest.approx(-4, abs=0.1)
    assert np.median(disparity[30:40, 28:38]) == pytest.approx(4, abs=0.1)
    settings = tifffile.TiffFile(out).shaped_metadata[0]
    assert settings["content"] == "disparity" and settings["input"] == str(path)
    assert settings["disparity_range"] == pytest.approx(list(expected.disparity_range))
    assert settings["radius"] == expected.params["radius"] and settings["confidence_file"] == "d_confidence.tif"
    # What it prints: the range found and the median confidence; progress on stderr.
    low, high = float(expected.disparity.min()), float(expected.disparity.max())
    assert f"disparity {low:+.3g} .. {high:+.3g} px per view step" in stdout
    assert f"median confidence {float(np.median(expected.confidence)):.2f}" in stdout
    assert "disparity: 5/5 steps finished" in err
    for name in ("d.tif", "d_confidence.tif", "d_alternative.tif", "d.png"):
        assert f"wrote {tmp_path / name}" in stdout


def test_depth_png_is_the_coloured_disparity_over_a_colour_bar(capsys, depth):
    from napari_lfalias._cli.colormap import COLORMAP, colorize

    disparity = tifffile.imread(depth)
    pixels = iio.imread(depth.with_suffix(".png"))
    zoom = 4  # 64 px views are enlarged to 256 px
    assert pixels.dtype == np.uint8 and pixels.shape[1] == 64 * zoom and pixels.shape[0] > 64 * zoom + 10
    shown = colorize(disparity, float(disparity.min()), float(disparity.max()))
    np.testing.assert_array_equal(pixels[:64 * zoom:zoom, ::zoom, :3], shown)
    # Under it, the colour bar runs from the first colour of the map to the last.
    bar = pixels[64 * zoom + 5, :, :3]
    np.testing.assert_array_equal(bar[[4, -5]], COLORMAP[[0, -1]])


def test_the_colour_map_is_perceptual():
    from napari_lfalias._cli.colormap import COLORMAP, _to_oklab

    lightness = _to_oklab(COLORMAP / 255.0)[:, 0]
    assert np.diff(lightness).min() > -2e-3  # rises all the way, up to the 8-bit rounding
    assert lightness[-1] - lightness[0] > 0.6
    steps = np.linalg.norm(np.diff(_to_oklab(COLORMAP / 255.0), axis=0), axis=1)
    assert steps.max() < 3 * np.median(steps)  # no jumps: colours change at an even pace


def test_depth_range_is_the_searched_range(capsys, room, tmp_path):
    path, scene = room
    out = tmp_path / "d.tif"
    assert run(capsys, "depth", path, "-o", out, "--range", -5, 5, "-q")[0] == 0
    expected = lfa.estimate_disparity(scene.lightfield, (-5, 5))
    np.testing.assert_array_equal(tifffile.imread(out), expected.disparity)
    assert tifffile.TiffFile(out).shaped_metadata[0]["disparity_range"] == [-5, 5]


def test_refocus_antialias_is_the_dense_aperture_refocus_of_the_api(capsys, room, depth, tmp_path):
    path, scene = room
    lf = scene.lightfield
    out = tmp_path / "a.tif"
    status, stdout, _ = run(capsys, "refocus", path, "--slope", 4, "--antialias", "-o", out)
    assert status == 0 and "disparity" in stdout and "refocus (dense aperture)" in stdout
    expected = lfa.antialiased_refocus(lf, 4.0)
    np.testing.assert_array_equal(tifffile.imread(out), expected)
    metadata = tifffile.TiffFile(out).shaped_metadata[0]
    assert metadata["antialias"] is True and metadata["disparity"] == "estimated"
    # It is not the plain refocus: the wall's copies are joined into its blur, nearer the truth.
    reference = scene.reference(4.0, interpolation="bilinear")
    naive = lfa.refocus(lf, 4.0)
    from napari_lfalias.metrics import psnr

    assert psnr(expected, reference) > psnr(naive, reference) + 6
    # --disparity reuses the depth file and its confidence: the same image, no estimate.
    again = tmp_path / "b.tif"
    status, stdout, _ = run(capsys, "refocus", path, "--slope", 4, "--antialias", "--disparity", depth, "-o", again)
    assert status == 0 and "] disparity" not in stdout
    np.testing.assert_array_equal(tifffile.imread(again), expected)
    assert tifffile.TiffFile(again).shaped_metadata[0]["disparity"] == str(depth)


def test_a_disparity_without_confidence_is_trusted_everywhere(capsys, room, tmp_path):
    """A depth map from elsewhere (here the scene's true disparity): the API's result for that bare map."""
    path, scene = room
    truth = tmp_path / "truth.tif"
    tifffile.imwrite(truth, scene.disparity.astype(np.float32))
    out = tmp_path / "a.tif"
    assert run(capsys, "refocus", path, "--slope", 4, "--antialias", "--disparity", truth, "-o", out, "-q")[0] == 0
    np.testing.assert_array_equal(tifffile.imread(out), lfa.antialiased_refocus(scene.lightfield, 4.0, scene.disparity))


def test_detect_and_reduce_take_the_disparity_file(capsys, room, depth, tmp_path):
    from napari_lfalias._cli.depth import read_disparity

    path, scene = room
    lf = scene.lightfield
    estimate = read_disparity(depth).for_views(lf.image_shape)
    assert run(capsys, "detect", path, "--slope", 4, "--disparity", depth, "-o", tmp_path / "s.tif", "-q")[0] == 0
    expected = lfa.detect_aliasing(lf, 4.0, disparity=estimate)
    np.testing.assert_array_equal(tifffile.imread(tmp_path / "s.tif"), expected.cv)
    np.testing.assert_array_equal(tifffile.imread(tmp_path / "s_mask.tif").astype(bool), expected.mask)
    assert 0.3 < expected.mask.mean() < 0.9  # the wall aliases, the cube does not
    status, stdout, _ = run(capsys, "reduce", path, "--slope", 4, "--disparity", depth, "-o", tmp_path / "r.tif")
    assert status == 0
    expected = lfa.reduce_aliasing(lf, 4.0, disparity=estimate)
    np.testing.assert_array_equal(tifffile.imread(tmp_path / "r.tif"), expected.image)
    np.testing.assert_array_equal(tifffile.imread(tmp_path / "r_levels.tif"), expected.level)
    metadata = tifffile.TiffFile(tmp_path / "r.tif").shaped_metadata[0]
    assert metadata["method"] == "depth" and metadata["disparity"] == str(depth)
    # Without --disparity, the default estimates it (in a stage of its own): the API's default result.
    status, stdout, _ = run(capsys, "reduce", path, "--slope", 4, "-o", tmp_path / "e.tif")
    assert status == 0 and "] disparity" in stdout
    np.testing.assert_array_equal(tifffile.imread(tmp_path / "e.tif"), lfa.reduce_aliasing(lf, 4.0).image)


@pytest.mark.parametrize(
    "argv, words",
    [
        (["refocus", "{room}", "--slope", 4, "--disparity", "{depth}", "-o", "{tmp}/a.tif"], ["--disparity", "--antialias"]),
        (["detect", "{room}", "--slope", 4, "--method", "analytic", "--disparity", "{depth}", "-o", "{tmp}/a.tif"],
         ["--disparity", "--method analytic"]),
        (["reduce", "{room}", "--slope", 4, "--preset", "paper", "--disparity", "{depth}", "-o", "{tmp}/a.tif"],
         ["--disparity", "--preset paper"]),
        (["reduce", "{room}", "--slope", 4, "--disparity", "{tmp}/none.tif", "-o", "{tmp}/a.tif"],
         ["none.tif", "no such file"]),
        (["reduce", "{room}", "--slope", 4, "--disparity", "{tmp}/junk.tif", "-o", "{tmp}/a.tif"],
         ["junk.tif", "not a readable TIFF"]),
        (["reduce", "{room}", "--slope", 4, "--disparity", "{tmp}/nan.tif", "-o", "{tmp}/a.tif"], ["nan.tif", "NaN"]),
        (["reduce", "{room}", "--slope", 4, "--disparity", "{tmp}/cube.tif", "-o", "{tmp}/a.tif"],
         ["cube.tif", "one (Y, X) plane"]),
        (["refocus", "{room}", "--slope", 4, "--antialias", "--disparity", "{tmp}/odd.tif", "-o", "{tmp}/a.tif"],
         ["odd_confidence.tif", "[0, 1]"]),
        (["depth", "{room}", "-o", "{tmp}/a.png"], ["a.png", ".tif"]),
        (["depth", "{room}", "-o", "{tmp}/a.tif", "--range", 3, -3], ["--range", "LOW <= HIGH"]),
        (["depth", "{room}", "-o", "{tmp}/a.tif", "--range", "nan", 1], ["--range", "finite"]),
    ],
)
def test_bad_depth_options_fail_before_the_input_is_read(capsys, room, depth, tmp_path, monkeypatch, argv, words):
    from napari_lfalias._cli import commands

    def no_reading(*args):
        raise AssertionError("read the input before checking the options")

    monkeypatch.setattr(commands, "open_lightfield", no_reading)
    (tmp_path / "junk.tif").write_bytes(b"not a TIFF at all")
    tifffile.imwrite(tmp_path / "nan.tif", np.full((64, 64), np.nan, np.float32))
    tifffile.imwrite(tmp_path / "cube.tif", np.zeros((2, 64, 64, 3), np.float32), photometric="minisblack")
    tifffile.imwrite(tmp_path / "odd.tif", np.zeros((64, 64), np.float32))
    tifffile.imwrite(tmp_path / "odd_confidence.tif", np.full((64, 64), 2, np.float32))
    argv = [str(a).format(room=room[0], depth=depth, tmp=tmp_path) for a in argv]
    status, _, err = run(capsys, *argv)
    assert status == 1
    assert_one_line_error(err, *words)
    assert list(tmp_path.glob("a*")) == []


def test_a_disparity_map_of_another_shape_is_named(capsys, plane, depth, tmp_path):
    path, _ = plane  # 48 x 48 px views; the depth file is of the 64 px brick room
    out = tmp_path / "r.tif"
    status, _, err = run(capsys, "reduce", path, "--slope", 1, "--disparity", depth, "-o", out)
    assert status == 1
    assert_one_line_error(err, str(depth), "64 x 64 px", "48 x 48 px", "lfalias depth")
    assert not out.exists() and temporaries(tmp_path) == []


def test_depth_never_replaces_its_inputs_or_an_existing_output(capsys, room, depth, tmp_path):
    path, _ = room
    before = depth.read_bytes()
    status, _, err = run(capsys, "reduce", path, "--slope", 4, "--disparity", depth, "-o", depth, "--overwrite")
    assert status == 1
    assert_one_line_error(err, "is an input")
    confidence = depth.with_name("depth_confidence.tif")
    status, _, err = run(capsys, "refocus", path, "--slope", 4, "--antialias", "--disparity", depth, "-o",
                         confidence, "--overwrite")
    assert status == 1
    assert_one_line_error(err, "is an input")
    assert depth.read_bytes() == before
    out = tmp_path / "d.tif"
    (tmp_path / "d.png").write_bytes(b"mine")
    status, _, err = run(capsys, "depth", path, "-o", out)
    assert status == 1
    assert_one_line_error(err, "d.png", "--overwrite")
    assert not out.exists() and (tmp_path / "d.png").read_bytes() == b"mine"


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
    assert facts["nearer"].startswith("judged")  # a plane's file declares no occlusion order


def test_info_reports_the_occlusion_order_an_hci_folder_declares(capsys, lf_data):
    status, out, _ = run(capsys, "info", lf_data / "hci_antinous", "--json")
    assert status == 0 and json.loads(out)["nearer"] == "smaller disparities in front (declared)"


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


def test_info_on_a_processed_lytro_picture_says_it_has_no_raw_image(capsys, lf_data):
    path = lf_data / "lytro_lfp_processed_samples" / "IMG_0001-stk.lfp"
    status, _, err = run(capsys, "info", path)
    assert status == 1
    assert_one_line_error(err, "IMG_0001-stk.lfp", "processed Lytro picture", "raw")


def test_info_describes_a_lytro_raw_file(capsys, tmp_path):
    from test_sensor import _pack_f01

    (tmp_path / "IMG_0007.raw").write_bytes(_pack_f01(np.full((3280, 3280), 1000, np.uint16)))
    meta = {"image": {"rawDetails": {"mosaic": {"tile": "r,gr:gb,b", "upperLeftPixel": "b"},
                                     "pixelFormat": {"black": dict.fromkeys(("r", "gr", "gb", "b"), 168),
                                                     "white": dict.fromkeys(("r", "gr", "gb", "b"), 4095)}}}}
    (tmp_path / "IMG_0007.json").write_text(json.dumps(meta))
    status, out, _ = run(capsys, "info", tmp_path / "IMG_0007.raw", "--json")
    facts = json.loads(out)
    assert status == 0 and "--white" in facts["format"]
    assert facts["image_shape"] == [3280, 3280] and facts["bayer"] == "BGGR"


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
    from scipy import ndimage

    from napari_lfalias._cli.demo import DEMO_FILES
    from napari_lfalias._cli.demo_guv import guv_files

    files = guv_files()
    assert files is not None, "the bundled GUV sample (sample_data/guv) is missing"
    out = tmp_path / "demo"
    status, stdout, err = run(capsys, "demo", "--out", out)
    assert status == 0, err
    assert "GUV" in stdout and "note:" not in stdout and "15 x 15 views" in stdout
    for stage in ("load + decode", "disparity", "aliasing sweep", "refocus", "detect", "reduce", "write"):
        assert f"] GUV: {stage}" in stdout
    assert "found: " in stdout
    assert sorted(p.name for p in out.iterdir()) == sorted(DEMO_FILES)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["options"]["method"] == "depth" and summary["options"]["threshold"] == 0.02
    assert set(summary["seconds"]) >= {"GUV: load + decode", "GUV: disparity", "room: reduce (depth)", "all (wall)"}
    guv = summary["guv"]
    # The GUV images are the API's on the decoded capture, at the slope shown.
    lf = lfa.load(files["raw"], white=files["white"], dark=files["dark"])
    estimate = lfa.estimate_disparity(lf)
    np.testing.assert_array_equal(tifffile.imread(out / "guv_disparity.tif"), estimate.disparity)
    refocused, reduced = tifffile.imread(out / "guv_refocus.tif"), tifffile.imread(out / "guv_reduced.tif")
    np.testing.assert_array_equal(refocused, lfa.refocus(lf, guv["slope"])[..., 0])
    # The slope shown is the most aliased one of the sweep (ties: the largest mean score).
    candidates = guv["slope_candidates"]
    ranked = sorted(zip(candidates["aliased_fractions"], candidates["mean_scores"], candidates["slopes"]))
    assert guv["slope"] == ranked[-1][2]
    assert guv["aliased_fraction"] == pytest.approx(max(candidates["aliased_fractions"]))
    assert guv["largest_copy_spacing_px"] == pytest.approx(
        float(np.abs(estimate.disparity - guv["slope"]).max()), rel=1e-5)
    # The reduction changes the aliased pixels and their soft edge, nothing else.
    mask = iio.imread(out / "guv_mask.png")[::guv["preview_zoom"], ::guv["preview_zoom"]] > 0
    changed = reduced != refocused
    assert not (changed & ~ndimage.binary_dilation(mask, iterations=3)).any()
    assert guv["changed_fraction"] == pytest.approx(changed.mean())
    assert np.isfinite(reduced).all()
    zoom = guv["preview_zoom"]
    assert zoom > 1 and iio.imread(out / "guv_refocus.png").shape == (28 * zoom, 28 * zoom)
    assert iio.imread(out / "guv_overview.png").shape[1] > 6 * 28 * zoom

    # The brick room: the reduction removes the wall's aliasing and degrades nothing else.
    room = summary["brick_room"]
    from napari_lfalias.metrics import aliased_pixels, psnr
    from napari_lfalias.synthetic import brick_room

    scene = brick_room(n_views=8, size=256, seed=0)
    reference = scene.reference(4.0, interpolation="bilinear")
    naive, reduced = tifffile.imread(out / "room_naive.tif"), tifffile.imread(out / "room_reduced.tif")
    paper = tifffile.imread(out / "room_paper.tif")
    np.testing.assert_array_equal(naive, lfa.refocus(scene.lightfield, 4.0))
    np.testing.assert_array_equal(paper, lfa.reduce_aliasing(scene.lightfield, 4.0, preset="paper", seed=0).image)
    truth = aliased_pixels(naive, reference)
    assert 0.3 < truth.mean() < 0.9
    gain_aliased = psnr(reduced, reference, mask=truth) - psnr(naive, reference, mask=truth)
    gain_clean = psnr(reduced, reference, mask=~truth) - psnr(naive, reference, mask=~truth)
    assert gain_aliased > 6 and gain_clean > -0.1
    assert room["psnr"]["reduced"]["aliased"] == pytest.approx(psnr(reduced, reference, mask=truth))
    assert room["psnr"]["naive"]["clean"] == pytest.approx(psnr(naive, reference, mask=~truth))
    assert room["psnr"]["paper"]["image"] == pytest.approx(psnr(paper, reference))
    assert room["truly_aliased_fraction"] == pytest.approx(truth.mean())
    for label in ("naive refocus", "reduced (default: depth, T = 0.02)", "reduced (--preset paper"):
        assert label in stdout
    assert f"{room['psnr']['reduced']['aliased']:.2f}" in stdout
    assert f"the reduction {gain_aliased:+.1f} dB where aliased" in stdout
    # The overview shows the difference: two rows of five 256 px panels.
    overview = iio.imread(out / "overview.png")
    assert overview.shape[0] > 2 * 256 and overview.shape[1] > 5 * 256 and overview.std() > 10

    # A second run keeps the first run's files unless asked.
    before = (out / "room_reduced.tif").read_bytes()
    status, _, err = run(capsys, "demo", "--out", out)
    assert status == 1
    assert_one_line_error(err, "--overwrite")
    assert (out / "room_reduced.tif").read_bytes() == before
    # --slope, -q and the detection options reach both parts.
    status, stdout, _ = run(capsys, "demo", "--out", out, "--overwrite", "-q", "--slope", "-0.25",
                            "--method", "analytic", "--threshold", "0.011")
    assert status == 0 and "[1/" not in stdout and " s in all" not in stdout and f"{len(DEMO_FILES)} files in" in stdout
    summary = json.loads((out / "summary.json").read_text())
    assert summary["guv"]["slope"] == -0.25 and "slope_candidates" not in summary["guv"]
    assert "reduced (analytic, T = 0.011)" in stdout
    np.testing.assert_array_equal(tifffile.imread(out / "room_reduced.tif"),
                                  lfa.reduce_aliasing(scene.lightfield, 4.0, method="analytic", threshold=0.011).image)
    assert temporaries(out) == []


@pytest.mark.parametrize("missing", ["sample", "decoder"])
def test_demo_without_the_capture_shows_the_brick_room_and_says_so(capsys, tmp_path, monkeypatch, missing):
    from napari_lfalias._cli import demo

    if missing == "sample":
        monkeypatch.setattr(demo, "guv_files", lambda: None)
    else:
        monkeypatch.setattr(demo, "_lenslet_decoder_available", lambda: False)
    status, stdout, err = run(capsys, "demo", "--out", tmp_path / "demo", "-q")
    assert status == 0, err
    why = "the bundled GUV sample is missing" if missing == "sample" else "the lenslet decoder is not installed"
    assert f"note: {why}" in stdout and "brick room" in stdout
    assert sorted(p.name for p in (tmp_path / "demo").iterdir()) == sorted(demo.demo_files(False))
    summary = json.loads((tmp_path / "demo" / "summary.json").read_text())
    assert "guv" not in summary and summary["brick_room"]["views"] == [8, 8]


def test_demo_checks_its_options_before_any_work(capsys, tmp_path, monkeypatch):
    from napari_lfalias._cli import demo

    def no_work(*args):
        raise AssertionError("started before the options were checked")

    monkeypatch.setattr(demo, "run_guv", no_work)
    monkeypatch.setattr(demo, "run_room", no_work)
    status, _, err = run(capsys, "demo", "--out", tmp_path / "demo", "--gamma", 1.5)
    assert status == 1
    assert_one_line_error(err, "gamma")
    assert not (tmp_path / "demo").exists()
    (tmp_path / "file").write_text("")
    status, _, err = run(capsys, "demo", "--out", tmp_path / "file")
    assert status == 1
    assert_one_line_error(err, "must be a folder")
    (tmp_path / "old").mkdir()
    (tmp_path / "old" / "room_naive.png").write_bytes(b"mine")
    status, _, err = run(capsys, "demo", "--out", tmp_path / "old")
    assert status == 1
    assert_one_line_error(err, "room_naive.png", "--overwrite")
    assert [p.name for p in (tmp_path / "old").iterdir()] == ["room_naive.png"]


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
