"""Synthetic data with exact ground truth: camera frames and virtual experiments.

``render_frames(c, ...)`` draws side-wall frames whose heavy share per layer
follows the map ``c`` (see :mod:`granseg.synth.frames`);
``render_checkerboard(...)`` draws a calibration target through a lens;
``campaign(...)`` builds a set of virtual experiments (granseg.synth.virtual);
``SCENES`` names the renderer settings the detector is tested on.
"""

from __future__ import annotations

from typing import Any

from granseg.synth.frames import (
    MATERIAL_LOOKS,
    RenderedFrames,
    default_camera,
    render_checkerboard,
    render_frames,
)
from granseg.synth.scenes import SCENES, mixing_map

__all__ = [
    "MATERIAL_LOOKS", "SCENES", "TABLE1", "Condition", "RenderedFrames", "campaign", "default_camera",
    "mixing_map", "random_conditions", "random_effect", "render_checkerboard", "render_frames",
]


_VIRTUAL = ("campaign", "Condition", "TABLE1", "random_conditions", "random_effect")


def __getattr__(name: str) -> Any:
    # virtual experiments need the compiled solver; load them on first use so
    # that rendering frames does not
    if name in _VIRTUAL:
        from granseg.synth import virtual

        return getattr(virtual, name)
    raise AttributeError(f"module 'granseg.synth' has no attribute {name!r}")
