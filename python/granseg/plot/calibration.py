"""Figures of a campaign's calibration and of one model run.

Maps are drawn as the paper draws them: time t [s] on x, dimensionless
height H* = z / H on y, the initial profile c(H*, 0) in a panel at the left.

Example::

    >>> fig = map_comparison(campaign[0], cal.model_layers[0], H=0.06)  # doctest: +SKIP
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from granseg.fit import FitResult, beta_law, tanh_curve, tau_law
from granseg.plot.base import (
    C_LABEL,
    H_LABEL,
    T_LABEL,
    edges,
    map_edges,
    new_figure,
    style,
    time_edges,
)

__all__ = ["map_comparison", "bottom_fits", "laws", "rmsd_grid", "profiles", "simulation"]


# --------------------------------------------------------------------------- maps


def map_comparison(measured: Any, model: np.ndarray, *, H: float, rmsd: float | None = None,
                   initial: tuple[np.ndarray, np.ndarray] | None = None) -> Figure:
    """Measured map, model map and their residual side by side.

    ``measured`` is a :class:`granseg.maps.Map`; ``model`` (n_t, n_layers) the
    model's layer means at the measured times (what the RMSD compares);
    ``H`` [m] the bed height; ``initial`` optionally the model's initial
    profile (z [m], c [-]) on a fine grid, drawn in the left panel with the
    first measured row.
    """
    model = np.asarray(model, dtype=float)
    if model.shape != measured.c.shape:
        raise ValueError(f"model map shape {model.shape} != measured {measured.c.shape} ({measured.name})")
    resid = measured.c - model
    with style():
        fig = new_figure(7.2, 2.4)
        axes = fig.subplots(1, 4, sharey=True, gridspec_kw={"width_ratios": [0.32, 1, 1, 1]})
        te, ze = map_edges(measured, H)
        _initial_panel(axes[0], measured, model, H, initial)
        kw = {"shading": "flat", "rasterized": True}
        m1 = axes[1].pcolormesh(te, ze, measured.c.T, vmin=0, vmax=1, cmap="viridis", **kw)
        axes[2].pcolormesh(te, ze, model.T, vmin=0, vmax=1, cmap="viridis", **kw)
        lim = max(float(np.nanmax(np.abs(resid))), 1e-3)
        m3 = axes[3].pcolormesh(te, ze, resid.T, vmin=-lim, vmax=lim, cmap="RdBu_r", **kw)
        for ax, title in zip(axes[1:], ("measured", "model", "measured - model"), strict=True):
            ax.set_title(title)
            ax.set_xlabel(T_LABEL)
            ax.set_ylim(ze[0], ze[-1])
        fig.colorbar(m1, ax=axes[1:3], label=C_LABEL, shrink=0.9, pad=0.01)
        fig.colorbar(m3, ax=axes[3], label=r"residual $\Delta c$ [-]", shrink=0.9, pad=0.01)
        head = f"{measured.name}: {measured.heavy}/{measured.light}, " \
               rf"$\delta_R$ = {measured.delta_R:.2f}, $c_0$ = {measured.c0:.2f}"
        fig.suptitle(head + ("" if rmsd is None else f", RMSD = {rmsd:.3f}"), fontsize=9)
    return fig


def _initial_panel(ax: Any, measured: Any, model: np.ndarray, H: float,
                   initial: tuple[np.ndarray, np.ndarray] | None) -> None:
    ax.plot(measured.c[0], measured.z / H, "o", color="#D55E00", ms=3, label="measured")
    ax.plot(model[0], measured.z / H, "s", mfc="none", color="#0072B2", ms=3, label="model layers")
    if initial is not None:
        ax.plot(initial[1], np.asarray(initial[0]) / H, "-", color="#0072B2", lw=1, label="model")
    ax.set_xlim(-0.05, 1.05)
    ax.set_xticks([0, 0.5, 1])
    ax.set_xlabel(r"$c(t_0)$ [-]")
    ax.set_ylabel(H_LABEL)
    ax.set_title("initial", loc="left")
    ax.legend(loc="lower left", bbox_to_anchor=(-0.1, -0.62), fontsize=6.5, handlelength=1)


# --------------------------------------------------------------------------- curves


def bottom_fits(maps: Sequence[Any], fits: Mapping[str, FitResult]) -> Figure:
    """Bottom-layer series c[:, 0] of each map (markers) with its tanh fit (dashed).

    Maps without a fit in ``fits`` are drawn without a curve.
    """
    with style():
        fig = new_figure(5.2, 3.3)
        ax = fig.subplots()
        for i, m in enumerate(maps):
            color = f"C{i % 8}"
            every = max(1, m.n_times // 60)
            ax.plot(m.t[::every], m.bottom[::every], "o", ms=2.5, alpha=0.55, color=color,
                    mec="none")
            label = rf"{m.name} ($\delta_R$ = {m.delta_R:.2f})"
            if m.name in fits:
                f = fits[m.name]
                tt = np.linspace(m.t[0], m.t[-1], 400)
                ax.plot(tt, tanh_curve(tt, f["A"], f["t0"], f["tau"]), "--", color=color,
                        label=label + ("" if f.converged else " (not converged)"))
            else:
                ax.plot([], [], "o", color=color, label=label + " (no fit)")
        ax.set_xlabel(T_LABEL)
        ax.set_ylabel(r"bottom-layer concentration $c_b$ [-]")
        ax.set_ylim(-0.02, 1.02)
        ax.legend(loc="center left", bbox_to_anchor=(1.0, 0.5), ncols=1 if len(maps) <= 12 else 2)
        ax.set_title("bottom concentration: data (markers) and tanh fits (dashed)", loc="left")
    return fig


def laws(fits: Any) -> Figure:
    """A and tau of every tanh fit against delta_R, with the fitted laws.

    ``fits`` is a :class:`granseg.fit.CampaignFits`. Points of experiments
    used for the laws are filled; the others hollow.
    """
    with style():
        fig = new_figure(6.4, 2.7)
        ax_a, ax_t = fig.subplots(1, 2)
        _law_panel(ax_a, fits, "A", fits.beta, "final bottom concentration $A$ [-]")
        _law_panel(ax_t, fits, "tau", fits.tau, r"time to 88 % $\tau$ [s]")
    return fig


def _law_panel(ax: Any, fits: Any, key: str, law: FitResult | None, ylabel: str) -> None:
    names = list(fits.tanh)
    x = np.array([fits.delta_R[n] for n in names])
    y = np.array([fits.tanh[n][key] for n in names])
    err = np.array([fits.tanh[n].stderr[key] for n in names])
    used = np.array([n in fits.selected for n in names], dtype=bool)
    ax.errorbar(x[used], y[used], yerr=err[used], fmt="o", color="C0", capsize=2,
                label="experiments" if fits.c0 is None else f"$c_0$ = {fits.c0:g}")
    if np.any(~used):
        ax.errorbar(x[~used], y[~used], yerr=err[~used], fmt="o", mfc="white", color="C0",
                    capsize=2, label="other $c_0$ (not fitted)")
    if law is not None:
        xx = np.linspace(1.0, max(float(x.max()), 1.5) * 1.05, 300)
        if key == "A":
            yy = beta_law(xx, law["beta"])
            lab = rf"$1 - 1/(2\delta_R^\beta)$, $\beta$ = {law['beta']:.2f} $\pm$ {law.stderr['beta']:.2f}"
        else:
            yy = tau_law(xx, law["tau_1"], law["lam"])
            lab = rf"$\tau_1 e^{{-\lambda(\delta_R-1)}}$, $\lambda$ = {law['lam']:.2f} $\pm$ {law.stderr['lam']:.2f}"
        ax.plot(xx, yy, "-", color="C1", label=lab + f"\nMSE = {law.mse:.2g}")
    ax.set_xlabel(r"density ratio $\delta_R = \rho_h/\rho_l$ [-]")
    ax.set_ylabel(ylabel)
    ax.legend(loc="best")


# --------------------------------------------------------------------------- calibration


def rmsd_grid(points: Sequence[Mapping[str, float]], rmsd: Sequence[float], *,
              best: Mapping[str, float] | None = None,
              stderr: Mapping[str, float] | None = None, title: str = "mean RMSD") -> Figure:
    """Heat map of ``rmsd`` [-] over a two-parameter factorial grid.

    ``points`` are the grid points (dicts with the same two keys, full
    factorial); ``best``/``stderr`` mark the refined optimum with error bars.
    Grid values are drawn evenly spaced with their values as tick labels.
    """
    keys = list(points[0])
    if len(keys) != 2:
        raise ValueError(f"rmsd_grid: needs a grid of exactly two parameters, got {keys}")
    xs = sorted({p[keys[0]] for p in points})
    ys = sorted({p[keys[1]] for p in points})
    table = np.full((len(ys), len(xs)), np.nan)
    for p, r in zip(points, rmsd, strict=True):
        table[ys.index(p[keys[1]]), xs.index(p[keys[0]])] = r
    with style():
        fig = new_figure(3.9, 3.1)
        ax = fig.subplots()
        im = ax.pcolormesh(edges(np.array(xs)), edges(np.array(ys)), table, cmap="magma_r",
                           shading="flat")
        _annotate_cells(ax, xs, ys, table)
        if best is not None:
            _mark_best(ax, best, stderr or {}, keys)
            title += r"; $\star$ refined optimum $\pm$ 1 s.e."
        ax.set_xticks(xs)
        ax.set_yticks(ys)
        ax.set_xlabel(_param_label(keys[0]))
        ax.set_ylabel(_param_label(keys[1]))
        ax.set_title(title, loc="left")
        fig.colorbar(im, ax=ax, label="RMSD [-]")
    return fig


def _annotate_cells(ax: Any, xs: list, ys: list, table: np.ndarray) -> None:
    lo, hi = np.nanmin(table), np.nanmax(table)
    i_min = np.unravel_index(np.nanargmin(table), table.shape)
    for j, y in enumerate(ys):
        for i, x in enumerate(xs):
            v = table[j, i]
            dark = (v - lo) > 0.55 * (hi - lo) if hi > lo else False
            weight = "bold" if (j, i) == i_min else "normal"
            ax.text(x, y, f"{v:.3f}", ha="center", va="center", fontsize=7.5, weight=weight,
                    color="white" if dark else "black")


def _mark_best(ax: Any, best: Mapping[str, float], stderr: Mapping[str, float], keys: list) -> None:
    x, y = best[keys[0]], best[keys[1]]
    ax.errorbar([x], [y], xerr=[stderr.get(keys[0], 0.0) or 0.0],
                yerr=[stderr.get(keys[1], 0.0) or 0.0], fmt="*", ms=11, color="#00A0FF",
                mec="white", mew=0.6, capsize=3)


_LABELS = {"k": "friction correction $k$ [-]", "delta_over_H": r"shear-band decay $\delta/H$ [-]",
           "b": "diffusion constant $b$ [-]", "v1": "top slip speed $v_1$ [m/s]"}


def _param_label(key: str) -> str:
    return _LABELS.get(key, key)


def profiles(params: Mapping[str, float], *, deltas: Sequence[float] = (),
             delta_err: float | None = None) -> Figure:
    """Velocity v(z) [m/s] and shear rate |dv/dz| [1/s] against H* (docs/model.md closures).

    ``params`` needs ``rpm``, ``D_out`` [m], ``v1`` [m/s], ``H`` [m] and the
    calibrated ``delta_over_H``; ``deltas`` are further delta/H values (the
    grid) drawn thin; ``delta_err`` shades delta/H +- its standard error.
    """
    H = float(params["H"])
    v0 = float(params["rpm"]) * 2 * np.pi / 60 * float(params["D_out"]) / 2
    v1 = float(params["v1"])
    z = np.linspace(0.0, H, 300)

    def vel(dh: float) -> tuple[np.ndarray, np.ndarray]:
        d = dh * H
        return v1 + (v0 - v1) * np.exp(-z / d), (v0 - v1) / d * np.exp(-z / d)

    with style():
        fig = new_figure(5.6, 2.8)
        ax_v, ax_g = fig.subplots(1, 2, sharey=True)
        for dh in deltas:
            v, g = vel(dh)
            ax_v.plot(v, z / H, color="0.7", lw=0.8)
            ax_g.plot(g, z / H, color="0.7", lw=0.8)
        best = float(params["delta_over_H"])
        if delta_err:
            lo_v, lo_g = vel(max(best - delta_err, 1e-6))
            hi_v, hi_g = vel(best + delta_err)
            ax_v.fill_betweenx(z / H, lo_v, hi_v, color="C0", alpha=0.25, lw=0)
            ax_g.fill_betweenx(z / H, lo_g, hi_g, color="C0", alpha=0.25, lw=0)
        v, g = vel(best)
        err = rf" $\pm$ {delta_err:.3f}" if delta_err else ""
        ax_v.plot(v, z / H, color="C0", label=rf"calibrated $\delta/H$ = {best:.3f}{err}")
        ax_g.plot(g, z / H, color="C0")
        if deltas:
            ax_v.plot([], [], color="0.7", lw=0.8, label="grid values")
        ax_v.set_title("velocity profile", loc="left")
        ax_g.set_title("shear-rate profile", loc="left")
        ax_v.set_xlabel("velocity $v$ [m/s]")
        ax_g.set_xlabel(r"shear rate $\dot\gamma$ [1/s]")
        ax_g.set_xscale("log")
        ax_v.set_ylabel(H_LABEL)
        ax_v.set_ylim(0, 1)
        ax_v.legend(loc="upper right")
    return fig


# --------------------------------------------------------------------------- one run


def simulation(sol: Any, *, steady: tuple[np.ndarray, np.ndarray] | None = None,
               fit: FitResult | None = None, title: str = "") -> Figure:
    """One model run: the 15-layer map, profiles at chosen times, the bottom layer.

    ``sol`` is a :class:`granseg.model.Solution`; ``steady`` optionally the
    direct steady-state profile (z [m], c [-]); ``fit`` the tanh fit of the
    bottom layer, drawn dashed.
    """
    H = sol.params["H"]
    layers = sol.layers()
    n_layers = layers.shape[1]
    with style():
        fig = new_figure(7.2, 2.5)
        axes = fig.subplots(1, 3, gridspec_kw={"width_ratios": [1.35, 0.75, 1]})
        te = time_edges(sol.t)
        ze = np.linspace(0.0, 1.0, n_layers + 1)
        mesh = axes[0].pcolormesh(te, ze, layers.T, vmin=0, vmax=1, cmap="viridis",
                                  shading="flat", rasterized=True)
        axes[0].set_xlabel(T_LABEL)
        axes[0].set_ylabel(H_LABEL)
        axes[0].set_title("layer means (camera view)", loc="left")
        fig.colorbar(mesh, ax=axes[0], label=C_LABEL, pad=0.01)
        _profile_panel(axes[1], sol, H, steady)
        _bottom_panel(axes[2], sol.t, layers[:, 0], fit)
        if title:
            fig.suptitle(title, fontsize=9)
    return fig


def _profile_panel(ax: Any, sol: Any, H: float, steady: tuple[np.ndarray, np.ndarray] | None) -> None:
    picks = np.unique(np.searchsorted(sol.t, np.array([0.0, 0.1, 0.3, 1.0]) * sol.t[-1]).clip(0, sol.t.size - 1))
    for i in picks:
        ax.plot(sol.c[i], sol.z / H, label=f"t = {sol.t[i]:.0f} s")
    if steady is not None:
        ax.plot(steady[1], np.asarray(steady[0]) / H, "k--", lw=1, label="steady state")
    ax.set_xlim(-0.03, 1.03)
    ax.set_ylim(0, 1)
    ax.set_xlabel(C_LABEL)
    ax.set_ylabel(H_LABEL)
    ax.set_title("profiles", loc="left")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.3), ncol=2, fontsize=6.5,
              columnspacing=0.8, handlelength=1.2)


def _bottom_panel(ax: Any, t: np.ndarray, bottom: np.ndarray, fit: FitResult | None) -> None:
    ax.plot(t, bottom, color="#0072B2", label="model, layer 0")
    if fit is not None:
        p = fit.params
        ax.plot(t, tanh_curve(t, p["A"], p["t0"], p["tau"]), "--", color="#D55E00", label="tanh fit")
        ax.text(0.97, 0.52, f"A = {p['A']:.3f}\n$t_0$ = {p['t0']:.0f} s\n" + rf"$\tau$ = {p['tau']:.0f} s",
                transform=ax.transAxes, ha="right", va="center", fontsize=7)
    ax.set_ylim(-0.02, 1.02)
    ax.set_xlabel(T_LABEL)
    ax.set_ylabel(r"bottom layer $c_b$ [-]")
    ax.set_title("bottom concentration", loc="left")
    ax.legend(loc="lower right", fontsize=6.5)
    if fit is not None:
        ax.legend(loc="lower right", bbox_to_anchor=(1.0, 0.02), fontsize=6.5)
