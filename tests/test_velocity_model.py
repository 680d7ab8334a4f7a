"""A measured shear band into the model: calibrate with it in place of fitting delta/H, simulate
with it, and the diagnosis' second-instrument check (granseg.diagnosis.velocity_check)."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from granseg.calibration import calibrate
from granseg.cli import main
from granseg.diagnosis.velocity_check import compare
from granseg.errors import MapFormatError
from granseg.fit import fit_shear_band_law, shear_band_law, shear_band_velocity
from granseg.synth.virtual import campaign
from granseg.velocity import ShearBandLaw, VelocityProfile, load_velocity, measured_params

Z = (np.arange(15) + 0.5) * 0.006


def _profile(dh: float, **kw) -> VelocityProfile:
    v = shear_band_velocity(Z, 0.2332, 0.0, dh * 0.09)
    return VelocityProfile.fitted(Z, v, 0.002 + 0.02 * v, 0.09, **kw)


def test_calibration_with_a_measured_profile_recovers_k():
    """A campaign made at delta/H = 0.22 (k = 0.75): given the measured profile, only k is fitted,
    and its 95 % interval holds the truth."""
    maps = campaign(seed=31, noise="persistent", k=0.75, delta_over_H=0.22)[:8]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cal = calibrate(maps, velocity=_profile(0.22), progress=False)
    assert cal.keys == ["k"]
    lo, hi = cal.uncertainty.interval
    assert lo[0] <= 0.75 <= hi[0]
    assert cal.settings["velocity"]["params"][0]["delta_over_H"] == pytest.approx(0.22, rel=1e-6)


def test_a_law_fixes_delta_at_each_load_and_the_grid_may_not_fit_it(tmp_path):
    law = ShearBandLaw(0.18, 0.5)
    got = measured_params(law, [0.25, 0.5, 1.0])
    np.testing.assert_allclose([g["delta_over_H"] for g in got], shear_band_law([0.25, 0.5, 1.0], 0.18, 0.5))
    maps = campaign(seed=32, noise="persistent")[:4]
    with pytest.raises(ValueError, match="delta_over_H measured"):
        calibrate(maps, velocity=law, grid={"k": [0.7], "delta_over_H": [0.18]}, progress=False)


def test_velocity_files_are_told_apart_and_bad_ones_named(tmp_path):
    _profile(0.2).save(tmp_path / "v.json")
    assert isinstance(load_velocity(tmp_path / "v.json"), VelocityProfile)
    m = np.array([0.2, 0.5, 1.0, 2.0])
    law = fit_shear_band_law(m, shear_band_law(m, 0.17, 0.4), 0.003)
    (tmp_path / "law.json").write_text(json.dumps(law.to_dict()))
    got = load_velocity(tmp_path / "law.json")
    assert isinstance(got, ShearBandLaw) and got.exponent == pytest.approx(0.4, rel=1e-6)
    (tmp_path / "bad.json").write_text('{"params": {"k": 1}}')
    with pytest.raises(MapFormatError, match="bad.json"):
        load_velocity(tmp_path / "bad.json")


def test_simulate_takes_the_measured_band(tmp_path, capsys):
    _profile(0.25).save(tmp_path / "v.json")
    assert main(["simulate", "--velocity", str(tmp_path / "v.json"), "--t-end", "60",
                 "--out", str(tmp_path / "sim")]) == 0
    assert "delta/H = 0.250" in capsys.readouterr().out
    assert main(["simulate", "--velocity", str(tmp_path / "v.json"), "--delta-over-H", "0.2",
                 "--out", str(tmp_path / "sim2")]) == 2


def test_the_check_agrees_within_two_errors_and_names_a_disagreement():
    prof = _profile(0.18)
    se = prof.fit.stderr["delta_over_H"]
    near = compare(prof, ({"delta_over_H": 0.18 + se, "k": 0.7}, {"delta_over_H": se}), None)
    far = compare(prof, ({"delta_over_H": 0.18 + 5 * se, "k": 0.7}, {"delta_over_H": se}), None)
    assert near["agrees"] and not far["agrees"] and far["pairs"][0]["z"] > 3
    law = ShearBandLaw(0.18, 0.5, {"delta_over_H_ref": 0.005, "exponent": 0.05})
    fitted = ({"delta_over_H": 0.181, "exponent": 0.52}, {"delta_over_H": 0.004, "exponent": 0.06})
    assert compare(law, ({}, {}), fitted)["agrees"]
    assert compare(law, ({}, {}), None)["agrees"] is None


def test_diagnosis_checks_its_load_law_against_the_footage():
    """Five beds whose band follows M~^-0.5: the diagnosis fits that law from the maps alone and
    finds it agrees with the law measured from footage; a law of the opposite sign disagrees."""
    from granseg.diagnosis import diagnose
    from granseg.synth.virtual import Condition

    five = [Condition("steel", "POM", 0.5, 5.73), Condition("glass", "PP", 0.5, 2.04),
            Condition("ceramic", "PP", 0.75, 3.43), Condition("steel", "PP", 0.75, 7.30),
            Condition("POM", "PP", 0.5, 1.62)]
    maps = campaign(conditions=five, effect="load_dependent_shear_band", strength=0.5, seed=3)
    true = ShearBandLaw(0.18, 0.5, {"delta_over_H_ref": 0.004, "exponent": 0.04})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        d = diagnose(maps, causes=["load_dependent_shear_band"], velocity=true, progress=False)
    check = d.result["velocity_check"]
    assert check["measured"] == "law" and check["agrees"], check
    from granseg.report.diagnosis import render

    assert "agrees with the measured law" in render(d.result, [], Path("."))
    f = d.fits["load_dependent_shear_band"]
    wrong = compare(ShearBandLaw(0.18, -0.5, true.stderr), ({}, {}), (f.values(), f.errors()))
    assert not wrong["agrees"]


def test_a_tabulated_profile_makes_the_models_shear_rate_the_measured_one():
    """A linear band (what DEM shows at low load) is no exponential: with shape='tabulated' the
    model's shear rate is the profile's -dv/dz wherever the profile measures it."""
    import numpy as np

    from granseg.model import defaults, velocity_profile
    from granseg.velocity import VelocityProfile, measured_params

    H = defaults()["H"]
    z = (np.arange(15) + 0.5) * H / 15
    v = 0.20 * (1 - z / H) + 0.01  # a straight line: shear rate 0.2 / H everywhere
    prof = VelocityProfile.fitted(z, v, np.full(15, 0.002), H)
    for shape, close in (("exponential", False), ("tabulated", True)):
        p = measured_params(prof, [0.5], shape=shape)[0]
        zz = np.linspace(0.1, 0.9, 9) * H
        vel, rate = velocity_profile(zz, **p)
        ok = np.allclose(rate, 0.2 / H, rtol=0.02)
        assert ok == close, (shape, rate * H)
        if close:  # the velocity is the one that shear rate gives: the measured straight line
            v_at = 0.20 * (1 - zz / H) + 0.01
            assert np.allclose(vel - vel[0], v_at - v_at[0], atol=0.004), vel
    with pytest.raises(ValueError, match="tabulated"):
        from granseg.velocity import ShearBandLaw

        measured_params(ShearBandLaw(0.2, 0.4, {}, "law"), [0.5], shape="tabulated")
