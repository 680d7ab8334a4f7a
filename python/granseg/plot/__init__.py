"""Publication figures (matplotlib, headless, PNG + PDF), every granseg figure in one place.

Every function builds and returns a :class:`matplotlib.figure.Figure`
without pyplot (no GUI, no global state, Agg canvas), in one consistent
style (:data:`STYLE`); :func:`save_figure` writes it as ``STEM.png`` and
``STEM.pdf`` atomically, refusing to replace existing files unless ``force``.

- :mod:`~granseg.plot.base`: the style, axis labels, cell edges, saving;
- :mod:`~granseg.plot.calibration`: a campaign's calibration and one model run
  (``map_comparison``, ``map_pages``, ``bottom_fits``, ``laws``, ``rmsd_grid``, ``profiles``,
  ``simulation``);
- :mod:`~granseg.plot.diagnosis`: the evidence of a diagnosis (``residual_maps``,
  ``covariates``, ``candidates``, ``gain``, ``before_after``; by name in
  ``FIGURES``). Loaded on first use: it needs the solver, the rest does not;
- :mod:`~granseg.plot.views`: a run's camera view against its bulk (``view_comparison``).

Example::

    >>> fig = bottom_fits(campaign, fits.tanh)                  # doctest: +SKIP
    >>> save_figure(fig, "out/bottom")                          # doctest: +SKIP
    [PosixPath('out/bottom.png'), PosixPath('out/bottom.pdf')]
"""

from __future__ import annotations

import importlib
from typing import Any

from granseg.plot.base import C_LABEL, H_LABEL, STYLE, T_LABEL, save_figure, style
from granseg.plot.calibration import (
    bottom_fits,
    laws,
    map_comparison,
    map_pages,
    profiles,
    rmsd_grid,
    simulation,
)
from granseg.plot.views import view_comparison

_DIAGNOSIS = ("FIGURES", "residual_maps", "covariates", "candidates", "gain", "before_after")

__all__ = [
    "STYLE",
    "C_LABEL",
    "T_LABEL",
    "H_LABEL",
    "style",
    "save_figure",
    "map_comparison",
    "map_pages",
    "bottom_fits",
    "laws",
    "rmsd_grid",
    "profiles",
    "simulation",
    "view_comparison",
    *_DIAGNOSIS,
]


def __getattr__(name: str) -> Any:
    if name not in _DIAGNOSIS:
        raise AttributeError(f"module 'granseg.plot' has no attribute {name!r}")
    value = getattr(importlib.import_module("granseg.plot.diagnosis"), name)
    globals()[name] = value
    return value
