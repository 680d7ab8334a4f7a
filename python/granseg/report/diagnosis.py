"""The diagnosis page: what the model gets wrong, in plain language, with its evidence.

``write_report(diagnosis, DIR)`` writes::

    DIR/index.html            summary, verdict, candidate table, figures (embedded PNG)
    DIR/diagnosis.json        the JSON contract (same as diagnose --json)
    DIR/figures/*.png, *.pdf  the figures of :data:`granseg.plot.diagnosis.FIGURES`

The page is rendered from the JSON document (:func:`render`), in the same
style as the calibration page (:mod:`granseg.report.html`). Nothing existing
is replaced unless ``force``.

Example::

    >>> write_report(granseg.diagnose("campaign/"), "diag/")     # doctest: +SKIP
    PosixPath('diag/index.html')
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from granseg._io import atomic_write, prepare_output_dir, save_json
from granseg.plot.diagnosis import FIGURES
from granseg.report.html import esc, figures, num, page, save_figures, table, views_section

if TYPE_CHECKING:
    from granseg.diagnosis.run import Diagnosis

__all__ = ["OUTPUTS", "CAPTIONS", "write_report", "render"]

OUTPUTS = ("index.html", "diagnosis.json", "figures")

#: What each figure of :data:`~granseg.plot.diagnosis.FIGURES` shows, for the reader.
CAPTIONS = {
    "residual_maps": "Baseline model minus measurement for every experiment. Noise looks like speckle; "
                     "a cause shows as coherent patches that repeat across experiments.",
    "covariates": "Each experiment's own optimal delta/H and k, the depth-mean excess and where the "
                  "misfit sits. A trend against a covariate is the clue to the cause.",
    "candidates": "Every catalogued cause fitted to all experiments and scored on experiments it did "
                  "not see (leave-one-out). Only a gain beyond the threshold names a cause.",
    "gain": "RMSD per experiment before and after the extension, with the noise floor each map allows.",
    "before_after": "The experiment that gains most: measurement, baseline and extended model.",
    "departure": "Left: the fitted correction of the law that departs, as a factor on the baseline's law, "
                 "with its 95 % band (cluster-robust over experiments) and, dashed, a known form where one "
                 "lies inside the band. Right: every law of the model corrected in turn; the best in sample "
                 "are refitted without each experiment and scored on it.",
    "views": "Each run's camera view against its bulk: both maps, their difference, and each view's depth-mean "
             "heavy share with the band its counts allow (the last third, shaded, is judged). A view outside "
             "its band does not sample the bed fairly.",
}


def write_report(d: Diagnosis, out: str | os.PathLike, *, force: bool = False) -> Path:
    """Draw the figures and write ``out/index.html`` and ``out/diagnosis.json``; return the page."""
    out = prepare_output_dir(out, OUTPUTS, force, folders=["figures"])
    drawn = [(name, CAPTIONS[name], draw(d)) for name, draw in FIGURES.items()]
    figs = save_figures([(n, c, f) for n, c, f in drawn if f is not None], out, force=force)
    result = d.result
    save_json(out / "diagnosis.json", result, force=force)
    text = render(result, figs, out)
    return atomic_write(out / "index.html", lambda tmp: tmp.write_text(text, encoding="utf-8"), force=force)


def _open_world_section(r: Mapping[str, Any]) -> str:
    """The departure from the model's laws: what was tried, and the law that departs if one does."""
    ow = r.get("open_world")
    if not ow:
        return ""
    dep = r.get("departure")
    parts = ["<h2>Beyond the catalogue: the model's laws, one at a time</h2>"]
    if dep:
        lit = dep.get("literature_form")
        parts.append(f"<p class='verdict'><b>The {esc(dep['law'].replace('_', ' '))} law departs.</b> "
                     f"{esc(dep['summary'])} Held-out gain {num(dep['gain_held_out'], '+.4f')} "
                     f"({num(100 * dep['gain_relative'], '.1f')} % of the baseline's held-out RMSD).</p>")
        if lit:
            consts = ", ".join(f"{k} = {v:.3g}" for k, v in lit["constants"].items())
            parts.append(f"<p>Close to a known form: {esc(lit['name'])}, {esc(lit['expression'])} with "
                         f"{esc(consts)} ({esc(lit['reference'])}).</p>")
    else:
        parts.append("<p>No correction of a single law explains the misfit well enough to name it.</p>")
    rows = [[esc(x["name"].removeprefix("law_").replace("_", " ")), esc(x["description"]), num(x["rmsd"], ".4f"),
             num(x["rmsd_held_out"], ".4f") if x["rmsd_held_out"] is not None else "not scored",
             num(x["gain_held_out"], "+.4f") if x["gain_held_out"] is not None else "&ndash;"]
            for x in ow["laws"]]
    hi = ["best" if dep and x["name"] == dep["correction"] else "" for x in ow["laws"]]
    parts.append(table(["law corrected", "correction", "mean RMSD", "held-out RMSD", "held-out gain"], rows, hi,
                       left=2))
    return "".join(parts)


def _velocity_section(r: Mapping[str, Any]) -> str:
    """The shear band fitted to the maps against the one measured from footage (a second instrument)."""
    check = r.get("velocity_check")
    if not check:
        return ""
    head = "<h2>A second instrument: the shear band measured from footage</h2>"
    if not check["pairs"]:
        return head + f"<p>{esc(check['note'])}.</p>"
    word = "agrees with" if check["agrees"] else "<b>disagrees</b> with"
    rows = [[esc(p["parameter"]), num(p["fitted"], ".4f"), num(p["fitted_stderr"], ".4f"),
             num(p["measured"], ".4f"), num(p["measured_stderr"], ".4f"), num(p["z"], "+.1f")]
            for p in check["pairs"]]
    return (head + f"<p>The shear band fitted to the concentration maps {word} the measured {esc(check['measured'])} "
            f"(agreement: within 2 combined standard errors).</p>"
            + table(["parameter", "from the maps", "SE", "from footage", "SE", "difference [SE]"], rows,
                    [""] * len(rows), left=1))


def render(r: Mapping[str, Any], figs: Sequence[Mapping[str, str]], out: Path) -> str:
    """The HTML page of diagnosis document ``r`` with figures ``figs`` (files read from ``out``)."""
    b = r["baseline"]
    rows = [[esc(c["name"].replace("_", " ")), esc(c["law"]), num(c["rmsd"], ".4f"),
             num(c["rmsd_held_out"], ".4f"), num(c["gain_held_out"], "+.4f")] for c in r["candidates"]]
    best = ["best" if c["name"] == r["cause"] else "" for c in r["candidates"]]
    return page("granseg diagnosis", "".join([
        "<h1>What the model gets wrong</h1>",
        f"<p class='verdict'><b>Cause: {esc(r['cause'])}</b> &mdash; explained: {esc(r['explained'])}</p>",
        f"<p>{esc(r['summary'])}</p>",
        f"<p>Noise floor (mean over experiments): {num(r['noise_floor'], '.4f')} ({esc(r['noise']['method'])}). "
        f"Baseline: k = {num(b['params']['k'], '.3f')}, delta/H = {num(b['params']['delta_over_H'], '.3f')}; "
        f"mean RMSD {num(b['rmsd_mean'], '.4f')} in sample, {num(b['rmsd_held_out_mean'], '.4f')} held out. "
        f"Decision: {esc(r['decision']['reason'])}.</p>",
        "<p class='meta'>All numbers are in diagnosis.json beside this page.</p>",
        "<h2>Candidates</h2><p>Every catalogued cause, scored by leave-one-experiment-out; "
        "the highlighted row is the named cause.</p>",
        table(["cause", "fitted extension", "mean RMSD", "held-out RMSD", "held-out gain"], rows, best, left=2),
        _open_world_section(r),
        _velocity_section(r),
        views_section(r.get("views", [])),
        figures(figs, out, heading="Evidence"),
    ]))
