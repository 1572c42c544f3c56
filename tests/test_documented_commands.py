"""Every command line the README, docs/cli.md and ``lfalias --help`` show runs as written.

On the bundled GUV capture (a real lenslet raw with its white and dark
frames) under the names the documents use, each document's commands in
order in a folder of their own (a later line reads what an earlier one
wrote). Only what cannot run here is changed: ``--scheduler ADDRESS`` of a
remote cluster becomes a local ``--workers 1``, an absolute output under
``/tmp`` goes into the test's folder, and the shell's globs are expanded.
"""

import glob
import shlex
import shutil
from pathlib import Path

import pytest

from napari_lfalias import cli

ROOT = Path(__file__).resolve().parents[1]
GUV = ROOT / "sample_data" / "guv"


def _code_lines(markdown):
    """The ``lfalias`` lines of the fenced code blocks of ``markdown``."""
    lines, fenced = [], False
    for line in markdown.read_text().splitlines():
        if line.startswith("```"):
            fenced = not fenced
        elif fenced and line.strip().startswith("lfalias "):
            lines.append(line.strip())
    return lines


def _help_lines():
    return [line.strip() for line in cli.EXAMPLES.splitlines() if line.strip().startswith("lfalias ")]


DOCUMENTS = {
    "README.md": lambda: _code_lines(ROOT / "README.md"),
    "docs/cli.md": lambda: _code_lines(ROOT / "docs" / "cli.md"),
    "lfalias --help": _help_lines,
}


def _argv(line):
    """The arguments of a documented ``line`` as this test runs it."""
    words = shlex.split(line, comments=True)[1:]
    if "--scheduler" in words:
        at = words.index("--scheduler")
        words[at:at + 2] = ["--workers", "1"]
    words = [word.replace("/tmp/", "./") if word.startswith("/tmp/") else word for word in words]
    expanded = []
    for word in words:
        expanded += sorted(glob.glob(word)) if any(c in word for c in "*?[") else [word]
    return expanded


def _written(argv):
    """What the command says it writes: the file after ``-o`` or the folder after ``--out``."""
    for flag in ("-o", "--out"):
        if flag in argv:
            return Path(argv[argv.index(flag) + 1])
    return None


@pytest.fixture
def capture_folder(tmp_path, monkeypatch):
    for name, source in (("capture.tif", "Lightfield"), ("white.tif", "Radiometry"), ("dark.tif", "DarkFrame")):
        shutil.copy(GUV / f"{source}_GUVExperim1.tif", tmp_path / name)
    (tmp_path / "raw").mkdir()
    for name in ("a.tif", "b.tif"):
        shutil.copy(GUV / "Lightfield_GUVExperim1.tif", tmp_path / "raw" / name)
    monkeypatch.chdir(tmp_path)
    return tmp_path


@pytest.mark.parametrize("document", sorted(DOCUMENTS))
def test_the_documented_commands_run_as_written(document, capture_folder, capsys):
    lines = DOCUMENTS[document]()
    assert len(lines) >= 3, f"{document}: no command lines found"
    for line in lines:
        argv = _argv(line)
        status = cli.main(argv)
        err = capsys.readouterr().err
        assert status == 0, f"{document}: `{line}` exited {status}: {err}"
        written = _written(argv)
        if written is not None:
            assert written.exists() and (written.is_file() or any(written.iterdir())), f"{document}: `{line}`"
