"""Benchmark: `granseg diagnose` on a 16-experiment campaign (budget: < 2 min on 2 cores).

    RAYON_NUM_THREADS=2 python benches/bench_diagnose.py [--repeat 2]

Builds the paper's 16 conditions with the load-dependent shear band hidden
(strength 0.5, seed 1), diagnoses it (all six causes, leave-one-out), and
writes wall time, model runs and the verdict to
benches/results/diagnose_timing.json.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

from granseg.diagnosis import diagnose
from granseg.synth.virtual import campaign

BUDGET_S = 120.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--out", default="benches/results/diagnose_timing.json")
    args = ap.parse_args()
    maps = campaign(effect="load_dependent_shear_band", strength=0.5, seed=1)
    runs = []
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        d = diagnose(maps, progress=False)
        runs.append({"seconds": time.perf_counter() - t0, "cause": d.cause,
                     "model_runs": d.result["settings"]["n_model_runs"],
                     "sweeps": d.result["settings"]["n_sweeps"],
                     "sweep_seconds": d.result["settings"]["sweep_seconds"]})
        print(json.dumps(runs[-1]), flush=True)
    best = min(r["seconds"] for r in runs)
    out = {"experiments": len(maps), "entries": int(sum(m.c.size for m in maps)),
           "threads": os.environ.get("RAYON_NUM_THREADS", "all"), "cpu_count": os.cpu_count(),
           "best_seconds": best, "budget_seconds": BUDGET_S, "within_budget": best < BUDGET_S,
           "runs": runs}
    Path(args.out).write_text(json.dumps(out, indent=2) + "\n")
    print(json.dumps({k: v for k, v in out.items() if k != "runs"}, indent=2))


if __name__ == "__main__":
    main()
