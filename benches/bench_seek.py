"""What passing over a video's frames costs at a stride, sought or grabbed (``sources._Mover``).

    PYTHONPATH=python python benches/bench_seek.py [--seconds 100] [--every 30 60 150] [--gop 15 250] [--dir DIR]

Renders 37 frames of the throughput bench's look (steel/PP) at 640 x 480 (D = 13 px), writes them
over and over as ``--seconds`` of H.264 at 30 fps with a key frame every ``--gop`` frames at most
(the renderer's encoder, PyAV's x264, preset medium, so B-frames too: a GoPro's interval is 1 s,
x264's own default 250), and MPEG-4 Part 2 as OpenCV writes it (a key frame every 12). For each stream and stride N it times
``VideoFrames.frames()`` (frames 0, N, 2N, ... decoded and converted, nothing analysed) three
ways, in turn over ``--repeat`` rounds (best of them): ``measured`` (the default: sought or
grabbed by what each has cost in this stream), ``beyond-300`` (sought only more than 300 frames
apart, before the costs were measured) and ``grab`` (never sought). It prints the seconds, the
seeks the measured way made, and checks that every way gives the same frames, to the byte.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from granseg.measure import sources
from granseg.synth import render_frames
from granseg.synth.frames import VIDEO_PLAYBACK_FPS as FPS
from granseg.synth.frames import _encode

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_every import RENDERED, WAYS  # noqa: E402


def _streams(d: Path, seconds: float, gops: list[int]) -> dict[str, Path]:
    """``d``/h264-gopG.mp4 for each G and ``d``/mpeg4.mp4: the rendered frames in turn for ``seconds``."""
    c = np.zeros((RENDERED, 15))
    c[:, 8:] = 1.0
    c[1:] = 0.5
    frames = render_frames(c, heavy="steel", light="pp", particle_diameter_px=13.0, image_size=(640, 480),
                           out_dir=d / "frames", force=True, experiment={"fps": None}).images
    run = [frames[k % RENDERED] for k in range(int(seconds * FPS))]
    paths = {f"H.264, key frame every {g}": d / f"h264-gop{g}.mp4" for g in gops}
    for g, path in zip(gops, paths.values(), strict=True):
        if not path.exists():
            _encode(run, path, "h264", None, key_every=g)
    paths["MPEG-4 (OpenCV)"] = d / "mpeg4.mp4"
    if not paths["MPEG-4 (OpenCV)"].exists():
        _encode(run, paths["MPEG-4 (OpenCV)"], "mp4v", None)  # OpenCV's writer: a key frame every 12
    return paths


def _pass(path: Path, every: int, way: str) -> tuple[float, list[bytes], int]:
    """Seconds to get frames 0, every, ... of ``path`` the ``way`` given; their bytes' digests; seeks made."""
    import hashlib

    sources.SEEK_FRAMES, sources.TRY_SEEK_FRAMES = WAYS[way]
    try:
        video = sources.VideoFrames(path)
        video.keep(every)
        start = time.perf_counter()
        digests = [hashlib.blake2b(img.tobytes(), digest_size=8).digest() for _, img in video.frames()]
        took = time.perf_counter() - start
    finally:
        sources.SEEK_FRAMES, sources.TRY_SEEK_FRAMES = WAYS["measured"]
    return took, digests, video.sought


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=100.0, help="length of each video at 30 fps [s]")
    ap.add_argument("--every", type=int, nargs="+", default=[30, 60, 150])
    ap.add_argument("--gop", type=int, nargs="+", default=[15, 250], help="H.264 key-frame intervals [frames]")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--dir", type=Path, default=None, help="keep (or reuse) the videos here")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        d = args.dir if args.dir is not None else Path(tmp)
        d.mkdir(parents=True, exist_ok=True)
        streams = _streams(d, args.seconds, args.gop)
        best: dict[tuple[str, int, str], float] = {}
        seeks: dict[tuple[str, int], int] = {}
        for _ in range(args.repeat):
            for name, path in streams.items():
                for k in args.every:
                    got = {}
                    for way in WAYS:  # in turn, so that a busier spell hits each alike
                        took, got[way], made = _pass(path, k, way)
                        best[name, k, way] = min(best.get((name, k, way), np.inf), took)
                        if way == "measured":
                            seeks[name, k] = made
                    assert got["measured"] == got["beyond-300"] == got["grab"], f"{name}, every {k}: frames differ"
    print(f"{args.seconds:g} s at {FPS:g} fps, 640 x 480, frames 0, N, 2N, ... decoded; best of {args.repeat} "
          "[s]; every way gave the same frames")
    print("| stream | N | measured (seeks made) | beyond 300 | grab |")
    print("|---|---|---|---|---|")
    for name in streams:
        for k in args.every:
            n_read = -(-int(args.seconds * FPS) // k)
            print(f"| {name} | {k} | {best[name, k, 'measured']:.2f} ({seeks[name, k]} of {n_read}) | "
                  f"{best[name, k, 'beyond-300']:.2f} | {best[name, k, 'grab']:.2f} |")


if __name__ == "__main__":
    main()
