"""Benchmark: do fit_tanh's 95 % intervals contain the truth 95 % of the time?

    RAYON_NUM_THREADS=1 python benches/bench_fit_coverage.py --reps 100 --first-seed 8100

For each noise process (default ``independent``, ``persistent``,
``variable_counts``) and each replicate seed, one virtual campaign of the
paper's 16 conditions (granseg.synth.virtual.campaign, nothing hidden) gives
16 bottom series, one per condition; every series is fitted with
granseg.fit.fit_tanh and its errors computed three ways from the one
implementation (granseg.fitting.uncertainty):

``classical``
    the old errors: every point independent, s^2 (J'J)^-1 (``errors="jacobian"``);
``blocks``
    the default: time-block cluster sandwich (CR2), blocks of 6 residual correlation lengths;
``12 blocks``
    the same sandwich over 12 equal blocks of the whole span (what
    clip(n / 4 L, 5, 12) gives on these series), to show why the blocks follow
    the correlation length rather than the span.

A replicate is one (seed, condition) series: the 16 conditions of a campaign
draw independent noise, and each is compared with its own truth. The truth
of a condition is fit_tanh on the exact wall view (``campaign(noise=False)``:
no counting, no smoothing, the same for every seed) smoothed by the map's own
moving average (``smoothing_frames``), i.e. the tanh parameters the noisy
maps estimate without noise; the column "vs raw view" uses the unsmoothed
exact view instead (the moving average shifts t0 and tau of the fastest
rises by up to one spread). Reports per process and parameter: coverage
(share of the 16 x reps intervals that contain the truth), SE/spread (per
condition the mean stated error over the seeds' spread of the estimates;
median over conditions), the lowest coverage of one condition, and how the
series that fit_tanh notes as resting on fewer than 1.2 effective blocks do.

Seeds 8000-8049 were used to choose the block rule (``--correlation-lengths``,
``--misfit-window``, ``--cr1`` replay the alternatives); 8100 onwards are held
out (benches/results/fit_coverage.md).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

import granseg.fit
from granseg.fit import fit_tanh
from granseg.maps import moving_average
from granseg.synth.virtual import NOISE_PROCESSES, campaign

NAMES = ("A", "t0", "tau")
METHODS = ("classical", "blocks", "12 blocks")
FLAG = "may be too narrow"


def condition_truths() -> dict[str, dict[str, np.ndarray]]:
    """Per condition: tanh parameters of the exact view, smoothed as the maps are, and raw."""
    exact = campaign(seed=0, noise=False)
    ref = campaign(seed=0, noise="independent")  # only for each condition's smoothing_frames
    out = {}
    for m, r in zip(exact, ref, strict=True):
        sm = fit_tanh(m.t, moving_average(m.bottom, r.smoothing_frames))
        raw = fit_tanh(m.t, m.bottom)
        out[m.name] = {"smoothed": np.array([sm[n] for n in NAMES]), "raw": np.array([raw[n] for n in NAMES])}
    return out


def one(noise: str, seed: int) -> list[dict]:
    rows = []
    for m in campaign(seed=seed, noise=noise):
        t, c = m.t, m.bottom
        span = float(np.nanmax(t) - np.nanmin(t))
        fits = {"blocks": fit_tanh(t, c), "classical": fit_tanh(t, c, errors="jacobian"),
                "12 blocks": fit_tanh(t, c, block_s=span / 12 * (1 + 1e-9))}
        row = {"noise": noise, "seed": seed, "name": m.name,
               "estimate": [fits["blocks"][n] for n in NAMES], "methods": {}}
        for method, f in fits.items():
            u = f.uncertainty
            lo, hi = u.interval
            row["methods"][method] = {"stderr": u.stderr.tolist(), "lo": lo.tolist(), "hi": hi.tolist(),
                                      "dof": u.dof}
        notes = fits["blocks"].uncertainty.notes
        row["flagged"] = [any(FLAG in s and f" {n} " in s for s in notes) for n in NAMES]
        row["blocks_note"] = notes[0]
        rows.append(row)
    return rows


def summary(rows: list[dict], truth: dict) -> dict:
    out: dict = {}
    for noise in dict.fromkeys(r["noise"] for r in rows):
        sel = [r for r in rows if r["noise"] == noise]
        est = np.array([r["estimate"] for r in sel])
        tru = np.array([truth[r["name"]]["smoothed"] for r in sel])
        raw = np.array([truth[r["name"]]["raw"] for r in sel])
        conds = list(dict.fromkeys(r["name"] for r in sel))
        of = {cn: np.array([r["name"] == cn for r in sel]) for cn in conds}
        flagged = np.array([r["flagged"] for r in sel])
        s: dict = {"n_series": len(sel), "n_seeds": len({r["seed"] for r in sel})}
        for method in METHODS:
            lo = np.array([r["methods"][method]["lo"] for r in sel])
            hi = np.array([r["methods"][method]["hi"] for r in sel])
            se = np.array([r["methods"][method]["stderr"] for r in sel])
            hit = (lo <= tru) & (tru <= hi)
            hit_raw = (lo <= raw) & (raw <= hi)
            ratio = np.array([se[k].mean(0) / est[k].std(0, ddof=1) for k in of.values()])
            per_cond = np.array([hit[k].mean(0) for k in of.values()])
            s[method] = {n: {"coverage": float(hit[:, j].mean()), "coverage_raw_view": float(hit_raw[:, j].mean()),
                             "se_over_spread": float(np.median(ratio[:, j])),
                             "lowest_condition": float(per_cond[:, j].min()),
                             "lowest_condition_name": conds[int(np.argmin(per_cond[:, j]))],
                             "flagged_share": float(flagged[:, j].mean()),
                             "coverage_flagged": float(hit[flagged[:, j], j].mean()) if flagged[:, j].any() else None,
                             "coverage_unflagged": float(hit[~flagged[:, j], j].mean())}
                         for j, n in enumerate(NAMES)}
        s["bias_over_spread"] = {n: float(np.median([(est[k, j].mean() - tru[k, j].mean()) / est[k, j].std(ddof=1)
                                                    for k in of.values()])) for j, n in enumerate(NAMES)}
        out[noise] = s
    return out


def pct(v: float | None) -> str:
    return "-" if v is None else f"{100 * v:.0f} %"


def table(summ: dict) -> str:
    lines = ["| noise | param | classical: coverage | blocks: coverage | 12 blocks: coverage "
             "| blocks vs raw view | classical: SE/spread | blocks: SE/spread | 12 blocks: SE/spread "
             "| blocks: lowest condition | flagged: share, coverage | unflagged: coverage | series |",
             "|" + "---|" * 13]
    for noise, s in summ.items():
        for n in NAMES:
            c, b, w = s["classical"][n], s["blocks"][n], s["12 blocks"][n]
            lines.append(
                f"| {noise} | {n} | {pct(c['coverage'])} | {pct(b['coverage'])} | {pct(w['coverage'])} "
                f"| {pct(b['coverage_raw_view'])} | {c['se_over_spread']:.2f} | {b['se_over_spread']:.2f} "
                f"| {w['se_over_spread']:.2f} | {pct(b['lowest_condition'])} ({b['lowest_condition_name']}) "
                f"| {pct(b['flagged_share'])}, {pct(b['coverage_flagged'])} | {pct(b['coverage_unflagged'])} "
                f"| {s['n_series']} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=int, default=100)
    ap.add_argument("--first-seed", type=int, default=8000)
    ap.add_argument("--noise", nargs="+", default=["independent", "persistent", "variable_counts"],
                    choices=list(NOISE_PROCESSES))
    ap.add_argument("--correlation-lengths", type=float, default=granseg.fit.BLOCK_CORRELATION_LENGTHS,
                    help="block length of the 'blocks' errors in residual correlation lengths (tuning)")
    ap.add_argument("--misfit-window", type=float, default=granseg.fit.MISFIT_WINDOW,
                    help="share of the series whose running mean is removed before measuring the correlation "
                         "length (tuning)")
    ap.add_argument("--cr1", action="store_true", help="no leverage correction of the block scores (tuning)")
    ap.add_argument("--out", default=None, help="write rows and summary as JSON here")
    args = ap.parse_args()
    granseg.fit.BLOCK_CORRELATION_LENGTHS = args.correlation_lengths
    granseg.fit.MISFIT_WINDOW = args.misfit_window
    granseg.fit.LEVERAGE_CORRECTED = not args.cr1
    t0 = time.perf_counter()
    truth = condition_truths()
    rows: list[dict] = []
    for noise in args.noise:
        for rep in range(args.reps):
            rows += one(noise, args.first_seed + rep)
        print(f"[{noise}] {args.reps} campaigns, {time.perf_counter() - t0:.0f} s", flush=True)
    summ = summary(rows, truth)
    if args.out:
        out = Path(args.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps({"reps": args.reps, "first_seed": args.first_seed,
                                   "truth": {k: {kk: vv.tolist() for kk, vv in v.items()} for k, v in truth.items()},
                                   "seconds": time.perf_counter() - t0, "summary": summ, "rows": rows}))
    print(table(summ))
    print(f"\nseeds {args.first_seed}-{args.first_seed + args.reps - 1}, blocks of {args.correlation_lengths:g} "
          f"correlation lengths (misfit window {args.misfit_window:g} of the series, "
          f"{'CR1' if args.cr1 else 'CR2'}), {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
