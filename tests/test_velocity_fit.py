"""The shear-band fits (granseg.fit.fit_shear_band, fit_shear_band_law) and the profile JSON
(granseg.velocity.VelocityProfile) on profiles with a known answer."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from granseg.errors import FitError, MapFormatError
from granseg.fit import fit_shear_band, fit_shear_band_law, shear_band_law, shear_band_velocity
from granseg.velocity import VelocityProfile, load_profile

H = 0.09
Z = (np.arange(15) + 0.5) * 0.006


@settings(max_examples=30, deadline=None)
@given(dh=st.floats(0.08, 0.5), v0=st.floats(0.05, 1.0), slip=st.floats(0.0, 0.2))
def test_exact_profile_gives_its_parameters_back(dh, v0, slip):
    v = shear_band_velocity(Z, v0, slip * v0, dh * H)
    r = fit_shear_band(Z, v, 1e-3 * v0, H=H)
    assert r.converged
    assert r["delta_over_H"] == pytest.approx(dh, rel=1e-4)
    assert r["v0"] == pytest.approx(v0, rel=1e-4)
    assert r["v1"] == pytest.approx(slip * v0, abs=1e-4 * v0)


def test_noisy_profiles_are_covered_by_the_intervals():
    """Noise of the stated size: the 95 % interval of delta/H holds the truth in 90-99 % of 300 draws."""
    rng = np.random.default_rng(12)
    v = shear_band_velocity(Z, 0.233, 0.0, 0.18 * H)
    err = 0.002 + 0.03 * v
    hits = 0
    for _ in range(300):
        u = fit_shear_band(Z, v + rng.normal(0, err), err, H=H).uncertainty
        lo, hi = u.interval
        hits += bool(lo[2] <= 0.18 <= hi[2])
    assert 0.90 <= hits / 300 <= 0.99


def test_errors_shared_by_neighbouring_layers_are_stated_when_said():
    """Noise correlated 0.5 between neighbouring layers (AR(1), as footage's window sample is),
    300 draws: fitted as independent, delta/H's stated error is under 0.85 of the estimates'
    scatter; with ``layer_correlation=0.5`` it is 0.85-1.25 of it, the errors in it have an
    rms of at most 1.1, and the estimates scatter no more than the independent fit's."""
    rng = np.random.default_rng(13)
    v = shear_band_velocity(Z, 0.233, 0.0, 0.18 * H)
    err = 0.002 + 0.03 * v
    est, se = {0.0: [], 0.5: []}, {0.0: [], 0.5: []}
    for _ in range(300):
        e = np.empty(Z.size)
        e[0] = rng.normal()
        for k in range(1, Z.size):
            e[k] = 0.5 * e[k - 1] + np.sqrt(1 - 0.25) * rng.normal()
        for phi in est:
            r = fit_shear_band(Z, v + err * e, err, H=H, layer_correlation=phi)
            est[phi].append(r["delta_over_H"])
            se[phi].append(r.stderr["delta_over_H"])
    ratio = {phi: np.median(se[phi]) / np.std(est[phi]) for phi in est}
    rms_z = np.sqrt(np.mean(((np.array(est[0.5]) - 0.18) / np.array(se[0.5])) ** 2))
    assert ratio[0.0] < 0.85 and 0.85 <= ratio[0.5] <= 1.25 and rms_z <= 1.1, (ratio, rms_z)
    assert np.std(est[0.5]) <= 1.05 * np.std(est[0.0])
    with pytest.raises(ValueError, match="layer_correlation"):
        fit_shear_band(Z, v, err, H=H, layer_correlation=1.0)
    with pytest.raises(ValueError, match="layer_correlation = 0.5 takes one point per height"):
        fit_shear_band(np.r_[Z, Z[:2]], np.r_[v, v[:2]], np.r_[err, err[:2]], H=H, layer_correlation=0.5)
    assert fit_shear_band(np.r_[Z, Z[:2]], np.r_[v, v[:2]], np.r_[err, err[:2]], H=H).converged


def test_a_held_lid_speed_is_not_fitted():
    v = shear_band_velocity(Z, 0.233, 0.01, 0.2 * H)
    r = fit_shear_band(Z, v, 0.001, H=H, v1=0.01)
    assert set(r.params) == {"v0", "delta_over_H"} and r["delta_over_H"] == pytest.approx(0.2, rel=1e-6)


def test_bad_profiles_are_refused_by_name():
    with pytest.raises(ValueError, match="stated error"):
        fit_shear_band(Z, Z, np.zeros_like(Z), H=H)
    with pytest.raises(ValueError, match="H = "):
        fit_shear_band(Z, Z, H=0.0)
    with pytest.raises(FitError, match="one height"):
        fit_shear_band(np.full(5, 0.01), np.arange(5.0), H=H)
    with pytest.raises(ValueError, match="2 stated errors for 15"):
        fit_shear_band(Z, Z, [1.0, 2.0], H=H)


def test_the_law_gives_a_hidden_power_back():
    m = np.array([0.15, 0.3, 0.5, 0.9, 1.6])
    r = fit_shear_band_law(m, shear_band_law(m, 0.17, 0.45), 0.002)
    assert r["delta_over_H_ref"] == pytest.approx(0.17, rel=1e-6) and r["exponent"] == pytest.approx(0.45, rel=1e-6)
    with pytest.raises(FitError, match="same M~"):
        fit_shear_band_law([0.5, 0.5, 0.5], [0.1, 0.2, 0.3])


def test_profile_json_round_trip_and_bad_files(tmp_path):
    v = shear_band_velocity(Z, 0.233, 0.0, 0.18 * H)
    prof = VelocityProfile.fitted(Z, v, 0.002 + 0.01 * v, H, conditions={"M_g": 2.0, "M_w": 1.0},
                                  notes=["layer 15 left out"])
    path = prof.save(tmp_path / "v.json")
    again = load_profile(path)
    assert again.delta_over_H == pytest.approx(0.18, rel=1e-6) and again.M_tilde == 0.5
    assert again.notes == ["layer 15 left out"]
    # a footage profile's fit assumes neighbouring layers correlated: the file keeps it, and
    # the refit from the file gives the same errors
    noisy = v * (1 + 0.02 * np.sin(7 * Z / H))
    shared = VelocityProfile.fitted(Z, noisy, 0.002 + 0.01 * v, H, layer_correlation=0.5)
    back = load_profile(shared.save(tmp_path / "shared.json"))
    assert back.layer_correlation == 0.5
    assert back.fit.stderr["delta_over_H"] == pytest.approx(shared.fit.stderr["delta_over_H"], rel=1e-9)
    assert back.fit.stderr["delta_over_H"] != pytest.approx(
        VelocityProfile.fitted(Z, noisy, 0.002 + 0.01 * v, H).fit.stderr["delta_over_H"], rel=1e-3)
    d = prof.to_dict()
    assert {"delta_over_H", "delta_over_H_stderr", "v0", "v1", "profile"} <= set(d)
    assert set(d["profile"]) >= {"z", "v", "v_err"}
    with pytest.raises(FileExistsError):
        prof.save(path)
    (tmp_path / "bad.json").write_text('{"H": 0.09, "profile": {"z": [0, 1, 2], "v": [1, 2]}}')
    with pytest.raises(MapFormatError, match=r"bad.json: 'profile.v_err'"):
        load_profile(tmp_path / "bad.json")
    d_bad = {**shared.to_dict(), "layer_correlation": 1.5}
    (tmp_path / "phi.json").write_text(json.dumps(d_bad))
    with pytest.raises(MapFormatError, match=r"phi.json: 'layer_correlation'"):
        load_profile(tmp_path / "phi.json")
