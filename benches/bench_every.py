"""How fast ``granseg analyze --every N`` gets through a video filmed in real time.

    PYTHONPATH=python python benches/bench_every.py [--seconds 20] [--every 1 10 30] [--codec mp4v] [--dir DIR]
    PYTHONPATH=python python benches/bench_every.py --seconds 120 --every 30 --grab-too

Renders 37 frames of the throughput bench's look (granseg.synth, steel/PP, 1920 x 1440, D = 38
px) once, writes them over and over as a video of ``--seconds`` at 30 fps (37 is prime, so no
stride lands on one rendered frame only; ``--codec``: ``mp4v``, MPEG-4 Part 2 by OpenCV, or
``h264`` by PyAV with a key frame every 15 frames, as a GoPro, the renderer's own encoder), and
times ``analyze(video, every=N)``
on two workers for each N, taking turns over ``--repeat`` rounds (best of them). It also times
reading the stream through without converting a frame (``grab`` only): what passing over every
frame costs, where none is sought. Prints, for each N,
the recording's frames got through per second and the frames analysed per second.
``--ways`` says how the frames between are passed over, each way timed in turn: ``measured``
(the default: sought or grabbed by what each has cost in the stream, ``sources._Mover``),
``beyond-300`` (sought only more than ``sources.SEEK_FRAMES`` apart, as before the costs were
measured) and ``grab`` (never sought, as before that; ``--grab-too`` adds it).

    PYTHONPATH=python python benches/bench_every.py --seconds 120 --every 30 60 150 --ways measured beyond-300 grab
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from granseg._io import cv2_path
from granseg.measure import analyze, sources
from granseg.synth import render_frames
from granseg.synth.frames import VIDEO_PLAYBACK_FPS as PLAYBACK_FPS
from granseg.synth.frames import _encode

RENDERED = 37
# sources.SEEK_FRAMES and TRY_SEEK_FRAMES of each way of passing over the frames between
WAYS = {"measured": (sources.SEEK_FRAMES, sources.TRY_SEEK_FRAMES), "beyond-300": (300, 300),
        "grab": (10**12, 10**12)}


def _video(d: Path, seconds: float, codec: str) -> Path:
    """``d``/run-CODEC.mp4 (with experiment.json beside it): the rendered frames in turn for ``seconds``."""
    video = d / f"run-{codec}.mp4"
    if video.exists():
        return video
    c = np.zeros((RENDERED, 15))
    c[:, 8:] = 1.0
    c[1:] = 0.5
    frames = render_frames(c, heavy="steel", light="pp", particle_diameter_px=38.0, image_size=(1920, 1440),
                           out_dir=d / "frames", force=True, experiment={"fps": None})
    _encode([frames.images[i % RENDERED] for i in range(int(seconds * PLAYBACK_FPS))], video, codec, None)
    (d / "experiment.json").write_text((d / "frames" / "experiment.json").read_text())
    return video


def grab_seconds(video: Path) -> tuple[int, float]:
    """Frames in the stream and the seconds it takes to grab them all (decoded, not converted)."""
    cap = cv2.VideoCapture(cv2_path(video))
    start, n = time.perf_counter(), 0
    while cap.grab():
        n += 1
    cap.release()
    return n, time.perf_counter() - start


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=20.0, help="length of the video at 30 fps [s]")
    ap.add_argument("--every", type=int, nargs="+", default=[1, 10, 30])
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--codec", choices=("mp4v", "h264"), default="mp4v")
    ap.add_argument("--dir", type=Path, default=None, help="keep (or reuse) the video here")
    ap.add_argument("--ways", nargs="+", choices=tuple(WAYS), default=["measured"],
                    help="how the frames between those read are passed over")
    ap.add_argument("--grab-too", action="store_true", help="also time each N with every frame grabbed (--ways grab)")
    args = ap.parse_args()
    ways = {f" ({way})": WAYS[way] for way in dict.fromkeys(args.ways + (["grab"] if args.grab_too else []))}
    with tempfile.TemporaryDirectory() as tmp:
        d = args.dir if args.dir is not None else Path(tmp)
        d.mkdir(parents=True, exist_ok=True)
        video = _video(d, args.seconds, args.codec)
        best = {(k, way): np.inf for k in args.every for way in ways}
        grab = np.inf
        for _ in range(args.repeat):
            n, took = grab_seconds(video)
            grab = min(grab, took)
            for k, way in best:  # taking turns, so that a busier spell hits each alike
                sources.SEEK_FRAMES, sources.TRY_SEEK_FRAMES = ways[way]
                start = time.perf_counter()
                a = analyze(video, every=k, save=False, progress=False, workers=args.workers)
                best[k, way] = min(best[k, way], time.perf_counter() - start)
                assert len(a.t) == -(-n // k)
    print(f"{args.codec} video, {n} frames of 1920 x 1440 at {PLAYBACK_FPS:g} fps ({n / PLAYBACK_FPS:g} s), "
          f"{args.workers} workers, best of {args.repeat}")
    print(f"  grabbing the stream alone: {grab:.2f} s, {n / grab:.0f} frames/s")
    for (k, way), took in best.items():
        print(f"  --every {k:>3}{way}: {took:.2f} s, {n / took:.0f} recording frames/s "
              f"({n / took / PLAYBACK_FPS:.1f} x real time), {-(-n // k) / took:.1f} frames analysed/s")


if __name__ == "__main__":
    main()
