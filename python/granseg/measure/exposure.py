"""A camera's automatic exposure, undone: every frame brought to the first frame's look.

A camera left on automatic exposure changes its gain over a run (the bed
darkens as light grains rise, a lamp warms up, a cloud passes a window).
The classes are learned on the first frame; a frame taken at another gain
shows the same materials brighter or darker, and one class drifts towards
the other (the 2-D renderer's families with ``exposure_drift``,
BENCHMARKS.md: darkened by 30-50 % or brightened by 45-60 %, a third of the
maps went wrong).

What the window shows does not change over a run in the mean: the same
spheres, the same share of each material (the depth-mean heavy share is
conserved) and of gaps between them, only rearranged. So the bed's
brightness distribution is the same in every frame up to the gain, and the
ratio of a robust level of it (the mean of its middle half by rank: the
dark gaps and the bright highlights, which clip first, left out) measures
the gain. Each frame is divided by it.

Light clipped at 255 cannot be given back: a frame taken at gain g shows
everything brighter than 255 / g at the reference gain as 255, and after the
division as 255 / g, darker than the first frame showed it. So the run is
first surveyed (:func:`survey`, SURVEY_FRAMES spread over it) for the
largest gain, and every frame, the first included, is clipped at
255 / that gain: all of them then show the bright spheres as the brightest
frame could. That costs the bright materials their highlights in every
frame, the same in all, which the classes learn from the first.

Only a run whose gain strays by more than DRIFT_LIMIT (found among the
surveyed frames) is matched; a steadier one is left exactly as it was. The
level is not a perfect gauge: transparent glass shows what lies behind it,
so a bed of glass reads darker or brighter as it mixes with another
material (steady runs of the 2-D renderer read up to 1.13, the physically
based glass fixtures 0.81). Below DRIFT_LIMIT that error and a true drift
are alike harmless: the classes held on every mixture tried within a fifth
of the first frame's exposure before any correction (BENCHMARKS.md).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ["DRIFT_LIMIT", "SURVEY_FRAMES", "Exposure", "bed_level", "survey", "survey_indices"]

# A fifth: the change the classes learned on the first frame bore on every
# mixture of the 2-D renderer's drift families before this correction.
DRIFT_LIMIT = 0.2
# Frames read ahead of the analysis to find the run's largest gain. An
# automatic exposure drifts over seconds; 24 frames spread over the run miss
# little of its largest value, for under a second of reading.
SURVEY_FRAMES = 24


def bed_level(image: np.ndarray, bed_rows: tuple[int, int]) -> float:
    """The bed's brightness level: the mean grey level [0-255] of its middle half by rank.

    By rank, not between the quartiles' values: in a brightened frame many
    pixels are clipped at the same 255, and a cut by value would take them
    all in (a bed of which 40 % clipped read a gain of 1.81 for 1.6).
    """
    top, bottom = max(0, int(bed_rows[0])), min(image.shape[0], int(bed_rows[1]))
    bed = image[top:bottom]
    grey = (bed if bed.ndim == 2 else cv2.cvtColor(bed, cv2.COLOR_BGR2GRAY)).ravel()
    lo, hi = grey.size // 4, (3 * grey.size) // 4
    if hi <= lo:
        return float(grey.mean()) if grey.size else 0.0
    # the mean of ranks lo..hi-1 from the 256 levels' counts: the same as
    # sorting, and 3 ms a frame less than a partition at D = 80 px
    counts = np.bincount(grey, minlength=256)
    below = np.concatenate([[0], np.cumsum(counts)[:-1]])  # pixels darker than each level
    taken = np.clip(np.minimum(below + counts, hi) - np.maximum(below, lo), 0, None)
    return float((taken * np.arange(256)).sum() / (hi - lo))


@dataclass(frozen=True)
class Exposure:
    """A run's exposure: the first frame's bed level and the least and largest gain of a surveyed
    frame relative to it."""

    reference: float
    least_gain: float = 1.0
    most_gain: float = 1.0

    @property
    def drifting(self) -> bool:
        """Whether the gain strays by more than DRIFT_LIMIT: only then are frames matched."""
        return max(self.most_gain - 1.0, 1.0 - self.least_gain) > DRIFT_LIMIT

    @property
    def clip(self) -> int:
        """The grey level every frame is clipped at: what the brightest frame still resolves."""
        return int(255 / self.most_gain) if self.drifting and self.most_gain > 1.0 else 255

    def gain(self, level: float) -> float:
        """A frame's gain from its bed level (1 when there is no reference: a black first frame)."""
        ok = self.reference > 0 and np.isfinite(level) and level > 0
        return level / self.reference if ok else 1.0

    def match(self, image: np.ndarray, bed_rows: tuple[int, int]) -> tuple[np.ndarray, float]:
        """``image`` (uint8) brought to the first frame's exposure and clipped at ``clip``; and its gain.

        The image is returned unchanged unless the run is ``drifting``.
        """
        gain = self.gain(bed_level(image, bed_rows))
        if not self.drifting:
            return image, gain
        image = cv2.convertScaleAbs(image, alpha=1.0 / gain)
        if self.clip < 255:
            image = np.minimum(image, np.uint8(self.clip))
        return image, gain


def survey_indices(n_frames: int, first: int) -> set[int]:
    """The frames to survey: SURVEY_FRAMES spread evenly from ``first`` to the last, less ``first``
    itself (it is the reference, already read)."""
    return set(np.linspace(first, max(n_frames - 1, first), SURVEY_FRAMES).round().astype(int).tolist()) - {first}


def survey(levels: Iterable[float], reference: float) -> Exposure:
    """The run's :class:`Exposure` from the bed levels of the surveyed frames and the first frame's."""
    gains = [Exposure(reference).gain(level) for level in levels]
    return Exposure(reference, min([1.0, *gains]), max([1.0, *gains]))
