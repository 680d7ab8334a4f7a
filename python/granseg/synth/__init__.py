"""Synthetic data with exact ground truth: camera frames and virtual experiments.

``render_frames(c, ...)`` draws side-wall frames whose heavy share per layer
follows the map ``c`` (see :mod:`granseg.synth.frames`);
``render_checkerboard(...)`` draws a calibration target through a lens;
``campaign(...)`` builds a set of virtual experiments (granseg.synth.campaign).
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

__all__ = ["MATERIAL_LOOKS", "RenderedFrames", "campaign", "default_camera", "render_checkerboard", "render_frames"]


def campaign(*args: Any, **kwargs: Any) -> Any:
    """Virtual experiments; see :func:`granseg.synth.campaign.campaign` (loaded on first use)."""
    from granseg.synth.campaign import campaign as _campaign

    return _campaign(*args, **kwargs)
