"""High-speed footage of a pure bed whose velocity profile is known (issue 12's test data).

The side-wall renderer (:func:`granseg.synth.frames.render_frames`) moves every
half-diameter band of the bed at exactly the mean of docs/model.md's profile
v(z) = v1 + (v0 - v1) exp(-z / delta) over its grains (``exact_speeds``), with the
bumpy plate moving at v0 and each grain smeared over the distance it travels while the
shutter is open. A recording is one frame rate; :func:`render_recordings` makes the
paper's set (slow, medium and fast cameras) of one bed.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from granseg.constants import D_P, N_LAYERS
from granseg.model import derived
from granseg.synth.frames import RenderedFrames, render_frames

__all__ = ["render_highspeed", "render_recordings"]

#: Largest motion blur the renderer draws [diameters].
MAX_SMEAR = 5.0


def render_highspeed(
    out_dir: str | os.PathLike | None = None,
    *,
    delta_over_H: float = 0.18,
    v0: float | None = None,
    v1: float = 0.0,
    fps: float = 100.0,
    n_frames: int = 60,
    exposure_s: float | None = None,
    material: str = "glass",
    particle_diameter_px: float = 24.0,
    image_size: tuple[int, int] | None = None,
    bumps: bool = True,
    seed: int = 0,
    force: bool = False,
    **look: Any,
) -> RenderedFrames:
    """Render ``n_frames`` frames at ``fps`` [1/s] of a bed of ``material`` sheared with the
    profile (``v0``, ``v1`` [m/s], default docs/model.md's plate speed and 0; ``delta_over_H``
    [-] of a 15-diameter bed); ``exposure_s`` [s] is the shutter time (default half the
    frame interval), which smears each grain over the distance it moves meanwhile.

    ``experiment.json`` records the truth as ``velocity_truth`` and ``wall_radius`` = 0
    (the renderer draws the wall unrolled, flat). Other keywords go to ``render_frames``.
    """
    v0 = derived()["v0"] if v0 is None else float(v0)
    for name, value, ok in (("fps", fps, fps > 0), ("v0", v0, v0 > 0), ("v1", v1, 0 <= v1 < v0),
                            ("delta_over_H", delta_over_H, 0 < delta_over_H <= 2),
                            ("n_frames", n_frames, n_frames >= 2)):
        if not (np.isfinite(value) and ok):
            raise ValueError(f"render_highspeed: {name} = {value!r} is out of range")
    d = float(particle_diameter_px)
    exposure = 0.5 / fps if exposure_s is None else float(exposure_s)
    if not 0 <= exposure <= 1 / fps:
        raise ValueError(f"render_highspeed: exposure_s = {exposure_s!r} must lie in [0, 1/fps]")
    shift = v0 / fps / D_P * d  # the plate's travel per frame [px]
    smear = min(v0 * exposure / D_P, MAX_SMEAR)
    size = image_size or (int(round(11 * d)) + 16, int(round((N_LAYERS + 3) * d)))
    truth = {"v0": v0, "v1": float(v1), "delta_over_H": float(delta_over_H), "H": N_LAYERS * D_P,
             "exposure_s": exposure}
    return render_frames(
        np.ones((int(n_frames), N_LAYERS)), heavy=material, light="pp", particle_diameter_px=d,
        image_size=size, bottom_shift_px=shift, delta_over_H=delta_over_H, lid_slip=v1 / v0,
        exact_speeds=True, smear_diameters=smear, bumps=bumps, fps=fps, seed=seed, out_dir=out_dir,
        force=force, experiment={"name": f"highspeed-{material}-{fps:g}fps", "wall_radius": 0.0,
                                 "velocity_truth": truth, **look.pop("experiment", {})},
        **look)


def render_recordings(out_root: str | os.PathLike, *, fps: Sequence[float] = (24.0, 100.0, 1000.0),
                      n_frames: int | Sequence[int] = 60, seed: int = 0, force: bool = False,
                      **kw: Any) -> list[Path]:
    """One bed filmed at each of ``fps``: a recording per frame rate under ``out_root``
    (``fps_24``, ...), each with its own seed (``seed`` + i). Returns their directories."""
    counts = [int(n_frames)] * len(fps) if np.isscalar(n_frames) else [int(n) for n in n_frames]
    if len(counts) != len(fps):
        raise ValueError(f"render_recordings: {len(counts)} frame counts for {len(fps)} frame rates")
    out = []
    for i, (f, n) in enumerate(zip(fps, counts, strict=True)):
        path = Path(out_root) / f"fps_{f:g}"
        render_highspeed(path, fps=f, n_frames=n, seed=seed + i, force=force, **kw)
        out.append(path)
    return out
