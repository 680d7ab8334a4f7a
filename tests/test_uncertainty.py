"""Errors and intervals of fitted parameters (granseg.fitting.uncertainty): the estimators on
problems whose answer is known, the interval object, and calibrate's use of them."""

from __future__ import annotations

import json

import numpy as np
import pytest

from granseg.calibration import calibrate
from granseg.cli.calibrate import summary
from granseg.fitting import intervals
from granseg.fitting.uncertainty import (
    cluster_covariance,
    describe,
    jackknife_covariance,
    time_blocks,
)
from granseg.synth.virtual import campaign


def _clustered_line(rng: np.random.Generator, n_clusters: int = 16, per: int = 200, rho: float = 0.9):
    """A straight-line fit whose noise is strongly correlated inside each cluster (AR(1) in order)."""
    x = rng.uniform(-1, 1, size=(n_clusters, per))
    e = np.empty_like(x)
    e[:, 0] = rng.normal(size=n_clusters)
    for i in range(1, per):
        e[:, i] = rho * e[:, i - 1] + np.sqrt(1 - rho**2) * rng.normal(size=n_clusters)
    x = np.sort(x, axis=1)  # neighbours in x share noise, as neighbouring frames do
    y = 1.0 + 2.0 * x + 0.3 * e
    return x, y


def _fit_line(x: np.ndarray, y: np.ndarray):
    J = np.stack([np.ones(x.size), x.ravel()], axis=1)
    beta = np.linalg.lstsq(J, y.ravel(), rcond=None)[0]
    r = y.ravel() - J @ beta
    return J, r, beta


def test_cluster_errors_cover_where_counting_entries_does_not():
    """Correlated noise within clusters: the sandwich's 95 % intervals cover about 95 % of the
    time, the independent-entries errors far less (the issue's failure, on a problem with a known answer)."""
    rng = np.random.default_rng(18)
    hits = {"cluster": 0, "jackknife": 0, "independent": 0}
    n_rep, n_c, per = 300, 16, 200
    for _ in range(n_rep):
        x, y = _clustered_line(rng, n_c, per)
        J, r, beta = _fit_line(x, y)
        A = J.T @ J
        scores = np.array([J[c * per:(c + 1) * per].T @ r[c * per:(c + 1) * per] for c in range(n_c)])
        loo = []
        for c in range(n_c):
            keep = np.ones(J.shape[0], bool)
            keep[c * per:(c + 1) * per] = False
            loo.append(np.linalg.lstsq(J[keep], y.ravel()[keep], rcond=None)[0])
        covs = {"cluster": (cluster_covariance(A, scores), n_c),
                "jackknife": (jackknife_covariance(np.array(loo)), n_c),
                "independent": (r @ r / (r.size - 2) * np.linalg.inv(A), None)}
        for name, (cov, n) in covs.items():
            u = describe("jacobian" if n is None else "cluster", ["a", "b"], beta, cov, n,
                         (np.full(2, -np.inf), np.full(2, np.inf)))
            lo, hi = u.interval
            hits[name] += bool(lo[1] <= 2.0 <= hi[1])
    cover = {k: v / n_rep for k, v in hits.items()}
    assert 0.90 <= cover["cluster"] <= 0.99, cover
    assert 0.90 <= cover["jackknife"] <= 1.0, cover
    assert cover["independent"] < 0.6, cover


def test_cluster_covariance_needs_two_clusters_and_is_symmetric():
    A = np.array([[2.0, 0.3], [0.3, 1.0]])
    assert np.isnan(cluster_covariance(A, np.ones((1, 2)))).all()
    cov = cluster_covariance(A, np.random.default_rng(1).normal(size=(5, 2)))
    np.testing.assert_allclose(cov, cov.T)
    assert np.all(np.linalg.eigvalsh(cov) >= -1e-12)
    assert np.isnan(jackknife_covariance(np.ones((1, 3)))).all()


def test_intervals_are_cut_at_bounds_and_say_so():
    u = describe("cluster", ["k", "delta_over_H"], np.array([0.21, 0.3]), np.diag([0.01**2, 0.001**2]), 16,
                 (np.array([0.2, 0.05]), np.array([1.6, 0.6])))
    lo, hi = u.interval
    assert lo[0] == 0.2 and hi[0] == pytest.approx(0.21 + u.quantile * 0.01)
    assert u.at_bound == ["k"]
    assert any("k" in w and "bound" in w for w in u.warnings())
    assert u.quantile == pytest.approx(2.1314, abs=1e-3)  # t with 15 degrees of freedom
    np.testing.assert_allclose(np.diag(u.correlation), 1.0)
    d = json.loads(json.dumps(u.to_dict()))
    assert d["method"] == "cluster" and d["dof"] == 15 and d["params"]["k"]["at_bound"] is True


@pytest.mark.parametrize("kwargs, match", [({"method": "bootstrap"}, "method"), ({"level": 1.5}, "level")])
def test_describe_names_a_bad_argument(kwargs, match):
    args = {"method": "cluster", "level": 0.95, **kwargs}
    with pytest.raises(ValueError, match=match):
        describe(args["method"], ["k"], np.ones(1), np.eye(1), 4, (np.zeros(1), np.full(1, 2.0)),
                 level=args["level"])


def test_time_blocks():
    np.testing.assert_array_equal(time_blocks(np.array([10.0, 20, 309, 310, 700]), 300.0), [0, 0, 0, 1, 2])
    with pytest.raises(ValueError, match="block"):
        time_blocks(np.arange(3.0), 0.0)


@pytest.fixture(scope="module")
def calibrated():
    maps = campaign(seed=21, noise="persistent")[:8]  # MIN_CLUSTERS: "auto" takes the cluster errors
    return calibrate(maps, grid={"k": (0.7,), "delta_over_H": (0.18,)}, progress=False)


def test_calibrate_reports_intervals_by_the_method_it_names(calibrated):
    cal = calibrated
    out = cal.to_json()["intervals"]
    assert out["method"] == cal.settings["errors"] == "cluster"
    assert out["dof"] == 7
    for k in ("k", "delta_over_H"):
        p = out["params"][k]
        assert p["lo"] < cal.best[k] < p["hi"]
        assert p["stderr"] == pytest.approx(cal.stderr[k])
    assert "95 % intervals (cluster errors, 7 degrees of freedom)" in summary(cal)


def test_every_error_method_gives_an_interval_around_the_same_estimate(calibrated):
    cal = calibrated
    widths = {}
    for method in ("jacobian", "cluster", "jackknife"):
        u = intervals(cal.data, cal.fit, method)
        np.testing.assert_allclose(u.estimate, cal.fit.x)
        assert np.all(np.isfinite(u.stderr)) and u.method == method
        widths[method] = u.stderr
    # grains persist in view: counting entries as independent states smaller errors
    assert np.all(widths["jacobian"] < widths["cluster"])
    with pytest.raises(ValueError, match="method"):
        intervals(cal.data, cal.fit, "bootstrap")


def test_calibrate_rejects_an_unknown_error_method():
    with pytest.raises(ValueError, match="errors"):
        calibrate(campaign(seed=1)[:2], errors="bootstrap", progress=False)
