"""The view's dwell (granseg.fitting.dwell): the lag on problems with a known answer, the
measurement on virtual campaigns whose window width the generator fixes, and what it buys
the calibration's intervals (seeds not used to build the method: it was tuned on 5000-5003)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from granseg.calibration import calibrate
from granseg.fitting import ExpInfo, dwell
from granseg.model import defaults
from granseg.synth import virtual
from granseg.synth.virtual import campaign

TRUTH = {"k": 0.70, "delta_over_H": 0.18}
GRID = {k: (v,) for k, v in TRUTH.items()}


@settings(max_examples=40, deadline=None)
@given(s=st.lists(st.floats(0.0, 0.999), min_size=3, max_size=3),
       c=st.lists(st.floats(0.0, 1.0), min_size=30, max_size=30))
def test_lag_is_the_slot_recursion_and_keeps_c_in_range(s, c):
    """lagged() is c_seen(i) = s c_seen(i-1) + (1 - s) c(i) from c_seen(0) = c(0), per layer."""
    seen = np.tile(np.asarray(c)[:, None], (1, 3))
    out = dwell.lagged(seen, np.asarray(s))
    ref = seen.copy()
    for j, sj in enumerate(s):
        for i in range(1, len(c)):
            ref[i, j] = sj * ref[i - 1, j] + (1 - sj) * seen[i, j]
    np.testing.assert_allclose(out, ref, atol=1e-12)
    assert (out >= -1e-12).all() and (out <= 1 + 1e-12).all()


def test_lag_leaves_a_steady_layer_and_a_fresh_view_alone():
    seen = np.column_stack([np.full(50, 0.3), np.linspace(0, 1, 50)])
    out = dwell.lagged(seen, np.array([0.95, 0.0]))
    np.testing.assert_allclose(out, seen)


def test_moving_average_factor_is_one_over_n_for_white_noise_and_one_for_frozen_noise():
    f = dwell.moving_average_factor(np.zeros(8), 40, 9)
    assert f[20] == pytest.approx(1 / 9)
    assert f[0] == pytest.approx(1.0)  # the centred average shrinks to one frame at the ends
    np.testing.assert_allclose(dwell.moving_average_factor(np.ones(8), 40, 9), 1.0)


def _measured(noise: str, seed: int) -> dwell.Dwell:
    maps = campaign(seed=seed, noise=noise)
    return dwell.measure(maps, [ExpInfo.of(m) for m in maps])


@pytest.mark.parametrize("noise", ["persistent", "variable_counts", "boundary_flips"])
def test_measured_window_and_shear_band_match_the_generator(noise):
    """The generator's grains leave a 9 D_p window at the model's speed: the fit of the counts'
    decorrelation finds the width and the shear band behind it."""
    d = _measured(noise, seed=71)
    assert d.applied, d.reason
    assert d.width / defaults()["D_p"] == pytest.approx(virtual.WINDOW_WIDTH_DP, rel=0.12), d.to_dict()
    assert d.delta_over_H == pytest.approx(TRUTH["delta_over_H"], abs=0.008), d.to_dict()
    assert len(d.survival) == 16 and all(np.all((s >= 0) & (s < 1)) for s in d.survival)
    top, bottom = d.survival[0][-1], d.survival[0][0]
    assert top > 0.9 > bottom  # the almost rigid top keeps its grains, the driven bottom renews them


def test_fresh_views_and_maps_without_counts_get_no_dwell():
    fresh = _measured("independent", seed=71)
    assert not fresh.applied and "new grains" in fresh.reason and fresh.rho1 < dwell.MIN_CORRELATION
    blind = _measured("no_counts", seed=71)
    assert not blind.applied and blind.reason.startswith("no counts")


def test_calibrate_records_the_dwell_and_flags_what_it_cannot_measure():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cal = calibrate(campaign(seed=72, noise="persistent")[:8], grid=GRID, progress=False)
        blind = calibrate(campaign(seed=72, noise="no_counts")[:8], grid=GRID, progress=False)
    assert cal.settings["dwell"]["applied"] and cal.data.dwell_width is not None
    assert not any("dwell" in n for n in cal.uncertainty.notes)
    assert not blind.settings["dwell"]["applied"] and blind.data.dwell_width is None
    assert any("dwell" in n for n in blind.uncertainty.notes)


def _coverage(noise: str, seeds: range) -> dict[str, float]:
    hits = dict.fromkeys(TRUTH, 0)
    for seed in seeds:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            cal = calibrate(campaign(seed=seed, noise=noise, **TRUTH), grid=GRID, progress=False)
        lo, hi = cal.uncertainty.interval
        for j, name in enumerate(cal.uncertainty.names):
            hits[name] += bool(lo[j] <= TRUTH[name] <= hi[j])
    return {k: v / len(seeds) for k, v in hits.items()}


@pytest.mark.parametrize("noise", ["persistent", "boundary_flips", "independent"])
def test_intervals_cover_the_truth_under_realistic_noise(noise):
    """Issue 18's test with fewer replicates: calibrate's default 95 % intervals contain the true k
    and delta/H in at least 85 % of 20 campaigns (the benchmark runs 200 per process)."""
    cover = _coverage(noise, range(7000, 7020))
    assert min(cover.values()) >= 0.85, cover


def test_the_dwell_is_what_removes_the_bias():
    """Without the dwell the persistent grains put delta/H several standard errors low; with it
    the mean offset over six campaigns is within 1.5 SE and under a quarter of the offset
    without (measured: -5.8 SE off, -0.9 SE on; the rest is a known residual, BENCHMARKS.md)."""
    z = {True: [], False: []}
    for seed in range(7100, 7106):
        maps = campaign(seed=seed, noise="persistent", **TRUTH)
        for on in (True, False):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                cal = calibrate(maps, grid=GRID, progress=False, view_dwell=on)
            z[on].append((cal.best["delta_over_H"] - TRUTH["delta_over_H"]) / cal.uncertainty.stderr[1])
    off, on = np.mean(z[False]), np.mean(z[True])
    assert off < -3 and abs(on) < 1.5 and abs(on) < abs(off) / 4, z
