"""The camera's view against the bulk: one run's views of the same bed, side by side.

A DEM run gives two maps of one bed (:func:`granseg.maps.views_of`): the grains touching
the side walls (what a camera sees) and all grains (the bed the model describes).
:func:`view_comparison` draws, for each run, both maps, their difference and each view's
depth-mean heavy share against time, with the band the window check allows
(:func:`granseg.measure.quality.depth_mean_check`): a fair view stays inside it.

Example::

    >>> fig = view_comparison([views_of(campaign[0])])           # doctest: +SKIP
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from granseg.constants import D_P, N_LAYERS
from granseg.plot.base import (
    C_LABEL,
    H_LABEL,
    STYLE,
    T_LABEL,
    literal,
    map_edges,
    new_figure,
    style,
)

__all__ = ["view_comparison", "depth_mean"]

#: views drawn left to right, and their colours in the depth-mean panel
ORDER = ("bulk", "wall")
COLOURS = dict(zip(ORDER, STYLE["axes.prop_cycle"].by_key()["color"], strict=False))


def depth_mean(m: Any) -> np.ndarray:
    """Depth-mean heavy share of map ``m`` at each time: by count where the map has counts
    (what the window check judges), else the mean of its layers."""
    if m.n is not None and m.n_heavy is not None:
        total = m.n.sum(axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(total > 0, m.n_heavy.sum(axis=1) / total, np.nan)
    return np.nanmean(m.c, axis=1)


def _height(m: Any) -> float:
    return float(m.cell.get("H", N_LAYERS * D_P))  # docs/model.md's bed unless the map carries its own


def view_comparison(runs: Sequence[Mapping[str, Any]], max_runs: int = 8) -> Figure:
    """A row per run (a ``{view: Map}`` holding ``bulk`` and ``wall``): bulk map, wall map,
    wall - bulk, and each view's depth-mean heavy share against time with the window check's
    band around the bulk's initial share (the last third, which the check judges, shaded).
    At most ``max_runs`` rows (the first ones), so the figure stays readable."""
    runs = [r for r in runs if all(v in r for v in ORDER)][:max_runs]
    if not runs:
        raise ValueError("view_comparison needs at least one run with both a bulk and a wall view")
    with style():
        fig = new_figure(7.2, 1.55 * len(runs) + 0.6)
        axes = np.atleast_2d(fig.subplots(len(runs), 4, gridspec_kw={"width_ratios": [1, 1, 1, 1.1]}))
        meshes = [None, None]
        for row, run in zip(axes, runs, strict=True):
            meshes = _map_panels(row[:3], run)
            _depth_mean_panel(row[3], run)
        for ax, title in zip(axes[0], ("bulk: all grains", "wall: grains at the walls", "wall $-$ bulk",
                                       "depth-mean heavy share"), strict=True):
            ax.set_title(title, fontsize=7.5)
        for ax in axes[-1]:
            ax.set_xlabel(T_LABEL, fontsize=7.5)
        fig.colorbar(meshes[0], ax=axes[-1, :2], location="bottom", label=C_LABEL, shrink=0.7, aspect=35)
        fig.colorbar(meshes[1], ax=axes[-1, 2], location="bottom", label=r"wall $-$ bulk $\Delta c$ [-]",
                     shrink=0.9, aspect=17)
        axes[0, 3].legend(loc="best", fontsize=6.5, handlelength=1.2)
    return fig


def _map_panels(axes: Sequence[Any], run: Mapping[str, Any]) -> list[Any]:
    bulk, wall = run["bulk"], run["wall"]
    te, ze = map_edges(bulk, _height(bulk))
    kw = {"shading": "flat", "rasterized": True}
    m1 = axes[0].pcolormesh(te, ze, bulk.c.T, vmin=0, vmax=1, cmap="viridis", **kw)
    same = wall.c.shape == bulk.c.shape
    axes[1].pcolormesh(*map_edges(wall, _height(wall)), wall.c.T, vmin=0, vmax=1, cmap="viridis", **kw)
    diff = wall.c - bulk.c if same else np.full(bulk.c.shape, np.nan)
    m2 = axes[2].pcolormesh(te, ze, diff.T, vmin=-0.6, vmax=0.6, cmap="RdBu_r", **kw)
    axes[0].set_ylabel(f"{literal(bulk.name)}\n{H_LABEL}", fontsize=7)
    for ax in axes:
        ax.tick_params(labelsize=6.5)
    for ax in axes[1:]:
        ax.tick_params(labelleft=False)
    return [m1, m2]


def _depth_mean_panel(ax: Any, run: Mapping[str, Any]) -> None:
    # imported here: the frame pipeline (scikit-learn and all) costs 1.5 s to import, which
    # every figure of granseg.plot, `granseg simulate`'s among them, would otherwise pay
    from granseg.measure.quality import window_check_of

    bulk = run["bulk"]
    ref = float(depth_mean(bulk)[0])
    ax.axhline(ref, color="0.4", lw=0.7, ls=":")
    for view in ORDER:
        m = run[view]
        colour = COLOURS[view]
        check = window_check_of(m)
        ax.plot(m.t, depth_mean(m), color=colour, lw=1.1,
                label=view + ("" if check is None else (" (fair)" if check.passed else " (flagged)")))
        if check is not None:
            ax.axhspan(ref - check.limit, ref + check.limit, color=colour, alpha=0.12, lw=0)
    n_t = len(bulk.t)
    ax.axvspan(bulk.t[n_t - max(1, n_t // 3)], bulk.t[-1], color="0.85", alpha=0.5, lw=0, zorder=0)
    ax.set_ylim(0, 1)
    ax.set_ylabel(r"$\langle c \rangle_z$ [-]", fontsize=7)
    ax.tick_params(labelsize=6.5)
