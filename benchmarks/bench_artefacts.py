"""Real-camera artefacts in folders of views: what the weights of ``lfa.load(folder)`` change.

Sections:

``speed``
    Loading HCI antinous (81 PNG views, 512x512 RGB, no artefacts: it comes
    back unchanged) with the code before this change (``--base-ref``, unpacked
    from git), and with this code without (``artefacts=False``) and with
    the artefacts examined (the default): wall and CPU seconds, each kind in
    its own interpreter, taking turns.
``margins``
    The lowest fall-off the estimate finds (and its upper bound, the one
    the decision reads) on light fields without vignetting: HCI antinous
    and synthetic scenes with strong parallax; a light field counts as
    vignetted only below ``DETECTED``.
``cases``
    Folders of 9x9 views of 256 x 256, written as 8-bit PNG as another tool
    would export them, loaded with and without the weights, against the
    views of an ideal camera:

    - *camera vignetting*: :func:`napari_lfalias.synthetic.camera.capture`
      with ``vignetting=1.5`` (corner views at 16-39 % of the centre's light;
      the ideal camera vignettes every view as the centre view, which no
      folder can tell from the scene);
    - *lenslet export*: the views of a plenoptic camera decoded elsewhere:
      outer views cut by the main-lens aperture (a cat's-eye fall-off to
      exactly black towards their outer corners), inner views untouched;
    - *saturated sky*: camera vignetting with ``exposure=3`` (the bright
      background clips in the inner views: the ideal camera clips it in
      every view); also with the clipping level ignored (an ablation);
    - *black borders*: rectified views with black bands of 1-18 px on
      every side, no vignetting.

    Per case and slope: the refocus's mean relative luminance error in the
    corners (outer quarter squares) and in the region (where some view keeps
    2-50 % of the light, the clipped sky, the borders), both where some view
    has data once shifted (elsewhere the refocus of a bordered folder is 0),
    and the share of pixels flagged there by the exact Cv at T = 0.02
    (``method="analytic"``) and by the default detector (``"depth"``), with
    the share of all flagged pixels that lie in the region.

Run (from the repository root)::

    .venv/bin/python benchmarks/bench_artefacts.py

Results go to ``benchmarks/results/artefacts.md`` and ``artefacts.png``.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from _harness import table, write_report

import napari_lfalias as lfa
from napari_lfalias.decoders import artefacts
from napari_lfalias.lightfield import REC709
from napari_lfalias.synthetic import brick_room, layered_scene
from napari_lfalias.synthetic.camera import capture, vignetting_falloff

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results"
HCI = Path(__file__).resolve().parents[2] / "shared" / "lf_data" / "hci_antinous"
N_VIEWS, SIZE = 9, 256
CENTRE = N_VIEWS // 2


# -- folders as users get them -----------------------------------------------------

def write_folder(folder, data):
    """Every view as an 8-bit PNG ``view_U_V.png``."""
    folder.mkdir(parents=True)
    for u, v in np.ndindex(data.shape[:2]):
        image = np.round(np.clip(data[u, v], 0, 1) * 255).astype(np.uint8)
        cv2.imwrite(str(folder / f"view_{u}_{v}.png"), image[..., ::-1])
    return folder


def quantised(data):
    return np.round(np.clip(data, 0, 1) * 255).astype(np.float32) / np.float32(255)


def cats_eye(positions, shape, radius=1.35, shift=0.4, edge=0.25):
    """A lenslet camera's outer views: the main-lens aperture seen off-axis, black beyond (``(U, V, Y, X)``)."""
    q = np.asarray(positions, np.float64) / np.abs(positions).max()
    height, width = shape
    y = (np.arange(height) - (height - 1) / 2) / (height / 2)
    x = (np.arange(width) - (width - 1) / 2) / (width / 2)
    py, px = np.meshgrid(y, x, indexing="ij")
    distance = np.hypot(q[..., 0, None, None] + shift * py, q[..., 1, None, None] + shift * px)
    t = np.clip((radius - distance) / edge, 0, 1)
    return (t * t * (3 - 2 * t)).astype(np.float32)


def _layered(seed=1):
    return layered_scene([(2.5, "checker", (0.25, 0.6, 0.2, 0.55)), (-1.0, "noise", None)],
                         n_views=N_VIEWS, size=SIZE, seed=seed)


def _corners(shape):
    mask = np.zeros(shape, bool)
    m = shape[0] // 4
    mask[:m, :m] = mask[:m, -m:] = mask[-m:, :m] = mask[-m:, -m:] = True
    return mask


def make_cases():
    """``name -> (recorded views, ideal camera's views, positions, region, region name, slopes)``."""
    cases = {}
    for label, scene, slopes in (("brick room", brick_room(n_views=N_VIEWS, size=SIZE, seed=0), (-4.0, 4.0)),
                                 ("layered", _layered(), (-1.0, 2.5))):
        ideal = scene.lightfield
        fall = vignetting_falloff(ideal.positions, ideal.image_shape, 1.5)
        relative = fall / fall.max(axis=(0, 1))
        recorded = capture(ideal, vignetting=1.5).data
        common = ideal.data * fall[CENTRE, CENTRE][..., None]
        region = (relative < 0.5).any(axis=(0, 1))
        cases[f"camera vignetting, {label}"] = (recorded, common, ideal.positions, region, "vignetted", slopes)
        eye = cats_eye(ideal.positions, ideal.image_shape)
        ring = ((eye > 0.02) & (eye < 0.5)).any(axis=(0, 1))
        cases[f"lenslet export, {label}"] = (ideal.data * eye[..., None], ideal.data, ideal.positions, ring,
                                             "vignetted ring", slopes)
    sky_scene = layered_scene([(2.5, "checker", (0.3, 0.7, 0.25, 0.6)), (-0.5, "smooth", None)],
                              n_views=N_VIEWS, size=SIZE, seed=3)
    ideal = sky_scene.lightfield
    fall = vignetting_falloff(ideal.positions, ideal.image_shape, 1.5)
    recorded = capture(ideal, vignetting=1.5, exposure=3.0).data
    sky = (recorded[CENTRE, CENTRE] >= 1).any(axis=-1)
    cases["saturated sky"] = (recorded, np.clip(ideal.data * fall[CENTRE, CENTRE][..., None] * 3.0, 0, 1),
                              ideal.positions, sky, "clipped sky", (-0.5, 2.5))
    ideal = _layered(seed=2).lightfield
    clean = 0.05 + 0.9 * ideal.data
    bands = np.zeros(ideal.shape[:4], bool)
    for u, v in np.ndindex(bands.shape[:2]):
        bands[u, v, :1 + 2 * u], bands[u, v, :, :1 + 2 * v] = True, True
        bands[u, v, SIZE - 1 - 2 * (N_VIEWS - 1 - u):], bands[u, v, :, SIZE - 1 - 2 * (N_VIEWS - 1 - v):] = True, True
    bordered = np.where(bands[..., None], np.float32(0), clean)
    seen = ~bands.all(axis=(0, 1))
    cases["black borders"] = (bordered, clean, ideal.positions, bands.any(axis=(0, 1)) & seen, "borders", (-1.0, 2.5))
    return cases


# -- measuring -------------------------------------------------------------------------

@contextlib.contextmanager
def clipping_ignored():
    """The ablation: the loader does not look for clipped light."""
    original = artefacts.clip_level
    artefacts.clip_level = lambda views, summaries: None
    try:
        yield
    finally:
        artefacts.clip_level = original


def luminance(image):
    return image @ REC709


def measure(light_fields, target, region, slopes):
    """Rows of the case's table, and the images of its first slope."""
    rows, images = [], {}
    weights = light_fields["weights (default)"].weights
    for slope in slopes:
        reference = luminance(lfa.refocus(target, slope))
        floor = 0.01 * float(reference.max())
        seen = np.ones(reference.shape, bool)  # where some view has data once shifted (else the refocus is 0)
        if weights is not None:
            seen = lfa.refocus(lfa.LightField(np.ones(weights.shape, np.float32), target.positions, weights=weights),
                               slope)[..., 0] > 0
        corners = _corners(reference.shape) & seen
        for name, lf in light_fields.items():
            refocused = lfa.refocus(lf, slope)
            error = luminance(refocused) / np.maximum(reference, floor) - 1
            analytic = lfa.detect_aliasing(lf, slope, method="analytic").mask
            depth = lfa.detect_aliasing(lf, slope).mask
            cells = [f"{slope:+.1f}", name, f"{error[corners].mean():+.3f}", f"{error[region & seen].mean():+.3f}"]
            for mask in (analytic, depth):
                inside = mask[region].sum() / max(mask.sum(), 1)
                cells += [f"{mask[region].mean():.3f}", f"{mask.mean():.3f}", f"{inside:.0%}" if mask.any() else "-"]
            rows.append(cells)
            if slope == slopes[0]:
                images[name] = (refocused, analytic)
    return rows, images


_TIMED_LOADS = """
import json, sys, time
import napari_lfalias as lfa
folder, repeats, options = sys.argv[1], int(sys.argv[2]), json.loads(sys.argv[3])
lfa.load(folder, **options)
wall, cpu = [], []
for _ in range(repeats):
    start, start_cpu = time.perf_counter(), time.process_time()
    lfa.load(folder, **options)
    wall.append(time.perf_counter() - start)
    cpu.append(time.process_time() - start_cpu)
print(json.dumps([wall, cpu]))
"""


def _timed_loads(source, repeats, options):
    """``(wall, cpu)`` seconds of ``repeats`` loads of HCI antinous in a fresh interpreter importing ``source``."""
    env = dict(os.environ, PYTHONPATH=str(source))
    out = subprocess.run([sys.executable, "-c", _TIMED_LOADS, str(HCI), str(repeats), json.dumps(options)],
                         env=env, capture_output=True, text=True, check=True).stdout
    return json.loads(out.splitlines()[-1])


def _source_of(ref, folder):
    """The package's ``src`` at git ``ref``, unpacked into ``folder``."""
    archive = subprocess.run(["git", "-C", str(REPO), "archive", ref, "src"], capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(folder)], input=archive, check=True)
    return folder / "src"


def speed_section(repeats, base_ref, blocks=3):
    """Loads of the code before this change (``base_ref``), and of this code without and with the artefacts.

    Each kind runs in its own fresh interpreter, ``repeats`` loads a block,
    the kinds taking turns for ``blocks`` blocks (the machine is shared).
    """
    commit = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", base_ref], capture_output=True,
                            text=True, check=True).stdout.strip()
    with tempfile.TemporaryDirectory() as tmp:
        kinds = {f"before this change ({base_ref} = {commit})": (_source_of(base_ref, Path(tmp)), {}),
                 "this change, artefacts=False": (REPO / "src", {"artefacts": False}),
                 "this change, default (examined)": (REPO / "src", {})}
        times = {name: ([], []) for name in kinds}
        for _ in range(blocks):
            for name, (source, options) in kinds.items():
                wall, cpu = _timed_loads(source, repeats, options)
                times[name][0].extend(wall)
                times[name][1].extend(cpu)
    base_wall, base_cpu = (float(np.median(t)) for t in next(iter(times.values())))
    rows = [[name, f"{np.median(wall):.3f}", f"{np.median(wall) / base_wall:.2f}x", f"{np.median(cpu):.3f}",
             f"{np.median(cpu) / base_cpu:.2f}x"] for name, (wall, cpu) in times.items()]
    views = lfa.load(HCI, artefacts=False)
    flat = views.data.reshape((-1,) + views.data.shape[2:])
    summarise, estimate = [], []
    for _ in range(repeats):
        start = time.process_time()
        summaries = [artefacts.summarise_view(view) for view in flat]
        summarise.append(time.process_time() - start)
        data = views.data.copy()
        start = time.process_time()
        artefacts.correct_artefacts(data, summaries)
        estimate.append(time.process_time() - start)
    return "\n".join([
        "## Loading speed: HCI antinous (81 views, 512x512 RGB PNG; nothing found, unchanged)", "",
        f"Medians of {blocks} x {repeats} loads per kind, each kind in its own interpreter, taking turns; "
        f"1-min load average {os.getloadavg()[0]:.1f} at the end (the machine is shared: the CPU column is "
        "steadier).", "",
        table(["load", "wall s", "vs before", "CPU s (all threads)", "vs before"], rows), "",
        "This change also decodes faster (the BGR to RGB swap by OpenCV, contiguous; the conversion to "
        "float32 straight into the light field), which pays for the artefact summaries. Of the examined load: "
        f"summarising the 81 float32 views {np.median(summarise) * 1e3:.0f} ms of CPU (in the reader "
        "threads; the loader finds the largest value on the 8-bit pixels, faster than here), the estimate "
        f"afterwards {np.median(estimate) * 1e3:.0f} ms.", ""])


def margins_section():
    scenes = {"HCI antinous 9x9x512": lfa.load(HCI, artefacts=False),
              "brick room 9x9x256 (disparity -4 and +4)": brick_room(n_views=9, size=256, seed=0).lightfield,
              "layered: flat occluder +4, bricks +1, tiles -2 (9x9x256)": layered_scene(
                  [(4.0, "flat", (0.1, 0.5, 0.1, 0.9)), (1.0, "bricks", (0.5, 0.9, 0.3, 0.7)), (-2.0, "tiles", None)],
                  n_views=9, size=256).lightfield,
              "layered: grey +2, stripes -1 (9x9x256)": layered_scene(
                  [(2.0, "grey", (0.2, 0.6, 0.5, 0.9)), (-1.0, "stripes", None)], n_views=9, size=256).lightfield}
    rows = []
    for name, lf in scenes.items():
        summaries = [artefacts.summarise_view(view) for view in lf.data.reshape((-1,) + lf.data.shape[2:])]
        small = np.stack([s.small for s in summaries])
        falloff, upper = artefacts.relative_falloff(small, np.ones_like(small))
        rows.append([name, f"{np.nanmin(falloff):.3f}", f"{np.nanmin(upper):.3f}"])
    return "\n".join([
        "## Decision margins: light fields without vignetting", "",
        f"A light field counts as vignetted where a view's upper bound drops below DETECTED = {artefacts.DETECTED}.",
        "", table(["light field", "lowest fall-off", "lowest upper bound"], rows), ""])


def save_strip(path, strips):
    tiles = []
    for refocused_by_name in strips:
        row = []
        for refocused, mask in refocused_by_name:
            image = np.clip(refocused, 0, 1)
            flagged = image.copy()
            flagged[mask] = 0.4 * flagged[mask] + 0.6 * np.array([1, 0, 1], np.float32)
            row += [image, flagged]
        tiles.append(np.concatenate(row, axis=1))
    strip = np.concatenate(tiles, axis=0)
    cv2.imwrite(str(path), np.round(strip[..., ::-1] * 255).astype(np.uint8))


def cases_section(folder_root):
    header = ["slope", "views", "corner err", "region err", "analytic: region", "all", "in region",
              "depth: region", "all", "in region"]
    text, strips = [], []
    for name, (recorded, ideal_views, positions, region, region_name, slopes) in make_cases().items():
        folder = write_folder(folder_root / name.replace(",", "").replace(" ", "_"), recorded)
        target = lfa.LightField(quantised(ideal_views), positions)
        light_fields = {"ideal camera": target, "files (artefacts=False)": lfa.load(folder, artefacts=False),
                        "weights (default)": lfa.load(folder)}
        found = light_fields["weights (default)"].meta.get("artefacts", {})
        if name == "saturated sky":
            with clipping_ignored():
                light_fields["weights, clipping ignored"] = lfa.load(folder)
        rows, images = measure(light_fields, target, region, slopes)
        strips.append([images[key] for key in ("ideal camera", "files (artefacts=False)", "weights (default)")])
        summary = ", ".join(f"{key} {len(value) if isinstance(value, list) else value}" for key, value in found.items())
        text += [f"### {name}", "", f"Region: {region_name} ({region.mean():.0%} of the image). Found: {summary}.", "",
                 table(header, rows), ""]
    save_strip(RESULTS / "artefacts.png", strips)
    return "\n".join(["## Cases (9x9 views of 256x256, 8-bit PNG folders)", "",
                      "err: mean relative luminance error of the refocus against the ideal camera's; flagged: share "
                      "of the pixels (region, all) and share of all flagged pixels that lie in the region.", "",
                      "![ideal | files | weights, each refocus and its exact-Cv mask, one row per case "
                      "(first slope)](artefacts.png)", ""] + text)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7, help="loads per block (speed)")
    parser.add_argument("--base-ref", default="main", help="git ref of the code before this change (speed)")
    parser.add_argument("--only", nargs="*", choices=("speed", "margins", "cases"))
    args = parser.parse_args()
    chosen = set(args.only or ("speed", "margins", "cases"))
    sections = []
    if "speed" in chosen:
        sections.append(speed_section(args.repeats, args.base_ref))
    if "margins" in chosen:
        sections.append(margins_section())
    if "cases" in chosen:
        with tempfile.TemporaryDirectory() as tmp:
            sections.append(cases_section(Path(tmp)))
    write_report(RESULTS / "artefacts.md", "Real-camera artefacts in folders of views", sections)


if __name__ == "__main__":
    main()
