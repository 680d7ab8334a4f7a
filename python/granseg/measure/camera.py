"""The lens: undistortion of frames (tables built once) and checkerboard calibration."""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Any

import cv2
import numpy as np

__all__ = ["Undistorter", "calibrate_camera", "find_checkerboard"]

log = logging.getLogger(__name__)
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp")


class Undistorter:
    """Undistort and crop frames with remap tables built once.

    ``camera_matrix`` (3x3) and ``dist_coeffs`` follow OpenCV; the undistorted
    image keeps the same camera matrix (as ``cv2.undistort``). ``crop`` =
    (x0, y0, x1, y1) is the region of undistorted pixels to produce, which may
    extend past the image (filled by replicating the border).
    """

    def __init__(self, camera_matrix: Any, dist_coeffs: Any, image_size: tuple[int, int],
                 crop: tuple[int, int, int, int]):
        self.image_size = tuple(int(v) for v in image_size)
        self.crop = tuple(int(v) for v in crop)
        k = np.asarray(camera_matrix, dtype=float)
        dist = np.asarray(dist_coeffs, dtype=float)
        x0, y0, x1, y1 = self.crop
        xs, ys = np.meshgrid(np.arange(x0, x1, dtype=float), np.arange(y0, y1, dtype=float))
        pts = np.stack([(xs - k[0, 2]) / k[0, 0], (ys - k[1, 2]) / k[1, 1], np.ones_like(xs)], -1)
        img, _ = cv2.projectPoints(pts.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), k, dist)
        img = img.reshape(y1 - y0, x1 - x0, 2).astype(np.float32)
        self.map1, self.map2 = cv2.convertMaps(img[..., 0], img[..., 1], cv2.CV_16SC2)
        self._source = img

    def __call__(self, frame: np.ndarray) -> np.ndarray:
        """The undistorted crop of ``frame`` (same dtype and channels)."""
        return cv2.remap(frame, self.map1, self.map2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    def inside_image(self, region: tuple[float, float, float, float]) -> bool:
        """True if every undistorted pixel of ``region`` is seen by the sensor."""
        x0, y0, x1, y1 = self.crop
        rx0, ry0, rx1, ry1 = (int(np.floor(region[0])) - x0, int(np.floor(region[1])) - y0,
                              int(np.ceil(region[2])) - x0, int(np.ceil(region[3])) - y0)
        src = self._source[max(ry0, 0):ry1, max(rx0, 0):rx1]
        w, h = self.image_size
        return bool(src.size) and bool(np.all((src[..., 0] >= 0) & (src[..., 0] <= w - 1)
                                              & (src[..., 1] >= 0) & (src[..., 1] <= h - 1)))


def find_checkerboard(gray: np.ndarray, pattern: tuple[int, int]) -> np.ndarray | None:
    """Inner corners (m, 1, 2) [px] of a checkerboard with ``pattern`` = (cols, rows) inner corners, or None."""
    ok, corners = cv2.findChessboardCorners(
        gray, pattern, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
    if not ok:
        return None
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4)
    return cv2.cornerSubPix(gray, corners, (7, 7), (-1, -1), crit)


def calibrate_camera(directory: str | os.PathLike, pattern: tuple[int, int] = (9, 6),
                     square: float = 1.0) -> dict[str, Any]:
    """Camera matrix and distortion from checkerboard photos in ``directory``.

    ``pattern`` = (columns, rows) of inner corners; ``square`` is the square
    side (any unit; it does not change the result). Returns the
    ``experiment.json`` fields ``camera_matrix`` [px] and ``dist_coeffs``
    (k1, k2, p1, p2, k3) plus ``reprojection_error_px`` (RMS, px),
    ``image_size`` and the images used / skipped.
    """
    d = Path(directory)
    if not d.is_dir():
        raise FileNotFoundError(f"{d}: checkerboard directory not found")
    files = sorted(p for p in d.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise ValueError(f"{d}: no checkerboard images (PNG/JPEG) in the directory")
    grid = np.zeros((pattern[0] * pattern[1], 3), np.float32)
    grid[:, :2] = np.mgrid[0:pattern[0], 0:pattern[1]].T.reshape(-1, 2) * square
    used, skipped, obj, img, size = [], [], [], [], None
    for f in files:
        gray = cv2.imread(str(f), cv2.IMREAD_GRAYSCALE)
        if gray is None:
            skipped.append(f"{f.name}: unreadable image")
            continue
        if size is not None and gray.shape[::-1] != size:
            skipped.append(f"{f.name}: size {gray.shape[::-1]} differs from {size}")
            continue
        corners = find_checkerboard(gray, pattern)
        if corners is None:
            skipped.append(f"{f.name}: no {pattern[0]}x{pattern[1]} checkerboard found")
            continue
        size = gray.shape[::-1]
        used.append(f.name), obj.append(grid), img.append(corners)
    for s in skipped:
        log.warning("calibrate-camera: skipped %s", s)
    if len(used) < 3:
        raise ValueError(f"{d}: need at least 3 images with a {pattern[0]}x{pattern[1]} checkerboard, found {len(used)}")
    rms, k, dist, _, _ = cv2.calibrateCamera(obj, img, size, None, None)
    return dict(camera_matrix=k.tolist(), dist_coeffs=dist.ravel().tolist(),
                reprojection_error_px=float(rms), image_size=list(size),
                images_used=used, images_skipped=skipped)
