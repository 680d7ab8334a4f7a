"""Benchmark: fits with the core's forward sensitivities against forward differences, one process.

    RAYON_NUM_THREADS=2 python benches/bench_sensitivities.py [--repeat 2] [--open-world]

Times, with each Jacobian method in turn (alternating, best of ``--repeat``):

* ``calibrate`` of the 16-experiment Table 1 campaign of ``bench_calibrate.py``
  (truth k = 0.65, delta/H = 0.19, seed 2024);
* ``diagnose`` of the 16-experiment virtual campaign with the load-dependent
  shear band hidden (strength 0.5, seed 1: the catalogue explains it);
* with ``--open-world``, ``diagnose`` of the Gaussian shear band (strength 0.35,
  seed 1: nothing in the catalogue explains it, every law correction is fitted).

"differences" is granseg before issue 15's sensitivities: p + 1 runs per
Jacobian. Both methods run in one process on the same campaigns, so the ratio
is what to read; the machine is shared. Writes benches/results/sensitivities.{json,md}.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import time
from pathlib import Path

from granseg.calibration import calibrate
from granseg.diagnosis import diagnose
from granseg.fitting import observe
from granseg.synth.virtual import campaign

HERE = Path(__file__).resolve().parent
METHODS = ("differences", "sensitivities")


def _table1(seed: int = 2024) -> list:
    spec = importlib.util.spec_from_file_location("bench_calibrate", HERE / "bench_calibrate.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.synthetic_campaign({"k": 0.65, "delta_over_H": 0.19}, 10, 5, 90, seed)


_ORIGINAL_OF = observe.Data.of


def _with_method(method: str) -> None:
    """Every Data made from now on differentiates by ``method`` (calibrate and diagnose make theirs)."""

    def make(*args, **kwargs):
        data = _ORIGINAL_OF(*args, **kwargs)
        data.jacobian = method
        return data

    observe.Data.of = staticmethod(make)


def _time_calibrate(maps: list) -> dict:
    t0 = time.perf_counter()
    cal = calibrate(maps)
    return {"seconds": time.perf_counter() - t0, "runs": cal.settings["n_runs"],
            "evaluations": cal.n_evaluations, "k": cal.best["k"], "delta_over_H": cal.best["delta_over_H"],
            "stderr_k": cal.stderr["k"], "stderr_delta_over_H": cal.stderr["delta_over_H"]}


def _time_diagnose(maps: list) -> dict:
    t0 = time.perf_counter()
    d = diagnose(maps, progress=False)
    return {"seconds": time.perf_counter() - t0, "runs": d.result["settings"]["n_model_runs"],
            "sweeps": d.result["settings"]["n_sweeps"], "cause": d.cause, "law": d.verdict.law}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--open-world", action="store_true")
    ap.add_argument("--out", default=str(HERE / "results" / "sensitivities"))
    args = ap.parse_args()
    jobs = {"calibrate 16 (Table 1)": (_time_calibrate, _table1()),
            "diagnose 16 (load-dependent band)": (_time_diagnose,
                                                  campaign(effect="load_dependent_shear_band", strength=0.5,
                                                           seed=1))}
    if args.open_world:
        jobs["diagnose 16 (Gaussian band, open world)"] = (
            _time_diagnose, campaign(effect="shear_gaussian", strength=0.35, seed=1))
    results: dict = {name: {m: [] for m in METHODS} for name in jobs}
    for r in range(args.repeat):
        order = METHODS if r % 2 == 0 else METHODS[::-1]
        for name, (job, maps) in jobs.items():
            for m in order:
                _with_method(m)
                out = job(maps)
                results[name][m].append(out)
                print(json.dumps({"job": name, "method": m, **out}), flush=True)
    summary = {}
    for name, by in results.items():
        best = {m: min(by[m], key=lambda o: o["seconds"]) for m in METHODS}
        summary[name] = {"best": best, "speedup": best["differences"]["seconds"] / best["sensitivities"]["seconds"]}
    meta = {"threads": os.environ.get("RAYON_NUM_THREADS", "all"), "cpu_count": os.cpu_count(),
            "load_average": os.getloadavg(), "repeat": args.repeat}
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps({"meta": meta, "summary": summary, "runs": results},
                                                   indent=2) + "\n")
    lines = ["| job | differences | sensitivities | speed-up | model runs (diff / sens) |", "|---|---|---|---|---|"]
    for name, s in summary.items():
        d, e = s["best"]["differences"], s["best"]["sensitivities"]
        lines.append(f"| {name} | {d['seconds']:.1f} s | {e['seconds']:.1f} s | {s['speedup']:.2f}x "
                     f"| {d['runs']} / {e['runs']} |")
    lines.append("")
    lines.append(f"Best of {args.repeat}, RAYON_NUM_THREADS={meta['threads']}, load average at the end "
                 f"{meta['load_average'][0]:.2f}.")
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
