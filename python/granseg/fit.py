"""Curve fits of the paper's analyses (MODEL.md), by scipy.optimize.least_squares.

* :func:`fit_tanh` fits the bottom-layer series with
  ``f(t) = A/2 [1 - tanh(-(t - t0) / (tau - t0))]``: ``A`` [-] the final
  bottom concentration, ``t0`` [s] the time to half of it, ``tau`` [s] the
  time to 88 % of it.
* :func:`fit_beta` fits ``A(delta_R) = 1 - 1 / (2 delta_R^beta)`` over a campaign.
* :func:`fit_tau` fits the exponential law
  ``tau(delta_R) = tau_1 exp(-lambda (delta_R - 1))`` (``tau_1`` [s], ``lambda`` [-]).
* :func:`fit_campaign` does all three for the maps of a campaign.

Each returns a :class:`FitResult` with the parameters, their standard errors
(from the Jacobian at the optimum), the mean squared error and a
``converged`` flag: a fit that stops without converging says so in
``message`` and still returns what it has. :class:`granseg.FitError` is raised
only when no fit is possible at all (too few finite points).

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
from typing import Any

import numpy as np
from scipy.optimize import least_squares

from granseg.errors import FitError

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
    "covariance",
    "weighted_covariance",
]

TANH_TO_88 = float(np.tanh(1.0))  # f(tau) = A/2 (1 + tanh 1) = 0.8808 A


# --------------------------------------------------------------------------- laws


def tanh_curve(t: Any, A: float, t0: float, tau: float) -> np.ndarray:
    """Bottom-concentration law f(t) [-] at times ``t`` [s] (MODEL.md); needs tau > t0."""
    t = np.asarray(t, dtype=float)
    return 0.5 * A * (1.0 - np.tanh(-(t - t0) / (tau - t0)))


def beta_law(delta_R: Any, beta: float) -> np.ndarray:
    """Final bottom concentration A [-] against density ratio delta_R [-]."""
    return 1.0 - 0.5 / np.asarray(delta_R, dtype=float) ** beta


def tau_law(delta_R: Any, tau_1: float, lam: float) -> np.ndarray:
    """Exponential law tau(delta_R) = tau_1 exp(-lam (delta_R - 1)) [s]."""
    return tau_1 * np.exp(-lam * (np.asarray(delta_R, dtype=float) - 1.0))


# --------------------------------------------------------------------------- result


@dataclass(frozen=True)
class FitResult:
    """Outcome of one fit: ``params`` and ``stderr`` (same units), ``mse`` of the data.

    ``result["A"]`` is a shortcut for ``result.params["A"]``. ``n_points`` is
    the number of finite data points used; ``converged`` is False when the
    optimiser stopped for another reason than convergence (see ``message``).
    """

    model: str
    params: dict[str, float]
    stderr: dict[str, float]
    mse: float
    n_points: int
    converged: bool
    message: str

    def __getitem__(self, key: str) -> float:
        return self.params[key]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        return {
            "model": self.model, "params": dict(self.params), "stderr": dict(self.stderr),
            "mse": self.mse, "n_points": self.n_points, "converged": self.converged,
            "message": self.message,
        }


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
    model: str,
    names: tuple[str, ...],
    resid: Callable[[np.ndarray], np.ndarray],
    p0: np.ndarray,
    bounds: tuple[Any, Any],
    max_nfev: int | None,
) -> tuple[np.ndarray, np.ndarray, FitResult]:
    """Run least_squares; return (x, covariance, partial FitResult without mapping)."""
    res = least_squares(resid, p0, bounds=bounds, x_scale="jac", max_nfev=max_nfev)
    cov = covariance(res.jac, res.fun, len(names))
    converged = bool(res.success) and res.status > 0
    message = str(res.message) if converged else f"not converged: {res.message}"
    out = FitResult(
        model=model,
        params={n: float(v) for n, v in zip(names, res.x, strict=True)},
        stderr={n: float(np.sqrt(max(cov[i, i], 0.0))) if np.isfinite(cov[i, i]) else float("nan")
                for i, n in enumerate(names)},
        mse=float(np.mean(res.fun**2)),
        n_points=int(res.fun.size),
        converged=converged,
        message=message,
    )
    return res.x, cov, out


# --------------------------------------------------------------------------- tanh


def _tanh_start(t: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Start values (A, t0, tau - t0) read off the series."""
    tail = c[t >= t[0] + 0.8 * (t[-1] - t[0])]
    A = float(np.clip(np.mean(tail) if tail.size else c[-1], 1e-3, 1.0))
    t_half = t[np.argmax(c >= 0.5 * A)] if np.any(c >= 0.5 * A) else 0.5 * (t[0] + t[-1])
    t_88 = t[np.argmax(c >= TANH_TO_88 * A)] if np.any(c >= TANH_TO_88 * A) else t[-1]
    width = max(float(t_88 - t_half), 0.02 * float(t[-1] - t[0]), 1e-6)
    return np.array([A, float(t_half), width])


def fit_tanh(t: Any, c: Any, *, max_nfev: int | None = None) -> FitResult:
    """Fit the bottom series ``c`` [-] at times ``t`` [s] with :func:`tanh_curve`.

    Returns params ``A`` [-], ``t0`` [s], ``tau`` [s] with standard errors
    (``tau`` = t0 + width is fitted through the width > 0, its error includes
    the covariance). NaN entries are skipped. ``max_nfev`` caps the function
    evaluations (a capped fit is marked not converged).
    """
    t, c = _finite_xy(t, c, "fit_tanh", 4)
    p0 = _tanh_start(t, c)
    span = float(t[-1] - t[0]) or 1.0

    def resid(p: np.ndarray) -> np.ndarray:
        return tanh_curve(t, p[0], p[1], p[1] + p[2]) - c

    lower = [0.0, t[0] - 10 * span, 1e-9 * span]
    upper = [1.5, t[-1] + 10 * span, 100 * span]
    x, cov, raw = _solve("tanh", ("A", "t0", "width"), resid, p0, (lower, upper), max_nfev)
    tau_err = np.sqrt(max(cov[1, 1] + cov[2, 2] + 2 * cov[1, 2], 0.0))
    return FitResult(
        model="tanh",
        params={"A": float(x[0]), "t0": float(x[1]), "tau": float(x[1] + x[2])},
        stderr={"A": raw.stderr["A"], "t0": raw.stderr["t0"], "tau": float(tau_err)},
        mse=raw.mse, n_points=raw.n_points, converged=raw.converged, message=raw.message,
    )


# --------------------------------------------------------------------------- campaign laws


def fit_beta(delta_R: Any, A: Any, *, max_nfev: int | None = None) -> FitResult:
    """Fit ``A = 1 - 1 / (2 delta_R^beta)`` to final concentrations ``A`` [-].

    ``delta_R`` [-] must be >= 1 (heavy over light). Returns ``beta`` [-] with
    its standard error and the MSE of A.
    """
    x, y = _finite_xy(delta_R, A, "fit_beta", 2)
    if np.any(x < 1.0):
        raise ValueError(f"fit_beta: delta_R must be >= 1, got {x.min():g}")
    if np.all(x == 1.0):
        raise FitError("fit_beta: every delta_R is 1; beta is undetermined")
    return _solve("beta", ("beta",), lambda p: beta_law(x, p[0]) - y, np.array([2.0]),
                  ([0.0], [50.0]), max_nfev)[2]


def fit_tau(delta_R: Any, tau: Any, *, max_nfev: int | None = None) -> FitResult:
    """Fit ``tau = tau_1 exp(-lam (delta_R - 1))`` to segregation times ``tau`` [s].

    Returns ``tau_1`` [s] (tau extrapolated to delta_R = 1) and ``lam`` [-]
    with standard errors and the MSE [s^2].
    """
    x, y = _finite_xy(delta_R, tau, "fit_tau", 3)
    if np.any(y <= 0):
        raise ValueError("fit_tau: tau must be > 0 s")
    slope, icpt = np.polyfit(x - 1.0, np.log(y), 1)
    p0 = np.array([np.exp(icpt), max(-slope, 0.0)])
    return _solve("tau", ("tau_1", "lam"), lambda p: tau_law(x, p[0], p[1]) - y, p0,
                  ([0.0, -50.0], [np.inf, 50.0]), max_nfev)[2]


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
