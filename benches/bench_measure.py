"""Frames per second of ``granseg analyze`` on 1920 x 1440 JPEG frames.

    PYTHONPATH=python python benches/bench_measure.py [--frames 30] [--diameter 38] [--workers 2] [--dir DIR]

Renders the frames once (granseg.synth, steel/PP, two side lamps, JPEG 90;
into DIR and kept there when given, reused if DIR already holds them), then
times the whole analysis (decode, undistort, detect, classify, bin) with the
given number of worker processes, best of --repeat runs.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from granseg.measure import analyze
from granseg.synth import render_frames


def main() -> None:
    """Render, analyse, print frames/s."""
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--diameter", type=float, default=38.0, help="sphere diameter [px]")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--dir", type=Path, default=None, help="keep (or reuse) the rendered frames here")
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    c = np.zeros((args.frames, 15))
    c[:, 8:] = 1.0
    c[1:] = 0.5
    with tempfile.TemporaryDirectory() as tmp:
        d = args.dir if args.dir is not None else Path(tmp) / "frames"
        if not (d / "experiment.json").exists() or len(list(d.glob("*.jpg"))) != args.frames:
            render_frames(c, heavy="steel", light="pp", particle_diameter_px=args.diameter,
                          image_size=(1920, 1440), jpeg_quality=90, out_dir=d, force=True)
        elapsed = np.inf
        for _ in range(args.repeat):
            start = time.perf_counter()
            a = analyze(d, save=False, progress=False, workers=args.workers)
            elapsed = min(elapsed, time.perf_counter() - start)
    per = a.n.sum(axis=1).mean()
    print(f"{args.frames} frames 1920x1440, D = {args.diameter:g} px, {per:.0f} spheres/frame in the window, "
          f"{args.workers} workers: {elapsed:.2f} s, {args.frames / elapsed:.1f} frames/s")


if __name__ == "__main__":
    main()
