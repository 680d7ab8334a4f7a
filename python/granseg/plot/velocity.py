"""Figures of a measured velocity profile (issue 12): the profile with its shear-band fit on
linear and log axes with the residuals (:func:`velocity_profile`), the tracks on a frame
(:func:`tracks_on_frame`), and delta/H against the normalised load over beds
(:func:`shear_band_law`)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import NullFormatter

from granseg.fit import FitResult, shear_band_velocity
from granseg.fit import shear_band_law as law_curve
from granseg.plot.base import H_LABEL, new_figure, style

__all__ = ["shear_band_law", "tracks_on_frame", "velocity_profile"]

V_LABEL = "streamwise speed v [m/s]"


def velocity_profile(prof: Any) -> Figure:
    """Three panels sharing the height axis: v(z) with the fit (linear), the same on a log
    speed axis (the exponential is a straight line there), and the residuals in errors."""
    z, v, e, H = prof.z, prof.v, prof.v_err, prof.H
    ok = np.isfinite(v) & np.isfinite(e)
    p = prof.fit.params
    v1 = p.get("v1", 0.0)
    zz = np.linspace(0, H, 200)
    curve = shear_band_velocity(zz, p["v0"], v1, p["delta_over_H"] * H)
    with style():
        fig = new_figure(7.2, 3.2)
        axes = fig.subplots(1, 3, sharey=True, gridspec_kw={"width_ratios": [1.2, 1.2, 0.8]})
        for ax, log in zip(axes[:2], (False, True), strict=True):
            ax.errorbar(v[ok], z[ok] / H, xerr=e[ok], fmt="o", ms=3.5, capsize=2, color="0.15",
                        label="measured (± 1 SE)")
            ax.plot(curve, zz / H, color="C3", lw=1.4, label="fit")
            ax.set_xlabel(V_LABEL + (" (log)" if log else ""))
            if log:
                ax.set_xscale("log")
                ax.xaxis.set_minor_formatter(NullFormatter())  # labelled minor ticks collide
        se = prof.fit.stderr
        axes[0].set_ylabel(H_LABEL)
        axes[0].legend(loc="upper right", fontsize=7, frameon=False)
        axes[0].set_title(fr"$\delta/H$ = {p['delta_over_H']:.3f} ± {se['delta_over_H']:.3f}", fontsize=9)
        resid = (v - shear_band_velocity(z, p["v0"], v1, p["delta_over_H"] * H)) / e
        axes[2].axvspan(-2, 2, color="0.9")
        axes[2].axvline(0, color="0.5", lw=0.8)
        axes[2].plot(resid[ok], z[ok] / H, "o", ms=3.5, color="C0")
        axes[2].set_xlabel("residual [SE]")
        axes[0].set_ylim(0, 1)
    return fig


def tracks_on_frame(image: np.ndarray, tracks: np.ndarray, window: Sequence[float], frame: int = 0,
                    length: int = 30) -> Figure:
    """The tracks that pass ``frame`` drawn over it (``length`` frames on either side), coloured
    by height; ``image`` is the undistorted BGR or grey frame, ``tracks`` (m, 6) as
    :class:`granseg.velocity.Recording` holds them (x, y [px] in columns 4-5)."""
    with style():
        fig = new_figure(5.0, 5.0 * image.shape[0] / image.shape[1])
        fig.set_layout_engine("none")  # the frame fills the figure
        ax = fig.add_axes((0, 0, 1, 1))
        rgb = image[..., ::-1] if image.ndim == 3 else image
        ax.imshow(rgb, cmap="gray" if image.ndim == 2 else None)
        ids = np.unique(tracks[tracks[:, 0] == frame, 1])
        near = np.isin(tracks[:, 1], ids) & (np.abs(tracks[:, 0] - frame) <= length)
        y0, y1 = window[1], window[3]
        for tid in ids:
            sel = near & (tracks[:, 1] == tid)
            pts = tracks[sel][np.argsort(tracks[sel, 0])]
            if len(pts) > 1:
                ax.plot(pts[:, 4], pts[:, 5], lw=1.0, color=_height_colour((y1 - pts[:, 5].mean()) / (y1 - y0)))
        ax.add_patch(_rectangle(window))
        ax.set_axis_off()
    return fig


def shear_band_law(M_tilde: np.ndarray, delta_over_H: np.ndarray, err: np.ndarray, fit: FitResult | None,
                   labels: Sequence[str] = (), diagnosed: tuple[float, float] | None = None) -> Figure:
    """delta/H of each bed against M~ = M_w / M_g with the fitted power law and its 95 % band
    (log-log, like the paper's inset); ``diagnosed`` = (delta/H_ref, exponent) draws the law a
    diagnosis fitted to concentration maps, to compare."""
    with style():
        fig = new_figure(3.6, 3.0)
        ax = fig.add_subplot()
        ax.errorbar(M_tilde, delta_over_H, yerr=err, fmt="o", ms=4, capsize=2, color="0.15", label="measured")
        for x, y, name in zip(M_tilde, delta_over_H, labels, strict=False):
            ax.annotate(name, (x, y), textcoords="offset points", xytext=(4, 3), fontsize=6)
        mm = np.geomspace(min(M_tilde) / 1.3, max(M_tilde) * 1.3, 100)
        if fit is not None:
            p = fit.params
            ax.plot(mm, law_curve(mm, p["delta_over_H_ref"], p["exponent"]), color="C3", lw=1.4,
                    label=fr"fit: exponent {p['exponent']:.2f} ± {fit.stderr['exponent']:.2f}")
        if diagnosed is not None:
            ax.plot(mm, law_curve(mm, *diagnosed), color="C0", lw=1.2, ls="--", label="diagnosis (maps)")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel(r"normalised load $\tilde M = M_w/M_g$ [-]")
        ax.set_ylabel(r"$\delta/H$ [-]")
        ax.legend(fontsize=7, frameon=False)
    return fig


def _height_colour(h: float) -> Any:
    from matplotlib import colormaps

    return colormaps["viridis"](float(np.clip(h, 0, 1)))


def _rectangle(window: Sequence[float]) -> Any:
    from matplotlib.patches import Rectangle

    x0, y0, x1, y1 = window
    return Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, ec="w", lw=0.8, ls="--")
