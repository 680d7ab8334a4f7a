"""Benchmark: calibrate the 16-experiment campaign of the paper's Table 1.

The campaign is synthetic but shaped like the real one: the 16 (pair, c0,
M_g) combinations of Table 1, filmed at 1.5 fps (delta_R > 3) or 0.5 fps,
15 layers, binomial counting noise of ``--particles`` grains per layer and
frame, and the moving average of ``--smoothing`` frames the maps record.
The maps come from the model at a known (k, delta/H); the benchmark times
``granseg.calibrate`` (3 x 3 factorial + bounded least-squares refinement)
and checks that the truth is recovered.

    python benches/bench_calibrate.py                 # the BENCHMARKS.md number
    python benches/bench_calibrate.py --n-cells 180 --json bench-out/calibrate.json
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

# loaded before the clock starts, as importing granseg.calibration did before 2026-11-30: the
# fitting layer now imports scipy on its first fit (granseg.fitting), and the figures of
# BENCHMARKS.md time the calibration, not the import
import scipy.optimize  # noqa: F401
import scipy.stats  # noqa: F401

import granseg
from granseg._io import save_json
from granseg.calibration import calibrate
from granseg.maps import Map, moving_average

RHO = {"S": 7800.0, "C": 3500.0, "G": 2450.0, "POM": 1750.0, "PP": 946.0}
NAMES = {"S": "steel", "C": "ceramic", "G": "glass", "POM": "POM", "PP": "PP"}
# Table 1: pair -> {c0: M_g [kg]}
TABLE1 = {
    "S-PP": {0.50: 5.25, 0.75: 7.30, 0.90: 8.54},
    "S-POM": {0.10: 2.83, 0.25: 3.92, 0.50: 5.73, 0.75: 7.55, 0.90: 8.64},
    "C-PP": {0.50: 2.67, 0.75: 3.43, 0.90: 3.89},
    "G-PP": {0.50: 2.04, 0.75: 2.49, 0.90: 2.76},
    "POM-PP": {0.50: 1.62},
    "G-POM": {0.50: 2.52},
}


def experiments() -> list[dict]:
    """The 16 experiments: name, materials, densities [kg/m^3], c0, M_g [kg], fps [1/s]."""
    out = []
    for pair, masses in TABLE1.items():
        heavy, light = pair.split("-")
        for c0, m_g in masses.items():
            fast = RHO[heavy] / RHO[light] > 3.0
            out.append(dict(name=f"{pair}-{round(100 * c0)}", heavy=NAMES[heavy], light=NAMES[light],
                            rho_h=RHO[heavy], rho_l=RHO[light], c0=c0, M_g=m_g,
                            fps=1.5 if fast else 0.5, duration=900.0 if fast else 2700.0))
    return out


def synthetic_campaign(truth: dict, particles: int, smoothing: int, n_cells: int, seed: int) -> list[Map]:
    """Model maps at ``truth`` (one sweep) with binomial counting noise, smoothed."""
    exps = experiments()
    rng = np.random.default_rng(seed)
    maps = []
    for e in exps:
        t = np.arange(0.0, e["duration"] + 1e-9, 1.0 / e["fps"])
        sol = granseg.simulate(rho_h=e["rho_h"], rho_l=e["rho_l"], c0=e["c0"], t=t, n_cells=n_cells, **truth)
        c_true = np.clip(np.asarray(sol.layers()), 0.0, 1.0)
        n = np.full(c_true.shape, particles)
        n_heavy = rng.binomial(n, c_true)
        c_raw = n_heavy / n
        maps.append(Map(c=moving_average(c_raw, smoothing), t=t, z=(np.arange(15) + 0.5) * 6e-3,
                        name=e["name"], heavy=e["heavy"], light=e["light"], rho_h=e["rho_h"],
                        rho_l=e["rho_l"], c0=e["c0"], M_g=e["M_g"], M_w=1.093, n=n, n_heavy=n_heavy,
                        c_raw=c_raw, fps=e["fps"], smoothing_frames=smoothing))
    return maps


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--n-cells", type=int, default=90, help="finite volumes (default 90)")
    p.add_argument("--particles", type=int, default=10, help="grains per layer and frame")
    p.add_argument("--smoothing", type=int, default=5, help="moving-average width in frames")
    p.add_argument("--k", type=float, default=0.65, help="true k")
    p.add_argument("--delta-over-H", type=float, default=0.19, help="true delta/H")
    p.add_argument("--per-experiment", action="store_true", help="also each experiment's optimum")
    p.add_argument("--json", default=None, help="write the calibration JSON + timing here")
    p.add_argument("--force", action="store_true")
    args = p.parse_args(argv)
    truth = {"k": args.k, "delta_over_H": args.delta_over_H}
    t0 = time.perf_counter()
    maps = synthetic_campaign(truth, args.particles, args.smoothing, args.n_cells, seed=2024)
    t_synth = time.perf_counter() - t0
    frames = sum(m.n_times for m in maps)
    print(f"campaign: {len(maps)} experiments, {frames} frames x 15 layers (made in {t_synth:.1f} s)")
    t0 = time.perf_counter()
    cal = calibrate(maps, n_cells=args.n_cells, per_experiment=args.per_experiment)
    wall = time.perf_counter() - t0
    print(cal.table())
    rows = [f"  {k:>13}: true {truth[k]:.4f}  found {cal.best[k]:.4f} +- {cal.stderr[k]:.4f}"
            f"  ({(cal.best[k] - truth[k]) / cal.stderr[k]:+.1f} s.e.)" for k in truth]
    print("\n".join(rows))
    print(f"calibration wall time: {wall:.1f} s ({cal.settings['n_runs']} runs in "
          f"{cal.settings['n_sweeps']} sweeps, {cal.n_evaluations} refinement evaluations, "
          f"n_cells={args.n_cells})")
    if args.json:
        save_json(Path(args.json), {"wall_s": wall, "truth": truth, "n_cells": args.n_cells,
                                    "frames": frames, **cal.to_json()}, force=args.force)
    return 0


if __name__ == "__main__":
    sys.exit(main())
