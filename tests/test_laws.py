"""The open world's law corrections (granseg.fitting.laws) and the verdict that uses them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from granseg.diagnosis import selection
from granseg.fitting import Baseline, Data, laws, model_maps
from granseg.fitting.effects import Effect
from granseg.synth import departures
from granseg.synth.virtual import campaign, random_conditions


@dataclass
class _FitStub:
    """Just what laws.shape / sentence / literature_form read of a Fit."""

    effect: Effect
    x: np.ndarray
    cov: np.ndarray

    @property
    def keys(self) -> list[str]:
        return ["k", "delta_over_H", *[f"a{j}" for j in range(self.x.size - 2)]]

    def values(self) -> dict[str, float]:
        return dict(zip(self.keys, map(float, self.x), strict=True))


def _stub(law: laws.LawCorrection, g: np.ndarray, sd: float = 0.02) -> _FitStub:
    """A fit whose correction is the projection of log-factor ``g`` on the law's basis."""
    a = np.linalg.lstsq(law.phi, g, rcond=None)[0]
    cov = np.zeros((a.size + 2, a.size + 2))
    cov[2:, 2:] = np.eye(a.size) * sd**2
    return _FitStub(law, np.concatenate([[0.7, 0.18], a]), cov)


@pytest.mark.parametrize("centred", [False, True])
def test_basis_is_orthonormal_and_centred_when_asked(centred):
    phi = laws.basis(centred=centred)
    assert phi.shape == (laws.KNOTS.size, laws.N_BASIS - centred)
    np.testing.assert_allclose(phi.T @ phi / laws.KNOTS.size, np.eye(phi.shape[1]), atol=1e-12)
    if centred:
        np.testing.assert_allclose(phi.mean(axis=0), 0.0, atol=1e-12)
    else:  # a constant factor is in the span (e.g. a uniformly stronger diffusivity)
        one = np.ones(laws.KNOTS.size)
        np.testing.assert_allclose(phi @ np.linalg.lstsq(phi, one, rcond=None)[0], one, atol=1e-12)


def test_every_correction_at_zero_is_the_baseline():
    maps = campaign(conditions=random_conditions(3, 5), seed=5, noise="persistent")
    data = Data.of(maps)
    x0 = {"k": 0.7, "delta_over_H": 0.18}
    ref = model_maps(data, Baseline(), [(x0, i) for i in range(data.n)])
    for law in laws.build(3600.0):
        x = {**x0, **{p.name: 0.0 for p in law.extra(data.exps)}}
        got = model_maps(data, law, [(x, i) for i in range(data.n)])
        for a, b in zip(ref, got, strict=True):
            np.testing.assert_allclose(a, b, atol=1e-12, err_msg=law.name)


def test_a_correction_changes_the_model_and_a_time_law_needs_a_time_scale():
    maps = campaign(conditions=random_conditions(2, 6), seed=6, noise="persistent")
    data = Data.of(maps)
    law = laws.build(1800.0, ["law_diffusivity_time"])[0]
    x = {"k": 0.7, "delta_over_H": 0.18, **{f"a{j}": 0.0 for j in range(law.phi.shape[1])}}
    x["a0"] = 1.0
    assert law.solver_params(x, data.exps[0])["law_time"] == 1800.0
    zero = model_maps(data, law, [({**x, "a0": 0.0}, 0)])[0]
    assert np.abs(model_maps(data, law, [(x, 0)])[0] - zero).max() > 1e-3
    with pytest.raises(ValueError, match="time_scale"):
        laws.DiffusivityTime(-1.0)
    with pytest.raises(ValueError, match="unknown law correction"):
        laws.build(100.0, ["law_gravity"])


def test_shape_band_sentence_and_literature_form_of_an_asymmetric_flux():
    law = laws.SegregationFlux()
    A = 0.5  # w c (1 - c) (1 + A (1 - 2c)): faster where the bed is light-rich
    g = np.log(1 + A * (1 - 2 * laws.KNOTS))
    f = _stub(law, g - g.mean())
    sh = laws.shape(f)
    assert np.all(np.asarray(sh["lo"]) <= np.asarray(sh["factor"]))
    assert np.all(np.asarray(sh["factor"]) <= np.asarray(sh["hi"]))
    assert sh["factor"][0] > 1 > sh["factor"][-1]
    assert laws.sentence(f, sh).startswith("Heavy grains sink through a light-rich bed faster")
    lit = laws.literature_form(f, sh)
    assert lit is not None and lit["name"] == "asymmetric flux"
    assert lit["constants"]["A"] == pytest.approx(A, abs=0.03)
    # the reverse asymmetry reads the other way, and a form outside the band is not claimed
    f_rev = _stub(law, -(g - g.mean()))
    assert laws.sentence(f_rev).startswith("Light grains rise through a heavy-rich bed faster")
    bump = np.exp(-(((laws.KNOTS - 0.5) / 0.1) ** 2))
    assert laws.literature_form(_stub(law, bump - bump.mean(), sd=0.005)) is None


def test_sentence_names_where_a_depth_law_departs():
    law = laws.DiffusivityDepth()
    f = _stub(law, np.log1p(4 * np.exp(-(((laws.KNOTS - 0.5) / 0.15) ** 2))))
    s = laws.sentence(f)
    assert s.startswith("Mixing by diffusion is") and "stronger at z/H = 0.50" in s, s


def test_a_gaussian_shear_band_is_recognised():
    law = laws.ShearProfile()
    d, w = 0.18, 0.35
    g = laws.KNOTS / d - (laws.KNOTS / w) ** 2
    lit = laws.literature_form(_stub(law, g, sd=0.05))
    assert lit is not None and lit["name"] == "Gaussian shear band"
    assert lit["constants"]["w"] == pytest.approx(w, rel=0.05)


def _quiet() -> selection.Misfit:
    return selection.misfit(0.05, 0.05, True, selection.Coherence(0.5, 0.0))


def _loud() -> selection.Misfit:
    return selection.misfit(0.08, 0.05, True, selection.Coherence(1e-4, 0.6))


def test_open_world_rule():
    unexplained = selection.decide({"a": 1e-5}, 0.1, _loud(), {"a": _loud()}.get)
    assert selection.needs_open_world(unexplained)
    # a law gaining clearly held out and leaving no structure is the new cause
    v = selection.extend(unexplained, {"law_x": 0.01, "law_y": 0.004}, 0.1, {"law_x": _quiet()}.get)
    assert (v.cause, v.explained, v.law) == ("new_law", True, "law_x")
    assert v.gain_relative == pytest.approx(0.1)
    # ...but not when it leaves a structured misfit, nor when it gains too little
    assert selection.extend(unexplained, {"law_x": 0.01}, 0.1, {"law_x": _loud()}.get).cause == "unexplained"
    assert selection.extend(unexplained, {"law_x": 0.0015}, 0.1, {"law_x": _quiet()}.get).cause == "unexplained"
    # a catalogue cause that predicts about as well, with fewer parameters, keeps the verdict...
    partial = selection.decide({"a": 0.005}, 0.1, _loud(), {"a": _loud()}.get)
    assert (partial.cause, partial.explained) == ("a", False) and selection.needs_open_world(partial)
    kept = selection.extend(partial, {"law_x": 0.006}, 0.1, {"law_x": _quiet()}.get)
    assert kept.cause == "a"
    # ...and a cause that helps without explaining is settled as unexplained, naming it as best
    settled = selection.settle(kept)
    assert (settled.cause, settled.best, settled.explained) == ("unexplained", "a", False)
    assert selection.extend(partial, {"law_x": 0.02}, 0.1, {"law_x": _quiet()}.get).cause == "new_law"
    # the catalogue explaining the misfit never reaches the open world
    explained = selection.decide({"a": 0.01}, 0.1, _loud(), {"a": _quiet()}.get)
    assert not selection.needs_open_world(explained) and selection.settle(explained) == explained


def test_hidden_departures_are_outside_the_catalogue_and_act_on_their_law():
    from granseg.fitting import causes

    assert not {"flux_asymmetry", "mixing_layer", "mixing_burst", "shear_gaussian", "camera_sag"} & set(causes.names())
    exp = Data.of(campaign(conditions=random_conditions(1, 3), seed=3)).exps[0]
    for cls in (departures.FluxAsymmetry, departures.MixingLayer, departures.MixingBurst, departures.ShearGaussian):
        eff = cls()
        p = eff.solver_params({"k": 0.7, "delta_over_H": 0.18, **eff.hidden(eff.draw_range[0], exp, {})}, exp)
        table = [p[f"{eff.table}_{j}"] for j in range(17)]
        assert np.ptp(table) > 0.3 and max(map(abs, table)) <= 6.0, cls.name
        assert eff.law in {"segregation_flux", "diffusivity", "shear_profile"}
    sag = departures.CameraSag()
    layers = np.tile(np.linspace(0, 1, 15), (5, 1))
    seen = sag.observe({"sag": 2.0}, exp, layers)
    np.testing.assert_allclose(seen[0], layers[0])
    assert seen[-1, 5] == pytest.approx(layers[0, 7])
