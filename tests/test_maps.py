"""Map and campaign files (docs/formats.md): round trip, validation, moving average."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from granseg._io import OutputExistsError
from granseg.maps import (
    Map,
    MapFormatError,
    load_campaign,
    load_map,
    moving_average,
    save_map,
)

D_P = 6e-3


def fields(name: str = "G-PP-50", n_t: int = 12, n_layers: int = 15, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    return dict(
        c=rng.uniform(0, 1, (n_t, n_layers)),
        t=np.arange(n_t) * 2.0,
        z=(np.arange(n_layers) + 0.5) * D_P,
        name=name, heavy="glass", light="PP",
        rho_h=2450.0, rho_l=946.0, c0=0.5, M_g=2.04, M_w=1.093,
    )


def write_raw(path, **arrays) -> None:
    """Write an .npz directly (bypassing save_map's validation) to test the reader."""
    with open(path, "wb") as fh:
        np.savez(fh, **arrays)


# --------------------------------------------------------------------------- round trip


def test_round_trip_keeps_every_field_and_derives(tmp_path):
    f = fields()
    n = np.full(f["c"].shape, 20)
    nh = np.round(f["c"] * 20).astype(int)
    save_map(tmp_path / "a.npz", **f, n=n, n_heavy=nh, c_raw=f["c"], fps=0.5, smoothing_frames=5)
    m = load_map(tmp_path / "a.npz")
    np.testing.assert_array_equal(m.c, f["c"])
    np.testing.assert_array_equal(m.n_heavy, nh)
    assert (m.name, m.heavy, m.light) == ("G-PP-50", "glass", "PP")
    assert m.delta_R == pytest.approx(2450 / 946)
    assert m.M_tilde == pytest.approx(1.093 / 2.04)
    assert (m.n_layers, m.n_times, m.smoothing_frames, m.fps) == (15, 12, 5, 0.5)
    np.testing.assert_array_equal(m.bottom, f["c"][:, 0])
    assert m.measured()["smoothing_frames"] == 5


def test_defaults_and_extra_keys_kept(tmp_path):
    f = fields()
    write_raw(tmp_path / "a.npz", **f, operator=np.str_("anna"))
    m = load_map(tmp_path / "a.npz")
    assert m.smoothing_frames == 1 and m.n is None and m.fps is None
    assert str(m.extra["operator"]) == "anna"


def test_save_never_silently_overwrites(tmp_path):
    save_map(tmp_path / "a.npz", **fields())
    with pytest.raises(OutputExistsError):
        save_map(tmp_path / "a.npz", **fields(seed=1))
    save_map(tmp_path / "a.npz", **fields(seed=1), force=True)
    np.testing.assert_array_equal(load_map(tmp_path / "a.npz").c, fields(seed=1)["c"])


def test_save_refuses_unknown_field(tmp_path):
    with pytest.raises(MapFormatError, match="unknown field"):
        save_map(tmp_path / "a.npz", **fields(), smothing_frames=3)
    assert not (tmp_path / "a.npz").exists()


# --------------------------------------------------------------------------- validation


@pytest.mark.parametrize(
    "field, value, pattern",
    [
        ("c", None, "'c': missing"),
        ("rho_l", None, "'rho_l': missing"),
        ("c", np.full((12, 15), 1.2), "'c': values must lie in"),
        ("c", np.full((12, 15), np.nan), "'c': every entry is NaN"),
        ("c", np.zeros(15), "'c': expected 2"),
        ("t", np.arange(12)[::-1] * 1.0, "'t': is not strictly increasing"),
        ("t", np.arange(11) * 1.0, "'t': length 11"),
        ("z", np.arange(14) * 1.0, "'z': length 14"),
        ("rho_h", 500.0, "'rho_h' and 'rho_l': 500.0 < "),
        ("c0", 1.0, "'c0': value 1.0 outside"),
        ("M_g", -1.0, "'M_g': value -1.0 outside"),
        ("name", np.str_(" "), "'name': experiment name is empty"),
        ("name", 3.0, "'name': expected a string"),
        ("smoothing_frames", 4, "'smoothing_frames'.*odd"),
        ("n", np.ones((12, 15)), "'n': expected an integer array"),
    ],
)
def test_reader_names_file_and_field(tmp_path, field, value, pattern):
    f = fields()
    if value is None:
        del f[field]
    else:
        f[field] = value
    path = tmp_path / "bad.npz"
    write_raw(path, **f)
    with pytest.raises(MapFormatError, match=pattern) as info:
        load_map(path)
    assert str(path) in str(info.value)


def test_a_zero_lid_load_is_rejected_naming_the_field(tmp_path):
    # the core rejects M_w = 0 (no load, no overburden scale), so a map must not pass with it
    f = fields()
    f["M_w"] = 0.0
    write_raw(tmp_path / "a.npz", **f)
    with pytest.raises(MapFormatError, match="field 'M_w': value 0.0 outside") as info:
        load_map(tmp_path / "a.npz")
    assert str(tmp_path / "a.npz") in str(info.value)
    with pytest.raises(MapFormatError, match="'M_w'"):
        Map(**f)


@pytest.mark.parametrize(
    ("field", "value"),
    [("rho_h", 0.0), ("rho_l", 0.0), ("rho_l", -1.0), ("c0", 0.0), ("c0", 1.0), ("M_w", 0.0),
     ("M_w", -1.0), ("M_w", np.inf), ("rho_h", np.nan),
     ("c0", 1e-9), ("c0", 1 - 1e-9), ("M_w", 1e-9), ("rho_h", 946.0), ("rho_l", 1e-9)],
)
def test_map_validation_agrees_with_the_core(field, value):
    """The model parameters a map fixes are valid in the map exactly when the core accepts them."""
    pytest.importorskip("granseg._core", reason="the Rust extension is not built (maturin develop)")
    from granseg import model

    f = fields()
    f[field] = value
    try:
        model.derived(**{k: f[k] for k in ("rho_h", "rho_l", "c0", "M_w")})
        core_ok = True
    except ValueError:
        core_ok = False
    try:
        Map(**f)
        map_ok = True
    except MapFormatError as exc:
        map_ok = False
        assert f"'{field}'" in str(exc)
    assert map_ok == core_ok or (not map_ok and field == "rho_h" and value < f["rho_l"])


def test_map_built_in_code_is_validated():
    f = fields()
    f["c"] = f["c"] * 2
    with pytest.raises(MapFormatError, match="map 'G-PP-50': field 'c'"):
        Map(**f)
    m = Map(**fields(), smoothing_frames=np.int64(3))
    assert m.smoothing_frames == 3 and m.c.dtype == float


def test_n_heavy_not_more_than_n(tmp_path):
    f = fields()
    write_raw(tmp_path / "a.npz", **f, n=np.full((12, 15), 3), n_heavy=np.full((12, 15), 4))
    with pytest.raises(MapFormatError, match="'n_heavy'"):
        load_map(tmp_path / "a.npz")


def test_not_an_npz(tmp_path):
    (tmp_path / "a.npz").write_text("hello")
    with pytest.raises(MapFormatError, match="not a readable"):
        load_map(tmp_path / "a.npz")
    with pytest.raises(FileNotFoundError):
        load_map(tmp_path / "missing.npz")


# --------------------------------------------------------------------------- campaign


def test_campaign_sorted_by_name_not_file(tmp_path):
    save_map(tmp_path / "1.npz", **fields("S-PP-50"))
    save_map(tmp_path / "2.npz", **fields("C-PP-50"))
    save_map(tmp_path / "3.npz", **fields("G-POM-50"))
    camp = load_campaign(tmp_path)
    assert camp.names == ["C-PP-50", "G-POM-50", "S-PP-50"]
    assert camp["G-POM-50"].path.name == "3.npz" and len(camp) == 3 and camp.n_layers == 15


def test_campaign_errors(tmp_path):
    with pytest.raises(MapFormatError, match="no map files"):
        load_campaign(tmp_path)
    with pytest.raises(FileNotFoundError):
        load_campaign(tmp_path / "nope")
    save_map(tmp_path / "a.npz", **fields("A"))
    save_map(tmp_path / "b.npz", **fields("A"))
    with pytest.raises(MapFormatError, match="duplicate experiment name 'A'"):
        load_campaign(tmp_path)
    (tmp_path / "b.npz").unlink()
    save_map(tmp_path / "c.npz", **fields("C", n_layers=14))
    with pytest.raises(MapFormatError, match="mismatched layer counts.*c.npz has 14"):
        load_campaign(tmp_path)
    (tmp_path / "c.npz").unlink()
    f = fields("D")
    f["c"][:] = np.nan
    write_raw(tmp_path / "d.npz", **f)
    with pytest.raises(MapFormatError, match="d.npz: field 'c': every entry is NaN"):
        load_campaign(tmp_path)


# --------------------------------------------------------------------------- moving average


def test_moving_average_by_hand():
    x = np.array([1.0, 2.0, 4.0, 8.0, 16.0, 32.0])
    out = moving_average(x, 5)
    # windows: [1], [1 2 4], [1 2 4 8 16], [2 4 8 16 32], [8 16 32], [32]
    expected = [1.0, 7 / 3, 31 / 5, 62 / 5, 56 / 3, 32.0]
    np.testing.assert_allclose(out, expected)
    np.testing.assert_array_equal(moving_average(x, 1), x)


def test_moving_average_skips_nan_and_works_per_column():
    x = np.array([[1.0, 0.0], [np.nan, 1.0], [3.0, 2.0]])
    out = moving_average(x, 3)
    np.testing.assert_allclose(out, [[1.0, 0.0], [2.0, 1.0], [3.0, 2.0]])
    np.testing.assert_allclose(moving_average(x.T, 3, axis=1), out.T)
    assert np.isnan(moving_average([np.nan, np.nan], 3)).all()


@pytest.mark.parametrize("n", [0, 2, -3, 2.0, True])
def test_moving_average_rejects_bad_window(n):
    with pytest.raises(ValueError, match="odd integer"):
        moving_average([1.0, 2.0], n)


@settings(deadline=None, derandomize=True, max_examples=60)
@given(
    x=arrays(float, st.integers(1, 40), elements=st.floats(-1e3, 1e3, allow_nan=False)),
    half=st.integers(0, 6),
)
def test_moving_average_matches_definition(x, half):
    n = 2 * half + 1
    out = moving_average(x, n)
    for i in range(x.size):
        h = min(half, i, x.size - 1 - i)
        assert out[i] == pytest.approx(np.mean(x[i - h : i + h + 1]), abs=1e-9)
