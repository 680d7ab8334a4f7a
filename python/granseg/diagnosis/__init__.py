"""What the model gets wrong, why, and how much a better model gains.

``diagnose(campaign)`` takes a campaign of measured maps (a directory, a
:class:`granseg.maps.Campaign` or a list of maps) and

1. calibrates the baseline's global ``k`` [-] and ``delta/H`` [-] (the 3 x 3
   factorial of the calibration, then least squares on every map at once);
2. estimates the measurement-noise floor [-] from the maps' own counts and
   frame-to-frame scatter (:mod:`granseg.diagnosis.noise`);
3. gathers the misfit evidence (:mod:`granseg.diagnosis.evidence`);
4. fits every cause of the catalogue (:mod:`granseg.diagnosis.catalogue`) and
   compares them by leave-one-experiment-out prediction, with a significance
   rule calibrated on null campaigns (:mod:`granseg.diagnosis.selection`);
5. names the cause (a catalogue name, ``none`` or ``unexplained``) with the
   fitted extension, its uncertainty and the gain in and out of sample;
6. optionally writes the JSON contract and an HTML report with the evidence
   figures (:mod:`granseg.diagnosis.report`).

Example::

    >>> d = granseg.diagnose("campaign/", json="diagnosis.json", report="diag/")  # doctest: +SKIP
    >>> d.cause, d.result["gain"]                                                 # doctest: +SKIP
    ('load_dependent_shear_band', {'rmsd_in_sample': 0.021, 'rmsd_held_out': 0.019})
"""

from __future__ import annotations

import itertools
import os
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from granseg.diagnosis import catalogue, selection
from granseg.diagnosis.catalogue import CATALOGUE, Baseline
from granseg.diagnosis.evidence import Evidence, gather
from granseg.diagnosis.fitting import Data, Fit, fit, loo_predict, model_maps, rmsd
from granseg.diagnosis.noise import NoiseEstimate, campaign_floor
from granseg.maps import check_accepted

__all__ = ["CATALOGUE", "Diagnosis", "diagnose"]

DEFAULT_N_CELLS = 72
START_GRID = {"k": (0.5, 0.6, 0.7, 0.85), "delta_over_H": (0.14, 0.18, 0.22, 0.27)}


@dataclass
class Diagnosis:
    """The outcome of :func:`diagnose`.

    ``result`` is the JSON contract (see :meth:`to_json`); the other fields
    keep the arrays the report draws: ``maps``, the baseline and candidate
    :class:`~granseg.diagnosis.fitting.Fit` objects, held-out RMSDs and maps,
    the noise estimates and the evidence.
    """

    result: dict[str, Any]
    maps: list[Any]
    baseline: Fit
    fits: dict[str, Fit]
    held_out: dict[str, np.ndarray]
    held_out_layers: dict[str, list[np.ndarray]]
    noise: list[NoiseEstimate]
    evidence: Evidence
    verdict: selection.Verdict
    timing: dict[str, float] = field(default_factory=dict)

    @property
    def cause(self) -> str:
        """The named cause: a catalogue name, ``none`` or ``unexplained``."""
        return self.result["cause"]

    @property
    def explained(self) -> bool:
        return bool(self.result["explained"])

    def to_json(self) -> dict[str, Any]:
        """The machine-readable diagnosis (the contract of issue 5)."""
        return self.result


def _as_maps(campaign: Any) -> list[Any]:
    from granseg.maps import load_campaign

    if isinstance(campaign, str | os.PathLike):
        maps = list(load_campaign(Path(campaign)))
    else:
        maps = list(campaign)
    if len(maps) < 3:
        raise ValueError(f"diagnose: a campaign needs at least 3 experiments for leave-one-out, got {len(maps)}")
    names = [m.name for m in maps]
    if len(set(names)) != len(names):
        raise ValueError(f"diagnose: duplicate experiment names in {names}")
    return maps


def _start(data: Data) -> dict[str, float]:
    """Best point of a small (k, delta/H) factorial, all experiments in one sweep."""
    pts = [dict(zip(START_GRID, v, strict=True)) for v in itertools.product(*START_GRID.values())]
    runs = [(p, i) for p in pts for i in range(data.n)]
    layers = model_maps(data, Baseline(), runs)
    score = np.array([rmsd(data, i, lay) for (_, i), lay in zip(runs, layers, strict=True)])
    return pts[int(np.argmin(score.reshape(len(pts), data.n).mean(axis=1)))]


def _printer(progress: bool) -> Callable[[str], None]:
    if not progress:
        return lambda msg: None
    return lambda msg: print(f"[diagnose] {msg}", file=sys.stderr, flush=True)


def diagnose(
    campaign: Any,
    *,
    json: str | os.PathLike | None = None,
    report: str | os.PathLike | None = None,
    force: bool = False,
    causes: Sequence[str] | None = None,
    n_cells: int = DEFAULT_N_CELLS,
    rtol: float | None = None,
    atol: float | None = None,
    max_nfev: int = 25,
    gain_threshold: float = selection.GAIN_THRESHOLD,
    excess_threshold: float = selection.EXCESS_THRESHOLD,
    progress: bool = True,
    accept_flagged: bool = False,
) -> Diagnosis:
    """Find what the baseline model gets wrong on a campaign, name the cause, measure the gain.

    Parameters
    ----------
    campaign : campaign directory of map ``.npz`` files (DATA.md), a
        :class:`granseg.maps.Campaign` or a list of maps (at least 3).
    json : write the JSON contract here (refuses to overwrite unless ``force``).
    report : write the HTML report and figures into this directory.
    causes : catalogue names to consider (default: all six).
    n_cells : finite-volume cells of the model runs (coarse is enough: the
        maps have 15 layers).
    rtol, atol : solver tolerances (default: the core's).
    max_nfev : cap on residual evaluations (one sweep each) per fit.
    gain_threshold, excess_threshold : the decision thresholds in units of the
        noise floor (defaults calibrated on null campaigns, see
        :mod:`granseg.diagnosis.selection`).
    progress : log each step to stderr.
    accept_flagged : use maps that failed their frame-analysis quality checks
        (refused by default with :class:`granseg.errors.FlaggedMapError`).

    Returns a :class:`Diagnosis`; ``Diagnosis.result`` is the JSON contract.
    """
    from granseg._io import check_writable

    t_start = time.perf_counter()
    if json is not None:
        check_writable(json, force)
    exts = catalogue.build(causes)
    log = _printer(progress)
    maps = _as_maps(campaign)
    check_accepted(maps, accept_flagged)
    opts = {k: v for k, v in dict(n_cells=n_cells, rtol=rtol, atol=atol).items() if v is not None}
    data = Data.of(maps, opts, log)
    timing: dict[str, float] = {}

    floor, noise = campaign_floor(maps)
    log(f"{data.n} experiments; noise floor {floor:.4f} (mean over experiments)")
    start = _start(data)
    base = fit(data, Baseline(), x0=start, max_nfev=max_nfev)
    timing["baseline"] = time.perf_counter() - t_start
    ev = gather(data, base, [e.floor for e in noise])
    fits = {e.name: fit(data, e, x0=base.values(), max_nfev=max_nfev) for e in exts}
    timing["candidates"] = time.perf_counter() - t_start - timing["baseline"]
    held, held_layers = {}, {}
    for name, f in {"baseline": base, **fits}.items():
        held[name], held_layers[name], _ = loo_predict(data, f)
    gains = {n: selection.held_out_gain(held["baseline"], held[n]) for n in fits}
    verdict = selection.decide(gains, floor, base.rmsd_mean, {n: f.rmsd_mean for n, f in fits.items()},
                               gain_threshold=gain_threshold, excess_threshold=excess_threshold)
    timing["total"] = time.perf_counter() - t_start
    log(f"verdict: {verdict.cause} ({verdict.reason}); {data.n_runs} model runs in "
        f"{data.n_sweeps} sweeps, {timing['total']:.1f} s")
    result = _result(data, floor, noise, base, fits, held, gains, verdict, ev, timing)
    diag = Diagnosis(result, maps, base, fits, held, held_layers, noise, ev, verdict, timing)
    _write_outputs(diag, json, report, force, log)
    return diag


def _write_outputs(diag: Diagnosis, json: Any, report: Any, force: bool, log: Callable[[str], None]) -> None:
    from granseg._io import save_json

    if report is not None:
        from granseg.diagnosis.report import write_report

        index = write_report(diag, Path(report), force=force)
        diag.result["report"] = str(index)
        log(f"report: {index}")
    if json is not None:
        save_json(json, diag.result, force=force)
        log(f"json: {json}")


# --------------------------------------------------------------------------- the JSON


def _model_entry(data: Data, f: Fit, held: np.ndarray) -> dict[str, Any]:
    names = [e.name for e in data.exps]
    return {
        "model": f.ext.name,
        "params": f.values(), "stderr": f.errors(), "law": f.ext.law(f.values(), f.errors()),
        "rmsd": dict(zip(names, map(float, f.rmsd), strict=True)), "rmsd_mean": f.rmsd_mean,
        "rmsd_held_out": dict(zip(names, map(float, held), strict=True)),
        "rmsd_held_out_mean": float(np.mean(held)),
        "converged": f.converged, "n_evaluations": f.nfev,
    }


def _summary(v: selection.Verdict, ext: dict[str, Any] | None, base: dict[str, Any], floor: float,
             n: int) -> str:
    if v.cause == "none":
        return (f"The baseline model explains all {n} experiments within the measurement noise "
                f"(mean RMSD {base['rmsd_mean']:.3f} against a noise floor of {floor:.3f}); "
                f"no candidate cause improves the held-out predictions.")
    if v.cause == "unexplained":
        return (f"The baseline misses the data beyond the noise (mean RMSD {base['rmsd_mean']:.3f}, "
                f"noise floor {floor:.3f}), but none of the catalogued causes improves the held-out "
                f"predictions enough to name it; the misfit has a cause outside the catalogue.")
    assert ext is not None
    desc = CATALOGUE[v.cause].description.split(":")[0].split(".")[0]
    tail = ("which brings the misfit down to the noise floor" if v.explained else
            "but a misfit beyond the noise remains")
    return (f"Cause: {v.cause.replace('_', ' ')} ({desc.lower()}); fitted law: {ext['law']}. "
            f"It lowers the mean held-out RMSD from {base['rmsd_held_out_mean']:.3f} to "
            f"{ext['rmsd_held_out_mean']:.3f} over {n} experiments (noise floor {floor:.3f}), {tail}.")


def _result(data: Data, floor: float, noise: list[NoiseEstimate], base: Fit, fits: Mapping[str, Fit],
            held: Mapping[str, np.ndarray], gains: Mapping[str, float], v: selection.Verdict,
            ev: Evidence, timing: Mapping[str, float]) -> dict[str, Any]:
    b = _model_entry(data, base, held["baseline"])
    baseline = {"params": b["params"], "stderr": b["stderr"], "rmsd": b["rmsd"], "rmsd_mean": b["rmsd_mean"],
                "rmsd_held_out": b["rmsd_held_out"], "rmsd_held_out_mean": b["rmsd_held_out_mean"]}
    cands = []
    for name, f in fits.items():
        e = _model_entry(data, f, held[name])
        cands.append({"name": name, "rmsd_held_out": e["rmsd_held_out_mean"], "rmsd": e["rmsd_mean"],
                      "gain_held_out": gains[name], "gain_in_sample": base.rmsd_mean - f.rmsd_mean,
                      "params": e["params"], "stderr": e["stderr"], "law": e["law"],
                      "description": f.ext.description})
    ext = None
    gain = {"rmsd_in_sample": 0.0, "rmsd_held_out": 0.0, "per_experiment_in_sample": {},
            "per_experiment_held_out": {}}
    if v.cause in fits:
        ext = _model_entry(data, fits[v.cause], held[v.cause])
        names = list(ext["rmsd"])
        gain = {"rmsd_in_sample": base.rmsd_mean - fits[v.cause].rmsd_mean,
                "rmsd_held_out": gains[v.cause],
                "per_experiment_in_sample": {n: b["rmsd"][n] - ext["rmsd"][n] for n in names},
                "per_experiment_held_out": {n: b["rmsd_held_out"][n] - ext["rmsd_held_out"][n] for n in names}}
    return {
        "cause": v.cause, "explained": v.explained,
        "summary": _summary(v, ext, b, floor, data.n),
        "noise_floor": floor,
        "noise": {"per_experiment": {e.name: e.floor for e in noise}, "method": noise[0].method},
        "baseline": baseline, "extended": ext, "gain": gain, "candidates": cands,
        "decision": {"reason": v.reason, "best_candidate": v.best, "runner_up": v.runner_up,
                     "gain_over_floor": v.gain_ratio, "baseline_rmsd_over_floor": v.excess_ratio,
                     "margin_to_runner_up": v.margin,
                     "gain_threshold": selection.GAIN_THRESHOLD if v else None,
                     "excess_threshold": selection.EXCESS_THRESHOLD},
        "evidence": dict(ev),
        "experiments": [{"name": e.name, "heavy": e.heavy, "light": e.light, "c0": e.c0, "M_g": e.M_g,
                         "M_w": e.M_w, "M_tilde": e.M_tilde, "delta_R": e.delta_R} for e in data.exps],
        "settings": {**data.opts, "n_model_runs": data.n_runs, "n_sweeps": data.n_sweeps,
                     "sweep_seconds": data.sweep_seconds, "elapsed_s": timing.get("total")},
    }
