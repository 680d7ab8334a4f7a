"""Curve fits: known values are recovered from synthetic series, errors are honest."""

from __future__ import annotations

import numpy as np
import pytest

from granseg.errors import FitError
from granseg.fit import (
    beta_law,
    fit_beta,
    fit_campaign,
    fit_tanh,
    fit_tau,
    tanh_curve,
    tau_law,
)
from granseg.maps import load_campaign, save_map


def test_tanh_curve_meaning_of_t0_and_tau():
    A, t0, tau = 0.8, 100.0, 160.0
    assert tanh_curve(t0, A, t0, tau) == pytest.approx(A / 2)
    assert tanh_curve(tau, A, t0, tau) == pytest.approx(0.8808 * A, rel=1e-4)
    assert tanh_curve(1e6, A, t0, tau) == pytest.approx(A)


@pytest.mark.parametrize("A, t0, tau", [(0.93, 150.0, 240.0), (0.62, 900.0, 1600.0), (0.99, 20.0, 35.0)])
def test_tanh_fit_recovers_known_values_within_errors(A, t0, tau):
    rng = np.random.default_rng(42)
    t = np.linspace(0.0, 4.0 * tau, 300)
    sigma = 0.03
    y = tanh_curve(t, A, t0, tau) + rng.normal(0, sigma, t.size)
    r = fit_tanh(t, y)
    assert r.converged
    for name, true in (("A", A), ("t0", t0), ("tau", tau)):
        assert abs(r[name] - true) < 4 * r.stderr[name], (name, r[name], true, r.stderr[name])
        assert 0 < r.stderr[name] < 0.05 * abs(true) + 5
    assert r.mse == pytest.approx(sigma**2, rel=0.2)


def test_tanh_stderr_is_calibrated_over_repeats():
    """Over many noise draws the scatter of A matches the reported error."""
    rng = np.random.default_rng(7)
    t = np.arange(0.0, 600.0, 3.0)
    truth = tanh_curve(t, 0.85, 120.0, 190.0)
    fits = [fit_tanh(t, truth + rng.normal(0, 0.04, t.size)) for _ in range(60)]
    scatter = np.std([f["A"] for f in fits])
    reported = np.median([f.stderr["A"] for f in fits])
    assert 0.7 < scatter / reported < 1.4


def test_tanh_fit_skips_nan():
    t = np.arange(0.0, 500.0, 2.0)
    y = tanh_curve(t, 0.9, 100.0, 150.0)
    y[::3] = np.nan
    r = fit_tanh(t, y)
    assert r["A"] == pytest.approx(0.9, abs=1e-6) and r.n_points == np.isfinite(y).sum()


def test_tanh_fit_not_converged_is_marked_and_returns():
    t = np.arange(0.0, 500.0, 2.0)
    r = fit_tanh(t, tanh_curve(t, 0.9, 100.0, 150.0) + 0.01 * np.sin(t), max_nfev=2)
    assert not r.converged and "not converged" in r.message
    assert set(r.params) == {"A", "t0", "tau"}


def test_tanh_fit_too_few_points():
    with pytest.raises(FitError, match="at least 4 finite points"):
        fit_tanh([0.0, 1.0, 2.0, 3.0], [0.0, np.nan, 0.5, 0.6])
    with pytest.raises(ValueError, match="different lengths"):
        fit_tanh([0.0, 1.0], [0.0])


def test_beta_fit_recovers_known_value():
    rng = np.random.default_rng(3)
    dR = np.array([8.25, 4.46, 3.70, 2.59, 1.85, 1.40])
    A = beta_law(dR, 2.27) + rng.normal(0, 0.01, dR.size)
    r = fit_beta(dR, A)
    assert r.converged
    assert abs(r["beta"] - 2.27) < 3 * r.stderr["beta"]
    assert r.stderr["beta"] < 0.3
    exact = fit_beta(dR, beta_law(dR, 2.32))
    assert exact["beta"] == pytest.approx(2.32, rel=1e-6) and exact.mse < 1e-20


def test_beta_fit_rejects_bad_ratio():
    with pytest.raises(ValueError, match="delta_R must be >= 1"):
        fit_beta([0.5, 2.0], [0.5, 0.9])
    with pytest.raises(FitError, match="undetermined"):
        fit_beta([1.0, 1.0], [0.5, 0.5])


def test_tau_fit_recovers_known_values():
    dR = np.array([8.25, 4.46, 3.70, 2.59, 1.85, 1.40])
    exact = fit_tau(dR, tau_law(dR, 2500.0, 0.9))
    assert exact["tau_1"] == pytest.approx(2500.0, rel=1e-6)
    assert exact["lam"] == pytest.approx(0.9, rel=1e-6)
    rng = np.random.default_rng(5)
    noisy = fit_tau(dR, tau_law(dR, 2500.0, 0.9) * (1 + rng.normal(0, 0.05, dR.size)))
    assert abs(noisy["lam"] - 0.9) < 4 * noisy.stderr["lam"]
    assert noisy.mse > 0


def test_fit_campaign_selects_c0_and_fits_laws(tmp_path):
    rng = np.random.default_rng(11)
    z = (np.arange(15) + 0.5) * 6e-3
    rho_l = 946.0
    for i, (rho_h, c0) in enumerate([(7800, 0.5), (3500, 0.5), (2450, 0.5), (1750, 0.5), (2450, 0.75)]):
        dR = rho_h / rho_l
        A, tau = float(beta_law(dR, 2.3)), float(tau_law(dR, 3000.0, 0.8))
        t = np.arange(0.0, 5 * tau, 2.0)
        c = np.tile(tanh_curve(t, A, 0.6 * tau, tau)[:, None], (1, 15))
        c = np.clip(c + rng.normal(0, 0.005, c.shape), 0, 1)
        save_map(tmp_path / f"{i}.npz", c=c, t=t, z=z, name=f"E{i}", heavy="h", light="PP",
                 rho_h=rho_h, rho_l=rho_l, c0=c0, M_g=2.0, M_w=1.093)
    fits = fit_campaign(load_campaign(tmp_path))
    assert fits.selected == ["E0", "E1", "E2", "E3"]
    assert set(fits.tanh) == {f"E{i}" for i in range(5)}
    assert abs(fits.beta["beta"] - 2.3) < 3 * fits.beta.stderr["beta"] + 0.01
    assert fits.tau["lam"] == pytest.approx(0.8, rel=0.05)
    d = fits.to_dict()
    assert d["beta"]["params"]["beta"] == fits.beta["beta"] and d["c0"] == 0.5


def test_fit_campaign_too_few_for_laws_says_why(tmp_path):
    t = np.arange(0.0, 400.0, 2.0)
    c = np.tile(tanh_curve(t, 0.9, 100.0, 150.0)[:, None], (1, 15))
    save_map(tmp_path / "a.npz", c=c, t=t, z=(np.arange(15) + 0.5) * 6e-3, name="A", heavy="h",
             light="l", rho_h=2450.0, rho_l=946.0, c0=0.5, M_g=2.0, M_w=1.093)
    fits = fit_campaign(load_campaign(tmp_path))
    assert fits.beta is None and fits.tau is None
    assert any("beta law not fitted" in n for n in fits.notes)


def test_weighted_covariance_matches_the_scatter_of_weighted_fits():
    """Straight-line fits weighting a 10-point and a 200-point group equally: the
    sandwich covariance matches the scatter over noise draws; equal weights give
    the plain covariance."""
    from granseg.fit import covariance, weighted_covariance

    rng = np.random.default_rng(3)
    x = np.concatenate([np.linspace(0, 1, 10), np.linspace(0.5, 3, 200)])
    w = np.concatenate([np.full(10, 1 / np.sqrt(10)), np.full(200, 1 / np.sqrt(200))])
    jac = -np.column_stack([np.ones_like(x), x]) * w[:, None]  # of the weighted residuals w (y - a - b x)
    fits, covs = [], []
    for _ in range(400):
        y = 1.0 + 2.0 * x + rng.normal(0, 0.1, x.size)
        p = np.linalg.lstsq(-jac, y * w, rcond=None)[0]
        fits.append(p)
        covs.append(weighted_covariance(jac, (y - p[0] - p[1] * x) * w, w, 2))
    scatter, mean_cov = np.cov(np.array(fits).T), np.mean(covs, axis=0)
    np.testing.assert_allclose(np.sqrt(np.diag(mean_cov)), np.sqrt(np.diag(scatter)), rtol=0.15)
    r = rng.normal(0, 0.1, x.size)
    np.testing.assert_allclose(weighted_covariance(-np.column_stack([np.ones_like(x), x]) * 0.5, r * 0.5,
                                                   np.full(x.size, 0.5), 2),
                               covariance(-np.column_stack([np.ones_like(x), x]), r, 2), rtol=1e-12)


# --------------------------------------------------------------------------- 95 % intervals (issue 18)


def _ar1(rng: np.random.Generator, n: int, rho: float, sigma: float) -> np.ndarray:
    """AR(1) noise of marginal standard deviation ``sigma``, started in its stationary state."""
    from scipy.signal import lfilter

    return lfilter([np.sqrt(1 - rho**2)], [1, -rho], rng.normal(0, 1, n + 200))[200:] * sigma


def test_tanh_intervals_cover_under_time_correlated_noise():
    """AR(1) noise (0.9 per sample) on a tanh curve: the time-block intervals contain the true
    A, t0 and tau in 88-99 % of 300 repeats, the classical ones (points independent) in far fewer."""
    rng = np.random.default_rng(18)
    t = np.arange(0.0, 2400.0, 1.0)
    truth = np.array([0.85, 800.0, 1100.0])
    clean = tanh_curve(t, *truth)
    n_rep = 300
    hits = {"cluster": np.zeros(3), "jacobian": np.zeros(3)}
    for _ in range(n_rep):
        y = clean + _ar1(rng, t.size, 0.9, 0.03)
        for errors in hits:
            lo, hi = fit_tanh(t, y, errors=errors).uncertainty.interval
            hits[errors] += (lo <= truth) & (truth <= hi)
    cover = {k: v / n_rep for k, v in hits.items()}
    assert np.all((cover["cluster"] >= 0.88) & (cover["cluster"] <= 0.99)), cover
    assert np.all(cover["jacobian"] < 0.6), cover


def test_tanh_uncertainty_is_time_blocks_and_matches_stderr():
    rng = np.random.default_rng(4)
    t = np.arange(0.0, 1200.0, 1.0)
    r = fit_tanh(t, tanh_curve(t, 0.9, 300.0, 420.0) + _ar1(rng, t.size, 0.8, 0.02))
    u = r.uncertainty
    assert u.method == "cluster" and u.names == ["A", "t0", "tau"]
    assert "time blocks of" in u.notes[0]
    n_blocks = int(u.notes[0].split(": ")[1].split()[0])
    assert u.dof == n_blocks - 1 and n_blocks >= 5
    np.testing.assert_allclose([r.stderr[n] for n in u.names], u.stderr)
    np.testing.assert_allclose(u.estimate, [r[n] for n in u.names])
    lo, hi = u.interval
    assert np.all(lo < u.estimate) and np.all(u.estimate < hi)
    # tau = t0 + width: the tau row is not the width's
    assert r.stderr["tau"] != pytest.approx(r.stderr["t0"])


def test_tanh_given_blocks_and_too_few_blocks_fall_back_with_a_note():
    rng = np.random.default_rng(5)
    t = np.arange(0.0, 600.0, 2.0)
    y = tanh_curve(t, 0.9, 150.0, 220.0) + rng.normal(0, 0.02, t.size)
    given = fit_tanh(t, y, block_s=60.0).uncertainty
    assert given.method == "cluster" and given.dof == 8  # 598 s: 9 whole blocks, the tail joins the last
    assert "time blocks of 60 s (given)" in given.notes[0]
    few = fit_tanh(t, y, block_s=200.0)
    assert few.uncertainty.method == "jacobian" and few.uncertainty.dof == t.size - 3
    assert any("count the 300 points as independent" in w for w in few.uncertainty.warnings())
    classical = fit_tanh(t, y, errors="jacobian")
    assert classical.stderr == pytest.approx(few.stderr)
    with pytest.raises(ValueError, match="block length must be > 0"):
        fit_tanh(t, y, block_s=0.0)
    with pytest.raises(ValueError, match="errors"):
        fit_tanh(t, y, errors="bootstrap")


def test_fit_result_to_dict_has_intervals():
    import json

    t = np.arange(0.0, 600.0, 2.0)
    y = tanh_curve(t, 0.9, 150.0, 220.0) + np.random.default_rng(6).normal(0, 0.02, t.size)
    d = json.loads(json.dumps(fit_tanh(t, y).to_dict()))
    iv = d["intervals"]
    assert iv["method"] == "cluster" and iv["level"] == 0.95
    assert set(iv["params"]) == {"A", "t0", "tau"}
    for name, p in iv["params"].items():
        assert p["lo"] < d["params"][name] < p["hi"] and p["stderr"] == pytest.approx(d["stderr"][name])
    assert any("time blocks" in w for w in iv["warnings"])
    from granseg.fit import FitResult

    bare = FitResult("tanh", {"A": 1.0}, {"A": 0.1}, 0.0, 3, True, "")
    assert bare.uncertainty is None and "intervals" not in bare.to_dict()


def test_beta_interval_uses_t_on_m_minus_1_dof():
    from scipy import stats

    rng = np.random.default_rng(3)
    dR = np.array([8.25, 4.46, 3.70, 2.59, 1.85, 1.40])
    r = fit_beta(dR, beta_law(dR, 2.27) + rng.normal(0, 0.01, dR.size))
    u = r.uncertainty
    assert u.method == "jacobian" and u.dof == dR.size - 1
    lo, hi = u.interval
    half = stats.t.ppf(0.975, dR.size - 1) * r.stderr["beta"]
    assert hi[0] - lo[0] == pytest.approx(2 * half, rel=1e-9)
    assert r.to_dict()["intervals"]["dof"] == dR.size - 1


def test_tau_interval_uses_t_on_m_minus_2_dof_and_bounds():
    from scipy import stats

    rng = np.random.default_rng(5)
    dR = np.array([8.25, 4.46, 3.70, 2.59, 1.85, 1.40])
    r = fit_tau(dR, tau_law(dR, 2500.0, 0.9) * (1 + rng.normal(0, 0.05, dR.size)))
    u = r.uncertainty
    assert u.dof == dR.size - 2 and u.names == ["tau_1", "lam"]
    np.testing.assert_allclose(u.bounds[0], [0.0, -50.0])
    lo, hi = u.interval
    np.testing.assert_allclose(hi - lo, 2 * stats.t.ppf(0.975, dR.size - 2) * u.stderr)


def test_fit_campaign_results_carry_intervals(tmp_path):
    rng = np.random.default_rng(11)
    z = (np.arange(15) + 0.5) * 6e-3
    for i, rho_h in enumerate((7800, 3500, 2450, 1750)):
        dR = rho_h / 946.0
        tau = float(tau_law(dR, 3000.0, 0.8))
        t = np.arange(0.0, 5 * tau, 2.0)
        c = np.tile(tanh_curve(t, float(beta_law(dR, 2.3)), 0.6 * tau, tau)[:, None], (1, 15))
        save_map(tmp_path / f"{i}.npz", c=np.clip(c + rng.normal(0, 0.005, c.shape), 0, 1), t=t, z=z,
                 name=f"E{i}", heavy="h", light="PP", rho_h=rho_h, rho_l=946.0, c0=0.5, M_g=2.0, M_w=1.093)
    fits = fit_campaign(load_campaign(tmp_path))
    d = fits.to_dict()
    assert all("intervals" in v for v in d["tanh"].values())
    assert d["beta"]["intervals"]["dof"] == 3 and d["tau"]["intervals"]["dof"] == 2


def test_leverage_corrected_cluster_covariance_is_cr2():
    """cluster_covariance with each cluster's J'J equals the CR2 sandwich written out with the hat matrix."""
    from scipy.linalg import sqrtm

    from granseg.fitting.uncertainty import cluster_covariance

    rng = np.random.default_rng(0)
    J, r = rng.normal(size=(120, 3)), rng.normal(size=120)
    block = np.arange(120) * 8 // 120
    scores = np.array([J[block == b].T @ r[block == b] for b in range(8)])
    own = np.array([J[block == b].T @ J[block == b] for b in range(8)])
    a_inv = np.linalg.inv(J.T @ J)
    meat = np.zeros((3, 3))
    for b in range(8):
        k = block == b
        s = J[k].T @ np.real(np.linalg.inv(sqrtm(np.eye(k.sum()) - J[k] @ a_inv @ J[k].T))) @ r[k]
        meat += np.outer(s, s)
    np.testing.assert_allclose(cluster_covariance(J.T @ J, scores, own), a_inv @ meat @ a_inv * 8 / 7, rtol=1e-8)
    plain = cluster_covariance(J.T @ J, scores)
    assert np.all(np.diag(cluster_covariance(J.T @ J, scores, own)) > np.diag(plain))
