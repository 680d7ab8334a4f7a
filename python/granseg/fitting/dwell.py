"""The view's dwell: a grain stays in view until the flow carries it out of the window.

The camera counts the grains in a window of the side wall. Near the driven
bottom the flow replaces them every frame; near the almost rigid top the same
grains stay in view for minutes. The wall then shows each layer's composition
late: if a grain survives from one frame to the next with probability s_j
(layer j), the expected share in view follows the bed's share c through the
first-order lag

    c_seen(i) = s_j c_seen(i - 1) + (1 - s_j) c(i),     c_seen(0) = c(0),

which a fit that compares the bed's share directly with the map mistakes for a
slower top: in virtual campaigns with persistent grains it put delta/H 1-2 %
low, 4-5 of its standard errors (``benches/probe_view_lag.py``).

The survival is measured from the maps' counts, not assumed. A grain leaves
when the flow has carried it across the window's width W, so per frame
s_j = exp(-|v(z_j)| dt / W) with v the shear profile v(z) = v0 exp(-z / delta)
of docs/model.md. Only W is carried into the fits: each model run lags its map
with its own velocity profile (:func:`survival`), so a cause that changes the
shear band of some experiments (a load-dependent band) changes their dwell
with it, as it does in the bed. The counting noise of a layer is then correlated over lag l
frames as a s_j^l (a <= 1: the count itself changes from frame to frame,
misread grains do not persist). :func:`measure` fits W, delta/H and one
overlap a per experiment to the measured correlations at lags 1 to
:data:`MAX_LAG` of every layer of every experiment at once (each layer weighted
by its counting variance, so pure layers, which carry no information, do not
count). The delta/H it finds comes from the noise alone: a cross-check of
the calibration, not an input to it.

Where the counts are not correlated (pooled lag-one correlation below
:data:`MIN_CORRELATION`) every frame shows new grains and nothing is applied.
Without counts the dwell cannot be measured: nothing is applied and the
record says so (the bias then remains).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from granseg import _core
from granseg.maps import Map
from granseg.model import defaults, velocity_profile

__all__ = ["MAX_LAG", "MIN_CORRELATION", "Dwell", "lag_correlation", "lagged", "measure", "moving_average_factor",
           "survival"]

#: Lags [frames] of the correlations fitted.
MAX_LAG = 20
#: Pooled lag-one correlation of the counting noise below which the view is taken as fresh every frame.
MIN_CORRELATION = 0.1
#: Range of the window width W searched [D_p].
WIDTH_RANGE_DP = (0.3, 300.0)
#: Range of the shear band's delta/H searched.
DELTA_RANGE = (0.02, 1.0)


@dataclass(frozen=True)
class Dwell:
    """The measured dwell of grains in view.

    ``survival`` per experiment (n_layers,) per frame [-] at the measured
    delta/H (None where not applied); ``width`` W [m] and ``delta_over_H``
    [-] of the fit; ``rho1``
    the pooled lag-one correlation of the counting noise; ``overlap`` the
    mean fitted a; ``reason`` why it is or is not applied.
    """

    applied: bool
    reason: str
    survival: list[np.ndarray] | None = None
    width: float = float("nan")
    delta_over_H: float = float("nan")
    rho1: float = float("nan")
    overlap: float = float("nan")

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready record (no per-layer arrays beyond the mean dwell per layer in frames)."""
        out: dict[str, Any] = {"applied": self.applied, "reason": self.reason}
        if np.isfinite(self.width):
            out.update(width_Dp=self.width / defaults()["D_p"], delta_over_H=self.delta_over_H,
                       rho1=self.rho1, overlap=self.overlap)
        return out


def lag_correlation(c_raw: np.ndarray, var_raw: np.ndarray, max_lag: int) -> np.ndarray:
    """Correlation (n_layers, max_lag) of the counting noise at lags 1..max_lag, in [0, 0.995].

    From E[(c_raw(t+k) - c_raw(t))^2] = 2 var_raw (1 - rho_k): no shape is
    assumed for the decay. Layers with too few readings take the median over
    layers.
    """
    n_l = c_raw.shape[1]
    rho = np.full((n_l, max(max_lag, 1)), np.nan)
    for k in range(1, max_lag + 1):
        d2 = (c_raw[k:] - c_raw[:-k]) ** 2
        v = 0.5 * (var_raw[k:] + var_raw[:-k])
        ok = np.isfinite(d2) & np.isfinite(v)
        for j in range(n_l):
            vj = v[ok[:, j], j].sum()
            if ok[:, j].sum() > 10 and vj > 1e-9 * ok[:, j].sum():
                rho[j, k - 1] = 1.0 - d2[ok[:, j], j].sum() / (2.0 * vj)
    fill = np.nanmedian(rho, axis=0) if np.any(np.isfinite(rho)) else np.zeros(rho.shape[1])
    fill = np.where(np.isfinite(fill), fill, 0.0)
    return np.clip(np.where(np.isfinite(rho), rho, fill[None, :]), 0.0, 0.995)


def moving_average_factor(rho: np.ndarray, n_t: int, window: int) -> np.ndarray:
    """Variance reduction (n_t,) of the centred moving average of noise with
    lag correlations ``rho[k-1]`` (k = 1 .. window-1)."""
    half = (window - 1) // 2
    i = np.arange(n_t)
    h = np.minimum(np.minimum(half, i), n_t - 1 - i)
    out = np.empty(n_t)
    for hh in np.unique(h):
        n = 2 * hh + 1
        k = np.arange(1, n)
        out[h == hh] = (n + 2.0 * float(((n - k) * rho[: n - 1]).sum())) / n**2
    return out


def lagged(seen: np.ndarray, survival: np.ndarray) -> np.ndarray:
    """The expected share in view (n_t, n_layers) when each layer's grains survive a frame with ``survival``."""
    # y[0] = x[0], y[t] = (1 - s) x[t] + s y[t-1]: in the core (scipy's lfilter, one call per
    # layer, took most of a diagnosis's time)
    return _core.lagged(np.ascontiguousarray(seen, dtype=float), np.ascontiguousarray(survival, dtype=float))


def _counted(m: Map, max_lag: int) -> tuple[np.ndarray, np.ndarray] | None:
    """Per-layer noise correlation (n_layers, max_lag) and counting variance (n_t, n_layers)
    of a map's per-frame share, None without counts.

    The binomial variance c (1 - c) / n takes c from the smoothed map, whose
    own noise biases c (1 - c) low by the moving average's variance factor f
    (large where grains persist: averaging the same grains removes little);
    two rounds of correlation -> factor -> variance undo it, as the noise
    floor does (:mod:`granseg.diagnosis.noise`).
    """
    if m.n is None or (m.n_heavy is None and m.c_raw is None):
        return None
    n = m.n.astype(float)
    share = m.c_raw if m.c_raw is not None else np.where(n > 0, m.n_heavy / np.maximum(n, 1), np.nan)
    c = np.clip(m.c, 0.0, 1.0)
    f = np.zeros_like(c)
    lags = max(max_lag, m.smoothing_frames - 1)
    for _ in range(2):
        with np.errstate(invalid="ignore", divide="ignore"):
            var = np.where(n > 0, c * (1.0 - c) / np.maximum(n - f, 0.5), np.nan)
        rho = lag_correlation(share, var, lags)
        f = np.column_stack([moving_average_factor(rho[j], m.n_times, m.smoothing_frames)
                             for j in range(m.n_layers)])
    return rho[:, :max_lag], var


def _speed_per_frame(params: dict[str, float], m: Map) -> np.ndarray:
    """|v(z_j)| dt [m] per layer: the distance the wall's grains travel between frames
    (the profile at t = 0: a drifting band is taken at its start)."""
    dt = float(np.median(np.diff(m.t))) if m.n_times > 1 else 0.0
    return np.abs(velocity_profile(np.asarray(m.z, dtype=float), 0.0, **params)[0]) * dt


def survival(params: dict[str, float], m: Map, width: float) -> np.ndarray:
    """Survival per frame (n_layers,) of a grain in view of map ``m`` when the bed moves with the
    velocity profile of the model parameters ``params`` and the window is ``width`` [m] wide."""
    # every model map of every fit asks, mostly with parameters it asked before (a law knot or
    # an observation parameter moves nothing here): a small cache keyed by value, per map
    key = (id(m), m.n_times, float(width), tuple(sorted(params.items())))
    hit = _SURVIVAL.get(key)
    if hit is None or hit[0] is not m:
        if len(_SURVIVAL) >= 4096:
            _SURVIVAL.clear()
        value = np.exp(-_speed_per_frame(params, m) / width)
        value.flags.writeable = False  # shared by every caller
        hit = _SURVIVAL[key] = (m, value)
    return hit[1]


_SURVIVAL: dict[tuple[Any, ...], tuple[Map, np.ndarray]] = {}


def _params(exp: Any, delta_over_H: float, fixed: dict[str, float]) -> dict[str, float]:
    return {**fixed, **exp.case(), "delta_over_H": delta_over_H}


def measure(maps: Sequence[Map], exps: Sequence[Any], fixed: dict[str, float] | None = None) -> Dwell:
    """Measure the dwell of grains in view from the maps' counts (see the module text)."""
    fixed = dict(fixed or {})
    rows = []
    for m, e in zip(maps, exps, strict=True):
        counted = _counted(m, MAX_LAG) if m.n_times > 2 * MAX_LAG else None
        if counted is None:
            continue
        rho, var = counted
        w = np.nansum(var, axis=0)
        if w.sum() > 0:
            rows.append((m, e, rho, w / w.sum()))
    if not rows:
        why = ("no counts in the maps" if all(m.n is None for m in maps)
               else f"no map with counts has more than {2 * MAX_LAG} frames")
        return Dwell(False, f"{why}: the dwell of grains in view cannot be measured; "
                            "where grains stay in view, delta/H comes out about 1-2 % low")
    rho1 = float(np.mean([(w * r[:, 0]).sum() for _, _, r, w in rows]))
    if rho1 < MIN_CORRELATION:
        return Dwell(False, f"the counts decorrelate within a frame (pooled lag-one correlation "
                            f"{rho1:.2f} < {MIN_CORRELATION}): every frame shows new grains", rho1=rho1)
    lags = np.arange(1, MAX_LAG + 1)

    def residual(x: np.ndarray) -> np.ndarray:
        inv_width, delta = np.exp(x[0]), x[1]
        out = []
        for m, e, r, w in rows:
            pred = np.exp(-_speed_per_frame(_params(e, delta, fixed), m) * inv_width)[:, None] ** lags[None, :]
            ww = np.sqrt(w)[:, None]
            a = np.clip((w[:, None] * r * pred).sum() / max((w[:, None] * pred**2).sum(), 1e-12), 0.0, 1.0)
            out.append((ww * (r - a * pred)).ravel())
        return np.concatenate(out)

    D_p = {**fixed, **rows[0][1].case()}.get("D_p", defaults()["D_p"])  # the campaign's cell
    lo = [-np.log(WIDTH_RANGE_DP[1] * D_p), DELTA_RANGE[0]]
    hi = [-np.log(WIDTH_RANGE_DP[0] * D_p), DELTA_RANGE[1]]
    x0 = [-np.log(10.0 * D_p), fixed.get("delta_over_H", defaults()["delta_over_H"])]
    from scipy.optimize import least_squares  # here: see granseg.fitting on import time

    sol = least_squares(residual, x0, bounds=(lo, hi))
    width, delta = float(np.exp(-sol.x[0])), float(sol.x[1])
    overlaps = []
    for m, e, r, w in rows:
        pred = survival(_params(e, delta, fixed), m, width)[:, None] ** lags[None, :]
        overlaps.append(float(np.clip((w[:, None] * r * pred).sum() / max((w[:, None] * pred**2).sum(), 1e-12), 0, 1)))
    seen = [survival(_params(e, delta, fixed), m, width) for m, e in zip(maps, exps, strict=True)]
    return Dwell(True, f"measured from the counts' decorrelation ({len(rows)} of {len(maps)} maps with counts)",
                 seen, width, delta, rho1, float(np.mean(overlaps)))
