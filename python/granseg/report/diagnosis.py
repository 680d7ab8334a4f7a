"""The diagnosis page: what the model gets wrong, in plain language, with its evidence.

``write_report(diagnosis, DIR)`` writes::

    DIR/index.html            summary, verdict, candidate table, figures (embedded PNG)
    DIR/diagnosis.json        the JSON contract (same as diagnose --json) with its ``provenance``
    DIR/figures/*.png, *.pdf  the figures of :data:`granseg.plot.diagnosis.FIGURES`

The page is rendered from the JSON document (:func:`render`), in the same
style as the calibration page (:mod:`granseg.report.html`). It opens with the
provenance (input, granseg version, UTC date, command line) and, for data not
measured in a laboratory, a SYNTHETIC banner (:mod:`granseg.report.provenance`).
Nothing existing is replaced unless ``force``; the page, its JSON and figures
are written into a hidden ``.DIR.*.partial`` folder and moved into place at
the end, so a failure leaves no half report.

Example::

    >>> write_report(granseg.diagnose("campaign/"), "diag/")     # doctest: +SKIP
    PosixPath('diag/index.html')
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from granseg._io import (
    atomic_write_text,
    check_output_dir,
    check_writable,
    save_json,
    staged_output_dir,
)
from granseg.diagnosis.selection import GAIN_THRESHOLD
from granseg.plot.diagnosis import FIGURES
from granseg.report.html import (
    esc,
    figures,
    num,
    page,
    provenance_section,
    save_figures,
    table,
    tidy_pm,
    views_section,
    yesno,
)
from granseg.report.provenance import provenance

if TYPE_CHECKING:
    from granseg.diagnosis.run import Diagnosis

__all__ = ["OUTPUTS", "CAPTIONS", "write_report", "write_outputs", "render"]

OUTPUTS = ("index.html", "diagnosis.json", "figures")

#: What each figure of :data:`~granseg.plot.diagnosis.FIGURES` shows, for the reader.
CAPTIONS = {
    "residual_maps": "Residual of the baseline, measured minus model (red: more heavy grains measured than "
                     "modelled), for every experiment. Noise looks like speckle; a cause shows as coherent "
                     "patches that repeat across experiments.",
    "covariates": "Each experiment's own optimal delta/H and k, the depth-mean excess and where the "
                  "misfit sits. A trend against a covariate is the clue to the cause.",
    "candidates": "Every catalogued cause fitted to all experiments and scored on experiments it did "
                  "not see (leave-one-out): held-out gain in % of the baseline's held-out RMSD (bottom axis) "
                  "and as an RMSD difference (top axis). Only a gain beyond the threshold names a cause.",
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


def _provenance(d: Diagnosis, command: str | None, synthetic: bool | None, origin: str | None) -> dict[str, Any]:
    return provenance(d.maps, command=command, synthetic=synthetic, origin=origin)


def _captions(r: Mapping[str, Any]) -> dict[str, str]:
    """The figures' captions, with the decision threshold in both of its units where it is drawn."""
    out = dict(CAPTIONS)
    thr = r.get("decision", {}).get("gain_threshold")
    base = r.get("baseline", {}).get("rmsd_held_out_mean")
    if thr is not None and base is not None:
        out["candidates"] += (f" Threshold: {100 * thr:.1f} % of the baseline's held-out RMSD {base:.4f}, "
                              f"a gain of {thr * base:.4f}.")
    return out


def _write(d: Diagnosis, out: str | os.PathLike, force: bool, prov: Mapping[str, Any]) -> Path:
    out = check_output_dir(out, OUTPUTS, force)
    result = {**d.result, "provenance": dict(prov)}
    captions = _captions(result)
    # one figure at a time, into a hidden folder moved into place at the end (nothing half written)
    drawn = ((name, captions[name], fig) for name, draw in FIGURES.items() if (fig := draw(d)) is not None)
    with staged_output_dir(out, OUTPUTS, force, folders=["figures"]) as stage:
        figs = save_figures(drawn, stage)
        save_json(stage / "diagnosis.json", result)
        text = render(result, figs, stage)
        atomic_write_text(stage / "index.html", text)
    return out / "index.html"


def write_report(d: Diagnosis, out: str | os.PathLike, *, force: bool = False, command: str | None = None,
                 synthetic: bool | None = None, origin: str | None = None) -> Path:
    """Draw the figures and write ``out/index.html`` and ``out/diagnosis.json``; return the page.

    ``command`` is the command line that ran the diagnosis (shown in the
    provenance; None from the Python API). ``synthetic`` says whether the data
    were generated rather than measured (None: as the maps tell,
    :func:`granseg.report.provenance.data_origin`); ``origin`` what made them.
    """
    return _write(d, out, force, _provenance(d, command, synthetic, origin))


def write_outputs(d: Diagnosis, *, report: str | os.PathLike | None = None, json: str | os.PathLike | None = None,
                  force: bool = False, command: str | None = None, synthetic: bool | None = None,
                  origin: str | None = None) -> None:
    """The report (:func:`write_report`) and the JSON contract, both with the same ``provenance``.

    What ``diagnose(json=, report=)`` writes, for callers that know the
    command line or that the data are synthetic (``granseg diagnose``,
    ``granseg demo``). The report is written first, so the JSON names it.
    """
    if json is not None:
        check_writable(json, force)
    prov = _provenance(d, command, synthetic, origin)
    if report is not None:
        d.report_path = str(_write(d, report, force, prov))
    if json is not None:
        save_json(json, {**d.result, "provenance": prov}, force=force)


def _pct(gain: Any, base: Any) -> str:
    """A held-out gain in % of the baseline's held-out RMSD (a dash when either is unknown)."""
    if gain is None or not base:
        return "&ndash;"
    return num(100 * gain / base, "+.1f")


def _open_world_section(r: Mapping[str, Any]) -> str:
    """The departure from the model's laws: what was tried, and the law that departs if one does."""
    ow = r.get("open_world")
    if not ow:
        return ""
    dep = r.get("departure")
    base = r["baseline"].get("rmsd_held_out_mean")
    parts = ["<h2>Beyond the catalogue: the model's laws, one at a time</h2>"]
    if dep:
        lit = dep.get("literature_form")
        parts.append(f"<p class='verdict'><b>The {esc(dep['law'].replace('_', ' '))} law departs.</b> "
                     f"{esc(tidy_pm(dep['summary']))} Held-out gain {num(dep['gain_held_out'], '+.4f')} "
                     f"({num(100 * dep['gain_relative'], '.1f')} % of the baseline's held-out RMSD).</p>")
        if lit:
            consts = ", ".join(f"{k} = {v:.3g}" for k, v in lit["constants"].items())
            parts.append(f"<p>Close to a known form: {esc(lit['name'])}, {esc(lit['expression'])} with "
                         f"{esc(consts)} ({esc(lit['reference'])}).</p>")
    else:
        parts.append("<p>No correction of a single law explains the misfit well enough to name it.</p>")
    rows = [[esc(x["name"].removeprefix("law_").replace("_", " ")), esc(tidy_pm(x["description"])),
             num(x["rmsd"], ".4f"),
             num(x["rmsd_held_out"], ".4f") if x["rmsd_held_out"] is not None else "not scored",
             num(x["gain_held_out"], "+.4f") if x["gain_held_out"] is not None else "&ndash;",
             _pct(x["gain_held_out"], base)]
            for x in ow["laws"]]
    hi = ["best" if dep and x["name"] == dep["correction"] else "" for x in ow["laws"]]
    parts.append(table(["law corrected", "correction", "mean RMSD [-]", "held-out RMSD [-]", "held-out gain [-]",
                        "gain [% of baseline]"], rows, hi, left=2))
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


def _rules(r: Mapping[str, Any]) -> str:
    """The decision's thresholds, each in the units the page and the figures use."""
    dec, b = r.get("decision", {}), r["baseline"]
    base = b.get("rmsd_held_out_mean")
    thr = dec.get("gain_threshold", GAIN_THRESHOLD)
    gain = (f"(1) a candidate names a cause when its held-out gain (the baseline's minus its held-out RMSD, mean "
            f"over experiments) exceeds <b>{num(100 * thr, '.1f')} %</b> of the baseline's held-out RMSD"
            + (f" {num(base, '.4f')}, i.e. a gain of <b>{num(thr * base, '.4f')}</b>" if base else "") + ";")
    parts = [gain]
    excess, floor = dec.get("excess_threshold"), r.get("noise_floor")
    if excess is not None:
        within = f"{num(excess, '.2f')} &times; the counted noise floor"
        if floor is not None:
            within += f" ({num(floor, '.4f')}), i.e. {num(excess * floor, '.4f')}"
        alpha, share = dec.get("coherence_alpha"), dec.get("coherence_share")
        parts.append(f"(2) a misfit is left beyond the noise when the mean RMSD exceeds {within}"
                     + (f", or when a residual pattern shared across experiments has p &lt; {num(alpha, 'g')} and "
                        f"holds more than {num(100 * share, '.0f')} % of the residual energy"
                        if alpha is not None and share is not None else "") + ".")
    return "<p>Decision rules: " + " ".join(parts) + "</p>"


def _standing(r: Mapping[str, Any]) -> str:
    """The candidates beyond the threshold other than the named one, and the runner-up's margin."""
    dec, base = r.get("decision", {}), r["baseline"].get("rmsd_held_out_mean")
    thr = dec.get("gain_threshold", GAIN_THRESHOLD)
    cands = sorted(r["candidates"], key=lambda c: c["gain_held_out"], reverse=True)
    if not cands or not base:
        return ""
    named = r["cause"] if r["cause"] != "new_law" else None
    above = [c for c in cands if c["gain_held_out"] > thr * base]
    others = [c for c in above if c["name"] != named]

    def one(c: Mapping[str, Any]) -> str:
        return (f"{esc(c['name'].replace('_', ' '))} ({num(c['gain_held_out'], '+.4f')}, "
                f"{_pct(c['gain_held_out'], base)} %)")

    if not above:
        text = f"No candidate gains beyond the threshold; the best is {one(cands[0])}."
    elif others:
        listed = ", ".join(one(c) for c in others)
        text = (f"{len(above)} of {len(cands)} candidates gain beyond the threshold; besides the named cause, "
                f"{esc(named.replace('_', ' '))}: {listed}." if named in {c['name'] for c in above} else
                f"{len(above)} of {len(cands)} candidates gain beyond the threshold without being named "
                f"(see the decision): {listed}.")
    else:
        text = f"Only {one(above[0])} gains beyond the threshold."
    runner, margin = dec.get("runner_up"), dec.get("margin_to_runner_up")
    if runner and margin is not None:
        lead = ("the law correction leads the catalogue's best," if r["cause"] == "new_law"
                else f"the best candidate, {esc(str(dec.get('best_candidate', '')).replace('_', ' '))}, leads")
        text += (f" Runner-up: {esc(runner.replace('_', ' '))}; {lead} by a held-out gain of "
                 f"{num(margin, '.4f')} ({num(100 * margin / base, '.1f')} % of the baseline's held-out RMSD).")
    return f"<p>{text}</p>"


def render(r: Mapping[str, Any], figs: Sequence[Mapping[str, str]], out: Path) -> str:
    """The HTML page of diagnosis document ``r`` with figures ``figs`` (files read from ``out``)."""
    b = r["baseline"]
    base = b.get("rmsd_held_out_mean")
    thr = r.get("decision", {}).get("gain_threshold", GAIN_THRESHOLD)
    above = [base is not None and c["gain_held_out"] > thr * base for c in r["candidates"]]
    rows = [[esc(c["name"].replace("_", " ")), esc(tidy_pm(c["law"])), num(c["rmsd"], ".4f"),
             num(c["rmsd_held_out"], ".4f"), num(c["gain_held_out"], "+.4f"), _pct(c["gain_held_out"], base),
             yesno(a)] for c, a in zip(r["candidates"], above, strict=True)]
    best = ["best" if c["name"] == r["cause"] else "" for c in r["candidates"]]
    prov = r.get("provenance") or {}
    title = "granseg diagnosis" + (" (SYNTHETIC data)" if prov.get("synthetic") else "")
    threshold = (f"{num(100 * thr, '.1f')} % of the baseline's held-out RMSD"
                 + (f" = a gain of {num(thr * base, '.4f')}" if base else ""))
    return page(title, "".join([
        "<h1>What the model gets wrong</h1>",
        provenance_section(prov),
        f"<p class='verdict'><b>Cause: {esc(r['cause'])}</b> &mdash; misfit explained: "
        f"{yesno(r.get('explained'))}</p>",
        f"<p>{esc(tidy_pm(r['summary']))}</p>",
        f"<p>Noise floor (mean over experiments): {num(r['noise_floor'], '.4f')} "
        f"({esc(r['noise']['method'])}). Baseline: k = {num(b['params']['k'], '.3f')}, "
        f"delta/H = {num(b['params']['delta_over_H'], '.3f')}; mean RMSD {num(b['rmsd_mean'], '.4f')} in sample, "
        f"{num(base, '.4f')} held out. All RMSDs are in units of the heavy share c [-].</p>",
        _rules(r),
        f"<p>Decision: {esc(tidy_pm(r.get('decision', {}).get('reason', '')))}.</p>",
        "<p class='meta'>All numbers are in diagnosis.json beside this page.</p>",
        "<h2>Candidates</h2><p>Every catalogued cause, scored by leave-one-experiment-out; "
        f"the highlighted row is the named cause. Threshold: a held-out gain above {threshold}.</p>",
        table(["cause", "fitted extension", "mean RMSD [-]", "held-out RMSD [-]", "held-out gain [-]",
               "gain [% of baseline]", "above threshold"], rows, best, left=2),
        _standing(r),
        _open_world_section(r),
        _velocity_section(r),
        views_section(r.get("views", [])),
        figures(figs, out, heading="Evidence"),
    ]))
