"""The window check needs no ground truth (issue 17): the depth-mean heavy share of a fair view
stays at c0. It must never flag the project's own virtual maps (c0 from 0.25 to 0.75, every
noise process with counts); the DEM side of it is in tests/test_dem.py."""

from __future__ import annotations

import pytest

from granseg.measure.quality import depth_mean_check
from granseg.synth.virtual import NOISE_PROCESSES, Condition, campaign

COUNTED = [name for name, p in NOISE_PROCESSES.items() if p.counts]


@pytest.mark.parametrize("noise", COUNTED)
def test_virtual_maps_pass_for_c0_from_a_quarter_to_three_quarters(noise):
    conds = [Condition("steel", "PP", c0, 3.0) for c0 in (0.25, 0.4, 0.5, 0.6, 0.75)]
    for seed in range(3):
        for m in campaign(conditions=conds, noise=noise, seed=seed, duration=1800.0, fps=0.1, n_cells=60):
            check = depth_mean_check(m.n, m.n_heavy, m.c0)
            assert check.passed, (noise, seed, m.name, check.line())


def test_a_drifting_view_fails():
    import numpy as np

    n = np.full((30, 15), 10)
    n_heavy = np.tile(np.r_[np.zeros(8, int), np.full(7, 10)], (30, 1))
    c0 = 7 / 15
    assert depth_mean_check(n, n_heavy, c0).passed
    n_heavy[20:, :5] = 6  # the bottom layers turn heavy in view while the bed cannot gain heavy grains
    assert not depth_mean_check(n, n_heavy, c0).passed


def test_diagnosis_takes_a_drifting_window_as_the_observation_law():
    """Maps whose view favours heavy grains wherever the bed is mixed (c_wall = c + s c (1 - c)):
    each is flagged by the window check, and the diagnosis names the observation law instead of
    fitting physics causes to it."""
    import numpy as np

    from granseg.diagnosis import diagnose
    from granseg.maps import Map
    from granseg.measure.quality import Quality

    conds = [Condition("glass", "PP", c0, mg) for c0, mg in ((0.3, 1.5), (0.5, 2.0), (0.7, 2.5))]
    conds.append(Condition("POM", "PP", 0.5, 1.6))
    rng = np.random.default_rng(0)
    maps = []
    for m in campaign(conditions=conds, noise=False, fps=1 / 60, n_cells=48):
        n = np.full(m.c.shape, 40)
        n_heavy = rng.binomial(n, np.clip(m.c + 1.0 * m.c * (1 - m.c), 0, 1))
        quality = Quality((depth_mean_check(n, n_heavy, m.c0),), {}).to_json()
        maps.append(Map.from_arrays({**m.to_arrays(), "c": n_heavy / n, "n": n, "n_heavy": n_heavy,
                                     "quality": quality}))
    assert all(m.failed_checks == ["heavy_share_conserved"] for m in maps)
    d = diagnose(maps, n_cells=48, progress=False, max_nfev=12)
    r = d.result
    assert r["window_check"]["flagged"] == [m.name for m in maps]
    assert r["candidates"] == []  # no physics cause was bent to fit the view
    assert r["cause"] == "new_law" and r["departure"]["law"] == "observation", r["decision"]["reason"]
