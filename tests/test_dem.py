"""DEM dumps as data (issue 12): exact layer counts, shares and speeds from tiny dumps the
tests write, in LAMMPS ``lj`` and SI units; one clear error per kind of bad input."""

from __future__ import annotations

import gzip
import json
import math
from pathlib import Path

import numpy as np
import pytest

from granseg.dem import load_config, load_run, read_dumps
from granseg.errors import DemFormatError, OutputExistsError
from granseg.maps import load_campaign, load_map

# lj units of the example: d = 6 mm, light density 946 kg/m^3, g = 1
LJ = {"length_m": 0.006, "time_s": math.sqrt(0.006 / 9.81), "density_kg_m3": 946.0}
LX, LY, BOTTOM = 8.0, 4.0, 0.5  # box along the flow, gap between the side walls, plate surface
STEPS = (0, 1000, 2000, 3000, 4000, 5000)


def _bed(seed: int = 0) -> dict[str, np.ndarray]:
    """A 4-layer bed: per layer, grains at known heights and across-positions; the heavy
    (type 2) count per layer is fixed; a plate (type 3) row below the bed."""
    rng = np.random.default_rng(seed)
    rows = []
    heavy_per_layer = (1, 2, 5, 6)
    for j, n_heavy in enumerate(heavy_per_layer):
        for k in range(8):
            y = 0.5 if k < 2 else (LY - 0.6 if k < 3 else 1.5 + rng.uniform(0, 1.0))  # 3 grains at the walls
            z = BOTTOM + j + 0.5 + rng.uniform(-0.3, 0.3)
            rows.append((2 if k < n_heavy else 1, rng.uniform(0, LX), y, z))
    rows += [(3, x + 0.5, 2.0, 0.0) for x in range(int(LX))]
    typ, x, y, z = (np.array(c) for c in zip(*rows, strict=True))
    return {"id": np.arange(1, len(typ) + 1), "type": typ, "x": x, "y": y, "z": z}


def _speeds(bed: dict[str, np.ndarray], step: int) -> np.ndarray:
    """Flow speed per grain: 2 exp(-h / 1.2) (h above the plate, dump units), plus a
    per-snapshot offset that averages out, zero for the plate."""
    h = bed["z"] - BOTTOM
    v = 2.0 * np.exp(-h / 1.2) + 0.05 * math.sin(step)
    return np.where(bed["type"] == 3, 1.0, v)


def _write_dump(path: Path, bed: dict[str, np.ndarray], steps=STEPS, *, scale: float = 1.0, vscale: float = 1.0,
                order=("id", "type", "x", "y", "z", "vx", "vy", "vz", "radius"), tilted: bool = False,
                radius: float = 0.5, cut: bool = False) -> None:
    lines = []
    for step in steps:
        cols = {"id": bed["id"], "type": bed["type"], "x": bed["x"] * scale, "y": bed["y"] * scale,
                "z": bed["z"] * scale, "vx": _speeds(bed, step) * vscale, "vy": 0 * bed["x"], "vz": 0 * bed["x"],
                "radius": np.full(bed["id"].size, radius * scale), "diameter": np.full(bed["id"].size, 2 * radius * scale)}
        cols["xs"] = cols["x"] / (LX * scale)
        lines += ["ITEM: TIMESTEP", str(step), "ITEM: NUMBER OF ATOMS", str(bed["id"].size)]
        if tilted:
            lines += ["ITEM: BOX BOUNDS xy xz yz pp ff ff", f"0 {(LX + 1) * scale} {scale}", f"0 {LY * scale} 0",
                      f"-1 {20 * scale} 0"]
        else:
            lines += ["ITEM: BOX BOUNDS pp ff ff", f"0 {LX * scale}", f"0 {LY * scale}", f"-1 {20 * scale}"]
        lines.append("ITEM: ATOMS " + " ".join(order))
        for i in range(bed["id"].size):
            lines.append(" ".join(f"{cols[c][i]:.10g}" if c not in ("id", "type") else str(int(cols[c][i]))
                                  for c in order))
    text = "\n".join(lines) + "\n"
    if cut:
        text = text[: int(len(text) * 0.93)]
    if path.suffix == ".gz":
        with gzip.open(path, "wt") as f:
            f.write(text)
    else:
        path.write_text(text)


def _config(units=LJ, scale: float = 1.0, **over) -> dict:
    cfg = {"types": {"1": {"name": "light", "density": 1.0}, "2": {"name": "heavy", "density": 3.0}},
           "units": units, "flow_axis": "x", "up_axis": "z", "side_walls": {"y": [0.0, LY * scale]},
           "bottom_z": BOTTOM * scale, "timestep": 2e-4, "lid_force": 300.0, "plate_speed": 2.0,
           "diameter": 1.0 * scale, "gravity": 1.0}
    cfg.update(over)
    return cfg


def _run_dir(tmp_path: Path, name="run", config=None, **dump_kw) -> Path:
    d = tmp_path / name
    d.mkdir()
    _write_dump(d / "grains.dump", _bed(), **dump_kw)
    (d / "dem.json").write_text(json.dumps(config if config is not None else _config()))
    return d


def _expected(view: str = "bulk"):
    bed = _bed()
    g = bed["type"] != 3
    if view == "wall":
        g &= (bed["y"] < 1.0) | (bed["y"] > LY - 1.0)
    h = bed["z"] - BOTTOM
    H = (h[bed["type"] != 3] + 0.5).max()
    layer = np.clip(np.floor(h / (H / 4)).astype(int), 0, 3)
    n = np.bincount(layer[g], minlength=4)
    n_heavy = np.bincount(layer[g], bed["type"][g] == 2, minlength=4)
    return bed, g, layer, n, n_heavy, H


def test_lj_run_gives_exact_counts_shares_times_and_cell(tmp_path):
    run = load_run(_run_dir(tmp_path))
    bed, g, layer, n, n_heavy, H = _expected()
    m = run.to_map("bulk")
    assert m.n_layers == 4 and m.view == "bulk"
    assert np.array_equal(m.n, np.tile(n, (len(STEPS), 1)))
    assert np.array_equal(m.n_heavy, np.tile(n_heavy, (len(STEPS), 1)))
    np.testing.assert_allclose(m.c[0], n_heavy / n)  # equal sizes: volume share = count share
    np.testing.assert_allclose(m.t, np.array(STEPS) * 2e-4 * LJ["time_s"])
    np.testing.assert_allclose(m.z, (np.arange(4) + 0.5) * H / 4 * 0.006)
    assert m.rho_h == pytest.approx(3 * 946) and m.rho_l == pytest.approx(946)
    assert m.c0 == pytest.approx(14 / 32)
    grain_mass = 946 * math.pi / 6 * 0.006**3 * (18 + 3 * 14)
    assert m.M_g == pytest.approx(grain_mass)
    force_unit = 946 * 0.006**4 / LJ["time_s"] ** 2
    assert m.M_w == pytest.approx(300 * force_unit / 9.81, rel=1e-9)
    cell = m.cell
    assert cell["H"] == pytest.approx(H * 0.006) and cell["D_p"] == pytest.approx(0.006)
    assert cell["g"] == pytest.approx(9.81)
    area = LX * LY * 0.006**2
    assert math.pi * (cell["D_out"] ** 2 - cell["D_in"] ** 2) / 4 == pytest.approx(area)
    plate = 2.0 * 0.006 / LJ["time_s"]
    assert cell["rpm"] * 2 * math.pi / 60 * cell["D_out"] / 2 == pytest.approx(plate)
    assert cell["phi_s"] == pytest.approx(32 * math.pi / 6 / (LX * LY * H))
    assert any("type(s) [3]" in note for note in run.notes)


def test_wall_view_counts_only_grains_at_the_side_walls(tmp_path):
    run = load_run(_run_dir(tmp_path))
    _, _, _, n, n_heavy, _ = _expected("wall")
    m = run.to_map("wall")
    assert m.view == "wall" and np.array_equal(m.n[0], n) and np.array_equal(m.n_heavy[0], n_heavy)
    assert m.c0 == pytest.approx(run.to_map("bulk").c0)  # the bed's c0, whatever the window sees


def test_velocity_profile_is_the_exact_layer_mean_and_fits_the_band(tmp_path):
    run = load_run(_run_dir(tmp_path))
    bed, g, layer, n, _, H = _expected()
    prof = run.velocity_profile(t_from=0.0)
    speed_unit = 0.006 / LJ["time_s"]
    want = [np.mean([_speeds(bed, s)[g & (layer == j)].mean() for s in STEPS]) * speed_unit for j in range(4)]
    np.testing.assert_allclose(prof.v, want, rtol=1e-9)
    assert np.all(np.isfinite(prof.v_err)) and np.all(prof.v_err > 0)
    assert np.array_equal(prof.n, n * len(STEPS))
    # a later window holds fewer snapshots; its mean is that of those snapshots
    late = run.velocity_profile()
    assert "3 snapshots" in late.notes[-1]
    # the grains move as 2 exp(-h / 1.2): delta = 1.2 diameters
    assert prof.delta_over_H * prof.H == pytest.approx(1.2 * 0.006, rel=0.15)
    d = prof.to_dict()
    assert {"delta_over_H", "delta_over_H_stderr", "v0", "v1", "profile"} <= set(d)


def test_si_units_other_columns_gz_split_files_and_tilted_box_agree_with_lj(tmp_path):
    lj_map = load_run(_run_dir(tmp_path)).to_map("bulk")
    d = tmp_path / "si"
    d.mkdir()
    L, T = LJ["length_m"], LJ["time_s"]
    order = ("type", "z", "xs", "id", "vx", "y", "diameter")
    # every length in metres, speeds in m/s, two files (one gzip), the first repeating a step
    _write_dump(d / "a.dump", _bed(), STEPS[:4], scale=L, vscale=L / T, order=order, radius=0.5)
    _write_dump(d / "b.dump.gz", _bed(), STEPS[3:], scale=L, vscale=L / T, order=order, radius=0.5)
    si = _config(units="si", scale=L, timestep=2e-4 * T,
                 types={"1": {"name": "light", "density": 946.0}, "2": {"name": "heavy", "density": 2838.0}}, lid_force=300 * 946 * L**4 / T**2,
                 plate_speed=2.0 * L / T, gravity=9.81)
    m = load_run(d, config=si).to_map("bulk")
    for key in ("c", "t", "z", "M_g", "M_w", "c0", "rho_h"):
        np.testing.assert_allclose(getattr(m, key), getattr(lj_map, key), rtol=1e-6, err_msg=key)
    assert np.array_equal(m.n, lj_map.n)
    # a tilted box: the flow length comes out of the bounds as LAMMPS defines them
    t = tmp_path / "tilted"
    t.mkdir()
    _write_dump(t / "grains.dump", _bed(), tilted=True)
    run = load_run(t, config=_config())
    assert run.area == pytest.approx(LX * LY * 0.006**2)


def test_map_with_its_cell_and_view_round_trips_through_the_file(tmp_path):
    run = load_run(_run_dir(tmp_path))
    written = run.save(tmp_path / "out", views=("bulk", "wall"))
    assert [p.relative_to(tmp_path / "out").as_posix() for p in written] == [
        "bulk/run.npz", "wall/run.npz", "velocity/run.json"]
    back = load_map(written[1])
    assert back.view == "wall" and back.cell == pytest.approx(run.cell())
    assert "cell" not in back.extra and "H" not in back.extra
    with pytest.raises(OutputExistsError):
        run.save(tmp_path / "out", views=("bulk",))
    assert json.loads(written[2].read_text())["conditions"]["view"] == "bulk"


def test_equal_densities_make_the_top_material_heavy(tmp_path):
    cfg = _config(types={"1": {"name": "blue", "density": 1.0}, "2": {"name": "red", "density": 1.0}})
    m = load_run(_run_dir(tmp_path, config=cfg)).to_map()
    assert m.heavy == "red" and m.rho_h == m.rho_l  # type 2 fills the upper layers of the test bed


def test_named_materials_take_model_densities():
    cfg = load_config(_config(units="si", types={"1": "pp", "2": "Steel"}))
    assert cfg.types[2].name == "steel" and cfg.types[2].density == 7800.0


# ------------------------------------------------------------------------- bad input


def test_a_snapshot_cut_short_is_named(tmp_path):
    d = _run_dir(tmp_path, cut=True)
    with pytest.raises(DemFormatError, match=r"grains.dump.*step 5000.*cut short"):
        read_dumps(d)


def test_a_configured_type_missing_from_the_dumps_is_named(tmp_path):
    cfg = _config(types={"1": {"name": "light", "density": 1.0}, "7": {"name": "heavy", "density": 3.0}})
    with pytest.raises(DemFormatError, match=r"'types': type\(s\) \[7\].*absent"):
        load_run(_run_dir(tmp_path, config=cfg))


def test_a_run_without_heavy_grains_cannot_make_a_map(tmp_path):
    d = tmp_path / "pure"
    d.mkdir()
    bed = _bed()
    bed["type"] = np.where(bed["type"] == 2, 1, bed["type"])
    _write_dump(d / "grains.dump", bed)
    (d / "dem.json").write_text(json.dumps(_config()))
    with pytest.raises(DemFormatError, match=r"type\(s\) \[2\].*absent"):
        load_run(d)
    one = _config(types={"1": "PP"})
    run = load_run(d, config=one)
    with pytest.raises(DemFormatError, match="needs exactly two materials"):
        run.to_map()
    assert np.isfinite(run.velocity_profile().delta_over_H)  # a pure bed still has a shear band
    with pytest.raises(DemFormatError, match="needs exactly two materials"):
        run.save(tmp_path / "out")
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


@pytest.mark.parametrize(("change", "message"), [
    ({"units": None}, r"'units': missing"),
    ({"units": {"length_m": 0.006}}, r"'units': missing \['time_s', 'density_kg_m3'\]"),
    ({"units": {"length_m": 0.006, "time_s": -1, "density_kg_m3": 1}}, r"'units.time_s': must be > 0"),
    ({"flow_axis": "w"}, r"'flow_axis'"),
    ({"up_axis": "x"}, r"'up_axis': the same axis"),
    ({"side_walls": {"z": [0, 1]}}, r"'side_walls'"),
    ({"types": {"1": "unobtainium"}}, r"'types.1': unknown material"),
    ({"types": {"1": {"name": "a", "density": "heavy"}}}, r"'types.1.density'"),
    ({"timestep": 0}, r"'timestep': must be > 0"),
])
def test_bad_configs_are_named(change, message):
    cfg = _config()
    for k, v in change.items():
        if v is None:
            cfg.pop(k)
        else:
            cfg[k] = v
    with pytest.raises(DemFormatError, match=message):
        load_config(cfg)


def test_missing_columns_and_files_are_named(tmp_path):
    d = _run_dir(tmp_path, order=("id", "type", "x", "y", "vx"))
    with pytest.raises(DemFormatError, match="no position column for z"):
        read_dumps(d)
    e = _run_dir(tmp_path, name="novel", order=("id", "type", "x", "y", "z"))
    with pytest.raises(DemFormatError, match="no vx column"):
        load_run(e).velocity_profile()
    with pytest.raises(FileNotFoundError, match="no LAMMPS dump file"):
        read_dumps(tmp_path)  # holds run directories, no dump file
    with pytest.raises(FileNotFoundError, match="DEM config not found"):
        load_run(e / "grains.dump", config=tmp_path / "nope.json")


def test_cli_writes_both_views_and_the_profile_and_keeps_existing_files(tmp_path, capsys):
    from granseg.cli import main

    a = _run_dir(tmp_path, name="a")
    b = _run_dir(tmp_path, name="b")
    out = tmp_path / "campaign"
    assert main(["dem", str(a), str(b), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "[2/2] b: 6 snapshots" in text and "shear band (bulk): delta/H = " in text
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*.*")) == [
        "bulk/a.npz", "bulk/b.npz", "velocity/a.json", "velocity/b.json", "wall/a.npz", "wall/b.npz"]
    before = (out / "bulk" / "a.npz").read_bytes()
    assert main(["dem", str(a), "--out", str(out), "--view", "bulk"]) != 0
    assert "already holds" in capsys.readouterr().err
    assert (out / "bulk" / "a.npz").read_bytes() == before
    assert len(load_campaign(out / "wall").maps) == 2  # each view's folder is a campaign
    # a bad run among good ones: nothing is written
    bad = _run_dir(tmp_path, name="bad", config=_config(types={"1": "PP"}))
    fresh = tmp_path / "fresh"
    assert main(["dem", str(a), str(bad), "--out", str(fresh)]) != 0
    assert "needs exactly two materials" in capsys.readouterr().err
    assert not fresh.exists()


def test_cli_finds_a_clash_before_reducing_the_runs(tmp_path, capsys, monkeypatch):
    """Issue 14: the products' names are known once the runs are read, so a clash is refused
    before the (long) reduction of their snapshots."""
    from granseg.cli import main
    from granseg.dem.run import DemRun

    a = _run_dir(tmp_path, name="a")
    out = tmp_path / "campaign"
    (out / "velocity").mkdir(parents=True)
    (out / "velocity" / "a.json").write_text("mine")

    def refuse(*args, **kwargs):
        raise AssertionError("the runs were reduced before the outputs were checked")

    monkeypatch.setattr(DemRun, "products", refuse)
    assert main(["dem", str(a), "--out", str(out)]) == 2
    assert "a.json" in capsys.readouterr().err
    (tmp_path / "a_file").write_text("x")
    assert main(["dem", str(a), "--out", str(tmp_path / "a_file" / "c")]) == 2
    assert "a_file is a file" in capsys.readouterr().err
    assert (out / "velocity" / "a.json").read_text() == "mine"


def test_the_depth_mean_check_flags_a_wall_view_that_favours_heavy_grains(tmp_path):
    """Heavy grains gather at the side walls over the run while the bed keeps its grains: the bulk
    keeps its depth-mean heavy share exactly, the wall view drifts, and its quality record says so."""
    d = tmp_path / "drift"
    d.mkdir()
    bed = _bed()
    text = []
    for k, step in enumerate(STEPS):
        b = {key: v.copy() for key, v in bed.items()}
        if k >= 2:  # every heavy grain to a wall, every light wall grain inside
            grain = b["type"] != 3
            b["y"] = np.where(grain & (b["type"] == 2), 0.5, np.where(grain, 2.0, b["y"]))
        p = tmp_path / f"s{k}.dump"
        _write_dump(p, b, (step,))
        text.append(p.read_text())
    (d / "grains.dump").write_text("".join(text))
    (d / "dem.json").write_text(json.dumps(_config()))
    run = load_run(d)
    bulk, wall = run.to_map("bulk"), run.to_map("wall")
    assert not bulk.failed_checks
    assert wall.failed_checks == ["heavy_share_conserved"]
    assert json.loads(wall.quality)["checks"]["heavy_share_conserved"]["value"] > 0.4
