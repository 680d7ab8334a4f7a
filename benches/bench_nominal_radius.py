"""Spheres placed with the nominal radius instead of a fitted one: tried against the outward bias, dropped.

On the physically based looks the outline fit finds matte spheres 3-6 %
too small (their limbs away from the side panels fade into the gaps) and
follows the lit limb, outward of the truth near the window's sides
(BENCHMARKS.md). This bench re-places every sphere the detector found with
a circle of the nominal radius (``particle_diameter_px / 2``) fitted to its
outline, starting from the detector's centre, with the learned outline bias
taken off, and compares it with the detector as it is:

- ``--pbr DIR --looks ...``: physically based looks (the tuning packings,
  ``python -m granseg.synth.pbr fixtures DIR --seed-offset 100 --no-verify``):
  spheres missed, per-frame layer counts, mean outward error near the
  window's sides (x) and its top and bottom (y), the 95th percentile of the
  centre error, and the spread (MAD) of the distances of touching pairs,
  lying (h) and standing (v), as a figure that needs no truth. The centres
  are the frame worker's, before the classes' shift is taken off.
- ``--scenes ... --seeds ...``: 2-D renderer scenes through the whole
  ``analyze``, scored as ``bench_measure_accuracy.py`` scores them.

    PYTHONPATH=python python benches/bench_nominal_radius.py --pbr /tmp/pbr-tune \\
        --looks pom-pp ceramic-pom ceramic-pp steel-pom \\
        --scenes apparatus-S-POM-25-mp4v apparatus-C-PP-50-h264 POM-PP-50 S-POM-25 --seeds 7 8 \\
        --json benches/results/nominal_radius_tuning.json
"""

from __future__ import annotations

import argparse
import contextlib
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

import granseg.measure.detect as detect
from granseg._io import save_json
from granseg.errors import QualityWarning
from granseg.measure import analyze
from granseg.measure.layers import layer_counts
from granseg.measure.outline import fit_outlines
from granseg.synth.scenes import render_scene

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_measure_accuracy import score  # noqa: E402
from bench_pbr_centre_bias import _outward, detections, touching_pairs  # noqa: E402


@contextlib.contextmanager
def placement(mode: str):
    """The detector as it is ("fitted") or with every found sphere re-placed at the nominal radius ("nominal")."""
    examine = detect._examine
    if mode == "nominal":
        def nominal(smooth, image, templates, smeared_below=None):
            found, rim, judged = examine(smooth, image, templates, smeared_below)
            sign = templates.signs[found[:, 4].astype(int)]
            for s in np.unique(sign):
                mine = sign == s
                bias = None if templates.ray_bias is None else templates.ray_bias[found[mine, 4].astype(int)]
                found[mine, :2] = fit_outlines(smooth[int(s)], found[mine, :2], np.full(mine.sum(), templates.d / 2),
                                               templates.d, ray_bias=bias, free_radius=False).centres
            return found, rim, judged
        detect._examine = nominal
    try:
        yield
    finally:
        detect._examine = examine


def _mad(a: np.ndarray) -> float:
    return float(np.median(np.abs(a - np.median(a))))


def pbr_figures(folder: Path) -> dict:
    """Misses, counts, outward errors, p95 and touching-pair spreads of one physically based look."""
    truth, exp, found = detections(folder)
    d = exp.particle_diameter_px
    rows, counts, missed, lying, standing = [], [], 0, [], []
    for tp, s in zip(truth.particles, found, strict=True):
        pts = np.column_stack([s.x, s.y])
        dist, j = cKDTree(tp[:, :2]).query(pts)
        m = dist < 0.3 * d
        rows.append(np.column_stack([tp[j[m], :2], pts[m] - tp[j[m], :2]]))
        counts.append(layer_counts(s.x, s.y, np.zeros(len(s.x), bool), exp.window)[0])
        back, _ = cKDTree(pts).query(tp[tp[:, 4] > 0, :2])
        missed += int((back > 0.3 * d).sum())
        a, b, length = touching_pairs(pts, d)
        flat = np.abs(b[:, 0] - a[:, 0]) / np.maximum(length, 1e-9)
        lying.append(length[flat > 0.9] / d)
        standing.append(length[flat < 0.6] / d)
    rows = np.concatenate(rows)
    n = truth.n
    outward = _outward(rows, exp.window)
    return {"missed": missed,
            "frame_layer_count_error": round(float(np.mean(np.abs(np.array(counts) - n)[n > 0] / n[n > 0])), 4),
            "x_outward_sides_px": outward["x_sides"], "y_outward_top_bottom_px": outward["y_top_bottom"],
            "p95_px": round(float(np.percentile(np.hypot(rows[:, 2], rows[:, 3]), 95)), 2),
            "pair_spread_lying_d": round(_mad(np.concatenate(lying)), 4),
            "pair_spread_standing_d": round(_mad(np.concatenate(standing)), 4)}


def scene_figures(scene: str, seed: int, frames: int) -> dict:
    """bench_measure_accuracy's figures of one 2-D scene and seed."""
    with tempfile.TemporaryDirectory() as tmp:
        r = render_scene(scene, frames, seed=seed, out_dir=Path(tmp))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", QualityWarning)  # scored below
            a = analyze(r.source, smooth=1, save=False, progress=False, workers=2)
    s = score(r, a)
    keep = ("rmsd", "frame_layer_count_error", "heavy_bias_px", "light_bias_px", "heavy_p95_px", "light_p95_px",
            "failed_checks")
    return {k: (round(v, 4) if isinstance(v, float) else v) for k, v in s.items() if k in keep}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pbr", type=Path, default=None, help="folder of physically based looks")
    ap.add_argument("--looks", nargs="+", default=[])
    ap.add_argument("--scenes", nargs="+", default=[])
    ap.add_argument("--seeds", type=int, nargs="+", default=[7, 8])
    ap.add_argument("--frames", type=int, default=6)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    results = {}
    jobs = [(look, None) for look in (args.looks if args.pbr else [])]
    jobs += [(scene, seed) for scene in args.scenes for seed in args.seeds]
    for i, (name, seed) in enumerate(jobs, 1):
        for mode in ("fitted", "nominal"):
            with placement(mode):
                fig = pbr_figures(args.pbr / name) if seed is None else scene_figures(name, seed, args.frames)
            key = name if seed is None else f"{name} seed {seed}"
            results.setdefault(key, {})[mode] = fig
            print(f"[{i}/{len(jobs)}] {key:32s} {mode:8s} {fig}", flush=True)
    if args.json is not None:
        save_json(args.json, {"command": " ".join(sys.argv), "results": results}, force=True)


if __name__ == "__main__":
    main()
