"""The lens: undistortion of frames (tables built once) and checkerboard calibration."""

from __future__ import annotations

import logging
import operator
import os
import warnings
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from granseg.errors import BadFrame, CameraWarning, FitError
from granseg.measure.stills import IMAGE_SUFFIXES, decode_still

__all__ = ["CameraWarning", "Undistorter", "calibrate_camera", "check_pattern", "checkerboard_dir",
           "find_checkerboard", "reduce_frame"]

log = logging.getLogger(__name__)


# How many frames wide and high a crop may be. Undistorted, what the sensor
# sees is little wider than the frame: 1.3 frames through the GoPro-like lens
# of granseg.synth.scenes.WIDE_ANGLE at a focal length of 0.8 frame widths
# (wider angles fold OpenCV's polynomial model). A larger crop holds pixels no
# lens shows; its tables (28 bytes a pixel) are refused before they are
# allocated (a mistyped window of 2e6 px asked for 16 TB).
MAX_CROP_FRAMES = 3


class Undistorter:
    """Undistort and crop frames with remap tables built once.

    ``camera_matrix`` (3x3) and ``dist_coeffs`` follow OpenCV; the undistorted
    image keeps the same camera matrix (as ``cv2.undistort``). ``crop`` =
    (x0, y0, x1, y1) is the region of undistorted pixels to produce, which may
    extend past the image (filled by replicating the border), up to
    MAX_CROP_FRAMES times the image's width and height (ValueError beyond).
    """

    def __init__(self, camera_matrix: Any, dist_coeffs: Any, image_size: tuple[int, int],
                 crop: tuple[int, int, int, int]):
        self.image_size = tuple(int(v) for v in image_size)
        self.crop = tuple(int(v) for v in crop)
        if not self.within_reach(self.crop, self.image_size):
            raise ValueError(f"crop {list(self.crop)} is more than {MAX_CROP_FRAMES} times the image "
                             f"({self.image_size[0]} x {self.image_size[1]} px) wide or high")
        k = np.asarray(camera_matrix, dtype=float)
        dist = np.asarray(dist_coeffs, dtype=float)
        x0, y0, x1, y1 = self.crop
        # where each undistorted pixel of the crop comes from: the crop is the
        # undistorted image seen by a camera whose principal point is moved by
        # the crop's origin (the same tables as projecting every pixel through
        # the lens, to the bit, in 7 ms instead of 1.2 s at 1920 x 1440)
        shifted = k.copy()
        shifted[0, 2] -= x0
        shifted[1, 2] -= y0
        sx, sy = cv2.initUndistortRectifyMap(k, dist, None, shifted, (x1 - x0, y1 - y0), cv2.CV_32FC1)
        self.map1, self.map2 = cv2.convertMaps(sx, sy, cv2.CV_16SC2)
        self._source = np.stack([sx, sy], -1)

    @staticmethod
    def within_reach(crop: tuple[float, float, float, float], image_size: tuple[int, int]) -> bool:
        """True if ``crop`` is no more than MAX_CROP_FRAMES times ``image_size`` (w, h) wide and high."""
        return bool(crop[2] - crop[0] <= MAX_CROP_FRAMES * image_size[0]
                    and crop[3] - crop[1] <= MAX_CROP_FRAMES * image_size[1])

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


def reduce_frame(image: np.ndarray, k: int) -> np.ndarray:
    """``image`` reduced k times: each pixel the mean of a k x k block (rows and columns beyond the
    last whole block dropped). The frame as a sensor of 1/k the pixels would take it
    (:meth:`granseg.measure.experiment.Experiment.reduced` is its camera)."""
    if k == 1:
        return image
    h, w = image.shape[:2]
    return cv2.resize(image[:h - h % k, :w - w % k], (w // k, h // k), interpolation=cv2.INTER_AREA)


def find_checkerboard(gray: np.ndarray, pattern: tuple[int, int]) -> np.ndarray | None:
    """Inner corners (m, 1, 2) [px] of a checkerboard with ``pattern`` = (cols, rows) inner corners, or None."""
    ok, corners = cv2.findChessboardCorners(
        gray, pattern, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
    if not ok:
        return None
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4)
    return cv2.cornerSubPix(gray, corners, (7, 7), (-1, -1), crit)


# Limits of calibrate_camera (issue 14).
MAX_PATTERN = 100          # inner corners per side accepted by ``pattern``
MIN_VIEWS = 3              # distinct board poses needed
SAME_POSE_PX = 1.0         # corner sets closer than this (RMS) [px] are one pose
FOCAL_STDERR_LIMIT = 0.02  # warn above this standard error of fx or fy, relative
CENTRE_STDERR_LIMIT = 0.03  # warn above this standard error of cx (cy), share of width (height)
MIN_TILT_SPAN_DEG = 10.0   # warn if the boards' normals span less than this [degrees]
_INTRINSICS = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")


def check_pattern(pattern: Any) -> tuple[int, int]:
    """``pattern`` as (columns, rows) of inner corners, each a whole number from 2 to MAX_PATTERN.

    Raises ValueError naming the pattern otherwise (before anything is allocated).
    """
    try:
        cols, rows = (operator.index(v) for v in pattern)
    except (TypeError, ValueError):
        raise ValueError(f"pattern must be (columns, rows) inner corners, two whole numbers, "
                         f"got {pattern!r}") from None
    if not (2 <= cols <= MAX_PATTERN and 2 <= rows <= MAX_PATTERN):
        raise ValueError(f"pattern {cols}x{rows}: the columns and rows of inner corners must each "
                         f"be between 2 and {MAX_PATTERN}")
    return cols, rows


def checkerboard_dir(directory: str | os.PathLike) -> Path:
    """``directory`` as a Path; FileNotFoundError (NotADirectoryError) naming it if it is not a folder."""
    d = Path(directory)
    if not d.exists():
        raise FileNotFoundError(f"{d}: checkerboard photo folder not found")
    if not d.is_dir():
        raise NotADirectoryError(f"{d}: not a folder; give the folder of checkerboard photos")
    return d


def _pose_distance(a: np.ndarray, b: np.ndarray, pattern: tuple[int, int]) -> float:
    """RMS distance [px] between two corner sets of one board, whatever corner the detector began at."""
    cols, rows = pattern
    a, b = a.reshape(rows, cols, 2), b.reshape(rows, cols, 2)
    orders = [b, b[::-1], b[:, ::-1], b[::-1, ::-1]]
    if cols == rows:
        orders += [o.transpose(1, 0, 2) for o in orders]
    return min(float(np.sqrt(np.mean(np.sum((a - o) ** 2, axis=-1)))) for o in orders)


def _tilt_span_deg(rvecs: Any) -> float:
    """Largest angle [degrees] between the board normals of two views."""
    normals = [cv2.Rodrigues(np.asarray(r, float))[0][:, 2] for r in rvecs]
    cos = min(abs(float(a @ b)) for a in normals for b in normals)
    return float(np.degrees(np.arccos(min(cos, 1.0))))


def calibrate_camera(directory: str | os.PathLike, pattern: tuple[int, int] = (9, 6),
                     square: float = 1.0) -> dict[str, Any]:
    """Camera matrix and distortion from checkerboard photos in ``directory``.

    ``pattern`` = (columns, rows) of inner corners (each 2 to MAX_PATTERN);
    ``square`` is the square side (any unit; it does not change the result).
    Returns the ``experiment.json`` fields ``camera_matrix`` [px] and
    ``dist_coeffs`` (k1, k2, p1, p2, k3) plus ``reprojection_error_px`` (RMS,
    px), ``stderr`` (standard errors of fx, fy, cx, cy [px] and k1 ... k3),
    ``tilt_span_deg`` (largest angle between two views' board normals),
    ``image_size`` and the images used / skipped.

    A photo whose corners lie within SAME_POSE_PX (RMS) of an earlier one's
    shows the same pose and is skipped (it adds nothing but a false
    confidence). Fewer than MIN_VIEWS distinct poses raise ValueError. A
    CameraWarning gives the figures if fx or fy is known to worse than
    FOCAL_STDERR_LIMIT, cx or cy to worse than CENTRE_STDERR_LIMIT of the image
    size, or the board normals span less than MIN_TILT_SPAN_DEG.
    """
    pattern = check_pattern(pattern)
    if not (np.isfinite(square) and square > 0):
        raise ValueError(f"square must be a positive length, got {square!r}")
    d = checkerboard_dir(directory)
    files = sorted(p for p in d.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise ValueError(f"{d}: no checkerboard images (PNG, JPEG, TIFF or BMP) in the directory")
    cols, rows = pattern
    grid = np.zeros((cols * rows, 3), np.float32)
    grid[:, :2] = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2) * square
    used, skipped, img, size, found = [], [], [], None, 0
    for f in files:
        try:  # decoded from memory: cv2.imread crashes on a name that is not UTF-8
            gray = decode_still(f.read_bytes(), f.name, gray=True)  # a 16-bit board at its own depth
        except (OSError, cv2.error, BadFrame):
            gray = None
        if gray is None:
            skipped.append(f"{f.name}: unreadable image")
            continue
        if size is not None and gray.shape[::-1] != size:
            skipped.append(f"{f.name}: size {gray.shape[::-1]} differs from {size}")
            continue
        corners = find_checkerboard(gray, pattern)
        if corners is None:
            skipped.append(f"{f.name}: no {cols}x{rows} checkerboard found")
            continue
        size, found = gray.shape[::-1], found + 1
        near = [(_pose_distance(corners, c, pattern), name) for c, name in zip(img, used, strict=True)]
        same = min(near, default=None)
        if same is not None and same[0] < SAME_POSE_PX:
            skipped.append(f"{f.name}: same pose as {same[1]} (corners within {same[0]:.2f} px RMS)")
            continue
        used.append(f.name), img.append(corners)
    for s in skipped:
        log.warning("calibrate-camera: skipped %s", s)
    if len(used) < MIN_VIEWS:
        board = f"{cols}x{rows} checkerboard"
        if found >= 2 and len(used) == 1:
            raise ValueError(
                f"{d}: the {found} photos of the {board} show the board in one pose (corners "
                f"within {SAME_POSE_PX:g} px RMS); calibration needs at least {MIN_VIEWS} photos "
                f"with the board tilted differently in each")
        raise ValueError(
            f"{d}: need at least {MIN_VIEWS} images with a {board} in distinct poses, with the "
            f"board tilted differently in each; found the board in {found} of {len(files)} "
            f"images, {len(used)} distinct pose(s) used")
    try:
        rms, k, dist, rvecs, _, std, _, _ = cv2.calibrateCameraExtended(
            [grid] * len(img), img, size, None, None)
    except cv2.error as exc:
        raise FitError(f"{d}: OpenCV could not calibrate from {len(used)} views: {exc}") from None
    std = std.ravel()
    stderr = {name: (float(v) if np.isfinite(v) else None)
              for name, v in zip(_INTRINSICS, std, strict=False)}
    tilt = _tilt_span_deg(rvecs)
    _warn_if_weak(d, len(used), k, std, size, tilt)
    return dict(camera_matrix=k.tolist(), dist_coeffs=dist.ravel().tolist(),
                reprojection_error_px=float(rms), stderr=stderr, tilt_span_deg=tilt,
                image_size=list(size), images_used=used, images_skipped=skipped)


def _warn_if_weak(d: Path, n: int, k: np.ndarray, std: np.ndarray, size: tuple[int, int],
                  tilt: float) -> None:
    """CameraWarning with the figures if the intrinsics are poorly constrained."""
    fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
    rel = [std[0] / abs(fx), std[1] / abs(fy)]
    share = [std[2] / size[0], std[3] / size[1]]
    weak_focal = not all(np.isfinite(v) and v <= FOCAL_STDERR_LIMIT for v in rel)
    weak_centre = not all(np.isfinite(v) and v <= CENTRE_STDERR_LIMIT for v in share)
    flat = tilt < MIN_TILT_SPAN_DEG
    if not (weak_focal or weak_centre or flat):
        return
    problems = []
    if weak_focal or weak_centre:
        problems.append(
            f"the camera is poorly constrained: fx = {fx:.1f} ± {std[0]:.1f} px ({100 * rel[0]:.1f} %), "
            f"fy = {fy:.1f} ± {std[1]:.1f} px ({100 * rel[1]:.1f} %), cx = {cx:.1f} ± {std[2]:.1f} px "
            f"({100 * share[0]:.1f} % of the width), cy = {cy:.1f} ± {std[3]:.1f} px "
            f"({100 * share[1]:.1f} % of the height); limits {100 * FOCAL_STDERR_LIMIT:g} % of fx, fy "
            f"and {100 * CENTRE_STDERR_LIMIT:g} % of the image for cx, cy")
    if flat:
        problems.append(f"the boards' tilts span only {tilt:.1f}° (want at least {MIN_TILT_SPAN_DEG:g}°)")
    warnings.warn(
        f"calibrate-camera: {d}: {n} views: " + "; ".join(problems)
        + ". Photograph the board tilted by 20-45° in different directions (left, right, up, "
        "down), covering different parts of the image.", CameraWarning, stacklevel=3)
