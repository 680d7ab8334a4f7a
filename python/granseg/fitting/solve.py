"""One bounded least-squares fit, its standard errors, and leave-one-experiment-out.

:func:`fit` fits any :class:`~granseg.fitting.effects.Effect` to a set of
experiments of a :class:`~granseg.fitting.observe.Data`. Each residual
evaluation is one sweep holding every fitted experiment at the trial point
with the core's forward sensitivities of its map, plus a forward-difference
run for each parameter the core cannot differentiate by (a delayed start, a
density; :func:`~granseg.fitting.observe.maps_and_jacobians`); the last point
is cached so that scipy's separate calls for residuals and Jacobian cost one
sweep. scipy sees the
problem compressed to p + 1 rows (:func:`compress`, exact: same steps).

Standard errors (:func:`covariance`, :func:`intervals`; the estimators live
in :mod:`granseg.fitting.uncertainty`, shared by every fit in granseg):

* ``"jacobian"``: the weighted-least-squares covariance
  (:func:`granseg.fit.weighted_covariance`) inflated by the maps' smoothing
  width (a moving average of n frames leaves about 1/n as many independent
  residuals). Right for independent frame noise; too small when grains stay
  in view for many frames (BENCHMARKS.md "Uncertainty" measures by how much);
* ``"cluster"``: cluster-robust sandwich with the experiments as clusters:
  residuals within a map are correlated in time and depth, experiments are
  not. Needs several experiments (with one it is undefined and NaN is returned);
* ``"jackknife"``: leave-one-experiment-out, one Gauss-Newton step each.

:func:`loo_predict` predicts every experiment from the others: by default one
Gauss-Newton step from the full fit with that experiment's Jacobian block
removed (no extra solver runs), then one sweep for all held-out maps.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from granseg.constants import ERROR_METHODS
from granseg.fit import weighted_covariance
from granseg.fitting import uncertainty
from granseg.fitting.effects import Effect, Param
from granseg.fitting.observe import Data, maps_and_jacobians, model_maps, residual, rmsd

__all__ = ["ERROR_METHODS", "MIN_CLUSTERS", "PRIOR_WEIGHT", "Fit", "compact", "compress", "covariance", "evaluate",
           "factorial", "fit", "intervals", "loo_params", "loo_predict"]

#: Weight of the parameter priors, in units of the stacked sum of squares
#: (sum over experiments of MSE): one prior sd costs PRIOR_WEIGHT**2.
PRIOR_WEIGHT = 0.01
#: Fewer experiments than this and the robust errors say their own spread is uncertain.
MIN_CLUSTERS = 8
#: Stopping tolerances of every fit (relative step and cost change).
XTOL, FTOL, GTOL = 1e-5, 1e-7, 1e-8


@dataclass
class Fit:
    """One effect fitted to the experiments ``which`` of a campaign.

    ``x`` the parameters (``params`` in order), ``cov`` their covariance by
    ``error_method``, ``layers[i]`` the model map of experiment i (every
    experiment, the unfitted ones too), ``rmsd[i]`` its RMSD [-]; ``res`` and
    ``jac`` the weighted residual and Jacobian blocks of the fitted ones at
    ``x`` (empty after :func:`compact`; :func:`blocks` gives them either way),
    ``G``/``g`` their J_i'J_i and J_i'r_i, ``A``/``grad`` the sums plus
    the prior (for the leave-one-out step).
    """

    effect: Effect
    params: list[Param]
    x: np.ndarray
    cov: np.ndarray
    error_method: str
    layers: list[np.ndarray]
    rmsd: np.ndarray
    res: list[np.ndarray]
    jac: list[np.ndarray]
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
        """Parameter names, in order."""
        return [p.name for p in self.params]

    @property
    def stderr(self) -> np.ndarray:
        """Standard errors (same units as ``x``; NaN where unknown)."""
        d = np.diag(self.cov) if self.cov.size else np.zeros(0)
        return np.sqrt(np.where(np.isfinite(d), np.clip(d, 0.0, None), np.nan))

    def values(self, x: np.ndarray | None = None) -> dict[str, float]:
        """Parameter dict of ``x`` (default the fit)."""
        return dict(zip(self.keys, map(float, self.x if x is None else x), strict=True))

    def errors(self) -> dict[str, float]:
        """Standard errors by parameter name."""
        return dict(zip(self.keys, map(float, self.stderr), strict=True))

    @property
    def rmsd_mean(self) -> float:
        """Mean RMSD [-] over the fitted experiments."""
        return float(np.mean(self.rmsd[self.which]))

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper bounds of the parameters."""
        return _bounds(self.params)

    def at_bounds(self) -> list[str]:
        """Parameters within 1e-6 of their range's width from a bound."""
        lo, hi = self.bounds()
        tol = 1e-6 * (hi - lo)
        return [p.name for j, p in enumerate(self.params) if self.x[j] <= lo[j] + tol[j] or self.x[j] >= hi[j] - tol[j]]


def _bounds(params: Sequence[Param]) -> tuple[np.ndarray, np.ndarray]:
    return np.array([p.lo for p in params], dtype=float), np.array([p.hi for p in params], dtype=float)


def _steps(x: np.ndarray, params: Sequence[Param], hi: np.ndarray) -> np.ndarray:
    """Forward-difference steps, turned backward where the forward point leaves the bounds."""
    h = np.array([p.step for p in params], dtype=float)
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
    """Residual and Jacobian blocks at x, one sweep per new x (the last one cached)."""

    def __init__(self, data: Data, effect: Effect, params: list[Param], which: list[int]) -> None:
        self.data, self.effect, self.params, self.which = data, effect, params, which
        self.lo, self.hi = _bounds(params)
        self.keys = [p.name for p in params]
        self._key: bytes | None = None
        self._value: tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]] | None = None
        self._compressed_key: bytes | None = None
        self._compressed: tuple[np.ndarray, np.ndarray] = (np.zeros(0), np.zeros((0, 0)))

    def __call__(self, x: np.ndarray) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
        """(residual blocks, Jacobian blocks, model maps) of the fitted experiments at x."""
        key = np.asarray(x, dtype=float).tobytes()
        if key != self._key:
            self._key, self._value = key, self._evaluate(np.asarray(x, dtype=float))
        assert self._value is not None
        return self._value

    def _evaluate(self, x: np.ndarray) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
        t0 = time.perf_counter()
        runs_before = self.data.n_runs
        h = _steps(x, self.params, self.hi)
        point = dict(zip(self.keys, map(float, x), strict=True))
        layers, jacobians = maps_and_jacobians(self.data, self.effect, point, self.which, h)
        n = len(self.which)
        res, jac = [], []
        for k, i in enumerate(self.which):
            mask, w = self.data.masks[i], self.data.weights[i]
            res.append(residual(self.data, i, layers[k]))
            J = jacobians[k].reshape(len(self.keys), -1)
            # (entries, params) as a transposed view of the columns, weighted in place: a
            # complete map needs no boolean gather and no copy (long maps, many parameters)
            J = J if mask.all() else J[:, mask.ravel()]
            J *= w
            jac.append(J.T)
        ms = float(sum(r @ r for r in res)) / n
        pars = " ".join(f"{k}={v:.5g}" for k, v in zip(self.keys, x, strict=True))
        self.data.log(f"{self.effect.name}: {pars} root mean of the experiments' MSE={ms ** 0.5:.5f} "
                      f"({self.data.n_runs - runs_before} runs, {time.perf_counter() - t0:.1f} s)")
        return res, jac, layers

    def compressed(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(residual, Jacobian) of the same least-squares problem at x in p + 1 rows (module doc)."""
        key = np.asarray(x, dtype=float).tobytes()
        if key != self._compressed_key:
            res, jac, _ = self(x)
            self._compressed_key, self._compressed = key, compress(res, jac)
        return self._compressed

    def fun(self, x: np.ndarray) -> np.ndarray:
        return np.concatenate([self.compressed(x)[0], _prior(self.params, x)[0]])

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        return np.vstack([self.compressed(x)[1], _prior(self.params, x)[1]])


def compress(res: Sequence[np.ndarray], jac: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """The least-squares problem (r, J) of the stacked blocks in p + 1 rows: (r~, J~).

    With J'J = V L V', J~ = [L^1/2 V'; 0] and r~ = [L^-1/2 V'J'r; rho], rho^2 = r'r - the
    rest, every step s has ||J~ s + r~||^2 = s'J'Js + 2 s'J'r + r'r = ||J s + r||^2:
    the same cost, gradient, Gauss-Newton matrix and column norms at x, so scipy's
    trust-region solver takes the same steps as on the full problem. That one is
    ~10^6 x 10 for a campaign of hour-long maps, and the solver takes its SVD at
    every iteration (0.44 s, more than the sweep); a QR of the blocks costs as much
    (35 ms per block), their Gram matrices 1 ms. Directions J cannot see (eigenvalues
    below 1e-13 of the largest) get zero rows: J'r has no component along them.
    """
    p = jac[0].shape[1] if jac else 0
    G = sum((j.T @ j for j in jac), np.zeros((p, p)))
    g = sum((j.T @ r for j, r in zip(jac, res, strict=True)), np.zeros(p))
    rr = float(sum(r @ r for r in res))
    lam, V = np.linalg.eigh(G)
    seen = lam > 1e-13 * max(float(lam.max(initial=0.0)), np.finfo(float).tiny)
    root = np.sqrt(np.where(seen, lam, 0.0))
    top = np.where(seen, (V.T @ g) / np.where(seen, root, 1.0), 0.0)
    rho = np.sqrt(max(rr - float(top @ top), 0.0))
    return np.concatenate([top, [rho]]), np.vstack([root[:, None] * V.T, np.zeros((1, p))])


def fit(data: Data, effect: Effect, *, params: Sequence[Param] | None = None,
        x0: Mapping[str, float] | None = None, which: Sequence[int] | None = None,
        max_nfev: int = 30, errors: str = "cluster") -> Fit:
    """Bounded least-squares fit of ``effect`` over experiments ``which`` (default all).

    ``params`` replaces the effect's own parameter list (a calibration frees
    other model parameters or other ranges); ``x0`` overrides the start
    values (warm start). ``errors`` picks the standard-error estimator (see
    the module doc). Every experiment gets a model map at the optimum, the
    ones left out too, so the caller can score them.
    """
    if errors not in ERROR_METHODS:
        raise ValueError(f"errors = {errors!r}: choose one of {', '.join(ERROR_METHODS)}")
    which = list(range(data.n)) if which is None else list(which)
    params = list(effect.params(data.exps) if params is None else params)
    ev = _Evaluator(data, effect, params, which)
    span = ev.hi - ev.lo
    start = np.array([float((x0 or {}).get(p.name, p.start)) for p in params])
    start = np.clip(start, ev.lo + 1e-9 * span, ev.hi - 1e-9 * span)
    t0 = time.perf_counter()
    from scipy.optimize import least_squares  # here: see granseg.fitting on import time

    sol = least_squares(ev.fun, start, jac=ev.jacobian, bounds=(ev.lo, ev.hi), x_scale="jac",
                        max_nfev=max_nfev, xtol=XTOL, ftol=FTOL, gtol=GTOL)
    res, jac, layers = ev(sol.x)
    f = _assemble(data, effect, params, sol.x, which, res, jac, layers, errors)
    f.converged, f.nfev = bool(sol.status > 0), int(sol.nfev)
    f.message = str(sol.message) if f.converged else f"not converged: {sol.message}"
    data.log(f"fit {effect.name}: " + ", ".join(f"{k}={v:.4g}" for k, v in f.values().items())
             + f"; mean RMSD {f.rmsd_mean:.4f} ({sol.nfev} evaluations, {time.perf_counter() - t0:.1f} s)")
    return f


def evaluate(data: Data, effect: Effect, params: Sequence[Param], x: Mapping[str, float],
             which: Sequence[int] | None = None) -> Fit:
    """The model at fixed parameters ``x`` as a :class:`Fit` (no optimisation, NaN errors)."""
    which = list(range(data.n)) if which is None else list(which)
    params = list(params)
    xv = np.array([float(x[p.name]) for p in params])
    res, jac, layers = _Evaluator(data, effect, params, which)(xv)
    f = _assemble(data, effect, params, xv, which, res, jac, layers, "jacobian")
    f.cov = np.full_like(f.cov, np.nan)
    f.message = "fixed parameters, not fitted"
    return f


def compact(f: Fit) -> Fit:
    """``f`` without its weighted residual and Jacobian blocks, which are most of its memory
    (on the open-world test campaign, 14 experiments, about 33 MB a fit, and a diagnosis keeps
    every fit it makes). What the fit's results need stays: x, its covariance, the maps, the
    leave-one-out sums. A Jacobian asked of it later (:func:`covariance` by ``"jacobian"``,
    the coherence test's model derivatives) comes from :func:`evaluate` at ``x`` again."""
    return replace(f, res=[], jac=[])


def blocks(data: Data, f: Fit) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The weighted residual and Jacobian blocks of ``f`` at its ``x``: its own, or evaluated
    again for a :func:`compact` one."""
    if f.jac or not f.which or not f.params:
        return f.res, f.jac
    again = evaluate(data, f.effect, f.params, f.values(), f.which)
    return again.res, again.jac


def _assemble(data: Data, effect: Effect, params: list[Param], x: np.ndarray, which: list[int],
              res: list[np.ndarray], jac: list[np.ndarray], layers: list[np.ndarray], errors: str) -> Fit:
    G = np.stack([j.T @ j for j in jac])
    g = np.stack([j.T @ r for j, r in zip(jac, res, strict=True)])
    pr, pj = _prior(params, x)
    every = _every_layers(data, effect, params, x, which, layers)
    f = Fit(effect, params, x, np.zeros((0, 0)), errors, every,
            np.array([rmsd(data, i, every[i]) for i in range(data.n)]), res, jac, G, g,
            G.sum(axis=0) + pj.T @ pj, g.sum(axis=0) + pj.T @ pr, True, "", 0, which)
    f.cov = covariance(data, f, errors)
    return f


def _every_layers(data: Data, effect: Effect, params: list[Param], x: np.ndarray,
                  which: list[int], layers: list[np.ndarray]) -> list[np.ndarray]:
    out: dict[int, np.ndarray] = dict(zip(which, layers, strict=True))
    missing = [i for i in range(data.n) if i not in out]
    if missing:
        d = dict(zip([p.name for p in params], map(float, x), strict=True))
        out.update(zip(missing, model_maps(data, effect, [(d, i) for i in missing]), strict=True))
    return [out[i] for i in range(data.n)]


def covariance(data: Data, f: Fit, method: str) -> np.ndarray:
    """Covariance of ``f.x`` by ``method`` (one of :data:`ERROR_METHODS`, :mod:`granseg.fitting.uncertainty`)."""
    p = len(f.params)
    if p == 0:
        return np.zeros((0, 0))
    if method == "cluster":
        return uncertainty.cluster_covariance(f.A, f.g)
    if method == "jackknife":
        return uncertainty.jackknife_covariance(np.array([loo_params(f, i) for i in f.which]))
    res, jac = blocks(data, f)
    jac, r = np.vstack(jac), np.concatenate(res)
    w = np.concatenate([np.full(int(data.masks[i].sum()), data.weights[i]) for i in f.which])
    return weighted_covariance(jac, r, w, p) * _smoothing_factor(data, f.which)


def intervals(data: Data, f: Fit, method: str | None = None, level: float = uncertainty.LEVEL
              ) -> uncertainty.Uncertainty:
    """Standard errors, ``level`` intervals and correlations of ``f`` by ``method`` (default the fit's own).

    The experiments are the clusters of ``"cluster"`` and ``"jackknife"`` (t with
    n_experiments - 1 degrees of freedom); ``"jacobian"`` counts entries.
    """
    method = f.error_method if method is None else method
    if method not in ERROR_METHODS:
        raise ValueError(f"method = {method!r}: choose one of {', '.join(ERROR_METHODS)}")
    cov = f.cov if method == f.error_method else covariance(data, f, method)
    if method == "jacobian":
        notes = ["jacobian errors count every map entry as independent: too small where grains stay in view "
                 "for many frames (BENCHMARKS.md, Uncertainty)"]
    else:
        notes = [] if len(f.which) >= MIN_CLUSTERS else [
            f"{method} errors from only {len(f.which)} experiments: their spread is itself uncertain"]
    if data.dwell_record is not None and data.dwell_record.get("reason", "").startswith("no counts"):
        notes.append("the dwell of grains in view could not be measured (no counts): the intervals "
                     "do not cover the bias it causes where grains persist (delta/H about 1-2 % low)")
    return uncertainty.describe(method, f.keys, f.x, cov, None if method == "jacobian" else len(f.which),
                                f.bounds(), level, notes)


def _smoothing_factor(data: Data, which: Sequence[int]) -> float:
    """Entry-weighted mean smoothing width: the variance inflation of the Jacobian errors."""
    w = np.array([data.masks[i].sum() for i in which], dtype=float)
    n = np.array([data.maps[i].smoothing_frames for i in which], dtype=float)
    return float((w * n).sum() / w.sum())


def factorial(data: Data, effect: Effect, grid: Mapping[str, Sequence[float]]
              ) -> tuple[list[dict[str, float]], np.ndarray]:
    """Every point of the full factorial ``grid`` and the RMSD table (n_points, n_experiments), one sweep."""
    points = [dict(zip(grid, map(float, v), strict=True)) for v in itertools.product(*grid.values())]
    runs = [(p, i) for p in points for i in range(data.n)]
    layers = model_maps(data, effect, runs)
    table = np.array([rmsd(data, i, lay) for (_, i), lay in zip(runs, layers, strict=True)])
    return points, table.reshape(len(points), data.n)


def loo_params(f: Fit, i: int, damping: float = 1e-6) -> np.ndarray:
    """Parameters with experiment i left out: one Gauss-Newton step from the full fit.

    The training gradient is the full gradient minus experiment i's, the
    normal matrix the full one minus J_i'J_i (Levenberg damping ``damping``
    x its diagonal), all stored at the full fit.
    """
    k = f.which.index(i)
    A = f.A - f.G[k]
    grad = f.grad - f.g[k]
    A = A + damping * np.diag(np.maximum(np.diag(A), 1e-12))
    step = -np.linalg.lstsq(A, grad, rcond=None)[0]
    lo, hi = f.bounds()
    return np.clip(f.x + step, lo, hi)


def loo_predict(data: Data, f: Fit, *, exact: bool = False, max_nfev: int = 4, start: str = "step"
                ) -> tuple[np.ndarray, list[np.ndarray], list[np.ndarray]]:
    """Leave-one-experiment-out predictions of a fit.

    Returns (held-out RMSD per fitted experiment [-], held-out model maps,
    fold parameter vectors). ``exact=True`` refits each fold (``max_nfev``
    evaluations) from the one-step estimate (``start="step"``) or from the
    full fit (``start="full"``: safer where the one step overshoots, as for
    flexible, strongly nonlinear corrections).
    """
    if start not in ("step", "full"):
        raise ValueError(f"start = {start!r}: choose 'step' or 'full'")
    folds = [loo_params(f, i) if start == "step" else f.x for i in f.which]
    if exact:
        # each fold's fit maps every experiment at its optimum, the one left out too
        refits = [fit(data, f.effect, params=f.params, x0=f.values(x), which=[j for j in f.which if j != i],
                      max_nfev=max_nfev, errors=f.error_method)
                  for x, i in zip(folds, f.which, strict=True)]
        folds = [r.x for r in refits]
        layers = [r.layers[i] for r, i in zip(refits, f.which, strict=True)]
    else:
        layers = model_maps(data, f.effect, [(f.values(x), i) for x, i in zip(folds, f.which, strict=True)])
    out = np.array([rmsd(data, i, lay) for i, lay in zip(f.which, layers, strict=True)])
    return out, layers, folds
