"""Maps that say when they cannot be trusted: learned classes, quality checks, refusal downstream."""

from __future__ import annotations

import csv
import json
import re
import warnings
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from granseg.cli import main
from granseg.errors import FlaggedMapError, QualityWarning
from granseg.maps import check_accepted, load_map
from granseg.measure import analyze, pipeline, quality
from granseg.measure.classify import (
    BLUR_ZONE,
    FEATURES,
    LEARNED,
    LEARNED_AT_SPOTS,
    LIGHT_SHARE,
    RESOLUTION,
    ResolvedScaler,
    _fit_classes,
    blur_test,
    disk_rises,
    interface_labels,
    learn_classes,
    learn_spots,
    sphere_features,
    spot_weights,
)
from granseg.measure.experiment import load_experiment
from granseg.measure.exposure import DRIFT_LIMIT
from granseg.measure.init import _camera as init_camera
from granseg.measure.layers import N_LAYERS, WALL_CLEARANCE, followed_window
from granseg.measure.quality import (
    BED_RISE_SLACK,
    LENS_HINT,
    LENS_SLACK,
    LENS_SPHERES,
    LEVEL_SIGMAS,
    LEVEL_SLACK,
    SPACING_SLACK,
    VACANCY_GAP,
    VIEW_MOVE_SLACK,
    WALL_LINE_SLACK,
    Quality,
    WallLines,
    assess,
    bed_rise,
    level_reading,
    plate_tilt,
    spacing_across_view,
    sphere_spacing,
    vacancies,
    view_move,
    wall_follow,
    wall_lines,
)
from granseg.measure.sources import open_frames
from granseg.synth import render_frames
from granseg.synth.mishaps import move_view, raise_lid, turn_view
from granseg.synth.scenes import render_scene

SMALL = dict(particle_diameter_px=20, image_size=(400, 480))


def stratified_map(n_t: int, c0: float, n_layers: int = 15) -> np.ndarray:
    """Heavy above (1 - c0) H at t = 0, relaxing linearly to a graded profile of mean c0."""
    z = (np.arange(n_layers) + 0.5) / n_layers
    t = np.linspace(0, 1, n_t)[:, None]
    end = np.clip(c0 + 0.8 * c0 * (0.5 - z), 0, 1)
    return np.clip(np.where(z > 1 - c0, 1.0, 0.0) * (1 - t) + end * t, 0, 1)


def _analyze(tmp_path, c0=0.5, n_t=4, seed=7, **look):
    r = render_frames(stratified_map(n_t, c0), seed=seed, out_dir=tmp_path, **{**SMALL, **look})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", QualityWarning)
        a = analyze(tmp_path, smooth=1, save=False, progress=False, workers=2)
    return r, a


@pytest.mark.parametrize("heavy, light, c0", [
    ("steel", "pom", 0.25),  # grey on grey: brightness and gloss, hardly hue (issue 9)
    ("glass", "pom", 0.5),
    ("ceramic", "pp", 0.75),
])
def test_learned_classes_give_the_map_and_pass_every_check(tmp_path, heavy, light, c0):
    r, a = _analyze(tmp_path, c0=c0, heavy=heavy, light=light)
    assert np.sqrt(np.nanmean((a.c_raw - r.c_raw) ** 2)) <= 0.03
    assert a.quality.ok, a.quality.report()
    assert a.classes.separation.cv_accuracy >= 0.99


@pytest.mark.parametrize("look", ["pp", "pom"])
def test_identical_materials_are_flagged_not_split(tmp_path, look):
    _, a = _analyze(tmp_path, heavy=look, light=look, lighting="left")
    failed = {c.name for c in a.quality.failed}
    assert "class_separation" in failed and a.classes.separation.cv_accuracy < 0.8


def test_a_pair_that_differs_in_brightness_only_is_flagged_when_its_classes_are_unsure(tmp_path):
    """Matte greys 21 % apart in brightness, alike in finish: a few per cent of the spheres are
    ambiguous, and some of them in the wrong class, enough to put c_raw off by about the target
    (2-D tuning seed 7: 1.2 % wrong, RMSD 0.036, 3.6 % ambiguous); ambiguous_spheres flags it. The
    same grey told apart by its finish as well passes."""
    for light, flagged in (("pp-matte-grey", True), ("pp-grey", False)):
        r = render_scene("grey-matte-glossy", 6, seed=7, out_dir=tmp_path / light, heavy="pom-grey", light=light)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", QualityWarning)
            a = analyze(r.source, smooth=1, save=False, progress=False, workers=2)
        unsure = next(c for c in a.quality.checks if c.name == "ambiguous_spheres")
        assert unsure.passed != flagged, a.quality.report()


def _first_frame_checks(heavy_of, settle=None):
    """Quality of a perfect stratified first frame whose classes are then set by ``heavy_of``."""
    rng = np.random.default_rng(0)
    h = rng.uniform(0.5, 14.5, 140)  # heights [d] of the first frame's spheres
    heavy = heavy_of(h > 7.5)
    n = np.zeros((3, 15), int)
    nh = np.zeros((3, 15), int)
    layer = np.floor(h).astype(int)
    for i in range(3):
        n[i] = np.bincount(layer, minlength=15)
        nh[i] = np.bincount(layer[heavy], minlength=15)
    return assess(n=n, n_heavy=nh, c0=0.5, first_heights=h, first_heavy=heavy, scores=np.full(140, 0.9),
                  settle=settle, p_heavy=None, separation=None, n_bad_frames=0, wall_detections=0.0)


def test_centres_that_do_not_settle_are_flagged():
    """A tenth of the spheres still moving by a pixel in the outline fit's last step fails the check."""
    quiet = _first_frame_checks(lambda truth: truth, settle=np.full(140, 0.05))
    assert quiet.ok
    restless = np.where(np.arange(140) % 8 == 0, 1.0, 0.05)  # an eighth of them
    assert [c.name for c in _first_frame_checks(lambda truth: truth, settle=restless).failed] == ["centres_settled"]


def test_consistency_checks_catch_a_wrong_class_assignment():
    assert _first_frame_checks(lambda truth: truth).ok
    swapped = {c.name for c in _first_frame_checks(lambda truth: ~truth).failed}
    assert "first_frame_order" in swapped
    all_heavy = {c.name for c in _first_frame_checks(lambda truth: np.ones_like(truth)).failed}
    assert {"initial_heavy_share", "first_frame_order", "heavy_share_conserved"} <= all_heavy


def _packed(lattice: str, d: float, window) -> np.ndarray:
    """Centres (m, 2) of touching spheres of diameter d filling the window, rows of a hexagonal or a
    square lattice."""
    x0, y0, x1, y1 = window
    pitch = d * np.sqrt(3) / 2 if lattice == "hexagonal" else d
    rows = np.arange(y0 + d / 2, y1, pitch)
    out = [np.column_stack([np.arange(x0 - d, x1 + d, d) + (d / 2 if lattice == "hexagonal" and k % 2 else 0),
                            np.full(len(np.arange(x0 - d, x1 + d, d)), y)]) for k, y in enumerate(rows)]
    return np.concatenate(out)


@pytest.mark.parametrize("lattice", ["hexagonal", "square"])
def test_a_packed_bed_has_no_vacancies(lattice):
    """No room for a sphere between touching spheres, not even in a square lattice's gaps (0.41 d)."""
    d, window = 30.0, (100.0, 50.0, 400.0, 500.0)
    centres = _packed(lattice, d, window)
    holes, searched = vacancies(centres[:, 0], centres[:, 1], window, d)
    assert len(holes) == 0 and searched > 100


def test_vacancies_are_the_spheres_taken_out_of_a_packed_bed():
    """Taking spheres out of a hexagonal packing, one alone and three side by side, leaves one vacancy
    each, where they were."""
    d, window = 30.0, (100.0, 50.0, 400.0, 500.0)
    centres = _packed("hexagonal", d, window)
    order = np.argsort(np.hypot(*(centres - np.array([250.0, 275.0])).T))
    row = np.flatnonzero((np.abs(centres[:, 1] - centres[order[40], 1]) < 1) & (centres[:, 0] > 150))[:3]
    out = np.r_[order[0], row]
    kept = np.delete(centres, out, axis=0)
    holes, _ = vacancies(kept[:, 0], kept[:, 1], window, d)
    assert len(holes) == 4
    dist = np.hypot(*(holes[:, None, :] - centres[out][None]).transpose(2, 0, 1))
    assert dist.min(axis=1).max() < (1 - VACANCY_GAP) * d + 3.0  # each vacancy where a sphere was taken out


def test_spheres_missed_at_the_window_side_are_found_with_the_spheres_beside_it():
    """A sphere missed right at the window's side is a vacancy once the spheres beyond the side are
    known; without them it lies in the inset where nothing is searched."""
    d, window = 30.0, (100.0, 50.0, 400.0, 500.0)
    centres = _packed("hexagonal", d, window)
    inside = (centres[:, 0] >= 100.0) & (centres[:, 0] < 400.0)
    rows = (centres[:, 1] >= 50.0) & (centres[:, 1] < 500.0)
    beside = centres[~inside & rows & (centres[:, 0] > 100.0 - 0.75 * d) & (centres[:, 0] < 400.0 + 0.75 * d)]
    edge = np.flatnonzero(inside & (centres[:, 0] < 100.0 + 0.5 * d) & (np.abs(centres[:, 1] - 275.0) < d))[0]
    kept = np.delete(centres[inside], np.flatnonzero(np.flatnonzero(inside) == edge), axis=0)
    holes, _ = vacancies(kept[:, 0], kept[:, 1], window, d)
    assert len(holes) == 0  # in the inset: not searched
    holes, searched = vacancies(kept[:, 0], kept[:, 1], window, d, beside, (0.75 * d, 0.75 * d))
    assert len(holes) == 1 and np.hypot(*(holes[0] - centres[edge])) < (1 - VACANCY_GAP) * d + 3.0
    assert searched > len(kept) - 40  # up to the sides


def test_a_side_with_no_bed_beyond_it_keeps_its_inset():
    """Where nothing is found beyond a side (the bed ends there, or the image does), the gap
    along it is not taken for spheres missed."""
    d, window = 30.0, (100.0, 50.0, 400.0, 500.0)
    centres = _packed("hexagonal", d, window)
    bed = centres[(centres[:, 0] >= 100.0 + 0.5 * d) & (centres[:, 0] < 400.0)]  # ends half a diameter in
    rows = (centres[:, 1] >= 50.0) & (centres[:, 1] < 500.0)
    right = centres[rows & (centres[:, 0] >= 400.0) & (centres[:, 0] < 400.0 + 0.75 * d)]
    holes, _ = vacancies(bed[:, 0], bed[:, 1], window, d, right, (0.75 * d, 0.75 * d))
    assert len(holes) == 0
    holes, _ = vacancies(bed[:, 0], bed[:, 1], window, d, np.zeros((0, 2)), (0.0, 0.75 * d))
    assert len(holes) == 0


def test_spheres_missed_are_flagged_as_vacancies():
    """The check fails once a run misses more than one sphere in twenty."""
    def quality(vacant):
        return _first_frame_checks_with(vacant)
    assert quality((2, 400)).ok
    assert [c.name for c in quality((40, 400)).failed] == ["vacancies"]


def _first_frame_checks_with(vacant, walls=None):
    rng = np.random.default_rng(0)
    h = rng.uniform(0.5, 14.5, 140)
    heavy = h > 7.5
    layer = np.floor(h).astype(int)
    n = np.tile(np.bincount(layer, minlength=15), (3, 1))
    nh = np.tile(np.bincount(layer[heavy], minlength=15), (3, 1))
    return assess(n=n, n_heavy=nh, c0=0.5, first_heights=h, first_heavy=heavy, scores=np.full(140, 0.9),
                  p_heavy=None, separation=None, n_bad_frames=0, wall_detections=0.0, vacant=vacant, walls=walls)


def _bed_between_walls(d: float, window, bumps: bool) -> np.ndarray:
    """y of a hexagonal packing resting on the plate and pressed under the lid (rows from both
    walls meet in the middle), with the walls' hemispheres as a detector finds them (centred on
    the wall line, up to 0.3 d off) when ``bumps``."""
    _, y0, _, y1 = window
    rows = d * np.sqrt(3) / 2
    up = y1 - d / 2 - rows * np.arange(9)  # from the plate
    down = y0 + d / 2 + rows * np.arange(8)  # from the lid
    y = np.repeat(np.r_[up, down], 10)
    if bumps:
        rng = np.random.default_rng(0)
        y = np.r_[y, y1 - rng.uniform(-0.3, 0.3, 4) * d, y0 + rng.uniform(-0.3, 0.3, 4) * d]
    return y


@pytest.mark.parametrize("bumps", [False, True])
def test_window_lines_on_the_walls_read_half_a_diameter(bumps):
    d, window = 30.0, (100.0, 50.0, 400.0, 50.0 + 15 * 30.0)
    walls = wall_lines(_bed_between_walls(d, window, bumps), window)
    assert abs(walls.plate) < 0.01 and abs(walls.lid) < 0.01 and walls.layer_px == pytest.approx(d)


@pytest.mark.parametrize("line, move", [("lid", 0.15), ("lid", -0.15), ("plate", 0.2), ("plate", -0.12)])
def test_a_window_line_off_the_wall_is_read_by_how_much_and_which_way(line, move):
    """A line moved ``move`` diameters out of the bed (negative: into it) reads that much at its
    wall and nothing at the other, the bumps and the spheres left out as bumps included."""
    d, window = 30.0, (100.0, 50.0, 400.0, 50.0 + 15 * 30.0)
    y = _bed_between_walls(d, window, bumps=True)
    x0, y0, x1, y1 = window
    moved = (x0, y0 - move * d, x1, y1) if line == "lid" else (x0, y0, x1, y1 + move * d)
    walls = wall_lines(y, moved)
    other = walls.plate if line == "lid" else walls.lid
    assert getattr(walls, line) == pytest.approx(move, abs=0.02) and abs(other) < 0.02


def test_the_window_lines_check_says_which_line_to_move_and_by_how_many_pixels():
    quality = _first_frame_checks_with(None, walls=WallLines(plate=0.2, lid=-0.01, layer_px=40.0))
    assert [c.name for c in quality.failed] == ["window_lines"]
    about = quality.failed[0].about
    assert "move y1 up by 8 px" in about and "move y0" not in about
    assert _first_frame_checks_with(None, walls=WallLines(0.5 * WALL_LINE_SLACK, float("nan"), 40.0)).ok


def test_a_window_drawn_off_the_lid_is_flagged(tmp_path):
    """The same frames pass with the window as rendered and fail with its lid line 0.25 d up."""
    r = render_frames(stratified_map(4, 0.5), seed=5, out_dir=tmp_path, heavy="ceramic", light="pp", **SMALL)
    exp_path = tmp_path / "experiment.json"
    exp = json.loads(exp_path.read_text())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", QualityWarning)
        right = analyze(tmp_path, smooth=1, save=False, progress=False, workers=2)
        x0, y0, x1, y1 = exp["window"]
        exp_path.write_text(json.dumps({**exp, "window": [x0, y0 - 0.25 * SMALL["particle_diameter_px"], x1, y1]}))
        off = analyze(tmp_path, smooth=1, save=False, progress=False, workers=2)
    assert "window_lines" not in [c.name for c in right.quality.failed], right.quality.report()
    assert "window_lines" in [c.name for c in off.quality.failed], off.quality.report()
    assert np.sqrt(np.nanmean((off.c_raw - r.c_raw) ** 2)) > np.sqrt(np.nanmean((right.c_raw - r.c_raw) ** 2))


@pytest.mark.parametrize("lattice", ["hexagonal", "square"])
def test_touching_spheres_lie_a_diameter_apart(lattice):
    """Touching spheres read 1 in their own diameter, and 1.25 in a diameter given a fifth too small;
    spheres beside the window are neighbours of those at its sides, not asked about themselves."""
    d, window = 30.0, (100.0, 50.0, 400.0, 500.0)
    centres = _packed(lattice, d, window)
    inside = (centres[:, 0] >= window[0]) & (centres[:, 0] < window[2])
    frames = [(centres[inside], centres[~inside])] * 3
    assert sphere_spacing(frames, d) == pytest.approx(1.0)
    assert sphere_spacing(frames, 0.8 * d) == pytest.approx(1.25)
    # alone, the sphere at the window's side in a square row has only the one beside it inside
    row = np.column_stack([np.arange(5) * d, np.zeros(5)])
    assert sphere_spacing([(row[:1], row[1:])], d) == pytest.approx(1.0)
    assert np.isnan(sphere_spacing([(row[:1], np.zeros((0, 2)))], d))
    assert np.isnan(sphere_spacing([], d))


def test_a_diameter_given_wrong_is_flagged_with_the_spacing_found(tmp_path):
    """Frames analysed with particle_diameter_px right pass the spacing check; given 20 % too large
    or too small, it fails and names the spacing the spheres do have: the diameter right, to within a
    tenth of it (with the diameter given so far off, the spheres are found a little off too)."""
    render_frames(stratified_map(4, 0.5), seed=5, out_dir=tmp_path, heavy="ceramic", light="pp", **SMALL)
    exp_path = tmp_path / "experiment.json"
    exp = json.loads(exp_path.read_text())
    d = exp["particle_diameter_px"]

    def spacing_check(given):
        exp_path.write_text(json.dumps({**exp, "particle_diameter_px": given}))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", QualityWarning)
            a = analyze(tmp_path, smooth=1, save=False, progress=False, workers=2)
        check = next(c for c in a.quality.checks if c.name == "sphere_spacing")
        return check, float(re.search(r"the spheres lie ([0-9.]+) px apart", check.about).group(1))

    right, apart = spacing_check(d)
    assert right.passed and right.value < 0.5 * SPACING_SLACK, right.line()
    for given in (1.2 * d, 0.8 * d):
        wrong, found = spacing_check(given)
        assert not wrong.passed, wrong.line()
        assert found == pytest.approx(apart, abs=0.1 * d), wrong.line()


def _through_lens(centres: np.ndarray, axis: np.ndarray, k1: float, f: float = 600.0) -> np.ndarray:
    """Centres as a lens of radial distortion k1 (focal length f [px]) shows them: r (1 + k1 r^2)."""
    u = (centres - axis) / f
    return axis + f * u * (1 + k1 * (u**2).sum(axis=1, keepdims=True))


@pytest.mark.parametrize("lattice", ["hexagonal", "square"])
def test_spheres_far_from_the_lens_axis_lie_closer_where_the_lens_is_not_taken_off(lattice):
    """Touching spheres read 1 near the axis and far from it; seen through a barrel lens left on, the
    far third lie closer together (below 1 - LENS_SLACK), through a pincushion lens farther apart."""
    d, window = 30.0, (100.0, 50.0, 400.0, 500.0)
    centres = _packed(lattice, d, window)
    inside = (centres[:, 0] >= window[0]) & (centres[:, 0] < window[2])
    axis = np.array([260.0, 290.0])  # not the window's middle

    def across(k1):
        seen = _through_lens(centres, axis, k1)
        return spacing_across_view([(seen[inside], seen[~inside])] * 2, axis[1])

    assert across(0.0) == pytest.approx(1.0)
    assert across(-0.3) < 1 - LENS_SLACK
    assert across(0.3) > 1 + LENS_SLACK
    assert abs(across(-0.03) - 1) < LENS_SLACK  # a mild lens left on reads as one taken off
    few = centres[inside][: LENS_SPHERES - 1]
    assert np.isnan(spacing_across_view([(few, np.zeros((0, 2)))], axis[1]))


def _checks_as_given(r, pinhole: bool = False) -> dict:
    """The quality checks, by name, of the rendered run ``r`` analysed with its own camera model or,
    with ``pinhole``, the one granseg init writes when given none (a pinhole without distortion)."""
    exp_path = r.source / "experiment.json"
    exp = dict(r.experiment)
    if pinhole:
        k, dist = init_camera(None, r.images[0].shape[1::-1])
        exp.update(camera_matrix=k.tolist(), dist_coeffs=dist.tolist())
    exp_path.write_text(json.dumps(exp))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", QualityWarning)
        a = analyze(r.source, smooth=1, save=False, progress=False, workers=2)
    return {c.name: c for c in a.quality.checks}


def test_a_lens_not_taken_off_is_flagged_and_named(tmp_path):
    """A wide-angle look analysed with its camera model passes the check; with the camera model granseg
    init writes when given none (a pinhole without distortion), it fails by name."""
    r = render_frames(stratified_map(4, 0.5), seed=5, out_dir=tmp_path, heavy="ceramic", light="pp",
                      dist_coeffs=[-0.32, 0.11, 0.0005, -0.0004, -0.015], **SMALL)
    given = _checks_as_given(r)["spacing_across_view"]
    assert given.passed, given.line()
    pinhole = _checks_as_given(r, pinhole=True)["spacing_across_view"]
    assert not pinhole.passed, pinhole.line()


def test_window_lines_names_a_lens_left_on_where_the_camera_model_takes_none_off():
    """window_lines adds the lens to its line only where the camera model takes no distortion off and
    the spheres far from the axis lie more than LENS_HINT closer (or farther apart) than near it."""
    walls = WallLines(plate=0.0, lid=0.2, layer_px=30.0)

    def line(across_view):
        (check,) = [c for c in quality._detection_checks(np.ones(9), None, walls, None, None, across_view)
                    if c.name == "window_lines"]
        assert not check.passed
        return check.about

    assert "calibrate-camera" in line((1 - 2 * LENS_HINT, False)) and "closer together" in line((0.97, False))
    assert "farther apart" in line((1 + 2 * LENS_HINT, False))
    for told in ((1 - 2 * LENS_HINT, True), (1 - 0.5 * LENS_HINT, False), (float("nan"), False), None):
        assert "calibrate-camera" not in line(told), told


def test_a_mild_lens_left_on_is_named_by_window_lines_before_a_line_is_moved(tmp_path):
    """Under the 2-D renderer's mild default lens, granseg init's pinhole passes spacing_across_view but
    fails window_lines; its line names the lens (moving the line instead gives a map that passes
    every check and misses: benches/bench_window_advice.py). With the lens's camera model, no hint."""
    r = render_scene("S-PP-75", 6, seed=9, out_dir=tmp_path)
    pinhole = _checks_as_given(r, pinhole=True)
    assert pinhole["spacing_across_view"].passed and not pinhole["window_lines"].passed
    assert "calibrate-camera" in pinhole["window_lines"].about, pinhole["window_lines"].line()
    assert "calibrate-camera" not in _checks_as_given(r)["window_lines"].about


def test_view_move_is_what_both_walls_do_together():
    """A move of the view moves the lid's reading and the plate's alike; one wall alone (the bottom
    layer riding the plate's bumps, a lid that rises) or a frame's glitch is not a move."""
    rng = np.random.default_rng(0)
    still = np.column_stack([0.01 + 0.005 * rng.standard_normal(40), 0.02 + 0.005 * rng.standard_normal(40)])
    assert view_move(still)[0] < 0.01
    knocked = still.copy()
    knocked[25:] += [-0.08, 0.08]  # the image moved down by 0.08 d from row 25 on
    move, row = view_move(knocked)
    assert move == pytest.approx(0.08, abs=0.012) and row >= 24
    up = still.copy()
    up[25:] += [0.08, -0.08]
    assert view_move(up)[0] == pytest.approx(0.08, abs=0.012)
    plate_rides = still.copy()
    plate_rides[10:14, 0] += 0.2  # four frames, the plate alone
    plate_rides[30, :] += [-0.3, 0.3]  # one frame's glitch
    assert view_move(plate_rides)[0] < 0.01
    lid_rises = still.copy()
    lid_rises[20:, 1] -= 0.1
    assert view_move(lid_rises)[0] < 0.01
    ride_at_end = lid_rises.copy()
    ride_at_end[-3:, 0] += 0.18  # the plate's layer rides its bumps in the last frames, the lid risen
    assert view_move(ride_at_end)[0] < 0.01
    gaps = knocked.copy()
    gaps[::2] = np.nan  # rows without a reading are left out; the row named is the map's
    move, row = view_move(gaps)
    assert move == pytest.approx(0.08, abs=0.012) and 24 <= row < 40 and np.isfinite(gaps[row]).all()
    assert np.isnan(view_move(still[:2])[0]) and np.isnan(view_move(np.full((9, 2), np.nan))[0])


def test_the_plates_ride_on_its_bumps_does_not_hide_a_move():
    """The layer on the plate rides its bumps up for a few frames, never below where it nests. A ride
    of four frames in the middle of a move must not break the move into runs too short to hold, as
    it did on bumps-S-PP seed 8 (a view moved 0.1 d down read 0.000, a lid risen 0.1 d 0.003)."""
    rng = np.random.default_rng(1)
    still = np.column_stack([0.015 + 0.003 * rng.standard_normal(24), 0.008 + 0.003 * rng.standard_normal(24)])
    ride = np.zeros((24, 2))
    ride[16:20, 0] = [0.16, 0.22, 0.23, 0.11]  # rows 16-19, as read on that run
    moved = still + ride
    moved[12:] += [-0.1, 0.1]  # the image moved down 0.1 d from row 12 on
    assert view_move(moved)[0] == pytest.approx(0.1, abs=0.015)
    assert abs(bed_rise(moved)[0]) < 0.02
    risen = still + ride
    risen[12:, 1] -= 0.1  # the lid rose 0.1 d from row 12 on
    assert bed_rise(risen)[0] == pytest.approx(0.1, abs=0.015)
    assert view_move(risen)[0] < 0.02
    assert view_move(still + ride)[0] < 0.01 and abs(bed_rise(still + ride)[0]) < 0.01


def _bed_rows(n_t: int, rng, heavy_low: float, light_high: float, moved_from: int, move: float) -> list:
    """Rows of a 15-layer bed, 20 px a layer, whose plate layer turns from light to heavy over the
    run: the heavy class found ``heavy_low`` d lower there and the light ``light_high`` d higher
    (the smear of the moving plate), the view moved ``move`` d down from row ``moved_from``."""
    rows = []
    for i in range(n_t):
        h = np.repeat(np.arange(N_LAYERS) + 0.5, 9) + 0.01 * rng.standard_normal(9 * N_LAYERS)
        heavy = np.repeat(np.arange(N_LAYERS) >= 8, 9)
        heavy[:9] = np.arange(9) < round(9 * i / (n_t - 1))  # the plate layer's heavy share 0 -> 1
        h[:9] += np.where(heavy[:9], -heavy_low, light_high)
        h -= move if i >= moved_from else 0.0
        rows.append(SimpleNamespace(y=400.0 - 20.0 * h, heavy=heavy, wall_y=np.empty(0), wall_x=np.empty(0)))
    return rows


def test_the_walls_are_read_with_the_classes_gap_on_the_plate_taken_off():
    """In the layer smeared by the moving plate the classes keep a gap of their own (the heavy read
    low, the light high). The plate's reading must not sink as the heavy class comes down into that
    layer, or a view moved 0.1 d reads half of it (motion-blur-S-PP seed 7: 0.047)."""
    window = (0.0, 100.0, 180.0, 400.0)
    rng = np.random.default_rng(4)
    still = pipeline._walls_by_row(_bed_rows(24, rng, 0.045, 0.02, 24, 0.0), window)
    assert np.ptp(still[:, 0]) < 0.03 and np.ptp(still[:, 1]) < 0.03 and view_move(still)[0] < 0.01
    moved = pipeline._walls_by_row(_bed_rows(24, rng, 0.045, 0.02, 12, -0.1), window)
    assert view_move(moved)[0] == pytest.approx(0.1, abs=0.01)
    assert abs(bed_rise(moved)[0]) < 0.01
    unclassed = _bed_rows(24, rng, 0.045, 0.02, 24, 0.0)
    for s in unclassed:
        s.heavy = None  # before the classes are learned, read as found
    assert np.ptp(pipeline._walls_by_row(unclassed, window)[:, 0]) > 0.05
    # on a bumpy plate each sphere nests at its own height, and the frames' gaps are noise
    bumpy = _bed_rows(24, rng, 0.0, 0.0, 24, 0.0)
    for s in bumpy:
        s.y[:9] -= 20.0 * rng.uniform(0.0, 0.4, 9)
    assert pipeline._plate_class_gap(bumpy, window) == 0.0
    assert pipeline._plate_class_gap(_bed_rows(24, rng, 0.045, 0.02, 24, 0.0), window) == pytest.approx(0.065, abs=0.01)


def _lid_rows(n_t: int, rng, lowered_from: int, lowered: float, moved_from: int, moved: float,
              bump_found_from: int = 0) -> list:
    """Rows of a 15-layer bed, 20 px a layer and 9 spheres across, under a bumpy lid that holds most
    of the layer under it off: two spheres touch it, the rest nest between its bumps, and one of
    those rises 0.09 d into contact over the run (as on bumps-S-PP seed 16). The lid's three bumps
    are found 0.26 d below its line, within the wall clearance (0.38 d), as the walls' detections.
    The lid lowered ``lowered`` d from row ``lowered_from`` on (its bumps with it), the view moved
    ``moved`` d down from row ``moved_from`` on; what comes within the clearance of the lid's line
    is found among the walls' detections. The middle bump is not found before row ``bump_found_from``
    (the bumps are found in some frames and not others)."""
    rows = []
    bumps_x = np.array([30.0, 90.0, 150.0])
    for i in range(n_t):
        h = np.repeat(np.arange(N_LAYERS) + 0.5, 9) + 0.003 * rng.standard_normal(9 * N_LAYERS)
        x = np.tile(10.0 + 20.0 * np.arange(9), N_LAYERS)
        depth = np.array([0.50, 0.505, 0.60 - 0.09 * i / (n_t - 1), 0.62, 0.65, 0.68, 0.80, 0.92, 0.98])
        down = (lowered if i >= lowered_from else 0.0)
        h[-9:] = N_LAYERS - depth - down + 0.003 * rng.standard_normal(9)
        x[-9:] = [0.0, 60.0, 120.0, 45.0, 75.0, 105.0, 15.0, 165.0, 135.0]  # the touching pair between bumps
        h = np.r_[h, np.full(3, N_LAYERS - 0.26 - down)] - (moved if i >= moved_from else 0.0)
        x = np.r_[x, bumps_x]
        if i < bump_found_from:
            h, x = np.delete(h, -2), np.delete(x, -2)
        walls = N_LAYERS - h < WALL_CLEARANCE
        rows.append(SimpleNamespace(y=400.0 - 20.0 * h[~walls], heavy=None, wall_y=400.0 - 20.0 * h[walls],
                                    wall_x=x[walls]))
    return rows


def test_the_lid_is_read_from_the_spheres_that_touch_it():
    """Under a bumpy lid only a few spheres touch it. The lid's reading from frame to frame must
    follow those, not the next one as it settles into contact: read at the 20th percentile, the
    lid's reading drifted 0.075 d on bumps-S-PP seed 16, where a view moved 0.1 d read 0.044 and a
    lid lowered 0.1 d read 0.028. Nor may it take the lid's own bumps, which a view moved down or a
    lid lowered carries into its band: read with them, a lid lowered 0.1 d read as risen (+0.077 on
    apparatus-S-PP-75-jpeg seed 18; here +0.14)."""
    window = (0.0, 100.0, 180.0, 400.0)
    rng = np.random.default_rng(5)
    still = pipeline._walls_by_row(_lid_rows(24, rng, 24, 0.0, 24, 0.0), window)
    assert np.ptp(still[:, 1]) < 0.03 and abs(bed_rise(still)[0]) < 0.02 and view_move(still)[0] < 0.01
    lowered = pipeline._walls_by_row(_lid_rows(24, rng, 12, 0.1, 24, 0.0), window)
    assert bed_rise(lowered)[0] == pytest.approx(-0.1, abs=0.015) and view_move(lowered)[0] < 0.01
    moved = pipeline._walls_by_row(_lid_rows(24, rng, 24, 0.0, 12, 0.1), window)
    assert view_move(moved)[0] == pytest.approx(0.1, abs=0.015) and abs(bed_rise(moved)[0]) < 0.02
    # the spheres that come within the clearance as the view moves up are still read: they stand
    # between the bumps
    up = pipeline._walls_by_row(_lid_rows(24, rng, 24, 0.0, 12, -0.15), window)
    assert view_move(up)[0] == pytest.approx(0.15, abs=0.015) and abs(bed_rise(up)[0]) < 0.02
    # a bump not found in the first frames is still left out: the middle one of apparatus-S-PP-75-jpeg
    # seed 22 was found from its fifth frame on, and its lowered lid read 0.069
    late = pipeline._walls_by_row(_lid_rows(24, rng, 12, 0.1, 24, 0.0, bump_found_from=4), window)
    assert bed_rise(late)[0] == pytest.approx(-0.1, abs=0.015) and view_move(late)[0] < 0.01
    # the first frame's window_lines keeps the 20th percentile, for which its limit was set
    first = _lid_rows(24, rng, 24, 0.0, 24, 0.0)[0]
    first = np.r_[first.y, first.wall_y]
    assert wall_lines(first, window).lid > wall_lines(first, window, lid_quantile=quality.LID_MOVE_QUANTILE).lid


def test_the_window_follows_what_the_checks_read():
    """wall_follow moves each row's window as far as view_move and bed_rise read a move where its
    check fails: from the step's first row on (the hold alone lags it), the view's move where both
    walls go together, the lid's against the plate where the lid alone goes; a few rows' excursion
    is not followed, nor a move the check passes."""
    rng = np.random.default_rng(3)
    still = np.column_stack([0.01 + 0.005 * rng.standard_normal(40), 0.02 + 0.005 * rng.standard_normal(40)])
    assert np.abs(wall_follow(still)).max() < 0.01
    lines = still.copy()
    lines[25:] += [-0.08, 0.08]  # the view moved down by 0.08 d from row 25 on
    lines[30:, 1] += 0.1  # and the lid fell (the bed settled) by 0.1 d from row 30 on
    lines[10:14, 0] += 0.2  # the plate's layer riding its bumps for four frames
    lines[5, :] += [-0.3, 0.3]  # one frame's glitch
    follow = wall_follow(lines)
    assert np.abs(follow[:25]).max() < 0.012
    assert follow[25:, 0] == pytest.approx(0.08, abs=0.012)
    assert np.abs(follow[25:30, 1]).max() < 0.012 and follow[30:, 1] == pytest.approx(-0.1, abs=0.012)
    slight = still.copy()
    slight[25:] += [-0.04, 0.04]  # a move under the check's slack is not followed: nor is noise
    slight[30:, 1] -= 0.06
    assert not wall_follow(slight).any()
    rises = still.copy()
    rises[20:, 1] -= 0.1  # the lid alone rose
    assert np.abs(wall_follow(rises)[:, 0]).max() < 0.012 and wall_follow(rises)[20:, 1] == pytest.approx(0.1, abs=0.012)
    gaps = lines.copy()
    gaps[27] = np.nan  # a row without a reading follows its neighbours
    assert wall_follow(gaps)[27] == pytest.approx(follow[27], abs=0.012)
    assert not wall_follow(still[:2]).any() and wall_follow(still[:2]).shape == (2, 2)
    window = (10.0, 100.0, 310.0, 400.0)  # 20 px a layer
    assert followed_window(window, 0.5, 0.0) == (10.0, 110.0, 310.0, 410.0)
    assert followed_window(window, 0.0, 0.5) == (10.0, 90.0, 310.0, 400.0)


def _counts_off(n: np.ndarray, n_true: np.ndarray) -> float:
    return float(np.mean(np.abs(n - n_true) / np.maximum(n_true, 1)))


def test_a_camera_moved_during_the_run_is_flagged(tmp_path):
    """The frames' second half moved down by a tenth of a diameter (a camera knocked): the map's
    later rows are binned by lines off the walls, and view_steady says so; as rendered, it passes."""
    r = render_scene("S-PP-75", 12, seed=9, out_dir=tmp_path / "frames", **SMALL)
    as_rendered = analyze(r.source, save=False, progress=False, workers=2)
    assert {c.name: c for c in as_rendered.quality.checks}["view_steady"].passed
    assert len(list(Path(r.source).glob("*.png"))) == 12
    move_view(r.source, 0.1 * SMALL["particle_diameter_px"], first=6)
    with pytest.warns(QualityWarning, match="view_steady"):
        moved = analyze(r.source, save=False, progress=False, workers=2)
    check = {c.name: c for c in moved.quality.checks}["view_steady"]
    assert not check.passed and check.value > VIEW_MOVE_SLACK and "map row" in check.about
    assert "granseg init-experiment" in quality.ADVICE["view_steady"]
    assert "--follow-walls" in quality.ADVICE["view_steady"]
    # counted in windows that follow the walls, the moved rows come back to the truth, and the
    # check judges the lines as followed
    followed = analyze(r.source, save=False, progress=False, workers=2, follow_walls=True)
    assert {c.name: c for c in followed.quality.checks}["view_steady"].passed
    assert followed.quality.figures["view_followed_d"] == pytest.approx(0.1, abs=0.03)
    assert followed.window_of(0) == tuple(followed.experiment.window) and followed.window_of(11)[1] > followed.window_of(0)[1]
    off, left = _counts_off(moved.n[6:], r.n[6:]), _counts_off(followed.n[6:], r.n[6:])
    assert left < 0.5 * off, (off, left)
    # the command line's flag, and the moves followed kept in the map's quality record
    out = tmp_path / "followed.npz"
    assert main(["analyze", str(r.source), "--follow-walls", "--strict", "--no-progress", "--out", str(out)]) == 0
    figures = json.loads(load_map(out).quality)["figures"]
    assert figures["view_followed_d"] == pytest.approx(followed.quality.figures["view_followed_d"])
    np.testing.assert_array_equal(load_map(out).n, followed.n)
    with pytest.raises(ValueError, match="follow_walls"):
        analyze(r.source, save=False, progress=False, follow_walls="yes")


def test_bed_rise_is_the_lid_moving_against_the_plate():
    """A lid that rises (the bed dilates) shrinks the lid's reading alone: the bed's height grows by
    that much; a settling bed is a fall; a move of the whole view, a frame's glitch or the bottom
    layer riding the plate's bumps for a few frames changes no height."""
    rng = np.random.default_rng(2)
    still = np.column_stack([0.01 + 0.005 * rng.standard_normal(40), 0.02 + 0.005 * rng.standard_normal(40)])
    assert abs(bed_rise(still)[0]) < 0.01
    lid_rises = still.copy()
    lid_rises[20:, 1] -= 0.1  # the lid's spheres 0.1 d nearer the lid's line: the lid rose
    rise, row = bed_rise(lid_rises)
    assert rise == pytest.approx(0.1, abs=0.012) and row >= 19
    settles = still.copy()
    settles[20:, 1] += 0.08
    assert bed_rise(settles)[0] == pytest.approx(-0.08, abs=0.012)
    view_moves = still.copy()
    view_moves[25:] += [-0.08, 0.08]
    view_moves[10:14, 0] += 0.2
    view_moves[30, :] += [-0.3, 0.4]
    assert abs(bed_rise(view_moves)[0]) < 0.01
    view_moves[-3:, 0] += 0.18  # after the move, the plate's layer rides its bumps in the last frames
    assert abs(bed_rise(view_moves)[0]) < 0.01
    assert np.isnan(bed_rise(still[:2])[0])


def test_a_view_move_under_its_limit_is_not_taken_off_the_lids():
    """The plate's reading strays by a few hundredths of a diameter (spheres of the blurred layer on
    the moving plate found low in some frames). Where it strays the way a lowered lid carries the
    layer under it, the two walls agree on a small move of the view; taken off the lid's move, it
    hid a lid lowered 0.1 d under the bed's limit (motion-blur-S-PP seed 17: 0.052). A view that
    passes its check is taken as still, and the lid's whole move is the bed's; one that fails it is
    taken off."""
    rng = np.random.default_rng(4)
    still = np.column_stack([0.01 + 0.005 * rng.standard_normal(24), 0.02 + 0.005 * rng.standard_normal(24)])
    lowered = still.copy()
    lowered[12:, 1] += 0.1  # the lid lowered 0.1 d from row 12 on, its layer with it
    lowered[12:, 0] -= 0.04  # and the plate's reading strayed down, under the view's limit
    assert view_move(lowered)[0] < VIEW_MOVE_SLACK
    assert bed_rise(lowered)[0] == pytest.approx(-0.1, abs=0.012)
    follow = wall_follow(lowered)
    assert not follow[:, 0].any() and follow[12:, 1] == pytest.approx(-0.1, abs=0.012)
    knocked = still.copy()
    knocked[12:, 1] += 0.1
    knocked[12:] += [-0.06, 0.06]  # the view moved down 0.06 d as well: over its limit, taken off
    assert view_move(knocked)[0] > VIEW_MOVE_SLACK
    assert bed_rise(knocked)[0] == pytest.approx(-0.1, abs=0.012)
    strays = still.copy()
    strays[12:] += [-0.045, 0.045]  # a stray of both walls under the view's limit stays under the bed's
    assert abs(bed_rise(strays)[0]) < BED_RISE_SLACK


def test_a_lid_that_rises_during_the_run_is_flagged(tmp_path):
    """The bed above the plate stretched so that the lid rises by a fifth of a diameter in the second
    half of the frames (the bed dilating under shear): the upper rows are binned by lines the layers
    have left, and bed_steady says so, not view_steady; as rendered, it passes."""
    r = render_scene("S-PP-75", 12, seed=9, out_dir=tmp_path / "frames", **SMALL)
    as_rendered = analyze(r.source, save=False, progress=False, workers=2)
    assert {c.name: c for c in as_rendered.quality.checks}["bed_steady"].passed
    raise_lid(r.source, 0.2 * SMALL["particle_diameter_px"], r.experiment["window"], first=6)
    with pytest.warns(QualityWarning, match="bed_steady"):
        risen = analyze(r.source, save=False, progress=False, workers=2)
    checks = {c.name: c for c in risen.quality.checks}
    assert not checks["bed_steady"].passed and checks["bed_steady"].value > BED_RISE_SLACK
    assert "rose" in checks["bed_steady"].about and checks["view_steady"].passed
    assert risen.quality.figures["bed_rise_d"] == pytest.approx(0.2, abs=0.05)
    assert "--follow-walls" in quality.ADVICE["bed_steady"]
    # the layer under the risen lid lies 0.3 d from the window's own line, where the lid's
    # hemispheres are told from spheres (layers.WALL_CLEARANCE): left out as bumps, it empties the
    # top row; followed, the lid line moves with the lid, the layer is told from the bumps by it
    # and counted again
    assert risen.n[6:, -1].max() <= 0.5 * r.n[6:, -1].min()
    followed = analyze(r.source, save=False, progress=False, workers=2, follow_walls=True,
                       detections=tmp_path / "found.csv")
    assert followed.quality.ok, followed.quality.failed
    with open(tmp_path / "found.csv", newline="", encoding="utf-8") as f:  # each row's layers as counted
        rows = [(int(d["frame"]), int(d["layer"])) for d in csv.DictReader(f)]
    np.testing.assert_array_equal(np.bincount([fr * 15 + j for fr, j in rows], minlength=12 * 15).reshape(12, 15),
                                  followed.n)
    assert followed.quality.figures["bed_followed_d"] == pytest.approx(0.2, abs=0.05)
    off, left = _counts_off(risen.n[6:], r.n[6:]), _counts_off(followed.n[6:], r.n[6:])
    assert left < 0.3 * off and left < 0.03, (off, left)


@pytest.mark.parametrize("climb", [0.15, -0.15, 0.0])
def test_plate_tilt_reads_how_the_plate_layer_climbs_across_the_window(climb):
    """Spheres resting on the plate, their heights climbing by ``climb`` d across the window (a view
    turned), with a loose second layer above: plate_tilt reads the climb; too few spheres, NaN."""
    window = (0.0, 0.0, 300.0, 450.0)  # 15 layers of 30 px
    x = np.tile(np.arange(15.0, 300.0, 30.0), 4) + np.repeat([0.0, 3.0, 7.0, 11.0], 10)
    resting = 0.5 + climb * (x - 150.0) / 300.0
    y = np.r_[450.0 - 30.0 * resting, 450.0 - 30.0 * (resting + 0.87)]
    assert plate_tilt(np.r_[x, x], y, window) == pytest.approx(climb, abs=0.02)
    assert np.isnan(plate_tilt(x[:6], y[:6], window))


def test_level_reading_gives_its_own_error_and_the_check_judges_the_least_climb():
    """Frames that agree give a reading with no error; frames whose plate layer scatters give a
    large one, and window_level judges the reading less LEVEL_SIGMAS errors (a noisy look's reading
    is not a turned camera); fewer than LEVEL_FRAMES frames are not read."""
    window = (0.0, 0.0, 300.0, 450.0)
    x = np.tile(np.arange(15.0, 300.0, 30.0), 3) + np.repeat([0.0, 5.0, 9.0], 10)
    rng = np.random.default_rng(1)

    def frame(climb, scatter):
        resting = 0.5 + climb * (x - 150.0) / 300.0 + scatter * rng.standard_normal(len(x))
        return x, 450.0 - 30.0 * np.clip(resting, 0.31, 1.19)

    tilt, error = level_reading([frame(0.15, 0.0)] * 8, window)
    assert tilt == pytest.approx(0.15, abs=0.02) and error == pytest.approx(0.0, abs=1e-12)
    assert not quality._level_check((tilt, error, 1.0))[0].passed
    tilt, error = level_reading([frame(0.0, 0.25) for _ in range(8)], window)
    assert error > 0.02
    (check,) = quality._level_check((0.12, error, 1.0))
    assert check.value == pytest.approx(0.12 - LEVEL_SIGMAS * error) and check.passed
    assert np.isnan(level_reading([frame(0.15, 0.0)] * 2, window)[0])
    # a reading whose error could not be read (most resamplings too few spheres) is not judged: no
    # check, rather than a failed one
    assert quality._level_check((0.3, float("nan"), 2.0)) == []


def test_a_camera_not_level_is_flagged(tmp_path):
    """Every frame turned by 1.5 deg (a camera not level): the plate's layer climbs across the window
    and window_level says by how much and by what angle; as rendered, it passes."""
    r = render_scene("S-PP-75", 6, seed=9, out_dir=tmp_path / "frames", **SMALL)
    as_rendered = analyze(r.source, save=False, progress=False, workers=2)
    assert {c.name: c for c in as_rendered.quality.checks}["window_level"].passed
    turn_view(r.source, 1.5)
    with pytest.warns(QualityWarning, match="window_level"):
        turned = analyze(r.source, save=False, progress=False, workers=2)
    check = {c.name: c for c in turned.quality.checks}["window_level"]
    assert not check.passed and check.value > LEVEL_SLACK and "right end" in check.about
    degrees = float(re.search(r"turned by about ([0-9.]+) deg", check.about).group(1))
    assert 0.7 < degrees < 1.8
    assert turned.quality.figures["window_level_d"] > LEVEL_SLACK


def test_quality_is_stored_in_the_map_and_refused_downstream(tmp_path):
    frames = tmp_path / "frames"
    render_frames(stratified_map(4, 0.5), seed=3, out_dir=frames, heavy="pp", light="pp", **SMALL)
    with pytest.warns(QualityWarning, match="class_separation"):
        a = analyze(frames, out=tmp_path / "flagged.npz", smooth=1, progress=False, workers=2)
    assert a.previews, "a failed check writes the preview that shows it"
    assert (tmp_path / "flagged_preview").is_dir()
    with pytest.warns(QualityWarning, match="class_separation"):
        m = load_map(a.out)
    record = json.loads(m.quality)
    assert record["ok"] is False and record["checks"]["class_separation"]["passed"] is False
    assert Quality.from_json(m.quality).failed[0].name == a.quality.failed[0].name
    with pytest.raises(FlaggedMapError, match="flagged.npz: .*class_separation"):
        check_accepted([m], accept_flagged=False)
    check_accepted([m], accept_flagged=True)
    from granseg.calibration import calibrate

    with pytest.raises(FlaggedMapError, match="--accept-flagged"):
        calibrate([m], progress=False)


def test_cli_strict_exit_and_detections_csv(tmp_path, capsys):
    good, bad = tmp_path / "good", tmp_path / "bad"
    r = render_frames(stratified_map(3, 0.5), seed=4, out_dir=good, heavy="glass", light="pp", **SMALL)
    render_frames(stratified_map(3, 0.5), seed=4, out_dir=bad, heavy="pp", light="pp", **SMALL)
    det = tmp_path / "det.csv"
    assert main(["analyze", str(good), "--no-progress", "--strict", "--smooth", "1",
                 "--detections", str(det)]) == 0
    out = capsys.readouterr().out
    assert "quality: ok" in out and "initial_heavy_share" in out
    # which reading of gloss the run kept is in the map and said when it is the learned spots
    spots = Quality.from_json(str(load_map(good / "map.npz").quality)).figures["gloss_at_learned_spots"]
    assert isinstance(spots, bool) and spots == ("gloss read where the first frame's glossy spheres" in out)
    with open(det, newline="") as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0]) == ["frame", "x", "y", "r", "class", "p_heavy", "layer"]
    m = load_map(good / "map.npz")
    assert len(rows) == int(m.n.sum())
    for i in range(3):
        layer = np.array([int(x["layer"]) for x in rows if int(x["frame"]) == i])
        heavy = np.array([x["class"] == "heavy" for x in rows if int(x["frame"]) == i])
        assert np.array_equal(np.bincount(layer, minlength=15), m.n[i])
        assert np.array_equal(np.bincount(layer[heavy], minlength=15), m.n_heavy[i])
    assert np.abs(m.c_raw - r.c_raw).max() <= 0.2
    # the detections file is an output like any other: not replaced without --force
    assert main(["analyze", str(good), "--no-progress", "--detections", str(det), "--out",
                 str(tmp_path / "other.npz")]) == 2
    assert main(["analyze", str(bad), "--no-progress", "--strict"]) == 3
    err = capsys.readouterr().err
    assert "WARNING" in err and "class_separation" in err


# --------------------------------------------------------------------------- motion blur


def test_blur_test_keeps_smeared_classes_only_for_disagreements_near_the_plate():
    rng = np.random.default_rng(3)
    height = rng.uniform(0.5, 14.5, 1000)
    sharp = rng.random(1000) < 0.5
    near = np.flatnonzero(height < BLUR_ZONE)[:12]
    anywhere = rng.choice(1000, 12, replace=False)
    # a few disagreements cannot tell: the smear-trained classes stay
    for differ, smeared in ((near, True), (anywhere, False), (near[:2], True), (anywhere[:2], True), ([], True)):
        other = sharp.copy()
        other[np.asarray(differ, dtype=int)] ^= True
        test = blur_test(height, sharp, other)
        assert test.smeared is smeared, test
        assert test.disagree == len(differ)


def test_smeared_classes_are_kept_for_blurred_footage_only(tmp_path, capsys):
    """The plate's motion blur (a 2-D apparatus look) keeps the smear-trained classes; the
    physically based glossy-over-matte footage, with no blur, keeps the sharp ones: trained on
    smeared copies too, 4 % of its matte spheres were taken for glossy (BENCHMARKS.md)."""
    r = render_scene("apparatus-G-POM-50-jpeg", 4, seed=9, out_dir=tmp_path / "blur")
    a = analyze(r.source, smooth=1, save=False, progress=False, workers=2)
    figures = a.quality.figures
    assert figures["classes_learned_smeared"], figures
    assert figures["blur_disagreements_near_plate"] >= 0.8 * figures["blur_disagreements"] > 0
    pbr = Path(__file__).parent / "fixtures" / "pbr" / "grey-glossy-matte"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", QualityWarning)
        b = analyze(pbr, smooth=1, save=False, progress=False, workers=2)
    assert not b.quality.figures["classes_learned_smeared"], b.quality.figures
    assert b.quality.figures["evidence_against_blur"] > 100
    # the record survives the map file, and analyze says which classes it kept
    assert json.loads(Quality.from_json(a.quality.to_json()).to_json())["figures"]["classes_learned_smeared"]
    main(["analyze", str(pbr), "--out", str(tmp_path / "map.npz"), "--no-progress", "--smooth", "1"])
    assert "learned from sharp spheres only (motion blur ruled out)" in capsys.readouterr().out


# --------------------------------------------------------------------------- feature resolution


def test_a_feature_constant_among_the_labelled_spheres_does_not_decide_a_class():
    """Two grey materials share their chroma to 0.02 levels in the first frame; lossy video shifts
    a later frame's chroma by a level. Standardised by that spread, the shift weighed 50 standard
    deviations and called matte spheres polished steel with p_heavy = 1 (S-POM-25 in MPEG-4). The
    spread is now never taken finer than the feature's resolution (one level)."""
    rng = np.random.default_rng(5)
    m = 120
    height = np.concatenate([rng.uniform(9, 14.5, m // 2), rng.uniform(0.5, 6, m // 2)])
    heavy = height > 7.5
    feats = np.zeros((m, len(FEATURES)))
    col = {name: i for i, name in enumerate(FEATURES)}
    feats[:, col["L"]] = np.where(heavy, 95, 68) + rng.normal(0, 8, m)  # brightness and gloss differ ...
    feats[:, col["specular"]] = np.where(heavy, 140, 36) + rng.normal(0, 20, m)
    feats[:, col["a"]] = np.where(heavy, 127.45, 127.39) + rng.normal(0, 0.01, m)  # ... chroma hardly
    feats[:, col["b"]] = 129.8 + rng.normal(0, 0.02, m)
    classes = learn_classes(feats, height, 0.5, 15)
    assert classes.separation.cv_accuracy == 1.0
    later = feats[~heavy].copy()
    later[:, col["a"]] += 1.0  # a level of chroma from the compression of a later frame
    assert classes.p_heavy(later).max() < 0.5
    scaler = classes.model.steps[0][1]
    assert isinstance(scaler, ResolvedScaler)
    assert scaler.scale_[list(LEARNED).index(col["a"])] == RESOLUTION["a"] == 1.0


def test_a_run_that_ends_unmixed_shows_each_class_high_and_low():
    """Under a lamp above the cell the spheres are brighter the higher they sit, by as much as the
    two materials differ. From the first frame alone (heavy high, light low) brightness is learned as
    the material, and later heavy spheres low down are called light. The un-mixed last frame (heavy
    low, light high), labelled by where its spheres sit, shows both classes at both heights, and
    with each sphere's height the classes hold everywhere."""
    rng = np.random.default_rng(3)
    m = 120
    col = {name: i for i, name in enumerate(FEATURES)}

    def frame(heavy_high: bool):
        h = np.concatenate([rng.uniform(9, 14.5, m // 2), rng.uniform(0.5, 6, m // 2)])
        heavy = (h > 7.5) == heavy_high
        feats = np.zeros((m, len(FEATURES)))
        feats[:, col["L"]] = np.where(heavy, 110, 100) + 2.5 * h + rng.normal(0, 2, m)
        return feats, h, heavy

    first, last, later = frame(True), frame(False), frame(False)
    alone = learn_classes(first[0], first[1], 0.5, 15)
    assert not alone.uses_height and not alone.both_ends
    assert np.mean((alone.p_heavy(later[0], later[1]) > 0.5) != later[2]) > 0.3
    both = learn_classes(np.concatenate([first[0], last[0]]), np.concatenate([first[1], last[1]]), 0.5, 15,
                         labelled_by=np.concatenate([first[1], 15 - last[1]]))
    assert both.both_ends and both.uses_height
    assert np.mean((both.p_heavy(later[0], later[1]) > 0.5) != later[2]) < 0.02
    with pytest.raises(ValueError, match="heights"):
        both.p_heavy(later[0])


def test_the_light_over_the_view_is_taken_off_before_the_classes_read_the_features():
    """A lamp above the cell and vignetting: a sphere is brighter the higher it sits and the nearer
    the window's middle. In the first frame the heavy spheres all sit high, so classes learned from
    it alone take the lamp's fall-off for the material and call the heavy spheres of the bottom
    layers light. Told where each labelled sphere lies, the classes read the light's field off
    them (the step at the interface is the material, the smooth change within each class the
    light) and hold everywhere; without the places they cannot be used."""
    rng = np.random.default_rng(3)
    m = 120
    col = {name: i for i, name in enumerate(FEATURES)}

    def frame(heavy: np.ndarray, h: np.ndarray):
        u = rng.uniform(-1, 1, len(h))
        light = (1 + 0.03 * h) * (1 - 0.1 * u * u)  # what multiplies the grey levels
        feats = np.zeros((len(h), len(FEATURES)))
        feats[:, [col["a"], col["b"]]] = 128.0  # grey
        feats[:, col["L"]] = (np.where(heavy, 110, 100) + 40.8) * light ** (2.2 / 3) - 40.8 + rng.normal(0, 2, len(h))
        feats[:, col["specular"]] = 20 * light + rng.normal(0, 1, len(h))  # a faint sheen, as bright as the light
        return feats, h, u, heavy

    h0 = np.concatenate([rng.uniform(9, 14.5, m // 2), rng.uniform(0.5, 6, m // 2)])
    first = frame(h0 > 7.5, h0)
    h1 = rng.uniform(0.5, 14.5, m)
    later = frame(rng.random(m) < 0.5, h1)  # mixed: each class high and low
    alone = learn_classes(first[0], first[1], 0.5, 15)
    assert alone.field is None
    assert np.mean((alone.p_heavy(later[0], later[1]) > 0.5) != later[3]) > 0.2
    levelled = learn_classes(first[0], first[1], 0.5, 15, across=first[2])
    assert levelled.field is not None and not levelled.uses_height
    assert np.mean((levelled.p_heavy(later[0], later[1], later[2]) > 0.5) != later[3]) < 0.02
    # the field found is the lamp's and the vignetting's: 1.45 at the top's middle, 0.9 at the
    # bottom corners
    assert 1.45 / 0.9 - 0.15 < levelled.field.contrast() < 1.45 / 0.9 + 0.15
    with pytest.raises(ValueError, match="across"):
        levelled.p_heavy(later[0], later[1])
    with pytest.raises(ValueError, match="heights"):
        levelled.p_heavy(later[0])


def test_classes_far_apart_are_left_as_learned_under_a_faint_light_over_the_view():
    """Where the light moves the classes' score by a small share of the gap between them, the classes
    hold wherever a sphere lies: they are left as learned (no field), and the share is reported."""
    rng = np.random.default_rng(4)
    col = {name: i for i, name in enumerate(FEATURES)}
    h = np.concatenate([rng.uniform(9, 14.5, 60), rng.uniform(0.5, 6, 60)])
    u = rng.uniform(-1, 1, 120)
    feats = np.zeros((120, len(FEATURES)))
    feats[:, [col["a"], col["b"]]] = 128.0  # grey
    feats[:, col["L"]] = np.where(h > 7.5, 160, 80) + 0.5 * h + rng.normal(0, 3, 120)
    classes = learn_classes(feats, h, 0.5, 15, across=u)
    assert classes.field is None and classes.light_share < LIGHT_SHARE
    steep = feats.copy()
    steep[:, col["L"]] += 6.0 * h  # the same pair under a lamp above that brightens the top by 90 levels
    levelled = learn_classes(steep, h, 0.5, 15, across=u)
    assert levelled.field is not None and levelled.light_share >= LIGHT_SHARE


def test_a_lamp_above_fools_the_first_frame_until_its_light_or_the_last_frame_is_read(tmp_path, capsys,
                                                                                      monkeypatch):
    """Matte greys a fifth apart in brightness under a lamp above that darkens the bed's bottom by a
    quarter, in a run that ends un-mixed. Learned from the first frame's looks alone, 6 % of the
    spheres go to the wrong class (c_raw off by 0.12, 2-D tuning seed 7): the lamp's fall-off is
    learned as the material's. Two ways out, each within about the target: the light over the view
    read off the first frame and taken off (the default), and --ends-unmixed, which learns from the
    un-mixed last frame too and sees each class high and low (the light is then left on: taking it
    off as well cost on the tuning seeds)."""
    import granseg.measure.classify as classify

    r = render_scene("grey-matte-glossy", 6, end="unmixed", seed=7, out_dir=tmp_path / "frames",
                     heavy="pom-grey", light="pp-matte-grey", light_from_above=0.25)
    rmsd = {}
    for name, level, flag in (("looks alone", False, []), ("light taken off", True, []),
                              ("both ends", True, ["--ends-unmixed"])):
        monkeypatch.setattr(classify, "LEVEL_LIGHT", level)
        out = tmp_path / f"{name}.npz"
        main(["analyze", str(r.source), "--smooth", "1", "--out", str(out), "--no-progress", *flag])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", QualityWarning)  # the pair is flagged (ambiguous): judged here
            m = load_map(out)
        rmsd[name] = float(np.sqrt(np.nanmean((m.c_raw - r.c_raw) ** 2)))
        assert ("light_over_view" in json.loads(m.quality)["figures"]) == (name == "light taken off"), name
    said = capsys.readouterr().out
    assert said.count("classes learned from the first frame and from the last") == 1
    # light taken off: 0.040 on this seed (BENCHMARKS.md, "The light over the view taken off")
    assert rmsd["looks alone"] > 0.08 and rmsd["light taken off"] < 0.045 and rmsd["both ends"] < 0.04, rmsd
    with pytest.raises(ValueError, match="ends_unmixed"):
        analyze(r.source, save=False, progress=False, ends_unmixed="yes")


def _grey_spheres(rng, specks, d: int = 24, gloss: bool = True):
    """15 rows of 16 grey spheres of one shade; those above the middle glossy (the two lamps' images
    at the same places on each; with ``gloss`` False matte too), those below matte. ``specks``:
    (sphere, (dx, dy) [diameters]) of bright specks of dust on the wall. Returns the image,
    centres, heights [diameters], heavy."""
    step = d + 3
    img = np.full((15 * step + 20, 16 * step + 20), 40.0)
    yy, xx = np.mgrid[:img.shape[0], :img.shape[1]]
    rows, cols = np.divmod(np.arange(15 * 16), 16)
    centres = np.column_stack([12 + step * cols, img.shape[0] - 12 - step * rows]) + rng.uniform(-1, 1, (240, 2))
    heights = rows + 0.5
    heavy = heights > 7.5

    def speck(x, y, amplitude):
        img[:] += amplitude * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * 1.2 ** 2))

    for (x, y), glossy in zip(centres, heavy, strict=True):
        r2 = ((xx - x) ** 2 + (yy - y) ** 2) / (0.5 * d) ** 2
        img[r2 < 1] = 110 - 30 * r2[r2 < 1] + rng.normal(0, 2)
        if glossy and gloss:
            speck(x - 0.25 * d, y - 0.2 * d, 130)
            speck(x + 0.2 * d, y - 0.25 * d, 110)
    for i, (dx, dy) in specks:
        speck(centres[i, 0] + dx * d, centres[i, 1] + dy * d, 130)
    img += rng.normal(0, 2, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8), centres, heights, heavy


def test_a_speck_of_dust_lights_a_matte_spheres_brightest_point_but_not_the_learned_spots():
    """Grey glossy over grey matte: a bright speck on the wall over a matte sphere gives it a
    glossy sphere's sharpest highlight (the `specular` maximum) but not the glossy spheres'
    highlights where they show them. Two specks over the first frame's labelled matte spheres
    make the maxima the worse cue there, and the classes read gloss at the spots."""
    rng = np.random.default_rng(3)
    d = 24
    first, centres, heights, _ = _grey_spheres(rng, [(20, (0.1, 0.25)), (40, (-0.3, 0.05))], d)
    spots = learn_spots(first, centres, d, heights, 0.5, 15)
    assert spots is not None and np.isclose(np.abs(spots).sum(), 1.0)
    classes = learn_classes(sphere_features(first, centres, d, spots), heights, 0.5, 15,
                            rises=[disk_rises(first, centres, d)])
    assert classes.gloss_at_spots
    matte = np.flatnonzero(heights < 6.5)
    specked = rng.choice(matte, 12, replace=False)
    later, centres, heights, heavy = _grey_spheres(rng, list(zip(specked, rng.uniform(-0.3, 0.3, (12, 2)), strict=True)), d)
    feats = sphere_features(later, centres, d, spots)
    col = {name: i for i, name in enumerate(FEATURES)}
    clean = np.setdiff1d(np.flatnonzero(~heavy), specked)
    for name in ("specular", "highlight_at_spots"):
        glossy, plain, dusty = (np.median(feats[s, col[name]]) for s in (heavy, clean, specked))
        # where between matte (0) and glossy (1) a specked matte sphere reads, in the median
        where = (dusty - plain) / (glossy - plain)
        if name == "specular":
            assert where > 0.8, where  # the maximum takes the speck for a lamp's image
        else:
            assert where < 0.2, where  # the learned spots do not
            assert feats[specked, col[name]].max() < 0.5 * (glossy + plain)


def test_spot_weights_are_fitted_per_fold_so_noise_does_not_look_separable():
    """The spot weights are fitted to the first frame's labels. Fitted to all of them, 73 samples
    of pure noise make held-out spheres look about 70 % separable (two identical POMs in the
    README's example looked 71 % separable); fitted per cross-validation fold, as learn_classes
    fits them, the noise stays at about one half."""
    nested, leaky = [], []
    samples = disk_rises(np.zeros((40, 40), np.uint8), np.array([[20.0, 20.0]]), 24).shape[1]
    for seed in range(5):
        rng = np.random.default_rng(seed)
        height = rng.uniform(0.5, 14.5, 240)
        rises = rng.gamma(2.0, 3.0, (240, samples))
        feats = rng.normal(100.0, 5.0, (240, len(FEATURES)))
        label = interface_labels(height, 0.5, 15)
        feats[:, FEATURES.index("highlight_at_spots")] = rises @ spot_weights(rises, label)
        classes = learn_classes(feats, height, 0.5, 15, rises=[rises])
        nested.append(classes.separation.cv_accuracy)
        # the control: the same spot column, cross-validated without refitting its weights
        use = label >= 0
        leaky.append(_fit_classes([feats[use]], label[use], LEARNED_AT_SPOTS, 0)[2])
    assert np.mean(nested) < 0.6 < 0.65 < np.mean(leaky), (nested, leaky)


def test_each_frame_is_detected_once(tmp_path, monkeypatch):
    """The first frame's spheres, found while learning the templates and the spots, are the run's
    first row: no frame is searched twice."""
    import granseg.measure.pipeline as pipeline

    calls = []
    detect = pipeline.detect_particles
    monkeypatch.setattr(pipeline, "detect_particles", lambda *a, **k: calls.append(1) or detect(*a, **k))
    render_frames(stratified_map(4, 0.5), seed=4, out_dir=tmp_path, heavy="glass", light="pp", **SMALL)
    a = analyze(tmp_path, smooth=1, save=False, progress=False, workers=2)
    assert len(calls) == len(a.spheres) == 4


def test_detect_frames_finds_what_analyze_finds_without_describing_the_spheres(tmp_path, monkeypatch):
    """The velocity tracking's detection (detect_frames) places the same spheres as analyze, but
    measures no appearance and learns no spots: it never tells the kinds apart."""
    import granseg.measure.pipeline as pipeline

    render_frames(stratified_map(3, 0.5), seed=5, out_dir=tmp_path, heavy="steel", light="pp", **SMALL)
    a = analyze(tmp_path, smooth=1, save=False, progress=False, workers=1)
    described = []
    features = pipeline.sphere_features
    monkeypatch.setattr(pipeline, "sphere_features", lambda *a, **k: described.append(1) or features(*a, **k))
    monkeypatch.setattr(pipeline, "learn_spots", lambda *a, **k: pytest.fail("spots learned for velocity"))
    det = pipeline.detect_frames(tmp_path, workers=1, progress=False)
    assert described == []
    shift = abs(a.quality.figures["class_shift_px"])  # analyze takes the classes' relative shift off y
    for s, t in zip(a.spheres, det.spheres, strict=True):
        np.testing.assert_allclose(t.x, s.x, atol=1e-9)
        np.testing.assert_allclose(t.y, s.y, atol=shift + 1e-9)
        assert t.features.shape == (len(t.x), 0)


def test_polished_steel_over_pom_in_mpeg4_keeps_its_classes(tmp_path):
    """The same failure end to end: S-POM-25 written as MPEG-4 video. Before the resolution
    floor, 1-7 POM spheres a frame rising among the steel were called steel and the map was off
    by RMSD 0.093 with every check passing; the matte and the polished grey now stay apart."""
    from scipy.spatial import cKDTree

    r = render_scene("S-POM-25", 6, seed=9, out_dir=tmp_path, video="mp4v")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", QualityWarning)
        a = analyze(r.source, smooth=1, save=False, progress=False, workers=2)
    d = r.experiment["particle_diameter_px"]
    wrong = found = 0
    for truth, s in zip(r.particles, a.spheres, strict=True):
        dist, idx = cKDTree(truth[:, :2]).query(np.column_stack([s.x, s.y]))
        ok = dist <= 0.3 * d
        found += int(ok.sum())
        wrong += int((s.heavy[ok] != (truth[idx[ok], 3] > 0)).sum())
    assert wrong <= 0.002 * found, f"{wrong} of {found} spheres in the wrong class"
    assert np.sqrt(np.nanmean((a.c_raw - r.c_raw) ** 2)) <= 0.03


# --------------------------------------------------------------------------- a camera that adjusts itself


def test_cli_says_when_it_took_the_exposure_off(tmp_path, capsys):
    """The analyze report names the drift it took off, and says nothing of a steady camera."""
    drifting, steady = tmp_path / "drifting", tmp_path / "steady"
    render_frames(stratified_map(3, 0.5), seed=4, out_dir=drifting, exposure_drift=-0.4, **SMALL)
    render_frames(stratified_map(3, 0.5), seed=4, out_dir=steady, **SMALL)
    assert main(["analyze", str(drifting), "--no-progress", "--smooth", "1"]) == 0
    out = capsys.readouterr().out
    assert "camera exposure changed over the run: 0.6" in out and "to 1.00 times" in out
    assert main(["analyze", str(steady), "--no-progress", "--smooth", "1"]) == 0
    assert "camera exposure" not in capsys.readouterr().out


@pytest.mark.parametrize("drift", [0.0, -0.4, 0.4])
def test_learning_while_the_survey_runs_learns_what_learning_after_it_does(tmp_path, drift):
    """The run's fixed part does the exposure survey and the learning from the first frame at once
    (pipeline._FrameWorker.prepare). The first frame is the survey's reference, so the looks learned
    from it, its spheres and its record are those learned after the survey: steady, darkening
    (the frames matched, the first left as it is) and brightening (the first clipped too, so learned
    again)."""
    r = render_frames(stratified_map(4, 0.5), seed=6, out_dir=tmp_path, exposure_drift=drift, **SMALL)
    source, json_path = open_frames(r.source)
    exp = load_experiment(json_path)
    first = source.read(0)
    at_once = pipeline._FrameWorker(exp, first.shape[1::-1])
    at_once.prepare(source, 0, first, workers=2)
    after = pipeline._FrameWorker(exp, first.shape[1::-1])
    after.exposure = after.survey(source, 0, first, workers=2)
    after.learn(first)
    assert at_once.exposure == after.exposure
    assert after.exposure.drifting == (abs(drift) > DRIFT_LIMIT) and (after.exposure.clip < 255) == (drift > 0)
    for a, b in zip(at_once.templates.patches, after.templates.patches, strict=True):
        assert np.array_equal(a, b)
    one, other = at_once.first[0], after.first[0]
    assert np.array_equal(one.x, other.x) and np.array_equal(one.features, other.features)
    assert (one.gain, one.gain_taken_off) == (other.gain, other.gain_taken_off)
    assert np.array_equal(at_once.spots, after.spots) and np.array_equal(at_once.first[1], after.first[1])


@pytest.mark.parametrize("scene, seed, drift", [
    ("S-POM-25", 9, -0.25),
    ("S-POM-25", 9, -0.5),
    ("G-POM-50", 9, -0.4),
    # brightened by 60 %: light clipped at 255 cannot be given back, and the
    # glossy spheres' highlights flatten (c_raw RMSD 0.05, flagged by ambiguous_spheres)
    ("grey-matte-glossy", 23, 0.6),
])
def test_automatic_exposure_drift_is_held_or_flagged(tmp_path, scene, seed, drift):
    """A camera's automatic exposure changing the frames' brightness over the run. The bed's level
    measures the gain and every frame is brought back to the first's (measure.exposure): darkened
    even by half (matte POM then looked like the steel before) the map is right; brightened until
    the bright spheres clip, a wrong map must not pass as right."""
    r = render_scene(scene, 6, seed=seed, out_dir=tmp_path, exposure_drift=drift)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", QualityWarning)
        a = analyze(r.source, smooth=1, save=False, progress=False, workers=2)
    rmsd = float(np.sqrt(np.nanmean((a.c_raw - r.c_raw) ** 2)))
    low, high = a.quality.figures["exposure_gain_range"]
    assert (low, high) == pytest.approx((min(1, 1 + drift), max(1, 1 + drift)), abs=0.08)  # the drift is seen
    assert a.quality.figures["exposure_matched"] == (abs(drift) > DRIFT_LIMIT)  # ... and taken off beyond a fifth
    if drift < 0:
        assert a.quality.ok and rmsd <= 0.03, (rmsd, a.quality.report())
    assert rmsd <= 0.03 or not a.quality.ok, (rmsd, a.quality.report())
