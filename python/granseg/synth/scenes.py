"""Named settings of :func:`granseg.synth.render_frames` that a sphere detector must handle.

Each scene is a dict of keyword arguments: the two materials, the lamps, the
lens, blur, noise and compression. Together they cover the five materials
of the paper's mixtures (steel, ceramic, glass, dark POM, coloured PP), a
single side lamp (the hardest shading), a strong barrel lens, heavy JPEG
compression, and spheres 20 to 64 px across. The measurement tests
(tests/test_measure_accuracy.py) and the accuracy benchmark
(benches/bench_measure_accuracy.py) render them; a user can render them to
see what the detector is tested on.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["SCENES", "mixing_map"]

SCENES: dict[str, dict[str, Any]] = {
    # white ceramic lit from the upper left: its shadowed rim is as dark as the gaps
    "ceramic-glass-left-jpeg": dict(heavy="ceramic", light="glass", lighting="left", jpeg_quality=60, noise=4),
    "steel-pp-two-sided": dict(heavy="steel", light="pp"),
    "glass-pp-front-strong-lens": dict(heavy="glass", light="pp", lighting="front",
                                       dist_coeffs=[-0.22, 0.06, 0, 0, 0], blur=1.2),
    # dark POM: its outline barely differs from the gaps, its lower rim is darker than them
    "glass-pom": dict(heavy="glass", light="pom"),
    "steel-ceramic-diffuse-small": dict(heavy="steel", light="ceramic", lighting="diffuse",
                                        particle_diameter_px=20, image_size=(400, 480)),
    # the window filling most of the frame, as when filming a 15 D bed with a 1200 px sensor
    "pom-pp-large": dict(heavy="pom", light="pp", particle_diameter_px=64, image_size=(1000, 1200)),
}


def mixing_map(n_t: int, n_layers: int = 15) -> np.ndarray:
    """A heavy-share map to render: the heavy layer on top at t = 0, relaxing linearly to a graded profile.

    (n_t, n_layers), layer 0 at the bottom; the last frame runs from 0.7 at
    the bottom to 0.3 at the top.
    """
    z = (np.arange(n_layers) + 0.5) / n_layers
    t = np.linspace(0, 1, n_t)[:, None]
    return np.clip(np.where(z > 0.5, 1.0, 0.0) * (1 - t) + (0.5 + 0.4 * (0.5 - z)) * t, 0, 1)
