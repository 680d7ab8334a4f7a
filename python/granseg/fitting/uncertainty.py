"""Standard errors, intervals and correlations of fitted parameters: one implementation.

Every fit in granseg ends at the optimum of a least-squares problem: a
Gauss-Newton matrix A = J'J (plus the prior's rows) and the residuals r.
How far the estimate would move under new noise depends on how the noise of
different entries is correlated, and the maps' noise is: a grain stays in
view for many frames where the bed barely moves, the moving average spreads
every frame over ``smoothing_frames``, neighbouring layers share grains.
Counting every (time, layer) entry as an independent observation (the
``"jacobian"`` method) then states errors several times too small.

The robust methods group the entries into clusters that are independent of
one another and let the data say how the noise inside a cluster is
correlated, through each cluster's score s_c = J_c' r_c:

``"cluster"``
    sandwich A^-1 (G/(G-1) sum_c s_c s_c') A^-1 over G clusters (optionally with
    the scores corrected for the clusters' leverage, CR2: :func:`cluster_covariance`);
``"jackknife"``
    (G-1)/G sum_c (x_(c) - mean)(x_(c) - mean)' over the leave-one-cluster-out
    estimates x_(c), each one Gauss-Newton step from the optimum;
``"jacobian"``
    s^2 A^-1 with independent entries (inflated by the smoothing width for a
    campaign fit): today's sandwich, kept to compare with.

A campaign's clusters are its experiments; one series' clusters are blocks
of consecutive times (:func:`time_blocks`). Intervals use Student's t with
G - 1 degrees of freedom (the score covariance is estimated from G sums),
which matters for the few experiments a campaign has. Which method granseg
uses by default was chosen by measured coverage (benches/bench_coverage.py,
BENCHMARKS.md "Uncertainty").
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["LEVEL", "METHODS", "Uncertainty", "cluster_covariance", "describe", "jackknife_covariance",
           "time_blocks"]

METHODS = ("cluster", "jackknife", "jacobian")
#: Default coverage of the intervals [-].
LEVEL = 0.95
#: An interval "touches" a bound when it reaches within this share of the range of it.
BOUND_MARGIN = 1e-6
#: Largest share of a cluster's noise the CR2 correction takes the fit to have absorbed (a
#: cluster holding a parameter's whole information has scores of ~0 there; the cap keeps them finite).
MAX_LEVERAGE = 0.999


def cluster_covariance(A: np.ndarray, scores: np.ndarray, cluster_A: np.ndarray | None = None) -> np.ndarray:
    """Cluster-robust sandwich A^+ B A^+, B = G/(G-1) sum_c s_c s_c' (``scores`` (G, p)).

    ``cluster_A`` (G, p, p), each cluster's own J_c'J_c: given, every score is
    first corrected for the part of its cluster's noise the fit absorbed, which
    matters when a few clusters carry most of a parameter's information (CR2,
    Bell & McCaffrey 2002): s_c <- A^{1/2} (I - S_c)^{-1/2} A^{-1/2} s_c with
    S_c = A^{-1/2} A_c A^{-1/2}, its eigenvalues capped at :data:`MAX_LEVERAGE`
    (B keeps the G/(G-1)).

    NaN when there are fewer than 2 clusters (the spread of the scores is then unknown).
    """
    scores = np.atleast_2d(np.asarray(scores, dtype=float))
    n_c, p = scores.shape
    if n_c < 2:
        return np.full((p, p), np.nan)
    a_inv = np.linalg.pinv(A)
    if cluster_A is not None:
        scores = _leverage_corrected(np.asarray(A, dtype=float), np.asarray(cluster_A, dtype=float), scores)
    return a_inv @ (scores.T @ scores * (n_c / (n_c - 1))) @ a_inv


def _leverage_corrected(A: np.ndarray, cluster_A: np.ndarray, scores: np.ndarray) -> np.ndarray:
    """CR2 scores A^{1/2} (I - S_c)^{-1/2} A^{-1/2} s_c (see :func:`cluster_covariance`)."""
    w, v = np.linalg.eigh((A + A.T) / 2)
    keep = w > w.max(initial=0.0) * 1e-12
    root = np.where(keep, np.sqrt(np.clip(w, 0.0, None)), 0.0)
    root_inv = np.divide(1.0, root, out=np.zeros_like(root), where=keep)
    a_half, a_half_inv = (v * root) @ v.T, (v * root_inv) @ v.T
    s = a_half_inv @ cluster_A @ a_half_inv
    lev, vec = np.linalg.eigh((s + np.swapaxes(s, 1, 2)) / 2)
    shrink = (vec / np.sqrt(1.0 - np.clip(lev, 0.0, MAX_LEVERAGE))[:, None, :]) @ np.swapaxes(vec, 1, 2)
    return np.einsum("ij,cjk,kl,cl->ci", a_half, shrink, a_half_inv, scores)


def jackknife_covariance(estimates: np.ndarray) -> np.ndarray:
    """Jackknife covariance (G-1)/G sum_c (x_(c) - mean)(x_(c) - mean)' of leave-one-out estimates (G, p)."""
    est = np.atleast_2d(np.asarray(estimates, dtype=float))
    n_c, p = est.shape
    if n_c < 2:
        return np.full((p, p), np.nan)
    d = est - est.mean(axis=0)
    return (n_c - 1) / n_c * (d.T @ d)


def time_blocks(t: np.ndarray, block_s: float) -> np.ndarray:
    """Block index of each time ``t`` [s]: consecutive blocks ``block_s`` long from the first time."""
    t = np.asarray(t, dtype=float)
    if not block_s > 0:
        raise ValueError(f"block_s = {block_s!r}: the block length must be > 0 s")
    return np.floor((t - t[0]) / block_s).astype(np.int64)


@dataclass(frozen=True)
class Uncertainty:
    """Estimates, covariance and ``level`` intervals of a fit's parameters.

    ``dof`` is the t quantile's degrees of freedom (inf: normal); ``lo``/``hi``
    the intervals, clipped to the parameters' ``bounds``; ``at_bound`` names the
    parameters whose interval touches a bound (the interval is then cut there and
    does not mean what it says); ``notes`` say what else to know.
    """

    method: str
    names: list[str]
    estimate: np.ndarray
    cov: np.ndarray
    dof: float
    bounds: tuple[np.ndarray, np.ndarray]
    level: float = LEVEL
    notes: list[str] = field(default_factory=list)

    @property
    def stderr(self) -> np.ndarray:
        """Standard errors (NaN where unknown)."""
        d = np.diag(self.cov) if self.cov.size else np.zeros(0)
        return np.sqrt(np.where(np.isfinite(d), np.clip(d, 0.0, None), np.nan))

    @property
    def quantile(self) -> float:
        """Half-width of the interval in standard errors."""
        from scipy import stats  # here: see granseg.fitting on import time

        q = 0.5 + self.level / 2
        return float(stats.norm.ppf(q) if not np.isfinite(self.dof) else stats.t.ppf(q, self.dof))

    @property
    def interval(self) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) of every parameter, within its bounds."""
        half = self.quantile * self.stderr
        lo, hi = self.bounds
        return np.maximum(self.estimate - half, lo), np.minimum(self.estimate + half, hi)

    @property
    def correlation(self) -> np.ndarray:
        """Correlation matrix of the estimates (NaN where an error is unknown or 0)."""
        se = self.stderr
        with np.errstate(invalid="ignore", divide="ignore"):
            return self.cov / np.outer(se, se)

    @property
    def at_bound(self) -> list[str]:
        """Parameters whose interval reaches a bound of their range."""
        half = self.quantile * self.stderr
        lo, hi = self.bounds
        with np.errstate(invalid="ignore"):
            tol = np.where(np.isfinite(hi - lo), BOUND_MARGIN * (hi - lo), 0.0)  # an open range has no margin
        return [n for j, n in enumerate(self.names)
                if np.isfinite(half[j]) and (self.estimate[j] - half[j] <= lo[j] + tol[j]
                                             or self.estimate[j] + half[j] >= hi[j] - tol[j])]

    def warnings(self) -> list[str]:
        """Plain sentences for what a reader of the intervals must know."""
        out = [f"the {100 * self.level:.0f} % interval of {n} reaches a bound of its range; it is cut there "
               f"and the estimate may lie beyond" for n in self.at_bound]
        bad = [n for n, s in zip(self.names, self.stderr, strict=True) if not np.isfinite(s)]
        if bad:
            out.append(f"no standard error for {', '.join(bad)} ({self.method}: too few clusters or "
                       f"a parameter the data do not constrain)")
        return out + list(self.notes)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: method, level, dof, per parameter estimate / stderr / lo / hi, correlation, warnings."""
        lo, hi = self.interval
        corr = self.correlation

        def num(v: float) -> float | None:
            return float(v) if np.isfinite(v) else None

        return {"method": self.method, "level": self.level, "dof": num(self.dof),
                "params": {n: {"estimate": float(self.estimate[j]), "stderr": num(self.stderr[j]),
                               "lo": num(lo[j]), "hi": num(hi[j]), "at_bound": n in self.at_bound}
                           for j, n in enumerate(self.names)},
                "correlation": [[num(v) for v in row] for row in corr],
                "warnings": self.warnings()}


def describe(method: str, names: Sequence[str], x: np.ndarray, cov: np.ndarray, n_clusters: int | None,
             bounds: tuple[np.ndarray, np.ndarray], level: float = LEVEL,
             notes: Sequence[str] = (), dof: float | None = None) -> Uncertainty:
    """An :class:`Uncertainty` from a covariance by ``method`` over ``n_clusters`` clusters
    (t with n - 1 degrees of freedom; None: entries, normal quantile).

    ``dof`` overrides the t quantile's degrees of freedom, e.g. m - p for the classical
    s^2 (J'J)^-1 of m independent points and p parameters (<= 0: unknown, NaN)."""
    if method not in METHODS:
        raise ValueError(f"method = {method!r}: choose one of {', '.join(METHODS)}")
    if not 0 < level < 1:
        raise ValueError(f"level = {level!r}: must lie in (0, 1)")
    if dof is not None:
        dof = float(dof) if dof > 0 else float("nan")
    else:
        dof = float("inf") if n_clusters is None else float(max(n_clusters - 1, 0)) or float("nan")
    lo, hi = (np.asarray(b, dtype=float) for b in bounds)
    return Uncertainty(method, list(names), np.asarray(x, dtype=float), np.asarray(cov, dtype=float), dof,
                       (lo, hi), level, list(notes))
