"""What the transparent wall adds to a frame: the lamps' reflections, taken off before detection.

The lamps are mirrored by the curved PMMA wall as bright vertical bands that
lie over spheres and gaps alike: they add light, the same in every frame. A
dark sphere under one loses its outline (dark POM under a reflection was
missed: recall 0.96 on the apparatus G-POM look), and a matte sphere under
one gains what looks like gloss (matte grey POM called glossy PP). The gaps
between the spheres of the wall layer are the frame's darkest places, and
every column of the bed crosses one within a diameter or two; so a grey
opening (erosion, then dilation) along each column over 2.5 diameters finds
the level the gaps have there, and what it has above the frame's usual gap
level is light the wall added. It is subtracted from every channel.

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


def remove_wall_glare(image: np.ndarray, particle_diameter_px: float) -> tuple[np.ndarray, float]:
    """The frame less the light the wall's reflections added, and the largest amount taken [grey levels].

    ``image``: undistorted uint8, BGR or grey; ``particle_diameter_px``:
    sphere diameter [px]. Returns an image of the same shape and dtype.
    """
    d = float(particle_diameter_px)
    # a reflection is white: it lifts every channel, so the darkest channel shows it
    darkest = image if image.ndim == 2 else cv2.min(cv2.min(image[..., 0], image[..., 1]), image[..., 2])
    k = np.ones((int(OPENING_D * d) | 1, 1), np.uint8)
    floor = cv2.dilate(cv2.erode(darkest.astype(np.float32), k), k)
    floor = cv2.GaussianBlur(floor, (0, 0), sigmaX=max(1.0, 0.05 * d), sigmaY=0.5 * d)
    excess = np.maximum(floor - np.percentile(floor[::4, ::4], GAP_PERCENTILE), 0.0)  # a sample is enough
    most = float(excess.max())
    if most < 0.5:
        return image, most
    lift = np.rint(excess).astype(np.uint8)
    return cv2.subtract(image, cv2.merge([lift] * image.shape[2]) if image.ndim == 3 else lift), most
