"""Benchmark: do calibrate's 95 % intervals contain the truth 95 % of the time?

    RAYON_NUM_THREADS=2 python benches/bench_coverage.py --reps 200 --noise all \\
        --out benches/results/coverage.json

For each noise process of granseg.synth.virtual.NOISE_PROCESSES, ``--reps``
virtual campaigns of the paper's 16 conditions with nothing hidden (k = 0.70,
delta/H = 0.18, seeds ``--first-seed`` + replicate, the same seeds for every
process), each calibrated as a user would (the factorial is the one point
nearest the truth, so every replicate starts alike and the benchmark spends
its time on the refinement). Every error method of the fitting layer
(granseg.fitting.uncertainty) is evaluated on the same fit, so the methods
are compared on the same estimates. Writes per-replicate rows and, per
process, method and parameter: the share of intervals that contain the
truth, the mean estimate's bias in standard errors, and the ratio of the
mean stated error to the estimates' actual spread. Seeds 5000-5099 were used
to choose the method; the reported table uses others (BENCHMARKS.md).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from granseg.calibration import calibrate
from granseg.fitting import intervals
from granseg.fitting.solve import ERROR_METHODS
from granseg.synth.virtual import NOISE_PROCESSES, campaign

TRUTH = {"k": 0.70, "delta_over_H": 0.18}


def one(noise: str, seed: int) -> dict:
    t0 = time.perf_counter()
    maps = campaign(seed=seed, noise=noise, **TRUTH)
    cal = calibrate(maps, grid={k: (v,) for k, v in TRUTH.items()}, progress=False)
    row = {"noise": noise, "seed": seed, "estimate": cal.best, "converged": cal.converged, "methods": {}}
    for method in ERROR_METHODS:
        u = intervals(cal.data, cal.fit, method)
        lo, hi = u.interval
        row["methods"][method] = {n: {"stderr": float(u.stderr[j]), "lo": float(lo[j]), "hi": float(hi[j]),
                                      "covers": bool(lo[j] <= TRUTH[n] <= hi[j])}
                                  for j, n in enumerate(u.names)}
    row["seconds"] = time.perf_counter() - t0
    return row


def summary(rows: list[dict]) -> dict:
    out: dict = {}
    for noise in dict.fromkeys(r["noise"] for r in rows):
        sel = [r for r in rows if r["noise"] == noise]
        out[noise] = {"n": len(sel)}
        for method in ERROR_METHODS:
            out[noise][method] = {}
            for name, true in TRUTH.items():
                x = np.array([r["estimate"][name] for r in sel])
                se = np.array([r["methods"][method][name]["stderr"] for r in sel])
                cover = np.mean([r["methods"][method][name]["covers"] for r in sel])
                out[noise][method][name] = {
                    "coverage": float(cover), "bias_over_se": float((x.mean() - true) / np.mean(se)),
                    "bias_relative": float(x.mean() / true - 1),
                    "stated_over_actual": float(np.mean(se) / x.std(ddof=1)) if len(sel) > 1 else None}
    return out


def table(summ: dict) -> str:
    head = "| noise | method | " + " | ".join(f"{n}: coverage | {n}: bias/SE | {n}: SE/spread" for n in TRUTH) + " | n |"
    lines = [head, "|" + "---|" * (3 + 3 * len(TRUTH))]
    for noise, s in summ.items():
        for method in ERROR_METHODS:
            cells = []
            for n in TRUTH:
                c = s[method][n]
                ratio = "-" if c["stated_over_actual"] is None else f"{c['stated_over_actual']:.2f}"
                cells += [f"{100 * c['coverage']:.0f} %", f"{c['bias_over_se']:+.1f}", ratio]
            lines.append(f"| {noise} | {method} | " + " | ".join(cells) + f" | {s['n']} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=int, default=200)
    ap.add_argument("--first-seed", type=int, default=6000)
    ap.add_argument("--noise", nargs="+", default=["all"], choices=["all", *NOISE_PROCESSES])
    ap.add_argument("--out", default="benches/results/coverage.json")
    args = ap.parse_args()
    processes = list(NOISE_PROCESSES) if "all" in args.noise else args.noise
    rows, t0 = [], time.perf_counter()
    total = len(processes) * args.reps
    for noise in processes:
        for rep in range(args.reps):
            rows.append(one(noise, args.first_seed + rep))
            print(f"[{len(rows)}/{total}] {json.dumps(rows[-1])}", flush=True)
    summ = summary(rows)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(".tmp")
    tmp.write_text(json.dumps({"truth": TRUTH, "reps": args.reps, "first_seed": args.first_seed,
                               "seconds": time.perf_counter() - t0, "summary": summ, "rows": rows}, indent=1))
    tmp.replace(out)
    out.with_suffix(".md").write_text(table(summ) + "\n")
    print(table(summ))


if __name__ == "__main__":
    main()
