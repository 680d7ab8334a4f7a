"""Benchmark: velocity profiles from rendered high-speed footage with a known shear band.

For each delta/H, seed and set of frame rates, one pure glass bed is rendered
(granseg.synth.highspeed: bumpy plate moving at v0, motion blur over half the frame
interval, the lens' barrel distortion), measured with granseg.measure_velocity, and the
fitted delta/H compared with the truth. The method's constants were set on seeds 1-4 at
delta/H = 0.18 and 100 fps; the default seeds here (100 on) were not used for that.

    RAYON_NUM_THREADS=2 python benches/bench_velocity.py --out benches/results/velocity.json
    python benches/bench_velocity.py --throughput     # 1920 x 1440 frames, frames per second
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "python"))

from granseg.synth.highspeed import render_highspeed, render_recordings  # noqa: E402
from granseg.velocity import measure_velocity  # noqa: E402

RATE_SETS = {"100 fps": (100.0,), "24+100+1000 fps": (24.0, 100.0, 1000.0)}


def one(dh: float, seed: int, rates: tuple[float, ...], frames: int, root: Path) -> dict:
    out = root / f"dh{dh}_s{seed}_{len(rates)}"
    paths = render_recordings(out, fps=rates, n_frames=frames, seed=seed, delta_over_H=dh)
    t = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        prof, _ = measure_velocity(paths, progress=False)
    seconds = time.perf_counter() - t
    est, se = prof.fit.params["delta_over_H"], prof.fit.stderr["delta_over_H"]
    return {"delta_over_H": dh, "seed": seed, "fps": list(rates), "estimate": est, "stderr": se,
            "rel_error": est / dh - 1, "z": (est - dh) / se, "v0": prof.fit.params["v0"],
            "layers": int(np.isfinite(prof.v).sum()), "notes": list(prof.notes) + prof.fit_notes,
            "measure_s": seconds, "frames": frames * len(rates)}


def table(rows: list[dict]) -> str:
    lines = ["| delta/H | frame rates | runs | mean estimate | max abs error | max abs z | within 5 % and 3 SE |",
             "|---|---|---|---|---|---|---|"]
    keys = sorted({(r["delta_over_H"], tuple(r["fps"])) for r in rows})
    for dh, rates in keys:
        sel = [r for r in rows if r["delta_over_H"] == dh and tuple(r["fps"]) == rates]
        ok = sum(abs(r["rel_error"]) <= 0.05 and abs(r["z"]) <= 3 for r in sel)
        lines.append(f"| {dh:.2f} | {'+'.join(f'{f:g}' for f in rates)} | {len(sel)} | "
                     f"{np.mean([r['estimate'] for r in sel]):.4f} | "
                     f"{100 * max(abs(r['rel_error']) for r in sel):.1f} % | "
                     f"{max(abs(r['z']) for r in sel):.1f} | {ok} of {len(sel)} |")
    return "\n".join(lines)


def throughput(frames: int) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        render_highspeed(Path(tmp) / "big", fps=100.0, n_frames=frames, particle_diameter_px=80.0, material="pom",
                         image_size=(1920, 1440), seed=5)
        t = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            measure_velocity(Path(tmp) / "big", progress=False)
        dt = time.perf_counter() - t
    print(f"velocity on {frames} frames of 1920 x 1440 px (spheres 80 px): {dt:.1f} s, "
          f"{frames / dt:.1f} frames/s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--delta-over-H", type=float, nargs="+", default=[0.12, 0.18, 0.24, 0.30])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--first-seed", type=int, default=100)
    ap.add_argument("--frames", type=int, default=60, help="frames per recording")
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--throughput", action="store_true")
    args = ap.parse_args()
    if args.throughput:
        throughput(args.frames)
        return
    rows = []
    cases = [(dh, s, rates) for rates in RATE_SETS.values() for dh in args.delta_over_H
             for s in range(args.first_seed, args.first_seed + args.seeds)]
    with tempfile.TemporaryDirectory() as tmp:
        for i, (dh, seed, rates) in enumerate(cases):
            r = one(dh, seed, rates, args.frames, Path(tmp))
            rows.append(r)
            print(f"[{i + 1}/{len(cases)}] " + json.dumps({k: r[k] for k in
                  ("delta_over_H", "seed", "fps", "estimate", "stderr", "rel_error", "z", "layers")}), flush=True)
    md = table(rows)
    print(md)
    if args.out is not None:
        args.out.write_text(json.dumps(rows, indent=1))
        args.out.with_suffix(".md").write_text(md + "\n")


if __name__ == "__main__":
    main()
