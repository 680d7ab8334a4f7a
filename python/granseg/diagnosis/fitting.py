"""Fitting any catalogue extension to a whole campaign, and its cheap leave-one-out.

All model evaluations go through :func:`granseg.sweep`, one call per residual
evaluation, with every experiment *and* every finite-difference point of the
Jacobian in that call (so both cores work). The model is asked for its raw
layer means at the measured times (``smoothing_frames = 1``); the extension's
time shift and observation transform are applied here, then the map's own
moving average (:func:`granseg.maps.moving_average`), so an observation model
acts on what the camera sees frame by frame, before smoothing.

Residuals are weighted by 1 / sqrt(N_i) (N_i = finite entries of experiment
i), so that the sum of squares is the sum of the experiments' mean square
deviations and each experiment counts once, as in the mean RMSD the paper and
the JSON report. Standard errors are cluster-robust (sandwich with the
experiments as clusters): the residuals within a map are correlated by the
moving average and by grains that stay in view, the experiments are not.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import least_squares

from granseg.diagnosis.catalogue import BASE_PARAMS, ExpInfo, Extension, Param
from granseg.maps import Map, moving_average

__all__ = ["Data", "Fit", "fit", "loo_predict", "model_maps"]

#: Weight of the parameter priors, in units of the stacked sum of squares
#: (sum over experiments of MSE): one prior sd costs PRIOR_WEIGHT**2.
PRIOR_WEIGHT = 0.01


@dataclass
class Data:
    """A campaign prepared for fitting: maps, covariates, masks, solver options."""

    maps: list[Map]
    exps: list[ExpInfo]
    masks: list[np.ndarray]
    weights: np.ndarray
    opts: dict[str, Any]
    log: Callable[[str], None] = field(default=lambda msg: None)
    n_runs: int = 0
    n_sweeps: int = 0
    sweep_seconds: float = 0.0

    @classmethod
    def of(cls, maps: Sequence[Map], opts: Mapping[str, Any], log: Callable[[str], None] | None = None) -> Data:
        """Prepare ``maps`` with solver options ``opts`` (n_cells, rtol, atol)."""
        masks = [np.isfinite(m.c) for m in maps]
        weights = np.array([1.0 / math.sqrt(max(int(k.sum()), 1)) for k in masks])
        return cls(list(maps), [ExpInfo.of(m) for m in maps], masks, weights, dict(opts),
                   log or (lambda msg: None))

    @property
    def n(self) -> int:
        """Number of experiments."""
        return len(self.maps)


def _request(ext: Extension, x: Mapping[str, float], exp: ExpInfo, m: Map
             ) -> tuple[dict[str, float], np.ndarray, np.ndarray]:
    """Solver case, output times and index back to the map's times."""
    tm = m.t - ext.time_shift(x, exp)
    positive = tm > 0
    req = tm[positive]
    idx = np.zeros(m.t.size, dtype=np.int64)
    if not positive.all():
        req = np.concatenate([[0.0], req])
        idx[positive] = np.arange(1, req.size)
    else:
        idx[:] = np.arange(req.size)
    return ext.solver_params(x, exp), req, idx


def model_maps(data: Data, ext: Extension, runs: Sequence[tuple[Mapping[str, float], int]]
               ) -> list[np.ndarray]:
    """What each run (parameters, experiment index) shows on its map's grid.

    One ``granseg.sweep`` call for all runs; returns (n_t_i, n_layers) arrays
    after time shift, observation transform and the map's moving average.
    """
    from granseg.model import sweep

    cases, times, back = [], [], []
    for x, i in runs:
        case, req, idx = _request(ext, x, data.exps[i], data.maps[i])
        cases.append(case)
        times.append(req)
        back.append(idx)
    t0 = time.perf_counter()
    res = sweep(cases=cases, t=times, progress=False, **data.opts)
    data.sweep_seconds += time.perf_counter() - t0
    data.n_runs += len(cases)
    data.n_sweeps += 1
    out = []
    for (x, i), raw, idx in zip(runs, res.layers, back, strict=True):
        seen = ext.observe(x, data.exps[i], np.asarray(raw)[idx])
        out.append(moving_average(seen, data.maps[i].smoothing_frames, axis=0))
    return out


def residual(data: Data, i: int, layers: np.ndarray) -> np.ndarray:
    """Weighted model - measured over the finite entries of experiment i."""
    return (layers - data.maps[i].c)[data.masks[i]] * data.weights[i]


def rmsd(data: Data, i: int, layers: np.ndarray) -> float:
    """RMSD [-] of experiment i (MODEL.md definition)."""
    d = (layers - data.maps[i].c)[data.masks[i]]
    return float(np.sqrt(np.mean(d**2)))


@dataclass
class Fit:
    """One extension fitted to a set of experiments.

    ``x`` parameter vector (names ``keys``), ``stderr`` cluster-robust
    standard errors, ``layers[i]`` the model map of experiment i (all
    experiments, also those not fitted), ``rmsd[i]`` its RMSD [-],
    ``G``/``g`` the per-experiment blocks J_i'J_i and J_i'r_i at ``x`` (for
    the leave-one-out step), ``A``/``grad`` their sums plus the prior.
    """

    ext: Extension
    params: list[Param]
    x: np.ndarray
    stderr: np.ndarray
    layers: list[np.ndarray]
    rmsd: np.ndarray
    G: np.ndarray
    g: np.ndarray
    A: np.ndarray
    grad: np.ndarray
    converged: bool
    message: str
    nfev: int
    which: list[int]

    @property
    def keys(self) -> list[str]:
        return [p.name for p in self.params]

    def values(self, x: np.ndarray | None = None) -> dict[str, float]:
        """Parameter dict of ``x`` (default the fit)."""
        return dict(zip(self.keys, map(float, self.x if x is None else x), strict=True))

    def errors(self) -> dict[str, float]:
        return dict(zip(self.keys, map(float, self.stderr), strict=True))

    @property
    def rmsd_mean(self) -> float:
        return float(np.mean(self.rmsd[self.which]))


def _bounds(params: Sequence[Param]) -> tuple[np.ndarray, np.ndarray]:
    return np.array([p.lo for p in params]), np.array([p.hi for p in params])


def _steps(x: np.ndarray, params: Sequence[Param], hi: np.ndarray) -> np.ndarray:
    h = np.array([p.step for p in params])
    return np.where(x + h > hi, -h, h)


def _prior(params: Sequence[Param], x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Prior residual rows and their Jacobian (rows only for parameters with a prior)."""
    rows = [(j, p) for j, p in enumerate(params) if p.prior_sd]
    r = np.array([PRIOR_WEIGHT * (x[j] - p.start) / p.prior_sd for j, p in rows])
    jac = np.zeros((len(rows), len(params)))
    for k, (j, p) in enumerate(rows):
        jac[k, j] = PRIOR_WEIGHT / p.prior_sd
    return r, jac


class _Evaluator:
    """Residuals and forward-difference Jacobian at x, one sweep per new x."""

    def __init__(self, data: Data, ext: Extension, params: list[Param], which: list[int]) -> None:
        self.data, self.ext, self.params, self.which = data, ext, params, which
        self.lo, self.hi = _bounds(params)
        self.keys = [p.name for p in params]
        self._key: bytes | None = None
        self._value: tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]] | None = None

    def __call__(self, x: np.ndarray) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
        """(residual blocks, Jacobian blocks, layers) per fitted experiment at x."""
        key = np.asarray(x, dtype=float).tobytes()
        if key != self._key:
            self._key, self._value = key, self._evaluate(np.asarray(x, dtype=float))
        assert self._value is not None
        return self._value

    def _evaluate(self, x: np.ndarray):
        h = _steps(x, self.params, self.hi)
        pts = [x] + [x + np.eye(x.size)[j] * h[j] for j in range(x.size)]
        dicts = [dict(zip(self.keys, map(float, p), strict=True)) for p in pts]
        runs = [(d, i) for d in dicts for i in self.which]
        layers = model_maps(self.data, self.ext, runs)
        n = len(self.which)
        res, jac, lay0 = [], [], layers[:n]
        for k, i in enumerate(self.which):
            r0 = residual(self.data, i, layers[k])
            cols = [(residual(self.data, i, layers[(j + 1) * n + k]) - r0) / h[j] for j in range(x.size)]
            res.append(r0)
            jac.append(np.column_stack(cols) if cols else np.zeros((r0.size, 0)))
        return res, jac, lay0

    def fun(self, x: np.ndarray) -> np.ndarray:
        res, _, _ = self(x)
        return np.concatenate([*res, _prior(self.params, x)[0]])

    def jac(self, x: np.ndarray) -> np.ndarray:
        _, jac, _ = self(x)
        return np.vstack([*jac, _prior(self.params, x)[1]])


def fit(data: Data, ext: Extension, *, x0: Mapping[str, float] | None = None,
        which: Sequence[int] | None = None, max_nfev: int = 30) -> Fit:
    """Least-squares fit of ``ext`` over experiments ``which`` (default all).

    ``x0`` overrides the parameters' start values (warm start, e.g. from the
    baseline fit). Every experiment gets a model map at the optimum (for the
    held-out ones too, so the caller can score them).
    """
    which = list(range(data.n)) if which is None else list(which)
    params = ext.params(data.exps)
    ev = _Evaluator(data, ext, params, which)
    start = np.array([float((x0 or {}).get(p.name, p.start)) for p in params])
    start = np.clip(start, ev.lo + 1e-9 * (ev.hi - ev.lo), ev.hi - 1e-9 * (ev.hi - ev.lo))
    t0 = time.perf_counter()
    sol = least_squares(ev.fun, start, jac=ev.jac, bounds=(ev.lo, ev.hi), x_scale="jac",
                        max_nfev=max_nfev, xtol=1e-5, ftol=1e-7, gtol=1e-8)
    res, jac, layers = ev(sol.x)
    G = np.stack([j.T @ j for j in jac])
    g = np.stack([j.T @ r for j, r in zip(jac, res, strict=True)])
    pr, pj = _prior(params, sol.x)
    A = G.sum(axis=0) + pj.T @ pj
    grad = g.sum(axis=0) + pj.T @ pr
    stderr = _sandwich(A, g)
    all_layers = _all_layers(data, ext, params, sol.x, which, layers)
    rm = np.array([rmsd(data, i, all_layers[i]) for i in range(data.n)])
    converged = bool(sol.status > 0)
    data.log(f"fit {ext.name}: " + ", ".join(f"{p.name}={v:.4g}" for p, v in zip(params, sol.x, strict=True))
             + f"; mean RMSD {rm[which].mean():.4f} ({sol.nfev} evaluations, {time.perf_counter() - t0:.1f} s)")
    return Fit(ext, params, sol.x, stderr, all_layers, rm, G, g, A, grad, converged,
               str(sol.message), int(sol.nfev), which)


def _all_layers(data: Data, ext: Extension, params: list[Param], x: np.ndarray,
                which: list[int], layers: list[np.ndarray]) -> list[np.ndarray]:
    out: list[np.ndarray | None] = [None] * data.n
    for k, i in enumerate(which):
        out[i] = layers[k]
    missing = [i for i in range(data.n) if out[i] is None]
    if missing:
        d = dict(zip([p.name for p in params], map(float, x), strict=True))
        for i, lay in zip(missing, model_maps(data, ext, [(d, i) for i in missing]), strict=True):
            out[i] = lay
    return out  # type: ignore[return-value]


def _sandwich(A: np.ndarray, g: np.ndarray) -> np.ndarray:
    """Cluster-robust standard errors: A^-1 (sum_i g_i g_i') A^-1, small-sample corrected."""
    n = g.shape[0]
    if A.size == 0:
        return np.zeros(0)
    Ainv = np.linalg.pinv(A)
    B = (g.T @ g) * n / max(n - 1, 1)
    cov = Ainv @ B @ Ainv
    return np.sqrt(np.clip(np.diag(cov), 0.0, None))


def loo_params(f: Fit, i: int, damping: float = 1e-6) -> np.ndarray:
    """Parameters with experiment i left out: one Gauss-Newton step from the full fit.

    Uses the Jacobian blocks stored at the full fit: the training gradient is
    the full gradient minus experiment i's, the normal matrix the full one
    minus J_i'J_i (Levenberg damping ``damping`` x its diagonal).
    """
    k = f.which.index(i)
    A = f.A - f.G[k]
    grad = f.grad - f.g[k]
    A = A + damping * np.diag(np.maximum(np.diag(A), 1e-12))
    step = -np.linalg.lstsq(A, grad, rcond=None)[0]
    lo, hi = _bounds(f.params)
    return np.clip(f.x + step, lo, hi)


def loo_predict(data: Data, f: Fit, *, exact: bool = False, max_nfev: int = 4) -> tuple[np.ndarray, list[np.ndarray], list[np.ndarray]]:
    """Leave-one-experiment-out predictions of the fitted extension.

    Returns (held-out RMSD per experiment [-], held-out model maps, fold
    parameter vectors). The default folds take one Gauss-Newton step from the
    full fit (no extra solver runs) and predict every held-out experiment in
    one sweep; ``exact=True`` refits each fold from there (``max_nfev``
    evaluations), for checking the approximation.
    """
    folds = [loo_params(f, i) for i in f.which]
    if exact:
        folds = [fit(data, f.ext, x0=f.values(x), which=[j for j in f.which if j != i],
                     max_nfev=max_nfev).x for x, i in zip(folds, f.which, strict=True)]
    runs = [(f.values(x), i) for x, i in zip(folds, f.which, strict=True)]
    layers = model_maps(data, f.ext, runs)
    out = np.array([rmsd(data, i, lay) for i, lay in zip(f.which, layers, strict=True)])
    return out, layers, folds


def baseline_keys() -> list[str]:
    """Names of the baseline's fitted parameters."""
    return [p.name for p in BASE_PARAMS]
