"""Exports (issue 13): maps as CSV and .mat read back to the map's own arrays, campaigns,
the diagnosis and calibration JSON tables, refusal to overwrite, bad input named, the CLI."""

from __future__ import annotations

import csv
import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
import scipy.io

from granseg._io import save_json
from granseg.cli import main
from granseg.errors import OutputExistsError
from granseg.export import export_campaign, export_json_tables, export_map, export_paths
from granseg.maps import Map, load_campaign, load_map

FIXTURES = Path(__file__).parent / "fixtures" / "dem" / "bulk"
MATLAB_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,62}")


def small_map(name: str = "G-PP-50", counts: bool = True) -> Map:
    """A 4-frame, 3-layer map with a NaN reading, counts and a cell constant."""
    n = np.array([[10, 12, 9], [11, 0, 10], [10, 12, 8], [9, 11, 10]])
    n_heavy = np.array([[2, 6, 9], [3, 0, 8], [4, 6, 2], [5, 5, 5]])
    with np.errstate(invalid="ignore", divide="ignore"):
        c = np.where(n > 0, n_heavy / np.maximum(n, 1), np.nan)
    arrays = dict(c=c, t=np.array([0.0, 0.1, 0.2, 0.30000000000000004]), z=np.array([0.003, 0.009, 0.015]),
                  name=name, heavy="glass", light="PP", rho_h=2450.0, rho_l=946.0, c0=0.5, M_g=2.04, M_w=1.093,
                  fps=10.0, smoothing_frames=1, H=0.018)
    if counts:
        arrays.update(n=n, n_heavy=n_heavy)
    return Map.from_arrays(arrays)


def read_csv(path: Path) -> tuple[list[str], list[list[str]]]:
    with open(path, encoding="utf-8", newline="") as fh:
        rows = list(csv.reader(fh))
    return rows[0], rows[1:]


def as_float(cells: list[list[str]]) -> np.ndarray:
    return np.array([[float(v) if v else np.nan for v in row] for row in cells])


def assert_map_csv(m: Map, out: Path) -> None:
    """Every CSV table of ``m`` in ``out`` holds exactly the map's numbers."""
    head, rows = read_csv(out / f"{m.name}_c.csv")
    assert head[0] == "t_s" and len(head) == m.n_layers + 1 and len(set(head)) == len(head)
    np.testing.assert_allclose([float(h[2:-1]) for h in head[1:]], m.z, rtol=1e-3)  # z_<metres>m
    a = as_float(rows)
    np.testing.assert_array_equal(a[:, 0], m.t)
    np.testing.assert_array_equal(a[:, 1:], m.c)  # exact, NaN where no reading
    # numpy reads it back as well (what a lab script does)
    b = np.genfromtxt(out / f"{m.name}_c.csv", delimiter=",", skip_header=1)
    np.testing.assert_array_equal(b[:, 1:], m.c)
    for key in ("n", "n_heavy"):
        arr = getattr(m, key)
        path = out / f"{m.name}_{key}.csv"
        if arr is None:
            assert not path.exists()
            continue
        h, r = read_csv(path)
        assert h == head
        np.testing.assert_array_equal(np.array([[int(v) for v in row[1:]] for row in r]), arr)
    h, r = read_csv(out / f"{m.name}_conditions.csv")
    assert h == ["key", "value", "unit"]
    cond = {k: (v, u) for k, v, u in r}
    for key in ("name", "heavy", "light"):
        assert cond[key][0] == getattr(m, key)
    for key in ("rho_h", "rho_l", "c0", "M_g", "M_w"):
        assert float(cond[key][0]) == getattr(m, key)
    assert cond["rho_h"][1] == "kg/m^3" and cond["M_g"][1] == "kg" and cond["c0"][1] == "-"
    assert int(cond["smoothing_frames"][0]) == m.smoothing_frames
    assert cond["fps"][0] == ("" if m.fps is None else repr(m.fps))
    assert cond["view"][0] == (m.view or "")
    for key, value in m.cell.items():
        assert float(cond[key][0]) == value


def assert_map_mat(m: Map, path: Path) -> None:
    d = scipy.io.loadmat(path)
    names = [k for k in d if not k.startswith("__")]
    assert all(MATLAB_NAME.fullmatch(k) for k in names), names
    np.testing.assert_array_equal(d["c"], m.c)
    assert d["t"].shape == (m.n_times, 1) and d["z"].shape == (m.n_layers, 1)  # column vectors
    np.testing.assert_array_equal(d["t"][:, 0], m.t)
    np.testing.assert_array_equal(d["z"][:, 0], m.z)
    for key in ("n", "n_heavy"):
        if getattr(m, key) is None:
            assert key not in d
        else:
            assert d[key].dtype == float
            np.testing.assert_array_equal(d[key], getattr(m, key))
    s = scipy.io.loadmat(path, simplify_cells=True)
    for key in ("name", "heavy", "light"):
        assert s[key] == getattr(m, key)
    for key in ("rho_h", "rho_l", "c0", "M_g", "M_w"):
        assert s[key] == getattr(m, key)
    for key, value in m.cell.items():
        assert s[key] == value
    assert s["smoothing_frames"] == m.smoothing_frames
    assert s["units"]["t"] == "s" and s["units"]["rho_h"] == "kg/m^3"
    assert all(MATLAB_NAME.fullmatch(k) for k in s["units"])


# --------------------------------------------------------------------------- maps


def test_map_round_trip_csv_and_mat(tmp_path: Path) -> None:
    m = small_map()
    written = export_map(m, tmp_path / "out")
    assert sorted(p.name for p in written) == sorted(
        ["G-PP-50_c.csv", "G-PP-50_n.csv", "G-PP-50_n_heavy.csv", "G-PP-50_conditions.csv", "G-PP-50.mat"])
    assert all(p.is_file() for p in written)
    assert_map_csv(m, tmp_path / "out")
    assert_map_mat(m, tmp_path / "out" / "G-PP-50.mat")
    text = (tmp_path / "out" / "G-PP-50_c.csv").read_text(encoding="utf-8")
    assert "0.30000000000000004," in text  # repr precision
    assert "\n0.1,0.2727272727272727,,0.8\n" in text  # NaN is an empty cell
    assert not list((tmp_path / "out").glob(".*"))  # no temporary files left


def test_fixture_map_from_path(tmp_path: Path) -> None:
    src = FIXTURES / "dem-r2-F150.npz"
    m = load_map(src)
    export_map(src, tmp_path)
    assert_map_csv(m, tmp_path)
    assert_map_mat(m, tmp_path / f"{m.name}.mat")


def test_formats_and_map_without_counts(tmp_path: Path) -> None:
    m = small_map(counts=False)
    assert [p.name for p in export_map(m, tmp_path / "csv", formats="csv")] == [
        "G-PP-50_c.csv", "G-PP-50_conditions.csv"]
    assert_map_csv(m, tmp_path / "csv")
    assert [p.name for p in export_map(m, tmp_path / "mat", formats=("mat",))] == ["G-PP-50.mat"]
    assert_map_mat(m, tmp_path / "mat" / "G-PP-50.mat")
    with pytest.raises(ValueError, match="formats"):
        export_map(m, tmp_path / "x", formats=("xlsx",))


def test_campaign(tmp_path: Path) -> None:
    camp = tmp_path / "camp"
    camp.mkdir()
    for f in sorted(FIXTURES.glob("*.npz"))[:3]:
        shutil.copy(f, camp)
    written = export_campaign(camp, tmp_path / "out", formats="csv")
    maps = list(load_campaign(camp))
    assert len(written) == 4 * len(maps)  # c, n, n_heavy, conditions each
    for m in maps:
        assert_map_csv(m, tmp_path / "out")
    # a Campaign object, .mat only
    export_campaign(load_campaign(camp), tmp_path / "mat", formats="mat")
    for m in maps:
        assert_map_mat(m, tmp_path / "mat" / f"{m.name}.mat")


def test_never_overwrites_without_force(tmp_path: Path) -> None:
    m = small_map()
    out = tmp_path / "out"
    out.mkdir()
    (out / "G-PP-50.mat").write_text("mine")
    with pytest.raises(OutputExistsError, match="G-PP-50.mat"):
        export_map(m, out)
    assert [p.name for p in out.iterdir()] == ["G-PP-50.mat"]  # nothing written, not even the CSVs
    assert (out / "G-PP-50.mat").read_text() == "mine"
    export_map(m, out, force=True)
    assert_map_mat(m, out / "G-PP-50.mat")


def test_two_inputs_writing_one_file_refused(tmp_path: Path) -> None:
    a = small_map().save(tmp_path / "a.npz")
    b = small_map().save(tmp_path / "b.npz")  # same experiment name
    with pytest.raises(ValueError, match=f"{re.escape(str(a))} and {re.escape(str(b))} would both write .*G-PP-50_c.csv"):
        export_paths([a, b], tmp_path / "out")
    with pytest.raises(ValueError, match="two exports would both write G-PP-50"):
        export_campaign([small_map(), small_map()], tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_odd_name_gives_safe_file_names(tmp_path: Path) -> None:
    m = small_map(name="run 3/wall")
    names = {p.name for p in export_map(m, tmp_path)}
    assert "run_3_wall_c.csv" in names and "run_3_wall.mat" in names
    assert scipy.io.loadmat(tmp_path / "run_3_wall.mat", simplify_cells=True)["name"] == "run 3/wall"


# --------------------------------------------------------------------------- JSON tables


@pytest.fixture(scope="module")
def calibration_json(tmp_path_factory: pytest.TempPathFactory) -> Path:
    pytest.importorskip("granseg._core", reason="the Rust extension is not built (maturin develop)")
    from granseg.calibration import calibrate
    from granseg.synth.virtual import TABLE1, campaign

    maps = campaign(conditions=TABLE1[:2], n_cells=48, duration=600.0)
    cal = calibrate(maps, refine=False, grid={"k": [0.5, 1.0], "delta_over_H": [0.2, 0.3]}, n_cells=48,
                    progress=False)
    return save_json(tmp_path_factory.mktemp("cal") / "cal.json", cal.to_json())  # as `calibrate --json` does


def test_calibration_tables(calibration_json: Path, tmp_path: Path) -> None:
    doc = json.loads(calibration_json.read_text())
    written = export_json_tables(calibration_json, tmp_path)
    assert sorted(p.name for p in written) == [
        "calibration_experiments.csv", "calibration_grid.csv", "calibration_parameters.csv"]

    head, rows = read_csv(tmp_path / "calibration_parameters.csv")
    assert head == ["parameter", "value", "stderr", "at_bound"]
    assert [r[0] for r in rows] == list(doc["best"])
    for p, value, stderr, at_bound in rows:
        assert float(value) == doc["best"][p]
        assert stderr == "" and doc["stderr"][p] is None  # grid only: no errors (NaN -> null -> empty)
        assert at_bound == "false"

    head, rows = read_csv(tmp_path / "calibration_experiments.csv")
    assert head == ["experiment", "rmsd"]
    assert {r[0]: float(r[1]) for r in rows} == doc["rmsd"]

    head, rows = read_csv(tmp_path / "calibration_grid.csv")
    names = list(doc["rmsd"])
    assert head == ["point", "k", "delta_over_H", *(f"rmsd_{n}" for n in names), "rmsd_mean"]
    assert len(rows) == len(doc["grid"]) == 4
    for row, g in zip(rows, doc["grid"], strict=True):
        vals = [float(v) for v in row[1:]]
        assert vals == [g["k"], g["delta_over_H"], *(g["rmsd"][n] for n in names), g["rmsd_mean"]]


def test_calibration_intervals_and_own_optima(calibration_json: Path, tmp_path: Path) -> None:
    doc = json.loads(calibration_json.read_text())
    names = list(doc["rmsd"])
    doc["stderr"] = {"k": 0.01, "delta_over_H": 0.002}
    doc["at_bound"] = ["k"]
    doc["intervals"] = {"method": "cluster", "level": 0.95, "dof": 1.0, "correlation": [[1.0, 0.1], [0.1, 1.0]],
                        "warnings": [], "params": {p: {"estimate": v, "stderr": doc["stderr"][p], "lo": v - 0.1,
                                                       "hi": v + 0.1, "at_bound": False}
                                                   for p, v in doc["best"].items()}}
    doc["per_experiment"] = {n: {"best": {"k": 0.6 + i, "delta_over_H": 0.2}, "stderr": {"k": 0.05,
                                 "delta_over_H": None}, "rmsd": 0.01 * (i + 1), "converged": True, "message": ""}
                             for i, n in enumerate(names)}
    src = save_json(tmp_path / "cal.json", doc)
    export_json_tables(src, tmp_path / "out")
    head, rows = read_csv(tmp_path / "out" / "calibration_parameters.csv")
    assert head == ["parameter", "value", "stderr", "at_bound", "lo", "hi", "level"]
    k = rows[[r[0] for r in rows].index("k")]
    assert k[2:] == ["0.01", "true", repr(doc["best"]["k"] - 0.1), repr(doc["best"]["k"] + 0.1), "0.95"]
    head, rows = read_csv(tmp_path / "out" / "calibration_experiments.csv")
    assert head == ["experiment", "rmsd", "own_k", "own_k_stderr", "own_delta_over_H", "own_delta_over_H_stderr",
                    "own_rmsd", "own_converged"]
    assert rows[1][:3] == [names[1], repr(doc["rmsd"][names[1]]), "1.6"]
    assert rows[1][5:] == ["", "0.02", "true"]


def diagnosis_doc(open_world: bool = True) -> dict:
    """The keys of result.py's DiagnosisJSON the exporter reads, as `diagnose --json` writes them."""
    names = ["G-PP-50", "S-PP-50"]
    base = {"params": {"k": 0.7, "delta_over_H": 0.18}, "stderr": {"k": 0.01, "delta_over_H": 0.003},
            "rmsd": {"G-PP-50": 0.05, "S-PP-50": 0.07}, "rmsd_mean": 0.06,
            "rmsd_held_out": {"G-PP-50": 0.06, "S-PP-50": 0.08}, "rmsd_held_out_mean": 0.07}
    ext = {**base, "model": "wall_friction", "law": "k = 0.6", "converged": True, "n_evaluations": 12,
           "params": {"k": 0.6, "delta_over_H": 0.2, "mu_w": 0.3}, "stderr": {"k": 0.02, "delta_over_H": 0.004,
                                                                              "mu_w": None},
           "rmsd": {"G-PP-50": 0.02, "S-PP-50": 0.03}, "rmsd_held_out": {"G-PP-50": 0.025, "S-PP-50": 0.035}}
    cands = [{"name": "wall_friction", "rmsd_held_out": 0.03, "rmsd": 0.025, "gain_held_out": 0.04,
              "gain_in_sample": 0.035, "params": ext["params"], "stderr": ext["stderr"], "law": "k = 0.6",
              "description": "Friction at the walls: a, b"},
             {"name": "dilation", "rmsd_held_out": 0.065, "rmsd": 0.055, "gain_held_out": 0.005,
              "gain_in_sample": 0.005, "params": {"k": 0.7, "beta": 1.5e-3}, "stderr": {"k": 0.01, "beta": 2e-4},
              "law": "beta = 0.0015", "description": "Dilation"}]
    doc = {"cause": "wall_friction", "explained": True, "summary": "...", "noise_floor": 0.02,
           "noise": {"per_experiment": {"G-PP-50": 0.018, "S-PP-50": 0.022}, "method": "counts"},
           "baseline": base, "extended": ext, "candidates": cands,
           "experiments": [{"name": n, "heavy": n.split("-")[0], "light": "PP", "c0": 0.5, "M_g": 2.0 + i,
                            "M_w": 1.093, "M_tilde": 0.5, "delta_R": 2.6} for i, n in enumerate(names)],
           "open_world": None}
    if open_world:
        doc["open_world"] = {"time_scale_s": 600.0, "seconds": 3.2, "note": "...", "laws": [
            {"name": "flux_c", "law": "segregation_flux", "variable": "c", "description": "d", "rmsd": 0.04,
             "rmsd_held_out": 0.05, "gain_held_out": 0.02, "n_params": 19, "converged": True},
            {"name": "shear_z", "law": "shear_rate", "variable": "z/H", "description": "e", "rmsd": 0.045,
             "rmsd_held_out": None, "gain_held_out": None, "n_params": 19, "converged": False}]}
    return doc


def test_diagnosis_tables(tmp_path: Path) -> None:
    doc = diagnosis_doc()
    src = save_json(tmp_path / "diag.json", doc)
    written = export_json_tables(src, tmp_path / "out")
    assert sorted(p.name for p in written) == ["diagnosis_candidates.csv", "diagnosis_experiments.csv",
                                              "diagnosis_laws.csv", "diagnosis_parameters.csv"]
    out = tmp_path / "out"

    head, rows = read_csv(out / "diagnosis_candidates.csv")
    assert head == ["name", "rmsd", "rmsd_held_out", "gain_in_sample", "gain_held_out", "k", "k_stderr",
                    "delta_over_H", "delta_over_H_stderr", "mu_w", "mu_w_stderr", "beta", "beta_stderr",
                    "law", "description"]
    assert rows[0] == ["wall_friction", "0.025", "0.03", "0.035", "0.04", "0.6", "0.02", "0.2", "0.004", "0.3",
                       "", "", "", "k = 0.6", "Friction at the walls: a, b"]
    assert rows[1][11:13] == ["0.0015", "0.0002"] and rows[1][7:11] == ["", "", "", ""]

    head, rows = read_csv(out / "diagnosis_experiments.csv")
    assert head == ["experiment", "baseline_rmsd", "baseline_rmsd_held_out", "extended_rmsd",
                    "extended_rmsd_held_out", "noise_floor", "heavy", "light", "c0", "M_g", "M_w"]
    assert rows == [["G-PP-50", "0.05", "0.06", "0.02", "0.025", "0.018", "G", "PP", "0.5", "2.0", "1.093"],
                    ["S-PP-50", "0.07", "0.08", "0.03", "0.035", "0.022", "S", "PP", "0.5", "3.0", "1.093"]]

    head, rows = read_csv(out / "diagnosis_parameters.csv")
    assert head == ["model", "effect", "parameter", "value", "stderr"]
    assert rows == [["baseline", "baseline", "k", "0.7", "0.01"], ["baseline", "baseline", "delta_over_H", "0.18",
                                                                    "0.003"],
                    ["extended", "wall_friction", "k", "0.6", "0.02"],
                    ["extended", "wall_friction", "delta_over_H", "0.2", "0.004"],
                    ["extended", "wall_friction", "mu_w", "0.3", ""]]

    head, rows = read_csv(out / "diagnosis_laws.csv")
    assert head == list(doc["open_world"]["laws"][0])
    assert rows[1] == ["shear_z", "shear_rate", "z/H", "e", "0.045", "", "", "19", "false"]


def test_diagnosis_without_extension_or_laws(tmp_path: Path) -> None:
    doc = diagnosis_doc(open_world=False)
    doc.update(cause="none", extended=None)
    written = export_json_tables(save_json(tmp_path / "d.json", doc), tmp_path / "out")
    assert "diagnosis_laws.csv" not in {p.name for p in written}
    _, rows = read_csv(tmp_path / "out" / "diagnosis_experiments.csv")
    assert rows[0][3:5] == ["", ""]
    _, rows = read_csv(tmp_path / "out" / "diagnosis_parameters.csv")
    assert {r[0] for r in rows} == {"baseline"}


def test_bad_json_names_the_file(tmp_path: Path) -> None:
    other = tmp_path / "velocity.json"
    other.write_text(json.dumps({"v0": 0.2, "delta_over_H": 0.18}))
    with pytest.raises(ValueError, match=re.escape(str(other))):
        export_json_tables(other, tmp_path / "out")
    broken = tmp_path / "broken.json"
    broken.write_text("{not json")
    with pytest.raises(ValueError, match=re.escape(str(broken)) + ".*not valid JSON"):
        export_json_tables(broken, tmp_path / "out")
    malformed = tmp_path / "diag.json"
    malformed.write_text(json.dumps({"cause": "none", "baseline": {}, "candidates": []}))
    with pytest.raises(ValueError, match=re.escape(str(malformed)) + ".*malformed diagnosis"):
        export_json_tables(malformed, tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_json_tables_refuse_to_overwrite(tmp_path: Path) -> None:
    src = save_json(tmp_path / "diag.json", diagnosis_doc())
    export_json_tables(src, tmp_path / "out")
    before = (tmp_path / "out" / "diagnosis_candidates.csv").read_text()
    with pytest.raises(OutputExistsError, match="diagnosis_"):
        export_json_tables(src, tmp_path / "out")
    assert export_json_tables(src, tmp_path / "out", force=True)
    assert (tmp_path / "out" / "diagnosis_candidates.csv").read_text() == before


# --------------------------------------------------------------------------- CLI


def test_cli(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    m = small_map()
    npz = m.save(tmp_path / "map.npz")
    diag = save_json(tmp_path / "diag.json", diagnosis_doc())
    out = tmp_path / "out"
    assert main(["export", str(npz), str(diag), "--out", str(out), "--format", "csv"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 4 + 4 and all(line.startswith("wrote ") for line in lines)
    assert {Path(line[6:]).name for line in lines} == {p.name for p in out.iterdir()}
    assert_map_csv(m, out)
    assert not (out / "G-PP-50.mat").exists()

    # again: refused, one line naming the file, exit code 2, nothing changed
    assert main(["export", str(npz), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("granseg export: error:") and "G-PP-50_c.csv" in err and len(err.splitlines()) == 1
    assert not (out / "G-PP-50.mat").exists()
    assert main(["export", str(npz), "--out", str(out), "--format", "mat", "--force"]) == 0
    assert_map_mat(m, out / "G-PP-50.mat")
    capsys.readouterr()

    # a campaign directory
    assert main(["export", str(FIXTURES), "--out", str(tmp_path / "camp"), "--format", "both"]) == 0
    assert len(capsys.readouterr().out.splitlines()) == 5 * len(list(FIXTURES.glob("*.npz")))

    # bad inputs: one line naming the file
    other = tmp_path / "notes.txt"
    other.write_text("x")
    for bad in (other, tmp_path / "missing.npz"):
        assert main(["export", str(bad), "--out", str(tmp_path / "bad")]) == 2
        err = capsys.readouterr().err
        assert str(bad) in err and len(err.splitlines()) == 1
