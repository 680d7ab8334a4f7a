"""Curve fits of the paper's analyses (docs/model.md), by scipy.optimize.least_squares.

* :func:`fit_tanh` fits the bottom-layer series with
  ``f(t) = A/2 [1 - tanh(-(t - t0) / (tau - t0))]``: ``A`` [-] the final
  bottom concentration, ``t0`` [s] the time to half of it, ``tau`` [s] the
  time to 88 % of it.
* :func:`fit_beta` fits ``A(delta_R) = 1 - 1 / (2 delta_R^beta)`` over a campaign.
* :func:`fit_tau` fits the exponential law
  ``tau(delta_R) = tau_1 exp(-lambda (delta_R - 1))`` (``tau_1`` [s], ``lambda`` [-]).
* :func:`fit_campaign` does all three for the maps of a campaign.
* :func:`fit_shear_band` fits a measured velocity profile with docs/model.md's
  ``v(z) = v1 + (v0 - v1) exp(-z / delta)`` (``v0``, ``v1`` [m/s], ``delta_over_H`` [-]).
* :func:`fit_shear_band_law` fits ``delta/H = (delta/H)_ref (M~ / M~_ref)^(-exponent)``
  over several beds: the diagnosis' ``load_dependent_shear_band`` law, so the two compare.

Each returns a :class:`FitResult` with the parameters, their standard errors
and 95 % intervals (``uncertainty``, from the fitting layer's one
implementation, :mod:`granseg.fitting.uncertainty`), the mean squared error
and a ``converged`` flag: a fit that stops without converging says so in
``message`` and still returns what it has. :class:`granseg.FitError` is raised
only when no fit is possible at all (too few finite points).

Errors:

* :func:`fit_tanh` fits one time series whose residuals are correlated in
  time (the map is a moving average over ``smoothing_frames``, grains stay in
  view, and the tanh law does not follow the curve exactly), so counting its
  points as independent states errors several times too small. Its errors are
  time-block cluster-robust (method ``"cluster"``): the series is cut into
  consecutive blocks of :data:`BLOCK_CORRELATION_LENGTHS` correlation lengths
  of the residuals (:func:`residual_correlation_length`), the sandwich is
  taken over the blocks' scores (corrected for the fit's leverage on each
  block, CR2) and the intervals use Student's t with blocks - 1 degrees of
  freedom. Fewer than :data:`MIN_BLOCKS` blocks: the
  classical errors, with a note. The rule was chosen by measured coverage
  (benches/bench_fit_coverage.py, benches/results/fit_coverage.md).
* :func:`fit_beta` and :func:`fit_tau` fit one point per experiment, taken
  as independent: the classical s^2 (J'J)^-1 with t on m - p degrees of
  freedom (method ``"jacobian"``). So do :func:`fit_shear_band` (one point per
  layer, each weighted by its stated error) and :func:`fit_shear_band_law` (one
  point per bed), where s^2 (the residuals in stated errors) scales the errors up when
  the points scatter beyond their stated errors and never down.

Example::

    >>> import numpy as np
    >>> t = np.linspace(0, 600, 301)
    >>> r = fit_tanh(t, tanh_curve(t, 0.9, 120.0, 200.0))
    >>> round(r["A"], 3), round(r["t0"], 1), round(r["tau"], 1)
    (0.9, 120.0, 200.0)
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from granseg.errors import FitError
from granseg.maps import moving_average

if TYPE_CHECKING:  # granseg.fitting imports this module: its uncertainty is imported where used
    from granseg.fitting.uncertainty import Uncertainty

__all__ = [
    "FitResult",
    "CampaignFits",
    "tanh_curve",
    "beta_law",
    "tau_law",
    "fit_tanh",
    "fit_beta",
    "fit_tau",
    "fit_campaign",
    "shear_band_velocity",
    "fit_shear_band",
    "fit_shear_band_law",
    "covariance",
    "weighted_covariance",
    "residual_correlation_length",
]

#: Reference normalised load M~ = M_w / M_g [-] of the shear-band laws (:func:`shear_band_law`, the
#: diagnosis' load-dependent causes; the paper's three calibration cases sit at 0.41-0.54).
M_TILDE_REF = 0.5
TANH_TO_88 = float(np.tanh(1.0))  # f(tau) = A/2 (1 + tanh 1) = 0.8808 A
#: A tanh fit's time blocks are this many residual correlation lengths long [-].
BLOCK_CORRELATION_LENGTHS = 6
#: The residuals' running mean over this share of the series is removed before their correlation
#: length is measured (the law's smooth misfit is not noise) [-].
MISFIT_WINDOW = 0.1
#: Correct the blocks' scores for the fit's leverage on them (CR2); False: plain CR1, to compare.
LEVERAGE_CORRECTED = True
#: Fewest time blocks for the cluster errors; fewer fall back to the classical ones.
MIN_BLOCKS = 5
#: t0 or tau whose information lies in fewer effective blocks than this get a note.
MIN_EFFECTIVE_BLOCKS = 1.2


# --------------------------------------------------------------------------- laws


def tanh_curve(t: Any, A: float, t0: float, tau: float) -> np.ndarray:
    """Bottom-concentration law f(t) [-] at times ``t`` [s] (docs/model.md); needs tau > t0."""
    t = np.asarray(t, dtype=float)
    return 0.5 * A * (1.0 - np.tanh(-(t - t0) / (tau - t0)))


def beta_law(delta_R: Any, beta: float) -> np.ndarray:
    """Final bottom concentration A [-] against density ratio delta_R [-]."""
    return 1.0 - 0.5 / np.asarray(delta_R, dtype=float) ** beta


def tau_law(delta_R: Any, tau_1: float, lam: float) -> np.ndarray:
    """Exponential law tau(delta_R) = tau_1 exp(-lam (delta_R - 1)) [s]."""
    return tau_1 * np.exp(-lam * (np.asarray(delta_R, dtype=float) - 1.0))


def shear_band_velocity(z: Any, v0: float, v1: float, delta: float) -> np.ndarray:
    """docs/model.md's velocity profile v(z) = v1 + (v0 - v1) exp(-z / delta) [m/s] at heights ``z`` [m]."""
    return v1 + (v0 - v1) * np.exp(-np.asarray(z, dtype=float) / delta)


def shear_band_law(M_tilde: Any, delta_over_H_ref: float, exponent: float) -> np.ndarray:
    """delta/H [-] against the normalised load M~ = M_w / M_g [-], the form of the diagnosis'
    ``load_dependent_shear_band`` law (reference load :data:`M_TILDE_REF`)."""
    return delta_over_H_ref * (np.asarray(M_tilde, dtype=float) / M_TILDE_REF) ** (-exponent)


# --------------------------------------------------------------------------- result


@dataclass(frozen=True)
class FitResult:
    """Outcome of one fit: ``params`` and ``stderr`` (same units), ``mse`` of the data.

    ``result["A"]`` is a shortcut for ``result.params["A"]``. ``n_points`` is
    the number of finite data points used; ``converged`` is False when the
    optimiser stopped for another reason than convergence (see ``message``).
    ``uncertainty`` holds the 95 % intervals, correlations and notes
    (:class:`granseg.fitting.uncertainty.Uncertainty`; ``stderr`` are its
    standard errors); None for a result built without one.
    """

    model: str
    params: dict[str, float]
    stderr: dict[str, float]
    mse: float
    n_points: int
    converged: bool
    message: str
    uncertainty: Uncertainty | None = None

    def __getitem__(self, key: str) -> float:
        return self.params[key]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form (``"intervals"``: the uncertainty's, when there is one)."""
        out = {
            "model": self.model, "params": dict(self.params), "stderr": dict(self.stderr),
            "mse": self.mse, "n_points": self.n_points, "converged": self.converged,
            "message": self.message,
        }
        if self.uncertainty is not None:
            out["intervals"] = self.uncertainty.to_dict()
        return out


def covariance(jac: np.ndarray, residuals: np.ndarray, n_params: int) -> np.ndarray:
    """Parameter covariance s^2 (J^T J)^+ with s^2 = SSR / (m - p).

    ``jac`` (m, p) is the residual Jacobian at the optimum, ``residuals`` (m,).
    Returns a (p, p) matrix; all-NaN when the problem has no spare degree of
    freedom (m <= p).
    """
    m = residuals.size
    if m <= n_params:
        return np.full((n_params, n_params), np.nan)
    s2 = float(residuals @ residuals) / (m - n_params)
    return s2 * np.linalg.pinv(jac.T @ jac)


def weighted_covariance(jac: np.ndarray, residuals: np.ndarray, weights: np.ndarray,
                        n_params: int) -> np.ndarray:
    """Covariance of a fit that minimised the weighted residuals ``weights * r``.

    ``jac`` (m, p) and ``residuals`` (m,) are those of the weighted residuals.
    The weights set what the fit cares about, not the errors: those are taken
    equal for every entry, with s^2 from the unweighted residuals, so the
    covariance is the sandwich s^2 A (J^T W^2 J) A, A = (J^T J)^+. Equal
    weights give :func:`covariance`.
    """
    m = residuals.size
    if m <= n_params:
        return np.full((n_params, n_params), np.nan)
    raw = residuals / weights
    s2 = float(raw @ raw) / (m - n_params)
    a = np.linalg.pinv(jac.T @ jac)
    return s2 * a @ (jac.T @ (jac * (weights**2)[:, None])) @ a


def _finite_xy(x: Any, y: Any, what: str, min_points: int) -> tuple[np.ndarray, np.ndarray]:
    x = np.asarray(x, dtype=float).ravel()
    y = np.asarray(y, dtype=float).ravel()
    if x.shape != y.shape:
        raise ValueError(f"{what}: x and y have different lengths ({x.size} and {y.size})")
    keep = np.isfinite(x) & np.isfinite(y)
    if keep.sum() < min_points:
        raise FitError(f"{what}: needs at least {min_points} finite points, got {int(keep.sum())}")
    return x[keep], y[keep]


def _solve(
    resid: Callable[[np.ndarray], np.ndarray],
    p0: np.ndarray,
    bounds: tuple[Any, Any],
    max_nfev: int | None,
) -> tuple[Any, bool, str]:
    """Run least_squares; return (result, converged, message)."""
    from scipy.optimize import least_squares  # here: see granseg.fitting on import time

    res = least_squares(resid, p0, bounds=bounds, x_scale="jac", max_nfev=max_nfev)
    converged = bool(res.success) and res.status > 0
    message = str(res.message) if converged else f"not converged: {res.message}"
    return res, converged, message


def _result(model: str, res: Any, converged: bool, message: str, u: Uncertainty) -> FitResult:
    """FitResult of the estimates and errors in ``u``."""
    return FitResult(
        model=model,
        params={n: float(v) for n, v in zip(u.names, u.estimate, strict=True)},
        stderr={n: float(v) for n, v in zip(u.names, u.stderr, strict=True)},
        mse=float(np.mean(res.fun**2)),
        n_points=int(res.fun.size),
        converged=converged,
        message=message,
        uncertainty=u,
    )


def _independent(model: str, names: tuple[str, ...], res: Any, converged: bool, message: str,
                 bounds: tuple[Any, Any], stated_errors: bool = False) -> FitResult:
    """A fit to independent points: classical errors, t on m - p degrees of freedom.

    With ``stated_errors`` the residuals are in units of the points' own errors: s^2 then
    only scales the covariance up (a scatter beyond the stated errors), never down (a fit
    closer than its errors, on few points, is luck, not precision)."""
    from granseg.fitting.uncertainty import describe

    p = len(names)
    cov = covariance(res.jac, res.fun, p)
    if stated_errors and res.fun.size > p:
        s2 = float(res.fun @ res.fun) / (res.fun.size - p)
        cov = cov * max(1.0, s2) / s2 if s2 > 0 else np.linalg.pinv(res.jac.T @ res.jac)
    lo, hi = (np.broadcast_to(np.asarray(b, dtype=float), (p,)) for b in bounds)
    u = describe("jacobian", names, res.x, cov, None, (lo, hi), dof=res.fun.size - p)
    return _result(model, res, converged, message, u)


# --------------------------------------------------------------------------- tanh


def _tanh_start(t: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Start values (A, t0, tau - t0) read off the series."""
    tail = c[t >= t[0] + 0.8 * (t[-1] - t[0])]
    A = float(np.clip(np.mean(tail) if tail.size else c[-1], 1e-3, 1.0))
    t_half = t[np.argmax(c >= 0.5 * A)] if np.any(c >= 0.5 * A) else 0.5 * (t[0] + t[-1])
    t_88 = t[np.argmax(c >= TANH_TO_88 * A)] if np.any(c >= TANH_TO_88 * A) else t[-1]
    width = max(float(t_88 - t_half), 0.02 * float(t[-1] - t[0]), 1e-6)
    return np.array([A, float(t_half), width])


def residual_correlation_length(residuals: Any) -> float:
    """Correlation length [samples] of a fit's residuals: the lag where their autocorrelation
    first falls below 1/e.

    The residuals' running mean over :data:`MISFIT_WINDOW` of the series is
    removed first: a law that does not follow the curve exactly leaves a slow,
    smooth misfit (on the scale of the rise) that would otherwise pass for
    correlated noise and make the blocks far too long (5-10 times on the
    virtual maps). The window shortens long correlation tails a little (AR(1)
    noise with 0.9 per sample: about 8 samples for the true 9.5). At least 1.
    """
    r = np.asarray(residuals, dtype=float)
    n = r.size
    if n < 4:
        return 1.0
    width = int(n * MISFIT_WINDOW) // 2 * 2 + 1
    if width >= 3:
        r = r - moving_average(r, width)
    r = r - r.mean()
    spec = np.fft.rfft(r, 2 * n)
    acf = np.fft.irfft(spec * np.conj(spec), 2 * n)[:n]
    if not acf[0] > 0:
        return 1.0
    below = np.flatnonzero(acf / acf[0] < np.exp(-1.0))
    return float(max(below[0] if below.size else n, 1))


def _tanh_uncertainty(t: np.ndarray, res: Any, block_s: float | None, errors: str) -> Uncertainty:
    """Errors and intervals of (A, t0, tau) from the fit of (A, t0, width): time-block cluster
    sandwich, or the classical ones (``errors="jacobian"``, or fewer than MIN_BLOCKS blocks)."""
    from granseg.fitting.uncertainty import cluster_covariance, describe, time_blocks

    names = ("A", "t0", "tau")
    to_tau = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 1.0, 1.0]])  # (A, t0, width) -> (A, t0, tau)
    x = to_tau @ res.x
    bounds = (np.array([0.0, -np.inf, -np.inf]), np.array([1.5, np.inf, np.inf]))
    jac, r = np.asarray(res.jac, dtype=float), np.asarray(res.fun, dtype=float)
    m, span = r.size, float(t[-1] - t[0])
    length = residual_correlation_length(r)
    if block_s is None:
        dt = float(np.median(np.diff(t))) if m > 1 else 0.0
        block_s = BLOCK_CORRELATION_LENGTHS * length * dt
        why = f"{BLOCK_CORRELATION_LENGTHS} residual correlation lengths of {length * dt:.3g} s"
    else:
        why = "given"
    n_blocks = int(span // block_s) if block_s > 0 and span > 0 else 0
    if errors == "jacobian" or n_blocks < MIN_BLOCKS:
        cov = to_tau @ covariance(jac, r, 3) @ to_tau.T
        if errors == "jacobian":
            return describe("jacobian", names, x, cov, None, bounds, dof=m - 3, notes=[
                f"the errors count the {m} points as independent (errors='jacobian'), and are too small "
                f"if the residuals are correlated in time"])
        note = (f"only {n_blocks} time blocks of {block_s:.3g} s ({why}) fit in the series (at least "
                f"{MIN_BLOCKS} needed): the errors count the {m} points as independent, and are too small "
                f"if the residuals are correlated in time")
        return describe("jacobian", names, x, cov, None, bounds, notes=[note], dof=m - 3)
    block = np.minimum(time_blocks(t, block_s), n_blocks - 1)  # a short tail joins the last block
    scores = np.zeros((n_blocks, 3))
    np.add.at(scores, block, jac * r[:, None])
    block_a = np.zeros((n_blocks, 3, 3))
    np.add.at(block_a, block, jac[:, :, None] * jac[:, None, :])
    a = jac.T @ jac
    # CR2: the blocks of the rise hold most of t0's and tau's information, and the fit absorbs
    # much of their noise; without it the fastest rise's t0 was covered 30-54 % of the time (tuning).
    cov = to_tau @ cluster_covariance(a, scores, block_a if LEVERAGE_CORRECTED else None) @ to_tau.T
    notes = [f"time blocks of {block_s:.3g} s ({why}): {n_blocks} blocks, t on {n_blocks - 1} "
             f"degrees of freedom"]
    # How many blocks carry each parameter's information (the design's share per block): a rise
    # inside about one block leaves the sandwich little to learn its noise from (tuning seeds:
    # 91 % coverage of t0 and 94 % of tau below 1.2 effective blocks, 99 % above).
    infl = (jac @ np.linalg.pinv(a) @ to_tau.T) ** 2
    share = np.array([np.bincount(block, infl[:, j], n_blocks) for j in range(3)])
    with np.errstate(invalid="ignore", divide="ignore"):
        eff = share.sum(axis=1) ** 2 / (share**2).sum(axis=1)
    notes += [f"the information on {n} lies in about {eff[j]:.1f} of the time blocks (a short rise, or one "
              f"at an end of the series): its interval rests on little more than one block and may be too narrow"
              for j, n in enumerate(names) if j and eff[j] < MIN_EFFECTIVE_BLOCKS]
    return describe("cluster", names, x, cov, n_blocks, bounds, notes=notes)


def fit_tanh(t: Any, c: Any, *, max_nfev: int | None = None, block_s: float | None = None,
             errors: str = "cluster") -> FitResult:
    """Fit the bottom series ``c`` [-] at times ``t`` [s] with :func:`tanh_curve`.

    Returns params ``A`` [-], ``t0`` [s], ``tau`` [s] with standard errors and
    95 % intervals (``uncertainty``; ``tau`` = t0 + width is fitted through
    the width > 0, its error includes their covariance). NaN entries are
    skipped. ``max_nfev`` caps the function evaluations (a capped fit is
    marked not converged).

    The errors are time-block cluster-robust (see the module doc): blocks of
    ``block_s`` [s], default :data:`BLOCK_CORRELATION_LENGTHS` correlation
    lengths of the residuals (:func:`residual_correlation_length`), with the
    blocks' scores corrected for the fit's leverage on them (CR2). Long blocks
    are safe against correlation across their ends but leave few blocks to
    estimate the spread from, and a rise shorter than a block rests on one of
    them; short blocks miss the correlation across their ends (AR(1) noise of
    0.9 per sample loses about 1/k of the variance with blocks of k e-folding
    lengths; a moving average about half that). Six correlation lengths (about
    four moving-average widths) was the choice on virtual maps; 12 blocks over
    the whole span covered t0 and tau only 74-80 % of the time, and the
    leverage correction lifted the fastest rise's t0 (S-PP-90) from 30-54 %
    to 82-86 % on the tuning seeds (benches/results/fit_coverage.md). The
    law's misfit on real-looking curves makes these errors conservative there
    (stated errors 1.4-3.3 times the spread); on noise alone (AR(1), 0.9 per
    sample) they cover about 90 %.
    ``errors="jacobian"`` gives the classical errors instead (every point
    independent, t on m - 3 degrees of freedom), to compare with.
    """
    if errors not in ("cluster", "jacobian"):
        raise ValueError(f"fit_tanh: errors = {errors!r}: choose 'cluster' or 'jacobian'")
    t, c = _finite_xy(t, c, "fit_tanh", 4)
    if block_s is not None and not block_s > 0:
        raise ValueError(f"fit_tanh: block_s = {block_s!r}: the block length must be > 0 s")
    p0 = _tanh_start(t, c)
    span = float(t[-1] - t[0]) or 1.0

    def resid(p: np.ndarray) -> np.ndarray:
        return tanh_curve(t, p[0], p[1], p[1] + p[2]) - c

    lower = [0.0, t[0] - 10 * span, 1e-9 * span]
    upper = [1.5, t[-1] + 10 * span, 100 * span]
    res, converged, message = _solve(resid, p0, (lower, upper), max_nfev)
    return _result("tanh", res, converged, message, _tanh_uncertainty(t, res, block_s, errors))


# --------------------------------------------------------------------------- campaign laws


def fit_beta(delta_R: Any, A: Any, *, max_nfev: int | None = None) -> FitResult:
    """Fit ``A = 1 - 1 / (2 delta_R^beta)`` to final concentrations ``A`` [-].

    ``delta_R`` [-] must be >= 1 (heavy over light). Returns ``beta`` [-] with
    its standard error and 95 % interval (the experiments taken as independent:
    s^2 (J'J)^-1, t on m - 1 degrees of freedom) and the MSE of A.
    """
    x, y = _finite_xy(delta_R, A, "fit_beta", 2)
    if np.any(x < 1.0):
        raise ValueError(f"fit_beta: delta_R must be >= 1, got {x.min():g}")
    if np.all(x == 1.0):
        raise FitError("fit_beta: every delta_R is 1; beta is undetermined")
    bounds = ([0.0], [50.0])
    res, converged, message = _solve(lambda p: beta_law(x, p[0]) - y, np.array([2.0]), bounds, max_nfev)
    return _independent("beta", ("beta",), res, converged, message, bounds)


def fit_tau(delta_R: Any, tau: Any, *, max_nfev: int | None = None) -> FitResult:
    """Fit ``tau = tau_1 exp(-lam (delta_R - 1))`` to segregation times ``tau`` [s].

    Returns ``tau_1`` [s] (tau extrapolated to delta_R = 1) and ``lam`` [-]
    with standard errors and 95 % intervals (independent experiments: t on
    m - 2 degrees of freedom) and the MSE [s^2].
    """
    x, y = _finite_xy(delta_R, tau, "fit_tau", 3)
    if np.any(y <= 0):
        raise ValueError("fit_tau: tau must be > 0 s")
    slope, icpt = np.polyfit(x - 1.0, np.log(y), 1)
    p0 = np.array([np.exp(icpt), max(-slope, 0.0)])
    bounds = ([0.0, -50.0], [np.inf, 50.0])
    res, converged, message = _solve(lambda p: tau_law(x, p[0], p[1]) - y, p0, bounds, max_nfev)
    return _independent("tau", ("tau_1", "lam"), res, converged, message, bounds)


def _finite_weighted(x: Any, y: Any, err: Any, what: str, min_points: int
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The finite (x, y) points and their weights 1 / err (None: equal weights); every stated
    error must be finite and > 0."""
    x = np.asarray(x, dtype=float).ravel()
    y = np.asarray(y, dtype=float).ravel()
    e = np.ones_like(y) if err is None else np.asarray(err, dtype=float).ravel()
    if e.size == 1:
        e = np.full_like(y, float(e[0]))
    if e.shape != y.shape:
        raise ValueError(f"{what}: {e.size} stated errors for {y.size} points")
    keep = np.isfinite(x) & np.isfinite(y)
    if not np.all(np.isfinite(e[keep]) & (e[keep] > 0)):
        raise ValueError(f"{what}: every stated error must be finite and > 0")
    xs, ys = _finite_xy(x, y, what, min_points)
    return xs, ys, 1.0 / e[keep]


def fit_shear_band(z: Any, v: Any, v_err: Any = None, *, H: float, v1: float | None = None,
                   layer_correlation: float = 0.0, max_nfev: int | None = None) -> FitResult:
    """Fit a velocity profile ``v`` [m/s] at heights ``z`` [m] above the plate with
    :func:`shear_band_velocity`; ``H`` [m] is the bed height delta is scaled by.

    Returns ``v0``, ``v1`` [m/s] and ``delta_over_H`` [-] with standard errors and 95 %
    intervals (points weighted by ``v_err`` [m/s], classical errors, t on m - p degrees of
    freedom). ``v1`` given: the lid's speed is held there and only v0 and delta/H are fitted.

    ``layer_correlation`` (phi in [0, 1)): the points' errors are correlated, phi^k between
    points k spacings apart (the smallest height step), as footage's layers are when the
    window's grains share a deviation from their bands; the fit is then generalised least
    squares, its residuals whitened by the Cholesky factor of that correlation.
    """
    if not 0.0 <= layer_correlation < 1.0:
        raise ValueError(f"fit_shear_band: layer_correlation = {layer_correlation!r} must lie in [0, 1)")
    x, y, w = _finite_weighted(z, v, v_err, "fit_shear_band", 3 if v1 is None else 2)
    if layer_correlation > 0 and np.unique(x).size < x.size:
        # two points at one height would be fully correlated (phi^0): the correlation is singular
        raise ValueError(f"fit_shear_band: layer_correlation = {layer_correlation!r} takes one point per "
                         f"height, but z repeats ({x.size - np.unique(x).size} repeated); fit each height's "
                         "mean, or give layer_correlation = 0")
    whiten = _ar1_whitener(x, layer_correlation)
    if not H > 0:
        raise ValueError(f"fit_shear_band: H = {H!r} m: the bed height must be > 0")
    if np.ptp(x) <= 0:
        raise FitError("fit_shear_band: every point is at one height; delta is undetermined")
    free_v1 = v1 is None
    lo_z, hi_z = x[np.argmin(x)], x[np.argmax(x)]
    v0_start, top = float(y[x == lo_z].mean()), float(y[x == hi_z].mean())
    start_v1 = top if free_v1 else float(v1)
    span = abs(v0_start - start_v1) or float(np.abs(y).max()) or 1.0

    def unpack(p: np.ndarray) -> tuple[float, float, float]:
        return (p[0], p[1], p[2]) if free_v1 else (p[0], float(v1), p[1])

    def resid(p: np.ndarray) -> np.ndarray:
        a, b, dh = unpack(p)
        return whiten(w * (shear_band_velocity(x, a, b, dh * H) - y))

    p0 = [v0_start, start_v1, 0.2] if free_v1 else [v0_start, 0.2]
    vmax = 10 * (float(np.abs(y).max()) + span)
    lower = [-vmax, -vmax, 1e-3] if free_v1 else [-vmax, 1e-3]
    upper = [vmax, vmax, 10.0] if free_v1 else [vmax, 10.0]
    names = ("v0", "v1", "delta_over_H") if free_v1 else ("v0", "delta_over_H")
    res, converged, message = _solve(resid, np.array(p0), (lower, upper), max_nfev)
    return _independent("shear_band", names, res, converged, message, (lower, upper), v_err is not None)


def _ar1_whitener(x: np.ndarray, phi: float) -> Callable[[np.ndarray], np.ndarray]:
    """r -> L^-1 r, with L L^T the correlation phi^(|x_i - x_j| / step) of points at ``x``
    (step: the smallest spacing); the identity for phi = 0."""
    if phi <= 0 or x.size < 2:
        return lambda r: r
    from scipy.linalg import cholesky, solve_triangular

    gaps = np.diff(np.sort(x))
    step = float(gaps[gaps > 0].min()) if np.any(gaps > 0) else 1.0
    lower = cholesky(phi ** (np.abs(x[:, None] - x[None, :]) / step), lower=True)
    return lambda r: solve_triangular(lower, r, lower=True)


def fit_shear_band_law(M_tilde: Any, delta_over_H: Any, delta_over_H_err: Any = None, *,
                       max_nfev: int | None = None) -> FitResult:
    """Fit :func:`shear_band_law` to the decay lengths ``delta_over_H`` [-] of beds under the
    normalised loads ``M_tilde`` [-] (weighted by ``delta_over_H_err``).

    Returns ``delta_over_H_ref`` [-] (at M~ = :data:`M_TILDE_REF`) and ``exponent`` [-] with
    standard errors and 95 % intervals (beds independent, t on m - 2 degrees of freedom).
    """
    x, y, w = _finite_weighted(M_tilde, delta_over_H, delta_over_H_err, "fit_shear_band_law", 3)
    if np.any(x <= 0) or np.any(y <= 0):
        raise ValueError("fit_shear_band_law: M_tilde and delta_over_H must be > 0")
    if np.ptp(x) <= 0:
        raise FitError("fit_shear_band_law: every bed has the same M~; the exponent is undetermined")
    slope, icpt = np.polyfit(np.log(x / M_TILDE_REF), np.log(y), 1)
    p0 = np.array([np.exp(icpt), -slope])
    bounds = ([0.0, -20.0], [10.0, 20.0])
    res, converged, message = _solve(lambda p: w * (shear_band_law(x, p[0], p[1]) - y), p0, bounds, max_nfev)
    return _independent("shear_band_law", ("delta_over_H_ref", "exponent"), res, converged, message, bounds,
                        delta_over_H_err is not None)


@dataclass(frozen=True)
class CampaignFits:
    """tanh fit per experiment plus the beta and tau laws over the selected ones.

    ``selected`` names the experiments used for the laws (those with the
    chosen c0); ``beta`` / ``tau`` are None with a reason in ``notes`` when
    there are too few of them.
    """

    tanh: dict[str, FitResult]
    delta_R: dict[str, float]
    selected: list[str]
    beta: FitResult | None
    tau: FitResult | None
    c0: float | None
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        return {
            "tanh": {k: v.to_dict() for k, v in self.tanh.items()},
            "delta_R": dict(self.delta_R),
            "selected": list(self.selected), "c0": self.c0,
            "beta": None if self.beta is None else self.beta.to_dict(),
            "tau": None if self.tau is None else self.tau.to_dict(),
            "notes": list(self.notes),
        }


def fit_campaign(maps: Iterable[Any], *, c0: float | None = 0.5) -> CampaignFits:
    """tanh-fit each map's bottom series; fit beta and tau over maps with ``c0``.

    ``maps`` are :class:`granseg.maps.Map` objects (or a Campaign). The laws
    A(delta_R) and tau(delta_R) describe mixtures of one c0 (the paper uses
    50:50); ``c0=None`` uses every map.
    """
    maps = list(maps)
    tanh: dict[str, FitResult] = {}
    notes: list[str] = []
    for m in maps:
        try:
            tanh[m.name] = fit_tanh(m.t, m.bottom)
        except FitError as exc:
            notes.append(f"{m.name}: {exc}")
    sel = [m.name for m in maps if m.name in tanh and (c0 is None or abs(m.c0 - c0) < 1e-9)]
    dR = {m.name: m.delta_R for m in maps}
    beta = _law(fit_beta, sel, dR, {k: v["A"] for k, v in tanh.items()}, notes, "beta")
    tau = _law(fit_tau, sel, dR, {k: v["tau"] for k, v in tanh.items()}, notes, "tau")
    return CampaignFits(tanh=tanh, delta_R=dR, selected=sel, beta=beta, tau=tau, c0=c0, notes=notes)


def _law(
    fitter: Callable[..., FitResult],
    names: list[str],
    x: Mapping[str, float],
    y: Mapping[str, float],
    notes: list[str],
    what: str,
) -> FitResult | None:
    try:
        return fitter([x[n] for n in names], [y[n] for n in names])
    except (FitError, ValueError) as exc:
        notes.append(f"{what} law not fitted: {exc}")
        return None
