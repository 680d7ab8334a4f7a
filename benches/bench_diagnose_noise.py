"""Null campaigns under every named noise process: what does the diagnosis call them?

Nothing is hidden in these campaigns, so every verdict other than ``none`` is a
false alarm. Issue 11 predicts that persistent grains (and the other processes
of real footage) push the baseline's RMSD above the estimated noise floor.

    RAYON_NUM_THREADS=2 python benches/bench_diagnose_noise.py --seeds 1 \
        --json benches/results/diagnose_noise_null.json
"""

from __future__ import annotations

import argparse
import json
import time

from granseg._io import save_json
from granseg.diagnosis import diagnose
from granseg.synth.virtual import NOISE_PROCESSES, campaign, random_conditions


def one(process: str, seed: int) -> dict:
    t0 = time.perf_counter()
    maps = campaign(conditions=random_conditions(14, seed=seed), noise=process, seed=seed)
    r = diagnose(maps, progress=False).result
    return {"process": process, "seed": seed, "called": r["cause"], "noise_floor": r["noise_floor"],
            "baseline_rmsd": r["baseline"]["rmsd_mean"],
            "baseline_over_floor": r["decision"]["baseline_rmsd_over_floor"],
            "best_gain_over_floor": r["decision"]["gain_over_floor"],
            "best_candidate": r["decision"]["best_candidate"], "seconds": time.perf_counter() - t0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=1, help="seeds per process (3000, 3001, ...)")
    ap.add_argument("--json", default=None, help="write the rows here")
    args = ap.parse_args()
    rows = []
    for process in NOISE_PROCESSES:
        for seed in range(3000, 3000 + args.seeds):
            rows.append(one(process, seed))
            print(json.dumps(rows[-1]), flush=True)
    alarms = sum(r["called"] != "none" for r in rows)
    print(f"false alarms: {alarms} / {len(rows)}")
    if args.json:
        save_json(args.json, {"rows": rows, "false_alarms": alarms, "n": len(rows)}, force=True)


if __name__ == "__main__":
    main()
