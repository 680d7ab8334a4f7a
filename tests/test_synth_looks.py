"""The renderer's wider looks: grey-on-grey materials, the bumpy lid and plate, motion blur,
wall reflections and dust, lossy video, and the named mixture and apparatus scenes."""

from __future__ import annotations

import importlib.util
import json

import cv2
import numpy as np
import pytest

from granseg.measure.sources import open_frames
from granseg.synth import (
    APPARATUS_SCENES,
    MATERIAL_LOOKS,
    MIXTURE_SCENES,
    SCENES,
    mixing_map,
    render_frames,
    render_scene,
)
from granseg.synth.frames import _smear

SMALL = dict(particle_diameter_px=20, image_size=(400, 480))
FLAT = dict(dist_coeffs=[0, 0, 0, 0, 0], noise=0, blur=0, vignetting=0)  # image px = undistorted px
HAVE_AV = importlib.util.find_spec("av") is not None


def _consistent(r) -> None:
    """The truth lists exactly the counted spheres, per frame and layer."""
    for p, n, nh in zip(r.particles, r.n, r.n_heavy, strict=True):
        inside = p[:, 4] > 0
        assert inside.sum() == n.sum() and p[inside, 3].sum() == nh.sum()


# --------------------------------------------------------------------------- bumps


def test_bumps_sit_on_the_walls_move_with_the_plate_and_are_not_counted():
    d, shift = 20.0, 7.0
    r = render_frames(mixing_map(3), bumps=True, bottom_shift_px=shift, seed=1, **SMALL, **FLAT)
    x0, y0, x1, y1 = r.experiment["window"]
    _consistent(r)
    for b, p in zip(r.bumps, r.particles, strict=True):
        assert b.shape[1] == 4 and len(b) >= 4
        assert np.all(np.where(b[:, 3] > 0, b[:, 1] == y1, b[:, 1] == y0))  # centres on the walls' surfaces
        assert np.all(b[:, 2] == d) and {0.0, 1.0} <= set(b[:, 3])
        # no grain overlaps a bump (they pack around them), so none can be one
        gap = np.hypot(p[:, None, 0] - b[None, :, 0], p[:, None, 1] - b[None, :, 1])
        assert np.all(gap >= (p[:, None, 2] + b[None, :, 2]) / 2 - 0.03 * d)
    # the lid's bumps stay, the plate's move by the bottom shift
    lid = [b[b[:, 3] == 0, 0] for b in r.bumps]
    assert np.array_equal(lid[0], lid[1])
    plate = [np.sort(b[b[:, 3] > 0, 0]) for b in r.bumps]
    moved = plate[1][:, None] - plate[0][None, :]
    assert np.sum(np.isclose(moved, shift)) >= len(plate[0]) - 1
    # each drawn as a half-sphere on the bed's side: grey PLA, brighter than the gaps
    img = r.images[0].astype(float).mean(axis=2)
    for x, y, _, on_plate in r.bumps[0]:
        if x0 + d < x < x1 - d:
            inside = img[int(round(y - 0.2 * d)) if on_plate else int(round(y + 0.2 * d)), int(round(x))]
            assert inside > 40


def test_bump_spacing_follows_the_setting():
    r = render_frames(mixing_map(1), bumps=True, bump_spacing=2.0, seed=2, **SMALL)
    lid = np.sort(r.bumps[0][r.bumps[0][:, 3] == 0, 0])
    spacing = np.diff(lid) / 20
    assert spacing.min() >= 1.4 - 1e-9 and spacing.max() <= 2.6 + 1e-9


# --------------------------------------------------------------------------- motion blur


def test_smear_moves_along_x_only_by_its_length():
    """A sprite smeared by L is the sprite (constant over each pixel) averaged over a move of L along x."""
    s, w, r = 24, 60, 10.0
    yy, xx = np.mgrid[0:s, 0:w].astype(float)
    alpha = np.clip(r - np.hypot(xx - 29.3, yy - 11.6) + 0.5, 0, 1).astype(np.float32)[None]
    colour = np.ones((1, s, w, 3), np.float32)
    for length in (0.6, 7.0, 12.5):
        _, smeared = _smear(colour, alpha, np.array([length]))
        # the move [-L/2, L/2] covers pixel j (spanning j - 1/2 .. j + 1/2) for this share of the exposure
        j = np.arange(-10, 11)
        kernel = np.clip(np.minimum(j + 0.5, length / 2) - np.maximum(j - 0.5, -length / 2), 0, None) / length
        expected = np.stack([np.convolve(row, kernel, mode="same") for row in alpha[0]])
        assert np.allclose(smeared[0], expected, atol=1e-5)
        assert smeared[0].sum() == pytest.approx(alpha.sum(), rel=1e-5)
        assert (smeared[0] * xx).sum() / smeared[0].sum() == pytest.approx((alpha[0] * xx).sum() / alpha.sum())
        assert np.allclose(smeared[0].sum(axis=1), alpha[0].sum(axis=1), atol=1e-4)  # nothing moves along y
    # no smear: the sprite unchanged
    _, same = _smear(colour, alpha, np.array([0.0]))
    assert np.allclose(same, alpha, atol=1e-5)


def test_motion_blur_smears_the_fast_bottom_rows_not_the_top_nor_the_truth():
    sharp = render_frames(mixing_map(1), seed=3, **SMALL, **FLAT)
    blurred = render_frames(mixing_map(1), seed=3, smear_diameters=1.0, **SMALL, **FLAT)
    assert np.array_equal(sharp.particles[0], blurred.particles[0])  # centres: mid-exposure
    x0, y0, x1, y1 = (int(v) for v in sharp.experiment["window"])
    a, b = sharp.images[0].astype(float), blurred.images[0].astype(float)
    top, bottom = slice(y0 + 5, y0 + 60), slice(y1 - 40, y1 - 5)  # under the lid / next to the plate
    assert np.abs(a[top, x0:x1] - b[top, x0:x1]).mean() < 0.5
    assert np.abs(a[bottom, x0:x1] - b[bottom, x0:x1]).mean() > 5
    # horizontal smearing keeps each row's light, it moves it along the row only
    rows_a, rows_b = a[bottom, x0:x1].mean(axis=(1, 2)), b[bottom, x0:x1].mean(axis=(1, 2))
    cols_a, cols_b = a[bottom, x0:x1].mean(axis=(0, 2)), b[bottom, x0:x1].mean(axis=(0, 2))
    assert np.abs(rows_a - rows_b).mean() < 0.25 * np.abs(cols_a - cols_b).mean()


# --------------------------------------------------------------------------- wall, video


def test_reflections_and_dust_are_static_and_leave_the_truth_alone():
    plain = render_frames(mixing_map(2), seed=4, **SMALL, **FLAT)
    marked = render_frames(mixing_map(2), seed=4, wall_reflections=1.0, dust=40, **SMALL, **FLAT)
    for p, q in zip(plain.particles, marked.particles, strict=True):
        assert np.array_equal(p, q)
    diff = [m.astype(float) - p.astype(float) for m, p in zip(marked.images, plain.images, strict=True)]
    # the reflections brighten whole columns, top to bottom (the lid is static, so compare there)
    y0 = int(plain.experiment["window"][1])
    lid = [dd[5:y0 - 5].mean(axis=(0, 2)) for dd in diff]
    assert lid[0].max() > 20 and np.allclose(lid[0], lid[1], atol=1e-6)
    assert (np.abs(diff[0]) > 1).mean() > 0.05


def test_mp4v_video_is_written_with_experiment_json_and_opens_as_a_frame_source(tmp_path):
    lossless = render_frames(mixing_map(3), seed=5, **SMALL)
    r = render_frames(mixing_map(3), seed=5, video="mp4v", out_dir=tmp_path, **SMALL)
    video, meta = r.paths
    assert r.source == video == tmp_path / "video.mp4" and meta == tmp_path / "experiment.json"
    assert json.loads(meta.read_text())["fps"] == r.experiment["fps"]
    cap = cv2.VideoCapture(str(video))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 3
    frames = []
    while True:
        ok, img = cap.read()
        if not ok:
            break
        frames.append(img)
    cap.release()
    assert len(frames) == 3 and all(np.array_equal(f, g) for f, g in zip(frames, r.images, strict=True))
    assert frames[0].shape == (480, 400, 3)
    # lossy: the frames differ from the lossless render, the truth does not
    assert all(np.array_equal(p, q) for p, q in zip(lossless.particles, r.particles, strict=True))
    psnr = cv2.PSNR(lossless.images[1], r.images[1])
    assert 25 < psnr < 45
    source, experiment = open_frames(r.source)
    assert experiment == meta and len(source) == 3


@pytest.mark.skipif(not HAVE_AV, reason="H.264 needs PyAV (pip install av)")
def test_h264_video_without_out_dir_returns_decoded_frames():
    lossless = render_frames(mixing_map(2), seed=6, **SMALL)
    r = render_frames(mixing_map(2), seed=6, video="h264", **SMALL)
    assert r.paths == [] and r.source is None and len(r.images) == 2
    assert 25 < cv2.PSNR(lossless.images[1], r.images[1]) < 45


@pytest.mark.skipif(HAVE_AV, reason="PyAV is installed")
def test_h264_without_pyav_says_what_to_install():
    with pytest.raises(ImportError, match="pip install av"):
        render_frames(mixing_map(1), video="h264", **SMALL)


# --------------------------------------------------------------------------- materials, scenes


def test_grey_pairs_differ_in_gloss_not_in_mean_brightness_or_hue():
    """pom-grey and pp-grey: mean brightness within 5 %, no hue, but the glossy one has highlights."""
    c = np.zeros((1, 15))
    c[0, 7:] = 1
    r = render_frames(c, heavy="pom-grey", light="pp-grey", seed=2, particle_diameter_px=30,
                      image_size=(480, 600), **FLAT)
    img = r.images[0].astype(float)
    hsv = cv2.cvtColor(r.images[0], cv2.COLOR_BGR2HSV)
    yy, xx = np.mgrid[0:img.shape[0], 0:img.shape[1]]
    grey = img.mean(axis=2)
    disk = {0: [], 1: []}
    for x, y, d, heavy, inside in r.particles[0]:
        if inside:
            disk[int(heavy)].append((xx - x) ** 2 + (yy - y) ** 2 < (0.4 * d) ** 2)
    pix = {k: np.any(v, axis=0) for k, v in disk.items()}
    mean = {k: grey[m].mean() for k, m in pix.items()}
    assert abs(mean[0] - mean[1]) < 0.05 * mean[1]
    assert hsv[..., 1][pix[0] | pix[1]].mean() < 15  # grey: hardly any saturation
    bright = {k: np.percentile(grey[m], 99.5) for k, m in pix.items()}
    assert bright[0] > bright[1] + 40  # the glossy PP's highlights


def test_a_grey_pair_can_differ_in_brightness_only():
    """pom-grey and pp-matte-grey: the same matte finish, no hue, the second about a fifth darker."""
    c = np.zeros((1, 15))
    c[0, 7:] = 1
    r = render_frames(c, heavy="pom-grey", light="pp-matte-grey", seed=2, particle_diameter_px=30,
                      image_size=(480, 600), **FLAT)
    grey = r.images[0].astype(float).mean(axis=2)
    yy, xx = np.mgrid[0:grey.shape[0], 0:grey.shape[1]]
    pix = {k: np.any([(xx - x) ** 2 + (yy - y) ** 2 < (0.4 * d) ** 2 for x, y, d, heavy, inside in r.particles[0]
                      if inside and int(heavy) == k], axis=0) for k in (0, 1)}
    assert 0.7 < grey[pix[0]].mean() / grey[pix[1]].mean() < 0.9
    bright = {k: np.percentile(grey[m], 99.5) - np.median(grey[m]) for k, m in pix.items()}
    assert abs(bright[0] - bright[1]) < 0.2 * bright[1] + 5  # alike in gloss


def test_polished_steel_is_a_mirror_darker_than_satin_steel():
    c = np.ones((1, 15))
    looks = {}
    for name in ("steel", "steel-polished"):
        r = render_frames(c, heavy=name, light="pom", seed=3, **SMALL, **FLAT)
        looks[name] = r.images[0].astype(float).mean(axis=2)
    assert looks["steel-polished"].mean() < 0.8 * looks["steel"].mean()
    assert np.percentile(looks["steel-polished"], 99.9) > 230  # sharp images of the lamps


def test_every_paper_mixture_and_two_grey_pairs_are_named():
    pairs = {(s["heavy"].split("-")[0], s["light"].split("-")[0]) for s in MIXTURE_SCENES.values()}
    for pair in [("steel", "pp"), ("steel", "pom"), ("ceramic", "pp"), ("glass", "pp"), ("pom", "pp"),
                 ("glass", "pom")]:
        assert pair in pairs
    grey = [n for n, s in MIXTURE_SCENES.items()
            if {s["heavy"], s["light"]} <= {"steel", "steel-polished", "pom", "pom-grey", "pp-grey"}]
    assert len(grey) >= 2
    assert all(MATERIAL_LOOKS[s[k]] for s in [*MIXTURE_SCENES.values(), *APPARATUS_SCENES.values()]
               for k in ("heavy", "light"))
    assert not set(SCENES) & (set(MIXTURE_SCENES) | set(APPARATUS_SCENES))


@pytest.mark.parametrize("name", [*MIXTURE_SCENES, *APPARATUS_SCENES])
def test_each_new_scene_renders_with_consistent_truth(name):
    look = {**MIXTURE_SCENES, **APPARATUS_SCENES}[name]
    if look.get("video") == "h264" and not HAVE_AV:
        pytest.skip("H.264 needs PyAV (pip install av)")
    r = render_scene(name, n_t=2, seed=9, **SMALL)
    _consistent(r)
    assert len(r.images) == 2 and r.images[0].shape == (480, 400, 3) and r.images[0].std() > 10
    c = mixing_map(2, c0=look.get("c0", 0.5))
    assert np.all(np.abs(r.n_heavy - c * r.n) <= 0.5 + 1e-9)
    assert r.n.min() >= 4
    assert all(len(b) > 0 for b in r.bumps) == bool(look.get("bumps"))
    if "experiment" in look:
        assert r.experiment["name"] == look["experiment"]["name"]
    assert r.experiment["rho_h"] > r.experiment["rho_l"]


def test_mixing_map_starts_stratified_at_c0_and_keeps_its_mean():
    for c0 in (0.1, 0.25, 0.5, 0.9):
        m = mixing_map(5, c0=c0)
        z = (np.arange(15) + 0.5) / 15
        assert np.array_equal(m[0], (z > 1 - c0).astype(float))
        assert m[-1].mean() == pytest.approx(c0, abs=1e-9)
    with pytest.raises(ValueError, match="c0"):
        mixing_map(3, c0=1.0)


def test_bad_apparatus_arguments_are_named():
    c = mixing_map(1)
    with pytest.raises(ValueError, match="smear_diameters"):
        render_frames(c, smear_diameters=-1)
    with pytest.raises(ValueError, match="dust"):
        render_frames(c, dust=2.5)
    with pytest.raises(ValueError, match="video"):
        render_frames(c, video="avi")
    with pytest.raises(ValueError, match="bump_spacing"):
        render_frames(c, bumps=True, bump_spacing=1.0)
    with pytest.raises(ValueError, match="unknown scene"):
        render_scene("no-such-scene")
