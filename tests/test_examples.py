"""The scripted pipeline in examples/ runs end to end and writes its figures."""

import json
import os
import subprocess
import sys
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def test_pipeline_example_writes_figures_and_metrics(tmp_path):
    for module in ("synthetic", "detect", "reduce", "metrics"):
        pytest.importorskip(f"napari_lfalias.{module}")
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
