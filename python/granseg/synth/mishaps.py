"""What can happen to a rig during a run, applied to frames already rendered as stills.

Each function rewrites the stills of a folder in place, from its ``first``
frame (in name order) on: the view moved in the image (a knocked camera, a
cell that shifts), turned (a camera that is not level), or the lid risen
against the plate (a bed that dilates under shear). The spheres stay the
ones rendered, so the truth of the frames as rendered scores the map made
from the altered ones. For the quality checks' tests and benches
(``view_steady``, ``window_level``, ``bed_steady``): meant for frames
rendered to be altered, never a user's recording.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

__all__ = ["move_view", "raise_lid", "turn_view"]

STILLS = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp")
JPEG_QUALITY = 95


def move_view(folder: str | Path, dy: float, first: int = 0) -> None:
    """Shift the frames by ``dy`` px down the image (negative: up)."""
    shift = np.float32([[1, 0, 0], [0, 1, dy]])
    _rewrite(folder, first, lambda img: cv2.warpAffine(img, shift, img.shape[1::-1], flags=cv2.INTER_LINEAR,
                                                       borderMode=cv2.BORDER_REPLICATE))


def turn_view(folder: str | Path, degrees: float, first: int = 0) -> None:
    """Turn the frames by ``degrees`` (counter-clockwise) about the image's centre."""
    def turn(img: np.ndarray) -> np.ndarray:
        h, w = img.shape[:2]
        m = cv2.getRotationMatrix2D((w / 2, h / 2), degrees, 1.0)
        return cv2.warpAffine(img, m, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    _rewrite(folder, first, turn)


def raise_lid(folder: str | Path, rise: float, window: list[float] | tuple[float, ...], first: int = 0) -> None:
    """Raise the lid by ``rise`` px (negative: lower it), the bed dilating evenly: each row of the
    window ``[x0, y0, x1, y1]`` lifted in proportion to its height above the plate line y1, the
    lid's line y0 and all above it by the whole rise, the plate and all below it not at all."""
    y0, y1 = float(window[1]), float(window[3])

    def lift(img: np.ndarray) -> np.ndarray:
        h, w = img.shape[:2]
        y = np.arange(h, dtype=np.float32)
        src_y = y + rise * np.clip((y1 - y) / (y1 - y0), 0.0, 1.0)
        map_y = np.repeat(src_y[:, None], w, axis=1).astype(np.float32)
        map_x = np.repeat(np.arange(w, dtype=np.float32)[None, :], h, axis=0)
        return cv2.remap(img, map_x, map_y, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    _rewrite(folder, first, lift)


def _rewrite(folder: str | Path, first: int, alter: Callable[[np.ndarray], np.ndarray]) -> None:
    """Apply ``alter`` to each still of ``folder`` from the ``first``-th on, in place, at its own
    depth (JPEG at quality JPEG_QUALITY)."""
    stills = sorted(p for p in Path(folder).iterdir() if p.suffix.lower() in STILLS)
    if not stills:
        raise FileNotFoundError(f"{folder}: no still frames ({', '.join(STILLS)}) to alter")
    for f in stills[first:]:
        img = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
        jpeg = f.suffix.lower() in (".jpg", ".jpeg")
        cv2.imwrite(str(f), alter(img), [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY] if jpeg else [])
