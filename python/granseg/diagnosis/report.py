"""The diagnosis report: evidence figures and a plain-language page.

``write_report(diagnosis, DIR)`` writes::

    DIR/index.html            summary, verdict, candidate table, figures (embedded PNG)
    DIR/diagnosis.json        the JSON contract (same as diagnose --json)
    DIR/figures/*.png, *.pdf  residual_maps, covariates, candidates, gain, before_after

Nothing existing is replaced unless ``force``.
"""

from __future__ import annotations

import base64
import html
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.colors import TwoSlopeNorm
from matplotlib.figure import Figure

from granseg._io import OutputExistsError, atomic_write, save_json
from granseg.fitting.causes import M_TILDE_REF
from granseg.model import defaults
from granseg.plot import H_LABEL, T_LABEL, save_figure, style

__all__ = ["write_report", "FIGURES"]

FIGURES = ("residual_maps", "covariates", "candidates", "gain", "before_after")
H_BED = defaults()["H"]  # bed height [m], for the z / H axes
PAIR_COLOURS = ["#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00", "#56B4E9", "#000000", "#F0E442"]


def _fig(w: float, h: float) -> Figure:
    return Figure(figsize=(w, h), layout="constrained")


def _edges(x: np.ndarray, lo: float = 0.0) -> np.ndarray:
    mid = 0.5 * (x[1:] + x[:-1])
    return np.concatenate([[max(lo, x[0] - (mid[0] - x[0]))], mid, [x[-1] + (x[-1] - mid[-1])]])


def residual_maps(d: Any) -> Figure:
    """Baseline residual (model - measured) of every experiment, time [s] by height H*."""
    n = len(d.maps)
    cols = min(4, n)
    rows = int(np.ceil(n / cols))
    with style():
        fig = _fig(7.2, 1.45 * rows + 0.5)
        axes = np.atleast_1d(fig.subplots(rows, cols, sharey=True)).ravel()
        norm = TwoSlopeNorm(0.0, -0.5, 0.5)
        mesh = None
        for ax, m, lay in zip(axes, d.maps, d.baseline.layers, strict=False):
            te, ze = _edges(m.t), _edges(m.z / H_BED)
            mesh = ax.pcolormesh(te, ze, (lay - m.c).T, cmap="RdBu_r", norm=norm, rasterized=True)
            ax.set_title(rf"{m.name}, $\tilde M$ = {m.M_tilde:.2f}", fontsize=7.5)
            ax.tick_params(labelsize=6.5)
        for ax in axes[n:]:
            ax.set_visible(False)
        for ax in axes[::cols]:
            ax.set_ylabel(H_LABEL, fontsize=7)
        for ax in axes[max(0, n - cols):n]:
            ax.set_xlabel(T_LABEL, fontsize=7)
        fig.colorbar(mesh, ax=axes.tolist(), label=r"baseline model $-$ measured, $\Delta c$ [-]",
                     shrink=0.6, pad=0.01)
        fig.suptitle("Baseline residuals (red: model shows too many heavy grains)", fontsize=9)
    return fig


def _pair_colour(pairs: list[str]) -> dict[str, str]:
    return {p: PAIR_COLOURS[i % len(PAIR_COLOURS)] for i, p in enumerate(sorted(set(pairs)))}


def covariates(d: Any) -> Figure:
    """Per-experiment optima and depth-mean excess against the experiments' covariates."""
    ev = d.evidence
    cov, per = ev["covariates"], ev["per_experiment"]
    colours = _pair_colour(cov["pair"])
    c = [colours[p] for p in cov["pair"]]
    mt = np.array(cov["M_tilde"])
    with style():
        fig = _fig(7.2, 5.0)
        (a, b), (e, f) = fig.subplots(2, 2)
        a.scatter(mt, per["delta_over_H_opt"], c=c, s=22, zorder=3)
        a.axhline(d.baseline.values()["delta_over_H"], color="0.5", ls=":", lw=1, label="baseline (one value)")
        law = d.fits.get("load_dependent_shear_band")
        if law is not None:
            x = law.values()
            grid = np.geomspace(mt.min() * 0.9, mt.max() * 1.1, 50)
            a.plot(grid, x["delta_over_H"] * (grid / M_TILDE_REF) ** (-x["exponent"]), "k--", lw=1,
                   label=rf"fitted law, exponent {x['exponent']:.2f}")
        a.set_xscale("log")
        a.set_yscale("log")
        _log_ticks(a, "x", mt)
        _log_ticks(a, "y", per["delta_over_H_opt"])
        a.set_xlabel(r"normalised load $\tilde M = M_w/M_g$ [-]")
        a.set_ylabel(r"own optimal $\delta/H$ ($k$ of baseline) [-]")
        a.set_title(f"(a) band width vs load, Spearman {ev['spearman']['delta_opt_vs_M_tilde']:+.2f}", loc="left")
        a.legend(loc="best")
        b.scatter(cov["delta_R"], per["k_opt"], c=c, s=22, zorder=3)
        b.axhline(d.baseline.values()["k"], color="0.5", ls=":", lw=1)
        b.set_xscale("log")
        _log_ticks(b, "x", cov["delta_R"])
        b.set_xlabel(r"density ratio $\delta_R$ [-]")
        b.set_ylabel(r"own optimal $k$ [-]")
        b.set_title("(b) friction correction by material pair", loc="left")
        for p, col in colours.items():
            b.scatter([], [], c=col, s=22, label=p)
        b.legend(loc="best", fontsize=6.5, ncols=2)
        e.scatter(mt, ev["depth_mean"]["excess_while_mixed"], c=c, s=22, zorder=3)
        e.axhline(0, color="0.5", lw=0.8)
        e.set_xlabel(r"normalised load $\tilde M$ [-]")
        e.set_ylabel(r"measured depth-mean $-\ c_0$ while mixed [-]")
        e.set_title(f"(c) wall excess, Spearman {ev['spearman']['depth_excess_vs_M_tilde']:+.2f}", loc="left")
        _structure_panel(f, ev, d)
    return fig


def _structure_panel(ax: Any, ev: Any, d: Any) -> None:
    s = ev["structure"]
    ax.plot(s["time_bins"], s["mean_abs_residual_by_time"], "o-", ms=3, color="#0072B2",
            label="baseline")
    cause = d.result["cause"]
    if cause in d.fits:
        ax.plot(s["time_bins"], _abs_by_time(d, d.fits[cause].layers), "s--", ms=3, color="#009E73",
                label=cause.replace("_", " "))
    ax.set_ylim(bottom=0)
    ax.set_xlim(0, 1)
    ax.set_xlabel(r"normalised time $t/t_{end}$ [-]")
    ax.set_ylabel(r"mean $|\Delta c|$ over experiments [-]")
    ax.set_title("(d) when the misfit sits", loc="left")
    ax.legend(loc="best")


def _abs_by_time(d: Any, layers: Any) -> list[float]:
    """Mean |model - measured| in normalised-time bins, averaged over experiments."""
    n_bins = len(d.evidence["structure"]["time_bins"])
    out = np.zeros(n_bins)
    for m, lay in zip(d.maps, layers, strict=True):
        bins = np.minimum((m.t / m.t[-1] * n_bins).astype(int), n_bins - 1)
        r = np.abs(lay - m.c)
        out += [np.nanmean(r[bins == b]) if np.any(bins == b) else 0.0 for b in range(n_bins)]
    return (out / len(d.maps)).tolist()


def _log_ticks(ax: Any, axis: str, values: Any) -> None:
    from matplotlib.ticker import FixedLocator, NullFormatter, NullLocator, ScalarFormatter

    lo, hi = float(np.min(values)), float(np.max(values))
    cands = [0.1, 0.15, 0.2, 0.3, 0.4, 0.5, 0.7, 1, 1.5, 2, 3, 4, 5, 7, 10]
    ticks = [t for t in cands if lo / 1.25 <= t <= hi * 1.25]
    a = ax.xaxis if axis == "x" else ax.yaxis
    a.set_major_locator(FixedLocator(ticks))
    a.set_major_formatter(ScalarFormatter())
    a.set_minor_locator(NullLocator())
    a.set_minor_formatter(NullFormatter())


def candidates(d: Any) -> Figure:
    """Held-out gain of each candidate, in noise-floor units, with the significance threshold."""
    r = d.result
    floor = r["noise_floor"]
    cands = sorted(r["candidates"], key=lambda c: c["gain_held_out"])
    thr = r["decision"]["gain_threshold"]
    with style():
        fig = _fig(5.0, 0.35 * len(cands) + 1.2)
        ax = fig.subplots()
        vals = [c["gain_held_out"] / floor for c in cands]
        cols = ["#009E73" if c["name"] == r["cause"] else "#999999" for c in cands]
        ax.barh([c["name"].replace("_", " ") for c in cands], vals, color=cols)
        ax.axvline(thr, color="#D55E00", ls="--", lw=1, label=f"significance threshold ({thr:.2f})")
        ax.axvline(0, color="k", lw=0.6)
        ax.set_xlabel("held-out RMSD gain over the baseline / noise floor [-]")
        ax.set_title(f"Leave-one-experiment-out comparison (noise floor {floor:.3f})", loc="left")
        ax.legend(loc="lower right")
    return fig


def gain(d: Any) -> Figure:
    """Per-experiment RMSD: baseline, extended in sample and held out, and the noise floor."""
    r = d.result
    names = list(r["baseline"]["rmsd"])
    x = np.arange(len(names))
    with style():
        fig = _fig(7.2, 2.8)
        ax = fig.subplots()
        ax.bar(x - 0.27, [r["baseline"]["rmsd"][n] for n in names], 0.27, color="#999999", label="baseline")
        if r["extended"] is not None:
            e = r["extended"]
            ax.bar(x, [e["rmsd"][n] for n in names], 0.27, color="#0072B2", label=f"{e['model']} (in sample)")
            ax.bar(x + 0.27, [e["rmsd_held_out"][n] for n in names], 0.27, color="#56B4E9",
                   label="same, held out")
        ax.plot(x, [r["noise"]["per_experiment"][n] for n in names], "k_", ms=14, mew=1.6,
                label="noise floor")
        ax.set_xticks(x, names, rotation=45, ha="right", fontsize=7)
        ax.set_ylabel("RMSD [-]")
        ax.set_title("Misfit per experiment", loc="left")
        ax.legend(ncols=2, loc="upper left", fontsize=7)
    return fig


def _showcase(d: Any) -> int:
    r = d.result
    if r["extended"] is not None:
        g = r["gain"]["per_experiment_held_out"]
        return list(g).index(max(g, key=g.get))
    return int(np.argmax(d.baseline.rmsd))


def before_after(d: Any) -> Figure:
    """Measured map, baseline model and extended model for the experiment that gains most."""
    i = _showcase(d)
    m = d.maps[i]
    panels = [("measured", m.c), (f"baseline, RMSD {d.baseline.rmsd[i]:.3f}", d.baseline.layers[i])]
    cause = d.result["cause"]
    if cause in d.fits:
        f = d.fits[cause]
        panels.append((f"{cause.replace('_', ' ')}, RMSD {f.rmsd[i]:.3f}", f.layers[i]))
    te, ze = _edges(m.t), _edges(m.z / H_BED)
    with style():
        fig = _fig(7.2, 2.3)
        axes = fig.subplots(1, len(panels), sharey=True)
        for ax, (title, arr) in zip(axes, panels, strict=True):
            mesh = ax.pcolormesh(te, ze, arr.T, vmin=0, vmax=1, cmap="viridis", rasterized=True)
            ax.set_title(title, fontsize=8)
            ax.set_xlabel(T_LABEL)
        axes[0].set_ylabel(H_LABEL)
        fig.colorbar(mesh, ax=list(axes), label="heavy concentration c [-]", shrink=0.9, pad=0.01)
        fig.suptitle(f"{m.name}: {m.heavy}/{m.light}, $c_0$ = {m.c0:.2f}, "
                     rf"$\tilde M$ = {m.M_tilde:.2f}", fontsize=9)
    return fig


CAPTIONS = {
    "residual_maps": "Baseline model minus measurement for every experiment. Noise looks like speckle; "
                     "a cause shows as coherent patches that repeat across experiments.",
    "covariates": "Each experiment's own optimal delta/H and k, the depth-mean excess and where the "
                  "misfit sits. A trend against a covariate is the clue to the cause.",
    "candidates": "Every catalogued cause fitted to all experiments and scored on experiments it did "
                  "not see (leave-one-out). Only a gain beyond the threshold names a cause.",
    "gain": "RMSD per experiment before and after the extension, with the noise floor each map allows.",
    "before_after": "The experiment that gains most: measurement, baseline and extended model.",
}


def _page(d: Any, pngs: dict[str, Path]) -> str:
    r = d.result
    e = html.escape
    rows = "".join(
        f"<tr><td>{e(c['name'])}</td><td>{c['rmsd']:.4f}</td><td>{c['rmsd_held_out']:.4f}</td>"
        f"<td>{c['gain_held_out']:+.4f}</td><td>{e(c['law'])}</td></tr>" for c in r["candidates"])
    figs = "".join(
        f"<figure><img src='data:image/png;base64,{base64.b64encode(p.read_bytes()).decode()}' "
        f"alt='{k}'><figcaption>{e(CAPTIONS[k])}</figcaption></figure>" for k, p in pngs.items())
    b = r["baseline"]
    return f"""<!doctype html><html><head><meta charset='utf-8'><title>granseg diagnosis</title>
<style>body{{font-family:sans-serif;max-width:60em;margin:2em auto;line-height:1.45}}
table{{border-collapse:collapse;font-size:90%}}td,th{{border-bottom:1px solid #ccc;padding:3px 8px;text-align:left}}
img{{max-width:100%}}figure{{margin:1.5em 0}}figcaption{{color:#444;font-size:90%}}
.verdict{{font-size:120%;padding:.6em;background:#eef5ee;border-left:4px solid #009E73}}</style></head><body>
<h1>What the model gets wrong</h1>
<p class='verdict'><b>Cause: {e(r['cause'])}</b> &mdash; explained: {r['explained']}</p>
<p>{e(r['summary'])}</p>
<p>Noise floor (mean over experiments): {r['noise_floor']:.4f} ({e(r['noise']['method'])}).
Baseline: k = {b['params']['k']:.3f}, delta/H = {b['params']['delta_over_H']:.3f};
mean RMSD {b['rmsd_mean']:.4f} in sample, {b['rmsd_held_out_mean']:.4f} held out.
Decision: {e(r['decision']['reason'])}.</p>
<h2>Candidates</h2><table><tr><th>cause</th><th>mean RMSD</th><th>held-out RMSD</th>
<th>held-out gain</th><th>fitted extension</th></tr>{rows}</table>
<h2>Evidence</h2>{figs}</body></html>
"""


def write_report(d: Any, out: Path, *, force: bool = False) -> Path:
    """Draw the figures and write ``out/index.html`` and ``out/diagnosis.json``; return the page."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise NotADirectoryError(f"{out}: exists and is not a directory")
    clash = [n for n in ("index.html", "diagnosis.json", "figures") if (out / n).exists()]
    if clash and not force:
        raise OutputExistsError(f"{out}: already holds {clash}; pass force=True (CLI: --force)")
    (out / "figures").mkdir(parents=True, exist_ok=True)
    pngs = {}
    for name in FIGURES:
        fig = globals()[name](d)
        pngs[name] = save_figure(fig, out / "figures" / name, force=force)[0]
    save_json(out / "diagnosis.json", d.result, force=force)
    page = _page(d, pngs)
    return atomic_write(out / "index.html", lambda p: p.write_text(page, encoding="utf-8"), force=force)
