"""Named settings of :func:`granseg.synth.render_frames` that a sphere detector must handle.

Three groups:

``SCENES`` -- the looks the detector is tested and benchmarked on (the
measurement tests, tests/test_measure_accuracy.py, and the accuracy
benchmark, benches/bench_measure_accuracy.py, render every one of them).
Each is a dict of keyword arguments: the two materials, the lamps, the lens,
blur, noise and compression. Together they cover the five materials of the
paper's mixtures (steel, ceramic, glass, dark POM, coloured PP), a single
side lamp (the hardest shading), a strong barrel lens, heavy JPEG
compression, and spheres 20 to 64 px across.

``MIXTURE_SCENES`` -- every mixture of the paper's Table 1 (S-PP, S-POM,
C-PP, G-PP, POM-PP, G-POM) at one of its heavy fractions, the two pairs of
its five materials that neither Table 1 nor SCENES holds (steel over glass,
S-G-50; ceramic over POM, C-POM-25), and grey-on-grey
pairs whose materials differ only in brightness and/or gloss: polished
steel over dark-grey POM (S-POM-25), matte light-grey POM over glossy grey
PP of the same mean brightness (grey-matte-glossy), satin steel over
light-grey POM of the same mean brightness (grey-steel-pom).

``APPARATUS_SCENES`` -- the paper's cell as a GoPro films it: the bumpy lid
and plate (hemispheres that are not grains), motion blur of the fast lower
layers (0.17 m/s at 1/60 s: 0.47 D), the lamps' reflections on the curved
PMMA wall, dust and scratches, a wide-angle lens, JPEG or lossy video
(MPEG-4 Part 2; H.264 needs PyAV), together, and each feature alone on S-PP.

The detector is not yet expected to pass the last two groups; they are
there so that its tests can show where it fails. Their dicts are
render_frames keyword arguments plus an optional ``c0``: the heavy fraction
the map starts from (heavy on top above (1 - c0) H; default 0.5), which is
a setting of :func:`mixing_map`, not of render_frames. :func:`render_scene`
renders any scene by name; by hand::

    look = dict(MIXTURE_SCENES["S-POM-25"])
    c0 = look.pop("c0", 0.5)
    r = render_frames(mixing_map(6, c0=c0), seed=7, **look)
"""

from __future__ import annotations

from typing import Any

import numpy as np

from granseg.synth.frames import render_frames

__all__ = ["APPARATUS_SCENES", "MIXTURE_SCENES", "SCENES", "WIDE_ANGLE", "mixing_map", "render_scene",
           "scene_names", "unmixing_map"]

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


def _paper(name: str, m_g: float) -> dict[str, Any]:
    """experiment.json fields of the paper's Table 1 run ``name`` (M_g [kg])."""
    return {"name": name, "M_g": m_g}


MIXTURE_SCENES: dict[str, dict[str, Any]] = {
    "S-PP-75": dict(heavy="steel", light="pp", c0=0.75, experiment=_paper("S-PP-75", 7.30)),
    # the case: polished steel over dark-grey POM, a quarter heavy;
    # they differ in brightness (a little) and gloss, hardly in hue
    "S-POM-25": dict(heavy="steel-polished", light="pom", c0=0.25, experiment=_paper("S-POM-25", 3.92)),
    # white ceramic over blue PP, nine tenths heavy: the light layer is one or two rows
    "C-PP-90": dict(heavy="ceramic", light="pp", c0=0.9, colours={"pp": (0.15, 0.35, 0.85)},
                    experiment=_paper("C-PP-90", 3.89)),
    "G-PP-50": dict(heavy="glass", light="pp", lighting="diffuse", experiment=_paper("G-PP-50", 2.04)),
    "POM-PP-50": dict(heavy="pom", light="pp", experiment=_paper("POM-PP-50", 1.62)),
    "G-POM-50": dict(heavy="glass", light="pom", experiment=_paper("G-POM-50", 2.52)),
    # the two pairs of the paper's five materials that neither its Table 1 nor
    # SCENES holds (ceramic-glass and steel-ceramic are there), so that every
    # pair is tested; M_g as Table 1 gives it: 1.2e-3 m^3 of solid times the
    # mean solid density
    "S-G-50": dict(heavy="steel", light="glass", experiment=_paper("S-G-50", 6.15)),
    "C-POM-25": dict(heavy="ceramic", light="pom", c0=0.25, experiment=_paper("C-POM-25", 2.63)),
    # grey on grey: matte light-grey POM over glossy grey PP, mean brightness within 2 %
    "grey-matte-glossy": dict(heavy="pom-grey", light="pp-grey", experiment=_paper("POM-PP-50", 1.62)),
    # grey on grey: satin steel over light-grey POM of the same mean brightness
    "grey-steel-pom": dict(heavy="steel", light="pom-grey", experiment=_paper("S-POM-50", 5.73)),
}

#: A GoPro-like wide-angle lens (strong barrel distortion), OpenCV k1 k2 p1 p2 k3.
WIDE_ANGLE = [-0.32, 0.11, 0.0005, -0.0004, -0.015]

# What the paper's cell adds to every frame: the bumpy lid and plate, the
# plate's motion blur (0.17 m/s x 1/60 s / 6 mm), the lamps' reflections on
# the PMMA wall, dust and scratches, a wide-angle lens.
_CELL = dict(bumps=True, smear_diameters=0.47, wall_reflections=1.0, dust=40, dist_coeffs=WIDE_ANGLE)

APPARATUS_SCENES: dict[str, dict[str, Any]] = {
    "apparatus-S-PP-75-jpeg": dict(heavy="steel", light="pp", c0=0.75, jpeg_quality=75, **_CELL,
                                   experiment=_paper("S-PP-75", 7.30)),
    "apparatus-G-POM-50-jpeg": dict(heavy="glass", light="pom", jpeg_quality=75, **_CELL,
                                    experiment=_paper("G-POM-50", 2.52)),
    "apparatus-grey-matte-glossy-jpeg": dict(heavy="pom-grey", light="pp-grey", jpeg_quality=75, **_CELL,
                                             experiment=_paper("POM-PP-50", 1.62)),
    # video from the camera: MPEG-4 Part 2 at OpenCV's bitrate (PSNR about 34 dB)
    "apparatus-S-POM-25-mp4v": dict(heavy="steel-polished", light="pom", c0=0.25, video="mp4v", **_CELL,
                                    experiment=_paper("S-POM-25", 3.92)),
    # H.264 at 0.25 bit per pixel and frame (PSNR 31-35 dB); needs PyAV (pip install av)
    "apparatus-C-PP-50-h264": dict(heavy="ceramic", light="pp", video="h264", **_CELL,
                                   experiment=_paper("C-PP-50", 2.67)),
    # one feature at a time, on the easy S-PP look
    "bumps-S-PP": dict(heavy="steel", light="pp", bumps=True),
    "motion-blur-S-PP": dict(heavy="steel", light="pp", smear_diameters=0.47),
    "reflections-dust-S-PP": dict(heavy="steel", light="pp", wall_reflections=1.0, dust=40),
    "wide-angle-jpeg-S-PP": dict(heavy="steel", light="pp", dist_coeffs=WIDE_ANGLE, jpeg_quality=75),
}


def scene_names() -> list[str]:
    """Every scene of the three groups (SCENES, MIXTURE_SCENES, APPARATUS_SCENES)."""
    return [*SCENES, *MIXTURE_SCENES, *APPARATUS_SCENES]


def mixing_map(n_t: int, n_layers: int = 15, c0: float = 0.5) -> np.ndarray:
    """A heavy-share map to render: the heavy layer on top at t = 0, relaxing linearly to a graded profile.

    (n_t, n_layers), layer 0 at the bottom. At t = 0 the layers above
    (1 - c0) H are heavy; the last frame runs linearly from c0 + 0.4 m at
    the bottom to c0 - 0.4 m at the top, m = 2 min(c0, 1 - c0) (for c0 = 0.5:
    0.7 to 0.3), so the mean share stays near c0.
    """
    if not 0 < c0 < 1:
        raise ValueError(f"c0 must be in (0, 1), got {c0!r}")
    z = (np.arange(n_layers) + 0.5) / n_layers
    t = np.linspace(0, 1, n_t)[:, None]
    final = c0 + 0.8 * min(c0, 1 - c0) * (0.5 - z)
    return np.clip(np.where(z > 1 - c0, 1.0, 0.0) * (1 - t) + final * t, 0, 1)


def unmixing_map(n_t: int, n_layers: int = 15, c0: float = 0.5) -> np.ndarray:
    """A heavy-share map to render: the heavy layer on top at t = 0, sinking linearly until the last
    frame is un-mixed the other way up (heavy below c0 H, light above), as a large density ratio
    leaves a run. (n_t, n_layers), layer 0 at the bottom."""
    if not 0 < c0 < 1:
        raise ValueError(f"c0 must be in (0, 1), got {c0!r}")
    z = (np.arange(n_layers) + 0.5) / n_layers
    t = np.linspace(0, 1, n_t)[:, None]
    return np.where(z > 1 - c0, 1.0, 0.0) * (1 - t) + np.where(z < c0, 1.0, 0.0) * t


def render_scene(name: str, n_t: int = 6, end: str = "graded", **overrides: Any):
    """Render the named scene (any group) over ``mixing_map(n_t, c0=...)`` (``end`` "graded") or
    ``unmixing_map`` ("unmixed"); ``overrides`` are render_frames keyword arguments (seed, out_dir,
    image_size, ...) and may set ``c0``."""
    maps = {"graded": mixing_map, "unmixed": unmixing_map}
    if end not in maps:
        raise ValueError(f"end: expected one of {sorted(maps)}, got {end!r}")
    for group in (SCENES, MIXTURE_SCENES, APPARATUS_SCENES):
        if name in group:
            look = {**group[name], **overrides}
            c0 = look.pop("c0", 0.5)
            return render_frames(maps[end](n_t, c0=c0), **look)
    raise ValueError(f"unknown scene {name!r}; choose from {scene_names()}")
