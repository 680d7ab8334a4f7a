"""Calibrate the significance rule of `granseg diagnose` on null campaigns.

Baseline-only virtual campaigns (no hidden effect) are diagnosed with the
decision thresholds switched off; for each we record the best candidate's
held-out gain in noise-floor units and the baseline's mean RMSD / noise
floor. The thresholds in granseg/diagnosis/selection.py are set above the
largest values seen here, with a margin (see its docstring).

    python benches/calibrate_diagnose.py --seeds 8 [--out benches/results/diagnose_null_calibration.json]

Half the campaigns use the paper's 16 conditions, half 14 random conditions.
Seeds used here (1000 + i) are disjoint from the ones of the confusion-matrix
bench and of the tests.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from granseg.diagnosis import diagnose
from granseg.synth.virtual import campaign, random_conditions


def one(seed: int) -> dict:
    conds = None if seed % 2 == 0 else random_conditions(14, seed)
    maps = campaign(conditions=conds, effect=None, seed=seed)
    t0 = time.perf_counter()
    d = diagnose(maps, gain_threshold=np.inf, excess_threshold=np.inf, progress=False)
    r = d.result["decision"]
    return {"seed": seed, "conditions": "table1" if conds is None else "random14",
            "best": r["best_candidate"], "gain_over_floor": r["gain_over_floor"],
            "baseline_rmsd_over_floor": r["baseline_rmsd_over_floor"],
            "gains": {c["name"]: c["gain_held_out"] for c in d.result["candidates"]},
            "noise_floor": d.result["noise_floor"], "seconds": time.perf_counter() - t0}


def suggest(gains: list[float], excess: list[float]) -> dict:
    """The rule: gain threshold 10 x the largest null gain (at least 0.02 x floor);
    excess threshold 5 % above the largest null baseline RMSD / floor."""
    return {"max_gain_over_floor": max(gains), "max_baseline_rmsd_over_floor": max(excess),
            "suggested_gain_threshold": max(0.02, 10 * max(gains)),
            "suggested_excess_threshold": round(1.05 * max(excess), 2)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--out", default="benches/results/diagnose_null_calibration.json")
    args = ap.parse_args()
    rows = []
    for i in range(args.seeds):
        rows.append(one(1000 + i))
        print(json.dumps(rows[-1]), flush=True)
    g = [r["gain_over_floor"] for r in rows]
    e = [r["baseline_rmsd_over_floor"] for r in rows]
    summary = {"n": len(rows), **suggest(g, e), "runs": rows}
    Path(args.out).write_text(json.dumps(summary, indent=2) + "\n")
    print(json.dumps({k: v for k, v in summary.items() if k != "runs"}, indent=2))


if __name__ == "__main__":
    main()
