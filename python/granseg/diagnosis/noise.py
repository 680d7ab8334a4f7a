"""The measurement-noise floor, estimated from the maps themselves.

"Beyond noise" needs a number: the RMSD [-] that a *perfect* model would still
show against a map, because the map counts a few spheres per layer and frame.

With counts (``n``, ``n_heavy``/``c_raw`` in the map, as the frame analysis
writes them) the per-frame variance of the heavy share is binomial,
var_raw = c (1 - c) / n, with c the smoothed map. Spheres that stay in view
from frame to frame make successive frames correlated; the lag-one
correlation rho_k of each layer at lag k follows from the scatter of
frames k apart, E[(c_raw(t+k) - c_raw(t))^2] = 2 var_raw (1 - rho_k), for
every lag inside the averaging window. The moving average of N frames then
leaves var_raw * (1/N^2) sum_{a,b} rho_|a-b| (N shrinks at the ends of the
series as the average does). The smoothed share is itself noisy, which biases
c (1 - c) low by the same factor; the estimate corrects for it.

Without counts only the frame-to-frame scatter of the map itself is
available: the variance of c(t + L) - c(t) at a lag L of one smoothing window
(where the averaging windows no longer overlap) is twice the noise variance
when the noise decorrelates within a window - a lower bound otherwise, and
flagged as such.

The floor of an experiment is sqrt(mean variance over its map's entries); the
campaign's floor is the mean over experiments, comparable with the mean RMSD.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from granseg.fitting.dwell import lag_correlation, moving_average_factor
from granseg.maps import Map, moving_average

__all__ = ["NoiseEstimate", "noise_floor", "campaign_floor"]


@dataclass(frozen=True)
class NoiseEstimate:
    """Noise floor of one map: ``floor`` [-] (expected RMSD of a perfect model),
    ``sd`` (n_t, n_layers) per-entry standard deviation [-], ``rho`` per-layer
    lag-one frame-to-frame correlation [-] (NaN if unknown), ``method``."""

    name: str
    floor: float
    sd: np.ndarray
    rho: np.ndarray
    method: str

    @property
    def counted(self) -> bool:
        """True when the floor comes from the map's counts (a model of the noise, not a lower bound)."""
        return self.method.startswith("counts")


def _from_counts(m: Map) -> NoiseEstimate:
    n = m.n.astype(float)
    c_raw = m.c_raw if m.c_raw is not None else np.where(n > 0, m.n_heavy / np.maximum(n, 1), np.nan)
    c_hat = np.clip(m.c, 0.0, 1.0)
    f = np.zeros_like(c_hat)
    for _ in range(2):
        # E[c_hat (1 - c_hat)] = c (1 - c) (1 - f / n) with f the averaging factor: undo that bias
        with np.errstate(invalid="ignore", divide="ignore"):
            var_raw = np.where(n > 0, c_hat * (1.0 - c_hat) / np.maximum(n - f, 0.5), np.nan)
        rho = lag_correlation(c_raw, var_raw, m.smoothing_frames - 1)
        f = np.column_stack([moving_average_factor(rho[j], m.n_times, m.smoothing_frames) for j in range(m.n_layers)])
    return _estimate(m, var_raw * f, rho[:, 0],
                     "counts (binomial, measured frame-to-frame correlation, moving average)")


def _from_scatter(m: Map) -> NoiseEstimate:
    lag = max(1, m.smoothing_frames)
    d = m.c[lag:] - m.c[:-lag]
    # the drift of the signal over one lag is removed by a wider average of the differences
    drift = moving_average(d, 2 * lag + 1 if lag > 1 else 3)
    var_layer = np.nanmean((d - drift) ** 2, axis=0) / 2.0
    var = np.broadcast_to(var_layer, m.c.shape).copy()
    return _estimate(m, var, np.full(m.n_layers, np.nan), "frame-to-frame scatter of c (lower bound)")


def _estimate(m: Map, var: np.ndarray, rho: np.ndarray, method: str) -> NoiseEstimate:
    mask = np.isfinite(m.c) & np.isfinite(var)
    floor = float(np.sqrt(np.mean(var[mask]))) if mask.any() else float("nan")
    return NoiseEstimate(m.name, floor, np.sqrt(np.clip(var, 0, None)), rho, method)


def noise_floor(m: Map) -> NoiseEstimate:
    """The noise floor of one map: from its counts if it has them, else from its scatter."""
    if m.n is not None and (m.n_heavy is not None or m.c_raw is not None):
        return _from_counts(m)
    return _from_scatter(m)


def campaign_floor(maps: list[Map]) -> tuple[float, list[NoiseEstimate]]:
    """Mean noise floor [-] over the experiments, and each experiment's estimate."""
    est = [noise_floor(m) for m in maps]
    return float(np.nanmean([e.floor for e in est])), est
