"""The converted DEM campaign (tests/fixtures/dem, made by examples/dem/campaign.py) through
the chain (issue 17): its maps load as campaigns in their own cells, the bulk view keeps its
heavy share exactly, and the diagnosis says what the baseline gets wrong."""

from __future__ import annotations

import json
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from granseg.calibration import CalibrationWarning
from granseg.diagnosis import diagnose
from granseg.errors import QualityWarning
from granseg.maps import load_campaign
from granseg.velocity import load_velocity

FIXTURE = Path(__file__).parent / "fixtures" / "dem"


def _wall() -> Any:
    with warnings.catch_warnings():  # most wall views fail their window check: that is tested below
        warnings.simplefilter("ignore", QualityWarning)
        return load_campaign(FIXTURE / "wall")


def test_both_views_load_as_campaigns_in_their_own_cells():
    bulk, wall = load_campaign(FIXTURE / "bulk"), _wall()
    assert [m.name for m in bulk.maps] == [m.name for m in wall.maps] and len(bulk.maps) == 8
    for b, w in zip(bulk.maps, wall.maps, strict=True):
        assert b.view == "bulk" and w.view == "wall" and b.cell == w.cell and b.c0 == w.c0
        assert {m.n_layers for m in (b, w)} <= {11, 12} and b.cell["H"] / b.cell["D_p"] == pytest.approx(
            b.n_layers, abs=0.5)
        # the bulk holds every grain in every snapshot: its heavy share by count never moves
        share = b.n_heavy.sum(1) / b.n.sum(1)
        assert np.ptp(share) == 0 and not b.failed_checks
        assert np.all(w.n <= b.n)


def test_the_depth_mean_check_flags_the_wall_view_and_passes_the_bulk():
    """The grains at the side walls are not the bed (issue 17): as the beds un-mix, the heavy
    share of the wall view drifts far beyond what its counts allow, while the bulk's holds."""
    bulk, wall = load_campaign(FIXTURE / "bulk"), _wall()
    assert all(not m.failed_checks for m in bulk.maps)
    flagged = [m.name for m in wall.maps if m.failed_checks == ["heavy_share_conserved"]]
    assert len(flagged) >= 6, flagged
    for b in bulk.maps:  # and the beds did un-mix: heavy grains reached the bottom layer
        assert b.c[0, 0] == 0 and b.c[-1, 0] > 0.05, b.name


def test_the_runs_velocity_profiles_fall_from_the_plate_to_the_lid():
    """A bed 12 grains wide shears all through: the grains next to the plate move at most at its
    0.97 m/s, and under the lighter lid the top of the bed still slides (the model's v1 = 0 is
    not this cell's)."""
    top = {}
    for path in sorted((FIXTURE / "velocity").glob("*.json")):
        prof = load_velocity(path)
        assert 0.7 < prof.v[0] < 1.0 and prof.v[0] > 1.5 * prof.v[-1] > 0, path.name
        assert 0.08 < prof.delta_over_H < 0.6, path.name
        assert json.loads(path.read_text())["conditions"]["view"] == "bulk"
        top[path.stem] = prof.v[-1]
    for ratio in ("1.5", "2", "3", "4"):
        assert top[f"dem-r{ratio}-F150"] > top[f"dem-r{ratio}-F600"], ratio


def test_the_chain_on_the_bulk_view_says_what_the_baseline_misses(tmp_path):
    with warnings.catch_warnings():  # k reaches its bound: the bed barely un-mixes in 11 s
        warnings.simplefilter("ignore", CalibrationWarning)
        r = diagnose(FIXTURE / "bulk", n_cells=48, progress=False, max_nfev=12, report=tmp_path / "diag").result
    assert r["baseline"]["rmsd_mean"] > 2 * r["noise_floor"]  # far beyond the noise
    assert r["cause"] != "none" and r["candidates"] and "window_check" not in r
    # the page sets each run's wall view beside its bulk
    assert len(r["views"]) == 8 and (tmp_path / "diag" / "figures" / "views.png").is_file()
    assert "<h2>The camera's view against the bulk</h2>" in (tmp_path / "diag" / "index.html").read_text()


def test_the_chain_on_the_wall_view_examines_the_view_not_the_physics():
    """Wall maps flagged by the window check are diagnosed with the observation law only: no
    physics cause is bent to fit a drifting view, and the view's bias is measured held out."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CalibrationWarning)
        r = diagnose(_wall(), n_cells=48, progress=False, max_nfev=12).result
    assert len(r["window_check"]["flagged"]) >= 6 and r["candidates"] == []
    laws = r["open_world"]["laws"]
    assert [x["name"] for x in laws] == ["law_observation"] and laws[0]["gain_held_out"] > 0.02, laws
    assert r["cause"] in ("new_law", "unexplained")


def test_each_runs_own_profile_goes_into_the_calibration(tmp_path):
    import shutil

    from granseg.calibration import calibrate

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CalibrationWarning)
        c = calibrate(FIXTURE / "bulk", velocity=FIXTURE / "velocity", velocity_shape="tabulated", n_cells=48,
                      progress=False)
    assert c.keys == ["k"] and np.isfinite(c.best["k"])
    assert any(k.startswith("law_shear_z_") for k in c.data.measured[0])  # the measured shear rate is used
    partial = tmp_path / "velocity"
    shutil.copytree(FIXTURE / "velocity", partial)
    (partial / "dem-r2-F150.json").unlink()
    with pytest.raises(FileNotFoundError, match="no velocity profile for experiment 'dem-r2-F150'"):
        calibrate(FIXTURE / "bulk", velocity=partial, n_cells=48, progress=False)


def test_each_map_finds_its_other_view_and_the_report_shows_both(tmp_path):
    """`granseg dem` writes a run's views as OUT/<view>/NAME.npz: a map finds its other view
    there, and the calibration page shows both views side by side with their window checks."""
    import shutil

    from granseg.maps import views_of
    from granseg.measure.quality import views_table
    from granseg.report import build_report

    bulk = load_campaign(FIXTURE / "bulk")
    views = views_of(bulk.maps[0])
    assert set(views) == {"bulk", "wall"} and views["wall"].path == FIXTURE / "wall" / bulk.maps[0].path.name
    rows = views_table(bulk.maps)
    assert [r["name"] for r in rows] == [m.name for m in bulk.maps]
    assert all(r["views"]["bulk"]["drift"] == 0 and r["views"]["bulk"]["passed"] for r in rows)
    assert all(r["views"]["wall"]["limit"] > r["views"]["bulk"]["limit"] for r in rows)  # fewer grains

    names = [m.path.name for m in bulk.maps[:2]]
    for view in ("bulk", "wall"):
        (tmp_path / view).mkdir()
        for name in names[: 2 if view == "bulk" else 1]:  # the second run has no wall view here
            shutil.copy(FIXTURE / view / name, tmp_path / view / name)
    camp = load_campaign(tmp_path / "bulk")
    assert [bool(views_of(m)) for m in camp.maps] == [True, False]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CalibrationWarning)
        page = build_report(camp, tmp_path / "report", refine=False, n_cells=48, progress=False,
                            grid={"k": [0.5, 1.0], "delta_over_H": [0.2, 0.3]})
    data = json.loads((tmp_path / "report" / "report.json").read_text())
    assert [r["name"] for r in data["views"]] == [camp.maps[0].name]
    assert "<h2>The camera's view against the bulk</h2>" in page.read_text()
    assert (tmp_path / "report" / "figures" / "views.png").is_file()
