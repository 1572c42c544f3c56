"""Camera-array folders: HCI benchmark, Stanford archive, indexed names, plain lists."""

import shutil
import sys

import cv2
import imageio.v3 as iio
import numpy as np
import pytest
import tifffile
from scipy import ndimage

import napari_lfalias as lfa
from napari_lfalias.decoders.camera_array import load_camera_array
from napari_lfalias.decoders.hci import read_parameters_cfg, read_pfm
from napari_lfalias.decoders.view_names import stanford_positions
from napari_lfalias.errors import DecodeError, LightFieldWarning, ParameterError
from napari_lfalias.lightfield import regular_positions
from napari_lfalias.refocus import view_moments

# -- helpers ------------------------------------------------------------------------


def _views(n_rows=3, n_cols=3, shape=(12, 16, 3), dtype=np.uint8, seed=0):
    """Random views; each view's top-left pixel holds its row-major index, bottom-right the maximum."""
    rng = np.random.default_rng(seed)
    top = np.iinfo(dtype).max
    views = rng.integers(0, top, size=(n_rows, n_cols) + shape, endpoint=True).astype(dtype)
    views[:, :, -1, -1] = top
    for u in range(n_rows):
        for v in range(n_cols):
            views[u, v, 0, 0] = u * n_cols + v
    return views


def _write_image(path, image):
    suffix = path.suffix.lower()
    if suffix in (".tif", ".tiff"):
        tifffile.imwrite(path, image, photometric="rgb" if image.ndim == 3 else "minisblack")
    elif image.dtype == np.uint16 and image.ndim == 3:
        cv2.imwrite(str(path), image[..., ::-1])  # Pillow cannot write 16-bit colour PNG
    else:
        iio.imwrite(path, image)


def _write_views(folder, views, name):
    folder.mkdir(parents=True, exist_ok=True)
    n_rows, n_cols = views.shape[:2]
    for u in range(n_rows):
        for v in range(n_cols):
            _write_image(folder / name(u, v, n_cols), views[u, v])
    return folder


def _expected(views):
    data = views.astype(np.float32) / np.float32(np.iinfo(views.dtype).max)
    return data if data.ndim == 5 else data[..., None]


def _write_pfm(path, image, little_endian=True):
    kind = b"PF" if image.ndim == 3 else b"Pf"
    dtype = "<f4" if little_endian else ">f4"
    scale = b"-1.0" if little_endian else b"1.0"
    header = kind + b"\n%d %d\n" % (image.shape[1], image.shape[0]) + scale + b"\n"
    path.write_bytes(header + np.flipud(image).astype(dtype).tobytes())


def _hci_name(u, v, n_cols):
    return f"input_Cam{u * n_cols + v:03d}.png"


# -- the real HCI scene -------------------------------------------------------------


@pytest.fixture(scope="module")
def antinous(lf_data):
    return lfa.load(lf_data / "hci_antinous")


def test_hci_antinous_loads_with_ground_truth(antinous, lf_data):
    lf = antinous
    folder = lf_data / "hci_antinous"
    assert lf.shape == (9, 9, 512, 512, 3)
    assert lf.data.dtype == np.float32
    assert lf.meta["format"] == "hci"
    # Cam011 is row 1, column 2 (row-major, 9 per row)
    np.testing.assert_array_equal(lf.data[1, 2], iio.imread(folder / "input_Cam011.png") / np.float32(255))
    np.testing.assert_array_equal(lf.positions, lfa.lightfield.regular_positions(9, 9))
    disparity = lf.meta["disparity"]
    assert disparity.shape == (512, 512) and disparity.dtype == np.float32
    np.testing.assert_array_equal(disparity, -read_pfm(folder / "gt_disp_lowres.pfm"))
    low, high = lf.meta["disparity_range"]
    assert low == pytest.approx(float(disparity.min())) and high == pytest.approx(float(disparity.max()))
    assert -3.5 < low < -2 and 2 < high < 3.5  # SOURCE.txt: HCI range -3.13 .. +2.69


def test_hci_disparity_sign_matches_ours_by_warping(antinous):
    """A point of our disparity d at centre pixel p is seen in view (u, v) at p + d * positions."""
    lum = antinous.luminance().data[..., 0]
    disparity = antinous.meta["disparity"].astype(np.float64)
    yy, xx = np.mgrid[0:512, 0:512].astype(np.float64)
    centre = lum[4, 4]
    inner = (slice(20, -20), slice(20, -20))
    for u, v in [(0, 0), (8, 8), (0, 8), (4, 0)]:
        qy, qx = antinous.positions[u, v]
        errors = {}
        for sign in (1, -1):
            coords = [yy + sign * disparity * qy, xx + sign * disparity * qx]
            warped = ndimage.map_coordinates(lum[u, v], coords, order=1, mode="nearest")
            errors[sign] = np.abs(warped - centre)[inner].mean()
        assert errors[1] < 0.5 * errors[-1], (u, v, errors)


def test_an_hci_folder_declares_its_occlusion_order_and_its_ground_truth_agrees(antinous):
    """The HCI rig's smaller disparities (this package's sign) are nearer: so say the views at the depth edges
    of antinous's ground truth, and so the loader declares it (every rendering reads it)."""
    from napari_lfalias.baselines import _larger_is_nearer
    from napari_lfalias.depth_guided import DepthGuide

    assert antinous.meta["nearer"] == "smaller"
    views = np.ascontiguousarray(antinous.views()[::2])  # every other view: the same geometry, half the work
    positions = antinous.flat_positions()[::2]
    assert not _larger_is_nearer(views, positions, antinous.meta["disparity"].astype(np.float64))
    guide = DepthGuide(antinous, antinous.meta["disparity"])
    assert guide.nearer == "smaller" and not guide.larger_first(0.0)


def _flat_textured_patch(centre, disparity, half):
    """Centre of the most textured window whose ground-truth disparity is nearly constant."""
    gy, gx = np.gradient(centre)
    size = 2 * half
    texture = ndimage.uniform_filter(np.hypot(gy, gx), size)
    mean = ndimage.uniform_filter(disparity, size)
    spread = np.sqrt(np.maximum(ndimage.uniform_filter(disparity**2, size) - mean**2, 0))
    score = np.where(spread < 0.05, texture, 0)
    margin = half + 24
    score[:margin], score[-margin:], score[:, :margin], score[:, -margin:] = 0, 0, 0, 0
    return np.unravel_index(np.argmax(score), score.shape)


def test_refocus_at_ground_truth_disparity_makes_views_agree(antinous):
    disparity = antinous.meta["disparity"].astype(np.float64)
    lum = antinous.luminance()
    half, margin = 16, 24
    cy, cx = _flat_textured_patch(lum.data[4, 4, ..., 0], disparity, half)
    crop = (slice(cy - half - margin, cy + half + margin), slice(cx - half - margin, cx + half + margin))
    sub = lfa.LightField(lum.data[:, :, crop[0], crop[1]])
    slope = float(np.median(disparity[cy - half:cy + half, cx - half:cx + half]))

    def variance(s):
        return float(view_moments(sub, s).variance[margin:-margin, margin:-margin].mean())

    focused = variance(slope)
    for other in (slope - 1, slope + 1, -1.0, 1.0):
        assert focused < 0.25 * variance(other), (slope, other)
    # the refocused image is sharp there: it matches the centre view
    image = lfa.refocus(sub, slope)[margin:-margin, margin:-margin, 0]
    centre = sub.data[4, 4, margin:-margin, margin:-margin, 0]
    assert np.abs(image - centre).mean() < 0.02


def test_hci_lazy_matches_eager(antinous, lf_data):
    lazy = lfa.load(lf_data / "hci_antinous", lazy=True)
    assert lazy.is_lazy and lazy.shape == antinous.shape
    assert lazy.data.chunksize == (1, 1, 512, 512, 3)
    np.testing.assert_array_equal(lazy.data[::4, ::4].compute(), antinous.data[::4, ::4])
    np.testing.assert_array_equal(lazy.meta["disparity"], antinous.meta["disparity"])


# -- HCI names on synthetic files ---------------------------------------------------


def test_hci_names_without_parameters(tmp_path):
    views = _views(3, 3)
    folder = _write_views(tmp_path / "scene", views, _hci_name)
    (folder / "valid_mask.png").write_bytes(b"not a view")  # other HCI files are not views
    lf = load_camera_array(folder)
    np.testing.assert_array_equal(lf.data, _expected(views))
    assert lf.meta["format"] == "hci"
    assert "hci" not in lf.meta and "disparity" not in lf.meta


def test_hci_names_with_parameters_cfg_and_pfm(tmp_path, lf_data):
    views = _views(9, 9, shape=(6, 8, 3))
    folder = _write_views(tmp_path / "dino", views, _hci_name)
    shutil.copy(lf_data / "hci_parameters_cfg_examples" / "training_dino_parameters.cfg", folder / "parameters.cfg")
    gt = np.linspace(-1.5, 1.2, 48, dtype=np.float32).reshape(6, 8)
    _write_pfm(folder / "gt_disp_lowres.pfm", gt)
    lf = load_camera_array(folder)
    hci = lf.meta["hci"]
    assert hci["baseline_mm"] == 60.0 and hci["focal_length_mm"] == 100.0 and hci["fstop"] == 300.0
    assert hci["scene"] == "dino" and hci["num_cams_x"] == 9.0
    np.testing.assert_array_equal(lf.meta["disparity"], -gt)  # rows flipped back, sign ours
    assert lf.meta["disparity_range"] == pytest.approx((-1.2, 1.5))


def test_hci_parameters_range_without_ground_truth(tmp_path, lf_data):
    folder = _write_views(tmp_path / "dino", _views(9, 9, shape=(4, 4, 3)), _hci_name)
    shutil.copy(lf_data / "hci_parameters_cfg_examples" / "training_dino_parameters.cfg", folder / "parameters.cfg")
    assert load_camera_array(folder).meta["disparity_range"] == (-1.9, 1.9)


def test_every_parameters_cfg_example_parses(lf_data):
    for path in sorted((lf_data / "hci_parameters_cfg_examples").glob("*.cfg")):
        params = read_parameters_cfg(path)
        assert params["num_cams_x"] == 9.0 and params["image_resolution_x_px"] == 512.0
        assert isinstance(params["baseline_mm"], float) and params["baseline_mm"] > 0
        assert isinstance(params["scene"], str)


def test_hci_cfg_sets_the_grid_and_grid_must_agree_with_it(tmp_path, lf_data):
    views = _views(3, 3)
    folder = _write_views(tmp_path / "scene", views, _hci_name)
    shutil.copy(lf_data / "hci_parameters_cfg_examples" / "training_boxes_parameters.cfg", folder / "parameters.cfg")
    with pytest.warns(LightFieldWarning, match="72 of the 81 views of the 9x9 grid are missing"):
        lf = load_camera_array(folder, artefacts=False)  # the marker pixels would count as black and clipped
    # input_Cam000..008 are the first row of the 9x9 grid the file describes
    np.testing.assert_array_equal(lf.data[0], _expected(views).reshape((9,) + views.shape[2:]))
    assert lf.weights[0].min() == 1 and lf.weights[1:].max() == 0
    with pytest.raises(DecodeError, match=r"parameters\.cfg: says 9x9 cameras.*3x3 grid \(grid=\)"):
        load_camera_array(folder, grid=(3, 3))


def test_hci_ground_truth_of_another_size_is_an_error(tmp_path):
    folder = _write_views(tmp_path / "scene", _views(3, 3), _hci_name)
    _write_pfm(folder / "gt_disp_lowres.pfm", np.zeros((5, 5), np.float32))
    with pytest.raises(DecodeError, match="gt_disp_lowres.pfm"):
        load_camera_array(folder)


def test_hci_grid_sets_a_rectangular_layout(tmp_path):
    views = _views(2, 3)
    folder = _write_views(tmp_path / "scene", views, _hci_name)
    lf = load_camera_array(folder, grid=(2, 3))
    np.testing.assert_array_equal(lf.data, _expected(views))


def test_read_pfm_big_endian_colour_and_damage(tmp_path):
    image = np.arange(2 * 3 * 3, dtype=np.float32).reshape(2, 3, 3)
    _write_pfm(tmp_path / "c.pfm", image, little_endian=False)
    np.testing.assert_array_equal(read_pfm(tmp_path / "c.pfm"), image)
    raw = (tmp_path / "c.pfm").read_bytes()
    (tmp_path / "short.pfm").write_bytes(raw[:-8])
    with pytest.raises(DecodeError, match=r"short\.pfm.*truncated"):
        read_pfm(tmp_path / "short.pfm")
    (tmp_path / "bad.pfm").write_bytes(b"P6\n3 2\n255\n" + bytes(18))
    with pytest.raises(DecodeError, match=r"bad\.pfm.*not a PFM"):
        read_pfm(tmp_path / "bad.pfm")


# -- Stanford names -----------------------------------------------------------------


@pytest.mark.parametrize("trailer", ["_", ""])
def test_stanford_positions_from_names(tmp_path, trailer):
    views = _views(3, 4)
    rng = np.random.default_rng(1)
    jitter = rng.uniform(-0.4, 0.4, size=(3, 4, 2))
    # y falls as RR grows, x grows with CC; spacing 40 units; irregular by the jitter
    y = -859.7 - 40 * (np.arange(3)[:, None] + jitter[..., 0])
    x = 1579.2 + 40 * (np.arange(4)[None, :] + jitter[..., 1])

    def name(u, v, n_cols):
        return f"out_{u:02d}_{v:02d}_{y[u, v]:.6f}_{x[u, v]:.6f}{trailer}.png"

    folder = _write_views(tmp_path / "stanford", views, name)
    lf = load_camera_array(folder)
    np.testing.assert_array_equal(lf.data, _expected(views))
    assert lf.meta["format"] == "stanford"
    expected = np.stack([np.arange(3)[:, None] + jitter[..., 0], np.arange(4)[None, :] + jitter[..., 1]], -1)
    expected -= expected.mean(axis=(0, 1))
    step = lf.meta["position_step"] / 40
    np.testing.assert_allclose(lf.positions * step, expected, atol=1e-5)
    assert 0.8 < step < 1.2  # median spacing is close to the nominal 40
    assert np.all(np.diff(lf.positions[..., 0], axis=0) > 0) and np.all(np.diff(lf.positions[..., 1], axis=1) > 0)
    assert lf.meta["position_signs"] == (-1, 1)


def test_stanford_positions_follow_rows_when_names_are_swapped():
    rows, cols = np.meshgrid(np.arange(3.0), np.arange(2.0), indexing="ij")
    coords = np.stack([5.0 * cols, 5.0 * rows], -1)  # first number follows the columns
    positions, info = stanford_positions(coords)
    assert info["name_axes"] == "xy"
    np.testing.assert_allclose(positions, lfa.lightfield.regular_positions(3, 2))


# -- indexed names, lists, formats -------------------------------------------------


@pytest.mark.parametrize(
    "name, base",
    [
        (lambda u, v, n: f"scene_{u:02d}_{v:02d}.png", 0),
        (lambda u, v, n: f"view_{u + 1}_{v + 1}.tif", 1),
        (lambda u, v, n: f"lf2024_cam{u + 1}x{v + 1}.png", 1),
    ],
    ids=["rr_cc_0based", "r_c_1based_tif", "prefix_digits_1based"],
)
def test_indexed_names(tmp_path, name, base):
    views = _views(3, 4)
    folder = _write_views(tmp_path / "views", views, name)
    (folder / "notes.txt").write_text("not a view")
    lf = load_camera_array(folder)
    np.testing.assert_array_equal(lf.data, _expected(views))
    assert lf.meta["format"] == "indexed" and lf.meta["index_base"] == base


def test_plain_list_with_grid_in_natural_order(tmp_path):
    views = _views(3, 4)
    folder = _write_views(tmp_path / "views", views, lambda u, v, n: f"frame{u * n + v + 1}.png")
    lf = load_camera_array(folder, grid=(3, 4))  # frame2 before frame10
    np.testing.assert_array_equal(lf.data, _expected(views))
    assert lf.meta["format"] == "list"
    assert lf.meta["files"][1].endswith("frame2.png")


@pytest.mark.parametrize(
    "suffix, dtype, channels",
    [
        (".png", np.uint8, 3),
        (".png", np.uint8, 1),
        (".png", np.uint16, 1),
        (".png", np.uint16, 3),
        (".tif", np.uint16, 3),
        (".tif", np.uint8, 1),
        (".bmp", np.uint8, 3),
    ],
)
def test_bit_depths_and_formats(tmp_path, suffix, dtype, channels):
    shape = (10, 14, 3) if channels == 3 else (10, 14)
    views = _views(2, 2, shape=shape, dtype=dtype)
    folder = _write_views(tmp_path / "v", views, lambda u, v, n: f"v_{u}_{v}{suffix}")
    lf = load_camera_array(folder)
    assert lf.shape == (2, 2, 10, 14, channels)
    np.testing.assert_array_equal(lf.data, _expected(views))
    assert float(lf.data.max()) == 1.0  # scaled by the dtype's maximum


def test_without_opencv_pillow_reads_and_16bit_colour_is_refused(tmp_path, monkeypatch):
    views8 = _views(2, 2, shape=(6, 6, 3))
    folder8 = _write_views(tmp_path / "v8", views8, lambda u, v, n: f"v_{u}_{v}.png")
    folder16 = _write_views(tmp_path / "v16", _views(2, 2, shape=(6, 6, 3), dtype=np.uint16),
                            lambda u, v, n: f"v_{u}_{v}.png")
    monkeypatch.setitem(sys.modules, "cv2", None)  # "import cv2" now fails
    np.testing.assert_array_equal(load_camera_array(folder8).data, _expected(views8))
    with pytest.raises(DecodeError, match=r"v_0_0\.png: a 16-bit colour PNG.*opencv"):
        load_camera_array(folder16)


def test_jpeg_views(tmp_path):
    smooth = np.linspace(0, 200, 32 * 32 * 3).reshape(32, 32, 3).astype(np.uint8)
    views = np.stack([np.stack([smooth + 10 * (2 * u + v) for v in range(2)]) for u in range(2)])
    folder = _write_views(tmp_path / "j", views, lambda u, v, n: f"v_{u}_{v}.jpg")
    lf = load_camera_array(folder, artefacts=False)  # view (0, 0) is clearly darker than the others
    assert lf.shape == (2, 2, 32, 32, 3)
    np.testing.assert_allclose(lf.data, _expected(views), atol=0.04)  # lossy


def test_rgba_drops_alpha(tmp_path):
    views = _views(2, 2, shape=(6, 6, 4))
    folder = _write_views(tmp_path / "a", views, lambda u, v, n: f"v_{u}_{v}.png")
    lf = load_camera_array(folder)
    np.testing.assert_array_equal(lf.data, _expected(views[..., :3]))


def test_lazy_equals_eager_and_reports_progress(tmp_path):
    views = _views(3, 3, shape=(9, 7, 3), dtype=np.uint16)
    folder = _write_views(tmp_path / "v", views, lambda u, v, n: f"v_{u}_{v}.png")
    calls = []
    eager = load_camera_array(folder, progress=lambda done, total: calls.append((done, total)))
    assert calls[-1] == (9, 9) and [c[0] for c in calls] == list(range(1, 10))
    lazy = lfa.load(folder, lazy=True)
    assert lazy.is_lazy and lazy.data.numblocks == (3, 3, 1, 1, 1)
    np.testing.assert_array_equal(lazy.data.compute(), eager.data)
    np.testing.assert_array_equal(lazy.compute().data, eager.data)


@pytest.mark.parametrize("mode, channels", [("LA", 1), ("P", 3), ("RGBA", 3), ("I;16", 1), ("1", 1)])
def test_lazy_header_check_agrees_with_the_decoder(tmp_path, mode, channels):
    from PIL import Image

    folder = tmp_path / mode.replace(";", "")
    folder.mkdir()
    rng = np.random.default_rng(2)
    for u in range(2):
        for v in range(2):
            pixels = rng.integers(0, 256, (6, 7, 3), dtype=np.uint8)
            image = Image.fromarray(pixels).convert("RGBA" if mode == "RGBA" else "L")
            if mode == "I;16":
                image = Image.fromarray(rng.integers(0, 65536, (6, 7), dtype=np.uint16))
            elif mode != "RGBA":
                image = image.convert(mode)
            image.save(folder / f"v_{u}_{v}.png")
    eager = load_camera_array(folder)
    assert eager.n_channels == channels
    np.testing.assert_array_equal(load_camera_array(folder, lazy=True).data.compute(), eager.data)


def test_lazy_views_compute_on_a_local_cluster(tmp_path):
    distributed = pytest.importorskip("distributed")
    views = _views(2, 3, shape=(8, 8, 3))
    folder = _write_views(tmp_path / "v", views, lambda u, v, n: f"v_{u}_{v}.png")
    lazy = load_camera_array(folder, lazy=True)
    with distributed.LocalCluster(
        n_workers=1, threads_per_worker=1, processes=True, dashboard_address=":0"
    ) as cluster, distributed.Client(cluster):
        mean = lazy.data.mean(axis=(0, 1)).compute()  # the reader travels to another process
    np.testing.assert_allclose(mean, _expected(views).mean(axis=(0, 1)), rtol=1e-6)


def test_lazy_broken_file_raises_when_computed(tmp_path):
    folder = _write_views(tmp_path / "v", _views(2, 2, shape=(64, 64, 3)), lambda u, v, n: f"v_{u}_{v}.png")
    broken = folder / "v_1_0.png"
    broken.write_bytes(broken.read_bytes()[:300])  # header intact, pixels cut
    lazy = load_camera_array(folder, lazy=True)
    lazy.data[0, 0].compute()  # the other views still read
    with pytest.raises(DecodeError, match=r"v_1_0\.png"):
        lazy.data.compute()


# -- bad input ----------------------------------------------------------------------


def _folder_of(tmp_path, views, name=lambda u, v, n: f"v_{u}_{v}.png"):
    return _write_views(tmp_path / "bad", views, name)


def test_empty_folder(tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(DecodeError, match=r"empty.*empty"):
        load_camera_array(tmp_path / "empty")


def test_folder_without_images(tmp_path):
    folder = tmp_path / "docs"
    folder.mkdir()
    (folder / "readme.txt").write_text("hello")
    with pytest.raises(DecodeError, match=r"docs: no view images.*readme\.txt"):
        lfa.load(folder)


def test_a_missing_view_gets_weight_0_at_its_position_and_is_named(tmp_path):
    views = _views(3, 3)
    folder = _folder_of(tmp_path, views)
    (folder / "v_1_2.png").unlink()
    with pytest.warns(LightFieldWarning, match=r"1 of the 9 views of the 3x3 grid are missing \(row 1, column 2"):
        lf = load_camera_array(folder, artefacts=False)  # the marker pixels would count as black and clipped
    expected = _expected(views)
    expected[1, 2] = 0
    np.testing.assert_array_equal(lf.data, expected)
    assert lf.weights[1, 2].max() == 0 and lf.weights.sum() == 8 * 12 * 16
    np.testing.assert_array_equal(lf.positions, regular_positions(3, 3))
    assert lf.meta["missing_views"] == ["row 1, column 2 (like v_0_0.png)"] and lf.meta["files"][5] is None


def test_missing_hci_view_is_named(tmp_path):
    folder = _folder_of(tmp_path, _views(3, 3), _hci_name)
    (folder / "input_Cam008.png").unlink()  # the last one: the grid stays 3x3
    with pytest.warns(LightFieldWarning, match=r"missing \(input_Cam008\.png\)"):
        lf = load_camera_array(folder, artefacts=False)
    assert lf.grid_shape == (3, 3) and lf.weights[2, 2].max() == 0 and lf.weights[:2].min() == 1


def test_list_count_must_match_grid(tmp_path):
    folder = _folder_of(tmp_path, _views(2, 3), lambda u, v, n: f"img{u * n + v}.png")
    with pytest.raises(DecodeError, match=r"grid=\(3, 3\) needs 9 views.*holds 6"):
        load_camera_array(folder, grid=(3, 3))


def test_duplicate_view_is_named(tmp_path):
    folder = _folder_of(tmp_path, _views(2, 2), lambda u, v, n: f"scene_{u}_{v}.png")
    shutil.copy(folder / "scene_1_1.png", folder / "copy_1_1.png")
    with pytest.raises(DecodeError, match=r"same view: .*copy_1_1\.png.*scene_1_1\.png"):
        load_camera_array(folder)


def test_mixed_sizes_are_named(tmp_path):
    folder = _folder_of(tmp_path, _views(2, 2, shape=(8, 8, 3)))
    iio.imwrite(folder / "v_1_1.png", np.zeros((8, 9, 3), np.uint8))
    with pytest.raises(DecodeError, match=r"v_1_1\.png: a 9x8 RGB view, but v_0_0\.png is 8x8 RGB"):
        load_camera_array(folder)
    with pytest.raises(DecodeError, match=r"v_1_1\.png.*same size"):
        load_camera_array(folder, lazy=True)  # found from the headers, before any compute


def test_mixed_grey_and_colour_is_an_error(tmp_path):
    folder = _folder_of(tmp_path, _views(2, 2, shape=(8, 8, 3)))
    iio.imwrite(folder / "v_0_1.png", np.zeros((8, 8), np.uint8))
    with pytest.raises(DecodeError, match=r"v_0_1\.png.*grey.*all colour"):
        load_camera_array(folder)


@pytest.mark.parametrize("suffix", [".png", ".jpg", ".tif"])
def test_truncated_file_is_named(tmp_path, suffix):
    folder = _folder_of(tmp_path, _views(2, 2, shape=(48, 48, 3)), lambda u, v, n: f"v_{u}_{v}{suffix}")
    target = folder / f"v_0_1{suffix}"
    raw = target.read_bytes()
    target.write_bytes(raw[: len(raw) // 2])
    with pytest.raises(DecodeError, match=rf"v_0_1\{suffix}: cannot read the image"):
        load_camera_array(folder)


def test_garbage_with_an_image_suffix_is_named(tmp_path):
    folder = _folder_of(tmp_path, _views(2, 2))
    (folder / "v_1_0.png").write_bytes(b"this is not a png")
    with pytest.raises(DecodeError, match=r"v_1_0\.png: cannot read the image"):
        load_camera_array(folder)


def test_names_without_indices_need_grid(tmp_path):
    folder = _folder_of(tmp_path, _views(2, 2), lambda u, v, n: f"shot{u * n + v}.png")
    with pytest.raises(DecodeError, match=r"grid=\(U, V\)"):
        load_camera_array(folder)


def test_unknown_option_is_named(tmp_path):
    folder = _folder_of(tmp_path, _views(2, 2))
    with pytest.raises(ParameterError, match="white"):
        lfa.load(folder, white="white.tif")
    with pytest.raises(ParameterError, match="grid"):
        load_camera_array(folder, grid=(2, 0))
    with pytest.raises(ParameterError, match="grid"):
        load_camera_array(folder, grid="2x2")
    with pytest.raises(ParameterError, match="progress"):
        load_camera_array(folder, progress=3)


def test_grid_contradicting_stanford_indices(tmp_path):
    folder = _folder_of(tmp_path, _views(2, 2), lambda u, v, n: f"out_{u:02d}_{v:02d}_{u}.0_{v}.0_.png")
    with pytest.raises(ParameterError, match=r"grid=\(3, 3\).*2x2"):
        load_camera_array(folder, grid=(3, 3))


def test_a_file_is_not_a_folder(tmp_path):
    path = tmp_path / "one.png"
    iio.imwrite(path, np.zeros((4, 4), np.uint8))
    with pytest.raises(DecodeError, match=r"one\.png: not a folder"):
        load_camera_array(path)
