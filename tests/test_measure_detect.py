"""Building blocks of the sphere detector: the disk correlation and its coordinates."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from granseg.measure.templates import DiskScores, Templates, _disk, _masked_correlation


def test_masked_correlation_equals_opencv():
    rng = np.random.default_rng(0)
    image = cv2.GaussianBlur(rng.uniform(0, 255, (90, 100)).astype(np.float32), (0, 0), 2)
    template = image[30:51, 40:61] + rng.normal(0, 4, (21, 21)).astype(np.float32)
    mask = _disk(21, (0.0, 0.0), 9.0)
    ours = _masked_correlation(image - image.mean(), template, mask)
    theirs = cv2.matchTemplate(image, template, cv2.TM_CCOEFF_NORMED, mask=mask)
    np.testing.assert_allclose(ours, theirs, atol=1e-4)
    assert np.unravel_index(np.argmax(ours), ours.shape) == (30, 40)


@pytest.mark.parametrize("d", [30.0, 80.0])  # full size, and shrunk to spheres 32 px across
def test_disk_scores_find_a_sphere_where_it_is(d):
    """A disk drawn at a known sub-pixel centre is found there (to the map's resolution)."""
    half = int(np.ceil(0.75 * d))
    size = 2 * half + 1
    yy, xx = np.mgrid[0:size, 0:size] - half
    patch = (200.0 * (np.hypot(xx, yy) <= d / 2) + 20.0).astype(np.float32)
    templates = Templates((patch,), np.zeros((1, 2)), np.array([d / 2]), np.zeros((1, 3)),
                          (_disk(size, (0.0, 0.0), 1.05 * d / 2),), d)
    x0, y0 = 3.3 * d + 0.37, 2.1 * d - 0.21
    h, w = int(4.5 * d), int(6.5 * d)
    yy, xx = np.mgrid[0:h, 0:w]
    alpha = np.clip(d / 2 - np.hypot(xx - x0, yy - y0) + 0.5, 0, 1)
    image = (20.0 + 200.0 * alpha).astype(np.float32)
    scores = DiskScores.of(image, templates)
    assert scores.scale == pytest.approx(min(1.0, 32.0 / d), rel=0.05)
    row, col = np.unravel_index(np.argmax(scores.maps[0]), scores.maps[0].shape)
    x, y = scores.to_image(np.array([col], float), np.array([row], float), np.zeros((1, 2)))
    assert abs(x[0] - x0) <= 0.5 / scores.scale + 0.1 and abs(y[0] - y0) <= 0.5 / scores.scale + 0.1
    back = scores.to_map(x, y, np.zeros((1, 2)))
    assert (back[0][0], back[1][0]) == (col, row)
