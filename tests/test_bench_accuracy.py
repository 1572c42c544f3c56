"""The accuracy benchmark's own bookkeeping (benchmarks/bench_accuracy.py): an interrupted run resumes."""

import sys
from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"
sys.path.insert(0, str(BENCHMARKS))
bench = pytest.importorskip("bench_accuracy")

#: Tiny cases at one slope: four synthetic scenes of the tune split have "over" in their names.
ARGS = ["--split", "tune", "--cases", "over", "--size", "48", "--slopes", "2"]


def test_an_interrupted_run_resumes_without_judging_its_cases_again(tmp_path, monkeypatch):
    out = tmp_path / "accuracy.md"
    judged = []
    judge = bench._judge_case

    def interrupted_after_two(case, slopes, images_dir):
        if len(judged) == 2:
            raise KeyboardInterrupt
        judged.append(case.name)
        return judge(case, slopes, images_dir)

    monkeypatch.setattr(bench, "_judge_case", interrupted_after_two)
    with pytest.raises(KeyboardInterrupt):
        bench.main(ARGS + ["--out", str(out)])
    assert not out.exists()
    assert len(bench._resumed(out)) == 2  # both judged cases were kept as they finished

    first = list(judged)
    judged.clear()
    monkeypatch.setattr(bench, "_judge_case", lambda case, slopes, images_dir: (
        judged.append(case.name), judge(case, slopes, images_dir))[1])
    bench.main(ARGS + ["--out", str(out), "--resume"])
    assert judged and not set(judged) & set(first)  # only the rest were judged
    text = out.read_text()
    sections = [line[4:].rsplit(" (", 1)[0] for line in text.splitlines() if line.startswith("### ")]
    assert sections == first + judged  # every case once, in the benchmark's order
    assert not bench._progress_file(out).exists()  # a finished report leaves no progress behind


def test_a_run_without_resume_starts_afresh(tmp_path):
    out = tmp_path / "accuracy.md"
    bench._progress_file(out).write_bytes(b"left by an older run")
    bench.main(["--split", "tune", "--cases", "smooth over", "--size", "48", "--slopes", "1", "--out", str(out)])
    assert "### smooth over fine noise" in out.read_text()
    assert not bench._progress_file(out).exists()


def test_resume_needs_the_report_it_continues():
    with pytest.raises(SystemExit, match="--resume needs --out"):
        bench.main(["--split", "tune", "--cases", "smooth over", "--resume"])


def _summary(report):
    text = report.read_text()
    return text[text.index("## Summary"):text.index("## Notes")]


def test_workers_share_the_cases_and_write_the_report_one_process_would(tmp_path):
    alone, shared = tmp_path / "alone" / "accuracy.md", tmp_path / "shared" / "accuracy.md"
    bench.main(ARGS + ["--out", str(alone)])
    bench.main(ARGS + ["--out", str(shared), "--workers", "2"])
    headings = [[line for line in out.read_text().splitlines() if line.startswith("### ")] for out in (alone, shared)]
    assert len(headings[0]) >= 4 and headings[1] == headings[0]  # every case once, in the benchmark's order
    assert _summary(shared) == _summary(alone)
    assert not list(shared.parent.glob("accuracy.md.progress*"))  # the workers' progress gathered and removed


def test_workers_need_the_report_they_keep_their_cases_beside():
    with pytest.raises(SystemExit, match="--workers needs --out"):
        bench.main(ARGS + ["--workers", "2"])
