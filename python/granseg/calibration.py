"""Calibration of the model's unknowns against a campaign of measured maps.

Two stages, both solved by the Rust sweep (one ``granseg.sweep`` call per
stage or per refinement step, all experiments at once, in parallel):

1. the paper's full factorial design over any model parameters (default
   ``k`` in {0.5, 0.6, 0.7} and ``delta_over_H`` in {0.18, 0.20, 0.22}): the
   RMSD [-] of every experiment for every grid point, printed by
   :meth:`Calibration.table` in the layout of the paper's Table 4;
2. a bounded least-squares refinement (``scipy.optimize.least_squares``)
   from the grid point with the lowest mean RMSD, on the residuals of every
   (time, layer) entry of every experiment stacked together, each experiment's
   weighted by 1 / sqrt(its number of entries) so that every experiment
   counts the same (the sum of squares is the sum of their mean squared
   errors). Each residual evaluation is one sweep over all experiments at the
   trial point *and* at the forward-difference points of the Jacobian, so the
   parallel core sees (n_params + 1) x n_experiments runs at once. Standard
   errors come from the Jacobian at the optimum (see
   :func:`granseg.fit.weighted_covariance`), inflated by the smoothing width
   the maps record (a moving average of n frames leaves about 1/n as many
   independent residuals).

The model map is compared on the measured grid: the layer means at the
measured times, smoothed with the moving average the map records (done in
the Rust core, exactly as ``granseg.sweep(measured=...)`` documents).

Example::

    >>> cal = calibrate("campaign/")                           # doctest: +SKIP
    >>> print(cal.table()); cal.best, cal.stderr               # doctest: +SKIP
"""

from __future__ import annotations

import itertools
import math
import os
import sys
import threading
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import least_squares

from granseg.fit import weighted_covariance
from granseg.maps import Campaign, Map, check_accepted, load_campaign

__all__ = ["DEFAULT_GRID", "Calibration", "CalibrationWarning", "ExperimentOptimum", "calibrate", "check_grid"]

DEFAULT_GRID: dict[str, tuple[float, ...]] = {"k": (0.5, 0.6, 0.7), "delta_over_H": (0.18, 0.20, 0.22)}
FIXED_BY_MAPS = ("rho_h", "rho_l", "c0")


# --------------------------------------------------------------------------- results


@dataclass(frozen=True)
class ExperimentOptimum:
    """One experiment's own optimum: ``best`` and ``stderr`` per parameter, its RMSD [-]."""

    best: dict[str, float]
    stderr: dict[str, float]
    rmsd: float
    converged: bool
    message: str

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        return {"best": self.best, "stderr": self.stderr, "rmsd": self.rmsd,
                "converged": self.converged, "message": self.message}


class CalibrationWarning(UserWarning):
    """The calibration finished, but a result needs care (an optimum on a bound)."""


@dataclass(frozen=True, eq=False)
class Calibration:
    """Result of :func:`calibrate` (RMSD and concentrations are dimensionless).

    ``grid_points[i]`` is a dict of the grid parameters, ``grid_rmsd[i, j]``
    the RMSD of experiment ``names[j]`` at it. ``best``/``stderr`` are the
    refined optimum and its standard errors (the best grid point with NaN
    errors when ``refined`` is False); ``rmsd`` the RMSD of each experiment
    there; ``model_layers[j]`` the model map compared with experiment j at
    the optimum (measured grid, smoothed like the measurement);
    ``at_bound`` the parameters the refinement left on a bound of its range
    (the optimum may lie beyond: widen ``bounds``).
    """

    names: list[str]
    keys: list[str]
    grid_points: list[dict[str, float]]
    grid_rmsd: np.ndarray
    best: dict[str, float]
    stderr: dict[str, float]
    rmsd: dict[str, float]
    refined: bool
    converged: bool
    message: str
    model_layers: list[np.ndarray]
    n_evaluations: int = 0
    elapsed: float = 0.0
    settings: dict[str, Any] = field(default_factory=dict)
    per_experiment: dict[str, ExperimentOptimum] | None = None
    at_bound: list[str] = field(default_factory=list)

    @property
    def grid_mean(self) -> np.ndarray:
        """Mean RMSD over experiments at each grid point, (n_points,)."""
        return self.grid_rmsd.mean(axis=1)

    @property
    def best_grid_index(self) -> int:
        """Index of the grid point with the lowest mean RMSD."""
        return int(np.nanargmin(self.grid_mean))

    @property
    def rmsd_mean(self) -> float:
        """Mean over experiments of the RMSD at the optimum [-]."""
        return float(np.mean(list(self.rmsd.values())))

    def table(self) -> str:
        """The factorial design as text, laid out like the paper's Table 4."""
        return format_table(self.names, self.keys, self.grid_points, self.grid_rmsd)

    def to_json(self) -> dict[str, Any]:
        """The machine-readable result (schema of issue 4, plus run details)."""
        out: dict[str, Any] = {
            "best": dict(self.best), "stderr": dict(self.stderr), "rmsd": dict(self.rmsd),
            "rmsd_mean": self.rmsd_mean,
            "grid": [
                {**p, "rmsd": dict(zip(self.names, map(float, row), strict=True)),
                 "rmsd_mean": float(np.mean(row))}
                for p, row in zip(self.grid_points, self.grid_rmsd, strict=True)
            ],
            "refined": self.refined, "converged": self.converged, "message": self.message,
            "at_bound": list(self.at_bound), "n_evaluations": self.n_evaluations, "elapsed_s": self.elapsed,
            "settings": self.settings,
        }
        if self.per_experiment is not None:
            out["per_experiment"] = {k: v.to_dict() for k, v in self.per_experiment.items()}
        return out


def format_table(names: Sequence[str], keys: Sequence[str], points: Sequence[Mapping[str, float]],
                 rmsd: np.ndarray) -> str:
    """Text table: ID, factor columns, one RMSD column per experiment, mean; '*' marks the minimum."""
    width = max(7, *(len(n) for n in names))
    kw = [max(6, len(k)) for k in keys]
    head1 = " " * 4 + "  ".join(f"{'':>{w}}" for w in kw)
    head1 = f"{'':4}{'Factors':^{len(head1) - 4}}  RMSD"
    head2 = f"{'ID':>4}" + "".join(f"  {k:>{w}}" for k, w in zip(keys, kw, strict=True))
    head2 += "".join(f"  {n:>{width}}" for n in names) + f"  {'mean':>{width}}"
    best = int(np.nanargmin(rmsd.mean(axis=1)))
    lines = [head1, head2, "-" * len(head2)]
    for i, (p, row) in enumerate(zip(points, rmsd, strict=True)):
        mark = "*" if i == best else " "
        line = f"{mark}{i + 1:>3}" + "".join(f"  {p[k]:>{w}.4g}" for k, w in zip(keys, kw, strict=True))
        line += "".join(f"  {v:>{width}.3f}" for v in row) + f"  {np.mean(row):>{width}.3f}"
        lines.append(line)
    lines.append(f"* lowest mean RMSD: run {best + 1}")
    return "\n".join(lines)


# --------------------------------------------------------------------------- inputs


def check_grid(grid: Mapping[str, Any] | None, known: Sequence[str]) -> dict[str, list[float]]:
    """Validate a factorial grid: known parameter names, finite distinct numbers.

    Returns ``{name: [values...]}``. Raises ValueError naming the parameter.
    """
    if grid is None:
        grid = DEFAULT_GRID
    if not isinstance(grid, Mapping) or not grid:
        raise ValueError("grid: expected a non-empty mapping {parameter: [values]}")
    out: dict[str, list[float]] = {}
    for key, values in grid.items():
        if key not in known:
            raise ValueError(f"grid parameter {key!r}: not a model parameter (known: {sorted(known)})")
        if key in FIXED_BY_MAPS:
            raise ValueError(f"grid parameter {key!r}: fixed by each experiment's map, cannot be calibrated")
        out[key] = _grid_values(key, values)
    return out


def _grid_values(key: str, values: Any) -> list[float]:
    arr = np.atleast_1d(np.asarray(values))
    if arr.ndim != 1 or arr.size == 0 or arr.dtype.kind not in "fiu":
        raise ValueError(f"grid parameter {key!r}: expected a non-empty list of numbers, got {values!r}")
    arr = arr.astype(float)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"grid parameter {key!r}: values must be finite, got {arr.tolist()}")
    if np.unique(arr).size != arr.size:
        raise ValueError(f"grid parameter {key!r}: repeated values {arr.tolist()}")
    return arr.tolist()


def _as_maps(campaign: Campaign | Sequence[Map] | str | os.PathLike) -> list[Map]:
    if isinstance(campaign, str | os.PathLike):
        return list(load_campaign(Path(campaign)))
    maps = list(campaign)
    if not maps:
        raise ValueError("calibrate: campaign has no maps")
    names = [m.name for m in maps]
    if len(set(names)) != len(names):
        raise ValueError(f"calibrate: duplicate experiment names in {names}")
    return maps


def _default_bounds(grid: Mapping[str, list[float]]) -> dict[str, tuple[float, float]]:
    """Each parameter within its grid range widened by the range on both sides (> 0)."""
    out = {}
    for key, vals in grid.items():
        lo, hi = min(vals), max(vals)
        span = hi - lo if hi > lo else 0.5 * abs(lo) or 1.0
        out[key] = (max(lo - span, 0.25 * lo if lo > 0 else lo - span), hi + span)
    return out


# --------------------------------------------------------------------------- the engine


class _Engine:
    """Evaluates model-vs-measurement residuals through granseg.sweep, counting runs."""

    def __init__(self, maps: list[Map], base: Mapping[str, Any], opts: Mapping[str, Any],
                 client: Any, log: Callable[[str], None]) -> None:
        self.maps = maps
        self.cases = [{**m.case(), **base} for m in maps]
        self.measured = [m.measured() for m in maps]
        self.masks = [np.isfinite(m.c) for m in maps]
        self.opts = dict(opts)
        self.client = client
        self.log = log
        self.n_sweeps = 0
        self.n_runs = 0
        self._lock = threading.Lock()

    def factorial(self, grid: Mapping[str, list[float]]) -> tuple[list[dict[str, float]], np.ndarray]:
        """RMSD (n_points, n_cases) of the full factorial ``grid`` in one sweep."""
        import granseg

        points = [dict(zip(grid, v, strict=True)) for v in itertools.product(*grid.values())]
        n = len(points) * len(self.cases)
        self.log(f"factorial design: {len(self.cases)} experiments x {len(points)} points = {n} runs")
        t0 = time.perf_counter()
        res = granseg.sweep(grid=dict(grid), cases=self.cases, measured=self.measured,
                            client=self.client, **self.opts)
        self._count(n)
        rmsd = np.asarray(res.rmsd, dtype=float).reshape(len(self.cases), len(points)).T
        self.log(f"factorial design: done in {time.perf_counter() - t0:.1f} s")
        return points, rmsd

    def at_points(self, points: list[dict[str, float]], which: Sequence[int] | None = None
                  ) -> list[list[np.ndarray]]:
        """Model maps of cases ``which`` (default all) at each point: [point][case] arrays."""
        import granseg

        idx = list(range(len(self.cases))) if which is None else list(which)
        cases = [{**self.cases[i], **p} for p in points for i in idx]
        measured = [self.measured[i] for _ in points for i in idx]
        res = granseg.sweep(grid={}, cases=cases, measured=measured, client=self.client, **self.opts)
        self._count(len(cases))
        layers = [np.asarray(a, dtype=float) for a in res.layers]
        return [layers[j * len(idx):(j + 1) * len(idx)] for j in range(len(points))]

    def residuals(self, layers: Sequence[np.ndarray], which: Sequence[int]) -> np.ndarray:
        """Stacked measured - model over the finite entries of cases ``which``, each case
        weighted by 1 / sqrt(its number of entries) (see :meth:`weights`)."""
        parts = [(self.maps[i].c - lay)[self.masks[i]] for i, lay in zip(which, layers, strict=True)]
        return np.concatenate(parts) * self.weights(which)

    def weights(self, which: Sequence[int]) -> np.ndarray:
        """Per stacked entry, 1 / sqrt(entries of its case).

        The sum of squares is then the sum of the cases' mean squared errors:
        every experiment counts the same however long it was filmed, as in the
        factorial design's criterion (the mean of the experiments' RMSD) and
        in the diagnosis. Pooled unweighted, a long experiment dominated: on
        the demo campaign the refinement then ended at a mean RMSD of 0.106
        while the diagnosis's baseline reached 0.099.
        """
        return np.concatenate([np.full(int(self.masks[i].sum()), 1.0 / math.sqrt(max(int(self.masks[i].sum()), 1)))
                               for i in which])

    def _count(self, runs: int) -> None:
        with self._lock:
            self.n_sweeps += 1
            self.n_runs += runs


# --------------------------------------------------------------------------- refinement


@dataclass
class _Fit:
    x: np.ndarray
    cov: np.ndarray
    layers: list[np.ndarray]
    converged: bool
    message: str
    n_eval: int


def _refine(engine: _Engine, which: Sequence[int], x0: np.ndarray, keys: list[str],
            bounds: tuple[np.ndarray, np.ndarray], fd_rel: float, max_nfev: int,
            label: str) -> _Fit:
    """Bounded least squares on the stacked residuals of cases ``which`` from ``x0``."""
    cache: dict[bytes, tuple[np.ndarray, np.ndarray, list[np.ndarray]]] = {}
    lo, hi = bounds

    def evaluate(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
        key = np.asarray(x, dtype=float).tobytes()
        if key not in cache:
            cache.clear()
            steps = _fd_steps(x, lo, hi, fd_rel)
            pts = [x] + [x + np.eye(len(x))[j] * steps[j] for j in range(len(x))]
            t0 = time.perf_counter()
            maps = engine.at_points([dict(zip(keys, map(float, p), strict=True)) for p in pts], which)
            r = [engine.residuals(m, which) for m in maps]
            jac = np.column_stack([(r[j + 1] - r[0]) / steps[j] for j in range(len(x))])
            cache[key] = (r[0], jac, maps[0])
            _log_step(engine, label, keys, x, r[0], len(which), len(pts) * len(which), t0)
        return cache[key]

    res = least_squares(lambda x: evaluate(x)[0], x0, jac=lambda x: evaluate(x)[1],
                        bounds=(lo, hi), x_scale="jac", max_nfev=max_nfev,
                        xtol=1e-6, ftol=1e-8)
    r, jac, layers = evaluate(res.x)
    inflate = _smoothing_factor(engine, which)
    cov = weighted_covariance(jac, r, engine.weights(which), len(keys)) * inflate
    converged = bool(res.success) and res.status > 0
    msg = str(res.message) if converged else f"not converged: {res.message}"
    return _Fit(res.x, cov, layers, converged, msg, int(res.nfev))


def _fd_steps(x: np.ndarray, lo: np.ndarray, hi: np.ndarray, rel: float) -> np.ndarray:
    """Forward-difference steps, turned backward where the forward point leaves the bounds."""
    h = rel * np.maximum(np.abs(x), 1e-2)
    return np.where(x + h > hi, -h, h)


def _smoothing_factor(engine: _Engine, which: Sequence[int]) -> float:
    """Entry-weighted mean smoothing width: variance inflation of the Jacobian errors."""
    w = np.array([engine.masks[i].sum() for i in which], dtype=float)
    n = np.array([engine.maps[i].smoothing_frames for i in which], dtype=float)
    return float((w * n).sum() / w.sum())


def _log_step(engine: _Engine, label: str, keys: list[str], x: np.ndarray, r: np.ndarray,
              n_cases: int, runs: int, t0: float) -> None:
    pars = " ".join(f"{k}={v:.5g}" for k, v in zip(keys, x, strict=True))
    engine.log(f"{label} evaluation {engine.n_sweeps}: {pars} root mean of the experiments' MSE="
               f"{math.sqrt(float(r @ r) / n_cases):.5f} ({runs} runs, {time.perf_counter() - t0:.1f} s)")


def _rmsd_of(engine: _Engine, layers: Sequence[np.ndarray], which: Sequence[int]) -> list[float]:
    return [float(np.sqrt(np.mean((engine.maps[i].c - lay)[engine.masks[i]] ** 2)))
            for i, lay in zip(which, layers, strict=True)]


# --------------------------------------------------------------------------- public entry


def calibrate(
    campaign: Campaign | Sequence[Map] | str | os.PathLike,
    *,
    grid: Mapping[str, Sequence[float]] | None = None,
    refine: bool = True,
    per_experiment: bool = False,
    bounds: Mapping[str, tuple[float, float]] | None = None,
    base: Mapping[str, Any] | None = None,
    n_cells: int | None = None,
    rtol: float | None = None,
    atol: float | None = None,
    fd_rel: float = 5e-3,
    max_nfev: int = 40,
    client: Any = None,
    progress: bool = True,
    accept_flagged: bool = False,
) -> Calibration:
    """Calibrate model parameters against every map of a campaign.

    Parameters
    ----------
    campaign : a campaign directory, a :class:`Campaign` or a list of :class:`Map`.
    grid : ``{parameter: [values]}`` full factorial (default :data:`DEFAULT_GRID`:
        ``k`` [-] and ``delta_over_H`` [-]); any model parameter except those
        each map fixes (rho_h, rho_l, c0).
    refine : run the bounded least-squares refinement from the best grid point.
    per_experiment : also find each experiment's own optimum (with errors).
    bounds : ``{parameter: (lo, hi)}`` for the refinement (default: the grid
        range widened by its width on both sides).
    base : extra model parameters applied to every experiment (SI units).
    n_cells, rtol, atol : solver settings passed to ``granseg.sweep``.
    fd_rel : relative forward-difference step of the Jacobian.
    max_nfev : cap on residual evaluations per refinement (each one sweep).
    client : a ``dask.distributed.Client``; passed to ``granseg.sweep``.
    progress : print a counted line per sweep to stderr.
    accept_flagged : use maps that failed their frame-analysis quality checks
        (refused by default with :class:`granseg.errors.FlaggedMapError`).
    """
    import granseg

    t_start = time.perf_counter()
    maps = _as_maps(campaign)
    check_accepted(maps, accept_flagged)
    grid = check_grid(grid, list(granseg.defaults()))
    keys = list(grid)
    bnds = _bounds_arrays(keys, bounds, grid)
    opts = {k: v for k, v in dict(n_cells=n_cells, rtol=rtol, atol=atol).items() if v is not None}
    log = _printer(progress)
    engine = _Engine(maps, dict(base or {}), opts, client, log)
    points, table = engine.factorial(grid)
    names = [m.name for m in maps]
    everyone = list(range(len(maps)))
    x0 = np.array([points[int(np.nanargmin(table.mean(axis=1)))][k] for k in keys])
    if refine:
        fit = _refine(engine, everyone, np.clip(x0, *bnds), keys, bnds, fd_rel, max_nfev, "refine")
    else:
        fit = _Fit(x0, np.full((len(keys), len(keys)), np.nan),
                   engine.at_points([dict(zip(keys, x0, strict=True))])[0], True, "grid only", 0)
    per = _per_experiment(engine, table, points, keys, bnds, fd_rel, max_nfev) if per_experiment else None
    rmsd = _rmsd_of(engine, fit.layers, everyone)
    settings = {"grid": grid, "bounds": {k: list(map(float, (bnds[0][i], bnds[1][i])))
                                         for i, k in enumerate(keys)},
                "base": dict(base or {}), **opts, "fd_rel": fd_rel, "max_nfev": max_nfev,
                "n_sweeps": engine.n_sweeps, "n_runs": engine.n_runs}
    cal = Calibration(
        names=names, keys=keys, grid_points=points, grid_rmsd=table,
        best=dict(zip(keys, map(float, fit.x), strict=True)),
        stderr={k: float(np.sqrt(fit.cov[i, i])) if np.isfinite(fit.cov[i, i]) else float("nan")
                for i, k in enumerate(keys)},
        rmsd=dict(zip(names, rmsd, strict=True)), refined=refine, converged=fit.converged,
        message=fit.message, model_layers=fit.layers, n_evaluations=fit.n_eval,
        elapsed=time.perf_counter() - t_start, settings=settings, per_experiment=per,
        at_bound=_on_bounds(keys, fit.x, bnds) if refine else [],
    )
    for k in cal.at_bound:
        warnings.warn(f"calibrate: the refined {k} = {cal.best[k]:.4g} lies on a bound of its range "
                      f"{settings['bounds'][k]}; the optimum may lie beyond it (widen bounds=)",
                      CalibrationWarning, stacklevel=2)
    log(f"done: {engine.n_runs} runs in {engine.n_sweeps} sweeps, {cal.elapsed:.1f} s")
    return cal


def _on_bounds(keys: list[str], x: np.ndarray, bounds: tuple[np.ndarray, np.ndarray]) -> list[str]:
    """Parameters within 1e-6 of their range's width from a bound."""
    lo, hi = bounds
    tol = 1e-6 * (hi - lo)
    return [k for i, k in enumerate(keys) if x[i] <= lo[i] + tol[i] or x[i] >= hi[i] - tol[i]]


def _bounds_arrays(keys: list[str], bounds: Mapping[str, tuple[float, float]] | None,
                   grid: Mapping[str, list[float]]) -> tuple[np.ndarray, np.ndarray]:
    b = {**_default_bounds(grid), **dict(bounds or {})}
    unknown = sorted(set(b) - set(keys))
    if unknown:
        raise ValueError(f"bounds: parameter(s) {unknown} are not grid parameters {keys}")
    lo = np.array([float(b[k][0]) for k in keys])
    hi = np.array([float(b[k][1]) for k in keys])
    for k, a, z in zip(keys, lo, hi, strict=True):
        if not (np.isfinite(a) and np.isfinite(z) and a < z):
            raise ValueError(f"bounds of {k!r}: need finite lo < hi, got ({a}, {z})")
    return lo, hi


def _per_experiment(engine: _Engine, table: np.ndarray, points: list[dict[str, float]],
                    keys: list[str], bnds: tuple[np.ndarray, np.ndarray], fd_rel: float,
                    max_nfev: int) -> dict[str, ExperimentOptimum]:
    """Each experiment's own refinement from its own best grid point (threads share the core)."""

    def one(i: int) -> ExperimentOptimum:
        x0 = np.clip([points[int(np.nanargmin(table[:, i]))][k] for k in keys], *bnds)
        fit = _refine(engine, [i], x0, keys, bnds, fd_rel, max_nfev, engine.maps[i].name)
        err = np.sqrt(np.clip(np.diag(fit.cov), 0, None))
        return ExperimentOptimum(
            best=dict(zip(keys, map(float, fit.x), strict=True)),
            stderr=dict(zip(keys, map(float, err), strict=True)),
            rmsd=_rmsd_of(engine, fit.layers, [i])[0], converged=fit.converged, message=fit.message)

    n = len(engine.maps)
    with ThreadPoolExecutor(max_workers=min(4, n)) as pool:
        results = list(pool.map(one, range(n)))
    return {m.name: r for m, r in zip(engine.maps, results, strict=True)}


def _printer(progress: bool) -> Callable[[str], None]:
    if not progress:
        return lambda msg: None
    return lambda msg: print(f"[calibrate] {msg}", file=sys.stderr, flush=True)
