"""Calibration: known parameters are recovered from noisy model maps, the factorial
table has the paper's layout, the CLI writes the documented JSON, dask gives the
same numbers, bad input names the parameter."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("granseg._core", reason="the Rust extension is not built (maturin develop)")

import granseg  # noqa: E402
from granseg.calibration import calibrate, check_grid  # noqa: E402
from granseg.cli import main  # noqa: E402
from granseg.maps import Map, load_campaign, moving_average, save_map  # noqa: E402

TRUTH = {"k": 0.62, "delta_over_H": 0.195}
N_CELLS = 60
PARTICLES = 12  # particles per layer and frame in a 9 D_p wide window
EXPERIMENTS = [  # name, heavy, rho_h, c0, M_g: the paper's Table 4 cases (Table 1 masses)
    ("C-PP-50", "ceramic", 3500.0, 0.50, 2.67),
    ("G-PP-50", "glass", 2450.0, 0.50, 2.04),
    ("G-POM-50", "glass", 2450.0, 0.50, 2.52),
]
RHO = {"PP": 946.0, "POM": 1750.0}
# Long enough to reach the steady profile, which pins k apart from delta/H (the
# transient alone only fixes their trade-off); coarse frames keep the test fast.
T = np.arange(0.0, 6000.0, 50.0)


def model_maps(truth: dict, seed: int = 1, smoothing: int = 1) -> list[Map]:
    """Maps the model makes at ``truth`` plus binomial counting noise."""
    rng = np.random.default_rng(seed)
    out = []
    for name, heavy, rho_h, c0, m_g in EXPERIMENTS:
        light = name.split("-")[1]
        sol = granseg.simulate(rho_h=rho_h, rho_l=RHO[light], c0=c0, t=T, n_cells=N_CELLS, **truth)
        c_true = np.clip(np.asarray(sol.layers()), 0, 1)
        n = np.full(c_true.shape, PARTICLES)
        n_heavy = rng.binomial(n, c_true)
        c_raw = n_heavy / n
        out.append(Map(c=moving_average(c_raw, smoothing), t=T, z=(np.arange(15) + 0.5) * 6e-3,
                       name=name, heavy=heavy, light=light, rho_h=rho_h, rho_l=RHO[light], c0=c0,
                       M_g=m_g, M_w=1.093, n=n, n_heavy=n_heavy, c_raw=c_raw,
                       smoothing_frames=smoothing))
    return out


@pytest.fixture(scope="module")
def maps() -> list[Map]:
    return model_maps(TRUTH)


@pytest.fixture(scope="module")
def cal(maps):
    return calibrate(maps, n_cells=N_CELLS, progress=False)


def test_recovers_truth_within_reported_uncertainty(cal):
    assert cal.refined and cal.converged, cal.message
    for key, true in TRUTH.items():
        err = cal.stderr[key]
        assert 0 < err < 0.05 * true, (key, err)  # informative, not a blanket
        assert abs(cal.best[key] - true) < 3 * err, (key, cal.best[key], true, err)
    # the noise floor: binomial variance c(1-c)/N averaged over the maps
    assert cal.rmsd_mean < np.sqrt(0.25 / PARTICLES)


def test_reported_uncertainty_is_calibrated_over_noise_draws():
    """Over many noise draws (maps smoothed over 5 frames, as real maps are) the
    scatter of the estimates matches the reported standard errors. Independent
    counts: the entries' errors (``"jacobian"``, what "auto" takes for three experiments)
    are right here (cluster errors: tests/test_uncertainty.py)."""
    z = []
    for seed in range(20):
        c = calibrate(model_maps(TRUTH, seed=100 + seed, smoothing=5), n_cells=N_CELLS, progress=False,
                      errors="jacobian")
        z.append([(c.best[k] - v) / c.stderr[k] for k, v in TRUTH.items()])
    z = np.array(z)
    assert np.all(np.abs(z.mean(axis=0)) < 0.8), z.mean(axis=0)
    assert np.all((z.std(axis=0) > 0.6) & (z.std(axis=0) < 1.6)), z.std(axis=0)


def test_factorial_table_layout_and_minimum(cal):
    lines = cal.table().splitlines()
    assert "Factors" in lines[0] and "RMSD" in lines[0]
    assert lines[1].split() == ["ID", "k", "delta_over_H", *cal.names, "mean"]
    rows = [ln for ln in lines[3:] if ln[:4].replace("*", "").strip().isdigit()]
    assert len(rows) == 9
    ids = [int(r[:4].replace("*", "")) for r in rows]
    assert ids == list(range(1, 10))
    factors = [tuple(float(v) for v in r[4:].split()[:2]) for r in rows]
    assert factors == [(k, d) for k in (0.5, 0.6, 0.7) for d in (0.18, 0.2, 0.22)]  # paper's order
    # minimum at the grid point nearest the truth (in grid steps), marked in the table
    nearest = min(range(9), key=lambda i: ((factors[i][0] - 0.62) / 0.1) ** 2
                  + ((factors[i][1] - 0.195) / 0.02) ** 2)
    assert cal.best_grid_index == nearest
    assert rows[nearest].startswith("*") and sum(r.startswith("*") for r in rows) == 1
    # the table is the sweep's own per-experiment RMSD
    assert cal.grid_rmsd.shape == (9, 3) and np.all(cal.grid_rmsd > 0)


def test_model_maps_compared_as_documented(maps, cal):
    """The model map is the layer mean at the measured times, smoothed the same way."""
    m = maps[0]
    sol = granseg.simulate(**m.case(), **cal.best, t=m.t, n_cells=N_CELLS)
    np.testing.assert_allclose(cal.model_layers[0], np.asarray(sol.layers()), atol=1e-6)
    rmsd = np.sqrt(np.nanmean((m.c - np.asarray(sol.layers())) ** 2))
    assert cal.rmsd[m.name] == pytest.approx(rmsd, abs=1e-6)


def test_smoothing_recorded_in_map_is_applied(maps):
    smooth = model_maps(TRUTH, smoothing=5)[:1]
    res = granseg.sweep(grid={"k": [0.62]}, cases=[{**smooth[0].case(), "delta_over_H": 0.195}],
                        measured=[smooth[0].measured()], n_cells=N_CELLS)
    raw = granseg.simulate(**smooth[0].case(), **TRUTH, t=T, n_cells=N_CELLS).layers()
    np.testing.assert_allclose(np.asarray(res.layers[0]), moving_average(np.asarray(raw), 5), atol=1e-6)


def test_cli_json_schema_and_no_overwrite(tmp_path, maps, capsys):
    camp = tmp_path / "campaign"
    camp.mkdir()
    for m in maps[:2]:
        m.save(camp / f"{m.name}.npz")
    out = tmp_path / "cal.json"
    args = ["calibrate", str(camp), "--json", str(out), "--per-experiment", "--n-cells", str(N_CELLS),
            "--max-nfev", "6", "-q"]
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert "Factors" in printed and "refined optimum" in printed
    data = json.loads(out.read_text())
    names = ["C-PP-50", "G-PP-50"]
    assert set(data["best"]) == set(data["stderr"]) == {"k", "delta_over_H"}
    assert sorted(data["rmsd"]) == names
    assert data["rmsd_mean"] == pytest.approx(np.mean([data["rmsd"][n] for n in names]))
    assert len(data["grid"]) == 9
    g = data["grid"][0]
    assert (g["k"], g["delta_over_H"]) == (0.5, 0.18) and sorted(g["rmsd"]) == names
    assert g["rmsd_mean"] == pytest.approx(np.mean(list(g["rmsd"].values())))
    per = data["per_experiment"]
    assert sorted(per) == names and set(per["G-PP-50"]["best"]) == {"k", "delta_over_H"}
    assert main(args) == 2  # exists: refused without --force
    assert "exists" in capsys.readouterr().err


@pytest.mark.parametrize(
    "grid, pattern",
    [
        ({"kk": [0.5]}, "'kk': not a model parameter"),
        ({"k": [0.5, float("nan")]}, "'k': values must be finite"),
        ({"k": []}, "'k': expected a non-empty list"),
        ({"k": [0.5, 0.5]}, "'k': repeated values"),
        ({"rho_h": [2000.0]}, "'rho_h': fixed by each experiment"),
    ],
)
def test_bad_grid_names_parameter(grid, pattern):
    with pytest.raises(ValueError, match=pattern):
        check_grid(grid, list(granseg.defaults()))


def test_invalid_grid_value_reaches_solver_check(maps):
    with pytest.raises(ValueError, match="k"):
        calibrate(maps[:1], grid={"k": [-0.5, 0.6], "delta_over_H": [0.2]}, n_cells=N_CELLS,
                  refine=False, progress=False)


def test_bad_bounds(maps):
    with pytest.raises(ValueError, match="bounds of 'k'"):
        calibrate(maps[:1], bounds={"k": (0.9, 0.3)}, n_cells=N_CELLS, progress=False)
    with pytest.raises(ValueError, match=r"bounds: parameter\(s\) \['b'\]"):
        calibrate(maps[:1], bounds={"b": (0.01, 0.1)}, n_cells=N_CELLS, progress=False)


def test_campaign_directory_errors_name_the_file(tmp_path, maps):
    with pytest.raises(ValueError, match="no map files"):
        calibrate(tmp_path, progress=False)
    maps[0].save(tmp_path / "a.npz")
    arrays = maps[1].to_arrays()
    arrays["c"] = np.full_like(arrays["c"], np.nan)
    with open(tmp_path / "b.npz", "wb") as fh:
        np.savez(fh, **arrays)
    with pytest.raises(ValueError, match="b.npz: field 'c': every entry is NaN"):
        calibrate(tmp_path, progress=False)


def test_dask_client_gives_same_numbers(maps):
    distributed = pytest.importorskip("distributed", reason="dask[distributed] not installed")
    kw = dict(n_cells=N_CELLS, max_nfev=5, progress=False)
    local = calibrate(maps[:2], **kw)
    with distributed.LocalCluster(processes=False, n_workers=1, threads_per_worker=2,
                                  dashboard_address=None) as cluster, distributed.Client(cluster) as client:
        remote = calibrate(maps[:2], client=client, **kw)
    np.testing.assert_allclose(remote.grid_rmsd, local.grid_rmsd, rtol=1e-10, atol=0)
    for key in local.best:
        assert remote.best[key] == pytest.approx(local.best[key], rel=1e-9)
        assert remote.stderr[key] == pytest.approx(local.stderr[key], rel=1e-6)


def test_load_campaign_then_calibrate_without_refine(tmp_path, maps):
    for m in maps:
        save_map(tmp_path / f"{m.name}.npz", **m.to_arrays())
    cal = calibrate(load_campaign(tmp_path), refine=False, n_cells=N_CELLS, progress=False)
    assert not cal.refined and all(np.isnan(v) for v in cal.stderr.values())
    assert cal.best == cal.grid_points[cal.best_grid_index]
    assert cal.to_json()["rmsd_mean"] == pytest.approx(cal.grid_mean[cal.best_grid_index])


def test_refinement_counts_every_experiment_the_same():
    """Two experiments the model cannot both fit, one filmed ten times longer: the refined
    point minimises the sum of the experiments' mean squared errors (the criterion the
    factorial table ranks by, and the diagnosis's), not the pooled sum of squares that
    the long experiment would dominate."""
    maps = []
    for (name, heavy, rho_h, c0, m_g), truth, t in zip(
            EXPERIMENTS[:2], [TRUTH, {"k": 0.72, "delta_over_H": 0.17}],
            [np.arange(0.0, 3000.0, 100.0), np.arange(0.0, 6000.0, 10.0)], strict=True):
        light = name.split("-")[1]
        sol = granseg.simulate(rho_h=rho_h, rho_l=RHO[light], c0=c0, t=t, n_cells=N_CELLS, **truth)
        maps.append(Map(c=np.clip(np.asarray(sol.layers()), 0, 1), t=t, z=(np.arange(15) + 0.5) * 6e-3,
                        name=name, heavy=heavy, light=light, rho_h=rho_h, rho_l=RHO[light], c0=c0,
                        M_g=m_g, M_w=1.093))
    cal = calibrate(maps, n_cells=N_CELLS, progress=False)
    assert cal.converged, cal.message

    def sum_mse(point):
        res = granseg.sweep(None, cases=[{**m.case(), **point} for m in maps],
                            measured=[m.measured() for m in maps], n_cells=N_CELLS)
        return float(np.sum(np.asarray(res.rmsd) ** 2))

    best = dict(cal.best)
    at_best = sum_mse(best)
    for key in best:
        for step in (-0.005, 0.005):
            moved = {**best, key: best[key] * (1 + step)}
            assert at_best <= sum_mse(moved) * (1 + 1e-9), (key, step)


def test_optimum_on_a_bound_is_flagged(maps, capsys):
    """Bounds that exclude the truth (k = 0.62): the refinement stops on k's upper bound,
    says so in the result, warns, and the CLI summary tells how to widen the range."""
    from granseg.calibration import CalibrationWarning
    from granseg.cli.calibrate import summary

    with pytest.warns(CalibrationWarning, match="k = 0.6 lies on a bound"):
        cal = calibrate(maps, n_cells=N_CELLS, progress=False, bounds={"k": (0.5, 0.6)})
    assert cal.at_bound == ["k"] and cal.best["k"] == pytest.approx(0.6)
    assert cal.to_json()["at_bound"] == ["k"]
    assert "--bounds k=LO:HI" in summary(cal)
    from granseg.report.calibration import _summary

    assert "k ended on a bound" in _summary({"calibration": cal.to_json()})
    free = calibrate(maps, n_cells=N_CELLS, progress=False)
    assert free.at_bound == []
