"""How far apart touching spheres are seen at a wall, in every world with a truth (issue 9).

The quality check ``sphere_spacing`` (``granseg.measure.quality.SPACING_SLACK``)
reads the median distance from each sphere found to the nearest other one, in
diameters of the ``particle_diameter_px`` given: spheres at a wall touch their
neighbours, so with the diameter right it lies near 1. This script gives the
same figure (``layers.nearest_spacing``, median per frame, then over frames)
for the true centres, no detector involved, and for the 2-D scenes and the
fixtures the figure of the check ``spacing_across_view`` (``LENS_SLACK``):
how far apart the third of the true centres farthest above or below the
lens's axis lie against the nearest third, which a lens taken off leaves at
the packing's own value:

- the 2-D renderer's scenes (``--scenes``, ``--seeds``): the spheres in the
  window, their neighbours within a diameter of it counted as neighbours;
- the physically based fixtures (``tests/fixtures/pbr``), the same way;
- the real photographs' checked centres of the 6 mm beads
  (``tests/fixtures/real-beads``; the 4 mm beads left out, as the detector
  is asked to);
- with ``--dem RUN_DIR`` (``grains.dump`` and ``dem.json`` of a LAMMPS run of
  ``examples/dem/shear_cell.in``; bench_layer_boundaries.py says how to make
  one): the grains touching a side wall, seen along the wall (flow axis and
  height; the box is periodic along the flow), in their mean diameter.

    PYTHONPATH=python python benches/bench_spacing.py [--scenes S-POM-25 ...] [--seeds 7 8] [--dem RUN_DIR]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

from granseg.measure.layers import nearest_spacing
from granseg.measure.quality import spacing_across_view
from granseg.synth import scene_names
from granseg.synth.pbr import load_fixture
from granseg.synth.scenes import render_scene

FIXTURES = Path(__file__).resolve().parents[1] / "tests" / "fixtures"


def _of_frames(particles: list[np.ndarray], d: float) -> float:
    """The spacing [d] of truth frames (m, 5: x, y, diameter, heavy, in_window): the median over
    frames of the median distance from a sphere in the window to its nearest neighbour."""
    return float(np.median([nearest_spacing(p[p[:, 4] > 0, :2], p[p[:, 4] == 0, :2]) for p in particles]) / d)


def _across_view(particles: list[np.ndarray], experiment: dict) -> float:
    """The spacing of the truth frames' far third over their near third, by height from the
    principal point (quality.spacing_across_view)."""
    frames = [(p[p[:, 4] > 0, :2], p[p[:, 4] == 0, :2]) for p in particles]
    return spacing_across_view(frames, float(np.asarray(experiment["camera_matrix"])[1, 2]))


def renderer(scenes: list[str], seeds: list[int], frames: int) -> None:
    for scene in scenes:
        values, across = [], []
        for seed in seeds:
            with tempfile.TemporaryDirectory() as tmp:
                r = render_scene(scene, frames, seed=seed, out_dir=Path(tmp))
            values.append(_of_frames(r.particles, r.experiment["particle_diameter_px"]))
            across.append(_across_view(r.particles, r.experiment))
        print(f"2-D renderer {scene:34s} seeds {seeds}: " + " ".join(f"{v:.3f}" for v in values)
              + "; far over near the axis " + " ".join(f"{v:.3f}" for v in across))


def fixtures() -> None:
    for look in sorted(p.name for p in (FIXTURES / "pbr").iterdir() if (p / "truth.npz").is_file()):
        truth = load_fixture(FIXTURES / "pbr" / look)
        print(f"physically based fixture {look:22s} {_of_frames(truth.particles, truth.experiment['particle_diameter_px']):.3f}"
              f"; far over near the axis {_across_view(truth.particles, truth.experiment):.3f}")


def real_beads(d: float = 29.2) -> None:
    """The 6 mm beads' checked centres (category 0), frame by frame; d: their diameter [px]
    (tests/test_real_beads.py)."""
    truth = np.loadtxt(FIXTURES / "real-beads" / "truth.csv", delimiter=",", skiprows=1)
    per = [nearest_spacing(truth[(truth[:, 0] == i) & (truth[:, 3] == 0), 1:3]) / d for i in np.unique(truth[:, 0])]
    print(f"real photographs, 6 mm beads: {np.median(per):.3f} (frames {min(per):.3f}-{max(per):.3f})")


def dem(run: Path) -> None:
    from granseg.dem.dump import read_dumps

    cfg = json.loads((run / "dem.json").read_text())
    wall_lo, wall_hi = cfg["side_walls"]["y"]
    per = []
    for snap in read_dumps(run / "grains.dump"):
        c = snap.columns
        grain = np.isin(c["type"], [int(k) for k in cfg["types"]])
        length = snap.hi[0] - snap.lo[0]  # the box is periodic along the flow (x)
        for touching in (c["y"] - c["radius"] - wall_lo < 0.05, wall_hi - c["y"] - c["radius"] < 0.05):
            m = grain & touching  # touching a side wall (the camera's view), within 0.05 diameters
            seen = np.column_stack([c["x"][m], c["z"][m]])
            # the grains across the periodic ends are neighbours too
            beside = np.concatenate([seen - [length, 0], seen + [length, 0]])
            per.append(nearest_spacing(seen, beside) / (2 * np.mean(c["radius"][m])))
    print(f"DEM run {run}, grains touching a side wall ({len(per)} views): {np.median(per):.3f} "
          f"({min(per):.3f}-{max(per):.3f})")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenes", nargs="+", default=["S-POM-25", "POM-PP-50", "apparatus-C-PP-50-h264"],
                   help="2-D scenes, or 'all'")
    p.add_argument("--seeds", type=int, nargs="+", default=[7, 8])
    p.add_argument("--frames", type=int, default=6)
    p.add_argument("--dem", type=Path, help="a LAMMPS run folder (grains.dump, dem.json)")
    a = p.parse_args(argv)
    renderer(scene_names() if "all" in a.scenes else a.scenes, a.seeds, a.frames)
    fixtures()
    real_beads()
    if a.dem is not None:
        dem(a.dem)
    return 0


if __name__ == "__main__":
    sys.exit(main())
