"""The one fitting layer: calibrate and diagnose share the baseline; a cause is one class."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from granseg.calibration import calibrate
from granseg.cli.demo import HIDDEN
from granseg.diagnosis import diagnose
from granseg.fitting import REGISTRY, Data, Effect, ExpInfo, Param, causes, register, shifted_times
from granseg.fitting.solve import compress
from granseg.synth.virtual import EFFECTS, Condition, campaign

FIVE = [Condition("steel", "POM", 0.5, 5.73), Condition("glass", "PP", 0.5, 2.04),
        Condition("ceramic", "PP", 0.75, 3.43), Condition("steel", "PP", 0.75, 7.30),
        Condition("POM", "PP", 0.5, 1.62)]


@pytest.fixture(scope="module")
def demo_campaign():
    """The demo's campaign (its hidden effect and default seed 7), Table 1 conditions."""
    return campaign(**HIDDEN, seed=7)


def test_calibrate_and_diagnose_report_the_same_baseline_on_the_demo_campaign(demo_campaign):
    cal = calibrate(demo_campaign, progress=False)
    d = diagnose(demo_campaign, causes=["spin_up_delay"], progress=False)
    base = d.result["baseline"]
    for key in ("k", "delta_over_H"):
        assert round(base["params"][key], 3) == round(cal.best[key], 3), key
    assert round(base["rmsd_mean"], 3) == round(cal.rmsd_mean, 3)


def test_calibrate_and_diagnose_share_the_baseline_on_a_small_campaign():
    maps = campaign(conditions=FIVE, effect="load_dependent_shear_band", strength=0.5, seed=3)
    cal = calibrate(maps, progress=False)
    d = diagnose(maps, causes=["load_dependent_shear_band"], progress=False)
    assert d.result["baseline"]["params"] == pytest.approx(cal.best, abs=5e-4)
    assert d.result["baseline"]["rmsd_mean"] == pytest.approx(cal.rmsd_mean, abs=5e-4)
    # handed the calibration, the diagnosis uses exactly it
    again = diagnose(maps, calibration=cal, causes=["load_dependent_shear_band"], progress=False)
    assert again.result["baseline"]["params"] == cal.best
    assert again.cause == "load_dependent_shear_band"


def test_the_json_records_the_thresholds_the_call_used():
    maps = campaign(conditions=FIVE[:3], seed=5)
    d = diagnose(maps, causes=["spin_up_delay"], gain_threshold=np.inf, excess_threshold=7.5, progress=False)
    assert d.result["decision"]["gain_threshold"] == np.inf
    assert d.result["decision"]["excess_threshold"] == 7.5
    assert d.cause in ("none", "unexplained")  # nothing can pass an infinite gain threshold


def test_a_calibration_of_other_experiments_is_refused():
    maps = campaign(conditions=FIVE, seed=4)
    cal = calibrate(maps[:4], progress=False, refine=False)
    with pytest.raises(ValueError, match="calibration"):
        diagnose(maps, calibration=cal, progress=False)


def test_shifted_times_map_plate_times_to_model_rows():
    t = np.array([0.0, 10.0, 20.0, 30.0])
    req, idx = shifted_times(t, 15.0)
    np.testing.assert_array_equal(req, [0.0, 5.0, 15.0])
    np.testing.assert_array_equal(req[idx], [0.0, 0.0, 5.0, 15.0])
    req, idx = shifted_times(t[1:], 0.0)
    np.testing.assert_array_equal(req[idx], t[1:])


class _Compaction(Effect):
    """A toy cause written in this test file only: where the bed is mixed, the wall's heavy
    share lags the bed by a share ``lag`` of the way back to c0 (pure layers show pure;
    a lag there too would be a confusion of the two kinds, which calibrate measures)."""

    name = "toy_wall_lag"
    description = "Toy: the wall shows c_wall = c + lag (c0 - c) 4 c (1 - c)."
    draw_range = (0.2, 0.4)
    strength_limits = (0.0, 0.9)

    def extra(self, exps: Sequence[ExpInfo]) -> list[Param]:
        return [Param("lag", -0.5, 0.9, 0.0, 0.005)]

    def observe(self, x: Mapping[str, float], exp: ExpInfo, layers: np.ndarray) -> np.ndarray:
        return layers + x["lag"] * (exp.c0 - layers) * 4.0 * layers * (1.0 - layers)


@pytest.fixture
def toy_cause():
    register(_Compaction)
    yield _Compaction.name
    REGISTRY.pop(_Compaction.name)


def test_a_new_cause_is_one_class_through_synth_and_diagnose(toy_cause):
    assert toy_cause in causes.names()
    maps = campaign(conditions=FIVE, effect=toy_cause, strength=0.3, seed=6)
    # the hidden effect is in the maps: the depth-mean no longer sits at c0 while mixed
    clean = campaign(conditions=FIVE, seed=6)
    assert max(np.abs(a.c - b.c).max() for a, b in zip(maps, clean, strict=True)) > 0.05
    d = diagnose(maps, causes=[toy_cause, "load_dependent_shear_band", "spin_up_delay"], progress=False)
    assert d.cause == toy_cause, d.result["decision"]
    assert d.fits[toy_cause].values()["lag"] == pytest.approx(0.3, abs=0.05)


def test_synth_effects_come_from_the_registry(toy_cause):
    from granseg.synth import virtual

    assert set(EFFECTS) == {"none", *causes.names(catalogued_only=False)} - {toy_cause}
    with pytest.raises(ValueError, match="strength"):
        campaign(conditions=FIVE[:1], effect="misclassification", strength=0.7)
    assert virtual.random_effect("spin_up_delay", seed=1)[0] == pytest.approx(
        np.random.default_rng(1).uniform(60.0, 240.0))


def test_data_defaults_to_the_fitting_cells():
    maps = campaign(conditions=FIVE[:1], seed=1, noise=False, duration=60.0)
    assert Data.of(maps).opts["n_cells"] == 90


@settings(max_examples=40, deadline=None)
@given(sizes=st.lists(st.integers(1, 40), min_size=1, max_size=5), p=st.integers(1, 6), seed=st.integers(0, 10**6))
def test_the_compressed_problem_has_the_cost_of_every_step_of_the_full_one(sizes, p, seed):
    """What scipy sees (p + 1 rows) must give the same cost for every step, so the same fit."""
    rng = np.random.default_rng(seed)
    jac = [rng.normal(size=(n, p)) for n in sizes]
    res = [rng.normal(size=n) for n in sizes]
    if seed % 2:  # a parameter the maps cannot see
        for j in jac:
            j[:, 0] = 0.0
    r_small, j_small = compress(res, jac)
    assert r_small.shape == (p + 1,) and j_small.shape == (p + 1, p)
    J, r = np.vstack(jac), np.concatenate(res)
    for s in rng.normal(size=(3, p)):
        assert np.sum((j_small @ s + r_small) ** 2) == pytest.approx(np.sum((J @ s + r) ** 2), rel=1e-9)
    np.testing.assert_allclose(j_small.T @ r_small, J.T @ r, atol=1e-9)


def test_a_compacted_fit_keeps_its_results_and_gives_its_jacobian_again():
    """A diagnosis keeps every fit it makes; compact() drops the residual and Jacobian blocks
    (most of a fit's memory) and what asks for them later gets them evaluated again, equal."""
    from granseg.diagnosis.selection import model_jacobians
    from granseg.fitting import compact, covariance, fit

    maps = campaign(conditions=FIVE[:3], effect="load_dependent_shear_band", strength=0.5, seed=3)
    cal = calibrate(maps, progress=False)
    effect = REGISTRY["load_dependent_shear_band"]()
    full = fit(cal.data, effect, x0=cal.fit.values(), max_nfev=3)
    small = compact(full)
    assert small.jac == [] and small.res == [] and full.jac  # the original is untouched
    np.testing.assert_array_equal(small.x, full.x)
    np.testing.assert_array_equal(small.cov, full.cov)
    np.testing.assert_allclose(covariance(cal.data, small, "jacobian"), covariance(cal.data, full, "jacobian"),
                               rtol=1e-10, atol=1e-14)
    for a, b in zip(model_jacobians(cal.data, small), model_jacobians(cal.data, full), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-14)
