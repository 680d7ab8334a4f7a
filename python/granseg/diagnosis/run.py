"""The diagnosis, step by step: calibrate, noise floor, evidence, candidates, held-out verdict.

:func:`diagnose` starts from a :class:`granseg.calibration.Calibration` of
the baseline (made here unless given), so that both report the same
baseline; every candidate is then fitted with the same fitting layer
(:mod:`granseg.fitting`) from the baseline's optimum, and every model,
baseline included, predicts each experiment from the others.
"""

from __future__ import annotations

import math
import os
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from granseg._io import check_writable, save_json
from granseg.calibration import Calibration, as_maps, calibrate
from granseg.diagnosis import selection
from granseg.diagnosis.evidence import Evidence, gather
from granseg.diagnosis.noise import NoiseEstimate, campaign_floor
from granseg.diagnosis.open_world import OpenWorld, explore
from granseg.diagnosis.result import DiagnosisJSON, build_result
from granseg.errors import short_repr
from granseg.fitting import DEFAULT_N_CELLS, Data, Fit, compact, fit, loo_predict
from granseg.fitting import causes as catalogue
from granseg.fitting.threads import one_blas_thread
from granseg.maps import Map, check_accepted

__all__ = ["Diagnosis", "diagnose"]

#: the quality check that says a map's view does not sample the bed fairly, and the law that models it
WINDOW_CHECK = "heavy_share_conserved"
WINDOW_LAW = "law_observation"


@dataclass
class Diagnosis:
    """The outcome of :func:`diagnose`; its JSON (:attr:`result`) is derived from it.

    ``calibration`` the baseline's calibration, ``baseline`` its
    :class:`~granseg.fitting.Fit` and ``fits`` the candidates'; ``held_out``
    and ``held_out_layers`` the leave-one-out RMSDs and maps by model name;
    ``gains`` the held-out gain [-] of each candidate; ``floor`` and ``noise``
    the noise floor [-]; ``thresholds`` the decision thresholds this call used.
    """

    maps: list[Map]
    data: Data
    calibration: Calibration
    baseline: Fit
    fits: dict[str, Fit]
    held_out: dict[str, np.ndarray]
    held_out_layers: dict[str, list[np.ndarray]]
    gains: dict[str, float]
    floor: float
    noise: list[NoiseEstimate]
    evidence: Evidence
    verdict: selection.Verdict
    thresholds: dict[str, float]
    timing: dict[str, float] = field(default_factory=dict)
    report_path: str | None = None
    #: the law corrections tried when the catalogue left a structured misfit (None: not needed or disabled)
    open_world: OpenWorld | None = None
    #: the fitted shear band against the measured one (None: no measurement given)
    velocity_check: dict[str, Any] | None = None
    #: maps whose view failed the window check (their depth-mean heavy share drifts): diagnosed
    #: with the observation law instead of the physics causes
    window_flagged: list[str] = field(default_factory=list)

    @property
    def cause(self) -> str:
        """The named cause: a catalogue name, ``none``, ``new_law`` or ``unexplained``."""
        return self.verdict.cause

    @property
    def explained(self) -> bool:
        return bool(self.verdict.explained)

    @property
    def result(self) -> DiagnosisJSON:
        """The machine-readable diagnosis (the contract of issue 5, :class:`DiagnosisJSON`)."""
        return build_result(self)

    def to_json(self) -> DiagnosisJSON:
        """Same as :attr:`result`."""
        return self.result


def _as_maps(campaign: Any) -> list[Map]:
    maps = as_maps(campaign)
    if len(maps) < 3:
        raise ValueError(f"diagnose: a campaign needs at least 3 experiments for leave-one-out, got {len(maps)}")
    return maps


def _printer(progress: bool) -> Callable[[str], None]:
    if not progress:
        return lambda msg: None
    return lambda msg: print(f"[diagnose] {msg}", file=sys.stderr, flush=True)


#: Accepted range of each decision threshold (lower, upper; both inclusive; an infinite
#: gain threshold accepts no cause, which tests use).
_THRESHOLD_RANGES = {"gain_threshold": (0.0, math.inf), "excess_threshold": (0.0, 100.0),
                     "coherence_alpha": (0.0, 1.0), "coherence_share": (0.0, 1.0)}


def _thresholds(**values: Any) -> tuple[float, ...]:
    """The decision thresholds as floats, each checked against its range (ValueError naming it)."""
    out = []
    for name, v in values.items():
        lo, hi = _THRESHOLD_RANGES[name]
        try:
            f = float(v)
        except (TypeError, ValueError, OverflowError):
            raise ValueError(f"{name} = {short_repr(v)} is not a number") from None
        if isinstance(v, bool) or math.isnan(f) or not lo <= f <= hi:
            raise ValueError(f"{name} = {short_repr(v)} is out of range: must be in [{lo:g}, {hi:g}]")
        out.append(f)
    return tuple(out)


def _check_calibration(cal: Calibration, maps: list[Map]) -> None:
    if not isinstance(cal, Calibration) or cal.fit is None or cal.data is None:
        raise ValueError("calibration: expected the Calibration that granseg.calibrate returned")
    if cal.names != [m.name for m in maps]:
        raise ValueError(f"calibration: made on experiments {cal.names}, not on this campaign's "
                         f"{[m.name for m in maps]}")
    if not cal.refined or set(cal.keys) != {"k", "delta_over_H"}:
        raise ValueError("calibration: the diagnosis starts from a refined calibration of k and delta_over_H")


@one_blas_thread
def diagnose(
    campaign: Any,
    *,
    calibration: Calibration | None = None,
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
    coherence_alpha: float = selection.COHERENCE_ALPHA,
    coherence_share: float = selection.COHERENCE_SHARE,
    progress: bool | str = True,
    accept_flagged: bool = False,
    open_world: bool = True,
    velocity: Any = None,
) -> Diagnosis:
    """Find what the baseline model gets wrong on a campaign, name the cause, measure the gain.

    Parameters
    ----------
    campaign : campaign directory of map ``.npz`` files (docs/formats.md), a
        :class:`granseg.maps.Campaign` or a list of maps (at least 3).
    calibration : the baseline's :func:`granseg.calibrate` result on the same
        maps (default: calibrated here with the same solver settings).
    json : write the JSON contract here (refuses to overwrite unless ``force``).
    report : write the HTML report and figures into this directory.
    causes : catalogue names to consider (default: all of
        :func:`granseg.fitting.causes.names`).
    n_cells : finite-volume cells of the model runs.
    rtol, atol : solver tolerances (default: the core's).
    max_nfev : cap on residual evaluations (one sweep each) per fit.
    gain_threshold, excess_threshold, coherence_alpha, coherence_share : the
        decision thresholds: held-out gain relative to the baseline's held-out
        RMSD, mean RMSD over the counted noise floor, p-value and energy share
        of a residual pattern across experiments (defaults calibrated on null campaigns under every
        named noise process, see :mod:`granseg.diagnosis.selection`).
    progress : log each step to stderr (True: every fit's evaluations too;
        ``"stages"``: a counted line per stage only; False: nothing).
    accept_flagged : use maps that failed their frame-analysis quality checks
        (refused by default with :class:`granseg.errors.FlaggedMapError`).
    open_world : when the catalogue leaves a structured misfit, fit a smooth
        correction of each law of the model (:mod:`granseg.fitting.laws`) and
        name the one that explains it (``new_law``, JSON ``departure``).
    velocity : a shear band measured from footage (a ``granseg velocity`` profile or
        ``velocity-law`` law, path or loaded): the diagnosis still fits delta/H from the maps
        and reports whether the two agree (JSON ``velocity_check``,
        :mod:`granseg.diagnosis.velocity_check`).
    """
    t_start = time.perf_counter()
    gain_threshold, excess_threshold, coherence_alpha, coherence_share = _thresholds(
        gain_threshold=gain_threshold, excess_threshold=excess_threshold, coherence_alpha=coherence_alpha,
        coherence_share=coherence_share)
    check_outputs(json=json, report=report, force=force)
    candidates = catalogue.build(causes)
    log = _printer(progress)
    maps = _as_maps(campaign)
    # a map whose only failed check is the window's is diagnosed: what its view gets wrong is the finding
    window = [m.name for m in maps if WINDOW_CHECK in m.failed_checks]
    check_accepted([m for m in maps if set(m.failed_checks) - {WINDOW_CHECK}], accept_flagged)
    if window:
        log(f"the window check flags {len(window)} of {len(maps)} maps ({', '.join(window)}): their depth-mean "
            "heavy share drifts, which no physics of a closed bed can do; the physics causes are not fitted, "
            "the observation law is")
        candidates = []
    if calibration is None:
        calibration = calibrate(maps, n_cells=n_cells, rtol=rtol, atol=atol, max_nfev=max_nfev,
                                progress=progress is True, accept_flagged=True)
    _check_calibration(calibration, maps)
    data, base = calibration.data, calibration.fit
    assert data is not None and base is not None
    data.log = log if progress != "stages" else (lambda msg: None)  # every fit evaluation, or not
    timing = {"baseline": time.perf_counter() - t_start}
    floor, noise = campaign_floor(maps)
    log(f"{data.n} experiments; noise floor {floor:.4f} (mean over experiments); baseline mean RMSD "
        f"{base.rmsd_mean:.4f}")
    ev = gather(data, base, [e.floor for e in noise])
    fits = {}
    for i, c in enumerate(candidates, 1):
        log(f"candidate {i}/{len(candidates)}: {c.name}")
        fits[c.name] = compact(fit(data, c, x0=base.values(), max_nfev=max_nfev))
    log(f"scoring the baseline and {len(fits)} candidates on experiments they did not see")
    timing["candidates"] = time.perf_counter() - t_start - timing["baseline"]
    held, held_layers = {}, {}
    for name, f in {"baseline": base, **fits}.items():
        held[name], held_layers[name], _ = loo_predict(data, f)
    gains = {n: selection.held_out_gain(held["baseline"], held[n]) for n in fits}
    counted = all(e.counted for e in noise)

    def misfit_of(f: Fit) -> selection.Misfit:
        coh = selection.coherence(maps, data.exps, f.layers, selection.model_jacobians(data, f))
        return selection.misfit(f.rmsd_mean, floor, counted, coh, excess_threshold=excess_threshold,
                                coherence_alpha=coherence_alpha, coherence_share=coherence_share)

    # only the baseline's and the named cause's misfit matter: test those, not every candidate
    verdict = selection.decide(gains, float(np.mean(held["baseline"])), misfit_of(base),
                               lambda name: misfit_of(fits[name]), gain_threshold=gain_threshold)
    ow = None
    if window or (open_world and selection.needs_open_world(verdict)):
        log(f"catalogue verdict: {verdict.cause} (explained: {verdict.explained}); trying the law corrections")
        ow = explore(data, base, held["baseline"], log=log, selected=[WINDOW_LAW] if window else None)
        verdict = selection.extend(verdict, ow.gains, float(np.mean(held["baseline"])),
                                   lambda name: misfit_of(ow.fits[name]), gain_threshold=gain_threshold)
        timing["open_world"] = ow.seconds
    verdict = selection.settle(verdict)
    check = _velocity_check(velocity, base, fits.get("load_dependent_shear_band"), log)
    timing["total"] = time.perf_counter() - t_start
    log(f"verdict: {verdict.cause} ({verdict.reason}); {data.n_runs} model runs in "
        f"{data.n_sweeps} sweeps, {timing['total']:.1f} s")
    diag = Diagnosis(maps, data, calibration, base, fits, held, held_layers, gains, floor, noise, ev, verdict,
                     {"gain": float(gain_threshold), "excess": float(excess_threshold),
                      "coherence_alpha": float(coherence_alpha), "coherence_share": float(coherence_share)},
                     timing, open_world=ow, velocity_check=check, window_flagged=window)
    _write_outputs(diag, json, report, force, log)
    return diag


def _velocity_check(velocity: Any, base: Fit, load_fit: Fit | None, log: Callable[[str], None]
                    ) -> dict[str, Any] | None:
    if velocity is None:
        return None
    from granseg.diagnosis.velocity_check import compare
    from granseg.velocity import ShearBandLaw, VelocityProfile, load_velocity

    v = velocity if isinstance(velocity, (VelocityProfile, ShearBandLaw)) else load_velocity(velocity)
    law = (load_fit.values(), load_fit.errors()) if load_fit is not None else None
    check = compare(v, (base.values(), base.errors()), law)
    for p in check["pairs"]:
        log(f"shear band, maps against footage: {p['parameter']} {p['fitted']:.3f} vs {p['measured']:.3f} "
            f"({'agree' if p['agrees'] else 'disagree'}, z = {p['z'] if p['z'] is None else round(p['z'], 1)})")
    return check


def check_outputs(*, json: str | os.PathLike | None, report: str | os.PathLike | None, force: bool) -> None:
    """Check the JSON file and the report folder can be written, before the work starts: a
    clash found after minutes of fitting loses them (issue 14)."""
    if json is not None:
        check_writable(json, force)
    if report is not None:
        from granseg._io import check_output_dir
        from granseg.report.diagnosis import OUTPUTS

        check_output_dir(report, OUTPUTS, force)


def _write_outputs(diag: Diagnosis, json: Any, report: Any, force: bool, log: Callable[[str], None]) -> None:
    if report is not None:
        from granseg.report.diagnosis import write_report

        diag.report_path = str(write_report(diag, Path(report), force=force))
        log(f"report: {diag.report_path}")
    if json is not None:
        save_json(json, diag.result, force=force)
        log(f"json: {json}")
