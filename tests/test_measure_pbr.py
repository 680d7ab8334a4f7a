"""The frame pipeline on footage from a second, physically based renderer it was not tuned on.

The fixtures (tests/fixtures/pbr, rendered once by ``python -m granseg.synth.pbr
fixtures``) are path-traced: real sphere materials behind the curved PMMA wall,
LED panels mirrored in it, bumpy lid and plate, lens distortion, JPEG. Nothing
in the detector or the classifier was tuned on them. Two promises are tested
apart: a map that passes its own quality checks meets the targets of issue 9
(c_raw RMSD <= 0.03, per-frame layer counts within 3 %); and which looks meet
those targets today, so that a change that fixes or breaks one shows.
"""

from __future__ import annotations

import warnings
from functools import cache
from pathlib import Path

import numpy as np
import pytest

from granseg.errors import QualityWarning
from granseg.measure import analyze
from granseg.synth.pbr import load_fixture

PBR = Path(__file__).parent / "fixtures" / "pbr"
LOOKS = sorted(p.name for p in PBR.iterdir() if (p / "truth.npz").is_file())

# Looks whose map misses a target today, and why (BENCHMARKS.md, "Footage it
# was not tuned on"). All but pom-pp are flagged by their quality checks.
MISSED = {
    "glass-pom": "transparent glass: centres do not settle on its outline, and some glass among POM is "
                 "taken for POM (flagged)",
    "glass-pp": "transparent glass: centres do not settle on its outline (flagged)",
    "steel-pp": "mirror-like steel over blue PP: centres do not settle on its outline (flagged)",
    "steel-pom": "mirror-like steel: with its own polarity its centres do not settle and a quarter of the "
                 "spheres are lost (flagged; one polarity made the better map here)",
    # not flagged: the side lamps shade off-axis spheres unevenly and the
    # outline fit follows the lit limb, so centres are found outward (x 1.0-1.6
    # px near the sides, y 0.4-0.7 px near top and bottom); spheres on a layer
    # boundary or a side are counted a layer outward or outside the window
    # (benches/bench_pbr_centre_bias.py; the truth and camera model are exact).
    # Even without that bias it would miss: most of its count error is three
    # still spheres whose true centre lies within 0.1 px of a layer boundary
    # in all four frames (a perfect x correction: 4.1 -> 3.8 %)
    "pom-pp": "centres biased outward by the side lamps' shading (not flagged)",
}
SILENT = ("pom-pp",)


@cache
def _measured(look: str):
    truth = load_fixture(PBR / look)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", QualityWarning)  # judged below
        a = analyze(PBR / look, smooth=1, save=False, progress=False, workers=2)
    rmsd = float(np.sqrt(np.nanmean((a.c_raw - truth.c_raw) ** 2)))
    count = float(np.mean(np.abs(a.n - truth.n)[truth.n > 0] / truth.n[truth.n > 0]))
    return a, rmsd, count


def test_every_look_is_here():
    assert len(LOOKS) >= 7, LOOKS


@pytest.mark.parametrize("look", [
    pytest.param(look, marks=pytest.mark.xfail(strict=True, reason=MISSED[look])) if look in SILENT else look
    for look in LOOKS])
def test_a_map_that_passes_its_checks_is_right(look):
    a, rmsd, count = _measured(look)
    right = rmsd <= 0.03 and count <= 0.03
    assert right or not a.quality.ok, f"unflagged map off: c_raw RMSD {rmsd:.3f}, per-frame counts {count:.3f}"


@pytest.mark.parametrize("look", [
    pytest.param(look, marks=pytest.mark.xfail(strict=True, reason=MISSED[look])) if look in MISSED else look
    for look in LOOKS])
def test_look_meets_the_targets(look):
    a, rmsd, count = _measured(look)
    assert a.quality.ok, a.quality.report()
    assert rmsd <= 0.03 and count <= 0.03, f"c_raw RMSD {rmsd:.3f}, per-frame layer counts {count:.3f}"
