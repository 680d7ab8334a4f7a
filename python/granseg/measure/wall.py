"""What the transparent wall adds to a frame: the lamps' reflections, taken off before detection.

The lamps are mirrored by the curved PMMA wall as bright vertical bands that
lie over spheres and gaps alike: they add light, the same in every frame. A
dark sphere under one loses its outline (dark POM under a reflection was
missed: recall 0.96 on the apparatus G-POM look), and a matte sphere under
one gains what looks like gloss (matte grey POM called glossy PP). The gaps
between the spheres of the wall layer are the frame's darkest places, and
every column of the bed crosses one within a diameter or two; so a grey
opening (erosion, then dilation) along each column over 2.5 diameters finds
the level the gaps have there. A reflection lifts that level over the bed's
whole height: what a column's level keeps over most of the height, above
the frame's usual gap level, is light the wall added. It is subtracted from
every channel and every row.

On frames without reflections the opening is flat and nothing changes; on
backlit frames (dark spheres on a bright ground) it finds the spheres'
level, again flat.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["remove_wall_glare"]

OPENING_D = 2.5  # height of the column opening [diameters]: every column meets a gap within it
GAP_PERCENTILE = 20  # the frame's usual gap level: most columns carry no reflection
COLUMN_PERCENTILE = 25  # a column's gap level: a quarter of the bed's height at least shows gaps


def remove_wall_glare(image: np.ndarray, particle_diameter_px: float,
                      bed_rows: tuple[int, int] | None = None) -> tuple[np.ndarray, float]:
    """The frame less the light the wall's reflections added, and the largest amount taken [grey levels].

    ``image``: undistorted uint8, BGR or grey; ``particle_diameter_px``:
    sphere diameter [px]; ``bed_rows``: the rows (top, bottom) [px] where the
    bed is seen, from which the gaps' level is taken (the lid and the plate
    are bright and have no gaps); rows outside take the nearest bed row's.
    Returns an image of the same shape and dtype.
    """
    d = float(particle_diameter_px)
    top, bottom = bed_rows if bed_rows is not None else (0, image.shape[0])
    top, bottom = max(0, int(top)), min(image.shape[0], int(bottom))
    # a reflection is white: it lifts every channel, so the darkest channel shows it
    bed = image[top:bottom]
    darkest = bed if bed.ndim == 2 else cv2.min(cv2.min(bed[..., 0], bed[..., 1]), bed[..., 2])
    k = np.ones((int(OPENING_D * d) | 1, 1), np.uint8)
    floor = cv2.dilate(cv2.erode(darkest, k), k)  # on the 8-bit levels: exact, 5x faster than float (D = 80 px)
    # A reflection runs the bed's whole height; what the opening finds in
    # only part of a column is the bed (the inside of glass spheres, a patch
    # of bright grains). So each column's level is a low quantile of its
    # floor over the bed's height, and the excess a profile across x.
    column = np.percentile(floor, COLUMN_PERCENTILE, axis=0)
    column = cv2.GaussianBlur(column[None, :], (0, 0), sigmaX=max(1.0, 0.05 * d))[0]
    excess = np.maximum(column - np.percentile(column, GAP_PERCENTILE), 0.0)
    most = float(excess.max())
    if most < 0.5:
        return image, most
    lift = np.ascontiguousarray(np.broadcast_to(np.rint(excess).astype(np.uint8), image.shape[:2]))
    return cv2.subtract(image, cv2.merge([lift] * image.shape[2]) if image.ndim == 3 else lift), most
