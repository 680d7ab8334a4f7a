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
from matplotlib.lines import Line2D
from matplotlib.ticker import FuncFormatter, MaxNLocator

from granseg.fit import FitResult, beta_law, tanh_curve, tau_law
from granseg.plot.base import (
    C_LABEL,
    H_LABEL,
    T_LABEL,
    edges,
    literal,
    map_edges,
    new_figure,
    pm_text,
    style,
    time_edges,
)

__all__ = ["map_comparison", "map_pages", "ROWS_PER_PAGE", "bottom_fits", "laws", "rmsd_grid", "profiles", "simulation"]


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
        fig = new_figure(7.2, 2.6)
        axes = fig.subplots(1, 4, sharey=True, gridspec_kw={"width_ratios": [0.36, 1, 1, 1]})
        te, ze = map_edges(measured, H)
        _initial_panel(axes[0], measured, model, H, initial)
        kw = {"shading": "flat", "rasterized": True}
        m1 = axes[1].pcolormesh(te, ze, measured.c.T, vmin=0, vmax=1, cmap="viridis", **kw)
        axes[2].pcolormesh(te, ze, model.T, vmin=0, vmax=1, cmap="viridis", **kw)
        lim = max(float(np.nanmax(np.abs(resid))), 1e-3)
        m3 = axes[3].pcolormesh(te, ze, resid.T, vmin=-lim, vmax=lim, cmap="RdBu_r", **kw)
        for ax, title in zip(axes[1:], ("measured", "model", "measured $-$ model"), strict=True):
            ax.set_title(title)
            ax.set_xlabel(T_LABEL)
            ax.set_ylim(ze[0], ze[-1])
        # the initial panel is too narrow for its legend: one row under the figure, inside it
        fig.legend(*axes[0].get_legend_handles_labels(), loc="outside lower left", ncols=3, fontsize=6.5,
                   handlelength=1.2, columnspacing=1.2, title="initial profile:", title_fontsize=6.5,
                   alignment="left")
        fig.colorbar(m1, ax=axes[1:3], label=C_LABEL, shrink=0.9, pad=0.01)
        fig.colorbar(m3, ax=axes[3], label=r"measured $-$ model $\Delta c$ [-]", shrink=0.9, pad=0.01)
        head = f"{literal(measured.name)}: {literal(measured.heavy)}/{literal(measured.light)}, " \
               rf"$\delta_R$ = {measured.delta_R:.2f}, $c_0$ = {measured.c0:.2f}"
        fig.suptitle(head + ("" if rmsd is None else f", RMSD = {rmsd:.3f}"), fontsize=9)
    return fig


#: Experiments per page of :func:`map_pages`: six rows fill a journal page (7.2 in x 9.3 in).
ROWS_PER_PAGE = 6


def map_pages(measured: Sequence[Any], models: Sequence[np.ndarray], *, H: float | Sequence[float],
              rmsd: Sequence[float | None] | None = None,
              initial: Sequence[tuple[np.ndarray, np.ndarray] | None] | None = None,
              resid_lim: float | None = None, title: str = "") -> Figure:
    """Several experiments' measured map, model map and residual on one page, a row each.

    What :func:`map_comparison` shows for one experiment, for up to
    :data:`ROWS_PER_PAGE` of them: the initial profile, the measured map, the
    model map and measured - model, with the experiment named above its row.
    The colour scales are shared (the residual's is ``resid_lim``, by default
    the largest residual on the page; pass one value for every page of a
    campaign so the pages compare). For the report of a large campaign:
    the page is laid out by hand (no layout engine) and saved without
    trimming, so it costs a fraction of one figure per experiment.
    ``H`` [m] is the bed height (one per experiment or one for all).
    """
    n = len(measured)
    if not 1 <= n <= ROWS_PER_PAGE:
        raise ValueError(f"map_pages: 1 to {ROWS_PER_PAGE} experiments per page, got {n}")
    if len(models) != n:
        raise ValueError(f"map_pages: {n} measured maps but {len(models)} model maps")
    heights = [float(H)] * n if np.isscalar(H) else [float(h) for h in H]  # type: ignore[arg-type]
    rmsds = list(rmsd) if rmsd is not None else [None] * n
    inits = list(initial) if initial is not None else [None] * n
    models = [np.asarray(m, dtype=float) for m in models]
    for m, mod in zip(measured, models, strict=True):
        if mod.shape != m.c.shape:
            raise ValueError(f"model map shape {mod.shape} != measured {m.c.shape} ({m.name})")
    resids = [m.c - mod for m, mod in zip(measured, models, strict=True)]
    lim = resid_lim or max(max(float(np.nanmax(np.abs(r))) if np.any(np.isfinite(r)) else 0.0
                               for r in resids), 1e-3)
    # the page in inches: margins, four columns, rows with room for tick labels and the next row's name
    W, left, right, gap = 7.2, 0.62, 0.1, 0.1
    top, row_h, row_gap, bottom = 0.78, 0.85, 0.5, 1.1
    Hin = top + n * row_h + (n - 1) * row_gap + bottom
    unit = (W - left - right - 3 * gap) / 3.36
    widths = [0.36 * unit, unit, unit, unit]
    xs = np.concatenate([[left], left + np.cumsum(np.array(widths[:-1]) + gap)])
    with style():
        fig = Figure(figsize=(W, Hin))
        rows = []
        for r, (m, mod, res) in enumerate(zip(measured, models, resids, strict=True)):
            y0 = Hin - top - (r + 1) * row_h - r * row_gap
            ax0 = fig.add_axes((xs[0] / W, y0 / Hin, widths[0] / W, row_h / Hin))
            axes = [ax0] + [fig.add_axes((x / W, y0 / Hin, w / W, row_h / Hin), sharey=ax0)
                            for x, w in zip(xs[1:], widths[1:], strict=True)]
            axes[2].sharex(axes[1])
            axes[3].sharex(axes[1])
            rows.append(axes)
            te, ze = map_edges(m, heights[r])
            _initial_panel(axes[0], m, mod, heights[r], inits[r], compact=True)
            kw = {"shading": "flat", "rasterized": True}
            m1 = axes[1].pcolormesh(te, ze, m.c.T, vmin=0, vmax=1, cmap="viridis", **kw)
            axes[2].pcolormesh(te, ze, mod.T, vmin=0, vmax=1, cmap="viridis", **kw)
            m3 = axes[3].pcolormesh(te, ze, res.T, vmin=-lim, vmax=lim, cmap="RdBu_r", **kw)
            axes[0].set_ylim(ze[0], ze[-1])
            for ax in axes[1:]:
                ax.tick_params(labelleft=False)
                ax.xaxis.set_major_locator(MaxNLocator(5))
            head = (f"{literal(m.name)}: {literal(m.heavy)}/{literal(m.light)}, " + rf"$\delta_R$ = {m.delta_R:.2f}, "
                    rf"$c_0$ = {m.c0:.2f}" + ("" if rmsds[r] is None else f", RMSD = {rmsds[r]:.3f}"))
            fig.text(xs[0] / W, (y0 + row_h + 0.06) / Hin, head, ha="left", va="bottom", fontsize=7.5,
                     fontweight="bold")
        for ax in rows[-1][1:]:
            ax.set_xlabel(T_LABEL)
        rows[-1][0].set_xlabel(r"$c(t_0)$ [-]")
        for axes in rows[:-1]:
            axes[0].tick_params(labelbottom=True)
        # column headings above the first row, the page's title and the initial panel's legend above them
        first_top = 1 - top / Hin
        for x, w, label in zip(xs, widths, ("initial", "measured", "model", "measured $-$ model"), strict=True):
            fig.text((x + w / 2) / W, first_top + 0.27 / Hin, label, ha="center", va="bottom", fontsize=8.5)
        if title:
            fig.text(left / W, 1 - 0.08 / Hin, title, ha="left", va="top", fontsize=9)
        fig.legend(*rows[0][0].get_legend_handles_labels(), loc="upper right", bbox_to_anchor=(1 - right / W,
                   1 - 0.04 / Hin), ncols=3, fontsize=6.5, handlelength=1.2, columnspacing=1.0,
                   title="initial profile:", title_fontsize=6.5, alignment="left", borderaxespad=0)
        # colour bars under the last row: c under measured and model, the residual under its column
        cb_y, cb_h, cb_gap = 0.42 / Hin, 0.09 / Hin, 0.2
        cax1 = fig.add_axes((xs[1] / W, cb_y, (xs[2] + widths[2] - xs[1] - cb_gap) / W, cb_h))
        cax2 = fig.add_axes(((xs[3] + cb_gap) / W, cb_y, (widths[3] - cb_gap) / W, cb_h))
        fig.colorbar(m1, cax=cax1, orientation="horizontal", label=C_LABEL)
        fig.colorbar(m3, cax=cax2, orientation="horizontal", label=r"measured $-$ model $\Delta c$ [-]")
        cax1.xaxis.set_major_locator(MaxNLocator(5))
        cax2.xaxis.set_major_locator(MaxNLocator(3, symmetric=True))
    return fig


def _initial_panel(ax: Any, measured: Any, model: np.ndarray, H: float,
                   initial: tuple[np.ndarray, np.ndarray] | None, compact: bool = False) -> None:
    ax.plot(measured.c[0], measured.z / H, "o", color="#D55E00", ms=3, label="measured")
    ax.plot(model[0], measured.z / H, "s", mfc="none", color="#0072B2", ms=3, label="model layers")
    if initial is not None:
        ax.plot(initial[1], np.asarray(initial[0]) / H, "-", color="#0072B2", lw=1, label="model")
    ax.set_xlim(-0.05, 1.05)
    ax.set_xticks([0, 1], ["0", "1"])  # a narrow panel: two labels do not collide
    ax.set_xticks([0.5], minor=True)
    if compact:  # a row of map_pages: the page says which panel is which
        ax.set_ylabel(r"$H^*$ [-]")
        return
    ax.set_xlabel(r"$c(t_0)$ [-]")
    ax.set_ylabel(H_LABEL)
    ax.set_title("initial", loc="left")


# --------------------------------------------------------------------------- curves


def _by_density_ratio(maps: Sequence[Any]) -> list[tuple[float, list[Any]]]:
    """The maps grouped by density ratio (to 2 decimals), in increasing delta_R."""
    groups: dict[float, list[Any]] = {}
    for m in maps:
        groups.setdefault(round(float(m.delta_R), 2), []).append(m)
    return sorted(groups.items())


def _log_times(t: np.ndarray, n: int) -> np.ndarray:
    """Indices of about ``n`` samples of the positive times ``t`` [s], evenly spaced in log t."""
    pos = np.flatnonzero(t > 0)
    if pos.size <= n:
        return pos
    grid = np.geomspace(t[pos[0]], t[pos[-1]], n)
    return np.unique(pos[np.clip(np.searchsorted(t[pos], grid), 0, pos.size - 1)])


#: Experiments named in a panel of :func:`bottom_fits`; a panel of more is coloured and counted by c0.
NAMED_PER_PANEL = 8


def bottom_fits(maps: Sequence[Any], fits: Mapping[str, FitResult]) -> Figure:
    """Bottom-layer series c[:, 0] of each map (markers) with its tanh fit (lines).

    Small multiples, one panel per density ratio, so that a campaign of 16
    experiments stays readable: within a panel each experiment has its own
    colour and its name in the panel's legend. Time runs on a log axis (from
    the first sample after t = 0), so the rise, which takes a few per cent of a
    long run, is as visible as the plateau. Maps without a fit in ``fits``
    are drawn without a curve. A panel of more than :data:`NAMED_PER_PANEL`
    experiments (a large campaign) cannot name each: its colours are the c0
    values instead, with the count of experiments at each.
    """
    groups = _by_density_ratio(maps)
    cols = min(3, len(groups))
    rows = int(np.ceil(len(groups) / cols))
    with style():
        fig = new_figure(7.2 if cols > 1 else 3.5, 1.75 * rows + 0.45)
        axes = np.atleast_1d(fig.subplots(rows, cols, sharey=True, squeeze=False)).ravel()
        for ax, (dR, group) in zip(axes, groups, strict=False):
            many = len(group) > NAMED_PER_PANEL
            by_c0 = {c: f"C{k % 8}" for k, c in enumerate(sorted({round(float(m.c0), 2) for m in group}))}
            for i, m in enumerate(group):
                color = by_c0[round(float(m.c0), 2)] if many else f"C{i % 8}"
                t = np.asarray(m.t, dtype=float)
                pick = _log_times(t, 20 if many else 50)
                ax.plot(t[pick], np.asarray(m.bottom)[pick], "o", ms=1.8 if many else 2.2, alpha=0.35 if many else 0.5,
                        color=color, mec="none")
                label = "_" if many else literal(m.name)  # "_": no legend entry of its own
                if m.name in fits:
                    f = fits[m.name]
                    tt = np.geomspace(t[t > 0][0], t[-1], 300) if np.any(t > 0) else t
                    ax.plot(tt, tanh_curve(tt, f["A"], f["t0"], f["tau"]), "-", lw=0.7 if many else 1.1,
                            color=color, label=label if many else label + ("" if f.converged else " (not conv.)"))
                elif not many:
                    ax.plot([], [], "o", color=color, label=label + " (no fit)")
            if many:  # too many to name: the colour says c0, the legend counts them
                for c0, color in by_c0.items():
                    n = sum(round(float(m.c0), 2) == c0 for m in group)
                    ax.plot([], [], "-", color=color, label=rf"$c_0$ = {c0:g} ({n})")
            ax.set_xscale("log")
            ax.set_ylim(-0.03, 1.03)
            pairs = sorted({literal(f"{m.heavy}/{m.light}") for m in group})
            ax.set_title(rf"$\delta_R$ = {dR:.2f}: " + ", ".join(pairs), loc="left", fontsize=7.5)
            ax.tick_params(labelsize=7)
            ax.legend(loc="best", fontsize=6, handlelength=1.0, borderaxespad=0.2, labelspacing=0.2,
                      title=f"{len(group)} experiments" if many else None, title_fontsize=6)
        for ax in axes[len(groups):]:
            ax.set_visible(False)
        for ax in axes[::cols]:
            ax.set_ylabel("bottom layer $c_b$ [-]", fontsize=7.5)
        for ax in axes[max(0, len(groups) - cols):len(groups)]:
            ax.set_xlabel("time t [s] (log)", fontsize=7.5)
        head = "Bottom concentration by density ratio" if len(groups) > 1 else "Bottom concentration"
        fig.suptitle(f"{head}:{' ' if cols > 1 else chr(10)}data (markers) and tanh fits (lines)", fontsize=8.5)
    return fig


def laws(fits: Any) -> Figure:
    """A and tau of every tanh fit against delta_R, with the fitted laws.

    ``fits`` is a :class:`granseg.fit.CampaignFits`. Points of experiments
    used for the laws are filled; the others hollow.
    """
    with style():
        fig = new_figure(6.4, 2.7)
        ax_a, ax_t = fig.subplots(1, 2)
        _law_panel(ax_a, fits, "A", fits.beta, "final bottom concentration $A$ [-]", "")
        _law_panel(ax_t, fits, "tau", fits.tau, r"time to 88 % $\tau$ [s]", " s")
    return fig


def _plain(x: float) -> str:
    """A positive number to two significant digits without an exponent (212 s, not 2.1e+02 s)."""
    return f"{x:.0f}" if abs(x) >= 100 else f"{x:.2g}"


def _law_panel(ax: Any, fits: Any, key: str, law: FitResult | None, ylabel: str, unit: str) -> None:
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
        ax.plot(xx, yy, "-", color="C1", label=lab + f"\nRMSE = {_plain(np.sqrt(law.mse))}{unit}")
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
    Grid values are the tick labels; where the optimum +- its error lies
    outside the grid, the axes extend to it with ticks continuing at the
    grid's step, and the optimum's values are written below the map.
    """
    keys = list(points[0])
    if len(keys) != 2:
        raise ValueError(f"rmsd_grid: needs a grid of exactly two parameters, got {keys}")
    xs = sorted({p[keys[0]] for p in points})
    ys = sorted({p[keys[1]] for p in points})
    table = np.full((len(ys), len(xs)), np.nan)
    for p, r in zip(points, rmsd, strict=True):
        table[ys.index(p[keys[1]]), xs.index(p[keys[0]])] = r
    err = {k: float((stderr or {}).get(k) or 0.0) for k in keys}
    err = {k: v if np.isfinite(v) else 0.0 for k, v in err.items()}
    with style():
        fig = new_figure(3.9, 3.4 if best is not None else 3.1)
        ax = fig.subplots()
        xe, ye = edges(np.array(xs)), edges(np.array(ys))
        im = ax.pcolormesh(xe, ye, table, cmap="magma_r", shading="flat")
        _annotate_cells(ax, xs, ys, table)
        for axis, vals, cell_edges, key, lim in ((ax.xaxis, xs, xe, keys[0], ax.set_xlim),
                                                 (ax.yaxis, ys, ye, keys[1], ax.set_ylim)):
            lo, hi = float(cell_edges[0]), float(cell_edges[-1])
            if best is not None:
                b = float(best[key])
                span = hi - lo
                # the optimum +- its error, within two grid spans of the grid (a huge error is cut)
                lo = min(lo, max(b - err[key], lo - 2 * span) - 0.04 * span)
                hi = max(hi, min(b + err[key], hi + 2 * span) + 0.04 * span)
            lim(lo, hi)
            ticks = _grid_ticks(vals, lo, hi)
            places = max((len(f"{t:.6g}".partition(".")[2]) for t in ticks), default=0)
            axis.set_ticks(ticks)
            axis.set_major_formatter(FuncFormatter(lambda v, _, d=places: f"{v:.{d}f}"))
        if best is not None:
            _mark_best(ax, best, err, keys)
            fig.legend(handles=[Line2D([], [], ls="none", marker="*", ms=9, color="#00A0FF", mec="k", mew=0.5)],
                       labels=[_best_label(best, err, keys)], loc="outside lower center", fontsize=7,
                       handletextpad=0.3)
        ax.set_xlabel(_param_label(keys[0]))
        ax.set_ylabel(_param_label(keys[1]))
        ax.set_title(title, loc="left")
        fig.colorbar(im, ax=ax, label="RMSD [-]")
    return fig


def _grid_ticks(vals: Sequence[float], lo: float, hi: float) -> list[float]:
    """The grid values, continued at the grid's end steps out to [lo, hi]."""
    ticks = [float(v) for v in vals]
    if len(ticks) > 1:
        step_lo, step_hi = ticks[1] - ticks[0], ticks[-1] - ticks[-2]
        while ticks[-1] + step_hi <= hi + 1e-9 * step_hi:
            ticks.append(round(ticks[-1] + step_hi, 12))
        while ticks[0] - step_lo >= lo - 1e-9 * step_lo:
            ticks.insert(0, round(ticks[0] - step_lo, 12))
    return ticks


def _best_label(best: Mapping[str, float], err: Mapping[str, float], keys: list) -> str:
    names = {"k": "$k$", "delta_over_H": r"$\delta/H$"}
    return "refined optimum $\\pm$ 1 s.e.:\n" + ", ".join(f"{names.get(k, literal(k))} = {pm_text(float(best[k]), err[k])}" for k in keys)


def _annotate_cells(ax: Any, xs: list, ys: list, table: np.ndarray) -> None:
    lo, hi = np.nanmin(table), np.nanmax(table)
    i_min = np.unravel_index(np.nanargmin(table), table.shape)
    for j, y in enumerate(ys):
        for i, x in enumerate(xs):
            v = table[j, i]
            dark = (v - lo) > 0.55 * (hi - lo) if hi > lo else False
            weight = "bold" if (j, i) == i_min else "normal"
            ax.text(x, y, f"{v:.3f}", ha="center", va="center", fontsize=7, weight=weight,
                    color="white" if dark else "black")


def _mark_best(ax: Any, best: Mapping[str, float], stderr: Mapping[str, float], keys: list) -> None:
    x, y = best[keys[0]], best[keys[1]]
    ax.errorbar([x], [y], xerr=[stderr.get(keys[0], 0.0) or 0.0],
                yerr=[stderr.get(keys[1], 0.0) or 0.0], fmt="*", ms=11, color="#00A0FF",
                mec="k", mew=0.5, capsize=3)


_LABELS = {"k": "friction correction $k$ [-]", "delta_over_H": r"shear-band decay $\delta/H$ [-]",
           "b": "diffusion constant $b$ [-]", "v1": "top slip speed $v_1$ [m/s]"}


def _param_label(key: str) -> str:
    return _LABELS.get(key, literal(key))


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
    if sol.c is None:
        raise ValueError("plot.simulation draws profiles in z: give it a run made with simulate(..., field=True)")
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
    ax.set_xlabel(r"heavy share $c$ [-]")  # the full label is wider than this panel
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
