"""Make the recordings of the README's walk-through "Your own recording" (rendered, SYNTHETIC).

    python examples/recording/make_recordings.py OUT

writes what a lab has after a day at the cell, and nothing granseg would write itself:

    OUT/checkerboards/board_*.png     six photos of a 9 x 6 checkerboard through the camera's lens
    OUT/recordings/NAME/frame_*.png   three experiments filmed at one frame every 2 min (no experiment.json)
    OUT/truth/NAME.npz                the maps the frames were rendered from (to compare against)
    OUT/conditions.txt                each experiment's materials, c0 and masses, as a lab notebook has them

The experiments are three of the paper's conditions (glass, ceramic and POM on PP, c0 = 0.5),
simulated by the model at its calibrated constants and rendered through a barrel-distorting
lens (k1 = -0.2) onto 800 x 600 px frames, spheres 30 px across. Deterministic (fixed seeds).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

from granseg.synth import default_camera, render_checkerboard, render_frames
from granseg.synth.virtual import TABLE1, campaign

SIZE = (800, 600)
CONDITIONS = ("G-PP-50", "C-PP-50", "POM-PP-50")
INTERVAL_S = 120.0
DURATION_S = 1440.0
#: (rotation, translation) of each checkerboard photo: tilted every way, filling the frame
POSES = [((0.1, -0.2, 0.05), (-3.5, -2.5, 14)), ((-0.3, 0.1, -0.1), (-5, -3, 13)),
         ((0.25, 0.3, 0.2), (-4, -4, 15)), ((-0.1, -0.35, 0.0), (-2, -2.5, 12)),
         ((0.35, 0.0, -0.2), (-6, -2, 14)), ((0.0, 0.2, 0.3), (-3, -5, 16))]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("out", type=Path)
    a = p.parse_args(argv)
    k, dist = default_camera(SIZE, k1=-0.2)
    boards = a.out / "checkerboards"
    boards.mkdir(parents=True, exist_ok=True)
    for i, (r, t) in enumerate(POSES):
        cv2.imwrite(str(boards / f"board_{i}.png"), render_checkerboard(k, dist, SIZE, r, t))
    conds = [c for c in TABLE1 if c.label() in CONDITIONS]
    maps = campaign(a.out / "truth", conditions=conds, seed=3, fps=1 / INTERVAL_S, duration=DURATION_S,
                    force=True)
    notes = []
    for n, m in enumerate(maps, 1):
        folder = a.out / "recordings" / m.name
        render_frames(np.clip(m.c, 0, 1), heavy=m.heavy.lower(), light=m.light.lower(), image_size=SIZE,
                      camera_matrix=k, dist_coeffs=dist, fps=1 / INTERVAL_S, seed=n, out_dir=folder, force=True)
        (folder / "experiment.json").unlink()  # the lab writes its own: granseg init-experiment
        notes.append(f"{m.name}: heavy {m.heavy}, light {m.light}, c0 {m.c0:g}, M_g {m.M_g:.3f} kg, "
                     f"M_w {m.M_w:.3f} kg, one frame every {INTERVAL_S:g} s")
        print(f"[{n}/{len(maps)}] {folder}: {m.n_times} frames", flush=True)
    (a.out / "conditions.txt").write_text("\n".join(notes) + "\n")
    print("\n".join(notes))
    return 0


if __name__ == "__main__":
    sys.exit(main())
