"""Confusion matrix and false-alarm rate of `granseg diagnose` on virtual campaigns.

For every catalogue cause (plus the null campaign and the out-of-catalogue
``misclassification`` effect) campaigns are generated with seeded random
strengths (granseg.synth.virtual.random_effect) and seeded random
conditions (14 of the 18 pair x c0 combinations; the paper's 16 conditions for
every third seed), diagnosed, and the named cause tabulated.

    python benches/bench_diagnose_matrix.py --seeds 3 --out benches/results/diagnose_confusion.json

Seeds 2000 + i (disjoint from the null calibration's 1000 + i). Writes the
JSON results and a Markdown table (same stem, .md).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from granseg.diagnosis import diagnose
from granseg.fitting.causes import names
from granseg.synth.virtual import campaign, random_conditions, random_effect

TRUTHS = ["none", *names(), "misclassification"]


def one(truth: str, seed: int) -> dict:
    conds = None if seed % 3 == 0 else random_conditions(14, seed)
    strength, extra = (0.0, {}) if truth == "none" else random_effect(truth, seed)
    maps = campaign(conditions=conds, effect=truth, strength=strength, effect_params=extra, seed=seed)
    t0 = time.perf_counter()
    d = diagnose(maps, progress=False)
    r = d.result
    return {"truth": truth, "seed": seed, "strength": strength, "effect_params": extra,
            "conditions": "table1" if conds is None else "random14", "called": r["cause"],
            "explained": r["explained"], "gain_held_out": r["gain"]["rmsd_held_out"],
            "gain_over_floor": r["decision"]["gain_over_floor"],
            "baseline_over_floor": r["decision"]["baseline_rmsd_over_floor"],
            "runner_up": r["decision"]["runner_up"], "seconds": time.perf_counter() - t0}


def table(rows: list[dict]) -> str:
    called = ["none", *names(), "unexplained"]
    head = "| truth \\ called | " + " | ".join(c.replace("_", " ") for c in called) + " | n |"
    lines = [head, "|" + "---|" * (len(called) + 2)]
    for t in TRUTHS:
        sel = [r for r in rows if r["truth"] == t]
        if sel:
            counts = [sum(r["called"] == c for r in sel) for c in called]
            lines.append(f"| {t.replace('_', ' ')} | " + " | ".join(map(str, counts)) + f" | {len(sel)} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--truths", nargs="+", default=TRUTHS, choices=TRUTHS)
    ap.add_argument("--out", default="benches/results/diagnose_confusion.json")
    args = ap.parse_args()
    rows = []
    for i in range(args.seeds):
        for t in args.truths:
            rows.append(one(t, 2000 + i))
            print(json.dumps(rows[-1]), flush=True)
    null = [r for r in rows if r["truth"] == "none"]
    hidden = [r for r in rows if r["truth"] in names()]
    outside = [r for r in rows if r["truth"] == "misclassification"]
    summary = {
        "n_runs": len(rows),
        "false_alarm_rate": sum(r["called"] != "none" for r in null) / max(len(null), 1),
        "hidden_effect_accuracy": sum(r["called"] == r["truth"] for r in hidden) / max(len(hidden), 1),
        "hidden_positive_gain": sum(r["gain_held_out"] > 0 for r in hidden) / max(len(hidden), 1),
        "outside_flagged": sum(r["called"] == "unexplained" or not r["explained"] for r in outside)
        / max(len(outside), 1),
        "seconds_mean": sum(r["seconds"] for r in rows) / max(len(rows), 1),
        "runs": rows,
    }
    out = Path(args.out)
    out.write_text(json.dumps(summary, indent=2) + "\n")
    md = table(rows) + "\n\n" + "\n".join(
        f"- {k}: {v:.3g}" for k, v in summary.items() if k != "runs") + "\n"
    out.with_suffix(".md").write_text(md)
    print(md)


if __name__ == "__main__":
    main()
