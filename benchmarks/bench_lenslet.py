"""Lenslet calibration + decoding of the ant-leg capture, against PlenoptiCam on the same files.

The ant leg (napari-LF, BSD-3): a 2160 x 2592 uint16 PNG light-field
microscope capture and its radiometry (white) frame, rectangular grid of
about 27.5 px. Timed stages, each the median of ``--repeats`` runs:

- napari-lfalias: read both PNGs (``read_sensor``), ``calibrate`` the white
  image, ``decode_lenslet`` (devignetting + slicing to 27 x 27 views); and a
  cold start (a fresh interpreter: imports, numba cache load, one load).
  Run on the grey PNGs as they are, and on the same pixels repeated to
  three channels (what PlenoptiCam is given, see below).
- PlenoptiCam (GPL, measured in its own virtual environment, never imported
  here): its reader, ``LfpCalibrator`` (calibration), ``LfpAligner``
  (alignment) and ``LfpExtractor`` (extraction), as its command line does,
  with its default settings (7 x 7 views; 27 x 27 fails inside its
  cropper). PlenoptiCam needs colour images (grey ones stop with "Each image
  must have 3 color channels"), so the driver repeats the grey pixels to
  three channels after its own reader.

Run (from the repository root; the PlenoptiCam part needs a venv with it)::

    python3.11 -m venv /tmp/pcam-venv
    /tmp/pcam-venv/bin/pip install --only-binary=scikit-image,scipy plenopticam "numpy<2" \\
        "scikit-image<0.25" "scipy<1.12"
    .venv/bin/python benchmarks/bench_lenslet.py --pcam-python /tmp/pcam-venv/bin/python

Without ``--pcam-python`` only napari-lfalias is timed. Results go to
``benchmarks/results/lenslet.md``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results" / "lenslet.md"
ANTLEG = ROOT.parent / "shared" / "lf_data" / "napari_lf_antleg"
RAW, WHITE = ANTLEG / "light_field.png", ANTLEG / "radiometry_frame.png"

#: Runs inside PlenoptiCam's own venv: its reader, calibrator, aligner, extractor; prints JSON timings.
PCAM_DRIVER = textwrap.dedent('''
    import json, os, sys, time
    import numpy as np
    from plenopticam.cfg import PlenopticamConfig
    from plenopticam import misc, lfp_reader, lfp_calibrator, lfp_aligner, lfp_extractor
    import plenopticam

    raw, white, repeats = sys.argv[1], sys.argv[2], int(sys.argv[3])
    runs = []
    for _ in range(repeats):
        cfg = PlenopticamConfig()
        cfg.default_values()
        cfg.params[cfg.lfp_path] = os.path.abspath(raw)
        cfg.params[cfg.cal_path] = os.path.abspath(white)
        cfg.params[cfg.opt_cali] = True
        cfg.params[cfg.opt_prnt] = False
        cfg.params[cfg.opt_refo] = False
        sta = misc.PlenopticamStatus()
        t = {}
        s = time.perf_counter()
        reader = lfp_reader.LfpReader(cfg, sta)
        reader.main()
        lfp_img = reader.lfp_img
        misc.mkdir_p(cfg.exp_path, False)
        wht_img = misc.load_img_file(cfg.params[cfg.cal_path])
        t["read"] = time.perf_counter() - s
        # PlenoptiCam needs three channels: repeat the grey pixels
        lfp_img = np.dstack([lfp_img] * 3) if lfp_img.ndim == 2 else lfp_img
        wht_img = np.dstack([wht_img] * 3) if wht_img.ndim == 2 else wht_img
        s = time.perf_counter()
        calibrator = lfp_calibrator.LfpCalibrator(wht_img, cfg, sta)
        calibrator.main()
        cfg = calibrator.cfg
        cfg.load_cal_data()
        t["calibration"] = time.perf_counter() - s
        s = time.perf_counter()
        aligner = lfp_aligner.LfpAligner(lfp_img, cfg, sta, wht_img)
        aligner.main()
        aligned = aligner.lfp_img
        t["alignment"] = time.perf_counter() - s
        s = time.perf_counter()
        lfp_calibrator.CaliFinder(cfg).main()
        extractor = lfp_extractor.LfpExtractor(aligned, cfg=cfg, sta=sta)
        extractor.main()
        t["extraction"] = time.perf_counter() - s
        t["views"] = list(np.asarray(extractor.vp_img_linear).shape)
        runs.append(t)
    print(json.dumps({"version": plenopticam.__version__, "numpy": np.__version__, "runs": runs}))
''')

COLD = textwrap.dedent('''
    import sys, time
    start = time.perf_counter()
    from napari_lfalias.decoders import load_lenslet
    lf = load_lenslet(sys.argv[1], white=sys.argv[2])
    print(time.perf_counter() - start)
''')


def _median(run, repeats):
    times = []
    result = None
    for _ in range(repeats):
        start = time.perf_counter()
        result = run()
        times.append(time.perf_counter() - start)
    return statistics.median(times), result


def time_ours(repeats, colour=False):
    """Medians (s) of read, calibrate, decode and their sum; and facts about the result."""
    from napari_lfalias.decoders import calibrate, decode_lenslet
    from napari_lfalias.decoders.sensor import SensorImage, read_sensor

    def read():
        raw, white = read_sensor(RAW), read_sensor(WHITE)
        if colour:
            raw = SensorImage(np.repeat(raw.data[..., None], 3, axis=2), None, raw.path, raw.format)
            white = SensorImage(np.repeat(white.data[..., None], 3, axis=2), None, white.path, white.format)
        return raw, white

    raw, white = read()
    grid = calibrate(white)
    decode_lenslet(raw, white, grid=grid)  # warm: numba cache loaded
    t_read, (raw, white) = _median(read, repeats)
    t_cal, grid = _median(lambda: calibrate(white), repeats)
    t_dec, lf = _median(lambda: decode_lenslet(raw, white, grid=grid), repeats)
    facts = {"pitch": grid.pitch, "rotation": grid.rotation, "shape": lf.shape,
             "distortion": bool(grid.distortion), "rms": grid.fit.get("rms_residual_px")}
    return {"read": t_read, "calibration": t_cal, "decode": t_dec}, facts


def time_cold(repeats):
    times = []
    for _ in range(repeats):
        done = subprocess.run([sys.executable, "-c", COLD, str(RAW), str(WHITE)], capture_output=True, text=True,
                              check=True, cwd=ROOT)
        times.append(float(done.stdout.strip().splitlines()[-1]))
    return statistics.median(times)


def time_plenopticam(python, repeats):
    """PlenoptiCam's medians per stage, run in its own interpreter on copies of the files."""
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        for source in (RAW, WHITE):
            (folder / source.name).write_bytes(source.read_bytes())
        driver = folder / "pcam_driver.py"
        driver.write_text(PCAM_DRIVER)
        done = subprocess.run([python, str(driver), str(folder / RAW.name), str(folder / WHITE.name), str(repeats)],
                              capture_output=True, text=True, cwd=folder, timeout=3600)
        if done.returncode != 0:
            return {"error": done.stderr.strip().splitlines()[-1] if done.stderr.strip() else "failed"}
        report = json.loads(done.stdout.strip().splitlines()[-1])
    runs = report["runs"]
    medians = {key: statistics.median(run[key] for run in runs) for key in ("read", "calibration", "alignment",
                                                                            "extraction")}
    return {"medians": medians, "views": runs[0]["views"], "version": report["version"], "numpy": report["numpy"],
            "repeats": len(runs)}


def _row(name, values):
    return f"| {name} | " + " | ".join(values) + " |"


def write_results(ours, ours_rgb, facts, cold, pcam, repeats, pcam_repeats, command):
    lines = [
        "# Lenslet calibration + decoding: napari-lfalias vs PlenoptiCam (ant leg)",
        "",
        f"Command: `{command}`",
        "",
        f"Machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores (shared with other jobs), "
        f"Python {platform.python_version()}. Input: `{RAW.name}` + `{WHITE.name}` (2160 x 2592 uint16 PNG, "
        "napari-LF ant leg). Seconds, median of the repeats.",
        "",
        f"napari-lfalias grid: rectangular, pitch {facts['pitch']:.3f} px, rotation {facts['rotation']:+.3f} deg, "
        f"cubic distortion fitted: {facts['distortion']}; light field {tuple(facts['shape'])} "
        f"(U, V, Y, X, C) with per-sample weights.",
        "",
        "## napari-lfalias",
        "",
        f"{repeats} repeats (warm: numba kernels already loaded); cold = a fresh interpreter doing imports, numba "
        "cache load and one `load_lenslet` from the files.",
        "",
        "| input | read PNGs | calibrate | decode | calibrate + decode | all from files |",
        "|---|---|---|---|---|---|",
    ]
    for name, t in (("grey (as stored)", ours), ("grey repeated to 3 channels", ours_rgb)):
        lines.append(_row(name, [f"{t['read']:.3f}", f"{t['calibration']:.3f}", f"{t['decode']:.3f}",
                                 f"{t['calibration'] + t['decode']:.3f}",
                                 f"{t['read'] + t['calibration'] + t['decode']:.3f}"]))
    lines += ["", f"Cold start, grey, one `load_lenslet` in a new interpreter: **{cold:.2f} s**.", ""]
    lines += ["## PlenoptiCam", ""]
    if pcam is None:
        lines += ["Not run (no `--pcam-python` given).", ""]
    elif "error" in pcam:
        lines += [f"PlenoptiCam could not be run: `{pcam['error']}`", ""]
    else:
        m = pcam["medians"]
        work = m["calibration"] + m["alignment"] + m["extraction"]
        ours_work = ours_rgb["calibration"] + ours_rgb["decode"]
        lines += [
            f"PlenoptiCam {pcam['version']} (numpy {pcam['numpy']}), in its own venv, {pcam['repeats']} repeats, "
            f"default settings: views {tuple(pcam['views'])} (it fails with 27 x 27 views in its cropper). "
            "Grey pixels repeated to 3 channels (it refuses grey images). Its extraction includes writing its "
            "view images to disk, as its pipeline does. Installing it: pip resolves plenopticam 0.8.2 under "
            "`numpy<2` with binary wheels only (0.9.3 pins `pyinstaller==4.10` and `tifffile==2022.4.8`), and "
            "`scipy<1.12` is needed because its dependency depthy imports `scipy.misc.face`; no source patch.",
            "",
            "| read | calibration | alignment | extraction | calibration + alignment + extraction |",
            "|---|---|---|---|---|",
            "| " + " | ".join([f"{m['read']:.2f}", f"{m['calibration']:.2f}", f"{m['alignment']:.2f}",
                               f"{m['extraction']:.2f}", f"{work:.2f}"]) + " |",
            "",
            "## Ratio",
            "",
            f"PlenoptiCam calibration + alignment + extraction / napari-lfalias calibrate + decode, same 3-channel "
            f"input: **{work / ours_work:.0f}x** ({work:.2f} s vs {ours_work:.3f} s; napari-lfalias also decodes "
            f"27 x 27 views where PlenoptiCam decodes {pcam['views'][0]} x {pcam['views'][1]}). "
            f"On the grey input as stored: {work / (ours['calibration'] + ours['decode']):.0f}x. "
            f"Including reading the files and a cold start of napari-lfalias: "
            f"{(work + m['read']) / cold:.0f}x. Goal: >= 5x.",
            "",
        ]
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text("\n".join(lines) + "\n")
    return RESULTS


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--pcam-python", help="python of a venv with plenopticam installed")
    parser.add_argument("--pcam-repeats", type=int, default=3)
    args = parser.parse_args(argv)
    ours, facts = time_ours(args.repeats)
    ours_rgb, _ = time_ours(args.repeats, colour=True)
    cold = time_cold(3)
    print("napari-lfalias grey:", ours, "\n3 channels:", ours_rgb, "\ncold:", cold, flush=True)
    pcam = time_plenopticam(args.pcam_python, args.pcam_repeats) if args.pcam_python else None
    print("PlenoptiCam:", pcam)
    command = ".venv/bin/python benchmarks/bench_lenslet.py" + (
        f" --pcam-python {args.pcam_python}" if args.pcam_python else "") + (
        f" --repeats {args.repeats}" if args.repeats != 5 else "") + (
        f" --pcam-repeats {args.pcam_repeats}" if args.pcam_repeats != 3 else "")
    print(write_results(ours, ours_rgb, facts, cold, pcam, args.repeats, args.pcam_repeats, command))


if __name__ == "__main__":
    main()
