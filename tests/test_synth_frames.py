"""The frame renderer: ground truth follows the requested map, looks are as asked."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from granseg.synth import render_frames


def _map(n_t: int = 3) -> np.ndarray:
    c = np.zeros((n_t, 15))
    c[:, 8:] = 1.0
    c[1:] = np.linspace(0.9, 0.1, 15)
    return c


def test_counts_follow_the_map_to_one_sphere_per_layer():
    r = render_frames(_map(), particle_diameter_px=20, image_size=(400, 480), seed=1)
    assert r.n.shape == (3, 15) and r.n.min() >= 6
    assert np.all(np.abs(r.n_heavy - _map() * r.n) <= 0.5 + 1e-9)
    assert np.array_equal(r.c_raw[0] > 0.5, np.arange(15) >= 8)


def test_truth_lists_the_spheres_counted():
    r = render_frames(_map(2), particle_diameter_px=20, image_size=(400, 480), seed=2)
    for i, p in enumerate(r.particles):
        inside = p[:, 4] > 0
        assert inside.sum() == r.n[i].sum()
        assert p[inside, 3].sum() == r.n_heavy[i].sum()


def test_bottom_rows_move_and_top_rows_stay():
    r = render_frames(_map(2), particle_diameter_px=20, image_size=(400, 480), seed=3, bottom_shift_px=8)
    a, b = r.particles
    y1 = r.experiment["window"][3]
    # under the lid (top 1.5 d) spheres barely move (< 1/20 of the bottom's 8 px)
    top_a, top_b = a[a[:, 1] < y1 - 270, :2], b[b[:, 1] < y1 - 270, :2]
    assert len(top_a) > 10
    dist, _ = cKDTree(top_b).query(top_a)
    assert np.median(dist) < 0.4 and dist.max() < 1.0
    # next to the bottom plate spheres moved by about bottom_shift_px
    bottom_a, bottom_b = a[a[:, 1] > y1 - 12, :2], b[b[:, 1] > y1 - 12, :2]
    dist, _ = cKDTree(bottom_b).query(bottom_a)
    assert np.median(dist) > 4


def test_packing_is_dense_random_and_free_of_overlaps():
    """Not a crystal: centres spread over the heights inside each layer; no pair overlaps by > 2 % d."""
    r = render_frames(_map(3), particle_diameter_px=20, image_size=(400, 480), seed=6)
    y1 = r.experiment["window"][3]
    for p in r.particles:
        dist, _ = cKDTree(p[:, :2]).query(p[:, :2], k=2)
        assert dist[:, 1].min() > 0.98 * p[:, 2].min() - 0.02 * 20
    inside = np.concatenate([p[p[:, 4] > 0] for p in r.particles])
    frac = ((y1 - inside[:, 1]) / 20) % 1
    hist, _ = np.histogram(frac[inside[:, 1] < y1 - 40], bins=5, range=(0, 1))
    assert hist.min() > 0.5 * hist.mean()  # away from the plate, no height is preferred
    n_area = len(inside) / len(r.particles) / (9 * 15)
    assert 0.95 < n_area < 1.1  # spheres per d^2: dense (hexagonal 1.15)


@pytest.mark.parametrize("material", ["steel", "ceramic", "glass", "pom", "pp", "steel-polished", "pom-grey", "pp-grey",
                                      "pp-matte-grey"])
def test_each_material_draws_distinct_spheres(material):
    c = np.ones((1, 15))
    r = render_frames(c, heavy=material, light="pp" if material != "pp" else "pom",
                      particle_diameter_px=20, image_size=(400, 480), noise=0, seed=4)
    img = r.images[0].astype(float)
    assert img.std() > 10  # spheres, gaps and highlights, not a flat image


def test_jpeg_and_noise_change_pixels_but_not_truth():
    clean = render_frames(_map(1), particle_diameter_px=20, image_size=(400, 480), noise=0, seed=5)
    dirty = render_frames(_map(1), particle_diameter_px=20, image_size=(400, 480), noise=5,
                          jpeg_quality=50, seed=5)
    assert np.array_equal(clean.particles[0], dirty.particles[0])
    assert np.abs(clean.images[0].astype(int) - dirty.images[0].astype(int)).mean() > 2


def test_exposure_drift_ramps_the_gain_over_the_run():
    steady = render_frames(_map(3), particle_diameter_px=20, image_size=(400, 480), noise=0, seed=5)
    darker = render_frames(_map(3), particle_diameter_px=20, image_size=(400, 480), noise=0, seed=5,
                           exposure_drift=-0.5)
    ratio = [float(b.astype(float).mean() / a.astype(float).mean()) for a, b in
             zip(steady.images, darker.images, strict=True)]
    assert ratio[0] == pytest.approx(1.0, abs=0.01)
    assert ratio[1] == pytest.approx(0.75, abs=0.03) and ratio[2] == pytest.approx(0.5, abs=0.03)
    assert all(np.array_equal(a, b) for a, b in zip(steady.particles, darker.particles, strict=True))
    with pytest.raises(ValueError, match="exposure_drift"):
        render_frames(_map(1), exposure_drift=-1.0)


def test_a_lamp_above_darkens_the_frame_down_its_height():
    """light_from_above = 0.4: the top rows keep their light, the bottom rows get about 60 % of it
    (the canvas extends a little past the image), and the spheres stay where they were."""
    level = render_frames(_map(1), particle_diameter_px=20, image_size=(400, 480), noise=0, seed=5)
    above = render_frames(_map(1), particle_diameter_px=20, image_size=(400, 480), noise=0, seed=5,
                          light_from_above=0.4)
    rows = [float(b.astype(float)[band].mean() / a.astype(float)[band].mean())
            for a, b in ((level.images[0], above.images[0]),) for band in (slice(0, 40), slice(-40, None))]
    assert rows[0] > 0.93 and 0.55 < rows[1] < 0.7, rows
    assert np.array_equal(level.particles[0], above.particles[0])
    with pytest.raises(ValueError, match="light_from_above"):
        render_frames(_map(1), light_from_above=1.0)


def test_bad_arguments_are_named():
    with pytest.raises(ValueError, match="unknown material"):
        render_frames(_map(1), heavy="wood")
    with pytest.raises(ValueError, match="c must"):
        render_frames(np.full((2, 15), 1.5))
