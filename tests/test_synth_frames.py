"""The frame renderer: ground truth follows the requested map, looks are as asked."""

from __future__ import annotations

import numpy as np
import pytest
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
    bottom_a = np.sort(a[(a[:, 1] > y1 - 15) & (a[:, 4] > 0), 0])
    top_a = a[(a[:, 1] < y1 - 270)]
    top_b = b[(b[:, 1] < y1 - 270)]
    assert len(top_a) and len(bottom_a)
    # top rows: the same centres, to 0.1 px
    common = np.isin(np.round(top_a[:, 1], 6), np.round(top_b[:, 1], 6))
    assert np.allclose(np.sort(top_a[common, 0]), np.sort(top_b[np.isin(np.round(top_b[:, 1], 6), np.round(top_a[:, 1], 6)), 0]), atol=0.1)
    bottom_b = np.sort(b[(b[:, 1] > y1 - 15) & (b[:, 4] > 0), 0])
    assert not np.allclose(bottom_a[:3], bottom_b[:3], atol=1.0)


@pytest.mark.parametrize("material", ["steel", "ceramic", "glass", "pom", "pp"])
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


def test_bad_arguments_are_named():
    with pytest.raises(ValueError, match="unknown material"):
        render_frames(_map(1), heavy="wood")
    with pytest.raises(ValueError, match="c must"):
        render_frames(np.full((2, 15), 1.5))
