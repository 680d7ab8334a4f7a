"""Each glass sphere placed up or down where its own look is symmetric: the gain, look by look (issue 9).

The outline fit leaves transparent glass where its template's match starts
it (``detect._held``: it "follows"); under lamps level with the camera on both
sides the template is centred where the glass spheres' mean look is
symmetric, and then each sphere is moved, within ``detect.OWN_SYMMETRY_SPAN``
diameters, to where its own look is most symmetric top to bottom
(``detect._y_by_own_symmetry``). For every look of a folder, ``analyze`` runs
twice, with that last move and without it (the same templates), and reports:

- ``moved``: the share of the spheres placed so (the map's ``y_by_own_symmetry``);
- ``dy_px``: the median |y error| [px] of those spheres against the truth
  (matched within 0.3 D);
- ``counts`` and ``rmsd``: the per-frame layer-count error and the c_raw RMSD
  of the map against the truth, on the window's layers;
- ``grid_counts`` and ``grid_rmsd``: the same over the inner layers of twenty
  layer grids shifted by twentieths of a layer. With four frames a single
  sphere crossing a boundary moves the window's counts by 0.7 points; the
  shifted grids average that luck out.

::

    PYTHONPATH=python python benches/bench_glass_own_symmetry.py --dir /tmp/pbr-tune --looks glass-pom glass-pp \
        --json benches/results/glass_own_symmetry_tuning.json
    PYTHONPATH=python python benches/bench_glass_own_symmetry.py --json benches/results/glass_own_symmetry_fixtures.json

(``--dir`` default: the committed fixtures; other packings of the looks come
from ``python -m granseg.synth.pbr fixtures FOLDER --seed-offset 100``.)
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

import granseg.measure.detect as detect
from granseg._io import save_json
from granseg.measure import analyze
from granseg.measure.layers import layer_counts
from granseg.synth.pbr import load_fixture

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_measure_accuracy import frame_count_error  # noqa: E402

PBR = Path(__file__).resolve().parents[1] / "tests" / "fixtures" / "pbr"
GRIDS = 20


def _analyse(folder: Path, own: bool):
    keep = detect._y_by_own_symmetry
    if not own:
        detect._y_by_own_symmetry = lambda smooth, found, templates: found
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return analyze(folder, smooth=1, save=False, progress=False, workers=2)
    finally:
        detect._y_by_own_symmetry = keep


def _grid_errors(a, truth) -> tuple[float, float]:
    """Count error and c_raw RMSD over the inner layers of GRIDS layer grids shifted through one layer."""
    x0, y0, x1, y1 = a.experiment.window
    layer = (y1 - y0) / truth.n.shape[1]
    counts, squares = [], []
    for shift in (np.arange(GRIDS) / GRIDS - 0.5) * layer:
        grid = (x0, y0 + shift, x1, y1 + shift)
        for s, rows in zip(a.spheres, truth.particles, strict=True):
            n, nh = (v[1:-1] for v in layer_counts(s.x, s.y, s.heavy, grid))
            nt, nht = (v[1:-1] for v in layer_counts(rows[:, 0], rows[:, 1], rows[:, 3] > 0, grid))
            counts.append(np.abs(n - nt)[nt > 0] / nt[nt > 0])
            both = (n > 0) & (nt > 0)
            squares.append((nh[both] / n[both] - nht[both] / nt[both]) ** 2)
    return float(np.mean(np.concatenate(counts))), float(np.sqrt(np.mean(np.concatenate(squares))))


def measure(folder: Path, own: bool) -> dict:
    truth = load_fixture(folder)
    a = _analyse(folder, own)
    d = a.experiment.particle_diameter_px
    dy = []
    for s, rows in zip(a.spheres, truth.particles, strict=True):
        dist, j = cKDTree(rows[:, :2]).query(np.column_stack([s.x, s.y]))
        mine = (dist < 0.3 * d) & s.placed["y_by_own_symmetry"]
        dy.append(np.abs(s.y[mine] - rows[j[mine], 1]))
    dy = np.concatenate(dy)
    grid_counts, grid_rmsd = _grid_errors(a, truth)
    return {"moved": round(float(a.quality.figures.get("y_by_own_symmetry", 0.0)), 3),
            "dy_px": round(float(np.median(dy)), 3) if len(dy) else None,
            "counts": round(frame_count_error(a.n, truth.n), 4),
            "rmsd": round(float(np.sqrt(np.nanmean((a.c_raw - truth.c_raw) ** 2))), 4),
            "grid_counts": round(grid_counts, 4), "grid_rmsd": round(grid_rmsd, 4)}


def _pair(without: dict, own: dict, key: str, scale: float, fmt: str) -> str:
    a, b = without[key], own[key]
    return "-" if a is None else f"{scale * a:{fmt}} -> {scale * b:{fmt}}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--dir", type=Path, default=PBR, help="folder of rendered looks (default: the fixtures)")
    ap.add_argument("--looks", nargs="+", default=["glass-pom", "glass-pp", "ceramic-glass", "steel-glass"])
    ap.add_argument("--json", type=Path, help="also write the figures here")
    args = ap.parse_args()
    results = {}
    print("look            moved | median |dy| [px] | counts [%] | c_raw RMSD | grid counts [%] | grid RMSD"
          "   (without -> with)")
    for look in args.looks:
        without, own = measure(args.dir / look, False), measure(args.dir / look, True)
        results[look] = {"without": without, "with": own}
        row = [_pair(without, own, *k) for k in (("dy_px", 1, ".2f"), ("counts", 100, ".1f"), ("rmsd", 1, ".3f"),
                                                 ("grid_counts", 100, ".2f"), ("grid_rmsd", 1, ".4f"))]
        print(f"{look:15s} {own['moved']:.2f} | " + " | ".join(row), flush=True)
    if args.json:
        save_json(args.json, {"command": "benches/bench_glass_own_symmetry.py", "dir": str(args.dir),
                              "results": results}, force=True)


if __name__ == "__main__":
    main()
