"""Frames per second of ``granseg analyze`` on 1920 x 1440 JPEG frames.

    PYTHONPATH=python python benches/bench_measure.py [--frames 30] [--diameter 38] [--workers 2] [--dir DIR]
    PYTHONPATH=python python benches/bench_measure.py --frames-from tests/fixtures/pbr/pom-pp --frames 120
    PYTHONPATH=python python benches/bench_measure.py --frames 120 --diameter 80 --dir DIR --repeat 1 --split-processes

Renders the frames once (granseg.synth, steel/PP, two side lamps, JPEG 90;
into DIR and kept there when given, reused if DIR already holds them), then
times the whole analysis (decode, undistort, detect, classify, bin) with the
given number of worker threads, best of --repeat runs. It also prints
the run's fixed part, the exposure survey and the learning of the spheres'
looks from the first frame (done once per run, before the workers start), and
the rate of the rest, which is what a long video sees. ``--frames-from DIR``
analyses the frames of DIR instead (a physically based fixture, say), each
used over and over until there are ``--frames``. ``--split-processes`` then
also splits the frames in ``--workers`` consecutive runs and analyses each in
its own process with one thread, all at once: what processes instead of
threads would give (the rate after each run's fixed part, summed).
``--frame-worker`` also times the per-frame work alone on one thread (frames
decoded beforehand): the figure a change to the per-frame code moves.
``--stages`` times the frame worker's largest steps (:data:`STAGES`) in one
process, round by round: what a change to one step saves, which the host's
drift between two whole runs can hide. ``--reduce K [K ...]`` times the
analysis of the frames reduced K times (analyze's ``reduce``; default its own
choice) for each K, taking turns:

    PYTHONPATH=python python benches/bench_measure.py --frames 120 --diameter 80 --dir DIR --reduce 1 2 --frame-worker

Shared machines differ from day to day (this bench read 12-14 frames/s one
day and 20-21 the next on the same tree), so each run also times a fixed
piece of OpenCV and numpy work that does not depend on granseg's code, on as
many processes at once as the analysis has workers, so that another job
taking a core shows in it too (the machine's yardstick, :func:`yardstick_ms`,
before and after the analysis):
two trees are compared by taking turns in one session, and a figure from
another day is read against its yardstick.
"""

from __future__ import annotations

import argparse
import multiprocessing
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import cv2
import numpy as np

from granseg.measure import analyze, detect, pipeline, templates
from granseg.measure.experiment import load_experiment
from granseg.measure.sources import read_image
from granseg.synth import render_frames


def yardstick_ms(frame: Path, workers: int) -> float:
    """Milliseconds a round of :func:`_yardstick` takes with ``workers`` processes doing it at once:
    the mean over ten rounds each, the slowest process's."""
    # spawned, not forked: a fork of a process whose OpenCV threads have run can hang
    context = multiprocessing.get_context("spawn")
    start_together = context.Barrier(workers)
    with ProcessPoolExecutor(workers, mp_context=context, initializer=_join, initargs=(start_together,)) as pool:
        return max(pool.map(_yardstick, [frame] * workers))


_BARRIER = None


def _join(barrier) -> None:
    """Pool initializer: keep the barrier at which the workers start their rounds together."""
    global _BARRIER
    _BARRIER = barrier


def _yardstick(frame: Path, rounds: int = 10) -> float:
    """Mean milliseconds, one thread, of a round of work like a frame's but not granseg's own:
    decode ``frame`` (a JPEG), blur it, match a 64 px patch over its middle, sort a million numbers."""
    data = np.frombuffer(frame.read_bytes(), np.uint8)
    cv2.setNumThreads(1)
    _BARRIER.wait()
    start = time.perf_counter()
    for _ in range(rounds):
        grey = cv2.cvtColor(cv2.imdecode(data, cv2.IMREAD_COLOR), cv2.COLOR_BGR2GRAY).astype(np.float32)
        blur = cv2.GaussianBlur(grey, (0, 0), 2.0)
        h, w = blur.shape
        middle = blur[h // 4: 3 * h // 4, w // 4: 3 * w // 4]
        cv2.matchTemplate(middle, middle[:64, :64].copy(), cv2.TM_CCOEFF_NORMED)
        np.sort(np.random.default_rng(0).random(1_000_000))
    return 1e3 * (time.perf_counter() - start) / rounds


def _repeated(source: Path, frames: int, out: Path) -> Path:
    """A folder of ``frames`` links to the JPEG frames of ``source``, used in turn, and its experiment.json."""
    images = sorted(source.glob("*.jpg"))
    if not images or not (source / "experiment.json").is_file():
        raise SystemExit(f"--frames-from {source}: needs JPEG frames and an experiment.json")
    out.mkdir(parents=True)
    (out / "experiment.json").write_bytes((source / "experiment.json").read_bytes())
    for i in range(frames):
        (out / f"frame_{i:05d}.jpg").symlink_to(images[i % len(images)].resolve())
    return out


def _split(source: Path, parts: int, out: Path) -> list[Path]:
    """``source``'s frames in ``parts`` folders of links, consecutive runs of them, each with the experiment.json."""
    images = sorted(source.glob("*.jpg"))
    folders = []
    for k, chunk in enumerate(np.array_split(np.arange(len(images)), parts)):
        folder = out / f"part{k}"
        folder.mkdir(parents=True)
        (folder / "experiment.json").write_bytes((source / "experiment.json").read_bytes())
        for i, j in enumerate(chunk):
            (folder / f"frame_{i:05d}.jpg").symlink_to(images[j].resolve())
        folders.append(folder)
    return folders


def _one_process(folder: Path) -> tuple[int, float, float]:
    """Frames, seconds and fixed-part seconds of one single-threaded analysis of ``folder`` (pool worker,
    started with the others at the barrier)."""
    import warnings

    cv2.setNumThreads(1)
    _BARRIER.wait()
    with _FixedPart() as part, warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a part that starts mid-run is not stratified: its checks fail
        start = time.perf_counter()
        analyze(folder, save=False, progress=False, workers=1)
        took = time.perf_counter() - start
    return len(list(folder.glob("*.jpg"))), took, part.seconds


def frame_worker_ms(source: Path, frames: int = 20, rounds: int = 3, reduce: int | None = None) -> float:
    """Milliseconds per frame of the frame worker alone (undistort, crop, detect, describe; decoded
    beforehand), one thread, on the first ``frames`` frames: the least of ``rounds`` rounds. What a
    change to the per-frame code moves, without the decoding, the threads and the fixed part."""
    cv2.setNumThreads(1)
    exp = load_experiment(source / "experiment.json")
    files = sorted(source.glob("*.jpg"))[:frames]
    k = pipeline.analysis_reduction(exp.particle_diameter_px) if reduce is None else reduce
    images = [read_image(p, k) for p in files]  # as analyze decodes them: at the size analysed
    worker = pipeline._FrameWorker(exp, cv2.imread(str(files[0])).shape[1::-1], reduce=k)
    worker.learn(images[0])
    best = np.inf
    for _ in range(rounds):
        start = time.perf_counter()
        for i, image in enumerate(images):
            worker(str(i), image)
        best = min(best, (time.perf_counter() - start) / len(images))
    return 1e3 * best


# The frame worker's largest steps, where the module that calls each looks it up.
STAGES = (
    ("undistort and crop", pipeline._FrameWorker, "_crop"),
    ("disk correlation", templates.DiskScores, "of"),
    ("  of which the disks' spread", templates, "_masked_spread"),
    ("outline fit", detect, "fit_outlines"),
    ("appearance features", pipeline, "sphere_features"),
)


def stage_ms(source: Path, frames: int = 20, rounds: int = 3, reduce: int | None = None) -> list[dict[str, float]]:
    """Per round, the frame worker's milliseconds per frame (``"frame"``) and those of each of
    :data:`STAGES` (one thread, decoded beforehand, as :func:`frame_worker_ms`), timed in one
    process: what a change to one step saves, read apart from the host's drift between runs."""
    cv2.setNumThreads(1)
    exp = load_experiment(source / "experiment.json")
    files = sorted(source.glob("*.jpg"))[:frames]
    k = pipeline.analysis_reduction(exp.particle_diameter_px) if reduce is None else reduce
    images = [read_image(p, k) for p in files]
    worker = pipeline._FrameWorker(exp, cv2.imread(str(files[0])).shape[1::-1], reduce=k)
    worker.learn(images[0])
    spent = dict.fromkeys([name for name, _, _ in STAGES], 0.0)
    saved = [(owner, attr, owner.__dict__[attr]) for _, owner, attr in STAGES]
    for (name, owner, attr), (_, _, original) in zip(STAGES, saved, strict=True):
        setattr(owner, attr, _timed(original, name, spent))
    try:
        result = []
        for _ in range(rounds):
            spent.update(dict.fromkeys(spent, 0.0))
            start = time.perf_counter()
            for i, image in enumerate(images):
                worker(str(i), image)
            took = time.perf_counter() - start
            result.append({"frame": 1e3 * took / len(images)} | {n: 1e3 * t / len(images) for n, t in spent.items()})
        return result
    finally:
        for owner, attr, original in saved:
            setattr(owner, attr, original)


def _timed(original, name: str, spent: dict[str, float]):
    """``original`` (a function or classmethod) adding its seconds to ``spent[name]``."""
    function = original.__func__ if isinstance(original, classmethod) else original

    def timed(*args, **kwargs):
        start = time.perf_counter()
        try:
            return function(*args, **kwargs)
        finally:
            spent[name] += time.perf_counter() - start

    return classmethod(timed) if isinstance(original, classmethod) else timed


def split_processes(source: Path, parts: int, tmp: Path) -> str:
    """The frames split in ``parts`` consecutive runs, each analysed by its own one-threaded process, all at
    once: the rate after each run's fixed part, summed (what processes instead of threads would give)."""
    folders = _split(source, parts, tmp / "split")
    context = multiprocessing.get_context("spawn")
    start_together = context.Barrier(parts)
    with ProcessPoolExecutor(parts, mp_context=context, initializer=_join, initargs=(start_together,)) as pool:
        runs = list(pool.map(_one_process, folders))
    after = sum(n - 1 for n, _, _ in runs) / max(took - fixed for _, took, fixed in runs)
    return (f"split in {parts} processes of one thread each, all at once: fixed parts "
            f"{', '.join(f'{fixed:.2f}' for _, _, fixed in runs)} s, then {after:.1f} frames/s together")


class _FixedPart:
    """Seconds spent in the run's fixed part (the frame worker's prepare: survey and learning), timed around it."""

    def __init__(self) -> None:
        self.seconds = 0.0
        self._saved = {name: getattr(pipeline._FrameWorker, name) for name in ("prepare",)}

    def __enter__(self) -> _FixedPart:
        for name, method in self._saved.items():
            setattr(pipeline._FrameWorker, name, self._timed(method))
        return self

    def __exit__(self, *exc) -> None:
        for name, method in self._saved.items():
            setattr(pipeline._FrameWorker, name, method)

    def _timed(self, method):
        def run(*args, **kwargs):
            start = time.perf_counter()
            try:
                return method(*args, **kwargs)
            finally:
                self.seconds += time.perf_counter() - start
        return run


def main() -> None:
    """Render, analyse, print frames/s."""
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--diameter", type=float, default=38.0, help="sphere diameter [px]")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--dir", type=Path, default=None, help="keep (or reuse) the rendered frames here")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--frames-from", type=Path, default=None,
                    help="analyse this folder's frames (and experiment.json), repeated up to --frames")
    ap.add_argument("--frame-worker", action="store_true",
                    help="also time the frame worker alone on one thread (ms per frame, first 20 frames)")
    ap.add_argument("--stages", action="store_true",
                    help="also time the frame worker's largest steps in one process (ms per frame, 3 rounds)")
    ap.add_argument("--split-processes", action="store_true",
                    help="also analyse the frames split in --workers runs, one process of one thread each")
    ap.add_argument("--reduce", type=int, nargs="+", default=[None], metavar="K",
                    help="analyse the frames reduced K times (analyze's reduce), each K in turn")
    args = ap.parse_args()
    c = np.zeros((args.frames, 15))
    c[:, 8:] = 1.0
    c[1:] = 0.5
    with tempfile.TemporaryDirectory() as tmp:
        d = args.dir if args.dir is not None else Path(tmp) / "frames"
        if args.frames_from is not None:
            d = _repeated(args.frames_from, args.frames, Path(tmp) / "repeated")
        elif not (d / "experiment.json").exists() or len(list(d.glob("*.jpg"))) != args.frames:
            render_frames(c, heavy="steel", light="pp", particle_diameter_px=args.diameter,
                          image_size=(1920, 1440), jpeg_quality=90, out_dir=d, force=True)
        first = sorted(d.glob("*.jpg"))[0]
        h, w = cv2.imread(str(first)).shape[:2]
        before = yardstick_ms(first, args.workers)
        best = {k: (np.inf, np.nan, None) for k in args.reduce}  # seconds, fixed part, analysis
        for _ in range(args.repeat):
            for k in args.reduce:  # taking turns, so that a busier spell hits each alike
                with _FixedPart() as part:
                    start = time.perf_counter()
                    a = analyze(d, save=False, progress=False, workers=args.workers, reduce=k)
                    took = time.perf_counter() - start
                if took < best[k][0]:
                    best[k] = (took, part.seconds, a)
        after = yardstick_ms(first, args.workers)
        split = split_processes(d, args.workers, Path(tmp)) if args.split_processes else None
        alone = {k: frame_worker_ms(d, reduce=k) for k in args.reduce} if args.frame_worker else None
        stages = {k: stage_ms(d, reduce=k) for k in args.reduce} if args.stages else None
    for k, (elapsed, fixed, a) in best.items():
        per = a.n.sum(axis=1).mean()
        diameter = a.experiment.particle_diameter_px
        print(f"{args.frames} frames {w}x{h}, D = {diameter:g} px, reduced {a.quality.figures['frames_reduced']} "
              f"times, {per:.0f} spheres/frame in the window, "
              f"{args.workers} workers: {elapsed:.2f} s, {args.frames / elapsed:.1f} frames/s "
              f"(survey and learning {fixed:.2f} s, then {(args.frames - 1) / (elapsed - fixed):.1f} frames/s); "
              f"machine yardstick {before:.0f} ms before, {after:.0f} ms after")
        if alone is not None:
            print(f"  frame worker alone, one thread: {alone[k]:.1f} ms/frame (least of 3 rounds over 20 frames)")
        if stages is not None:
            print("  its steps timed in one process, one thread, ms/frame over 20 frames in each of 3 rounds:")
            for name in stages[k][0]:
                print(f"    {name:<30} {', '.join(f'{r[name]:.1f}' for r in stages[k])}")
    if split is not None:
        print(split)


if __name__ == "__main__":
    main()
