"""Null campaigns under every named noise process: what does the diagnosis call them?

Nothing is hidden in these campaigns, so every verdict other than ``none`` is a
false alarm. Each row records the two misfit tests of the verdict (RMSD over
the counted floor, sign-flip p-value of a pattern shared across experiments),
the best candidate's relative held-out gain and the measured confusion of the
two kinds: the margins to the thresholds of granseg/diagnosis/selection.py.

    RAYON_NUM_THREADS=2 python benches/bench_diagnose_noise.py --seeds 3 \
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
    dec = r["decision"]
    return {"process": process, "seed": seed, "called": r["cause"], "noise_floor": r["noise_floor"],
            "floor_counted": dec["noise_floor_counted"], "baseline_rmsd": r["baseline"]["rmsd_mean"],
            "baseline_over_floor": dec["baseline_rmsd_over_floor"],
            "coherence_p": dec["baseline_misfit"]["coherence_p"],
            "coherence_share": dec["baseline_misfit"]["coherence_share"], "best_gain_relative": dec["gain_relative"],
            "best_candidate": dec["best_candidate"],
            "confusion_applied": {k: round(v["share"], 4) for k, v in (r["noise"]["confusion"] or {}).items()
                                  if v["applied"]},
            "seconds": time.perf_counter() - t0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=1, help="seeds per process (first, first + 1, ...)")
    ap.add_argument("--first-seed", type=int, default=3000,
                    help="3000: the seeds the thresholds were set on; 4000: held out from that")
    ap.add_argument("--json", default=None, help="write the rows here")
    args = ap.parse_args()
    rows = []
    for process in NOISE_PROCESSES:
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            rows.append(one(process, seed))
            print(json.dumps(rows[-1]), flush=True)
    alarms = sum(r["called"] != "none" for r in rows)
    counted = [r["baseline_over_floor"] for r in rows if r["floor_counted"]]
    margins = {"max_baseline_over_counted_floor": max(counted, default=None),
               "min_coherence_p": min(r["coherence_p"] for r in rows),
               "max_coherence_share": max(r["coherence_share"] for r in rows),
               "max_best_gain_relative": max(r["best_gain_relative"] for r in rows)}
    print(f"false alarms: {alarms} / {len(rows)}; {margins}")
    if args.json:
        save_json(args.json, {"rows": rows, "false_alarms": alarms, "n": len(rows), **margins}, force=True)


if __name__ == "__main__":
    main()
