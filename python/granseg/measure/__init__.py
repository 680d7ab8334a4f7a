"""From camera frames to concentration maps (issue 3).

    analyze(path, ...)          frames directory, TIFF stack or video -> map .npz
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

from granseg._lazy import lazy_names

# public name -> (the module that holds it, its name there)
_LAZY = {name: (module, name) for module, names in {
    "granseg.measure.pipeline": ("Analysis", "BadFrameWarning", "GreyFramesWarning", "analyze"),
    "granseg.measure.experiment": ("Experiment", "load_experiment"),
    "granseg.measure.camera": ("Undistorter", "calibrate_camera"),
    "granseg.measure.detect": ("detect_particles",),
}.items() for name in names}

__all__ = sorted(_LAZY)
__getattr__, __dir__ = lazy_names(__name__, _LAZY, __all__)
