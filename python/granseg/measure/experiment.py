"""Read and check ``experiment.json`` (docs/formats.md): metadata, camera model, window."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from granseg._io import read_json
from granseg.errors import short_repr
from granseg.maps import Conditions

__all__ = ["Experiment", "load_experiment"]

TEXT_FIELDS = ("name", "heavy", "light")
COLOUR_RANGES = ("heavy_hsv", "light_hsv", "heavy_lab", "light_lab")


@dataclass(frozen=True)
class Experiment(Conditions):
    """One experiment's description: densities [kg/m^3], masses [kg], fps [1/s],
    OpenCV camera model, investigation window and sphere diameter [undistorted px],
    and optional colour ranges (``heavy_hsv`` etc.: [[lo x3], [hi x3]], OpenCV
    8-bit HSV or LAB) that override the learned colour classes."""

    path: Path
    fps: float | None
    camera_matrix: np.ndarray
    dist_coeffs: np.ndarray
    window: tuple[float, float, float, float]
    particle_diameter_px: float
    t0: float = 0.0
    colour_ranges: dict[str, np.ndarray] = field(default_factory=dict)

    def metadata(self) -> dict[str, Any]:
        """The map metadata fields (docs/formats.md) of this experiment."""
        return dict(name=self.name, heavy=self.heavy, light=self.light, rho_h=self.rho_h,
                    rho_l=self.rho_l, c0=self.c0, M_g=self.M_g, M_w=self.M_w)

    def reduced(self, k: int) -> Experiment:
        """This experiment as seen in its frames reduced k times (each pixel the mean of a k x k
        block, :func:`reduce_frame`): the same lens and bed on a sensor of 1/k the pixels. A
        reduced pixel's centre lies at k j + (k - 1) / 2 in the frame's pixels (centres at integers)."""
        if k == 1:
            return self
        shift = 0.5 * (k - 1)
        camera = self.camera_matrix.astype(float).copy()
        camera[:2, :2] /= k
        camera[:2, 2] = (camera[:2, 2] - shift) / k
        return replace(self, camera_matrix=camera, window=tuple((v - shift) / k for v in self.window),
                       particle_diameter_px=self.particle_diameter_px / k)

    def crop_origin(self) -> tuple[int, int]:
        """Top-left corner [px] of the undistorted crop the frames are analysed in: the window and a diameter."""
        m = int(np.ceil(self.particle_diameter_px))
        return int(np.floor(self.window[0])) - m, int(np.floor(self.window[1])) - m


def load_experiment(path: str | os.PathLike) -> Experiment:
    """Read ``experiment.json`` at ``path``; ValueError names the file and the bad field."""
    p = Path(path)
    raw = read_json(p, "experiment.json", "it must sit beside the frames or video; granseg init-experiment "
                                          "writes one")
    if not isinstance(raw, dict):
        raise ValueError(f"{p}: expected a JSON object with the experiment's fields")
    return _parse(p, raw)


def _parse(p: Path, raw: dict[str, Any]) -> Experiment:
    get = _Fields(p, raw)
    rho_h, rho_l = get.number("rho_h", lo=0), get.number("rho_l", lo=0)
    if rho_h < rho_l:
        raise ValueError(f"{p}: fields 'rho_h' and 'rho_l': the heavy density must not be below the light "
                         f"one ({rho_h} < {rho_l})")
    k = get.array("camera_matrix", (3, 3))
    if k[0, 0] <= 0 or k[1, 1] <= 0 or not np.allclose(k[2], [0, 0, 1]):
        raise ValueError(f"{p}: field 'camera_matrix': expected [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0")
    dist = get.array("dist_coeffs", None)
    if dist.size not in (4, 5, 8, 12, 14):
        raise ValueError(f"{p}: field 'dist_coeffs': expected 4, 5, 8, 12 or 14 numbers, got {dist.size}")
    window = get.array("window", (4,))
    if not (window[0] < window[2] and window[1] < window[3]):
        raise ValueError(f"{p}: field 'window': expected [x0, y0, x1, y1] with x0 < x1 and y0 < y1")
    return Experiment(
        path=p, **{f: get.text(f) for f in TEXT_FIELDS}, rho_h=rho_h, rho_l=rho_l,
        c0=get.number("c0", lo=0, hi=1), M_g=get.number("M_g", lo=0), M_w=get.number("M_w", lo=0),
        fps=get.number("fps", lo=0, required=False), camera_matrix=k, dist_coeffs=dist.ravel(),
        window=tuple(float(v) for v in window),
        particle_diameter_px=_diameter(p, get, window),
        t0=_start_time(p, get),
        colour_ranges={f: get.array(f, (2, 3)) for f in COLOUR_RANGES if f in raw},
    )


def _diameter(p: Path, get: _Fields, window: np.ndarray) -> float:
    """The sphere diameter [px]: at least 4 px to be detected, and a bed of spheres needs
    the window to hold at least one across and two in height (a bigger value would also ask
    OpenCV for gigabytes of template tables)."""
    d = get.number("particle_diameter_px", lo=4)
    width, height = window[2] - window[0], window[3] - window[1]
    if d > width or 2 * d > height:
        raise ValueError(f"{p}: field 'particle_diameter_px': {d:g} px does not fit the window "
                         f"({width:.0f} x {height:.0f} px): the window must hold at least one sphere across "
                         "and two in height")
    return d


def _start_time(p: Path, get: _Fields) -> float:
    """t0 [s], the time of the first frame since the shear started (0 when not given). Negative when
    the camera was started first: the frames before the plate moved are then left out
    (:func:`granseg.measure.pipeline.from_plate_start`)."""
    return get.number("t0", required=False) or 0.0


def _finite(value: int | float) -> bool:
    try:
        return math.isfinite(value)
    except OverflowError:  # an int beyond any float, e.g. 10**400 written in the JSON
        return False



class _Fields:
    """Typed access to the JSON fields, with messages naming file and field."""

    def __init__(self, path: Path, raw: dict[str, Any]):
        self.path, self.raw = path, raw

    def _get(self, key: str, required: bool = True) -> Any:
        if key not in self.raw or self.raw[key] is None:
            if required:
                raise ValueError(f"{self.path}: missing field '{key}'")
            return None
        return self.raw[key]

    def text(self, key: str) -> str:
        value = self._get(key)
        if not isinstance(value, str) or not value.strip():
            raise ValueError(f"{self.path}: field '{key}': expected a non-empty string, got {value!r}")
        return value

    def number(self, key: str, lo: float | None = None, hi: float | None = None,
               required: bool = True) -> float | None:
        value = self._get(key, required)
        if value is None:
            return None
        if isinstance(value, bool) or not isinstance(value, int | float) or not _finite(value):
            raise ValueError(f"{self.path}: field '{key}': expected a finite number, got {short_repr(value)}")
        if (lo is not None and value <= lo) or (hi is not None and value >= hi):
            raise ValueError(f"{self.path}: field '{key}': {value} outside ({lo}, {hi if hi is not None else 'inf'})")
        return float(value)

    def array(self, key: str, shape: tuple[int, ...] | None) -> np.ndarray:
        value = self._get(key)
        try:
            a = np.asarray(value, dtype=float)
        except (TypeError, ValueError, OverflowError):
            raise ValueError(f"{self.path}: field '{key}': expected finite numbers, got {short_repr(value)}") from None
        if (shape is not None and a.shape != shape) or (shape is None and a.ndim != 1):
            want = "a list of numbers" if shape is None else f"shape {shape}"
            raise ValueError(f"{self.path}: field '{key}': expected {want}, got shape {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{self.path}: field '{key}': values must be finite")
        return a
