"""The scripted pipeline in examples/ runs end to end and writes its figures."""

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def _example():
    spec = importlib.util.spec_from_file_location("pipeline_example", EXAMPLES / "pipeline.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_pipeline_example_writes_figures_and_metrics(tmp_path):
    out = tmp_path / "figures"
    done = subprocess.run(
        [sys.executable, str(EXAMPLES / "pipeline.py"), "--out", str(out), "--size", "64", "--views", "5",
         "--slopes", "5"],
        capture_output=True, text=True, timeout=300, env={**os.environ, "MPLBACKEND": "Agg"},
    )
    assert done.returncode == 0, done.stderr
    for name in ("sweep.png", "detection.png", "reduction.png"):
        pixels = iio.imread(out / name)
        assert pixels.ndim == 3 and min(pixels.shape[:2]) > 100
        assert pixels.std() > 5, f"{name} is blank"
    numbers = json.loads((out / "metrics.json").read_text())
    fractions = numbers["aliased_fraction_per_slope"]
    assert len(fractions) == 5 and numbers["slope"] == numbers["slopes"][int(np.argmax(fractions))]
    assert numbers["aliased_fraction"] == pytest.approx(max(fractions))
    for key in ("refocus_vs_reference", "reduced_vs_reference"):
        assert 10 < numbers[key]["psnr"] < 100 and 0 < numbers[key]["ssim"] <= 1
    assert [p for p in out.iterdir() if p.name.startswith(".")] == []


def test_the_pipeline_composes_with_napari_layer_data(tmp_path):
    """A layer from the plugin's reader in, napari layers out; no viewer needed."""
    napari = pytest.importorskip("napari")
    from napari.layers import Layer

    import napari_lfalias as lfa
    from napari_lfalias._napari._reader import get_saved_lightfield_reader

    from _cli_scenes import write_plane

    path, lf = write_plane(tmp_path / "plane.tif", n=5, size=48, disparity=1)
    [layer_data] = get_saved_lightfield_reader(str(path))(str(path))
    layer = Layer.create(*layer_data)
    example = _example()
    # The plugin's layer carries the LightField (positions, metadata); a bare image layer makes one.
    from_plugin = example.lightfield_of_layer(layer)
    assert list(from_plugin.meta["disparity_range"]) == [1, 1]
    bare = example.lightfield_of_layer(napari.layers.Image(np.asarray(layer.data)))
    np.testing.assert_array_equal(bare.data, lf.data)
    np.testing.assert_array_equal(bare.positions, lf.positions)

    numbers, arrays = example.run(tmp_path / "figures", lightfield=from_plugin, n_slopes=3)
    np.testing.assert_allclose(numbers["slopes"], [0.5, 1.0, 1.5])
    assert numbers["aliased_fraction_per_slope"][1] < 0.05 < numbers["aliased_fraction"]
    expected = lfa.reduce_aliasing(lf, numbers["slope"], method="analytic", threshold=0.02, seed=0)
    np.testing.assert_array_equal(arrays["reduction"].image, expected.image)

    layers = {created.name: created for created in (Layer.create(*data) for data in example.result_layers(**arrays))}
    assert set(layers) == {"focus sweep", "Cv", "aliased", "level l*", "reduced"}
    sweep = layers["focus sweep"]
    assert sweep.data.shape == (3, 48, 48) and hasattr(sweep.data, "dask")  # still lazy: a slider in napari
    np.testing.assert_array_equal(np.asarray(sweep.data[1]), lfa.refocus(lf, 1.0)[..., 0])
    assert layers["aliased"].data.max() == 1 and layers["level l*"].data.max() > 0
