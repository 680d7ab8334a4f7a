"""Probe (issue 18): is the calibration's bias under persistent grains the view's lag?

    RAYON_NUM_THREADS=2 python benches/probe_view_lag.py --seed 5

A sphere stays in view until the flow carries it out of the window, so the
wall shows each layer's composition low-passed over the dwell time. This
probe calibrates the same campaign with the model map as is, and passed
through the first-order lag c_seen(i) = s c_seen(i-1) + (1 - s) c(i) per
layer, with the survival s per frame either the generator's own (oracle; a
campaign with 2000 spheres per layer, so no counting noise) or estimated
from the counts' decorrelation (log-linear in the lag, per layer). It
patches the fitting layer's model_maps for the run: a probe, not a method.
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy.signal import lfilter

import granseg.fitting.solve as solve
from granseg.calibration import calibrate
from granseg.fitting import observe
from granseg.fitting.dwell import lag_correlation
from granseg.maps import moving_average
from granseg.synth import virtual
from granseg.synth.virtual import NoiseProcess, campaign

GRID = {"k": (0.7,), "delta_over_H": (0.18,)}


def measured_survival(m, max_lag: int = 30) -> np.ndarray:
    """Per-layer survival per frame from the decay of the counts' correlation with lag."""
    n = m.n.astype(float)
    c_raw = np.where(n > 0, m.n_heavy / np.maximum(n, 1), np.nan)
    c = np.clip(m.c, 0, 1)
    rho = lag_correlation(c_raw, np.where(n > 0, c * (1 - c) / np.maximum(n, 0.5), np.nan), max_lag)
    lags = np.arange(1, max_lag + 1)
    s = np.zeros(rho.shape[0])
    for j, r in enumerate(rho):
        ok = r > 0.05
        if ok.sum() >= 3:
            s[j] = float(np.clip(np.exp(np.polyfit(lags[ok], np.log(r[ok]), 1)[0]), 0, 0.9999))
    return s


def lagged(c: np.ndarray, s: np.ndarray) -> np.ndarray:
    out = c.copy()
    for j in np.nonzero(s > 0)[0]:
        out[:, j] = lfilter([1 - s[j]], [1, -s[j]], c[:, j], zi=[s[j] * c[0, j]])[0]
    return out


def with_lag(survival: dict[str, np.ndarray]):
    """model_maps with the lag between the observation and the moving average."""
    def model_maps(data, effect, runs):
        cases, times, rows = [], [], []
        for x, i in runs:
            request, index = observe.shifted_times(data.maps[i].t, effect.time_shift(x, data.exps[i]))
            cases.append({**data.fixed, **effect.solver_params(x, data.exps[i])})
            times.append(request)
            rows.append(index)
        res = observe.sweep(cases=cases, t=times, progress=False, **data.opts)
        out = []
        for (x, i), raw, index in zip(runs, res.layers, rows, strict=True):
            seen = effect.observe(x, data.exps[i], np.asarray(raw)[index])
            if data.confusion is not None and data.confusion[i] > 0:
                seen = data.confusion[i] + (1.0 - 2.0 * data.confusion[i]) * seen
            out.append(moving_average(lagged(seen, survival[data.maps[i].name]), data.maps[i].smoothing_frames))
        return out
    return model_maps


def calibrated(maps, survival=None) -> dict[str, float]:
    plain = solve.model_maps
    solve.model_maps = plain if survival is None else with_lag(survival)
    try:
        return calibrate(maps, grid=GRID, progress=False).best
    finally:
        solve.model_maps = plain


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=5)
    args = ap.parse_args()
    truth_s: list[np.ndarray] = []
    spy = virtual._persistence
    virtual._persistence = lambda *a: truth_s.append(spy(*a)[0]) or spy(*a)
    try:
        maps = campaign(seed=args.seed, noise=NoiseProcess("dense", n_particles=(2000, 2000)))
    finally:
        virtual._persistence = spy
    oracle = {m.name: s for m, s in zip(maps, truth_s, strict=True)}
    print("2000 spheres per layer, no lag:      ", calibrated(maps))
    print("2000 spheres per layer, oracle lag:  ", calibrated(maps, oracle))
    for noise in ("persistent", "variable_counts"):
        maps = campaign(seed=args.seed, noise=noise)
        print(f"{noise}, no lag:       ", calibrated(maps))
        print(f"{noise}, measured lag: ", calibrated(maps, {m.name: measured_survival(m) for m in maps}))


if __name__ == "__main__":
    main()
