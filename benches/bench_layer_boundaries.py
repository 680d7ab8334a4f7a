"""How crowded the layer boundaries are: the renderer's packings against DEM grains (issue 9).

The per-frame layer counts of ``granseg analyze`` put each sphere in the
layer (one diameter tall) that holds its centre, as the paper does. A
sphere whose centre lies within a few hundredths of a diameter of a
boundary is counted on one side or the other by a few tenths of a pixel of
centre error. On bumpy walls many do: a sphere resting on a bump of the
plate sits one diameter above the bumps' centres. This script measures the
share of centres within ``--near`` diameters of a boundary, per boundary,

- in the 2-D renderer's packings (truth of every frame, no analysis), per
  scene group: the apparatus looks (bumpy walls), the bumps alone, flat walls;
- in a LAMMPS run of ``examples/dem/shear_cell.in`` (bumpy plate and lid
  of touching spheres, gravity, the lid loaded): the grains touching a
  side wall, heights above the plate's sphere centres and below the lid's.

A uniform spread puts 2 x near of the centres within ``near`` of a boundary.

    PYTHONPATH=python python benches/bench_layer_boundaries.py [--seeds 7 8] [--dem RUN_DIR]

where RUN_DIR holds ``grains.dump`` and ``dem.json`` from, e.g.::

    lmp -in examples/dem/shear_cell.in -screen none -var out RUN_DIR -var Lx 15 -var Ly 12 \\
        -var layers 11 -var ratio 2 -var load 150 -var U 4 -var c0 0.47 -var settle_steps 30000 \\
        -var steps 100000 -var dump_every 10000      # about a minute on one core
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

from granseg.measure.layers import height
from granseg.synth.scenes import render_scene

GROUPS = {
    "apparatus looks (bumps, blur, lens, compression)": ["apparatus-S-PP-75-jpeg", "apparatus-G-POM-50-jpeg",
                                                         "apparatus-grey-matte-glossy-jpeg",
                                                         "apparatus-S-POM-25-mp4v", "apparatus-C-PP-50-h264"],
    "bumps alone (bumps-S-PP)": ["bumps-S-PP"],
    "flat walls (S-PP-75, S-POM-25, G-POM-50)": ["S-PP-75", "S-POM-25", "G-POM-50"],
}


def _crowding(h: np.ndarray, near: float, top: int) -> tuple[float, np.ndarray]:
    """Share of heights h [D] within ``near`` of a whole number, and that share per boundary 1..top
    relative to a uniform spread (1 = as crowded as chance)."""
    b = np.round(h).astype(int)
    close = np.abs(h - b) < near
    per = np.bincount(b[close], minlength=top + 1)[1:top + 1]
    expected = len(h) / top * 2 * near
    return float(close.mean()), per / expected


def renderer(seeds: list[int], frames: int, near: float) -> None:
    print(f"2-D renderer, seeds {seeds}, {frames} frames (height above the plate's wall line, layers of the window):")
    for label, names in GROUPS.items():
        hs = []
        for name in names:
            for seed in seeds:
                with tempfile.TemporaryDirectory() as tmp:
                    r = render_scene(name, frames, seed=seed, out_dir=Path(tmp))
                    window = tuple(r.experiment["window"])
                for t in r.particles:
                    hs.append(height(t[t[:, 4] > 0, 1], window))
        share, per = _crowding(np.concatenate(hs), near, 14)
        print(f"  {label}: {share:.3f} within {near} D (uniform {2 * near:.2f}); per boundary 1..14, x chance:")
        print("    " + " ".join(f"{v:.1f}" for v in per))


def dem(run: Path, near: float) -> None:
    from granseg.dem.dump import read_dumps

    cfg = json.loads((run / "dem.json").read_text())
    wall_lo, wall_hi = cfg["side_walls"]["y"]
    above, below = [], []
    for snap in read_dumps(run / "grains.dump"):
        c = snap.columns
        plate, lid = c["z"][c["type"] == 3].mean(), c["z"][c["type"] == 4].mean()
        grain = np.isin(c["type"], [int(k) for k in cfg["types"]])
        # touching a side wall (the camera's view), within 0.05 diameters
        wall = grain & ((c["y"] - c["radius"] - wall_lo < 0.05) | (wall_hi - c["y"] - c["radius"] < 0.05))
        above.append(c["z"][wall] - plate)
        below.append(lid - c["z"][wall])
    print(f"DEM run {run} (grains touching a side wall, {len(above)} snapshots, "
          f"{np.mean([len(a) for a in above]):.0f} grains each):")
    for label, h in (("above the plate's sphere centres", above), ("below the lid's", below)):
        share, per = _crowding(np.concatenate(h), near, 12)
        print(f"  {label}: {share:.3f} within {near} D (uniform {2 * near:.2f}); per boundary 1..12, x chance:")
        print("    " + " ".join(f"{v:.1f}" for v in per))
    lowest = np.concatenate(above)
    print("  heights of the grains nearest the plate [D], histogram 0.5-1.5 in tenths:",
          np.histogram(lowest, bins=10, range=(0.5, 1.5))[0].tolist())


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=int, nargs="+", default=[7, 8])
    p.add_argument("--frames", type=int, default=6)
    p.add_argument("--near", type=float, default=0.02, help="distance to a boundary counted as on it [D]")
    p.add_argument("--dem", type=Path, help="a LAMMPS run folder (grains.dump, dem.json)")
    a = p.parse_args(argv)
    renderer(a.seeds, a.frames, a.near)
    if a.dem is not None:
        dem(a.dem, a.near)
    return 0


if __name__ == "__main__":
    sys.exit(main())
