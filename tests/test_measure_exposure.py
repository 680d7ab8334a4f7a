"""The camera's exposure measured on the bed and taken off (granseg.measure.exposure)."""

import numpy as np
import pytest

from granseg.measure.exposure import (
    DRIFT_LIMIT,
    SURVEY_FRAMES,
    Exposure,
    bed_level,
    survey,
    survey_indices,
)

ROWS = (0, 200)


def _bed(seed: int, gain: float = 1.0, size=(200, 300)) -> np.ndarray:
    """Dark gaps, two grey materials and bright highlights at random, taken at ``gain`` (clipped at
    255): (h, w, 3) uint8."""
    rng = np.random.default_rng(seed)
    kinds = rng.choice([20.0, 90.0, 160.0, 230.0], p=[0.2, 0.4, 0.3, 0.1], size=size)
    grey = np.clip(gain * (kinds + rng.normal(0, 6, size)), 0, 255)
    return np.repeat(grey[..., None], 3, axis=2).astype(np.uint8)


def test_the_level_is_the_same_for_the_same_bed_rearranged():
    """The window holds the same materials in every frame, only moved: the level does not move."""
    assert bed_level(_bed(1), ROWS) == pytest.approx(bed_level(_bed(2), ROWS), rel=0.01)


@pytest.mark.parametrize("gain", [0.5, 0.7, 1.3, 1.6])
def test_a_frame_at_another_gain_is_brought_back_and_clipped_as_the_brightest(gain):
    """Every frame, the first included, ends clipped where the brightest frame clipped: the first
    frame's look and a brightened frame's agree once both are matched."""
    first, frame = _bed(1), _bed(2, gain)
    ex = survey([bed_level(frame, ROWS)], bed_level(first, ROWS))
    assert ex.most_gain == pytest.approx(max(1.0, gain), rel=0.03)
    back, seen = ex.match(frame, ROWS)
    assert seen == pytest.approx(gain, rel=0.03)
    ref, _ = ex.match(first, ROWS)
    assert bed_level(back, ROWS) == pytest.approx(bed_level(ref, ROWS), rel=0.03)
    # the brightest material: clipped alike in both (it was at 255 in the brightened frame)
    assert np.percentile(back, 95) == pytest.approx(np.percentile(ref, 95), abs=3)
    if gain > 1:
        assert ref.max() == back.max() == ex.clip < 255


def test_a_steady_camera_leaves_the_frames_as_they_were():
    """A level that strays by less than DRIFT_LIMIT (glass mixing with POM reads so) changes nothing."""
    frame, level = _bed(2), bed_level(_bed(2), ROWS)
    ex = survey([1.15 * level, 0.85 * level], level)
    assert (ex.least_gain, ex.most_gain) == pytest.approx((0.85, 1.15)) and 0.15 < DRIFT_LIMIT
    assert not ex.drifting and ex.clip == 255
    same, seen = ex.match(frame, ROWS)
    assert same is frame and seen == pytest.approx(1.0)
    unmatched, seen = Exposure(0.0).match(frame, ROWS)  # no reference level (a black first frame)
    assert unmatched is frame and seen == 1.0


def test_the_survey_spreads_over_the_run_after_the_first_readable_frame():
    """The first frame is the reference, read once; the survey spreads from it to the last."""
    picked = survey_indices(500, 3)
    assert min(picked) > 3 and max(picked) == 499 and len(picked) == SURVEY_FRAMES - 1
    assert survey_indices(5, 0) == {1, 2, 3, 4}
    assert survey_indices(1, 0) == set()
