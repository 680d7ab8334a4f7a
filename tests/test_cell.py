"""Maps that carry their own cell (issue 17): another bed height, layer count and plate speed,
honoured by every model run made for the map."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import granseg
from granseg.calibration import CalibrationWarning, calibrate
from granseg.maps import load_campaign
from granseg.synth.virtual import Condition, campaign

# an 11-grain bed (H = 11 D_p) with the plate at 40 rpm instead of 23.44
CELL = {"H": 11 * 6e-3, "rpm": 40.0}
TRUTH = {"k": 0.85, "delta_over_H": 0.25}
CONDITIONS = [Condition("glass", "PP", 0.5, 1.5), Condition("steel", "PP", 0.5, 3.9),
              Condition("ceramic", "PP", 0.3, 2.0)]
N_CELLS = 66


@pytest.fixture(scope="module")
def cell_campaign(tmp_path_factory):
    out = tmp_path_factory.mktemp("cell")
    campaign(out, conditions=CONDITIONS, cell=CELL, n_layers=11, noise="independent", seed=3, fps=0.05,
             duration=2400.0, n_cells=N_CELLS, **TRUTH)
    return load_campaign(out)


def test_virtual_maps_carry_their_cell_and_layers(cell_campaign):
    m = cell_campaign.maps[0]
    assert m.n_layers == 11 and m.cell == pytest.approx(CELL)
    np.testing.assert_allclose(m.z, (np.arange(11) + 0.5) * 6e-3)
    assert m.case()["H"] == pytest.approx(0.066) and m.case()["rpm"] == 40.0


def test_a_campaign_in_another_cell_calibrates_back_to_its_truth(cell_campaign):
    cal = calibrate(cell_campaign, n_cells=N_CELLS, progress=False, view_dwell=False)
    assert cal.converged, cal.message
    for key, true in TRUTH.items():
        assert abs(cal.best[key] - true) < max(3 * cal.stderr[key], 0.02 * true), (key, cal.best[key], cal.stderr)


def test_the_cell_matters(cell_campaign):
    """The same maps read as if made in docs/model.md's cell fit worse and elsewhere: the cell is used."""
    stripped = [granseg.Map.from_arrays({**m.to_arrays(), "H": None, "rpm": None}) for m in cell_campaign.maps]
    assert stripped[0].cell == {}
    with_cell = calibrate(cell_campaign, n_cells=N_CELLS, progress=False, view_dwell=False)
    with warnings.catch_warnings():  # a wrong cell may push an interval to a bound: that is the point
        warnings.simplefilter("ignore", CalibrationWarning)
        without = calibrate(stripped, n_cells=N_CELLS, progress=False, view_dwell=False)
    assert without.rmsd_mean > with_cell.rmsd_mean + 0.02  # counting noise alone is ~0.1 here
    assert abs(without.best["k"] - TRUTH["k"]) > 3 * with_cell.stderr["k"]


def test_simulate_and_sweep_give_any_layer_count():
    sol = granseg.simulate(t=[0.0, 600.0], n_cells=N_CELLS, H=0.066, n_layers=1)
    res = granseg.sweep({"k": [0.6, 0.8]}, base={"H": 0.066}, t=[0.0, 600.0], n_layers=11, n_cells=N_CELLS)
    assert res.layers.shape == (2, 2, 11)
    np.testing.assert_allclose(res.layers[0].mean(axis=1), sol.layers(1)[:, 0], atol=1e-12)
    with pytest.raises(ValueError, match="n_layers"):
        granseg.sweep(base={}, t=[0.0, 1.0], n_layers=0)


def test_simulate_like_a_map_uses_its_cell_layers_and_times(cell_campaign, tmp_path, capsys):
    from granseg.cli import main
    from granseg.maps import load_map

    m = cell_campaign.maps[0]
    out = tmp_path / "sim.npz"
    assert main(["simulate", "--like", str(m.path), "--k", str(TRUTH["k"]), "--delta-over-H",
                 str(TRUTH["delta_over_H"]), "--n-cells", str(N_CELLS), "--out", str(tmp_path / "fig"),
                 "--npz", str(out)]) == 0
    text = capsys.readouterr().out
    rmsd = float(text.split("RMSD ")[-1].split()[0])
    assert rmsd < 0.2  # the truth against its own noisy map: counting noise only
    sim = load_map(out)
    assert sim.n_layers == 11 and sim.cell == pytest.approx(CELL) and np.array_equal(sim.t, m.t)
