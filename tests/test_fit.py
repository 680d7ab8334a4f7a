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
