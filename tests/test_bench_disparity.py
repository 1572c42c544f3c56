"""The disparity benchmark's own pieces, on tiny synthetic light fields (benchmarks/bench_disparity.py)."""

import sys
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

from napari_lfalias.synthetic import layered_scene, textured_plane

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"
sys.path.insert(0, str(BENCHMARKS))
bench = pytest.importorskip("bench_disparity")
harness = pytest.importorskip("_harness")


@pytest.fixture(scope="module")
def plane():
    return textured_plane(n_views=3, size=48, seed=1, disparity=1.25)


def test_slope_grid_is_centred_with_the_step():
    slopes = bench.slope_grid(-1.0, 2.0, 0.4)
    assert np.allclose(np.diff(slopes), 0.4)
    assert len(slopes) == 8  # 3.0 / 0.4 = 7.5 steps: 8 slopes fit
    assert slopes[0] >= -1.0 and slopes[-1] <= 2.0
    assert np.isclose(slopes.mean(), 0.5)


def test_naive_sweep_recovers_a_textured_plane(plane):
    disparity = bench.naive_sweep(plane.lightfield, bench.slope_grid(-3.0, 3.0, 0.25))
    assert disparity.shape == (48, 48) and disparity.dtype == np.float32
    inner = disparity[8:-8, 8:-8]
    assert abs(float(np.median(inner)) - 1.25) < 0.05
    assert np.mean(np.abs(inner - 1.25) < 0.25) > 0.9


def test_naive_sweep_off_grid_plane_needs_the_parabola():
    scene = textured_plane(n_views=3, size=48, seed=2, disparity=0.6)
    slopes = bench.slope_grid(-2.0, 2.0, 0.5)  # 0.6 lies between the slopes 0.5 and 1.0
    assert not np.any(np.isclose(slopes, 0.6))
    disparity = bench.naive_sweep(scene.lightfield, slopes)
    assert abs(float(np.median(disparity[8:-8, 8:-8])) - 0.6) < 0.1


def test_scores_add_share_within_and_median_to_the_hci_metrics():
    truth = np.zeros((50, 50))
    estimate = truth + 0.05
    estimate[15:25, 15:35] = 1.0  # 200 of the 400 inner pixels off by 1 px
    s = bench.scores(estimate, truth, border=15)
    assert s["badpix_0.07"] == pytest.approx(50.0)
    assert s["badpix_0.03"] == pytest.approx(100.0)
    assert s["mse_x100"] == pytest.approx(100 * (0.5 * 1.0 + 0.5 * 0.05 ** 2))
    assert s["within_0.25"] == pytest.approx(50.0)
    assert s["median_abs"] == pytest.approx(0.525)


def test_evaluate_gives_rows_for_the_estimate_and_the_naive_sweep():
    scene = layered_scene([(2.0, "tiles", (0.3, 0.7, 0.3, 0.7)), (-1.0, "noise", None)], n_views=5, size=64,
                          seed=3, name="tiny")
    result = bench.evaluate("tiny", scene.lightfield, scene.disparity, repeats=2)
    assert len(result["seconds"]) == 2 and len(result["cpu"]) == 2
    assert "sweep" in result["stages"] and len(result["stages"]["sweep"]) == 2
    assert result["n_slopes"] == len(bench.estimator_slopes(scene.lightfield, result["estimate"]))
    # both find the two layers on most pixels (a wrong sign or scale would find almost none)
    assert result["scores"]["within_0.25"] > 60 and result["naive_scores"]["within_0.25"] > 60
    rows = bench.accuracy_rows([result], floor=0.01)
    assert [row[:2] for row in rows] == [["tiny", "estimate_disparity"], ["tiny", "naive sweep (WTA variance)"]]
    assert all(len(row) == 2 + len(bench.SCORE_HEADER) + 2 for row in rows)
    assert rows[1][2] == f"{result['naive_scores']['badpix_0.07']:.2f}"


def test_unit_check_singles_out_the_true_scale(plane):
    truth = np.asarray(plane.disparity, np.float64)
    medians, least, count = bench.unit_check(plane.lightfield, truth, 1.25, border=8)
    assert count == 32 * 32
    assert min(medians, key=medians.get) == 1.0
    assert least[1.0] > 0.9


def test_line_fit_finds_scale_and_offset():
    truth = np.linspace(-3, 3, 60 * 60).reshape(60, 60)
    a, b = bench.line_fit(-2.0 * truth + 0.5, truth)
    assert a == pytest.approx(-2.0) and b == pytest.approx(0.5)


def test_depth_edges_and_slant_regions():
    truth = np.zeros((40, 40))
    truth[:, 20:] = 1.0
    near = bench.near_depth_edges(truth)
    assert near[:, 17:23].all()
    assert not near[:, :15].any() and not near[:, 25:].any()
    ramp = np.tile(np.arange(40) * 0.05, (40, 1))
    assert bench.steep_slant(ramp).all() and not bench.steep_slant(ramp * 0.1).any()


def test_error_regions_split_the_bad_pixels():
    truth = np.zeros((40, 40))
    estimate = truth.copy()
    estimate[:, :10] = 0.5  # bad on the left quarter
    left = np.zeros(truth.shape, bool)
    left[:, :20] = True
    rows = bench.error_regions(estimate, truth, {"left": left, "right": ~left}, border=0)
    assert rows == [["left", "50.0", "50.0", "100.0", "100.0"], ["right", "50.0", "0.0", "0.0", "0.0"]]


def test_weak_texture_finds_the_flat_part():
    data = np.full((3, 3, 32, 32, 1), 0.5, np.float32)
    data[:, :, :16] += np.random.default_rng(0).random((3, 3, 16, 32, 1), dtype=np.float32) * 0.4
    from napari_lfalias import LightField

    weak = bench.weak_texture(LightField(data))
    assert weak[22:, :].all() and not weak[:12, :].any()


def test_save_panels_writes_four_panels(tmp_path, plane):
    truth = np.asarray(plane.disparity, np.float32)
    path, (low, high) = bench.save_panels(tmp_path / "p.png", truth + 0.3, truth, np.full(truth.shape, 0.5), gap=4)
    image = iio.imread(path)
    assert image.shape == (48, 4 * 48 + 3 * 4, 3)
    error_panel = image[:, 2 * 52:2 * 52 + 48]
    assert (error_panel == error_panel[0, 0]).all()  # 0.3 px everywhere: clipped at 0.2, one colour
    assert low == pytest.approx(1.25) and high == pytest.approx(1.25)


def test_goal_line_and_kept_notes(tmp_path):
    result = {"scores": {"badpix_0.07": 8.0, "mse_x100": 1.5}, "seconds": np.array([1.0, 1.5, 3.0])}
    assert "MET" in bench.goal_line(result) and "NOT MET" not in bench.goal_line(result)
    result["scores"]["mse_x100"] = 2.5
    assert "NOT MET" in bench.goal_line(result)
    report = tmp_path / "r.md"
    assert "(no notes yet)" in harness.kept_notes(report)
    begin, end = harness.NOTES_BEGIN, harness.NOTES_END
    report.write_text(f"# t\n\n{begin}\nhalos at the silhouette\n{end}\n\nmore")
    assert harness.kept_notes(report) == f"{begin}\nhalos at the silhouette\n{end}"
