"""What the baseline's misfit looks like: residual structure, per-experiment optima, covariates.

These are the clues a researcher reads before naming a cause (the selection
itself is done by cross-validation in :mod:`granseg.diagnosis.selection`):

* residual maps (model - measured) and their mean over experiments in
  normalised time (t / t_end) and in depth (layer);
* the structured part of the misfit: the RMSD left after removing the noise
  floor in quadrature, sqrt(max(RMSD^2 - floor^2, 0)) [-];
* each experiment's own optimal delta/H (k held at the global value) and own
  optimal k (delta/H held), from one-dimensional scans run in one sweep, set
  against the covariates M~ = M_w / M_g, delta_R, c0 and the material pair,
  with Spearman rank correlations;
* the measured depth-mean of c minus c0 while the bed is mixed (the model
  conserves the depth-mean, a wall that over-shows heavy grains does not).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy.stats import spearmanr

from granseg.fitting import Baseline, Data, Fit, model_maps, rmsd

__all__ = ["DELTA_SCAN", "K_SCAN", "Evidence", "gather"]

DELTA_SCAN = np.geomspace(0.07, 0.5, 17)
K_SCAN = np.geomspace(0.3, 1.5, 13)
N_TIME_BINS = 10


class Evidence(dict):
    """A dict of JSON-ready evidence (see :func:`gather`); arrays kept as lists."""


def _scan(data: Data, base: Fit, key: str, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-experiment optimum of ``key`` on a log grid (parabolic refinement) and its RMSD."""
    x0 = base.values()
    runs = [({**x0, key: float(v)}, i) for i in range(data.n) for v in values]
    layers = model_maps(data, Baseline(), runs)
    table = np.array([rmsd(data, i, lay) for (_, i), lay in zip(runs, layers, strict=True)])
    table = table.reshape(data.n, values.size)
    best = np.empty(data.n)
    for i, row in enumerate(table):
        j = int(np.argmin(row))
        best[i] = values[j]
        if 0 < j < values.size - 1:
            u = np.log(values[j - 1:j + 2])
            a, b, _ = np.polyfit(u, row[j - 1:j + 2], 2)
            if a > 0:
                best[i] = float(np.exp(np.clip(-b / (2 * a), u[0], u[2])))
    return best, table.min(axis=1)


def _spearman(x: Sequence[float], y: Sequence[float]) -> float:
    x, y = np.asarray(x, float), np.asarray(y, float)
    if x.size < 3 or np.ptp(x) == 0 or np.ptp(y) == 0:
        return float("nan")
    return float(spearmanr(x, y).statistic)


def _structure(data: Data, base: Fit) -> dict[str, Any]:
    """Mean residual by normalised time bin and by layer, over all experiments (maps of other
    layer counts are interpolated in z/H onto the fewest layers any map has)."""
    n_l = min(m.n_layers for m in data.maps)
    at = (np.arange(n_l) + 0.5) / n_l
    tb = np.zeros(N_TIME_BINS)
    tb_n = np.zeros(N_TIME_BINS)
    layer = np.zeros(n_l)
    layer_n = np.zeros(n_l)
    for i, m in enumerate(data.maps):
        r = base.layers[i] - m.c
        ok = np.isfinite(r)
        bins = np.minimum((m.t / m.t[-1] * N_TIME_BINS).astype(int), N_TIME_BINS - 1)
        for b in range(N_TIME_BINS):
            sel = ok[bins == b]
            tb[b] += np.abs(np.where(sel, r[bins == b], 0)).sum() / max(sel.sum(), 1)
            tb_n[b] += 1
        per_layer = np.nanmean(r, axis=0)
        layer += np.interp(at, (np.arange(m.n_layers) + 0.5) / m.n_layers, per_layer)
        layer_n += 1
    return {"time_bins": ((np.arange(N_TIME_BINS) + 0.5) / N_TIME_BINS).tolist(),
            "mean_abs_residual_by_time": (tb / np.maximum(tb_n, 1)).tolist(),
            "mean_residual_by_layer": (layer / np.maximum(layer_n, 1)).tolist()}


def _depth_mean(data: Data, base: Fit) -> dict[str, list[float]]:
    """Measured depth-mean minus c0, averaged while the model bed is mixed, per experiment."""
    excess, peak = [], []
    for i, m in enumerate(data.maps):
        model = base.layers[i]
        mixing = (4 * model * (1 - model)).mean(axis=1) > 0.3
        read = np.isfinite(m.c).any(axis=1)  # dropped frames have no reading at all
        dm = np.full(m.n_times, np.nan)
        dm[read] = np.nanmean(m.c[read], axis=1) - m.c0
        sel = mixing if mixing.sum() >= 3 else np.ones_like(mixing)
        excess.append(float(np.nanmean(dm[sel])))
        peak.append(float(np.nanmax(np.abs(dm))))
    return {"excess_while_mixed": excess, "max_abs_departure": peak}


def gather(data: Data, base: Fit, floors: Sequence[float]) -> Evidence:
    """Collect the misfit evidence of the baseline fit ``base`` (JSON-ready)."""
    delta_opt, delta_rmsd = _scan(data, base, "delta_over_H", DELTA_SCAN)
    k_opt, k_rmsd = _scan(data, base, "k", K_SCAN)
    exps = data.exps
    cov = {"M_tilde": [e.M_tilde for e in exps], "delta_R": [e.delta_R for e in exps],
           "c0": [e.c0 for e in exps], "pair": [e.pair for e in exps]}
    dm = _depth_mean(data, base)
    structured = [float(np.sqrt(max(r**2 - f**2, 0.0))) for r, f in zip(base.rmsd, floors, strict=True)]
    corr = {f"{what}_vs_{c}": _spearman(vals, cov[c])
            for what, vals in (("delta_opt", delta_opt), ("k_opt", k_opt),
                               ("depth_excess", dm["excess_while_mixed"]))
            for c in ("M_tilde", "delta_R", "c0")}
    return Evidence(
        names=[e.name for e in exps], covariates=cov,
        per_experiment={"delta_over_H_opt": delta_opt.tolist(), "rmsd_at_delta_opt": delta_rmsd.tolist(),
                        "k_opt": k_opt.tolist(), "rmsd_at_k_opt": k_rmsd.tolist()},
        spearman=corr, depth_mean=dm, structure=_structure(data, base),
        structured_misfit=structured,
    )
