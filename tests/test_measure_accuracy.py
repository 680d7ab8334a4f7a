"""Detection, classification and maps against the renderer's exact ground truth."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from granseg.measure import analyze
from granseg.synth import render_frames

N_T = 6


def _mixing_map(n_t: int = N_T) -> np.ndarray:
    """Heavy layer on top at t = 0, relaxing to a graded profile."""
    z = (np.arange(15) + 0.5) / 15
    t = np.linspace(0, 1, n_t)[:, None]
    return np.clip(np.where(z > 0.5, 1.0, 0.0) * (1 - t) + (0.5 + 0.4 * (0.5 - z)) * t, 0, 1)


LOOKS = {
    "ceramic-glass-left-jpeg": dict(heavy="ceramic", light="glass", lighting="left", jpeg_quality=60, noise=4),
    "steel-pp-two-sided": dict(heavy="steel", light="pp"),
    "glass-pp-front-strong-lens": dict(heavy="glass", light="pp", lighting="front",
                                       dist_coeffs=[-0.22, 0.06, 0, 0, 0], blur=1.2),
}
# Looks the detector does not yet handle to the numbers (see the
# report): strict xfail, so that a fix shows up as an unexpected pass.
HARD_LOOKS = {
    "glass-pom": dict(heavy="glass", light="pom"),
}
SMALL_LOOK = dict(heavy="steel", light="ceramic", lighting="diffuse", particle_diameter_px=20, image_size=(400, 480))


def _run(tmp_path, look, seed=7):
    r = render_frames(_mixing_map(), seed=seed, out_dir=tmp_path, **look)
    a = analyze(tmp_path, smooth=1, save=False, progress=False, workers=2)
    return r, a


def _check(r, a):
    """Recall, precision, c_raw RMSD; returns per-layer count error: |detected - true| summed over
    the frames, relative to the true count of that layer."""
    d = r.experiment["particle_diameter_px"]
    tp = fp = fn = 0
    for truth, s in zip(r.particles, a.spheres, strict=True):
        det = np.column_stack([s.x, s.y])
        dist, _ = cKDTree(truth[:, :2]).query(det)
        fp += int((dist > 0.3 * d).sum())
        tp += int((dist <= 0.3 * d).sum())
        inside = truth[truth[:, 4] > 0, :2]
        back, _ = cKDTree(det).query(inside)
        fn += int((back > 0.3 * d).sum())
    precision, recall = tp / (tp + fp), 1 - fn / r.n.sum()
    rmsd = float(np.sqrt(np.nanmean((a.c_raw - r.c_raw) ** 2)))
    count_error = np.abs(a.n.sum(axis=0) - r.n.sum(axis=0)) / r.n.sum(axis=0)
    assert recall >= 0.98, f"recall {recall:.3f}"
    assert precision >= 0.98, f"precision {precision:.3f}"
    assert rmsd <= 0.03, f"c_raw RMSD {rmsd:.3f}"
    return count_error


@pytest.mark.parametrize("seed", [7, 8])  # two packings, so the detector is not tuned to one
@pytest.mark.parametrize("look", list(LOOKS), ids=list(LOOKS))
def test_map_matches_ground_truth(tmp_path, look, seed):
    r, a = _run(tmp_path, LOOKS[look], seed)
    _check(r, a)
    # heavy labelled by the first frame: top layers heavy at t = 0
    assert np.nanmean(a.c_raw[0, 10:]) > 0.9 and np.nanmean(a.c_raw[0, :6]) < 0.1


@pytest.mark.parametrize("seed", [7, 8])
def test_small_spheres_steel_ceramic(tmp_path, seed):
    r, a = _run(tmp_path, SMALL_LOOK, seed)
    _check(r, a)


@pytest.mark.xfail(strict=True, reason="measured (seed 7, every fast look): worst layer off by 7.7 % on "
                   "ceramic-glass (layer 9: one static ceramic sphere 0.12-0.16 px below the boundary fitted "
                   "0.39-0.47 px high in 4 of 6 frames: lighting bias of ceramic centres, 0.17 px up under the "
                   "left lamp, not scatter), steel-pp 1.8 %, glass-pp 1.9 %, steel-ceramic-small 1.9 %; issue 3 open")
def test_layer_counts_within_3_percent(tmp_path):
    looks = {**LOOKS, "steel-ceramic-diffuse-small": SMALL_LOOK}
    worst = {}
    for name, look in looks.items():
        r, a = _run(tmp_path / name, look)
        worst[name] = float(_check(r, a).max())
    assert max(worst.values()) <= 0.03, f"per-layer count error {worst}"


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="measured (seed 7): recall 0.995, precision 0.998, c_raw RMSD "
                   "0.037 > 0.03: dark POM centres 0.23 px high, scatter 0.3 px (POM's outline barely differs "
                   "from the gaps and its shadowed lower edge is found inside; one POM sphere missed in 3 "
                   "frames; issue 3 open)")
@pytest.mark.parametrize("look", list(HARD_LOOKS), ids=list(HARD_LOOKS))
def test_hard_looks(tmp_path, look):
    r, a = _run(tmp_path, HARD_LOOKS[look])
    _check(r, a)


@pytest.mark.parametrize("ranges, inverted", [
    ({"heavy_hsv": [[0, 0, 120], [179, 70, 255]]}, False),  # white ceramic = heavy
    ({"light_hsv": [[0, 0, 120], [179, 70, 255]]}, True),  # white declared light: map inverts
])
def test_colour_ranges_override_learning(tmp_path, ranges, inverted):
    r = render_frames(_mixing_map(2), seed=8, out_dir=tmp_path, heavy="ceramic", light="pp",
                      particle_diameter_px=20, image_size=(400, 480), experiment=ranges)
    a = analyze(tmp_path, smooth=1, save=False, progress=False)
    expected = 1 - r.c_raw if inverted else r.c_raw
    assert np.sqrt(np.nanmean((a.c_raw - expected) ** 2)) < 0.05
