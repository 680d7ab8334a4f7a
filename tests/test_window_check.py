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
