"""The physically based test footage (tests/fixtures/pbr) is complete and its truth consistent.

The fixtures are rendered once by ``python -m granseg.synth.pbr fixtures
tests/fixtures/pbr`` (Mitsuba 3, see granseg.synth.pbr) and committed; these
tests only read them. How well the detector does on them is tested elsewhere.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from granseg.measure import load_experiment
from granseg.synth.pbr import FIXTURE_LOOKS, PBR_MATERIALS, fixture_map, load_fixture

ROOT = Path(__file__).parent / "fixtures" / "pbr"
LOOKS = sorted(FIXTURE_LOOKS)


def test_every_look_is_rendered_and_the_folder_stays_small():
    assert sorted(p.name for p in ROOT.iterdir() if p.is_dir()) == LOOKS
    size = sum(p.stat().st_size for p in ROOT.rglob("*") if p.is_file())
    assert size < 0.65e6 * len(LOOKS)  # four JPEG frames and the truth: the 4.5 MB the first seven had


@pytest.mark.parametrize("look", LOOKS)
def test_look_is_complete(look):
    r = load_fixture(ROOT / look)
    exp = load_experiment(ROOT / look / "experiment.json")
    n_t, n_layers = r.n.shape
    assert n_t >= 4 and n_layers == 15
    assert len(r.images) == len(r.particles) == len(r.height) == n_t
    assert r.c.shape == r.n.shape and r.n_heavy.shape == r.n.shape and r.n_phys.shape == r.n.shape
    np.testing.assert_allclose(r.c, fixture_map(n_t, FIXTURE_LOOKS[look]["c0"]))
    assert exp.c0 == FIXTURE_LOOKS[look]["c0"] and exp.rho_h >= exp.rho_l
    for img in r.images:
        assert img.shape == (720, 640, 3) and img.dtype == np.uint8
        # an exposed photograph: neither black nor blown out
        assert 25 < img.mean() < 200 and img.std() > 20
        assert np.mean(img.max(axis=2) == 255) < 0.15 and np.mean(img.max(axis=2) < 8) < 0.25
    assert r.bumps.ndim == 2 and r.bumps.shape[1] == 4 and len(r.bumps) > 0


@pytest.mark.parametrize("look", LOOKS)
def test_truth_counts_are_those_of_the_listed_spheres(look):
    r = load_fixture(ROOT / look)
    x0, y0, x1, y1 = r.experiment["window"]
    n_layers = r.n.shape[1]
    for i, p in enumerate(r.particles):
        assert p.shape[1] == 5 and np.all(np.isfinite(p))
        x, y = p[:, 0], p[:, 1]
        inside = (x >= x0) & (x < x1) & (y >= y0) & (y < y1)
        np.testing.assert_array_equal(p[:, 4] > 0, inside)
        assert set(np.unique(p[:, 3])) <= {0.0, 1.0}
        layer = np.clip(np.floor((y1 - y[inside]) / (y1 - y0) * n_layers).astype(int), 0, n_layers - 1)
        np.testing.assert_array_equal(np.bincount(layer, minlength=n_layers), r.n[i])
        heavy = p[inside, 3] > 0
        np.testing.assert_array_equal(np.bincount(layer[heavy], minlength=n_layers), r.n_heavy[i])
        # every listed sphere is within one diameter of the window
        d = r.experiment["particle_diameter_px"]
        assert np.all((x >= x0 - d) & (x < x1 + d) & (y >= y0 - d) & (y < y1 + d))
    with np.errstate(invalid="ignore", divide="ignore"):
        np.testing.assert_allclose(r.c_raw, r.n_heavy / r.n)
    assert r.n.min() >= 3  # every layer holds spheres (the bottom and top ones share the wall with bumps)


@pytest.mark.parametrize("look", LOOKS)
def test_layers_are_heights_above_the_plate(look):
    """Layer j of the window holds spheres whose centre is [j, j + 1) D above the plate, up to perspective."""
    r = load_fixture(ROOT / look)
    x0, y0, x1, y1 = r.experiment["window"]
    d = r.experiment["particle_diameter_px"]
    n_layers = r.n.shape[1]
    # one layer per diameter (the curved wall widens spheres by ~1.5 % across, narrows them along)
    assert abs((y1 - y0) / n_layers / d - 1) < 0.02
    assert abs((x1 - x0) / d - 9) < 0.5
    for p, h in zip(r.particles, r.height, strict=True):
        inside = p[:, 4] > 0
        apparent = (y1 - p[inside, 1]) / (y1 - y0) * n_layers
        # exact in the centre column; towards the window's corners spheres look up to ~0.2 D closer to mid-height
        assert np.max(np.abs(apparent - h[inside])) < 0.25
    # The bed draws every sphere's diameter with the wider of the two materials' spreads (a
    # place keeps its size when the map changes its kind); the wall changes apparent sizes
    # by about 1 % more. The mean is the nominal diameter, the spread that of the material,
    # and no sphere lies further out than four of them (ceramic's 3.5 %: one sphere of
    # ceramic-glass is 10 % off; steel's 0.4 % with POM: 3.9 % at most).
    spread = max(PBR_MATERIALS[FIXTURE_LOOKS[look][k]]["size_spread"] for k in ("heavy", "light"))
    ratio = np.concatenate([p[:, 2] for p in r.particles]) / d
    assert abs(ratio.mean() - 1) < 0.01 and ratio.std() < 1.2 * spread + 0.01, (ratio.mean(), ratio.std())
    assert np.max(np.abs(ratio - 1)) < 4 * spread + 0.02
    assert abs(r.n.sum() - r.n_phys.sum()) <= 0.05 * r.n.sum()
    # the heavy share follows the map: stratified first, mixed later (whole spheres, window edges)
    c = r.c
    assert np.array_equal(r.c_raw[0] > 0.5, c[0] > 0.5)
    assert np.nanmean(np.abs(r.c_raw - c)) < 0.08


def test_truth_was_checked_against_rendered_masks():
    """Apparent centres agree with the masks Mitsuba renders through a dielectric wall (verification.json)."""
    report = json.loads((ROOT / "verification.json").read_text())
    assert sorted(report) == LOOKS
    for entry in report.values():
        assert entry["spheres"] > 100
        assert entry["truth_vs_shell_mask_px"]["p95"] < 0.2
        assert entry["truth_vs_shell_mask_px"]["max"] < 0.3
        assert entry["wall_camera_mask_vs_shell_mask_px"]["p95"] < 0.2


def test_loading_needs_no_mitsuba():
    code = ("import sys; from granseg.synth.pbr import load_fixture; "
            f"r = load_fixture({str(ROOT / LOOKS[0])!r}); "
            "assert 'mitsuba' not in sys.modules and 'drjit' not in sys.modules; print(r.n.sum())")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr


def test_scalar_fallback_is_said_aloud():
    pytest.importorskip("mitsuba")
    # A fresh process, so Dr.Jit has not yet been pointed at a libLLVM.
    code = ("import granseg.synth.pbr as p; p._find_llvm = lambda: None; "
            "mi = p._mitsuba(None); p._mitsuba(None); print(mi.variant())")
    env = {k: v for k, v in os.environ.items() if k not in ("DRJIT_LIBLLVM_PATH", "GRANSEG_MITSUBA_VARIANT")}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "scalar_rgb"
    assert out.stderr.count("no libLLVM >= 17 found") == 1 and "scalar" in out.stderr  # once, not per call


@pytest.mark.slow
def test_tiny_render_round_trips(tmp_path):
    pytest.importorskip("mitsuba")
    from granseg.synth.pbr import render_pbr_frames

    c = fixture_map(2, 0.5)
    r = render_pbr_frames(c, heavy="ceramic", light="pp", particle_diameter_px=10, image_size=(160, 200),
                          spp=4, seed=3, out_dir=tmp_path)
    assert len(r.images) == 2 and r.images[0].shape == (200, 160, 3)
    assert r.n.shape == (2, 15) and r.n.min() >= 2
    assert np.array_equal(r.c_raw[0] > 0.5, c[0] > 0.5)
    back = load_fixture(tmp_path)
    np.testing.assert_array_equal(back.n, r.n)
    for a, b in zip(back.images, r.images, strict=True):
        np.testing.assert_array_equal(a, b)
    for a, b in zip(back.particles, r.particles, strict=True):
        np.testing.assert_allclose(a, b, atol=1e-3)  # stored as float32
    load_experiment(tmp_path / "experiment.json")
