"""Forward sensitivities (issue 15): the core's derivatives of the layer maps, and the fits' Jacobians built on them.

The references are central differences of the whole solver at tight tolerances
(small steps, so that their truncation error is far below the checks); the
forward differences the fits used before are shown to be much further off.
"""

from __future__ import annotations

import numpy as np
import pytest

import granseg
from granseg.fitting import Data, causes
from granseg.fitting.observe import maps_and_jacobians, model_maps
from granseg.fitting.solve import _bounds, _steps
from granseg.model import DIFFERENTIABLE, sweep
from granseg.synth.virtual import campaign

TIGHT = {"rtol": 1e-8, "atol": 1e-9}
T = np.arange(0.0, 1801.0, 30.0)


@pytest.mark.parametrize("case", [{"rho_h": 2450.0, "c0": 0.5}, {"rho_h": 7800.0, "c0": 0.25, "delta_drift": 0.2}])
def test_sweep_sensitivities_match_central_differences(case):
    d = granseg.defaults()
    keys = [("k", 1e-3), ("delta_over_H", 2e-4), ("b", 4e-5), ("law_diff_z_4", 1e-2), ("delta_drift", 1e-3)]
    r = sweep(cases=[case], t=T, n_cells=60, tangents=[[{k: 1.0} for k, _ in keys]], **TIGHT)
    sens = r.sensitivities[0]
    assert sens.shape == (len(keys), T.size, 15)
    for j, (key, eps) in enumerate(keys):
        v = case.get(key, d.get(key, 0.0))
        up = sweep(cases=[{**case, key: v + eps}], t=T, n_cells=60, **TIGHT).layers[0]
        dn = sweep(cases=[{**case, key: v - eps}], t=T, n_cells=60, **TIGHT).layers[0]
        fd = (up - dn) / (2 * eps)
        scale = np.abs(fd).max()
        assert scale > 0, key
        assert np.abs(sens[j] - fd).max() < 2e-3 * scale, key


def test_a_direction_is_a_combination_of_parameters():
    # sensitivities are linear in the tangent: one direction of two parameters
    # equals the sum of the two single ones
    r = sweep(cases=[{}], t=T, n_cells=48, tangents=[[{"k": 1.0}, {"b": 1.0}, {"k": 2.0, "b": -3.0}]])
    s = r.sensitivities[0]
    np.testing.assert_allclose(s[2], 2 * s[0] - 3 * s[1], atol=1e-9 * np.abs(s).max())


def test_no_tangents_returns_no_sensitivities_and_same_maps():
    a = sweep(cases=[{}], t=T, n_cells=48)
    b = sweep(cases=[{}], t=T, n_cells=48, tangents=[[{"k": 1.0}]])
    assert a.sensitivities is None
    np.testing.assert_allclose(a.layers, b.layers, atol=1e-6)


@pytest.mark.parametrize("tangents, words", [
    ([[{"rho_h": 1.0}]], ["rho_h", "k"]),
    ([[{"k": float("nan")}]], ["tangents[0][0]", "'k'"]),
    ([[{"k": "x"}]], ["tangents[0][0]", "'k'"]),
    ([[{"k": 1.0}], [{"k": 1.0}]], ["tangents has 2 entries"]),
    ({"k": 1.0}, ["list"]),
])
def test_bad_tangents_are_named(tangents, words):
    with pytest.raises(ValueError) as e:
        sweep(cases=[{}], t=T, n_cells=24, tangents=tangents)
    for w in words:
        assert w in str(e.value)


def test_differentiable_names_come_from_the_core():
    assert {"k", "delta_over_H", "b"} <= set(DIFFERENTIABLE)


@pytest.fixture(scope="module")
def tight_data():
    maps = campaign(effect="load_dependent_shear_band", strength=0.5, seed=1)
    return Data.of([maps[i] for i in (0, 5, 10)], opts=TIGHT)


@pytest.mark.parametrize("effect", ["baseline", "evolving_shear_band", "diffusivity_scale",
                                    "load_dependent_shear_band", "spin_up_delay", "sidewall_excess"])
def test_fit_jacobians_match_central_differences(tight_data, effect):
    """Every column of a fit's Jacobian: the core's where it can, a forward difference where it
    cannot (a delayed start). With the core's, only the observation after the solver is a
    secant (the sidewall's c + a c (1 - c) is the one nonlinear one here): within 2e-3 of the
    column's size of a central difference, and closer than the forward differences of before."""
    data = tight_data
    eff = causes.get(effect)
    params = eff.params(data.exps)
    x = {p.name: p.start + 0.1 * (p.hi - p.start) for p in params}
    _, hi = _bounds(params)
    h = _steps(np.array(list(x.values())), params, hi)
    which = list(range(data.n))
    data.jacobian = "sensitivities"
    maps_s, jac_s = maps_and_jacobians(data, eff, x, which, h)
    data.jacobian = "differences"
    maps_d, jac_d = maps_and_jacobians(data, eff, x, which, h)
    data.jacobian = "sensitivities"
    for a, b in zip(maps_s, maps_d, strict=True):
        np.testing.assert_allclose(a, b, atol=1e-6)
    for j, p in enumerate(params):
        e = 0.05 * h[j]
        up = model_maps(data, eff, [({**x, p.name: x[p.name] + e}, i) for i in which])
        dn = model_maps(data, eff, [({**x, p.name: x[p.name] - e}, i) for i in which])
        ref = np.concatenate([((u - d) / (2 * e)).ravel() for u, d in zip(up, dn, strict=True)])
        got = np.concatenate([J[j].ravel() for J in jac_s])
        fwd = np.concatenate([J[j].ravel() for J in jac_d])
        scale = np.abs(ref).max()
        if scale == 0:
            assert np.abs(got).max() == 0, p.name
            continue
        err, err_fwd = np.abs(got - ref).max() / scale, np.abs(fwd - ref).max() / scale
        if p.name == "t_delay":  # the model's clock moves: no sensitivity, the difference stays
            np.testing.assert_allclose(got, fwd, rtol=0, atol=1e-4 * scale)
        else:
            assert err < 2e-3, (p.name, err)
            assert err <= max(err_fwd, 1e-6), (p.name, err, err_fwd)  # linear columns: both exact


def test_unknown_jacobian_method_is_refused(tight_data):
    eff = causes.get("baseline")
    params = eff.params(tight_data.exps)
    tight_data.jacobian = "magic"
    try:
        with pytest.raises(ValueError, match="jacobian = 'magic'"):
            maps_and_jacobians(tight_data, eff, {p.name: p.start for p in params}, [0], [p.step for p in params])
    finally:
        tight_data.jacobian = "sensitivities"
