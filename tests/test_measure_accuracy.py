"""Detection, classification and maps against the renderer's exact ground truth."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from granseg.errors import QualityWarning
from granseg.measure import analyze
from granseg.measure.layers import WALL_CLEARANCE
from granseg.synth import APPARATUS_SCENES, MIXTURE_SCENES, SCENES, mixing_map, render_frames
from granseg.synth.scenes import render_scene

N_T = 6  # frames per run


def _run(tmp_path, look, seed=7):
    r = render_frames(mixing_map(N_T), seed=seed, out_dir=tmp_path, **look)
    a = analyze(tmp_path, smooth=1, save=False, progress=False, workers=2)
    return r, a


def _check(r, a):
    """Recall, precision, c_raw RMSD and centre accuracy per material against the ground truth."""
    d = r.experiment["particle_diameter_px"]
    tp = fp = fn = 0
    errors = {0: [], 1: []}  # centre error [px] of the matched spheres, by material (1 = heavy)
    for truth, s in zip(r.particles, a.spheres, strict=True):
        det = np.column_stack([s.x, s.y])
        dist, idx = cKDTree(truth[:, :2]).query(det)
        fp += int((dist > 0.3 * d).sum())
        tp += int((dist <= 0.3 * d).sum())
        for heavy in (0, 1):
            match = (dist <= 0.3 * d) & (truth[idx, 3] == heavy)
            errors[heavy].append(det[match] - truth[idx[match], :2])
        inside = truth[truth[:, 4] > 0, :2]
        back, _ = cKDTree(det).query(inside)
        fn += int((back > 0.3 * d).sum())
    precision, recall = tp / (tp + fp), 1 - fn / r.n.sum()
    rmsd = float(np.sqrt(np.nanmean((a.c_raw - r.c_raw) ** 2)))
    assert recall >= 0.98, f"recall {recall:.3f}"
    assert precision >= 0.98, f"precision {precision:.3f}"
    assert rmsd <= 0.03, f"c_raw RMSD {rmsd:.3f}"
    # "refine centres to within about 1 px": 95 % of centres within 1 px, and
    # no material displaced as a whole by more than half a pixel
    for heavy, errs in errors.items():
        e = np.concatenate(errs)
        p95 = float(np.percentile(np.hypot(*e.T), 95))
        bias = float(np.hypot(*e.mean(axis=0)))
        assert p95 <= 1.0 and bias <= 0.5, f"{'heavy' if heavy else 'light'} centres: p95 {p95:.2f} px, bias {bias:.2f} px"


@pytest.mark.parametrize("seed", [7, 8])  # two packings, so the detector is not tuned to one
@pytest.mark.parametrize("look", list(SCENES), ids=list(SCENES))
def test_map_matches_ground_truth(tmp_path, look, seed):
    r, a = _run(tmp_path, SCENES[look], seed)
    _check(r, a)
    # heavy labelled by the first frame: top layers heavy at t = 0
    assert np.nanmean(a.c_raw[0, 10:]) > 0.9 and np.nanmean(a.c_raw[0, :6]) < 0.1


def test_layer_counts_within_3_percent(tmp_path):
    """Per-layer sphere counts within 3 %, pooled over four independent packings per scene.

    Why pooled: in these frames a layer holds about ten spheres and the upper
    half of the bed barely moves between frames, so a single static sphere
    whose centre lies within the lighting bias of a layer boundary (centres
    are displaced 0.1-0.4 px towards or away from the lamps, depending on the
    material) changes its layer's count summed over one run by 1.7 % for each
    frame; on single packings the worst layer is off by 0-9.3 % (seeds 7-14,
    BENCHMARKS.md), set by where spheres happen to sit. Over four packings a
    layer holds about 240 spheres: what still shows is systematic (spheres
    missed or doubled in some layers, a bias that moves whole rows).
    """
    worst = {}
    for name, look in SCENES.items():
        detected = true = 0
        for seed in (7, 8, 9, 10):
            r, a = _run(tmp_path / f"{name}-{seed}", look, seed)
            detected, true = detected + a.n.sum(axis=0), true + r.n.sum(axis=0)
        worst[name] = round(float((np.abs(detected - true) / true).max()), 4)
    assert max(worst.values()) <= 0.03, f"per-layer count error {worst}"


@pytest.mark.parametrize("ranges, inverted", [
    ({"heavy_hsv": [[0, 0, 120], [179, 70, 255]]}, False),  # white ceramic = heavy
    ({"light_hsv": [[0, 0, 120], [179, 70, 255]]}, True),  # white declared light: map inverts
])
def test_colour_ranges_override_learning(tmp_path, ranges, inverted):
    r = render_frames(mixing_map(2), seed=8, out_dir=tmp_path, heavy="ceramic", light="pp",
                      particle_diameter_px=20, image_size=(400, 480), experiment=ranges)
    if inverted:  # the ranges are obeyed, and the quality checks see the first frame upside down
        with pytest.warns(QualityWarning, match="first_frame_order"):
            a = analyze(tmp_path, smooth=1, save=False, progress=False)
        assert [c.name for c in a.quality.failed] == ["first_frame_order"]
    else:
        a = analyze(tmp_path, smooth=1, save=False, progress=False)
        assert a.quality.ok
    expected = 1 - r.c_raw if inverted else r.c_raw
    assert np.sqrt(np.nanmean((a.c_raw - expected) ** 2)) < 0.05


# The paper's six mixtures, the two pairs of its five materials that SCENES
# lacks, grey-on-grey pairs and the apparatus looks (bumpy
# lid and plate, motion blur, lamp reflections, dust, wide-angle lens, JPEG
# and lossy video). The detector was tuned on seeds 7 and 8; seed 9 is held
# out (BENCHMARKS.md reports seeds 9-12). Targets of issue 9: c_raw RMSD <=
# 0.03 and, per frame and layer, mean |n - n_true| / n_true <= 3 %.
NOT_YET = {
    # spheres hanging under the lid's bumps sit exactly on a layer boundary
    # (14.00 d) and MPEG-4 blurs the polished steel's outline by a few tenths
    # of a pixel either way (seeds 9-12: c_raw RMSD 0.007-0.032, per-frame
    # layer counts 2.8-6.1 %)
    "apparatus-S-POM-25-mp4v": "spheres on a layer boundary under the lid's bumps, MPEG-4",
}
# Runs whose seed 9 sits within a thousandth of the target, on one side on one machine and
# on the other side on another: OpenCV picks its kernels by the CPU, and both the renderer's
# frames and the detector's figures move with them (BENCHMARKS.md, "The same tree on another
# machine"). Reported, not asserted: XFAIL where it misses, XPASS where it meets the target.
AT_THE_EDGE = {
    # the same lid's-bumps boundary as above (its worst layer is the top one), in JPEG:
    # c_raw RMSD 0.0291 on one machine, 0.0304 on another (AMD EPYC, AVX2; seeds 10-12
    # there: 0.006-0.025)
    "apparatus-S-PP-75-jpeg": "spheres on a layer boundary under the lid's bumps: c_raw 0.029-0.030 by machine",
}


def _expectation(name: str):
    if name in NOT_YET:
        return pytest.param(name, marks=pytest.mark.xfail(strict=True, reason=NOT_YET[name]))
    if name in AT_THE_EDGE:
        return pytest.param(name, marks=pytest.mark.xfail(strict=False, reason=AT_THE_EDGE[name]))
    return name


@pytest.mark.parametrize("name", [_expectation(n) for n in [*MIXTURE_SCENES, *APPARATUS_SCENES]])
def test_mixtures_and_apparatus_looks(tmp_path, name):
    if "h264" in name:
        pytest.importorskip("av", reason="H.264 footage needs PyAV (the test extra installs it)")
    r = render_scene(name, N_T, seed=9, out_dir=tmp_path)
    a = analyze(r.source, smooth=1, save=False, progress=False, workers=2)
    assert a.quality.ok, a.quality.report()
    rmsd = float(np.sqrt(np.nanmean((a.c_raw - r.c_raw) ** 2)))
    count = float(np.mean(np.abs(a.n - r.n)[r.n > 0] / r.n[r.n > 0]))
    assert rmsd <= 0.03 and count <= 0.03, f"c_raw RMSD {rmsd:.3f}, per-frame layer count error {count:.3f}"


def test_hemispheres_of_lid_and_plate_are_not_counted(tmp_path):
    """The bumps are seen and left out: no sphere counted on a wall line, the wall layers' counts right."""
    r = render_scene("bumps-S-PP", N_T, seed=9, out_dir=tmp_path)
    a = analyze(r.source, smooth=1, save=False, progress=False, workers=2)
    d = r.experiment["particle_diameter_px"]
    _, y0, _, y1 = r.experiment["window"]
    assert a.quality.figures["wall_detections_per_frame"] >= 1.0  # the bumps were found ...
    for s in a.spheres:  # ... and none was counted
        assert np.all((s.y - y0 >= WALL_CLEARANCE * d) & (y1 - s.y >= WALL_CLEARANCE * d))
    for j in (0, 14):  # the layers against the plate and the lid: right within a sphere in every frame
        assert np.abs(a.n[:, j] - r.n[:, j]).max() <= 1, (j, a.n[:, j], r.n[:, j])


def test_a_light_band_thinner_than_a_diameter_sets_no_polarity(tmp_path):
    """C-PP-90 (c0 = 0.93) with the plate's motion blur, seed 22: the first frame's light band was
    7 px of rows by the plate, and the 3 gaps between smeared spheres it held made a polarity of
    their own; the ceramic template learned from their matches put every sphere a third of a
    diameter off (per-frame layer counts 19 % off, flagged by centres_settled). Such a band now
    learns nothing, and one polarity serves the frame."""
    r = render_scene("C-PP-90", N_T, seed=22, out_dir=tmp_path, smear_diameters=0.47)
    a = analyze(r.source, smooth=1, save=False, progress=False, workers=2)
    assert a.quality.ok, a.quality.report()
    rmsd = float(np.sqrt(np.nanmean((a.c_raw - r.c_raw) ** 2)))
    count = float(np.mean(np.abs(a.n - r.n)[r.n > 0] / r.n[r.n > 0]))
    assert rmsd <= 0.03 and count <= 0.03, f"c_raw RMSD {rmsd:.3f}, per-frame layer count error {count:.3f}"
