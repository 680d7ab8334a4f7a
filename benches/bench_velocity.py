"""Benchmark: velocity profiles from rendered high-speed footage with a known shear band.

For each delta/H, seed and set of frame rates, one pure glass bed is rendered
(granseg.synth.highspeed: bumpy plate moving at v0, motion blur over half the frame
interval, the lens' barrel distortion), measured with granseg.measure_velocity, and the
fitted delta/H compared with the truth. The method's constants were set on seeds 1-4 at
delta/H = 0.18 and 100 fps; the default seeds here (100 on) were not used for that.

    RAYON_NUM_THREADS=2 python benches/bench_velocity.py --out benches/results/velocity.json
    python benches/bench_velocity.py --first-seed 1 --seeds 4 --rates "100 fps" --phi-grid 0 0.3 0.4 0.5 0.6 0.7
    python benches/bench_velocity.py --throughput     # 1920 x 1440 frames, frames per second
    python benches/bench_velocity.py --window-sample 0.18 205 --v1 0.012   # the window's grains against their band
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
from granseg.velocity import VelocityProfile, measure_velocity  # noqa: E402

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
    # the same profile fitted with its layers taken as independent (as before LAYER_CORRELATION)
    alone = VelocityProfile.fitted(prof.z, prof.v, prof.v_err, prof.H).fit
    est0, se0 = alone.params["delta_over_H"], alone.stderr["delta_over_H"]
    return {"delta_over_H": dh, "seed": seed, "fps": list(rates), "estimate": est, "stderr": se,
            "rel_error": est / dh - 1, "z": (est - dh) / se, "layer_correlation": prof.layer_correlation,
            "independent_layers": {"estimate": est0, "stderr": se0, "rel_error": est0 / dh - 1,
                                   "z": (est0 - dh) / se0},
            "profile": {"z": prof.z.tolist(), "v": prof.v.tolist(), "v_err": prof.v_err.tolist(), "H": prof.H},
            "v0": prof.fit.params["v0"],
            "layers": int(np.isfinite(prof.v).sum()), "notes": list(prof.notes) + prof.fit_notes,
            "measure_s": seconds, "frames": frames * len(rates)}


def table(rows: list[dict]) -> str:
    lines = ["| delta/H | frame rates | runs | mean estimate | max abs error | max abs z | within 5 % and 3 SE "
             "| max abs z, layers independent |",
             "|---|---|---|---|---|---|---|---|"]
    keys = sorted({(r["delta_over_H"], tuple(r["fps"])) for r in rows})
    for dh, rates in keys:
        sel = [r for r in rows if r["delta_over_H"] == dh and tuple(r["fps"]) == rates]
        ok = sum(abs(r["rel_error"]) <= 0.05 and abs(r["z"]) <= 3 for r in sel)
        lines.append(f"| {dh:.2f} | {'+'.join(f'{f:g}' for f in rates)} | {len(sel)} | "
                     f"{np.mean([r['estimate'] for r in sel]):.4f} | "
                     f"{100 * max(abs(r['rel_error']) for r in sel):.1f} % | "
                     f"{max(abs(r['z']) for r in sel):.1f} | {ok} of {len(sel)} | "
                     f"{max(abs(r['independent_layers']['z']) for r in sel):.1f} |")
    for name, key in (("fitted as the pipeline does", None), ("layers taken as independent", "independent_layers")):
        z = np.array([(r[key] if key else r)["z"] for r in rows])
        rel = np.array([(r[key] if key else r)["rel_error"] for r in rows])
        lines.append(f"\nAll {len(rows)} beds, {name}: within 3 SE {int(np.sum(abs(z) <= 3))}, within 2 SE "
                     f"{int(np.sum(abs(z) <= 2))}, rms z {np.sqrt(np.mean(z ** 2)):.2f}, within 5 % "
                     f"{int(np.sum(abs(rel) <= 0.05))}, both {int(np.sum((abs(rel) <= 0.05) & (abs(z) <= 3)))}.")
    return "\n".join(lines)


def phi_grid(rows: list[dict], phis: list[float]) -> str:
    """Each bed's measured profile refitted at every layer correlation phi: the rms of the
    errors in standard errors, the beds within 3 SE and within 5 %, and how much the stated
    errors grow against independent layers (how LAYER_CORRELATION was chosen)."""
    from granseg.fit import fit_shear_band

    def fits(phi):
        out = []
        for r in rows:
            p = r["profile"]
            z, v, e = (np.asarray(p[k], dtype=float) for k in ("z", "v", "v_err"))
            ok = np.isfinite(v) & np.isfinite(e)
            f = fit_shear_band(z[ok], v[ok], e[ok], H=p["H"], layer_correlation=phi)
            out.append((f.params["delta_over_H"], f.stderr["delta_over_H"], r["delta_over_H"]))
        return np.array(out)

    base = fits(0.0)
    lines = [_layer_deviation_correlation(rows), ""]
    lines += ["| phi | rms z | within 3 SE | within 5 % | stated error / independent layers' |", "|---|---|---|---|---|"]
    for phi in phis:
        f = fits(phi)
        z, rel, grow = (f[:, 0] - f[:, 2]) / f[:, 1], f[:, 0] / f[:, 2] - 1, f[:, 1] / base[:, 1]
        lines.append(f"| {phi:g} | {np.sqrt(np.mean(z ** 2)):.2f} | {int(np.sum(abs(z) <= 3))} of {len(f)} | "
                     f"{int(np.sum(abs(rel) <= 0.05))} of {len(f)} | {grow.min():.2f}-{grow.max():.2f} |")
    return "\n".join(lines)


def _layer_deviation_correlation(rows: list[dict]) -> str:
    """How much neighbouring layers share their deviations: each layer's measured speed less the
    profile's mean over the layer (the renderer's bands move at exactly that), in its stated
    error, correlated with the layer k above, pooled over the beds (the plate's two layers left
    out: their errors are the blur's). The beds are rendered with v1 = 0 and the default v0."""
    from granseg.model import derived

    v0, dev = derived()["v0"], []
    for r in rows:
        p = r["profile"]
        z, v, e = (np.asarray(p[k], dtype=float) for k in ("z", "v", "v_err"))
        layer = p["H"] / z.size
        lo = np.floor(z / layer) * layer
        L = r["delta_over_H"] * p["H"]
        truth = v0 * L * (np.exp(-lo / L) - np.exp(-(lo + layer) / L)) / layer
        dev.append(((v - truth) / e)[2:])
    dev = np.array(dev)
    parts = []
    for k in (1, 2, 3, 4):
        a, b = dev[:, :-k].ravel(), dev[:, k:].ravel()
        ok = np.isfinite(a) & np.isfinite(b)
        parts.append(f"{k} apart {np.corrcoef(a[ok], b[ok])[0, 1]:+.2f}")
    return (f"Layers' deviations from the truth in their errors (rms {np.sqrt(np.nanmean(dev ** 2)):.2f}), "
            f"correlation with the layer k above: " + ", ".join(parts))


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


def window_sample(dh: float, seed: int, fps: float, v0: float, v1: float, frames: int) -> None:
    """Per layer, the true mean speed of the grains the window shows, of every grain of the band
    (the renderer's, read as it moves them) and the measured one:
    how much of a bed's error is its window's sample of grains rather than the method."""
    import granseg.synth.frames as F

    seen = []
    positions = F._Bed.positions

    def recorded(bed, *a, **kw):
        x = positions(bed, *a, **kw)
        seen.append((x.copy(), bed.in_window(x), bed.y.copy(), bed.win, bed.d, bed.length))
        return x

    F._Bed.positions = recorded
    try:
        with tempfile.TemporaryDirectory() as tmp:
            render_highspeed(Path(tmp) / "r", delta_over_H=dh, fps=fps, n_frames=frames, seed=seed, v0=v0, v1=v1)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                prof, _ = measure_velocity(Path(tmp) / "r", progress=False)
    finally:
        F._Bed.positions = positions
    x, inside, y = (np.array([p[k] for p in seen]) for k in range(3))
    win, d, length = seen[0][3:]
    step = (np.diff(x, axis=0) + length / 2) % length - length / 2  # [px per frame]
    both = inside[1:] & inside[:-1]
    # grains settle up and down a little as they make room: a step's layer is its mid-height's
    layer = np.clip(np.floor((win[3] - 0.5 * (y[1:] + y[:-1])) / d).astype(int), 0, prof.v.size - 1)
    to_speed = prof.H / prof.v.size / d * fps  # px per frame -> m/s
    print(f"delta/H {dh}, seed {seed}, {fps:g} fps, v0 {v0}, v1 {v1}: fitted {prof.delta_over_H:.4f} "
          f"+- {prof.fit.stderr['delta_over_H']:.4f}")
    print("layer  window's grains  whole band  measured [m/s]")
    for j in range(prof.v.size):
        win_v = step[both & (layer == j)].mean() * to_speed
        band_v = step[layer == j].mean() * to_speed
        print(f"{j + 1:5d}  {win_v:15.5f}  {band_v:10.5f}  {prof.v[j]:.5f} +- {prof.v_err[j]:.5f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--delta-over-H", type=float, nargs="+", default=[0.12, 0.18, 0.24, 0.30])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--first-seed", type=int, default=100)
    ap.add_argument("--frames", type=int, default=60, help="frames per recording")
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--rates", nargs="+", choices=list(RATE_SETS), default=list(RATE_SETS),
                    help="which sets of frame rates to film each bed with")
    ap.add_argument("--phi-grid", type=float, nargs="+", default=None, metavar="PHI",
                    help="also refit every bed at these layer correlations (how LAYER_CORRELATION was chosen)")
    ap.add_argument("--tables-from", type=Path, default=None, metavar="JSON",
                    help="print the tables of an earlier run's --out file instead of measuring")
    ap.add_argument("--throughput", action="store_true")
    ap.add_argument("--window-sample", nargs=2, type=float, metavar=("DELTA_OVER_H", "SEED"),
                    help="one 100 fps recording: the window's grains against their band, per layer")
    ap.add_argument("--v1", type=float, default=0.0, help="the lid's speed [m/s] for --window-sample")
    args = ap.parse_args()
    if args.window_sample:
        window_sample(args.window_sample[0], int(args.window_sample[1]), 100.0, 0.2332, args.v1, args.frames)
        return
    if args.throughput:
        throughput(args.frames)
        return
    if args.tables_from is not None:  # the tables again from a run's JSON, nothing measured
        rows = json.loads(args.tables_from.read_text())
        print(table(rows) + ("\n\n" + phi_grid(rows, args.phi_grid) if args.phi_grid else ""))
        return
    rows = []
    rate_sets = [RATE_SETS[k] for k in args.rates]
    cases = [(dh, s, rates) for rates in rate_sets for dh in args.delta_over_H
             for s in range(args.first_seed, args.first_seed + args.seeds)]
    with tempfile.TemporaryDirectory() as tmp:
        for i, (dh, seed, rates) in enumerate(cases):
            r = one(dh, seed, rates, args.frames, Path(tmp))
            rows.append(r)
            print(f"[{i + 1}/{len(cases)}] " + json.dumps({k: r[k] for k in
                  ("delta_over_H", "seed", "fps", "estimate", "stderr", "rel_error", "z", "layers")}), flush=True)
    md = table(rows)
    if args.phi_grid:
        md += "\n\n" + phi_grid(rows, args.phi_grid)
    print(md)
    if args.out is not None:
        args.out.write_text(json.dumps(rows, indent=1))
        args.out.with_suffix(".md").write_text(md + "\n")


if __name__ == "__main__":
    main()
