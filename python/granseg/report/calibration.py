"""The calibration page of a campaign: one self-contained HTML page plus JSON.

:func:`build_report` loads a campaign, fits the bottom curves and the
A / tau laws, calibrates the model (or takes a given calibration), draws the
figures and writes into ``OUT``::

    OUT/index.html      the page (figures embedded as PNG; opens offline)
    OUT/report.json     every number the page shows, machine-readable
    OUT/figures/*.png   the same figures as files, with a PDF beside each

Each experiment's measured and model maps are one figure per experiment in a
campaign of up to :data:`ONE_FIGURE_PER_EXPERIMENT_UP_TO` experiments, and
pages of six experiments in a larger one (PNG only, :data:`PAGE_FORMATS`).
The figures are drawn, saved and freed one at a time and the page is written
piece by piece, so the memory a report needs does not grow with the
campaign. Everything is written into a hidden
``.OUT.*.partial`` folder and moved into place at the end: a report that fails
leaves nothing behind (:func:`granseg._io.staged_output_dir`).

The HTML is rendered from the JSON document (:func:`render`), so the two
cannot disagree. The page opens with the provenance (input, granseg version,
UTC date, command line) and, for data not measured in a laboratory, a
SYNTHETIC banner (:mod:`granseg.report.provenance`); the calibration's
warnings are shown on it too. Nothing existing is replaced unless ``force=True``.

Example::

    >>> build_report("campaign/", "report/")                     # doctest: +SKIP
    PosixPath('report/index.html')
"""

from __future__ import annotations

import os
import re
import warnings
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from granseg._io import check_output_dir, save_json, staged_output_dir
from granseg.calibration import CalibrationWarning, calibrate
from granseg.fit import fit_campaign
from granseg.maps import load_campaign, views_of
from granseg.measure.quality import views_table
from granseg.model import defaults, simulate
from granseg.plot import (
    bottom_fits,
    laws,
    map_comparison,
    map_pages,
    profiles,
    rmsd_grid,
    view_comparison,
)
from granseg.plot.calibration import ROWS_PER_PAGE
from granseg.report.html import (
    esc,
    figure_parts,
    num,
    nums,
    page_parts,
    pm,
    provenance_section,
    save_figures,
    table,
    views_section,
    write_page,
    yesno,
)
from granseg.report.provenance import provenance as make_provenance

__all__ = ["OUTPUTS", "build_report", "report_data", "render", "render_parts"]

OUTPUTS = ("index.html", "report.json", "figures")
VIEWS_CAPTION = ("Each run's camera view against its bulk: both maps, their difference, and each view's "
                 "depth-mean heavy share with the band its counts allow (the last third, shaded, is judged)")


def _slug(i: int, name: str) -> str:
    return f"map_{i:02d}_" + re.sub(r"[^A-Za-z0-9._-]+", "_", name)


def build_report(
    campaign: Any,
    out: str | os.PathLike,
    *,
    calibration: Any = None,
    fits_c0: float | None = 0.5,
    force: bool = False,
    progress: bool = True,
    command: str | None = None,
    synthetic: bool | None = None,
    **calibrate_kwargs: Any,
) -> Path:
    """Write the report of ``campaign`` (directory or Campaign) into folder ``out``.

    ``calibration`` is a :class:`granseg.calibration.Calibration` to reuse;
    otherwise :func:`granseg.calibration.calibrate` runs with
    ``calibrate_kwargs``. ``fits_c0`` selects the experiments whose A and
    tau are fitted with the laws (None = all). ``command`` is the command line
    shown in the provenance (None from the Python API); ``synthetic`` says
    whether the data were generated rather than measured (None: as the maps
    tell, :func:`granseg.report.provenance.data_origin`). Returns the HTML path.
    """
    out = check_output_dir(out, OUTPUTS, force)  # a bad or taken DIR fails now, not after the calibration
    if fits_c0 is not None and not (isinstance(fits_c0, int | float) and 0.0 <= fits_c0 <= 1.0):
        raise ValueError(f"fits_c0 = {fits_c0!r}: expected a concentration in [0, 1] (or None for all)")
    camp = campaign if hasattr(campaign, "maps") else load_campaign(campaign)
    fits = fit_campaign(camp, c0=fits_c0)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", CalibrationWarning)
        cal = calibration or calibrate(camp, progress=progress, **calibrate_kwargs)
    notes = []
    for w in caught:  # shown as the caller's filters say (one line from the CLI), and kept for the page
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno, source=w.source)
        if issubclass(w.category, CalibrationWarning):
            notes.append(str(w.message))
    log = (lambda msg: print(f"[report] {msg}", flush=True)) if progress else None
    plan = _figure_plan(camp, fits, cal)
    # everything is written into a hidden folder beside (or in) OUT and moved into place at the end:
    # a failure (a bad name, a full disk, Ctrl-C) leaves no half report that blocks the rerun
    with staged_output_dir(out, OUTPUTS, force, folders=["figures"]) as stage:
        figs = save_figures(plan, stage, log=log, total=len(plan))
        prov = make_provenance(list(camp), directory=getattr(camp, "directory", None), command=command,
                               synthetic=synthetic)
        data = report_data(camp, fits, cal, figs, provenance=prov)
        data["warnings"] = notes
        save_json(stage / "report.json", data)
        write_page(stage / "index.html", render_parts(data, stage))
    return out / "index.html"


def _model_constants(cal: Any) -> dict[str, float]:
    params = dict(defaults())
    params.update(cal.settings.get("base", {}))
    params.update(cal.best)
    return params


def _initial_profile(m: Any, params: dict[str, Any], n_cells: int) -> tuple[np.ndarray, np.ndarray]:
    sol = simulate(**{**params, **m.case()}, t=np.array([0.0]), n_cells=n_cells, field=True)
    return np.asarray(sol.z), np.asarray(sol.c)[0]


#: Campaigns of up to this many experiments get a figure per experiment (:func:`granseg.plot.map_comparison`);
#: larger ones get pages of :data:`granseg.plot.calibration.ROWS_PER_PAGE` experiments each
#: (:func:`granseg.plot.map_pages`), a fraction of the cost per experiment and a page a reader can scan.
ONE_FIGURE_PER_EXPERIMENT_UP_TO = 12
#: The files of a page of maps: PNG only (the summary figures keep their PDF). A PDF of a page of
#: rasterized maps costs twice the PNG's time and ~300 MB of memory while it is written.
PAGE_FORMATS = ("png",)


def _figure_plan(camp: Any, fits: Any, cal: Any) -> list[tuple[Any, ...]]:
    """The report's figures as (file stem, caption, function drawing the figure[, formats]).

    Nothing is drawn here: :func:`granseg.report.html.save_figures` draws, saves and frees one
    figure at a time, so memory stays flat in the number of experiments."""
    params = _model_constants(cal)
    H = float(params["H"])
    maps = list(camp)
    plan: list[tuple[Any, ...]] = [
        ("bottom_fits", "Bottom-layer concentration with tanh fits", lambda: bottom_fits(maps, fits.tanh)),
        ("laws", "Final concentration A and time tau against density ratio", lambda: laws(fits)),
    ]
    if len(cal.keys) == 2:
        plan.append(("rmsd_grid", "Mean RMSD over the factorial grid",
                     lambda: rmsd_grid(cal.grid_points, cal.grid_mean, best=cal.best if cal.refined else None,
                                       stderr=cal.stderr if cal.refined else None)))
    dgrid = cal.settings["grid"].get("delta_over_H", [])
    cell, differ = _shared_cell(camp)
    caption = "Velocity and shear-rate profiles of the calibrated model"
    if differ:
        caption += f" (in the first map's cell: the maps' {', '.join(differ)} differ)"
    plan.append(("profiles", caption, lambda: profiles({**params, **cell}, deltas=dgrid,
                                                       delta_err=_finite(cal.stderr.get("delta_over_H")))))
    n_cells = int(cal.settings.get("n_cells", 180))
    heights = [float(m.cell.get("H", H)) for m in maps]
    layers = list(cal.model_layers)
    if len(maps) <= ONE_FIGURE_PER_EXPERIMENT_UP_TO:
        def comparison(i: int) -> Figure:
            m = maps[i]
            return map_comparison(m, layers[i], H=heights[i], rmsd=cal.rmsd[m.name],
                                  initial=_initial_profile(m, params, n_cells))

        for i, m in enumerate(maps):
            plan.append((_slug(i, m.name), f"{m.name}: measured and model maps", lambda i=i: comparison(i)))
    else:
        lim = max([float(np.nanmax(np.abs(m.c - lay))) for m, lay in zip(maps, layers, strict=True)
                   if np.any(np.isfinite(m.c - lay))] + [1e-3])

        def page(lo: int, hi: int) -> Figure:
            return map_pages(maps[lo:hi], layers[lo:hi], H=heights[lo:hi],
                             rmsd=[cal.rmsd[m.name] for m in maps[lo:hi]],
                             initial=[_initial_profile(m, params, n_cells) for m in maps[lo:hi]], resid_lim=lim,
                             title=f"Measured and model maps, experiments {lo + 1}-{hi} of {len(maps)}")

        for n, lo in enumerate(range(0, len(maps), ROWS_PER_PAGE), 1):
            hi = min(lo + ROWS_PER_PAGE, len(maps))
            names = ", ".join(m.name for m in maps[lo:hi])
            plan.append((f"maps_{n:03d}", f"Measured and model maps, experiments {lo + 1}-{hi} of {len(maps)}: "
                         f"{names} (residual colour scale shared by all pages)",
                         lambda lo=lo, hi=hi: page(lo, hi), PAGE_FORMATS))
    runs = [v for v in map(views_of, maps) if v]
    if runs:
        plan.append(("views", VIEWS_CAPTION, lambda: view_comparison(runs)))
    return plan


def _shared_cell(camp: Any) -> tuple[dict[str, float], list[str]]:
    """The cell the maps carry (the first map's; a DEM campaign's maps share most of it), and the
    keys on which the maps differ by more than 5 % (a DEM bed's height varies by a few per cent
    with its load; that does not change the figure)."""
    maps = list(camp)
    cell = dict(maps[0].cell) if maps else {}

    def same(a: float | None, b: float | None) -> bool:
        return a is not None and b is not None and bool(np.isclose(a, b, rtol=0.05))

    differ = sorted({k for m in maps for k in {*cell, *m.cell} if not same(m.cell.get(k), cell.get(k))})
    return cell, differ


def _finite(x: Any) -> float | None:
    return float(x) if x is not None and np.isfinite(x) else None


def report_data(camp: Any, fits: Any, cal: Any, figures: list[dict[str, str]], *,
                provenance: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The JSON document of the report: every number the page shows, and where they come from
    (``provenance``: :func:`granseg.report.provenance.provenance`, made here when not given)."""
    prov = dict(provenance or make_provenance(list(camp), directory=getattr(camp, "directory", None)))
    return {
        "provenance": prov,
        "granseg_version": prov["granseg_version"],
        "created": prov["created"],
        "campaign": str(getattr(camp, "directory", "")),
        "experiments": [_experiment(m) for m in camp],
        "fits": fits.to_dict(),
        "calibration": cal.to_json(),
        "model": {k: v for k, v in _model_constants(cal).items() if isinstance(v, int | float)},
        "views": views_table(camp),
        "figures": figures,
    }


def _experiment(m: Any) -> dict[str, Any]:
    return {
        "name": m.name, "heavy": m.heavy, "light": m.light, "rho_h": m.rho_h, "rho_l": m.rho_l,
        "delta_R": m.delta_R, "c0": m.c0, "M_g": m.M_g, "M_w": m.M_w, "M_tilde": m.M_tilde,
        "n_times": m.n_times, "n_layers": m.n_layers, "t_end": float(m.t[-1]),
        "smoothing_frames": m.smoothing_frames, "file": None if m.path is None else str(m.path),
    }


# --------------------------------------------------------------------------- page


def _tidy_numbers(text: str) -> str:
    """Floats printed with their binary noise (0.13999999999999999) to 4 significant digits."""
    return re.sub(r"-?\d+\.\d{7,}", lambda m: f"{float(m.group()):.4g}", text)


def _summary(d: Mapping[str, Any]) -> str:
    cal = d["calibration"]
    rows = [[esc(k), pm(cal["best"][k], cal["stderr"][k])] for k in cal["best"]]
    rows.append(["mean RMSD at the optimum", num(cal["rmsd_mean"], ".4f")])
    state = "refined by bounded least squares" if cal["refined"] else "best grid point (no refinement)"
    why = str(cal["message"]).removeprefix("not converged: ")
    warn = "" if cal["converged"] else f'<p class="warn">Refinement did not converge: {esc(why)}</p>'
    s = cal["settings"]
    for k in cal.get("at_bound", []):
        warn += (f'<p class="warn">{esc(k)} ended on a bound of its range {nums(s["bounds"][k])}: '
                 "the optimum may lie beyond it (widen the bounds).</p>")
    shown = set(cal.get("at_bound", []))
    for note in d.get("warnings", []):
        if not any(f"refined {k} =" in note for k in shown):  # those just said, in the page's words
            warn += f'<p class="warn">Warning: {esc(_tidy_numbers(note.removeprefix("calibrate: ")))}</p>'
    return (f"<h2>Calibrated parameters</h2><p class='key'>Optimum {state} "
            f"(&plusmn; one standard error from the Jacobian).</p>{warn}"
            + table(["parameter", "value"], rows)
            + f"<p class='meta'>{num(s.get('n_runs'))} model runs in {num(s.get('n_sweeps'))} sweeps, "
              f"{num(cal['elapsed_s'], '.1f')} s.</p>")


def _experiments(d: Mapping[str, Any]) -> str:
    cal, tanh = d["calibration"], d["fits"]["tanh"]
    head = ["experiment", "heavy / light", "&delta;<sub>R</sub>", "c<sub>0</sub>", "M<sub>g</sub> [kg]",
            "M&#771; [-]", "frames", "smoothing", "RMSD", "A [-]", "t<sub>0</sub> [s]", "&tau; [s]"]
    rows = []
    for x in d["experiments"]:
        f = tanh.get(x["name"])
        fit_cells = ["&ndash;"] * 3 if f is None else [
            pm(f["params"][k], f["stderr"][k], ".3g") + ("" if f["converged"] else " *")
            for k in ("A", "t0", "tau")]
        rows.append([esc(x["name"]), f"{esc(x['heavy'])} / {esc(x['light'])}", num(x["delta_R"], ".3g"),
                     num(x["c0"], ".3g"), num(x["M_g"], ".3g"), num(x["M_tilde"], ".3g"),
                     num(x["n_times"]), num(x["smoothing_frames"]),
                     num(cal["rmsd"].get(x["name"]), ".3f"), *fit_cells])
    return ("<h2>Experiments</h2><p>RMSD of each experiment at the calibrated optimum; "
            "A, t<sub>0</sub>, &tau; from the tanh fit of the bottom layer "
            "(* = fit not converged).</p>" + table(head, rows, left=2))


def _factorial(d: Mapping[str, Any]) -> str:
    cal = d["calibration"]
    names = [x["name"] for x in d["experiments"]]
    keys = list(cal["best"])
    grid = cal["grid"]
    best = min(range(len(grid)), key=lambda i: grid[i]["rmsd_mean"])
    rows = [[str(i + 1), *(num(g[k]) for k in keys), *(num(g["rmsd"][n], ".3f") for n in names),
             num(g["rmsd_mean"], ".3f")] for i, g in enumerate(grid)]
    classes = ["best" if i == best else "" for i in range(len(grid))]
    return ("<h2>Full factorial design</h2><p>RMSD of every experiment for every run; "
            "the highlighted row has the lowest mean.</p>"
            + table(["ID", *map(esc, keys), *map(esc, names), "mean"], rows, classes))


def _per_experiment(d: Mapping[str, Any]) -> str:
    per = d["calibration"].get("per_experiment")
    if not per:
        return ""
    keys = list(d["calibration"]["best"])
    rows = [[esc(n), *(pm(p["best"][k], p["stderr"][k]) for k in keys), num(p["rmsd"], ".3f"),
             yesno(p["converged"])] for n, p in per.items()]
    return ("<h2>Each experiment's own optimum</h2>"
            + table(["experiment", *map(esc, keys), "RMSD", "converged"], rows))


def _laws(d: Mapping[str, Any]) -> str:
    f = d["fits"]
    parts = ["<h2>Bottom-concentration laws</h2>"]
    sel = ", ".join(map(esc, f["selected"])) or "none"
    parts.append(f"<p>Experiments used (c<sub>0</sub> = {num(f['c0'])}): {sel}. RMSE: root-mean-square "
                 "difference between the law and the fitted A or &tau; of those experiments.</p>")
    rows = []
    for key, label, unit in (("beta", "A = 1 &minus; 1/(2 &delta;<sub>R</sub><sup>&beta;</sup>)", "[-]"),
                             ("tau", "&tau; = &tau;<sub>1</sub> exp(&minus;&lambda;(&delta;<sub>R</sub> &minus; 1))",
                              "s")):
        law = f[key]
        if law is None:
            rows.append([label, "not fitted", "&ndash;"])
            continue
        pars = ", ".join(f"{esc(k)} = {pm(v, law['stderr'][k])}" for k, v in law["params"].items())
        rmse = law["mse"] ** 0.5 if law["mse"] is not None and law["mse"] >= 0 else None
        rows.append([label, pars, f"{num(rmse, '.3g')} {unit}"])
    parts.append(table(["law", "parameters", "RMSE"], rows, left=2))
    parts += [f"<p class='warn'>{esc(n)}</p>" for n in f["notes"]]
    return "".join(parts)


def render(data: Mapping[str, Any], out: Path) -> str:
    """The HTML page of report document ``data``; figure files are read from ``out``."""
    return "".join(render_parts(data, out))


def render_parts(data: Mapping[str, Any], out: Path) -> Iterator[str]:
    """The pieces of :func:`render`, each figure read and encoded only when its piece is asked for."""
    title = f"granseg calibration: {Path(data['campaign']).name or data['campaign']}"
    prov = data.get("provenance") or {"input": data["campaign"], "granseg_version": data["granseg_version"],
                                      "created": data["created"], "command": None, "synthetic": False}

    def body() -> Iterator[str]:
        yield from (f"<h1>{esc(title)}</h1>", provenance_section(prov),
                    f"<p class='meta'>{len(data['experiments'])} experiments. "
                    "All numbers are in report.json beside this page.</p>",
                    _summary(data), _experiments(data), _factorial(data), _per_experiment(data), _laws(data),
                    views_section(data.get("views", [])))
        yield from figure_parts(data["figures"], out)

    return page_parts(title + (" (SYNTHETIC data)" if prov.get("synthetic") else ""), body())
