"""Synthetic data with exact ground truth: camera frames and virtual experiments.

``render_frames(c, ...)`` draws side-wall frames whose heavy share per layer
follows the map ``c`` (see :mod:`granseg.synth.frames`);
``render_checkerboard(...)`` draws a calibration target through a lens;
``campaign(...)`` builds a set of virtual experiments (granseg.synth.virtual),
measured under a named noise process (``NOISE_PROCESSES``, ``NoiseProcess``);
``SCENES`` names the renderer settings the detector is tested on;
``MIXTURE_SCENES`` (the paper's six mixtures, the other pairs of its five
materials, grey-on-grey pairs) and
``APPARATUS_SCENES`` (bumpy lid and plate, motion blur, wall reflections,
dust, wide-angle lens, JPEG and video) the harder looks it must yet handle;
``render_scene(name, n_t)`` renders any of them;
:mod:`granseg.synth.mishaps` alters rendered stills as a rig can go wrong
during a run (the view moved or turned, the lid risen).
"""

from __future__ import annotations

from typing import Any

from granseg.synth.frames import (
    MATERIAL_LOOKS,
    VIDEO_CODECS,
    RenderedFrames,
    default_camera,
    render_checkerboard,
    render_frames,
)
from granseg.synth.scenes import (
    APPARATUS_SCENES,
    MIXTURE_SCENES,
    SCENES,
    WIDE_ANGLE,
    mixing_map,
    render_scene,
    scene_names,
    unmixing_map,
)

__all__ = [
    "APPARATUS_SCENES", "MATERIAL_LOOKS", "MIXTURE_SCENES", "NOISE_PROCESSES", "SCENES", "TABLE1",
    "VIDEO_CODECS", "WIDE_ANGLE", "Condition", "NoiseProcess", "RenderedFrames", "campaign", "default_camera",
    "mixing_map", "random_conditions", "random_effect", "render_checkerboard", "render_frames", "render_scene",
    "scene_names", "unmixing_map",
]


_VIRTUAL = ("campaign", "Condition", "NOISE_PROCESSES", "NoiseProcess", "TABLE1", "random_conditions",
            "random_effect")


def __getattr__(name: str) -> Any:
    # virtual experiments need the compiled solver; load them on first use so
    # that rendering frames does not
    if name in _VIRTUAL:
        from granseg.synth import virtual

        return getattr(virtual, name)
    raise AttributeError(f"module 'granseg.synth' has no attribute {name!r}")
