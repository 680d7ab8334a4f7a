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

from granseg.fitting.dwell import lagged, survival
from granseg.fitting.effects import Effect, ExpInfo
from granseg.maps import Map, moving_average
from granseg.model import sweep

__all__ = ["DEFAULT_N_CELLS", "Data", "model_maps", "residual", "rmsd", "shifted_times"]

#: Finite-volume cells of the fits' model runs: 6 per layer of the maps. Against
#: 180 cells the layer means differ by at most 0.0024 and by 0.0005 RMS (steel/PP
#: and glass/PP, 1 h), far below the maps' noise floors of 0.02-0.05.
DEFAULT_N_CELLS = 90


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


def model_maps(data: Data, effect: Effect, runs: Sequence[tuple[Mapping[str, float], int]]
               ) -> list[np.ndarray]:
    """What each run (parameters, experiment index) shows on its map's grid.

    One sweep for all runs; returns (n_t_i, n_layers) arrays after time
    shift, observation transform, confusion, dwell and the map's moving average.
    """
    cases, times, rows = [], [], []
    for x, i in runs:
        exp = data.exps[i]
        request, index = shifted_times(data.maps[i].t, effect.time_shift(x, exp))
        cases.append({**data.fixed, **effect.solver_params(x, exp), **(data.measured[i] if data.measured else {})})
        times.append(request)
        rows.append(index)
    t0 = time.perf_counter()
    res = sweep(cases=cases, t=times, n_layers=[data.maps[i].n_layers for _, i in runs], progress=False,
                **data.opts)
    data.sweep_seconds += time.perf_counter() - t0
    data.n_runs += len(cases)
    data.n_sweeps += 1
    out = []
    for (x, i), case, raw, index in zip(runs, cases, res.layers, rows, strict=True):
        seen = effect.observe(x, data.exps[i], np.asarray(raw)[index])
        if data.confusion is not None and data.confusion[i] > 0:
            seen = data.confusion[i] + (1.0 - 2.0 * data.confusion[i]) * seen
        if data.dwell_width is not None:
            # the run's own shear band sets how long its grains stay in view
            seen = lagged(seen, survival(case, data.maps[i], data.dwell_width))
        out.append(moving_average(seen, data.maps[i].smoothing_frames, axis=0))
    return out


def residual(data: Data, i: int, layers: np.ndarray) -> np.ndarray:
    """Weighted model - measured over the finite entries of experiment i."""
    return (layers - data.maps[i].c)[data.masks[i]] * data.weights[i]


def rmsd(data: Data, i: int, layers: np.ndarray) -> float:
    """RMSD [-] of experiment i (docs/model.md definition)."""
    d = (layers - data.maps[i].c)[data.masks[i]]
    return float(np.sqrt(np.mean(d**2)))
