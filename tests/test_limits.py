"""Bounded memory and time: image bombs, parameters that imply huge arrays, huge slopes, numerics at the edges."""

import threading
import zlib

import numpy as np
import pytest
import tifffile

import napari_lfalias as lfa
from napari_lfalias import _budget, detect
from napari_lfalias.cli import main
from napari_lfalias.errors import DecodeError, ParameterError
from napari_lfalias.synthetic import brick_room

from _cli_scenes import plane_lightfield


@pytest.fixture
def budget_256m(monkeypatch):
    monkeypatch.setenv(_budget.ENV, "256M")


def _png_of_zeros(path, width, height):
    """A real, complete PNG of zeros: a few hundred KB that decode to width x height bytes."""
    def chunk(kind, body):
        return len(body).to_bytes(4, "big") + kind + body + zlib.crc32(kind + body).to_bytes(4, "big")

    compressor = zlib.compressobj(9)
    row = b"\0" * (width + 1)  # filter byte + pixels
    body = b"".join(compressor.compress(row) for _ in range(height)) + compressor.flush()
    ihdr = width.to_bytes(4, "big") + height.to_bytes(4, "big") + bytes([8, 0, 0, 0, 0])
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", body) + chunk(b"IEND", b""))
    return path


def png_bomb_folder(folder, side):
    """A folder of 3 x 3 views, each a PNG of ``side`` x ``side`` zeros; returns the first view."""
    folder.mkdir()
    first = _png_of_zeros(folder / "view_0_0.png", side, side)
    for u, v in np.ndindex(3, 3):
        if (u, v) != (0, 0):
            (folder / f"view_{u}_{v}.png").write_bytes(first.read_bytes())
    return first


def test_a_folder_of_png_bombs_is_refused_from_the_headers(tmp_path, budget_256m):
    folder = tmp_path / "bombs"
    first = png_bomb_folder(folder, 12000)
    assert first.stat().st_size < 200_000  # 144 Mpx in a small file
    with pytest.raises(DecodeError, match=r"view_0_0\.png: 9 views of 12000 x 12000 x 1 float32.* need 4\.8 GiB, "
                                          r"more than the memory budget of 256\.0 MiB \(set by LFALIAS_MEMORY_BUDGET\)"):
        lfa.load(folder)
    # One view alone, as a lenslet capture: refused before decoding too.
    with pytest.raises(DecodeError, match=r"view_0_0\.png: its header declares a 12000 x 12000 x 1 image"):
        lfa.load(first, white=first)


def test_a_compressed_tiff_bomb_is_refused_before_decoding(tmp_path, budget_256m):
    path = tmp_path / "bomb.tif"
    tiles = (np.zeros((512, 512), np.uint16) for _ in range(24 * 24))
    tifffile.imwrite(path, tiles, shape=(12288, 12288), dtype=np.uint16, tile=(512, 512), compression="zlib")
    assert path.stat().st_size < 2_000_000
    with pytest.raises(DecodeError, match=r"bomb\.tif: its header declares a 12288 x 12288 image.* need 864\.0 MiB"):
        lfa.load(path, white=path)
    folder = tmp_path / "views"
    folder.mkdir()
    (folder / "view_0_0.tif").write_bytes(path.read_bytes())
    (folder / "view_0_1.tif").write_bytes(path.read_bytes())
    with pytest.raises(DecodeError, match=r"2 views of 12288 x 12288 x 1 float32"):
        lfa.load(folder)


def test_the_budget_variable_is_checked():
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv(_budget.ENV, "lots")
        with pytest.raises(ParameterError, match="LFALIAS_MEMORY_BUDGET='lots' is not an amount"):
            _budget.memory_budget()
        patch.setenv(_budget.ENV, "1.5G")
        assert _budget.memory_budget()[0] == int(1.5 * 2**30)


@pytest.mark.parametrize("call, match", [
    (lambda lf: lfa.sweep.estimate_slope_range(lf, n_slopes=10**9), r"n_slopes=1000000000: the variances of every slope need 953\.7 GiB"),
    (lambda lf: detect.sampling_patterns(64, 0.2, 10**9), r"n_patterns=1000000000: .* need 238\.4 GiB"),
    (lambda lf: lfa.io_write.write_png("/tmp/never.png", np.zeros((4, 4)), zoom=10**6), r"zoom=1000000"),
])
def test_parameters_that_imply_huge_arrays_are_refused_by_name(budget_256m, call, match):
    lf = lfa.LightField(np.random.default_rng(0).random((3, 3, 16, 16, 1), np.float32))
    with pytest.raises(ParameterError, match=match):
        call(lf)


@pytest.mark.parametrize("block", [None, 9 * 7])
def test_monte_carlo_matches_its_definition(monkeypatch, block):
    """Eq. 7 by hand: the refocus from each pattern's views, std / mean over the patterns.

    With ``block``, the 300 patterns are drawn and accumulated 7 at a time.
    """
    if block is not None:
        monkeypatch.setattr(detect, "_PATTERN_BLOCK_ELEMENTS", block)
    lf = brick_room(n_views=3, size=32, seed=1).lightfield.luminance()
    slope, n_patterns = 2.0, 300
    patterns = detect.sampling_patterns(lf.n_views, 0.3, n_patterns, seed=5)
    stack = lfa.shift_views(lf, slope)
    values, weights = stack.values[..., 0].reshape(lf.n_views, -1), stack.weights.reshape(lf.n_views, -1)
    means = (patterns @ (values * weights)) / (patterns @ weights)
    floor = 0.01 * lf.data.max()
    expected = (means.std(axis=0) / np.maximum(means.mean(axis=0), floor)).reshape(lf.image_shape)
    found = lfa.detect_aliasing(lf, slope, gamma=0.3, n_patterns=n_patterns, seed=5, method="monte_carlo",
                                skip_flat=False).cv
    np.testing.assert_allclose(found, expected, rtol=1e-4, atol=1e-6)


@pytest.mark.parametrize("slope", [1e6, 1e12, 1e30, -1e300])
def test_huge_slopes_give_the_result_of_views_shifted_out_of_the_image(slope):
    lf = lfa.LightField(np.random.default_rng(0).random((3, 3, 16, 16, 1), np.float32))
    image = lfa.refocus(lf, slope)
    # Only the centre view (position 0) still sees the image.
    np.testing.assert_allclose(image, lf.data[1, 1], rtol=1e-6)
    for method in ("analytic", "monte_carlo"):
        det = lfa.detect_aliasing(lf, slope, method=method)
        assert np.isfinite(det.cv).all() and not det.mask.any()  # one view: nothing varies


@pytest.mark.parametrize("slope", [3.4028235677973366e38, 1e39, -1e300])
def test_the_default_reduction_takes_slopes_beyond_float32(slope):
    """Such a slope once overflowed the float32 disparity the renderer bins (fuzz: ValueError from NaN)."""
    lf = lfa.LightField(np.random.default_rng(0).random((3, 3, 16, 16, 1), np.float32))
    far = lfa.reduce_aliasing(lf, slope)
    near = lfa.reduce_aliasing(lf, np.copysign(1e30, slope))
    assert np.isfinite(far.image).all()
    np.testing.assert_array_equal(far.image, near.image)
    np.testing.assert_array_equal(far.level, near.level)


def test_levels_beyond_any_image_are_refused_by_name(capsys, tmp_path):
    lf = lfa.LightField(np.random.default_rng(0).random((2, 2, 8, 8, 1), np.float32))
    for level in (17, 63, 300):
        with pytest.raises(ParameterError, match=f"max_level must be an integer from 0 to 16, got {level}"):
            lfa.reduce_aliasing(lf, 0.0, max_level=level)
    path = lfa.save(lf, tmp_path / "views.tif")
    assert main(["reduce", str(path), "--slope", "0", "--levels", "300", "-o", str(tmp_path / "r.png")]) == 1
    assert capsys.readouterr().err == "lfalias: error: --levels must be an integer from 0 to 16, got 300\n"


@pytest.mark.parametrize("peak", [3e37, 3e38])
def test_refocus_of_data_near_the_float32_maximum_is_the_scaled_refocus(peak):
    """The float32 sums of 16 views this bright overflow: refocus once returned inf here."""
    lf = brick_room(n_views=4, size=48, seed=0).lightfield
    scale = peak / float(lf.data.max())
    found = lfa.refocus(lfa.LightField((lf.data.astype(np.float64) * scale).astype(np.float32), lf.positions), 2.0)
    np.testing.assert_allclose(found.astype(np.float64) / scale, lfa.refocus(lf, 2.0), rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("peak", [1e-40, 3e38])
@pytest.mark.parametrize("method", ["analytic", "monte_carlo"])
def test_cv_of_subnormal_and_near_maximal_float32_data(peak, method):
    """A subnormal peak once asked for a scale float32 cannot hold (inf, so a NaN Cv)."""
    lf = brick_room(n_views=4, size=48, seed=0).lightfield
    options = dict(method=method, seed=2, threshold=0.01)
    reference = lfa.detect_aliasing(lf, 2.0, **options)
    data = (lf.data.astype(np.float64) * (peak / float(lf.data.max()))).astype(np.float32)
    found = lfa.detect_aliasing(lfa.LightField(data, lf.positions), 2.0, **options)
    # 1e-40 is subnormal: the data themselves keep about 17 bits
    np.testing.assert_allclose(found.cv, reference.cv, rtol=0, atol=1e-4 * reference.cv.max())
    np.testing.assert_array_equal(found.mask, reference.mask)


@pytest.mark.parametrize("scale", [1e-30, 1e-20, 1e-10, 1e10, 1e20, 1e30])
@pytest.mark.parametrize("method, luminance", [("analytic", "rec709"), ("monte_carlo", "rec709"), ("analytic", "max")])
def test_cv_does_not_depend_on_the_scale_of_the_data(scale, method, luminance):
    lf = brick_room(n_views=4, size=48, seed=0).lightfield
    options = dict(method=method, seed=2, luminance=luminance, threshold=0.01)
    reference = lfa.detect_aliasing(lf, 2.0, **options)
    scaled = lfa.LightField(lf.data * np.float32(scale), lf.positions)
    found = lfa.detect_aliasing(scaled, 2.0, **options)
    assert reference.mask.any()
    np.testing.assert_allclose(found.cv, reference.cv, rtol=1e-5, atol=1e-6 * reference.cv.max())
    np.testing.assert_array_equal(found.mask, reference.mask)
    detector = lfa.AliasingDetector(scaled)
    assert detector.floor == pytest.approx(lfa.AliasingDetector(lf).floor * scale, rel=1e-5)


def test_one_detector_shared_by_threads_gives_the_serial_results():
    lf = brick_room(n_views=4, size=64, seed=0).lightfield
    jobs = [(slope, dict(gamma=gamma, method=method, seed=1, n_patterns=40))
            for slope in (0.0, 2.0, 4.0) for gamma in (0.2, 0.4) for method in ("analytic", "monte_carlo")]
    expected = [lfa.detect_aliasing(lf, slope, **options).cv for slope, options in jobs]
    shared = lfa.AliasingDetector(lf)
    failures, wrong = [], []

    def work(offset):
        for round_ in range(4):
            for k in range(len(jobs)):
                index = (k + offset + round_) % len(jobs)
                slope, options = jobs[index]
                try:
                    cv = shared.detect(slope, **options).cv
                except Exception as exc:  # noqa: BLE001 - any failure is a finding
                    failures.append(repr(exc))
                    continue
                if not np.allclose(cv, expected[index], rtol=1e-5, atol=1e-7):
                    wrong.append(index)

    threads = [threading.Thread(target=work, args=(offset,)) for offset in (0, 5, 9)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert failures == [] and wrong == []


def test_the_disparity_estimate_reads_the_central_views_of_a_large_array():
    """27 x 27 lenslet views cost 9x the central 9 x 9 for the same range (``lfalias info`` took 9 s)."""
    from napari_lfalias.sweep import estimate_slope_range

    lf = plane_lightfield(n=15, size=40, disparity=1, seed=4)
    data = lf.data.copy()
    outer = np.ones((15, 15), bool)
    outer[3:12, 3:12] = False
    data[outer] = np.random.default_rng(0).random(data[outer].shape)  # the outer views disagree with everything
    low, high = estimate_slope_range(lfa.LightField(data, lf.positions))
    assert low == pytest.approx(1.0) and high == pytest.approx(1.0)


def test_a_monte_carlo_cv_that_would_take_hours_is_refused_naming_n_patterns():
    lf = brick_room(n_views=4, size=32, seed=0).lightfield
    with pytest.raises(ParameterError, match=r"n_patterns=1000000000000: .*sample visits.*method='analytic'"):
        lfa.detect_aliasing(lf, 2.0, method="monte_carlo", n_patterns=10**12, threshold=0.01)


@pytest.mark.parametrize("peak", [1e-30, 3e37])
def test_the_default_reduction_does_not_depend_on_the_scale_of_the_data(peak):
    """The dense-aperture renderer sums in float32: extreme data are rendered at a power-of-two scale."""
    lf = brick_room(n_views=4, size=48, seed=0).lightfield
    reference = lfa.reduce_aliasing(lf, 2.0)
    factor = peak / float(lf.data.max())
    scaled = lfa.LightField((lf.data.astype(np.float64) * factor).astype(np.float32), lf.positions, lf.meta)
    found = lfa.reduce_aliasing(scaled, 2.0)
    np.testing.assert_array_equal(found.detections[0].mask, reference.detections[0].mask)
    # float32 sums of samples scaled by a factor that is not a power of two round differently (measured: one
    # element of 6912 1.7e-5 apart); an overflow or underflow would be far off
    np.testing.assert_allclose(found.image / factor, reference.image, rtol=1e-4, atol=1e-6)
