"""Named measurement-noise processes of virtual campaigns (granseg.synth.virtual.NOISE_PROCESSES)."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest

from granseg.maps import load_campaign, moving_average
from granseg.synth.virtual import NOISE_PROCESSES, Condition, NoiseProcess, _flip, campaign

SPOM = Condition("steel", "POM", 0.5, 5.73)  # strongly segregating: pure heavy bottom, pure light top
SMALL = [SPOM, Condition("glass", "PP", 0.5, 2.04)]
UPPER = (10, 11, 12, 13, 14)  # nearly rigid layers: the same spheres stay in view for minutes


def _one(noise, seed=5, **kw):
    return campaign(conditions=[SPOM], seed=seed, noise=noise, **kw)[0]


def _lag1(m, clean, j):
    d = m.c_raw[:, j] - clean.c[:, j]
    return np.corrcoef(d[1:], d[:-1])[0, 1]


def test_noise_true_is_todays_persistent_process_unchanged():
    # sha256 of (n, n_heavy) as little-endian int64, map by map, computed with the code
    # before noise processes existed (git show 1e252d5:python/granseg/synth/virtual.py)
    # for campaign(conditions=SMALL, seed=3, duration=600.0)
    before = "d741ee5915395a78e0757f98a7aab99937b2bb79b0a8a9d176793830ce8fe15a"
    runs = [campaign(conditions=SMALL, seed=3, duration=600.0, noise=noise)
            for noise in (True, "persistent", NoiseProcess(name="persistent"))]
    h = hashlib.sha256()
    for m in runs[0]:
        h.update(np.ascontiguousarray(m.n, dtype="<i8").tobytes())
        h.update(np.ascontiguousarray(m.n_heavy, dtype="<i8").tobytes())
        np.testing.assert_array_equal(m.c_raw, m.n_heavy / m.n)
        np.testing.assert_array_equal(m.c, np.clip(moving_average(m.c_raw, m.smoothing_frames), 0, 1))
    assert h.hexdigest() == before
    for other in runs[1:]:
        for a, b in zip(runs[0], other, strict=True):
            for key in ("c", "c_raw", "n", "n_heavy"):
                np.testing.assert_array_equal(getattr(a, key), getattr(b, key))


def test_every_process_writes_valid_maps_and_is_recorded(tmp_path):
    combined = NoiseProcess(persistent=False, n_particles=(8, 12), misclassified=0.1, boundary_flips=0.1,
                            dropped_frames=0.1)
    for noise in [*NOISE_PROCESSES, combined]:
        proc = NOISE_PROCESSES[noise] if isinstance(noise, str) else noise
        out = tmp_path / proc.name
        maps = campaign(out, conditions=SMALL, seed=2, duration=600.0, noise=noise)
        camp = load_campaign(out)  # docs/formats.md validation on reading back
        assert camp.names == sorted(m.name for m in maps)
        truth = json.loads((out / "campaign.json").read_text())
        assert truth["noise"] == proc.record() and truth["noise"]["name"] == proc.name
        for m in maps:
            if not proc.counts:
                assert m.n is None and m.n_heavy is None and m.c_raw is None and np.isfinite(m.c).all()
                continue
            assert m.n is not None and m.n_heavy is not None and np.all(m.n_heavy <= m.n)
            ok = m.n > 0
            np.testing.assert_allclose(m.c_raw[ok], m.n_heavy[ok] / m.n[ok])
            assert np.all(np.isnan(m.c_raw[~ok])) and np.all(np.isnan(m.c[~ok]))
            if not (proc.boundary_flips or proc.dropped_frames):
                lo, hi = proc.n_particles
                assert m.n.min() >= lo and m.n.max() <= hi
    truth = json.loads((tmp_path / "persistent" / "campaign.json").read_text())
    assert truth["noise"] == {"name": "persistent", "persistent": True, "n_particles": [9, 11],
                              "misclassified": 0.0, "boundary_flips": 0.0, "dropped_frames": 0.0,
                              "counts": True}
    exact = campaign(tmp_path / "exact", conditions=SMALL[:1], duration=600.0, noise=False)[0]
    assert exact.c_raw is None and json.loads((tmp_path / "exact" / "campaign.json").read_text())["noise"] is False


def test_independent_counts_decorrelate_where_persistent_ones_stay():
    clean = _one(False)
    ind, per = _one("independent"), _one("persistent")
    lag_ind = [_lag1(ind, clean, j) for j in UPPER]
    lag_per = [_lag1(per, clean, j) for j in UPPER]
    # measured (seed 5): independent -0.013 .. 0.052, persistent 0.88 .. 0.97
    assert max(abs(v) for v in lag_ind) < 0.12 and abs(np.mean(lag_ind)) < 0.05
    assert min(lag_per) > 0.7
    assert abs(_lag1(ind, clean, 0)) < 0.12  # the bottom is renewed every frame either way


def test_misclassified_shifts_pure_layers_by_the_share():
    clean = _one(False)
    late = (clean.t > 0.5 * clean.t[-1])[:, None]
    heavy, light = late & (clean.c > 0.99), late & (clean.c < 0.01)  # bottom 4, top 5 layers
    assert heavy.sum() > 1000 and light.sum() > 1000
    shifts = []
    for seed in (1, 2):
        mis, per = _one("misclassified", seed), _one("persistent", seed)
        shifts.append(per.c_raw[heavy].mean() - mis.c_raw[heavy].mean())  # heavy read as light
        shifts.append(mis.c_raw[light].mean() - per.c_raw[light].mean())  # light read as heavy
    # measured: 0.052, 0.049, 0.049, 0.048; expected f (1 - 2 c_pure) ~ 0.05
    np.testing.assert_allclose(shifts, 0.05, atol=0.012)
    custom = _one(NoiseProcess(misclassified=0.2), 1)
    assert abs(custom.c_raw[light].mean() - 0.2) < 0.05  # measured 0.202


def test_dropped_frames_are_nan_rows_in_the_stated_share():
    for share in (0.03, 0.2):
        m = _one(NOISE_PROCESSES["dropped_frames"] if share == 0.03 else NoiseProcess(dropped_frames=share))
        lost = np.all(m.n == 0, axis=1)
        assert abs(lost.mean() - share) <= 1.0 / m.n_times  # measured 84 of 2791 rows = 0.0301 at 0.03
        assert np.all(np.isnan(m.c_raw[lost])) and np.all(np.isnan(m.c[lost]))
        assert np.all(np.isfinite(m.c[~lost])) and np.all(m.n[~lost] >= 9)
        # the moving average skips the missing rows, as granseg.maps.moving_average does
        expected = np.clip(moving_average(m.c_raw, m.smoothing_frames), 0, 1)
        np.testing.assert_allclose(m.c[~lost], expected[~lost])


def test_boundary_flips_move_counts_between_neighbours_and_keep_each_frames_total():
    per, flip = _one("persistent"), _one("boundary_flips")
    # the spheres in view per layer and frame are drawn before any flip: the totals are the same
    np.testing.assert_array_equal(flip.n.sum(axis=1), per.n.sum(axis=1))
    assert flip.n.min() < 9 and flip.n.max() > 11 and np.any(flip.n != per.n)
    rng = np.random.default_rng(0)
    in_view = np.arange(11)[None, :] < rng.integers(9, 12, size=(15, 1))
    heavy = in_view & (rng.random((15, 11)) < 0.5)
    for p in (0.05, 0.5):
        n, n_heavy = _flip(in_view, heavy, p, rng)
        assert n.sum() == in_view.sum() and n_heavy.sum() == heavy.sum()
        assert np.all(n_heavy <= n)
        # a sphere moves one layer at most: the cumulative count shifts by no more than a layer's worth
        assert np.all(np.abs(np.cumsum(n) - np.cumsum(in_view.sum(axis=1))) <= 11)
    n, n_heavy = _flip(in_view, heavy, 0.0, rng)
    np.testing.assert_array_equal(n, in_view.sum(axis=1))
    np.testing.assert_array_equal(n_heavy, heavy.sum(axis=1))


def test_variable_counts_and_n_particles_override():
    m = _one("variable_counts", duration=600.0)
    assert m.n.min() == 8 and m.n.max() == 12
    o = _one("independent", duration=600.0, n_particles=(20, 20))
    assert np.all(o.n == 20)


@pytest.mark.parametrize("make, word", [
    (lambda: campaign(noise="cosmic_rays"), "noise"),
    (lambda: campaign(noise=0.5), "noise"),
    (lambda: NoiseProcess(misclassified=0.5), "misclassified"),
    (lambda: NoiseProcess(misclassified=float("nan")), "misclassified"),
    (lambda: NoiseProcess(boundary_flips=-0.1), "boundary_flips"),
    (lambda: NoiseProcess(dropped_frames=0.9), "dropped_frames"),
    (lambda: NoiseProcess(dropped_frames="a lot"), "dropped_frames"),
    (lambda: NoiseProcess(n_particles=(0, 3)), "n_particles"),
    (lambda: NoiseProcess(n_particles=(12, 8)), "n_particles"),
    (lambda: NoiseProcess(n_particles=(8.5, 12)), "n_particles"),
    (lambda: NoiseProcess(persistent="yes"), "persistent"),
    (lambda: NoiseProcess(name=""), "name"),
    (lambda: campaign(n_particles=(3, 2)), "n_particles"),
])
def test_bad_noise_names_the_field(make, word):
    with pytest.raises(ValueError, match=word):
        make()
