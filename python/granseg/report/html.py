"""Render the report's JSON document as one self-contained HTML page.

Every number on the page is read from the document :func:`render` gets, and
the figures are embedded as base64 PNG (each with a link to its PDF beside
the page). A small inline script counts the figures the browser decoded and
writes the count into ``<body data-figures-loaded="N/M">`` so that a headless
browser test can see what a user would.
"""

from __future__ import annotations

import base64
import html
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

__all__ = ["render"]

CSS = """
body{font:15px/1.45 system-ui,-apple-system,"Segoe UI",sans-serif;color:#1d1d1f;margin:0;background:#fafafa}
main{max-width:1100px;margin:0 auto;padding:24px 28px 60px;background:#fff}
h1{font-size:1.6em;margin:.2em 0}h2{font-size:1.2em;margin-top:1.8em;border-bottom:1px solid #ddd;padding-bottom:.2em}
.meta{color:#666;font-size:.9em}
table{border-collapse:collapse;font-size:.85em;margin:.6em 0;font-variant-numeric:tabular-nums}
th,td{padding:3px 8px;border-bottom:1px solid #eee;text-align:right}th{background:#f2f2f2}
td.l,th.l{text-align:left}tr.best td{background:#e4f0ff;font-weight:600}
.scroll{overflow-x:auto}
figure{margin:1.2em 0}figure img{max-width:100%;height:auto;border:1px solid #eee}
figcaption{font-size:.9em;color:#444}.key{font-size:1.05em}.warn{color:#a33}
"""

SCRIPT = """
window.addEventListener('load', function () {
  var imgs = document.querySelectorAll('img.fig'), ok = 0;
  imgs.forEach(function (im) { if (im.complete && im.naturalWidth > 0) ok++; });
  document.body.setAttribute('data-figures-loaded', ok + '/' + imgs.length);
});
"""


def _e(x: Any) -> str:
    return html.escape(str(x))


def _num(x: Any, fmt: str = ".4g") -> str:
    if x is None:
        return "&ndash;"
    if isinstance(x, float) and x != x:
        return "&ndash;"
    return format(x, fmt) if isinstance(x, int | float) else _e(x)


def _pm(value: Any, err: Any, fmt: str = ".4g") -> str:
    return f"{_num(value, fmt)} &plusmn; {_num(err, '.2g')}"


def _table(head: Sequence[str], rows: Iterable[Sequence[str]], classes: Sequence[str] = (),
           left: int = 1) -> str:
    th = "".join(f'<th class="{"l" if i < left else ""}">{h}</th>' for i, h in enumerate(head))
    body = []
    for n, row in enumerate(rows):
        cls = classes[n] if n < len(classes) else ""
        tds = "".join(f'<td class="{"l" if i < left else ""}">{c}</td>' for i, c in enumerate(row))
        body.append(f'<tr class="{cls}">{tds}</tr>')
    return f'<div class="scroll"><table><tr>{th}</tr>{"".join(body)}</table></div>'


# --------------------------------------------------------------------------- sections


def _summary(d: Mapping[str, Any]) -> str:
    cal = d["calibration"]
    rows = [[_e(k), _pm(cal["best"][k], cal["stderr"][k])] for k in cal["best"]]
    rows.append(["mean RMSD at the optimum", _num(cal["rmsd_mean"], ".4f")])
    state = "refined by bounded least squares" if cal["refined"] else "best grid point (no refinement)"
    warn = "" if cal["converged"] else f'<p class="warn">Refinement did not converge: {_e(cal["message"])}</p>'
    s = cal["settings"]
    for k in cal.get("at_bound", []):
        warn += (f'<p class="warn">{_e(k)} ended on a bound of its range {_e(str(s["bounds"][k]))}: '
                 "the optimum may lie beyond it (widen the bounds).</p>")
    return (f"<h2>Calibrated parameters</h2><p class='key'>Optimum {state} "
            f"(&plusmn; one standard error from the Jacobian).</p>{warn}"
            + _table(["parameter", "value"], rows)
            + f"<p class='meta'>{_num(s.get('n_runs'))} model runs in {_num(s.get('n_sweeps'))} sweeps, "
              f"{_num(cal['elapsed_s'], '.1f')} s.</p>")


def _experiments(d: Mapping[str, Any]) -> str:
    cal, tanh = d["calibration"], d["fits"]["tanh"]
    head = ["experiment", "heavy / light", "&delta;<sub>R</sub>", "c<sub>0</sub>", "M<sub>g</sub> [kg]",
            "M&#771; [-]", "frames", "smoothing", "RMSD", "A [-]", "t<sub>0</sub> [s]", "&tau; [s]"]
    rows = []
    for x in d["experiments"]:
        f = tanh.get(x["name"])
        fit_cells = ["&ndash;"] * 3 if f is None else [
            _pm(f["params"][k], f["stderr"][k], ".3g") + ("" if f["converged"] else " *")
            for k in ("A", "t0", "tau")]
        rows.append([_e(x["name"]), f"{_e(x['heavy'])} / {_e(x['light'])}", _num(x["delta_R"], ".3g"),
                     _num(x["c0"], ".3g"), _num(x["M_g"], ".3g"), _num(x["M_tilde"], ".3g"),
                     _num(x["n_times"]), _num(x["smoothing_frames"]),
                     _num(cal["rmsd"].get(x["name"]), ".3f"), *fit_cells])
    return ("<h2>Experiments</h2><p>RMSD of each experiment at the calibrated optimum; "
            "A, t<sub>0</sub>, &tau; from the tanh fit of the bottom layer "
            "(* = fit not converged).</p>" + _table(head, rows, left=2))


def _factorial(d: Mapping[str, Any]) -> str:
    cal = d["calibration"]
    names = [x["name"] for x in d["experiments"]]
    keys = list(cal["best"])
    grid = cal["grid"]
    best = min(range(len(grid)), key=lambda i: grid[i]["rmsd_mean"])
    rows = [[str(i + 1), *(_num(g[k]) for k in keys), *(_num(g["rmsd"][n], ".3f") for n in names),
             _num(g["rmsd_mean"], ".3f")] for i, g in enumerate(grid)]
    classes = ["best" if i == best else "" for i in range(len(grid))]
    return ("<h2>Full factorial design</h2><p>RMSD of every experiment for every run; "
            "the highlighted row has the lowest mean.</p>"
            + _table(["ID", *map(_e, keys), *map(_e, names), "mean"], rows, classes))


def _per_experiment(d: Mapping[str, Any]) -> str:
    per = d["calibration"].get("per_experiment")
    if not per:
        return ""
    keys = list(d["calibration"]["best"])
    rows = [[_e(n), *(_pm(p["best"][k], p["stderr"][k]) for k in keys), _num(p["rmsd"], ".3f"),
             "yes" if p["converged"] else "no"] for n, p in per.items()]
    return ("<h2>Each experiment's own optimum</h2>"
            + _table(["experiment", *map(_e, keys), "RMSD", "converged"], rows))


def _laws(d: Mapping[str, Any]) -> str:
    f = d["fits"]
    parts = ["<h2>Bottom-concentration laws</h2>"]
    sel = ", ".join(map(_e, f["selected"])) or "none"
    parts.append(f"<p>Experiments used (c<sub>0</sub> = {_num(f['c0'])}): {sel}.</p>")
    rows = []
    for key, label in (("beta", "A = 1 &minus; 1/(2 &delta;<sub>R</sub><sup>&beta;</sup>)"),
                       ("tau", "&tau; = &tau;<sub>1</sub> exp(&minus;&lambda;(&delta;<sub>R</sub> &minus; 1))")):
        law = f[key]
        if law is None:
            rows.append([label, "not fitted", "&ndash;"])
            continue
        pars = ", ".join(f"{_e(k)} = {_pm(v, law['stderr'][k])}" for k, v in law["params"].items())
        rows.append([label, pars, _num(law["mse"], ".3g")])
    parts.append(_table(["law", "parameters", "MSE"], rows, left=2))
    parts += [f"<p class='warn'>{_e(n)}</p>" for n in f["notes"]]
    return "".join(parts)


def _figures(d: Mapping[str, Any], out: Path) -> str:
    parts = ["<h2>Figures</h2>"]
    for n, fig in enumerate(d["figures"], 1):
        raw = (out / fig["png"]).read_bytes()
        width = int.from_bytes(raw[16:20], "big") // 2  # PNG IHDR width; shown at 2x density
        data = base64.b64encode(raw).decode("ascii")
        parts.append(
            f'<figure id="{_e(fig["id"])}"><img class="fig" width="{width}" alt="{_e(fig["caption"])}" '
            f'src="data:image/png;base64,{data}"><figcaption>Figure {n}. {_e(fig["caption"])} '
            f'(<a href="{_e(fig["pdf"])}">PDF</a>, <a href="{_e(fig["png"])}">PNG</a>)</figcaption></figure>')
    return "".join(parts)


def render(data: Mapping[str, Any], out: Path) -> str:
    """The HTML page of report document ``data``; figure files are read from ``out``."""
    title = f"granseg calibration: {Path(data['campaign']).name or data['campaign']}"
    body = "".join([
        f"<h1>{_e(title)}</h1><p class='meta'>{len(data['experiments'])} experiments from "
        f"{_e(data['campaign'])}; granseg {_e(data['granseg_version'])}, {_e(data['created'])}. "
        "All numbers are in report.json beside this page.</p>",
        _summary(data), _experiments(data), _factorial(data), _per_experiment(data), _laws(data),
        _figures(data, out),
    ])
    return (f'<!DOCTYPE html><html lang="en"><head><meta charset="utf-8">'
            f'<meta name="viewport" content="width=device-width,initial-scale=1">'
            f"<title>{_e(title)}</title><style>{CSS}</style><script>{SCRIPT}</script></head>"
            f"<body><main>{body}</main></body></html>\n")
