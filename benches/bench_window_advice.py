"""What following the ``window_lines`` advice does to a map made without the lens's camera model.

A user who gives no camera model gets ``granseg init``'s pinhole without
distortion. Under a lens the window's lid and plate lines then miss the walls
and ``window_lines`` fails, advising to move them by so many px. This script
renders each scene, analyses it with that pinhole, and moves the lines as the
check's figures say (``window_lines_d``: each line's offset in diameters, moved
where it is beyond ``WALL_LINE_SLACK``), up to three times, reporting at each
step the map's c_raw RMSD and per-frame layer count error against the truth,
the failed checks and the figure of ``spacing_across_view``. It measures the
trap of a mild lens: the lines moved, every check passes and the map is still
wrong (BENCHMARKS.md, "A lens not taken off").

    PYTHONPATH=python python benches/bench_window_advice.py --scenes S-PP-75 G-PP-50 --seeds 7 8 \\
        [--json FILE]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np

from granseg._io import save_json
from granseg.constants import N_LAYERS
from granseg.errors import QualityWarning
from granseg.measure import analyze
from granseg.measure.quality import WALL_LINE_SLACK
from granseg.synth.scenes import render_scene, scene_names

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_measure_accuracy import _as_given, frame_count_error  # noqa: E402

MOVES = 3


def _moved(window: list[float], figures: dict) -> list[float] | None:
    """The window with its lid (y0) and plate (y1) lines moved as window_lines advises; None where
    neither is beyond the slack."""
    offsets = figures.get("window_lines_d") or {}
    layer_px = (window[3] - window[1]) / N_LAYERS
    moved = list(window)
    for wall, index, inward in (("lid", 1, 1.0), ("plate", 3, -1.0)):
        off = offsets.get(wall)
        if off is not None and abs(off) > WALL_LINE_SLACK:
            moved[index] += inward * off * layer_px  # off > 0: the line lies outside the bed
    return None if moved == list(window) else moved


def follow(scene: str, seed: int, frames: int) -> list[dict]:
    """The steps of one run: analysed with the pinhole, then with the lines moved as advised."""
    steps = []
    with tempfile.TemporaryDirectory() as tmp:
        r = render_scene(scene, frames, seed=seed, out_dir=Path(tmp))
        exp_path = Path(tmp) / "experiment.json"
        window = list(r.experiment["window"])
        for _ in range(MOVES + 1):
            _as_given(exp_path, {**r.experiment, "window": window}, 1.0, r.images[0].shape[1::-1])
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", QualityWarning)  # reported below
                a = analyze(r.source, smooth=1, save=False, progress=False, workers=2)
            steps.append({"window": [round(v, 1) for v in window],
                          "rmsd": float(np.sqrt(np.nanmean((a.c_raw - r.c_raw) ** 2))),
                          "frame_layer_count_error": float(frame_count_error(a.n, r.n)),
                          "failed_checks": [c.name for c in a.quality.failed],
                          "spacing_across_view": a.quality.figures.get("spacing_across_view")})
            window = _moved(window, a.quality.figures)
            if window is None:
                break
    return steps


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", nargs="+", default=["S-PP-75", "G-PP-50"], choices=[*scene_names(), "all"])
    ap.add_argument("--seeds", type=int, nargs="+", default=[7, 8])
    ap.add_argument("--frames", type=int, default=6)
    ap.add_argument("--json", type=Path, default=None, help="also write the steps here")
    args = ap.parse_args()
    scenes = scene_names() if "all" in args.scenes else args.scenes
    results = {}
    for scene in scenes:
        for seed in args.seeds:
            results[f"{scene}/{seed}"] = steps = follow(scene, seed, args.frames)
            for k, s in enumerate(steps):
                print(f"{scene:28s} seed {seed:3d} {'as given' if k == 0 else f'moved {k}':8s}: window y "
                      f"{s['window'][1]:.1f}-{s['window'][3]:.1f} RMSD {s['rmsd']:.3f} counts "
                      f"{100 * s['frame_layer_count_error']:.1f} % far over near the axis "
                      f"{s['spacing_across_view']:.3f} failed {','.join(s['failed_checks']) or '-'}", flush=True)
    if args.json is not None:
        save_json(args.json, {"command": " ".join(sys.argv), "frames": args.frames, "results": results}, force=True)


if __name__ == "__main__":
    main()
