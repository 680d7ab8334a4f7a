"""granseg diagnose: catalogue neutrality, noise floor, leave-one-out, decision rule, CLI contract."""

from __future__ import annotations

import json

import numpy as np
import pytest

from granseg.cli import main
from granseg.diagnosis import selection
from granseg.diagnosis.noise import noise_floor
from granseg.fitting import Baseline, Data, ExpInfo, causes, fit, loo_params, loo_predict
from granseg.maps import Map, moving_average
from granseg.synth.virtual import Condition, campaign, random_conditions

COND = [Condition("steel", "POM", 0.5, 5.73), Condition("glass", "PP", 0.5, 2.04),
        Condition("ceramic", "PP", 0.75, 3.43), Condition("steel", "PP", 0.75, 7.30),
        Condition("glass", "POM", 0.5, 2.52)]


def test_every_extension_at_neutral_values_is_the_baseline():
    exps = [ExpInfo(c.label(), c.heavy, c.light, 2450.0, 946.0, c.c0, c.M_g, c.M_w) for c in COND]
    base = Baseline()
    neutral_extra = {"delta_drift": 0.0, "b": 0.041}
    layers = np.linspace(0, 1, 30).reshape(2, 15)
    for ext in causes.build():
        x = {p.name: p.start for p in ext.params(exps)}
        x.update({"t_delay": 0.0, "delta_drift": 0.0})
        for e in exps:
            def core(params):
                return {k: v for k, v in params.items() if neutral_extra.get(k) != v and k != "delta_drift_time"}

            assert core(ext.solver_params(x, e)) == core(base.solver_params(x, e))
            assert ext.time_shift(x, e) == 0.0
            np.testing.assert_array_equal(ext.observe(x, e, layers), layers)


def test_unknown_cause_is_named():
    with pytest.raises(ValueError, match="gravity"):
        causes.build(["gravity"])


def test_noise_floor_matches_the_true_noise_within_ten_percent():
    noisy = campaign(conditions=COND[:3], seed=21)
    clean = campaign(conditions=COND[:3], noise=False)
    for m, c in zip(noisy, clean, strict=True):
        true = np.sqrt(np.mean((m.c - moving_average(c.c, m.smoothing_frames)) ** 2))
        est = noise_floor(m)
        assert abs(est.floor / true - 1) < 0.1, (m.name, est.floor, true)
        # without counts only the map's scatter is left: a lower bound, flagged as such
        bare = Map(c=m.c, t=m.t, z=m.z, name=m.name, heavy=m.heavy, light=m.light, rho_h=m.rho_h,
                   rho_l=m.rho_l, c0=m.c0, M_g=m.M_g, M_w=m.M_w, smoothing_frames=m.smoothing_frames)
        low = noise_floor(bare)
        assert "lower bound" in low.method and 0 < low.floor < 1.1 * est.floor


def test_decision_rule():
    floor, quiet = 0.05, 0.5

    def mis(rmsd: float, p: float = quiet, counted: bool = True, share: float = 0.6) -> selection.Misfit:
        return selection.misfit(rmsd, floor, counted, selection.Coherence(p, share))

    v = selection.decide({"a": 0.01, "b": 0.0}, 0.1, mis(0.09), {"a": mis(0.051), "b": mis(0.09)}.get)
    assert (v.cause, v.explained, v.runner_up) == ("a", True, "b")
    v = selection.decide({"a": 0.01}, 0.1, mis(0.09), {"a": mis(0.08)}.get)
    assert (v.cause, v.explained) == ("a", False)
    # a gain under 2 % of the held-out RMSD names nothing
    v = selection.decide({"a": 0.0019}, 0.1, mis(0.0501), {"a": mis(0.05)}.get)
    assert (v.cause, v.explained) == ("none", True)
    v = selection.decide({"a": 1e-5}, 0.1, mis(0.08), {"a": mis(0.08)}.get)
    assert (v.cause, v.explained) == ("unexplained", False)
    # a pattern shared by the experiments is structured whatever the floor says...
    v = selection.decide({"a": 1e-5}, 0.1, mis(0.05, p=1e-4), {"a": mis(0.05)}.get)
    assert v.cause == "unexplained"
    # ...unless it is too small a share of the misfit to matter
    assert not mis(0.05, p=1e-4, share=0.2).structured
    # ...and without counts the floor (a lower bound) is not used at all
    assert not mis(0.08, counted=False).structured
    assert "lower bound" in mis(0.08, counted=False).why


def test_coherence_finds_a_shared_pattern_and_not_independent_noise():
    maps = campaign(conditions=random_conditions(14, seed=4), seed=4)
    exps = [ExpInfo.of(m) for m in maps]
    rng = np.random.default_rng(0)
    truth = [m.c.copy() for m in maps]
    # persistent noise: one random offset per layer for the whole run, independent between runs
    noisy = [t + rng.normal(0, 0.05, size=(1, t.shape[1])) for t in truth]
    assert selection.coherence(maps, exps, noisy).p > 0.01
    # the same offset pattern in every run (a model error) is found
    shared = rng.normal(0, 0.05, size=(1, truth[0].shape[1]))
    found = selection.coherence(maps, exps, [t + shared for t in truth])
    assert found.p < selection.COHERENCE_ALPHA and found.share > selection.COHERENCE_SHARE


def test_one_step_leave_one_out_matches_exact_refits():
    maps = campaign(conditions=COND[:4], seed=2, effect="load_dependent_shear_band", strength=0.5)
    data = Data.of(maps, {"n_cells": 60})
    ext = causes.get("load_dependent_shear_band")
    f = fit(data, ext, x0={"k": 0.7, "delta_over_H": 0.18})
    approx, _, folds = loo_predict(data, f)
    exact, _, exact_folds = loo_predict(data, f, exact=True, max_nfev=8)
    np.testing.assert_allclose(approx, exact, rtol=0.03)
    for a, e in zip(folds, exact_folds, strict=True):
        np.testing.assert_allclose(a, e, atol=0.03)
    assert np.all(np.isfinite(loo_params(f, 0)))


def test_cli_writes_the_json_contract_and_refuses_to_overwrite(tmp_path, capsys):
    camp = tmp_path / "camp"
    campaign(camp, conditions=random_conditions(5, seed=4), seed=4)
    out, rep = tmp_path / "d.json", tmp_path / "report"
    args = ["diagnose", str(camp), "--json", str(out), "--report", str(rep), "--quiet",
            "--causes", "load_dependent_shear_band", "spin_up_delay"]
    assert main(args) == 0
    assert "cause:" in capsys.readouterr().out
    r = json.loads(out.read_text())
    for key in ("cause", "explained", "summary", "noise_floor", "baseline", "extended", "gain", "candidates"):
        assert key in r
    assert r["cause"] in ("none", "unexplained", "load_dependent_shear_band", "spin_up_delay")
    assert set(r["baseline"]["params"]) == {"k", "delta_over_H"}
    assert len(r["baseline"]["rmsd"]) == 5
    assert r["baseline"]["rmsd_mean"] == pytest.approx(np.mean(list(r["baseline"]["rmsd"].values())))
    assert {c["name"] for c in r["candidates"]} == {"load_dependent_shear_band", "spin_up_delay"}
    assert all({"name", "rmsd_held_out", "params"} <= set(c) for c in r["candidates"])
    assert (r["extended"] is None) == (r["cause"] in ("none", "unexplained"))
    for name in ("residual_maps", "covariates", "candidates", "gain", "before_after"):
        assert (rep / "figures" / f"{name}.png").stat().st_size > 10_000
    assert "Cause:" in (rep / "index.html").read_text()
    assert main(args) == 2  # existing outputs are not replaced
    assert "exists" in capsys.readouterr().err


def test_bad_campaign_names_the_problem(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope"):
        from granseg.diagnosis import diagnose

        diagnose(tmp_path / "nope", progress=False)


def test_dropped_frames_are_skipped_without_warnings():
    """Frames with no reading (docs/formats.md: NaN rows) are left out of every step, silently."""
    import warnings

    maps = campaign(conditions=COND[:3], noise="dropped_frames", seed=8)
    assert any(np.isnan(m.c).all(axis=1).any() for m in maps)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        from granseg.diagnosis import diagnose

        d = diagnose(maps, causes=["spin_up_delay"], progress=False)
    assert np.isfinite(d.result["baseline"]["rmsd_mean"])
