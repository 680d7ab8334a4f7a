"""Calibration of the model's unknowns against a campaign of measured maps.

Two stages, both on the fitting layer (:mod:`granseg.fitting`), whose every
model evaluation is one parallel sweep over all experiments:

1. the paper's full factorial design over any model parameters (default
   ``k`` in {0.5, 0.6, 0.7} and ``delta_over_H`` in {0.18, 0.20, 0.22}): the
   RMSD [-] of every experiment for every grid point, printed by
   :meth:`Calibration.table` in the layout of the paper's Table 4;
2. a bounded least-squares refinement of the baseline
   (``fit(data, Baseline())``) from the grid point with the lowest mean RMSD,
   on the residuals of every (time, layer) entry of every experiment, each
   experiment weighted so that it counts once (see
   :mod:`granseg.fitting.observe`). Standard errors, 95 % intervals and
   correlations by :data:`DEFAULT_ERRORS` (:mod:`granseg.fitting.uncertainty`;
   ``Calibration.uncertainty``, ``"intervals"`` in the JSON). Where the maps show grains of
   one kind in layers the refined model calls pure at the stratified start
   (a confusion of the two kinds by the frame analysis), the confusion is
   measured there (:mod:`granseg.fitting.confusion`), put into the
   observation step and the refinement repeated; ``settings["confusion"]``
   records it per material pair.

Before both stages the dwell of grains in view is measured from the maps'
counts (:mod:`granseg.fitting.dwell`) and put into the observation step:
grains that stay in view for many frames show the bed's composition late,
which a fit without it reads as a slower top (``settings["dwell"]``).

The model map is compared on the measured grid: the layer means at the
measured times, smoothed with the moving average the map records.
:func:`granseg.diagnose` starts from this calibration, so both report the
same baseline.

Example::

    >>> cal = calibrate("campaign/")                           # doctest: +SKIP
    >>> print(cal.table()); cal.best, cal.stderr               # doctest: +SKIP
"""

from __future__ import annotations

import math
import os
import sys
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from granseg.constants import DEFAULT_ERRORS, ERRORS
from granseg.fitting import (
    BASE_PARAMS,
    Baseline,
    Data,
    Fit,
    Param,
    confusion,
    dwell,
    evaluate,
    factorial,
    fit,
    intervals,
)
from granseg.fitting.solve import MIN_CLUSTERS
from granseg.fitting.threads import one_blas_thread
from granseg.fitting.uncertainty import Uncertainty
from granseg.maps import Campaign, Map, check_accepted, load_campaign
from granseg.model import defaults

__all__ = ["DEFAULT_ERRORS", "DEFAULT_GRID", "ERRORS", "Calibration", "CalibrationWarning", "ExperimentOptimum", "calibrate", "check_grid"]

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
    (the optimum may lie beyond: widen ``bounds``); ``fit`` and ``data`` the
    fitting layer's objects behind the result (the diagnosis starts from them).
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
    fit: Fit | None = field(default=None, repr=False)
    data: Data | None = field(default=None, repr=False)
    uncertainty: Uncertainty | None = field(default=None, repr=False)

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
            "intervals": None if self.uncertainty is None else self.uncertainty.to_dict(),
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


def as_maps(campaign: Campaign | Sequence[Map] | str | os.PathLike) -> list[Map]:
    """The maps of a campaign directory, Campaign or list, with distinct names (ValueError otherwise)."""
    if isinstance(campaign, str | os.PathLike):
        return list(load_campaign(Path(campaign)))
    try:
        maps = list(campaign)
    except TypeError:
        raise ValueError(f"campaign: expected a campaign folder, a Campaign or a list of maps, "
                         f"got {type(campaign).__name__}") from None
    if not maps:
        raise ValueError("campaign: it has no maps")
    for i, m in enumerate(maps):
        if not isinstance(m, Map):
            raise ValueError(f"campaign[{i}]: expected a granseg Map (granseg.load_map), got {type(m).__name__}")
    names = [m.name for m in maps]
    if len(set(names)) != len(names):
        raise ValueError(f"campaign: duplicate experiment names in {names}")
    return maps


def _default_bounds(grid: Mapping[str, list[float]]) -> dict[str, tuple[float, float]]:
    """The baseline's physical ranges for k and delta/H (:data:`BASE_PARAMS`), so that a
    calibration and a diagnosis search the same space; any other parameter within
    its grid range widened by the range on both sides (> 0 for a positive grid)."""
    physical = {p.name: (p.lo, p.hi) for p in BASE_PARAMS}
    out = {}
    for key, vals in grid.items():
        lo, hi = min(vals), max(vals)
        span = hi - lo if hi > lo else 0.5 * abs(lo) or 1.0
        widened = (max(lo - span, 0.25 * lo if lo > 0 else lo - span), hi + span)
        out[key] = physical.get(key, widened)
    return out


def _free_params(grid: Mapping[str, list[float]], bounds: tuple[np.ndarray, np.ndarray],
                 x0: np.ndarray, fd_rel: float) -> list[Param]:
    """The calibrated parameters, forward-difference steps relative to the start."""
    return [Param(k, float(bounds[0][j]), float(bounds[1][j]), float(x0[j]), fd_rel * max(abs(float(x0[j])), 1e-2))
            for j, k in enumerate(grid)]


# --------------------------------------------------------------------------- public entry


@one_blas_thread
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
    errors: str = DEFAULT_ERRORS,
    view_dwell: bool = True,
    velocity: Any = None,
    velocity_shape: str = "exponential",
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
    bounds : ``{parameter: (lo, hi)}`` for the refinement (default: the
        baseline's physical ranges for k (0.2-1.6) and delta/H (0.05-0.6), the
        grid range widened by its width on both sides for any other parameter).
    base : extra model parameters applied to every experiment (SI units).
    n_cells, rtol, atol : solver settings (default: the fitting layer's
        :data:`granseg.fitting.DEFAULT_N_CELLS` cells and the core's tolerances).
    fd_rel : relative forward-difference step of the Jacobian.
    max_nfev : cap on residual evaluations per refinement (each one sweep).
    errors : how the standard errors and 95 % intervals are estimated: ``"auto"``
        (default, :data:`DEFAULT_ERRORS`) or one of
        :data:`granseg.constants.ERROR_METHODS` (see :mod:`granseg.fitting.uncertainty`).
    view_dwell : measure the dwell of grains in view from the counts and model it
        (:mod:`granseg.fitting.dwell`); False compares the bed's share directly.
    velocity : a measured shear band in place of fitting delta/H: a ``granseg velocity``
        profile or ``granseg velocity-law`` law (path, or the loaded
        :class:`granseg.velocity.VelocityProfile` / :class:`~granseg.velocity.ShearBandLaw`), or a
        folder of one profile per map, ``NAME.json`` (as ``granseg dem`` writes them).
        A profile fixes delta/H (and v1 where its fit freed it) for every experiment, a law
        fixes delta/H at each experiment's M~; the default grid is then ``k`` alone.
    velocity_shape : ``exponential`` (the profile's fitted band) or ``tabulated`` (a profile's
        own -dv/dz as the model's shear rate, whatever its shape; see
        :func:`granseg.velocity.measured_params`).
    client : a ``dask.distributed.Client``; passed to ``granseg.sweep``.
    progress : print a counted line per sweep to stderr.
    accept_flagged : use maps that failed their frame-analysis quality checks
        (refused by default with :class:`granseg.errors.FlaggedMapError`).
    """
    t_start = time.perf_counter()
    if errors not in ERRORS:
        raise ValueError(f"errors = {errors!r}: choose one of {', '.join(ERRORS)}")
    # a zero step makes the forward-difference Jacobian zero, and the fit's SVD fails on it
    if isinstance(fd_rel, bool) or not isinstance(fd_rel, int | float) or not 0 < fd_rel <= 0.5:
        raise ValueError(f"fd_rel = {fd_rel!r} must be a relative step in (0, 0.5]")
    if isinstance(max_nfev, bool) or not isinstance(max_nfev, int) or max_nfev < 1:
        raise ValueError(f"max_nfev = {max_nfev!r} must be a whole number >= 1")
    maps = as_maps(campaign)
    check_accepted(maps, accept_flagged)
    measured = _measured_velocity(velocity, maps, grid, velocity_shape, base)
    grid = check_grid({"k": DEFAULT_GRID["k"]} if measured and grid is None else grid, list(defaults()))
    keys = list(grid)
    bnds = _bounds_arrays(keys, bounds, grid)
    log = _printer(progress)
    data = Data.of(maps, dict(n_cells=n_cells, rtol=rtol, atol=atol, client=client), dict(base or {}), log)
    if measured:
        data.measured = measured["params"]
        log(f"shear band measured ({measured['source']}): delta/H = "
            + ", ".join(f"{p['delta_over_H']:.3f}" for p in measured["params"][:4])
            + (" ..." if data.n > 4 else "") + " (not fitted)")
    if view_dwell:
        _with_dwell(data)
    n_runs = len(maps) * math.prod(len(v) for v in grid.values())
    log(f"factorial design: {data.n} experiments x {n_runs // data.n} points = {n_runs} runs")
    points, table = factorial(data, Baseline(), grid)
    x0 = np.clip([points[int(np.nanargmin(table.mean(axis=1)))][k] for k in keys], *bnds)
    params = _free_params(grid, bnds, x0, fd_rel)
    if refine:
        f = fit(data, Baseline(), params=params, max_nfev=max_nfev, errors=_usable(errors, data.n, log))
        f = _with_confusion(data, f, params, max_nfev)
    else:
        f = evaluate(data, Baseline(), params, dict(zip(keys, x0, strict=True)))
        f.message = "grid only"
    per = _per_experiment(data, table, points, params, max_nfev) if per_experiment else None
    settings = {"grid": grid, "bounds": {p.name: [p.lo, p.hi] for p in params},
                "base": dict(base or {}), **data.solver_settings(), "fd_rel": fd_rel, "max_nfev": max_nfev,
                "errors": f.error_method, "n_sweeps": data.n_sweeps, "n_runs": data.n_runs,
                "confusion": data.confusion_record, "dwell": data.dwell_record,
                "velocity": measured or None}
    cal = Calibration(
        names=data.names, keys=keys, grid_points=points, grid_rmsd=table,
        best=f.values(), stderr=f.errors(), rmsd=dict(zip(data.names, map(float, f.rmsd), strict=True)),
        refined=refine, converged=f.converged, message=f.message, model_layers=f.layers,
        n_evaluations=f.nfev, elapsed=time.perf_counter() - t_start, settings=settings,
        per_experiment=per, at_bound=f.at_bounds() if refine else [], fit=f, data=data,
        uncertainty=intervals(data, f) if refine else None,
    )
    for k in [k for k in cal.uncertainty.at_bound if k not in cal.at_bound] if cal.uncertainty else []:
        warnings.warn(f"calibrate: the 95 % interval of {k} reaches a bound of its range "
                      f"{settings['bounds'][k]}; it is cut there (widen bounds=)", CalibrationWarning, stacklevel=2)
    for k in cal.at_bound:
        warnings.warn(f"calibrate: the refined {k} = {cal.best[k]:.4g} lies on a bound of its range "
                      f"{settings['bounds'][k]}; the optimum may lie beyond it (widen bounds=)",
                      CalibrationWarning, stacklevel=2)
    log(f"done: {data.n_runs} runs in {data.n_sweeps} sweeps, {cal.elapsed:.1f} s")
    return cal


def _measured_velocity(velocity: Any, maps: Sequence[Map], grid: Mapping[str, Any] | None,
                       shape: str = "exponential", base: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The model parameters a measured shear band fixes per map ({} without one); a grid that
    would fit them too is refused."""
    if velocity is None:
        return {}
    from granseg.velocity import ShearBandLaw, VelocityProfile, load_velocity, measured_params

    if isinstance(velocity, (VelocityProfile, ShearBandLaw)):
        measurements = [velocity] * len(maps)
    elif Path(velocity).is_dir():
        # one profile per map, by the map's name (what `granseg dem` writes into OUT/velocity)
        paths = [Path(velocity) / f"{m.name}.json" for m in maps]
        for m, path in zip(maps, paths, strict=True):
            if not path.is_file():
                raise FileNotFoundError(f"{path}: no velocity profile for experiment {m.name!r} in {velocity}")
        measurements = [load_velocity(path) for path in paths]
    else:
        measurements = [load_velocity(velocity)] * len(maps)
    params = [measured_params(v, [m.M_tilde], shape=shape, cells=[{**(base or {}), **m.cell}])[0]
              for v, m in zip(measurements, maps, strict=True)]
    clash = sorted(set(params[0]) & set(grid or {}))
    if clash:
        raise ValueError(f"grid: {', '.join(clash)} measured by the velocity file; leave it out of the grid")
    source = type(velocity).__name__ if isinstance(velocity, (VelocityProfile, ShearBandLaw)) else str(velocity)
    return {"source": source, "params": params, "shape": shape}


def _usable(errors: str, n_experiments: int, log: Callable[[str], None]) -> str:
    """The error method for ``errors`` (``"auto"``: experiments as clusters from
    MIN_CLUSTERS experiments on, else entries), ``"jacobian"`` when there is one experiment."""
    if errors == "auto":
        errors = "cluster" if n_experiments >= MIN_CLUSTERS else "jacobian"
        if errors == "jacobian":
            log(f"{n_experiments} experiments: too few clusters for robust errors; counting entries as "
                f"independent (too small where grains persist in view)")
    if errors == "jacobian" or n_experiments >= 2:
        return errors
    log(f"one experiment: no {errors} errors; counting entries as independent (too small where grains persist)")
    return "jacobian"


def _with_dwell(data: Data) -> None:
    """Measure the dwell of grains in view (:mod:`granseg.fitting.dwell`) and, where the counts
    show it, put it into the observation step of every later fit."""
    d = dwell.measure(data.maps, data.exps, data.fixed)
    data.dwell_record = d.to_dict()
    if d.applied:
        data.dwell_width = d.width
        data.log(f"grains stay in view: window W = {data.dwell_record['width_Dp']:.1f} D_p from the counts' "
                 f"decorrelation (its shear band delta/H = {d.delta_over_H:.3f}); modelled in the observation")
    else:
        data.log(d.reason)


def _with_confusion(data: Data, f: Fit, params: list[Param], max_nfev: int) -> Fit:
    """Measure the two kinds' confusion on the stratified start (:mod:`granseg.fitting.confusion`)
    and, where it is resolved, refit with it in the observation step."""
    conf = confusion.measure(data.maps, f.layers, [e.pair for e in data.exps])
    data.confusion_record = conf.to_dict()
    if not conf.share.any():
        return f
    data.confusion = conf.share
    applied = {p: round(float(v["share"]), 4) for p, v in conf.by_pair.items() if v["applied"]}
    data.log(f"measured confusion of the two kinds on the stratified start: {applied}; refitting with it")
    return fit(data, Baseline(), params=params, x0=f.values(), max_nfev=max_nfev, errors=f.error_method)


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


def _per_experiment(data: Data, table: np.ndarray, points: list[dict[str, float]], params: list[Param],
                    max_nfev: int) -> dict[str, ExperimentOptimum]:
    """Each experiment's own refinement from its own best grid point (threads share the core)."""

    def one(i: int) -> ExperimentOptimum:
        start = points[int(np.nanargmin(table[:, i]))]
        f = fit(data, Baseline(), params=params, x0=start, which=[i], max_nfev=max_nfev, errors="jacobian")
        return ExperimentOptimum(best=f.values(), stderr=f.errors(), rmsd=float(f.rmsd[i]),
                                 converged=f.converged, message=f.message)

    with ThreadPoolExecutor(max_workers=min(4, data.n)) as pool:
        results = list(pool.map(one, range(data.n)))
    return dict(zip(data.names, results, strict=True))


def _printer(progress: bool) -> Callable[[str], None]:
    if not progress:
        return lambda msg: None
    return lambda msg: print(f"[calibrate] {msg}", file=sys.stderr, flush=True)
