"""Shared measuring tools of the benchmarks: medians with their spread, the memory floor, reports."""

from __future__ import annotations

import os
import platform
import sys
import time
from pathlib import Path

import numpy as np


def timings(func, repeats, warmup=1):
    """Seconds of ``repeats`` calls of ``func`` (after ``warmup`` untimed calls)."""
    for _ in range(warmup):
        func()
    out = []
    for _ in range(repeats):
        start = time.perf_counter()
        func()
        out.append(time.perf_counter() - start)
    return np.array(out)


def median_iqr(values):
    """``(median, half the interquartile range)`` of ``values``."""
    values = np.asarray(values, np.float64)
    q1, median, q3 = np.percentile(values, [25, 50, 75])
    return float(median), float((q3 - q1) / 2)


def memory_floor(data, repeats):
    """Seconds of one plain sum over the view axes of ``data (U, V, Y, X, C)``: the floor a pass costs."""
    return timings(lambda: data.sum(axis=(0, 1)), repeats)


def machine_line():
    """One line on where a benchmark ran: CPU count, Python, load average now."""
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return (f"{platform.machine()}, {os.cpu_count()} logical CPUs (shared: other jobs may run), "
            f"Python {platform.python_version()}, 1-min load average {load:.2f}")


def command_line():
    """The command that is running, as a user would type it."""
    return " ".join([".venv/bin/python"] + [arg if " " not in arg else repr(arg) for arg in sys.argv])


def detection_counts(mask, truth):
    """``(true positives, false positives, false negatives)`` of the detection ``mask`` against ``truth``."""
    return (int(np.count_nonzero(mask & truth)), int(np.count_nonzero(mask & ~truth)),
            int(np.count_nonzero(~mask & truth)))


def pooled_f1(counts):
    """F1 of detections taken together: their :func:`detection_counts` summed (every slope's pixels)."""
    tp, fp, fn = np.sum(counts, axis=0)
    return float(2 * tp / max(2 * tp + fp + fn, 1))


def table(header, rows):
    """A markdown table."""
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(str(cell) for cell in row) + " |" for row in rows]
    return "\n".join(lines)


def write_report(path, title, sections):
    """Write ``# title`` and the ``sections`` (markdown strings) to ``path``, with the command and machine."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    text = [f"# {title}", "", f"Command: `{command_line()}`", "", f"Machine: {machine_line()}", ""]
    text += [section.rstrip() + "\n" for section in sections]
    path.write_text("\n".join(text))
    return path


#: Markers of the hand-written notes of a report, kept when the report is written again.
NOTES_BEGIN, NOTES_END = "<!-- notes -->", "<!-- end of notes -->"


def kept_notes(path):
    """The hand-written notes of an earlier report at ``path`` (between the markers), or a placeholder."""
    path = Path(path)
    text = path.read_text() if path.exists() else ""
    if NOTES_BEGIN in text and NOTES_END in text:
        return NOTES_BEGIN + text.split(NOTES_BEGIN, 1)[1].split(NOTES_END, 1)[0] + NOTES_END
    return f"{NOTES_BEGIN}\n(no notes yet)\n{NOTES_END}"


#: Relative luminance error a viewer perceives (the paper's T = 0.02: "minimal intensity of perceivable aliasing").
PERCEPTIBLE = 0.02


def aliasing_truth(naive, reference, tolerance=PERCEPTIBLE):
    """Pixels where the luminance of ``naive`` differs from ``reference`` by more than ``tolerance``.

    Relative to the reference luminance, floored at 1 % of its peak (as
    Cv is). Both images are (Y, X, 3) or (Y, X, 1) linear intensity.
    """
    from napari_lfalias.lightfield import REC709

    def luminance(image):
        return image @ REC709 if image.shape[-1] == 3 else image[..., 0]

    naive, reference = luminance(naive), luminance(reference)
    floor = 0.01 * float(reference.max())
    return np.abs(naive - reference) / np.maximum(reference, floor) > tolerance
