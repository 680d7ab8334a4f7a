"""Reading a recording held as one TIFF stack: what finding a page costs, and the analysis of a stack
against the same frames as files.

    PYTHONPATH=python python benches/bench_tiff_stack.py [--pages 3000] [--frames 40] [--repeat 2]

1. Finding a page: a stack of ``--pages`` small pages (160 x 120, RGB, uncompressed, written by
   tifffile) is read at its first page, a third of the way in and its last, by the source
   ``granseg.measure.sources.TiffStack`` (tifffile) and by OpenCV's ``imreadmulti(start, count=1)``
   (libtiff), each the best of five reads; the stack is opened once for TiffStack, as the analysis
   does. OpenCV's page index is walked from the file's start for every page it is asked for.
2. The analysis: ``--frames`` frames of the throughput bench's look (steel over PP, 1920 x 1440,
   D = 38 px) rendered as PNG, then the same frames as one uncompressed RGB stack; ``analyze`` of
   each on two workers, taking turns over ``--repeat`` rounds (best of them), and the maps compared.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import tifffile

from granseg.measure import analyze
from granseg.measure.sources import TiffStack
from granseg.synth import render_frames


def _best_ms(read, rounds: int = 5) -> float:
    best = np.inf
    for _ in range(rounds):
        start = time.perf_counter()
        read()
        best = min(best, time.perf_counter() - start)
    return 1e3 * best


def page_costs(pages: int, tmp: Path) -> None:
    rng = np.random.default_rng(0)
    path = tmp / "small.tif"
    tifffile.imwrite(path, rng.integers(0, 256, (pages, 120, 160, 3), dtype=np.uint8), photometric="rgb")
    stack = TiffStack(path)
    try:
        print(f"finding a page of a {pages}-page stack, 160 x 120 RGB, uncompressed (best of 5 reads, ms):")
        print("| page | TiffStack (tifffile) | OpenCV imreadmulti |")
        print("|---|---|---|")
        for page in (0, pages // 3, pages - 1):
            ours = _best_ms(lambda p=page: stack.read(p))
            theirs = _best_ms(lambda p=page: cv2.imreadmulti(str(path), start=p, count=1, flags=cv2.IMREAD_COLOR))
            print(f"| {page} | {ours:.2f} | {theirs:.2f} |")
    finally:
        stack.close()


def analysis(frames: int, repeat: int, tmp: Path) -> None:
    c = np.zeros((frames, 15))
    c[:, 8:] = 1.0
    c[1:] = 0.5
    folder = tmp / "frames"
    render_frames(c, heavy="steel", light="pp", particle_diameter_px=38.0, image_size=(1920, 1440), out_dir=folder)
    images = np.stack([cv2.imread(str(p))[..., ::-1] for p in sorted(folder.glob("*.png"))])
    stack = tmp / "stack" / "run.tif"
    stack.parent.mkdir()
    tifffile.imwrite(stack, images, photometric="rgb")
    (stack.parent / "experiment.json").write_text((folder / "experiment.json").read_text())
    best = {"PNG files": (np.inf, None), "one TIFF stack": (np.inf, None)}
    for _ in range(repeat):
        for name, path in (("PNG files", folder), ("one TIFF stack", stack)):  # taking turns
            start = time.perf_counter()
            m = analyze(path, save=False, progress=False, workers=2)
            took = time.perf_counter() - start
            if took < best[name][0]:
                best[name] = (took, m)
    (_, a), (_, b) = best.values()
    same = np.array_equal(a.n, b.n) and np.array_equal(a.c_raw, b.c_raw, equal_nan=True)
    mb = stack.stat().st_size / 2**20
    print(f"\n{frames} frames 1920 x 1440 (steel/PP, D = 38 px), two workers, best of {repeat}; "
          f"the stack {mb:.0f} MB; maps equal: {same}")
    for name, (took, _) in best.items():
        print(f"  {name}: {took:.2f} s, {frames / took:.1f} frames/s")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--pages", type=int, default=3000)
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        page_costs(args.pages, Path(tmp))
        analysis(args.frames, args.repeat, Path(tmp))


if __name__ == "__main__":
    main()
