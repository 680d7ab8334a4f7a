"""``experiment.json`` for a new recording, written for the user (``granseg init-experiment``).

A lab's first recording needs an experiment.json (docs/formats.md) before ``granseg analyze``
can read it. :func:`init_experiment` writes one beside the frames (or the video) from what is
known: the materials (densities from the model's table), c0 and the masses, the frame rate
(a video's own; stills' from their camera's clock, :func:`clock_rate`), the camera model from
``granseg calibrate-camera``'s JSON, and the window. Fields it cannot know are left ``null`` and listed, and every field is explained in the
file's ``_help`` object (the reader ignores keys starting with ``_``).

The window is read off a preview: :func:`window_preview` draws the first frame, undistorted
with the camera model, with a pixel ruler every 50 px and the window (when given), so its
corners can be read and passed back with ``window=``. The sphere diameter defaults to the
window's height over the bed's 15 layers (the window spans lid to plate).
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from granseg._io import atomic_write, check_writable, read_json
from granseg.constants import N_LAYERS
from granseg.measure.camera import Undistorter
from granseg.measure.sources import FrameDirectory, VideoFrames, open_frames

__all__ = ["HELP", "clock_rate", "init_experiment", "preview_path", "window_preview"]

log = logging.getLogger(__name__)

# Stills' rate is read off their camera's clock only where the clock's resolution (a second,
# without sub-seconds) is at most this share of the time from the first shot to the last, so that
# the rate is known within it: the share the frame_times check allows (quality.FRAME_TIMES_SHARE).
CLOCK_RESOLUTION_SHARE = 0.01

#: what each field means, with its unit: written into the template as ``_help``
HELP: dict[str, str] = {
    "name": "experiment name; names the map file when analyze writes into a campaign folder",
    "heavy": "heavy material (glass, ceramic, POM, steel, PP or your own name)",
    "light": "light material",
    "rho_h": "heavy material's density [kg/m^3] (from the model's table for a known material)",
    "rho_l": "light material's density [kg/m^3]",
    "c0": "heavy share of the bed by volume, strictly between 0 and 1",
    "M_g": "mass of the grains in the cell [kg]",
    "M_w": "load on the lid: lid plus added masses [kg]",
    "fps": "frames per second [1/s]; for stills taken every S seconds, 1/S (read off the camera's clock "
           "where the stills carry one); null for a video (its own rate is used)",
    "t0": "time of the first frame since the plate started [s]; negative if the camera started first",
    "camera_matrix": "OpenCV camera matrix [[fx,0,cx],[0,fy,cy],[0,0,1]] [px], from granseg calibrate-camera "
                     "(without one: a pinhole without distortion centred on the image)",
    "dist_coeffs": "OpenCV distortion coefficients [k1,k2,p1,p2,k3], from granseg calibrate-camera",
    "window": "investigation window [x0,y0,x1,y1] in undistorted pixels: y0 at the lid, y1 at the plate, "
              "x0..x1 the width to count; read it off the preview NAME_window.png beside the frames",
    "particle_diameter_px": "sphere diameter in undistorted pixels (default: window height / 15 layers); "
                            "analyze's check sphere_spacing says when the spheres found are not this size",
}


def init_experiment(
    path: str | os.PathLike,
    *,
    name: str | None = None,
    heavy: str | None = None,
    light: str | None = None,
    rho_h: float | None = None,
    rho_l: float | None = None,
    c0: float | None = None,
    M_g: float | None = None,
    M_w: float | None = None,
    fps: float | None = None,
    interval: float | None = None,
    camera: str | os.PathLike | Mapping[str, Any] | None = None,
    window: Sequence[float] | None = None,
    particle_diameter_px: float | None = None,
    preview: bool = True,
    force: bool = False,
) -> tuple[Path, list[str]]:
    """Write ``experiment.json`` for the frames directory or video at ``path``.

    ``camera``: the JSON file ``granseg calibrate-camera`` writes (or its dict); ``interval``
    [s] between stills instead of ``fps``; a known material's density comes from the model's
    table. With ``preview``, the window preview is written beside the recording
    (:func:`preview_path`). Returns the file and
    the fields still ``null`` (to fill in before ``granseg analyze``). Refuses to replace an
    existing file unless ``force``; bad values raise ValueError naming the field.
    """
    source, exp_path = open_frames(path)
    check_writable(exp_path, force)
    first = _first_frame(source)
    h, w = first.shape[:2]
    k, dist = _camera(camera, (w, h))
    rates = [v for v in (fps, None if interval is None else 1.0 / _positive("interval", interval)) if v is not None]
    if len(rates) > 1:
        raise ValueError("give fps or interval, not both")
    doc: dict[str, Any] = {
        "name": name or _default_name(Path(path)),
        "heavy": heavy, "light": light,
        "rho_h": _density("rho_h", rho_h, heavy), "rho_l": _density("rho_l", rho_l, light),
        "c0": None if c0 is None else _share(c0),
        "M_g": None if M_g is None else _positive("M_g", M_g),
        "M_w": None if M_w is None else _positive("M_w", M_w),
        "fps": _positive("fps", rates[0]) if rates else clock_rate(source),
        "t0": 0.0,
        "camera_matrix": k.tolist(), "dist_coeffs": dist.tolist(),
        "window": None if window is None else _window(window, (w, h)),
    }
    doc["particle_diameter_px"] = (_positive("particle_diameter_px", particle_diameter_px)
                                   if particle_diameter_px is not None
                                   else None if doc["window"] is None
                                   else round((doc["window"][3] - doc["window"][1]) / N_LAYERS, 2))
    # a video's stream and an ImageJ stack tell their own rate, used where fps is null
    missing = [f for f, v in doc.items() if v is None and not (f == "fps" and (isinstance(source, VideoFrames)
                                                                              or source.fps))]
    doc["_help"] = HELP
    text = json.dumps(doc, indent=1)
    atomic_write(exp_path, lambda tmp: tmp.write_text(text + "\n", encoding="utf-8"), force=force)
    if preview:
        img = window_preview(first, k, dist, doc["window"])
        atomic_write(preview_path(path), lambda tmp: _write_png(tmp, img), force=True)
    return exp_path, missing


def preview_path(path: str | os.PathLike) -> Path:
    """Where the window preview of the recording at ``path`` goes: beside the frames folder (or
    the video) as ``NAME_window.png``, never inside it, where it would be read as a frame."""
    p = Path(path)
    if p.name in ("", ".", ".."):
        p = p.resolve()
    return p.with_name((p.stem if p.is_file() else p.name) + "_window.png")


def window_preview(frame: np.ndarray, camera_matrix: Any, dist_coeffs: Any,
                   window: Sequence[float] | None = None) -> np.ndarray:
    """The frame undistorted with the camera model, a labelled pixel ruler every 50 px, and the
    window (with its 15 layer lines) when given: what the window's corners are read off."""
    h, w = frame.shape[:2]
    und = Undistorter(camera_matrix, dist_coeffs, (w, h), (0, 0, w, h))(frame)
    img = und.copy() if und.ndim == 3 else cv2.cvtColor(und, cv2.COLOR_GRAY2BGR)
    step = 50
    scale = max(0.35, min(w, h) / 1400)
    for x in range(0, w, step):
        cv2.line(img, (x, 0), (x, h - 1), (255, 255, 0) if x % (2 * step) == 0 else (120, 120, 0), 1)
        if x % (2 * step) == 0:
            cv2.putText(img, str(x), (x + 2, int(14 * scale / 0.35)), cv2.FONT_HERSHEY_SIMPLEX, scale,
                        (255, 255, 255), 1, cv2.LINE_AA)
    for y in range(0, h, step):
        cv2.line(img, (0, y), (w - 1, y), (255, 255, 0) if y % (2 * step) == 0 else (120, 120, 0), 1)
        if y % (2 * step) == 0:
            cv2.putText(img, str(y), (2, y - 3), cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), 1, cv2.LINE_AA)
    if window is not None:
        x0, y0, x1, y1 = (int(round(v)) for v in window)
        for j in range(1, N_LAYERS):
            y = int(round(y0 + j * (y1 - y0) / N_LAYERS))
            cv2.line(img, (x0, y), (x1, y), (0, 200, 255), 1)
        cv2.rectangle(img, (x0, y0), (x1, y1), (0, 0, 255), 2)
    return img


# --------------------------------------------------------------------------- fields


def clock_rate(source: FrameDirectory | VideoFrames) -> float | None:
    """Stills' frame rate [1/s] from their camera's clock (sources.shot_times): the shots after the
    first over the time from the first to the last, to 4 digits. None for a video (its own rate
    is used), stills without a clock, a clock that runs backwards in name order, or one too coarse
    for the time the stills span (CLOCK_RESOLUTION_SHARE)."""
    if not isinstance(source, FrameDirectory) or len(source) < 2:
        return None
    shot = source.clock()
    if shot is None:
        return None
    clock, resolution = shot
    span = float(clock[-1] - clock[0])
    if np.any(np.diff(clock) < 0) or span <= 0 or resolution > CLOCK_RESOLUTION_SHARE * span:
        return None
    rate = float(f"{(len(clock) - 1) / span:.4g}")
    log.info("fps = %g from the stills' clock: %d shot over %.6g s (EXIF)", rate, len(clock), span)
    return rate


def _first_frame(source: FrameDirectory | VideoFrames) -> np.ndarray:
    if isinstance(source, FrameDirectory):
        return source.read(0)
    for _, img in source.frames():
        return img
    raise ValueError(f"{source.path}: the video has no readable frame")


def _default_name(path: Path) -> str:
    return path.stem if path.is_file() else path.resolve().name


def _camera(camera: Any, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """The camera model from calibrate-camera's JSON, or a pinhole centred on the image."""
    if camera is None:
        w, h = size
        f = float(max(w, h))
        return np.array([[f, 0.0, (w - 1) / 2], [0.0, f, (h - 1) / 2], [0.0, 0.0, 1.0]]), np.zeros(5)
    src = str(camera) if not isinstance(camera, Mapping) else "camera"
    if not isinstance(camera, Mapping):
        camera = read_json(camera, "camera JSON", "granseg calibrate-camera writes it")
    try:
        k = np.asarray(camera["camera_matrix"], dtype=float)
        dist = np.asarray(camera["dist_coeffs"], dtype=float).ravel()
    except (KeyError, TypeError, ValueError):
        raise ValueError(f"{src}: expected 'camera_matrix' (3 x 3) and 'dist_coeffs', as granseg "
                         "calibrate-camera writes them") from None
    if k.shape != (3, 3) or dist.size not in (4, 5, 8, 12, 14):
        raise ValueError(f"{src}: 'camera_matrix' must be 3 x 3 and 'dist_coeffs' 4, 5, 8, 12 or 14 numbers")
    return k, dist


def _density(field: str, value: float | None, material: str | None) -> float | None:
    if value is not None:
        return _positive(field, value)
    if material is None:
        return None
    from granseg.model import MATERIALS

    known = {k.lower(): v for k, v in MATERIALS.items()}
    if material.lower() not in known:
        raise ValueError(f"{field}: no density known for material {material!r} "
                         f"(known: {', '.join(MATERIALS)}); give it explicitly")
    return float(known[material.lower()])


def _positive(field: str, value: float) -> float:
    v = float(value)
    if not np.isfinite(v) or v <= 0:
        raise ValueError(f"{field}: expected a number > 0, got {value!r}")
    return v


def _share(c0: float) -> float:
    v = float(c0)
    if not 0.0 < v < 1.0:
        raise ValueError(f"c0: expected a share strictly between 0 and 1, got {c0!r}")
    return v


def _window(window: Sequence[float], size: tuple[int, int]) -> list[float]:
    try:
        x0, y0, x1, y1 = (float(v) for v in window)
    except (TypeError, ValueError):
        raise ValueError(f"window: expected four numbers x0, y0, x1, y1, got {window!r}") from None
    w, h = size
    if not (0 <= x0 < x1 <= w and 0 <= y0 < y1 <= h):
        raise ValueError(f"window: expected 0 <= x0 < x1 <= {w} and 0 <= y0 < y1 <= {h} (the image), "
                         f"got {[x0, y0, x1, y1]}")
    return [x0, y0, x1, y1]


def _write_png(tmp: Path, img: np.ndarray) -> None:
    ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise OSError(f"{tmp}: could not encode the preview")
    tmp.write_bytes(buf.tobytes())
