"""Confusion matrix and false-alarm rate of `granseg diagnose` on virtual campaigns.

For every catalogue cause (plus the null campaign, ``misclassification``, a
confusion of the two kinds that the diagnosis must measure and not take for
physics, the open world's hidden law departures of granseg.synth.departures,
which must be called ``new_law`` with the right law, and ``camera_sag``, which
no law can produce and must be called ``unexplained``) campaigns are generated with seeded random
strengths (granseg.synth.virtual.random_effect) and seeded random
conditions (14 of the 18 pair x c0 combinations; the paper's 16 conditions for
every third seed), diagnosed, and the named cause tabulated.

    python benches/bench_diagnose_matrix.py --seeds 3 --out benches/results/diagnose_confusion.json
    python benches/bench_diagnose_matrix.py --seeds 1 --noise all --out benches/results/diagnose_matrix_noise.json
    python benches/bench_diagnose_matrix.py --seeds 3 --first-seed 2001 --truths open \
        --noise all --out benches/results/diagnose_open_world.json

``--noise`` repeats the matrix under named measurement-noise processes
(granseg.synth.virtual.NOISE_PROCESSES; ``all`` for every one).

Seeds ``--first-seed`` + i (default 2000, disjoint from the null calibration's).
``--truths open`` stands for the departures and camera_sag. Writes the
JSON results and a Markdown table (same stem, .md).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from granseg.diagnosis import diagnose
from granseg.fitting.causes import names
from granseg.synth import departures
from granseg.synth.virtual import NOISE_PROCESSES, campaign, random_conditions, random_effect

#: hidden departures and the law the diagnosis should name for each
DEPARTURES = {c.name: c.law for c in (departures.FluxAsymmetry, departures.MixingLayer, departures.MixingBurst,
                                      departures.ShearGaussian)}
OPEN = [*DEPARTURES, "camera_sag"]
TRUTHS = ["none", *names(), "misclassification", *OPEN]


def expected(truth: str) -> str:
    """The verdict a right diagnosis gives (``new_law:<law>`` for a departure)."""
    if truth in DEPARTURES:
        return f"new_law:{DEPARTURES[truth]}"
    return {"misclassification": "none", "camera_sag": "unexplained"}.get(truth, truth)


def one(truth: str, seed: int, noise: str = "persistent") -> dict:
    conds = None if seed % 3 == 0 else random_conditions(14, seed)
    strength, extra = (0.0, {}) if truth == "none" else random_effect(truth, seed)
    maps = campaign(conditions=conds, effect=truth, strength=strength, effect_params=extra, seed=seed, noise=noise)
    t0 = time.perf_counter()
    d = diagnose(maps, progress=False)
    r = d.result
    dec = r["decision"]
    dep = r["departure"]
    called = f"new_law:{dep['law']}" if dep else r["cause"]
    return {"truth": truth, "seed": seed, "noise": noise, "strength": strength, "effect_params": extra,
            "conditions": "table1" if conds is None else "random14", "called": called,
            "expected": expected(truth), "right": called == expected(truth),
            "departure": dep and {"correction": dep["correction"], "summary": dep["summary"],
                                  "gain_relative": dep["gain_relative"],
                                  "close_rivals": [x["law"] for x in dep["close_rivals"]],
                                  "literature_form": dep["literature_form"] and dep["literature_form"]["name"]},
            "open_world": r["open_world"] and {x["name"]: x["gain_held_out"] for x in r["open_world"]["laws"]},
            "explained": r["explained"], "gain_held_out": r["gain"]["rmsd_held_out"],
            "gain_relative": dec["gain_relative"], "best_candidate": dec["best_candidate"],
            "baseline_over_floor": dec["baseline_rmsd_over_floor"],
            "coherence_p": dec["baseline_misfit"]["coherence_p"],
            "coherence_share": dec["baseline_misfit"]["coherence_share"],
            "confusion_applied": {k: round(v["share"], 4) for k, v in (r["noise"]["confusion"] or {}).items()
                                  if v["applied"]},
            "runner_up": dec["runner_up"], "seconds": time.perf_counter() - t0}


def table(rows: list[dict]) -> str:
    laws = sorted({v for v in DEPARTURES.values()} | {r["called"][8:] for r in rows if r["called"].startswith("new_law:")})
    called = ["none", *names(), *[f"new_law:{x}" for x in laws], "unexplained"]
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
    ap.add_argument("--truths", nargs="+", default=TRUTHS, choices=[*TRUTHS, "open"])
    ap.add_argument("--first-seed", type=int, default=2000)
    ap.add_argument("--noise", nargs="+", default=["persistent"], choices=["all", *NOISE_PROCESSES])
    ap.add_argument("--out", default="benches/results/diagnose_confusion.json")
    args = ap.parse_args()
    processes = list(NOISE_PROCESSES) if "all" in args.noise else args.noise
    truths = [t for x in args.truths for t in (OPEN if x == "open" else [x])]
    rows = []
    for i in range(args.seeds):
        for noise in processes:
            for t in truths:
                rows.append(one(t, args.first_seed + i, noise))
                print(json.dumps(rows[-1]), flush=True)
    null = [r for r in rows if r["truth"] == "none"]
    hidden = [r for r in rows if r["truth"] in names()]
    confused = [r for r in rows if r["truth"] == "misclassification"]
    summary = {
        "n_runs": len(rows),
        "noise_processes": processes,
        "false_alarm_rate": sum(r["called"] != "none" for r in null) / max(len(null), 1),
        "hidden_effect_accuracy": sum(r["called"] == r["truth"] for r in hidden) / max(len(hidden), 1),
        "hidden_positive_gain": sum(r["gain_held_out"] > 0 for r in hidden) / max(len(hidden), 1),
        "confusion_measured_and_called_none": sum(r["called"] == "none" and bool(r["confusion_applied"])
                                                  for r in confused) / max(len(confused), 1),
        "departures_right_law": sum(r["right"] for r in rows if r["truth"] in DEPARTURES)
                                / max(sum(r["truth"] in DEPARTURES for r in rows), 1),
        "departures_positive_gain": sum(r["gain_held_out"] > 0 for r in rows if r["truth"] in DEPARTURES)
                                    / max(sum(r["truth"] in DEPARTURES for r in rows), 1),
        "camera_sag_unexplained": sum(r["right"] for r in rows if r["truth"] == "camera_sag")
                                  / max(sum(r["truth"] == "camera_sag" for r in rows), 1),
        "accuracy_all": sum(r["right"] for r in rows) / max(len(rows), 1),
        "seconds_max": max((r["seconds"] for r in rows), default=0.0),
        "seconds_mean": sum(r["seconds"] for r in rows) / max(len(rows), 1),
        "runs": rows,
    }
    out = Path(args.out)
    out.write_text(json.dumps(summary, indent=2) + "\n")
    md = table(rows) + "\n\n" + "\n".join(
        f"- {k}: {v:.3g}" if isinstance(v, float | int) else f"- {k}: {v}" for k, v in summary.items() if k != "runs") + "\n"
    out.with_suffix(".md").write_text(md)
    print(md)


if __name__ == "__main__":
    main()
