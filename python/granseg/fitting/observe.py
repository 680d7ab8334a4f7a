"""The observation step, written once: model run -> what the map would show -> residual.

For an effect, a parameter set and one experiment::

    time shift -> model layer means at the measured times -> observation
    transform -> the measured confusion of the two kinds -> the view's
    measured dwell (:mod:`granseg.fitting.dwell`) -> the map's moving
    average -> residual against the map

Every model evaluation of a fit, a factorial table or a leave-one-out
prediction goes through :func:`model_maps`, which puts all its runs (every
experiment, every finite-difference point) into one :func:`granseg.model.sweep`
call so that both cores work. The model is asked for its raw layer means at
the measured times (no smoothing in the core); the observation transform acts
on what the camera sees frame by frame, and only then does the map's own
centred moving average (:func:`granseg.maps.moving_average`) apply.

Residuals are weighted by 1 / sqrt(N_i) (N_i = finite entries of experiment
i), so that the sum of squares is the sum of the experiments' mean squared
errors: every experiment counts once, however long it was filmed, as in the
mean RMSD that the factorial table, the paper and the JSON report.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from granseg import _core
from granseg.fitting.dwell import lagged, survival
from granseg.fitting.effects import Effect, ExpInfo
from granseg.maps import Map
from granseg.model import DIFFERENTIABLE, LAW_KEYS, sweep

__all__ = ["TANGENT_STEP", "DEFAULT_N_CELLS", "Data", "maps_and_jacobians", "model_maps", "residual", "rmsd",
           "shifted_times"]

#: Finite-volume cells of the fits' model runs: 6 per layer of the maps. Against
#: 180 cells the layer means differ by at most 0.0024 and by 0.0005 RMS (steel/PP
#: and glass/PP, 1 h), far below the maps' noise floors of 0.02-0.05.
DEFAULT_N_CELLS = 90
#: Step of the forward difference through the map parameters -> solver parameters (cheap and
#: smooth), relative to each parameter's finite-difference step.
TANGENT_STEP = 1e-4


@dataclass
class Data:
    """A campaign prepared for fitting: maps, covariates, masks, weights, solver options.

    ``fixed`` are model parameters applied to every run (SI units); ``opts``
    the solver settings (n_cells, rtol, atol) and the optional dask
    ``client``. The counters record the work done for the reports.
    """

    maps: list[Map]
    exps: list[ExpInfo]
    masks: list[np.ndarray]
    weights: np.ndarray
    opts: dict[str, Any]
    fixed: dict[str, float] = field(default_factory=dict)
    log: Callable[[str], None] = field(default=lambda msg: None)
    #: measured confusion share of each experiment [-] (:mod:`granseg.fitting.confusion`), None: not measured
    confusion: np.ndarray | None = None
    #: the confusion measurement per material pair (JSON-ready), None: not measured
    confusion_record: dict[str, Any] | None = None
    #: measured width [m] of the view's window that grains cross before they leave it
    #: (:mod:`granseg.fitting.dwell`), None: no dwell modelled
    dwell_width: float | None = None
    #: the dwell measurement (JSON-ready), None: not measured
    dwell_record: dict[str, Any] | None = None
    #: model parameters measured per experiment (e.g. delta/H from a velocity profile); they
    #: override what the fitted effect gives, None: nothing measured
    measured: list[dict[str, float]] | None = None
    #: how fits differentiate the model maps: "sensitivities" (the core's, where a parameter
    #: allows) or "differences" (forward differences only: the reference)
    jacobian: str = "sensitivities"
    n_runs: int = 0
    n_sweeps: int = 0
    sweep_seconds: float = 0.0

    @classmethod
    def of(cls, maps: Sequence[Map], opts: Mapping[str, Any] | None = None,
           fixed: Mapping[str, float] | None = None, log: Callable[[str], None] | None = None) -> Data:
        """Prepare ``maps``; ``opts`` default to :data:`DEFAULT_N_CELLS` and the core's tolerances."""
        masks = [np.isfinite(m.c) for m in maps]
        weights = np.array([1.0 / math.sqrt(max(int(k.sum()), 1)) for k in masks])
        settings = {"n_cells": DEFAULT_N_CELLS, **{k: v for k, v in dict(opts or {}).items() if v is not None}}
        return cls(list(maps), [ExpInfo.of(m) for m in maps], masks, weights, settings,
                   dict(fixed or {}), log or (lambda msg: None))

    @property
    def n(self) -> int:
        """Number of experiments."""
        return len(self.maps)

    @property
    def names(self) -> list[str]:
        """Experiment names, in order."""
        return [m.name for m in self.maps]

    def solver_settings(self) -> dict[str, Any]:
        """The JSON-ready solver settings (no client object)."""
        return {k: v for k, v in self.opts.items() if k != "client"}


def shifted_times(t: np.ndarray, shift: float) -> tuple[np.ndarray, np.ndarray]:
    """Model times for plate times ``t`` [s] when the model's clock starts ``shift`` s late.

    Returns ``(request, index)``: the strictly increasing times to ask the
    solver for (t = 0 added once for every plate time before the start) and,
    for each plate time, the row of the solver's output that it sees.
    """
    tm = np.asarray(t, dtype=float) - shift
    started = tm > 0
    if started.all():
        return tm, np.arange(tm.size)
    request = np.concatenate([[0.0], tm[started]])
    index = np.zeros(tm.size, dtype=np.int64)
    index[started] = np.arange(1, request.size)
    return request, index


def _case(data: Data, effect: Effect, x: Mapping[str, float], i: int) -> dict[str, float]:
    """The solver parameters of run (x, experiment i): fixed, the effect's, then what was measured."""
    return {**data.fixed, **effect.solver_params(x, data.exps[i]), **(data.measured[i] if data.measured else {})}


def _observed(data: Data, effect: Effect, x: Mapping[str, float], i: int, case: Mapping[str, float],
              raw: np.ndarray) -> np.ndarray:
    """What map i shows of the model's layer means ``raw`` at its times (the steps after the solver)."""
    seen = effect.observe(x, data.exps[i], raw)
    if data.confusion is not None and data.confusion[i] > 0:
        seen = data.confusion[i] + (1.0 - 2.0 * data.confusion[i]) * seen
    if data.dwell_width is not None:
        # the run's own shear band sets how long its grains stay in view
        seen = lagged(seen, survival(case, data.maps[i], data.dwell_width))
    # the model's maps are finite: the core's moving average (the NaN-aware one is for measured maps)
    return _core.moving_average(np.ascontiguousarray(seen, dtype=float), data.maps[i].smoothing_frames)


def _solve(data: Data, runs: Sequence[tuple[dict[str, float], np.ndarray]],
           n_layers: Sequence[int], tangents: Sequence[list[dict[str, float]]] | None = None) -> Any:
    """One sweep of (solver parameters, request times) runs, counted on ``data``."""
    t0 = time.perf_counter()
    res = sweep(cases=[c for c, _ in runs], t=[t for _, t in runs], n_layers=list(n_layers), progress=False,
                tangents=None if tangents is None else list(tangents), **data.opts)
    data.sweep_seconds += time.perf_counter() - t0
    data.n_runs += len(runs)
    data.n_sweeps += 1
    return res


def model_maps(data: Data, effect: Effect, runs: Sequence[tuple[Mapping[str, float], int]]
               ) -> list[np.ndarray]:
    """What each run (parameters, experiment index) shows on its map's grid.

    One sweep for all runs; returns (n_t_i, n_layers) arrays after time
    shift, observation transform, confusion, dwell and the map's moving average.
    """
    cases, requests, rows = [], [], []
    for x, i in runs:
        request, index = shifted_times(data.maps[i].t, effect.time_shift(x, data.exps[i]))
        cases.append(_case(data, effect, x, i))
        requests.append(request)
        rows.append(index)
    res = _solve(data, list(zip(cases, requests, strict=True)), [data.maps[i].n_layers for _, i in runs])
    return [_observed(data, effect, x, i, case, np.asarray(raw)[index])
            for (x, i), case, raw, index in zip(runs, cases, res.layers, rows, strict=True)]


def maps_and_jacobians(data: Data, effect: Effect, x: Mapping[str, float], which: Sequence[int],
                       steps: Sequence[float]) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The model maps of experiments ``which`` at ``x`` and their Jacobians, (n_params, n_t, n_layers).

    Column j of experiment i comes from the core's forward sensitivities when
    parameter j reaches the solver only through parameters it differentiates by
    (:data:`granseg.model.DIFFERENTIABLE`, the law knots) and leaves the model's
    clock alone: the direction in solver parameters is a forward difference of
    step :data:`TANGENT_STEP` x ``steps[j]`` through the cheap parameter map, the
    solver's part is exact, and what follows the solver (observation transform,
    confusion, the view's dwell, moving average) is a secant over ``steps[j]``
    of the model map moved along its sensitivity, as all of it was before. The
    secant is kept on purpose: the dwell is steep where the bed barely moves
    (near the lid grains stay in view for hundreds of frames), its exact slope
    there is several times the secant's, and with it the trust region crawled
    (a shear-profile correction reached RMSD 0.106 in 15 evaluations, 0.050
    with the secant; BENCHMARKS.md). Otherwise (a time shift, a density) the
    column is a forward difference of the whole model of step ``steps[j]``
    (signed). ``data.jacobian = "differences"`` forces differences everywhere
    (the reference of the tests and benchmarks). Everything runs in one sweep.
    """
    keys = list(x)
    if data.jacobian not in ("sensitivities", "differences"):
        raise ValueError(f"jacobian = {data.jacobian!r}: choose 'sensitivities' or 'differences'")
    exact = data.jacobian == "sensitivities"
    runs, n_layers, tangents, plans = [], [], [], []
    for i in which:
        exp = data.exps[i]
        case = _case(data, effect, x, i)
        shift = effect.time_shift(x, exp)
        request, index = shifted_times(data.maps[i].t, shift)
        dirs: list[dict[str, float]] = []
        cols: list[tuple[Any, ...]] = []
        for j, key in enumerate(keys):
            # the direction in solver parameters: a small step through the cheap map
            eps = TANGENT_STEP * steps[j]
            moved = _case(data, effect, {**x, key: x[key] + eps}, i)
            tangent = {k: (moved[k] - case[k]) / eps for k in moved if moved[k] != case[k]}
            xp = {**x, key: x[key] + steps[j]}
            if exact and effect.time_shift(xp, exp) == shift and all(k in DIFFERENTIABLE or k in LAW_KEYS
                                                                      for k in tangent):
                cols.append(("chain", len(dirs) if tangent else None, steps[j], xp, _case(data, effect, xp, i)))
                if tangent:
                    dirs.append(tangent)
            else:
                xs = {**x, key: x[key] + steps[j]}
                cols.append(("difference", steps[j], xs, *shifted_times(data.maps[i].t, effect.time_shift(xs, exp))))
        plans.append((i, case, index, cols))
        runs.append((case, request))
        n_layers.append(data.maps[i].n_layers)
        tangents.append(dirs)
    extra = []  # the difference columns' runs, in plan order
    for i, _, _, cols in plans:
        for col in cols:
            if col[0] == "difference":
                extra.append((_case(data, effect, col[2], i), col[3]))
                n_layers.append(data.maps[i].n_layers)
                tangents.append([])
    res = _solve(data, runs + extra, n_layers, tangents)
    maps, jacs = [], []
    k_extra = len(runs)
    for k, (i, case, index, cols) in enumerate(plans):
        raw, sens = np.asarray(res.layers[k]), np.asarray(res.sensitivities[k])
        if index.size != raw.shape[0]:  # a delayed clock: rows repeat (else they are the map's own)
            raw, sens = raw[index], sens[:, index, :]
        seen = _observed(data, effect, x, i, case, raw)
        jac = np.empty((len(cols), *seen.shape))  # column by column, each contiguous
        for j, col in enumerate(cols):
            if col[0] == "chain":
                _, d, eps, xp, cp = col
                moved = raw if d is None else raw + eps * sens[d]
                np.divide(_observed(data, effect, xp, i, cp, moved) - seen, eps, out=jac[j])
            else:
                _, h, xs, _, s_idx = col
                shifted = np.asarray(res.layers[k_extra])[s_idx]
                k_extra += 1
                np.divide(_observed(data, effect, xs, i, _case(data, effect, xs, i), shifted) - seen, h,
                          out=jac[j])
        maps.append(seen)
        jacs.append(jac)
    return maps, jacs


def residual(data: Data, i: int, layers: np.ndarray) -> np.ndarray:
    """Weighted model - measured over the finite entries of experiment i."""
    return (layers - data.maps[i].c)[data.masks[i]] * data.weights[i]


def rmsd(data: Data, i: int, layers: np.ndarray) -> float:
    """RMSD [-] of experiment i (docs/model.md definition)."""
    d = (layers - data.maps[i].c)[data.masks[i]]
    return float(np.sqrt(np.mean(d**2)))
