"""The replacement-rule harness (benchmarks/replacement_rules.py): dumps that give back the default reduction."""

import sys
from pathlib import Path

import numpy as np
import pytest

import napari_lfalias as lfa
from napari_lfalias import metrics
from napari_lfalias.synthetic import layered_scene

from _accuracy_scenes import as_user_has_it

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
rules = pytest.importorskip("replacement_rules")


@pytest.fixture(scope="module")
def dumped(tmp_path_factory):
    """One slope of faint aliasing (two fine textures, 7x7 views) dumped as the harness does."""
    scene = layered_scene([(4.5, "fine", (0.2, 0.5, 0.2, 0.6)), (-2.7, "fine", None)], n_views=7, size=96, seed=1)
    lf, slope = as_user_has_it(scene.lightfield), 1.3
    reference = scene.reference(slope, interpolation="exact")
    truth = metrics.aliased_pixels(lfa.refocus(lf, slope), reference)
    folder = tmp_path_factory.mktemp("rules")
    rules.dump_slope(lf, slope, reference, truth, lfa.estimate_disparity(lf), folder / "faint.npz")
    return folder, lf, slope, reference


def test_the_packages_rule_gives_back_the_default_reduction(dumped):
    folder, lf, slope, reference = dumped
    (parameters, results), = rules.evaluate([folder], {"faint_fraction": [0.125]}, check=True)
    default = lfa.reduce_aliasing(lf, slope).image
    naive = lfa.refocus(lf, slope)
    expected = metrics.psnr(default, reference) - metrics.psnr(naive, reference)
    assert results.shape == (1, 4) and results[0, 0] == pytest.approx(expected, abs=1e-9)
    assert results[0, 0] > 4  # the faint aliasing taken


def test_other_parameters_judge_other_images(dumped):
    folder = dumped[0]
    rows = rules.evaluate([folder], {"faint_fraction": [0.125, 1.0], "faint_margin": [4.0]})
    (_, faint), (_, without) = rows
    assert faint[0, 0] > without[0, 0] + 3 and faint[0, 3] > without[0, 3]
    table = rules.report(rows)
    assert "faint_fraction 0.125, faint_margin 4" in table and "faint_fraction 1, faint_margin 4" in table


def test_a_dump_the_package_no_longer_gives_back_is_refused(dumped, tmp_path):
    record = dict(np.load(dumped[0] / "faint.npz"))
    record["default"] = record["naive"]
    np.savez(tmp_path / "stale.npz", **record)
    with pytest.raises(SystemExit, match="dump again"):
        rules.evaluate([tmp_path], {"faint_fraction": [0.125]}, check=True)


def test_the_faint_rule_variants_start_from_the_packages_rule(dumped):
    """benchmarks/faint_rules.py: its default variant is the package's rule, and each variant only takes
    faint pixels away from it (the flagged ones and their fringe stay)."""
    faint_rules = pytest.importorskip("faint_rules")
    record = dict(np.load(dumped[0] / "faint.npz"))
    from napari_lfalias.reduce import replaced_pixels

    package = replaced_pixels(record["score"], record["spread"], 0.02, record["faint_where"])
    assert np.array_equal(faint_rules.variant(record), package) and package.any()
    _, flagged = faint_rules.faint_and_flagged(record)
    for name, options in faint_rules.VARIANTS:
        mask = faint_rules.variant(record, **options)
        assert not (mask & ~package).any() and not (flagged & ~mask).any(), name
    assert faint_rules.variant(record, off=True).sum() < package.sum()  # this slope's aliasing is faint
    results = faint_rules.judged([dumped[0]])
    assert results["default"][0, 0] > results["no faint rule"][0, 0] + 3
