"""The README's Python example runs as written, and prints what the README says it does."""

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"


def python_blocks(text):
    return re.findall(r"```python\n(.*?)```", text, flags=re.S)


@pytest.mark.skipif(not (SHARED / "lf_data" / "hci_antinous").is_dir(), reason="needs ../shared/lf_data")
def test_the_readme_python_example_runs(tmp_path, monkeypatch, capsys):
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    blocks = python_blocks(readme)
    assert blocks, "the README has no Python example"
    # the example's relative paths, from a scratch copy of the repository root (nothing written into it)
    checkout = tmp_path / "checkout"
    checkout.mkdir()
    (checkout / "sample_data").symlink_to(ROOT / "sample_data")
    (tmp_path / "shared").symlink_to(SHARED)
    monkeypatch.chdir(checkout)
    exec(compile(blocks[0], "README.md", "exec"), {"__name__": "readme"})
    printed = capsys.readouterr().out
    naive, reduced = map(float, re.search(r"naive ([\d.]+) dB, reduced ([\d.]+) dB", printed).groups())
    assert reduced > naive + 6, printed     # the default reduction removes the wall's aliasing
    assert (checkout / "guv.zarr").is_dir()
    # the numbers the README quotes are the ones it prints (to the rounding of another machine)
    quoted = re.search(r"```text\n(.*?)```", readme, flags=re.S).group(1)
    numbers = lambda text: [float(x) for x in re.findall(r"(\d+\.\d) dB", text)]
    assert numbers(quoted) == pytest.approx(numbers(printed), abs=0.3), (quoted, printed)
