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
"""

from __future__ import annotations

from granseg.measure.camera import Undistorter, calibrate_camera
from granseg.measure.detect import detect_particles
from granseg.measure.experiment import Experiment, load_experiment
from granseg.measure.pipeline import Analysis, BadFrameWarning, GreyFramesWarning, analyze

__all__ = ["Analysis", "BadFrameWarning", "GreyFramesWarning", "Experiment", "Undistorter", "analyze",
           "calibrate_camera", "detect_particles", "load_experiment"]
