"""Progress of a lenslet decode on the command line (the napari widget's: tests/test_napari_conversion.py)."""

import io

import pytest

from napari_lfalias.cli import main

GUV = ("Lightfield_GUVExperim1.tif", "Radiometry_GUVExperim1.tif", "DarkFrame_GUVExperim1.tif")


@pytest.fixture
def guv(lf_data):
    return [lf_data / "napari_lf_guv" / name for name in GUV]


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def test_convert_shows_the_decode_steps_on_a_terminal(guv, tmp_path, monkeypatch, capsys):
    raw, white, dark = guv
    terminal = _Terminal()
    monkeypatch.setattr("sys.stderr", terminal)
    assert main(["convert", str(raw), "--white", str(white), "--dark", str(dark), "-o", str(tmp_path / "v.tif")]) == 0
    shown = terminal.getvalue()
    steps = [part.split("\x1b[K")[0] for part in shown.split("\r") if part.startswith("decoding:")]
    assert steps[0] == "decoding: 0/1 reading the capture"
    assert "decoding: 0/11 calibrating the microlens grid" in steps
    assert sum("slicing views (lens rows" in step for step in steps) == 8
    assert steps[-1] == "decoding: 11/11 steps finished" and shown.endswith("\n")


def test_convert_prints_one_line_off_a_terminal_and_nothing_when_quiet(guv, tmp_path, capsys):
    raw, white, dark = guv
    assert main(["convert", str(raw), "--white", str(white), "-o", str(tmp_path / "a.tif")]) == 0
    assert capsys.readouterr().err == "decoding: 11/11 steps finished\n"
    assert main(["convert", str(raw), "--white", str(white), "-o", str(tmp_path / "b.tif"), "--quiet"]) == 0
    assert capsys.readouterr().err == ""
