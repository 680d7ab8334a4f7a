"""From camera frames to concentration maps (issue 3).

    analyze(path, ...)          frames directory or video -> map .npz
    calibrate_camera(dir, ...)  checkerboard photos -> camera_matrix, dist_coeffs
    detect_particles(img, d)    sphere centres in one undistorted image
    load_experiment(path)       read and check experiment.json

Stages, one module each: experiment (the JSON), sources (frames, video),
camera (undistortion, calibration), detect (spheres: learning, then per
frame templates -> matches over the sphere disk, outline -> centres), classify
(heavy or light by colour), layers (binning), pipeline (the run), preview
(images).

Names are imported lazily, as in :mod:`granseg`: the detector loads scikit-learn
and scipy.stats (about 2.5 s), which ``granseg init-experiment`` and
``granseg calibrate-camera`` (camera, sources) do not need.
"""

from __future__ import annotations

import importlib
from typing import Any

# public name -> the module that holds it
_LAZY: dict[str, str] = {
    "Analysis": "granseg.measure.pipeline",
    "BadFrameWarning": "granseg.measure.pipeline",
    "GreyFramesWarning": "granseg.measure.pipeline",
    "analyze": "granseg.measure.pipeline",
    "Experiment": "granseg.measure.experiment",
    "load_experiment": "granseg.measure.experiment",
    "Undistorter": "granseg.measure.camera",
    "calibrate_camera": "granseg.measure.camera",
    "detect_particles": "granseg.measure.detect",
}

__all__ = sorted(_LAZY)


def __getattr__(name: str) -> Any:
    try:
        module_name = _LAZY[name]
    except KeyError:
        raise AttributeError(f"module 'granseg.measure' has no attribute {name!r}") from None
    value = getattr(importlib.import_module(module_name), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return __all__
