"""The evidence figures of a diagnosis (:class:`granseg.diagnosis.Diagnosis`).

Each function takes the diagnosis and returns a :class:`matplotlib.figure.Figure`
in granseg's style (or None when it does not apply: ``candidates`` only when
catalogue causes were fitted, ``departure`` only when the law corrections
were tried, ``views`` only when a run's other view lies beside its map);
:data:`FIGURES` maps each figure's name to its function, in the order the
diagnosis report shows them. Residuals are measured minus model throughout,
as in the calibration report.

Example::

    >>> fig = FIGURES["candidates"](diagnosis)                  # doctest: +SKIP
    >>> save_figure(fig, "out/candidates")                      # doctest: +SKIP
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from matplotlib.colors import TwoSlopeNorm
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch
from matplotlib.ticker import FixedLocator, MaxNLocator, NullFormatter, NullLocator, ScalarFormatter

from granseg.fitting.causes import M_TILDE_REF
from granseg.maps import views_of
from granseg.model import defaults
from granseg.plot.base import H_LABEL, STYLE, T_LABEL, literal, map_edges, new_figure, style
from granseg.plot.views import view_comparison

if TYPE_CHECKING:
    from granseg.diagnosis.run import Diagnosis

__all__ = ["FIGURES", "before_after", "candidates", "covariates", "departure", "gain", "residual_maps", "views"]

PAIR_COLOURS: list[str] = STYLE["axes.prop_cycle"].by_key()["color"]


def _bed_height(d: Diagnosis, m: Any) -> float:
    """Bed height H [m] of map ``m`` in the diagnosis: its own cell's, else the one fixed, else docs/model.md's."""
    return float({**d.data.fixed, **m.cell}.get("H", defaults()["H"]))


def residual_maps(d: Diagnosis) -> Figure:
    """Baseline residual (measured - model) of every experiment, time [s] by height H*.

    The sign is the calibration report's (:func:`granseg.plot.map_comparison`):
    red where more heavy grains were measured than modelled.
    """
    n = len(d.maps)
    cols = min(4, n)
    rows = int(np.ceil(n / cols))
    with style():
        fig = new_figure(7.2, 1.45 * rows + 0.6)
        axes = np.atleast_1d(fig.subplots(rows, cols, sharey=True)).ravel()
        norm = TwoSlopeNorm(0.0, -0.5, 0.5)
        mesh = None
        for ax, m, lay in zip(axes, d.maps, d.baseline.layers, strict=False):
            mesh = ax.pcolormesh(*map_edges(m, _bed_height(d, m)), (m.c - lay).T, cmap="RdBu_r", norm=norm,
                                 rasterized=True)
            ax.set_title(rf"{literal(m.name)}, $\tilde M$ = {m.M_tilde:.2f}", fontsize=7.5)
            ax.tick_params(labelsize=6.5)
            ax.xaxis.set_major_locator(MaxNLocator(4))
        for ax in axes[n:]:
            ax.set_visible(False)
        for ax in axes[::cols]:
            ax.set_ylabel(H_LABEL, fontsize=7)
        for ax in axes[max(0, n - cols):n]:
            ax.set_xlabel(T_LABEL, fontsize=7)
        cb = fig.colorbar(mesh, ax=axes.tolist(), shrink=0.6, pad=0.01, extend="both")
        cb.set_label(r"measured $-$ baseline model, $\Delta c$ [-]", fontsize=7.5)
        cb.ax.tick_params(labelsize=6.5)
        fig.suptitle("Baseline residuals, measured $-$ model (red: more heavy grains measured than modelled)",
                     fontsize=8.5)
    return fig


def _pair_colour(pairs: Sequence[str]) -> dict[str, str]:
    return {p: PAIR_COLOURS[i % len(PAIR_COLOURS)] for i, p in enumerate(sorted(set(pairs)))}


def covariates(d: Diagnosis) -> Figure:
    """Per-experiment optima and depth-mean excess against the experiments' covariates."""
    ev = d.evidence
    cov, per = ev["covariates"], ev["per_experiment"]
    colours = _pair_colour(cov["pair"])
    c = [colours[p] for p in cov["pair"]]
    mt = np.array(cov["M_tilde"])
    base = d.baseline.values()
    with style():
        fig = new_figure(7.2, 5.0)
        (a, b), (e, f) = fig.subplots(2, 2)
        a.scatter(mt, per["delta_over_H_opt"], c=c, s=22, zorder=3)
        a.axhline(base["delta_over_H"], color="0.5", ls=":", lw=1, label="baseline (one value)")
        law = d.fits.get("load_dependent_shear_band")
        if law is not None:
            x = law.values()
            grid = np.geomspace(mt.min() * 0.9, mt.max() * 1.1, 50)
            a.plot(grid, x["delta_over_H"] * (grid / M_TILDE_REF) ** (-x["exponent"]), "k--", lw=1,
                   label=rf"fitted law, exponent {x['exponent']:.2f}")
        a.set_xscale("log")
        a.set_yscale("log")
        _log_ticks(a.xaxis, mt)
        _log_ticks(a.yaxis, per["delta_over_H_opt"])
        a.set_xlabel(r"normalised load $\tilde M = M_w/M_g$ [-]")
        a.set_ylabel(r"own optimal $\delta/H$, $k$ fixed [-]")
        a.set_title(f"(a) band width vs load, Spearman {ev['spearman']['delta_opt_vs_M_tilde']:+.2f}", loc="left")
        a.legend(loc="best")
        b.scatter(cov["delta_R"], per["k_opt"], c=c, s=22, zorder=3)
        b.axhline(base["k"], color="0.5", ls=":", lw=1)
        b.set_xscale("log")
        _log_ticks(b.xaxis, cov["delta_R"])
        b.set_xlabel(r"density ratio $\delta_R$ [-]")
        b.set_ylabel(r"own optimal $k$ [-]")
        b.set_title("(b) friction correction by material pair", loc="left")
        for p, col in colours.items():
            b.scatter([], [], c=col, s=22, label=literal(p))
        b.legend(loc="best", fontsize=6.5, ncols=2)
        e.scatter(mt, ev["depth_mean"]["excess_while_mixed"], c=c, s=22, zorder=3)
        e.axhline(0, color="0.5", lw=0.8)
        e.set_xlabel(r"normalised load $\tilde M$ [-]")
        e.set_ylabel(r"depth-mean $c$ $-$ $c_0$, mixed [-]")
        e.set_title(f"(c) wall excess, Spearman {ev['spearman']['depth_excess_vs_M_tilde']:+.2f}", loc="left")
        _structure_panel(f, d)
    return fig


def _structure_panel(ax: Any, d: Diagnosis) -> None:
    s = d.evidence["structure"]
    ax.plot(s["time_bins"], s["mean_abs_residual_by_time"], "o-", ms=3, color="#0072B2",
            label="baseline")
    if d.cause in d.fits:
        ax.plot(s["time_bins"], _abs_by_time(d, d.fits[d.cause].layers), "s--", ms=3, color="#009E73",
                label=d.cause.replace("_", " "))
    ax.set_ylim(bottom=0)
    ax.set_xlim(0, 1)
    ax.set_xlabel(r"normalised time $t/t_{end}$ [-]")
    ax.set_ylabel(r"mean $|\Delta c|$ over experiments [-]")
    ax.set_title("(d) when the misfit sits", loc="left")
    ax.legend(loc="best")


def _abs_by_time(d: Diagnosis, layers: Sequence[np.ndarray]) -> list[float]:
    """Mean |model - measured| in normalised-time bins, averaged over experiments."""
    n_bins = len(d.evidence["structure"]["time_bins"])
    out = np.zeros(n_bins)
    for m, lay in zip(d.maps, layers, strict=True):
        bins = np.minimum((m.t / m.t[-1] * n_bins).astype(int), n_bins - 1)
        r = np.abs(lay - m.c)
        out += [np.nanmean(r[bins == b]) if np.any(bins == b) else 0.0 for b in range(n_bins)]
    return (out / len(d.maps)).tolist()


def _log_ticks(axis: Any, values: Any) -> None:
    """Plain-number ticks on a log ``axis`` spanning ``values``, no minor ticks.

    1-1.5-2-3-4-5-7 steps (1-2-5 over more than a factor 20, decades over more
    than 1000); over a narrow span, where those leave fewer than three ticks
    inside it, evenly spaced round numbers, so that every panel has labelled ticks.
    """
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v) & (v > 0)]
    if v.size == 0:
        return
    lo, hi = float(v.min()), float(v.max())
    decades = 10.0 ** np.arange(np.floor(np.log10(lo)) - 1, np.ceil(np.log10(hi)) + 1)
    steps = (1, 1.5, 2, 3, 4, 5, 7) if hi / lo <= 20 else (1, 2, 5) if hi / lo <= 1000 else (1,)
    cands = sorted({round(float(m * d), 12) for d in decades for m in steps})
    ticks = [t for t in cands if lo / 1.1 <= t <= hi * 1.1]
    if len([t for t in ticks if lo <= t <= hi]) >= 3 or hi / lo > 3:
        axis.set_major_locator(FixedLocator(ticks or [t for t in cands if lo / 1.25 <= t <= hi * 1.25]))
    else:
        axis.set_major_locator(MaxNLocator(4, steps=[1, 2, 2.5, 5, 10]))
    fmt = ScalarFormatter()
    fmt.set_useOffset(False)
    axis.set_major_formatter(fmt)
    axis.set_minor_locator(NullLocator())
    axis.set_minor_formatter(NullFormatter())


def candidates(d: Diagnosis) -> Figure | None:
    """Held-out gain of each candidate, relative to the baseline's held-out RMSD, with the threshold.

    The bottom axis gives the gain in % of the baseline's held-out RMSD (the
    unit of the threshold), the top axis the same gain as an RMSD difference
    [-] (the unit of the page's table). None when no candidate was fitted
    (a diagnosis of a flagged window).
    """
    r = d.result
    if not r["candidates"]:
        return None
    base = r["baseline"]["rmsd_held_out_mean"]
    cands = sorted(r["candidates"], key=lambda c: c["gain_held_out"])
    thr = 100 * r["decision"]["gain_threshold"]
    with style():
        fig = new_figure(5.0, 0.3 * len(cands) + 1.6)
        ax = fig.subplots()
        vals = [100 * c["gain_held_out"] / base for c in cands]
        cols = ["#009E73" if c["name"] == r["cause"] else "#56B4E9" if v > thr else "#999999"
                for c, v in zip(cands, vals, strict=True)]
        ax.barh([c["name"].replace("_", " ") for c in cands], vals, color=cols)
        ax.axvline(thr, color="#D55E00", ls="--", lw=1)
        ax.axvline(0, color="k", lw=0.6)
        lo, hi = min(0.0, *vals), max(thr, *vals)
        ax.set_xlim(lo - 0.05 * (hi - lo), hi + 0.05 * (hi - lo))
        ax.set_xlabel("held-out gain [% of the baseline's held-out RMSD]")
        top = ax.secondary_xaxis("top", functions=(lambda p: p * base / 100, lambda g: g * 100 / base))
        top.set_xlabel("held-out gain, baseline minus candidate RMSD [-]", fontsize=7.5)
        top.tick_params(labelsize=7)
        top.xaxis.set_major_locator(MaxNLocator(5))
        kinds = {"#009E73": "named cause", "#56B4E9": "above, not named", "#999999": "below threshold"}
        handles = [Patch(color=k, label=v) for k, v in kinds.items() if k in cols]
        handles.append(Line2D([], [], color="#D55E00", ls="--", lw=1,
                              label=f"threshold {thr:.1f} % = {thr * base / 100:.4f}"))
        fig.legend(handles=handles, loc="outside lower center", ncols=4, fontsize=6.5, handlelength=1.2,
                   columnspacing=1.0)
        fig.suptitle(f"Leave-one-experiment-out comparison (baseline held-out RMSD {base:.3f})", fontsize=8.5)
    return fig


def gain(d: Diagnosis) -> Figure:
    """Per-experiment RMSD: baseline, extended in sample and held out, and the noise floor."""
    r = d.result
    names = list(r["baseline"]["rmsd"])
    x = np.arange(len(names))
    with style():
        fig = new_figure(7.2, 2.9)
        ax = fig.subplots()
        ax.bar(x - 0.27, [r["baseline"]["rmsd"][n] for n in names], 0.27, color="#999999", label="baseline")
        if r["extended"] is not None:
            e = r["extended"]
            label = e["model"].removeprefix("law_").replace("_", " ")
            ax.bar(x, [e["rmsd"][n] for n in names], 0.27, color="#0072B2", label=f"{label} (in sample)")
            ax.bar(x + 0.27, [e["rmsd_held_out"][n] for n in names], 0.27, color="#56B4E9",
                   label=f"{label} (held out)")
        ax.plot(x, [r["noise"]["per_experiment"][n] for n in names], "k_", ms=14, mew=1.6,
                label="noise floor")
        ax.set_xticks(x, [literal(n) for n in names], rotation=45 if len(names) > 6 else 0, ha="right" if len(names) > 6 else "center",
                      fontsize=7)
        ax.set_ylabel("RMSD [-]")
        ax.set_title("Misfit per experiment", loc="left")
        fig.legend(loc="outside upper right", ncols=4, fontsize=7)
    return fig


def _showcase(d: Diagnosis) -> int:
    """Index of the experiment the extension helps most held out (else the worst baseline fit)."""
    r = d.result
    if r["extended"] is not None:
        g = r["gain"]["per_experiment_held_out"]
        return list(g).index(max(g, key=g.get))
    return int(np.argmax(d.baseline.rmsd))


def _extended_fit(d: Diagnosis) -> Any:
    """The named cause's fit: a catalogue cause or the departing law's correction (None for none)."""
    if d.cause in d.fits:
        return d.fits[d.cause]
    if d.cause == "new_law" and d.open_world is not None and d.verdict.law is not None:
        return d.open_world.fits[d.verdict.law]
    return None


def before_after(d: Diagnosis) -> Figure:
    """Measured map, baseline model and extended model for the experiment that gains most."""
    i = _showcase(d)
    m = d.maps[i]
    panels = [("measured\n", m.c), (f"baseline\nRMSD {d.baseline.rmsd[i]:.3f}", d.baseline.layers[i])]
    f = _extended_fit(d)
    if f is not None:
        label = f.effect.name.removeprefix("law_").replace("_", " ")
        panels.append((f"{label}\nRMSD {f.rmsd[i]:.3f}", f.layers[i]))
    te, ze = map_edges(m, _bed_height(d, m))
    with style():
        fig = new_figure(7.2, 2.5)
        axes = fig.subplots(1, len(panels), sharey=True)
        for ax, (title, arr) in zip(axes, panels, strict=True):
            mesh = ax.pcolormesh(te, ze, arr.T, vmin=0, vmax=1, cmap="viridis", rasterized=True)
            ax.set_title(title, fontsize=8)
            ax.set_xlabel(T_LABEL)
        axes[0].set_ylabel(H_LABEL)
        fig.colorbar(mesh, ax=list(axes), label=r"heavy share $c$ [-]", shrink=0.9, pad=0.01)
        fig.suptitle(f"{literal(m.name)}: {literal(m.heavy)}/{literal(m.light)}, $c_0$ = {m.c0:.2f}, "
                     rf"$\tilde M$ = {m.M_tilde:.2f}", fontsize=9)
    return fig


_VARIABLE_LABELS = {"c": "heavy share $c$ [-]", "z/H": "height above the driven plate $z/H$ [-]",
                    "t/T": "time $t/T$ [-]"}


def _departure_law(d: Diagnosis) -> str | None:
    """The law correction to show: the named one, else the best held out (None: open world not tried)."""
    ow = d.open_world
    if ow is None or not ow.fits:
        return None
    if d.verdict.law is not None:
        return d.verdict.law
    return max(ow.gains, key=ow.gains.get) if ow.gains else min(ow.fits, key=lambda n: ow.fits[n].rmsd_mean)


def departure(d: Diagnosis) -> Figure | None:
    """The departing law's fitted factor with its 95 % band, and every law correction's gain.

    None when the open world was not tried (the catalogue explained the misfit).
    """
    name = _departure_law(d)
    if name is None or d.open_world is None:
        return None
    from granseg.fitting import laws

    ow = d.open_world
    f = ow.fits[name]
    law: laws.LawCorrection = f.effect  # type: ignore[assignment]
    sh, lit = ow.shape(name)
    base = float(np.mean(d.held_out["baseline"]))
    named = d.verdict.law == name
    with style():
        fig = new_figure(7.2, 3.0)
        ax, bx = fig.subplots(1, 2, gridspec_kw={"width_ratios": [1.25, 1.0]})
        x = np.asarray(sh["x"])
        ax.fill_between(x, sh["lo"], sh["hi"], color="#56B4E9", alpha=0.35, lw=0, label="95 % band")
        ax.plot(x, sh["factor"], color="#0072B2", lw=1.8, label="fitted correction")
        if lit is not None:
            ax.plot(x, lit["factor"], color="#D55E00", ls="--", lw=1.2, label=lit["name"])
        ax.axhline(1.0, color="k", lw=0.6)
        ax.set_yscale("log")
        span = [*sh["lo"], *sh["hi"], 1.0]
        if max(span) / min(span) < 200:
            _log_ticks(ax.yaxis, span)
        ax.set_xlabel(_VARIABLE_LABELS.get(law.variable, law.variable))
        ax.set_ylabel("factor on the law [-]" if law.law_name != "observation" else "wall / bulk at $c$ = 1/2 [-]")
        verdict = "the law that departs" if named else "best correction tried, not named"
        ax.set_title(f"{law.quantity[0].upper()}{law.quantity[1:]}: {verdict}", loc="left", fontsize=8.5)
        ax.legend(fontsize=7, loc="best")
        if law.variable == "t/T":
            ax.text(0.99, 0.02, f"T = {ow.time_scale / 60:.0f} min", transform=ax.transAxes, ha="right",
                    va="bottom", fontsize=7)
        names = sorted(ow.fits, key=lambda n: ow.fits[n].rmsd_mean, reverse=True)
        y = np.arange(len(names))
        insample = [100 * (d.baseline.rmsd_mean - ow.fits[n].rmsd_mean) / d.baseline.rmsd_mean for n in names]
        held = [100 * ow.gains[n] / base if n in ow.gains else np.nan for n in names]
        bx.barh(y + 0.18, insample, 0.36, color="#999999", label="in sample")
        bx.barh(y - 0.18, held, 0.36, color=["#009E73" if n == d.verdict.law else "#56B4E9" for n in names],
                label="held out (refitted)")
        thr = 100 * d.thresholds["gain"]
        bx.axvline(thr, color="#D55E00", ls="--", lw=1, label=f"threshold ({thr:.1f} %)")
        bx.axvline(0, color="k", lw=0.6)
        bx.set_ylim(-0.7, len(names) - 0.3)
        bx.set_yticks(y, [n.removeprefix("law_").replace("_", " ") for n in names], fontsize=7)
        bx.set_xlabel("gain over the baseline [% of its RMSD]", fontsize=8)
        bx.set_title("Each law corrected in turn", loc="left", fontsize=8.5)
        bx.legend(fontsize=6.5, loc="upper center", bbox_to_anchor=(0.5, -0.25), ncols=3, handlelength=1.2,
                  columnspacing=1.0)
    return fig


def views(d: Diagnosis) -> Figure | None:
    """Each map's camera view against its bulk, where the run's other view lies beside it."""
    runs = [v for v in map(views_of, d.maps) if v]
    return view_comparison(runs) if runs else None


#: The diagnosis figures by name, in the order the report shows them.
FIGURES: dict[str, Callable[[Diagnosis], Figure | None]] = {
    "residual_maps": residual_maps,
    "covariates": covariates,
    "candidates": candidates,
    "gain": gain,
    "before_after": before_after,
    "departure": departure,
    "views": views,
}
