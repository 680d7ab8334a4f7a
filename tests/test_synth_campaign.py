"""Virtual campaigns: docs/formats.md format, the paper's conditions, realistic counting noise, effects."""

from __future__ import annotations

import json

import numpy as np
import pytest

from granseg.maps import load_campaign, moving_average
from granseg.synth.virtual import (
    TABLE1,
    Condition,
    campaign,
    fill_mass,
    random_conditions,
    random_effect,
)

SMALL = [Condition("steel", "POM", 0.5, 5.73), Condition("glass", "PP", 0.5, 2.04)]


def test_table1_has_the_papers_16_conditions_and_frame_rates():
    assert len(TABLE1) == 16
    assert sorted(round(c.M_g, 2) for c in TABLE1)[0] == 1.62
    maps = campaign(conditions=[TABLE1[0], TABLE1[-2]], noise=False)
    assert maps[0].fps == 1.5 and maps[1].fps == 0.5  # S-PP fast camera, POM-PP slow
    for m in maps:  # runs reach the steady state: the last 10 % barely change
        tail = m.c[int(0.9 * m.n_times):]
        assert np.abs(tail - tail[-1]).max() < 0.03


def test_fill_mass_matches_table1_within_3_percent():
    for c in TABLE1:
        assert abs(fill_mass(c.heavy, c.light, c.c0) / c.M_g - 1) < 0.03, c


def test_written_campaign_loads_back_and_refuses_overwrite(tmp_path):
    maps = campaign(tmp_path, conditions=SMALL, seed=3)
    camp = load_campaign(tmp_path)
    assert camp.names == sorted(m.name for m in maps)
    m = camp["S-POM-50"]
    assert m.n is not None and m.c_raw is not None and m.smoothing_frames == 15
    truth = json.loads((tmp_path / "campaign.json").read_text())
    assert truth["effect"] == "none" and truth["synthetic"] is True
    with pytest.raises(FileExistsError):
        campaign(tmp_path, conditions=SMALL, seed=3)


def test_counting_noise_is_binomial_smoothed_and_persistent():
    m = campaign(conditions=SMALL[:1], seed=5)[0]
    assert m.n.min() >= 9 and m.n.max() <= 11
    np.testing.assert_allclose(m.c_raw, m.n_heavy / m.n)
    np.testing.assert_allclose(m.c, np.clip(moving_average(m.c_raw, m.smoothing_frames), 0, 1))
    clean = campaign(conditions=SMALL[:1], noise=False)[0]
    d = m.c_raw - clean.c
    lag1 = [np.corrcoef(d[1:, j], d[:-1, j])[0, 1] for j in (0, 14)]
    assert lag1[0] < 0.3 < 0.7 < lag1[1]  # bottom renewed every frame, top nearly frozen
    assert 0.7 < np.std(d[:, 7]) / np.sqrt(np.mean(clean.c[:, 7] * (1 - clean.c[:, 7]) / 10)) < 1.3


def test_effects_change_the_maps_as_their_physics_says():
    base = campaign(conditions=SMALL, noise=False)
    wall = campaign(conditions=SMALL, noise=False, effect="sidewall_excess", strength=0.8)
    for b, w in zip(base, wall, strict=True):
        assert np.all(w.c >= b.c - 1e-12)
        assert w.c.mean(axis=1).max() > w.c0 + 0.02  # depth-mean departs from c0 while mixed
        np.testing.assert_allclose(b.c.mean(axis=1), b.c0, atol=2e-3)
    delay = campaign(conditions=SMALL[:1], noise=False, effect="spin_up_delay", strength=120.0,
                     duration=600.0)[0]
    early = delay.t <= 120.0
    np.testing.assert_allclose(delay.c[early], delay.c[0][None, :].repeat(early.sum(), 0))
    # wider band for the heavy bed (M~ = 0.19): faster bottom; thinner for the light one (M~ = 0.54): slower
    def t_half(m):
        b = m.c[:, 0]
        return m.t[np.argmax(b >= 0.5 * b[-1])]

    load = campaign(conditions=SMALL, noise=False, effect="load_dependent_shear_band",
                    strength=0.6, duration=3000.0)
    flat = campaign(conditions=SMALL, noise=False, duration=3000.0)
    assert t_half(load[0]) < 0.8 * t_half(flat[0])
    assert t_half(load[1]) > t_half(flat[1])


def test_random_draws_are_seeded_and_in_range():
    assert random_conditions(5, seed=1) == random_conditions(5, seed=1)
    s, extra = random_effect("evolving_shear_band", seed=4)
    assert 0.3 <= abs(s) <= 0.6 and 300 <= extra["drift_time"] <= 900
    assert random_effect("spin_up_delay", seed=4) == random_effect("spin_up_delay", seed=4)


@pytest.mark.parametrize("kwargs, word", [
    ({"effect": "gravity_waves", "strength": 1.0}, "effect"),
    ({"effect": "spin_up_delay"}, "strength"),
    ({"effect": "misclassification", "strength": 0.7}, "strength"),
    ({"conditions": [{"heavy": "gold", "light": "PP", "c0": 0.5, "M_g": 2.0}]}, "heavy"),
    ({"conditions": [{"heavy": "glass", "light": "PP", "c0": 1.5, "M_g": 2.0}]}, "c0"),
])
def test_bad_input_names_the_parameter(kwargs, word):
    with pytest.raises(ValueError, match=word):
        campaign(**kwargs)
