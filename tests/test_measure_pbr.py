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
from dataclasses import replace
from functools import cache
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial import cKDTree

from granseg.cli import main
from granseg.errors import QualityWarning
from granseg.maps import load_map
from granseg.measure import analyze, detect
from granseg.measure.experiment import load_experiment
from granseg.measure.pipeline import _FrameWorker
from granseg.measure.quality import Quality
from granseg.synth.pbr import load_fixture

PBR = Path(__file__).parent / "fixtures" / "pbr"
LOOKS = sorted(p.name for p in PBR.iterdir() if (p / "truth.npz").is_file())

# Looks whose map misses a target today, and why (BENCHMARKS.md, "Footage it
# was not tuned on" and "A sphere's look across the view"). All but pom-pp are
# flagged by their quality checks; the mirror steel maps now meet both targets
# and stay flagged (their outline fit does not settle).
MISSED = {
    "glass-pom": "transparent glass: centres do not settle on its outline (flagged); counts 2.6 %, RMSD 0.036 "
                 "since it is centred where its look is symmetric, its POM placed across the view by a "
                 "circle of its size and each glass sphere's y where its own look is symmetric",
    "glass-pp": "transparent glass: centres do not settle on its outline (flagged)",
    # mirror steel is learned from the matte spheres' matches and placed by its
    # template (detect._borrowed): both maps meet both targets since the look
    # across the view; the outline fit still does not settle on its rim
    "steel-pp": "mirror-like steel over blue PP: placed by its template, counts 0.5 % (flagged: centres_settled, "
                "window_lines)",
    "steel-pom": "mirror-like steel over POM: placed by its template, counts 2.3 % (flagged: centres_settled, "
                 "window_lines)",
    # not flagged: the side lamps shade off-axis spheres unevenly and the
    # outline fit follows the lit limb, so centres are found outward (x 1.0-1.6
    # px near the sides, y 0.4-0.7 px near top and bottom); spheres on a layer
    # boundary or a side are counted a layer outward or outside the window
    # (benches/bench_pbr_centre_bias.py; the truth and camera model are exact).
    # Even without that bias it would miss: most of its count error is three
    # still spheres whose true centre lies within 0.1 px of a layer boundary
    # in all four frames (a perfect x correction: 4.1 -> 3.8 %). 4.6 % since the
    # outline bias per kind of sphere (detect._ray_bias), which cannot take off
    # a bias that turns across the frame; 4.2 % with the classes' relative
    # shift taken off (outline.class_shift); 5.3 % with each group's look
    # learned across the view (templates.with_columns); 5.2 % with x from a
    # circle of the nominal size (detect._nominal_where_side_lit: the x bias
    # goes, 1.2 -> 0.2 px near the sides; the y bias stays)
    "pom-pp": "centres biased outward near the top and bottom by the side lamps' shading (not flagged)",
    # the four pairs of the paper's five materials it did not mix, rendered
    # after every choice above was made (seeds 18-21): glass and mirror steel
    # as on the other fixtures; ceramic over POM missed the counts a little
    # (3.4 %, not flagged) until the look across the view (1.6 %; 1.0 % since
    # its spheres are placed across the view by a circle of their size)
    "steel-glass": "mirror steel over transparent glass: neither settles on its outline, classes ambiguous "
                   "(flagged)",
    "steel-ceramic": "mirror steel over ceramic: counts 1.4 % (flagged: centres_settled)",
    "ceramic-glass": "transparent glass: centres do not settle on its outline (flagged)",
    # one panel straight behind the camera instead of the two side panels: the
    # wall mirrors it in a bright band down the middle of the window, and the
    # spheres under the band are missed
    "pom-pp-front": "spheres under the lamp's reflection are missed: counts 6.8 % (flagged: vacancies, "
                    "ambiguous_spheres)",
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


@pytest.mark.parametrize("look", ["steel-pp", "steel-pom"])
def test_mirror_steel_is_learned_from_the_matte_spheres(look):
    """Mirror steel seeds off its spheres; the matte material's template finds it, and the steel
    template learned from those matches places the first frame's steel within a tenth of a diameter
    (before: none of steel-pp's, a third of a diameter too high)."""
    truth = load_fixture(PBR / look)
    exp = load_experiment(PBR / look / "experiment.json")
    image = cv2.imread(str(PBR / look / "frame_0000.jpg"))
    worker = _FrameWorker(exp, (image.shape[1], image.shape[0]))
    worker.learn(image)
    assert worker.templates.by_match is not None and worker.templates.by_match.tolist() == [True, False]
    first = worker("frame_0000.jpg", image)[0]
    steel = truth.particles[0][(truth.particles[0][:, 4] > 0) & (truth.particles[0][:, 3] > 0)]
    dist, _ = cKDTree(np.column_stack([first.x, first.y])).query(steel[:, :2])
    d = exp.particle_diameter_px
    assert np.mean(dist < 0.1 * d) >= 0.9, np.mean(dist < 0.1 * d)


@pytest.mark.parametrize("tie", [detect.POLARITY_TIE, 0.0])
def test_a_tied_polarity_is_searched_both_ways(monkeypatch, tie):
    """Transparent glass's two polarities nearly tie. Tipped the wrong way (as on a packing at seed
    offset 300), glass beside bright ceramic was searched bright with the ceramic, and its first
    frame's glass was found within 0.3 d 9 times of 67. A band whose contrasts tie is searched in
    both polarities, and the set of each material's own finds the glass; without the tie (``tie``
    0), it does not."""
    monkeypatch.setattr(detect, "_contrasts", _glass_tipped_bright(detect._contrasts, band=1))
    monkeypatch.setattr(detect, "POLARITY_TIE", tie)
    signs, recall = _first_glass(PBR / "ceramic-glass", heavy=False)
    if tie > 0:
        assert signs == [1, -1]
        assert recall >= 0.9, recall  # as untipped: 0.925
    else:
        assert signs == [1, 1]
        assert recall < 0.5, recall


@pytest.mark.parametrize("rim_clear", [detect.RIM_CLEAR, np.inf])
def test_sharper_rims_decide_where_the_balance_does_not(monkeypatch, rim_clear):
    """Glass above PP, its tie tipped to bright: glass searched dark as well (a guess) balances the
    bands' spheres per row better than one polarity by only 0.022 (1.042 against 1.065), short of
    TIE_BALANCE, so balance and packing keep glass bright with PP (``rim_clear`` inf). Its rims in
    the glass band are sharper by 0.40 (log units), which decides for glass dark: the first frame's
    glass found within 0.3 d 61 times of 62, against 56 with glass bright."""
    monkeypatch.setattr(detect, "_contrasts", _glass_tipped_bright(detect._contrasts, band=0))
    monkeypatch.setattr(detect, "RIM_CLEAR", rim_clear)
    signs, recall = _first_glass(PBR / "glass-pp", heavy=True)
    if np.isfinite(rim_clear):
        assert signs == [-1, 1]
        assert recall >= 0.95, recall  # as untipped: 0.98
    else:
        assert signs == [1, 1]


def _glass_tipped_bright(contrasts, band: int):
    """detect._contrasts with band ``band``'s two polarities (glass's, 0.07-0.10 of their contrasts'
    sum apart) swapped and set 0.6 grey levels apart, as glass's tipped to bright at seed offset 300.
    The frame's own call comes first, then one per band."""
    calls = []

    def tipped(image, candidates, d):
        ranked = contrasts(image, candidates, d)
        calls.append(len(ranked))
        if len(calls) == band + 2 and len(ranked) == 2:
            mean = 0.5 * (ranked[0][0] + ranked[1][0])
            (_, sign, seeds), (_, other, others) = ranked
            ranked = [(mean + 0.3, other, others), (mean - 0.3, sign, seeds)]
        return ranked
    return tipped


def _first_glass(look: Path, heavy: bool) -> tuple[list[int], float]:
    """The signs of the templates a run of ``look`` learns, and the share of its first frame's glass
    spheres (the ``heavy`` class or the light) found within 0.3 d."""
    truth = load_fixture(look)
    exp = load_experiment(look / "experiment.json")
    image = cv2.imread(str(look / "frame_0000.jpg"))
    worker = _FrameWorker(exp, (image.shape[1], image.shape[0]))
    worker.learn(image)
    first = worker("frame_0000.jpg", image)[0]
    rows = truth.particles[0]
    glass = rows[(rows[:, 4] > 0) & (rows[:, 3] == int(heavy))]
    dist, _ = cKDTree(np.column_stack([first.x, first.y])).query(glass[:, :2])
    return worker.templates.signs.tolist(), float(np.mean(dist < 0.3 * exp.particle_diameter_px))


@pytest.mark.parametrize("look", ["glass-pp", "glass-pom"])
def test_glass_is_centred_where_its_look_is_symmetric(look):
    """Transparent glass gives the outline fit no rim to hold to, and its template kept the first
    seeds' offset: the first frame's glass spheres were found 2.2-2.9 px high on average. Centred
    where its mean look is symmetric, they are found within half a pixel of the truth on average."""
    truth = load_fixture(PBR / look)
    exp = load_experiment(PBR / look / "experiment.json")
    image = cv2.imread(str(PBR / look / "frame_0000.jpg"))
    worker = _FrameWorker(exp, (image.shape[1], image.shape[0]))
    worker.learn(image)
    first = worker("frame_0000.jpg", image)[0]
    found = np.column_stack([first.x, first.y])
    rows = truth.particles[0]
    dist, j = cKDTree(rows[:, :2]).query(found)
    glass = (dist < 0.3 * exp.particle_diameter_px) & (rows[j, 3] > 0)  # glass is the heavy class in both
    assert glass.sum() >= 50, glass.sum()
    error = (found[glass] - rows[j[glass], :2]).mean(axis=0)
    assert np.all(np.abs(error) < 0.5), error


@pytest.mark.parametrize("look", ["glass-pp", "glass-pom"])
def test_each_glass_sphere_is_placed_up_and_down_where_its_own_look_is_symmetric(look):
    """The outline fit leaves glass where its template's match starts it. Moved up or down to where
    its own look is most symmetric (detect._y_by_own_symmetry), the glass spheres' median height
    error is at most three quarters of what it is without (tuning packings: about half)."""
    truth = load_fixture(PBR / look)
    exp = load_experiment(PBR / look / "experiment.json")
    worker = _FrameWorker(exp, truth.images[0].shape[1::-1])
    worker.learn(truth.images[0])
    marked = worker.templates.symmetric_y
    # glass is dark inside (sign -1), the matte spheres bright
    assert marked is not None and marked.any() and np.all(worker.templates.signs[marked] < 0)

    def height_error() -> float:
        errors = []
        for i, (image, rows) in enumerate(zip(truth.images, truth.particles, strict=True)):
            found = worker(str(i), image)[0]
            dist, j = cKDTree(rows[:, :2]).query(np.column_stack([found.x, found.y]))
            mine = (dist < 0.3 * exp.particle_diameter_px) & (rows[j, 3] > 0)  # glass is the heavy class in both
            errors.append(np.abs(found.y[mine] - rows[j[mine], 1]))
        return float(np.median(np.concatenate(errors)))

    own = height_error()
    worker.templates = replace(worker.templates, symmetric_y=None)
    free = height_error()
    assert own <= 0.75 * free, (own, free)


@pytest.mark.parametrize("look", ["pom-pp", "ceramic-pp", "ceramic-pom", "grey-glossy-matte"])
def test_side_lit_matte_spheres_are_not_found_outward_at_the_window_sides(look):
    """Lamps beside the camera light the matte spheres near the window's sides from the side, and a
    circle free in size hugs the lit limb: those within 40 px of a side were found 0.8-1.6 px
    outward on average (benches/bench_pbr_centre_bias.py). Placed across the view by a circle of
    the nominal size, they are within 0.7 px, and less than half as far out as the free circle."""
    truth = load_fixture(PBR / look)
    exp = load_experiment(PBR / look / "experiment.json")
    worker = _FrameWorker(exp, truth.images[0].shape[1::-1])
    worker.learn(truth.images[0])
    assert worker.templates.nominal_x is not None
    x0, _, x1, _ = exp.window

    def outward() -> float:
        errors = []
        for i, (image, rows) in enumerate(zip(truth.images, truth.particles, strict=True)):
            found = worker(str(i), image)[0]
            dist, j = cKDTree(rows[:, :2]).query(np.column_stack([found.x, found.y]))
            near = (dist < 0.3 * exp.particle_diameter_px) & ((rows[j, 0] < x0 + 40) | (rows[j, 0] > x1 - 40))
            errors.append((found.x[near] - rows[j[near], 0]) * np.sign(rows[j[near], 0] - (x0 + x1) / 2))
        return float(np.concatenate(errors).mean())

    nominal = outward()
    worker.templates = replace(worker.templates, nominal_x=None)
    free = outward()
    assert nominal < 0.7 and nominal < 0.5 * free, (nominal, free)


def test_spheres_placed_by_their_template_are_reported(tmp_path, capsys):
    """The map records the share of spheres placed by their template's best match, analyze says so,
    and the map stays flagged: their outline fit does not settle."""
    main(["analyze", str(PBR / "steel-pp"), "--out", str(tmp_path / "map.npz"), "--no-progress", "--smooth", "1"])
    assert "placed where their template matches best" in capsys.readouterr().out
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", QualityWarning)  # the flag is what is asked for
        quality = Quality.from_json(str(load_map(tmp_path / "map.npz").quality))
    assert 0.3 < quality.figures["placed_by_template_match"] < 0.7, quality.figures  # steel: c0 = 0.5
    assert "centres_settled" in [c.name for c in quality.failed]
    assert _measured("ceramic-pp")[0].quality.figures["placed_by_template_match"] == 0.0


def test_spheres_placed_across_the_view_by_the_nominal_circle_are_reported():
    """The map records the share of spheres whose x came from a circle of the nominal size: every
    sphere of matte ceramic over PP under the side panels, none under one lamp behind the camera."""
    assert _measured("ceramic-pp")[0].quality.figures["x_by_nominal_circle"] > 0.95
    assert _measured("pom-pp-front")[0].quality.figures["x_by_nominal_circle"] == 0.0


def test_spheres_missed_under_a_lamp_behind_the_camera_are_flagged():
    """Under a lamp straight behind the camera, the spheres under its reflection on the wall are
    missed, and the packed bed shows the holes they leave (quality check vacancies, its limit set on
    the 2-D tuning seeds, the tuning packings and two-frame lighting controls); the same pair under the
    side panels, whose spheres are found, passes it."""
    a, _, count = _measured("pom-pp-front")
    assert "vacancies" in [c.name for c in a.quality.failed] and count > 0.03, a.quality.report()
    for look in ("pom-pp", "ceramic-pp", "ceramic-pom"):
        assert "vacancies" not in [c.name for c in _measured(look)[0].quality.failed], look


def test_every_look_is_here():
    """Every pair of the paper's five materials, and a pair that differs in gloss only."""
    materials = ("steel", "ceramic", "glass", "pom", "pp")
    pairs = {tuple(sorted(look.split("-"))) for look in LOOKS}
    assert all(tuple(sorted((a, b))) in pairs for i, a in enumerate(materials) for b in materials[i + 1:]), LOOKS
    assert "grey-glossy-matte" in LOOKS


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
