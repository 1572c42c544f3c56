"""Partial camera arrays: the HCI training scenes as often handed around, 33 of their 81 views."""

import shutil
import warnings

import numpy as np
import pytest

import napari_lfalias as lfa
from napari_lfalias.cli import main
from napari_lfalias.errors import DecodeError, LightFieldWarning


def _kept(u, v):
    """The cross, the diagonals and the centre 3x3 of a 9x9 grid: 33 views."""
    return u == 4 or v == 4 or u == v or u + v == 8 or (3 <= u <= 5 and 3 <= v <= 5)


KEPT = np.array([[_kept(u, v) for v in range(9)] for u in range(9)])


@pytest.fixture(scope="module")
def partial(lf_data, tmp_path_factory):
    folder = tmp_path_factory.mktemp("antinous_33")
    for u, v in zip(*np.nonzero(KEPT)):
        shutil.copy(lf_data / "hci_antinous" / f"input_Cam{u * 9 + v:03d}.png", folder)
    shutil.copy(lf_data / "hci_antinous" / "gt_disp_lowres.pfm", folder)
    return folder


@pytest.fixture(scope="module")
def full(lf_data):
    return lfa.load(lf_data / "hci_antinous")


def _load_quietly(path, **options):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LightFieldWarning)
        return lfa.load(path, **options)


def test_33_of_81_hci_views_load_at_their_positions_the_rest_at_weight_0(partial, full):
    assert KEPT.sum() == 33
    with pytest.warns(LightFieldWarning, match=r"48 of the 81 views of the 9x9 grid are missing \(input_Cam001\.png"):
        lf = lfa.load(partial)
    assert lf.grid_shape == (9, 9) and lf.meta["format"] == "hci" and len(lf.meta["missing_views"]) == 48
    np.testing.assert_array_equal(lf.positions, full.positions)
    np.testing.assert_array_equal(lf.data[KEPT], full.data[KEPT])
    assert np.all(lf.data[~KEPT] == 0)
    np.testing.assert_array_equal(lf.weights.max(axis=(2, 3)) > 0, KEPT)
    assert lf.weights[KEPT].min() == 1
    np.testing.assert_array_equal(lf.meta["disparity"], full.meta["disparity"])


def test_the_refocus_of_a_partial_array_averages_the_views_it_has(partial, full):
    lf = _load_quietly(partial)
    np.testing.assert_allclose(lfa.refocus(lf, 0.0), full.data[KEPT].mean(axis=0), rtol=1e-5, atol=1e-6)
    # At a slope, the partial array sees what the full one sees through the same 33 views.
    only_kept = lfa.LightField(full.data, full.positions, weights=np.broadcast_to(
        KEPT[:, :, None, None], full.data.shape[:4]).astype(np.float32))
    np.testing.assert_allclose(lfa.refocus(lf, 1.5), lfa.refocus(only_kept, 1.5), rtol=1e-5, atol=1e-6)


def test_lazy_loading_of_a_partial_array_matches_eager(partial):
    eager = _load_quietly(partial)
    lazy = _load_quietly(partial, lazy=True)
    np.testing.assert_array_equal(lazy.compute().data, eager.data)
    np.testing.assert_array_equal(lazy.weights, eager.weights)


def test_grid_that_contradicts_hci_numbering_is_named(partial):
    with pytest.raises(DecodeError, match=r"input_Cam036\.png.* beyond the 33 of the 3x11 grid of grid=\(3, 11\); "
                                          r"HCI names number the views row by row"):
        lfa.load(partial, grid=(3, 11))


def test_the_command_line_reads_a_partial_array(partial, capsys, tmp_path):
    assert main(["info", str(partial)]) == 0
    captured = capsys.readouterr()
    assert "missing views:  48 of 81 (weight 0): input_Cam001.png" in captured.out
    assert captured.err.startswith("lfalias: warning: ") and len(captured.err.splitlines()) == 1
    out = tmp_path / "near.png"
    assert main(["refocus", str(partial), "--slope", "-1e-3", "-o", str(out), "-q"]) == 0
    assert out.exists()


def test_grid_UxV_on_the_command_line_reads_a_plain_list(partial, tmp_path, capsys):
    """33 views with names that carry no indices: --grid 3x11 reads them row-major in sorted order."""
    plain = tmp_path / "plain"
    plain.mkdir()
    for i, path in enumerate(sorted(partial.glob("*.png"))):
        shutil.copy(path, plain / f"shot{i}.png")
    assert main(["info", str(plain)]) == 1
    assert "--grid UxV" in capsys.readouterr().err  # the library's grid=(U, V), said as the flag
    assert main(["info", str(plain), "--grid", "3x11", "--json"]) == 0
    assert '"views": "3 x 11"' in capsys.readouterr().out
    out = tmp_path / "views.zarr"
    assert main(["convert", str(plain), "--grid", "3x11", "-o", str(out), "-q"]) == 0
    assert lfa.load(out).grid_shape == (3, 11)


def test_a_stanford_folder_missing_a_view_keeps_the_positions_its_names_imply(tmp_path):
    import imageio.v3 as iio

    step = 2.5
    for u in range(3):
        for v in range(4):
            if (u, v) != (1, 2):
                y, x = 10 - step * u, 40 + step * v  # camera coordinates in the names, y falling with the row
                iio.imwrite(tmp_path / f"out_{u:02d}_{v:02d}_{y:.3f}_{x:.3f}_.png", np.full((4, 6), 50 * u + v, np.uint8))
    with pytest.warns(LightFieldWarning, match=r"1 of the 12 views of the 3x4 grid are missing \(out_01_02_\*\.png\)"):
        lf = lfa.load(tmp_path, artefacts=False)  # view (0, 0) is all black
    np.testing.assert_allclose(lf.positions, lfa.regular_positions(3, 4), atol=1e-12)
    assert lf.weights[1, 2].max() == 0 and lf.weights.sum() == 11 * 24
