"""The diagnosis' JSON contract, as TypedDicts, derived from a :class:`~granseg.diagnosis.run.Diagnosis`.

The contract (issues 5 and 11): ``cause`` (a catalogue name, ``none``,
``new_law`` or ``unexplained``), ``explained``, a one-paragraph ``summary``, the
``noise_floor`` [-], the ``baseline`` and the ``extended`` model (parameters,
standard errors, RMSD in sample and held out, per experiment [-]), the
``gain``, every ``candidate``, the ``decision`` with the thresholds the call
used, the ``evidence`` and the run's ``settings``; the ``departure`` (the law
that departs, its fitted shape with a 95 % band, a sentence, the held-out
gain, a literature form where one fits; null unless ``cause`` is
``new_law``) and the ``open_world`` (every law correction tried, or null when
the catalogue sufficed). Present only when they apply: ``velocity_check``
(the fitted shear band against a measured one), ``window_check`` (maps whose
view fails the depth-mean check) and ``views`` (each run's window check per
view, where its other view lies beside the map: issue 17).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, TypedDict

import numpy as np

from granseg.diagnosis.selection import Misfit
from granseg.fitting import REGISTRY, Fit, laws
from granseg.measure.quality import views_table

if TYPE_CHECKING:
    from granseg.diagnosis.run import Diagnosis

__all__ = ["DiagnosisJSON", "ModelJSON", "build_result"]


class BaselineJSON(TypedDict):
    params: dict[str, float]
    stderr: dict[str, float]
    rmsd: dict[str, float]
    rmsd_mean: float
    rmsd_held_out: dict[str, float]
    rmsd_held_out_mean: float


class ModelJSON(BaselineJSON):
    model: str
    law: str
    converged: bool
    n_evaluations: int


class CandidateJSON(TypedDict):
    name: str
    rmsd_held_out: float
    rmsd: float
    gain_held_out: float
    gain_in_sample: float
    params: dict[str, float]
    stderr: dict[str, float]
    law: str
    description: str


class GainJSON(TypedDict):
    rmsd_in_sample: float
    rmsd_held_out: float
    per_experiment_in_sample: dict[str, float]
    per_experiment_held_out: dict[str, float]


class MisfitJSON(TypedDict):
    rmsd_over_floor: float | None
    coherence_p: float
    coherence_share: float
    structured: bool
    why: str


class DecisionJSON(TypedDict):
    reason: str
    best_candidate: str | None
    runner_up: str | None
    gain_relative: float
    baseline_rmsd_over_floor: float | None
    baseline_misfit: MisfitJSON
    extended_misfit: MisfitJSON | None
    noise_floor_counted: bool
    margin_to_runner_up: float
    gain_threshold: float
    excess_threshold: float
    coherence_alpha: float
    coherence_share: float


class ShapeJSON(TypedDict, total=False):
    variable: str
    x: list[float]
    factor: list[float]
    lo: list[float]
    hi: list[float]
    log_sd: list[float]
    band: str
    time_scale_s: float


class DepartureJSON(TypedDict):
    law: str
    correction: str
    description: str
    summary: str
    shape: ShapeJSON
    params: dict[str, float]
    gain_held_out: float
    gain_relative: float
    literature_form: dict[str, Any] | None
    close_rivals: list[dict[str, Any]]


class DiagnosisJSON(TypedDict, total=False):
    cause: str
    explained: bool
    summary: str
    noise_floor: float
    noise: dict[str, Any]
    baseline: BaselineJSON
    extended: ModelJSON | None
    gain: GainJSON
    candidates: list[CandidateJSON]
    decision: DecisionJSON
    evidence: dict[str, Any]
    departure: DepartureJSON | None
    open_world: dict[str, Any] | None
    velocity_check: dict[str, Any] | None
    window_check: dict[str, Any]
    views: list[dict[str, Any]]
    experiments: list[dict[str, Any]]
    settings: dict[str, Any]
    report: str


def _finite(v: float) -> float | None:
    return float(v) if np.isfinite(v) else None


def _misfit(m: Misfit | None) -> MisfitJSON | None:
    if m is None:
        return None
    return MisfitJSON(rmsd_over_floor=_finite(m.excess), coherence_p=m.coherence_p,
                      coherence_share=m.coherence_share, structured=m.structured,
                      why=m.why)


def _by_name(names: list[str], values: Any) -> dict[str, float]:
    return dict(zip(names, map(float, values), strict=True))


def _model(d: Diagnosis, name: str, f: Fit) -> ModelJSON:
    names = d.data.names
    held = d.open_world.held_out[name] if name not in d.held_out and d.open_world else d.held_out[name]
    return ModelJSON(model=f.effect.name, params=f.values(), stderr=f.errors(),
                     law=f.effect.law(f.values(), f.errors()),
                     rmsd=_by_name(names, f.rmsd), rmsd_mean=f.rmsd_mean,
                     rmsd_held_out=_by_name(names, held), rmsd_held_out_mean=float(np.mean(held)),
                     converged=f.converged, n_evaluations=f.nfev)


def _candidate(d: Diagnosis, name: str, f: Fit) -> CandidateJSON:
    return CandidateJSON(name=name, rmsd_held_out=float(np.mean(d.held_out[name])), rmsd=f.rmsd_mean,
                         gain_held_out=d.gains[name], gain_in_sample=d.baseline.rmsd_mean - f.rmsd_mean,
                         params=f.values(), stderr=f.errors(), law=f.effect.law(f.values(), f.errors()),
                         description=f.effect.description)


def _gain(base: ModelJSON, ext: ModelJSON | None, held_gain: float) -> GainJSON:
    if ext is None:
        return GainJSON(rmsd_in_sample=0.0, rmsd_held_out=0.0, per_experiment_in_sample={},
                        per_experiment_held_out={})
    return GainJSON(rmsd_in_sample=base["rmsd_mean"] - ext["rmsd_mean"], rmsd_held_out=held_gain,
                    per_experiment_in_sample={n: base["rmsd"][n] - ext["rmsd"][n] for n in ext["rmsd"]},
                    per_experiment_held_out={n: base["rmsd_held_out"][n] - ext["rmsd_held_out"][n]
                                             for n in ext["rmsd"]})


def departure(d: Diagnosis) -> DepartureJSON | None:
    """The departing law of a ``new_law`` verdict (None otherwise)."""
    ow, name = d.open_world, d.verdict.law
    if d.verdict.cause != "new_law" or ow is None or name is None:
        return None
    f = ow.fits[name]
    law: laws.LawCorrection = f.effect  # type: ignore[assignment]
    sh, lit = ow.shape(name)
    base = float(np.mean(d.held_out["baseline"]))
    # another law predicting within the gain threshold of the named one: the data do not separate them
    rivals = [{"correction": n, "law": ow.fits[n].effect.law_name, "gain_held_out": g,  # type: ignore[attr-defined]
               "gain_relative": g / base}
              for n, g in ow.gains.items() if n != name and ow.gains[name] - g <= d.thresholds["gain"] * base]
    text = laws.sentence(f, sh)
    if rivals:
        text += (" A correction of " + " or ".join(r["law"].replace("_", " ") for r in rivals)
                 + " predicts almost as well: these data do not tell them apart.")
    return DepartureJSON(law=law.law_name, correction=name, description=law.description,
                         summary=text, shape=sh, params=f.values(),  # type: ignore[typeddict-item]
                         gain_held_out=ow.gains[name], gain_relative=d.verdict.gain_relative,
                         literature_form=lit, close_rivals=rivals)


def _open_world(d: Diagnosis) -> dict[str, Any] | None:
    ow = d.open_world
    if ow is None:
        return None
    return {"time_scale_s": ow.time_scale, "seconds": ow.seconds,
            "laws": [ow.record(n) for n in ow.fits],
            "note": "all corrections fitted; the best in sample scored held out by refitting without each experiment"}


def summary(cause: str, explained: bool, ext: ModelJSON | None, base: BaselineJSON, floor: float, n: int,
            dep: DepartureJSON | None = None, partial: str | None = None, laws_tried: bool = False) -> str:
    """The verdict in one paragraph of plain words."""
    if cause == "new_law" and dep is not None and ext is not None:
        return (f"No catalogued cause explains the misfit; a correction of the {dep['law'].replace('_', ' ')} "
                f"law does. {dep['summary']} It lowers the mean held-out RMSD from "
                f"{base['rmsd_held_out_mean']:.3f} to {ext['rmsd_held_out_mean']:.3f} over {n} experiments "
                f"(noise floor {floor:.3f}) and leaves no structured misfit.")
    if cause == "none":
        return (f"The baseline model explains all {n} experiments within the measurement noise "
                f"(mean RMSD {base['rmsd_mean']:.3f} against a noise floor of {floor:.3f}); "
                f"no candidate cause improves the held-out predictions.")
    if cause == "unexplained" or ext is None:
        helped = (f"{partial.replace('_', ' ')} improves the held-out predictions but leaves a structured "
                  f"misfit" if partial else "none of the catalogued causes improves the held-out predictions "
                  "enough to name it")
        laws_txt = (" Correcting each law of the model in turn does not explain it either." if laws_tried
                    else "")
        return (f"The baseline misses the data beyond the noise (mean RMSD {base['rmsd_mean']:.3f}, "
                f"noise floor {floor:.3f}); {helped}.{laws_txt} The misfit has a cause granseg cannot name.")
    desc = REGISTRY[cause].description.split(":")[0].split(".")[0]
    tail = ("which brings the misfit down to the noise floor" if explained else
            "but a misfit beyond the noise remains")
    # A gain on a baseline already inside the noise may be the candidate fitting this campaign's
    # noise: said loudly rather than hidden (seen on 3 rendered experiments with nothing hidden).
    caveat = (f" The baseline was already within the noise (held-out RMSD {base['rmsd_held_out_mean']:.3f} "
              f"<= floor {floor:.3f}): take this cause as a hint to test with more experiments, not a finding."
              if np.isfinite(floor) and base["rmsd_held_out_mean"] <= floor else "")
    return (f"Cause: {cause.replace('_', ' ')} ({desc.lower()}); fitted law: {ext['law']}. "
            f"It lowers the mean held-out RMSD from {base['rmsd_held_out_mean']:.3f} to "
            f"{ext['rmsd_held_out_mean']:.3f} over {n} experiments (noise floor {floor:.3f}), {tail}.{caveat}")


def build_result(d: Diagnosis) -> DiagnosisJSON:
    """The JSON contract of diagnosis ``d``."""
    v = d.verdict
    full = _model(d, "baseline", d.baseline)
    base = BaselineJSON(**{k: full[k] for k in BaselineJSON.__annotations__})  # type: ignore[typeddict-item]
    ext = _model(d, v.cause, d.fits[v.cause]) if v.cause in d.fits else None
    held_gain = d.gains.get(v.cause, 0.0)
    if v.cause == "new_law" and d.open_world is not None and v.law is not None:
        ext = _model(d, v.law, d.open_world.fits[v.law])
        held_gain = d.open_world.gains[v.law]
    dep = departure(d)
    out = DiagnosisJSON(
        cause=v.cause, explained=v.explained,
        summary=summary(v.cause, v.explained, ext, base, d.floor, d.data.n, dep,
                        partial=v.best if v.cause == "unexplained" and v.extended is not None else None,
                        laws_tried=d.open_world is not None),
        noise_floor=d.floor,
        noise={"per_experiment": {e.name: e.floor for e in d.noise}, "method": d.noise[0].method,
               "confusion": d.data.confusion_record},
        baseline=base, extended=ext, gain=_gain(full, ext, held_gain),
        candidates=[_candidate(d, n, f) for n, f in d.fits.items()],
        decision=DecisionJSON(reason=v.reason, best_candidate=v.best, runner_up=v.runner_up,
                              gain_relative=v.gain_relative,
                              baseline_rmsd_over_floor=_finite(v.baseline.excess),
                              baseline_misfit=_misfit(v.baseline), extended_misfit=_misfit(v.extended),
                              noise_floor_counted=all(e.counted for e in d.noise),
                              margin_to_runner_up=v.margin, gain_threshold=d.thresholds["gain"],
                              excess_threshold=d.thresholds["excess"],
                              coherence_alpha=d.thresholds["coherence_alpha"],
                              coherence_share=d.thresholds["coherence_share"]),
        evidence=dict(d.evidence),
        departure=dep,
        open_world=_open_world(d),
        experiments=[{"name": e.name, "heavy": e.heavy, "light": e.light, "c0": e.c0, "M_g": e.M_g,
                      "M_w": e.M_w, "M_tilde": e.M_tilde, "delta_R": e.delta_R} for e in d.data.exps],
        settings={**d.data.solver_settings(), "errors": {"baseline": d.baseline.error_method,
                                                        "candidates": "cluster"},
                  "n_model_runs": d.data.n_runs, "n_sweeps": d.data.n_sweeps,
                  "sweep_seconds": d.data.sweep_seconds, "elapsed_s": d.timing.get("total")},
    )
    if d.velocity_check is not None:
        out["velocity_check"] = d.velocity_check
    views = views_table(d.maps)
    if views:
        out["views"] = views
    if d.window_flagged:
        out["summary"] = (f"The window check flags {len(d.window_flagged)} of {d.data.n} maps: their depth-mean "
                          "heavy share drifts, which a closed bed cannot do, so the view was examined instead "
                          "of the physics. " + out["summary"].replace("No catalogued cause explains the misfit; ",
                                                                      "", 1))
        out["window_check"] = {
            "flagged": list(d.window_flagged), "check": "heavy_share_conserved",
            "meaning": "the depth-mean heavy share of these maps drifts beyond their counting noise: the view "
                       "does not sample the bed fairly, so the physics causes were not fitted and the "
                       "observation law was"}
    if d.report_path is not None:
        out["report"] = d.report_path
    return out
