"""The HTML pieces both report pages are made of: style, script, numbers, tables, figures.

A page is :func:`page` (title + body, with :data:`CSS` and :data:`SCRIPT`);
its figures are saved by :func:`save_figures` (PNG + PDF beside the page, one
figure at a time) and embedded by :func:`figures` as base64 PNG, each with
links to its files, so the page opens offline. A large page is written piece
by piece (:func:`page_parts`, :func:`figure_parts`, :func:`write_page`), never
held whole. The script counts the figures the browser decoded and
writes the count into ``<body data-figures-loaded="N/M">`` so that a headless
browser test can see what a user would.
"""

from __future__ import annotations

import base64
import html
import re
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

from matplotlib.figure import Figure

from granseg._io import atomic_write
from granseg.plot.base import pm_text, release, save_figure

__all__ = ["CSS", "SCRIPT", "esc", "num", "nums", "pm", "pm_text", "tidy_pm", "yesno", "table", "figures",
           "figure_parts", "save_figures", "page", "page_parts", "write_page", "views_section",
           "provenance_section"]

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
.verdict{font-size:1.2em;padding:.6em;background:#eef5ee;border-left:4px solid #009E73}
.banner{font-size:1.15em;font-weight:700;letter-spacing:.02em;padding:.7em 1em;margin:.4em 0 1em;
color:#5c2600;background:#fff1dc;border:2px solid #D55E00}
.prov{color:#555;font-size:.85em;line-height:1.5}.prov code{font-size:.95em;word-break:break-all}
"""

SCRIPT = """
window.addEventListener('load', function () {
  var imgs = document.querySelectorAll('img.fig'), ok = 0;
  imgs.forEach(function (im) { if (im.complete && im.naturalWidth > 0) ok++; });
  document.body.setAttribute('data-figures-loaded', ok + '/' + imgs.length);
});
"""


def esc(x: Any) -> str:
    """``x`` as text, HTML-escaped."""
    return html.escape(str(x))


def num(x: Any, fmt: str = ".4g") -> str:
    """A number in format ``fmt``; a dash for None or NaN; other values escaped."""
    if x is None:
        return "&ndash;"
    if isinstance(x, float) and x != x:
        return "&ndash;"
    return format(x, fmt) if isinstance(x, int | float) else esc(x)


def pm(value: Any, err: Any, fmt: str = ".4g") -> str:
    """``value ± err`` as HTML, the digits set by the error (:func:`pm_text`)."""
    return esc(pm_text(value, err, fmt)).replace("±", "&plusmn;")


_NUMBER = r"\d+(?:\.\d+)?(?:[eE][-+]?\d+)?"
_PM = re.compile(rf"(?<![\w.])(-?{_NUMBER}) ± ({_NUMBER})(?!\.?\d)")


def tidy_pm(text: str) -> str:
    """Every ``value ± error`` pair in plain ``text`` rewritten by :func:`pm_text`.

    For sentences made elsewhere (a fitted law's text, a summary) that print
    ``1.29e-06 ± 1.4``: on the page they read ``0.0 ± 1.4``.
    """
    return _PM.sub(lambda m: pm_text(float(m.group(1)), float(m.group(2))), text)


def nums(values: Iterable[Any], fmt: str = ".4g") -> str:
    """A sequence of numbers as ``[a, b]`` (each by :func:`num`): bounds, ranges."""
    return "[" + ", ".join(num(v, fmt) for v in values) + "]"


def yesno(flag: Any) -> str:
    """A boolean as the word a reader expects: yes / no (a dash for None)."""
    return "&ndash;" if flag is None else ("yes" if flag else "no")


def table(head: Sequence[str], rows: Iterable[Sequence[str]], classes: Sequence[str] = (),
          left: int = 1) -> str:
    """A scrollable table of HTML cells; the first ``left`` columns left-aligned, ``classes`` per row."""
    th = "".join(f'<th class="{"l" if i < left else ""}">{h}</th>' for i, h in enumerate(head))
    body = []
    for n, row in enumerate(rows):
        cls = classes[n] if n < len(classes) else ""
        tds = "".join(f'<td class="{"l" if i < left else ""}">{c}</td>' for i, c in enumerate(row))
        body.append(f'<tr class="{cls}">{tds}</tr>')
    return f'<div class="scroll"><table><tr>{th}</tr>{"".join(body)}</table></div>'


def save_figures(figs: Iterable[tuple[Any, ...]], out: Path, *, force: bool = False,
                 log: Callable[[str], None] | None = None, total: int | None = None,
                 formats: tuple[str, ...] = ("png", "pdf")) -> list[dict[str, str]]:
    """Save each ``(stem, caption, figure[, formats])`` as ``out/figures/STEM.png`` and ``.pdf``.

    One figure at a time: each is drawn (``figure`` may be a function of no
    arguments that makes it, called only now), saved and released
    (:func:`granseg.plot.base.release`) before the next is made, so memory
    does not grow with the number of figures (``figs`` may be a generator).
    A fourth item chooses that figure's files (default ``formats``).
    ``total`` is the count shown in the progress lines of ``log``.

    Returns the page's figure list: id, caption and the files relative to ``out``
    (``png``; ``pdf`` when one was written).
    """
    entries = []
    for n, (stem, caption, fig, *rest) in enumerate(figs, 1):
        if callable(fig) and not isinstance(fig, Figure):
            fig = fig()
        try:
            paths = save_figure(fig, out / "figures" / stem, force=force, formats=rest[0] if rest else formats)
        finally:
            release(fig)
            del fig
        entry = {"id": stem, "caption": caption}
        entry.update({p.suffix[1:]: f"figures/{p.name}" for p in paths})
        entries.append(entry)
        if log is not None:
            log(f"figure {n}/{total or '?'}: {paths[0].name}")
    return entries


def figure_parts(entries: Sequence[Mapping[str, str]], out: Path, heading: str = "Figures") -> Iterator[str]:
    """The pieces of :func:`figures`, one figure at a time (each PNG read and encoded only when its
    piece is asked for, so a page of hundreds of figures is written without holding them all)."""
    yield f"<h2>{esc(heading)}</h2>"
    for n, fig in enumerate(entries, 1):
        raw = (out / fig["png"]).read_bytes()
        width = int.from_bytes(raw[16:20], "big") // 2  # PNG IHDR width; shown at 2x density
        data = base64.b64encode(raw).decode("ascii")
        del raw
        links = [f'<a href="{esc(fig[k])}">{k.upper()}</a>' for k in ("pdf", "png") if fig.get(k)]
        yield (f'<figure id="{esc(fig["id"])}"><img class="fig" width="{width}" alt="{esc(fig["caption"])}" '
               f'src="data:image/png;base64,{data}"><figcaption>Figure {n}. {esc(fig["caption"])} '
               f'({", ".join(links)})</figcaption></figure>')


def figures(entries: Sequence[Mapping[str, str]], out: Path, heading: str = "Figures") -> str:
    """A section of numbered figures (entries of :func:`save_figures`), PNGs read from ``out``."""
    return "".join(figure_parts(entries, out, heading))


def views_section(rows: Sequence[Mapping[str, Any]]) -> str:
    """The camera's view against the bulk: each run's window check per view
    (:func:`granseg.measure.quality.views_table`); empty when no run has two views."""
    if not rows:
        return ""
    views = sorted({v for r in rows for v in r["views"]})

    def cell(c: Mapping[str, Any] | None) -> str:
        if c is None:
            return "no counts"
        verdict = "fair" if c["passed"] else "<b>flagged</b>"
        return f"{num(c['drift'], '.3f')} / {num(c['limit'], '.3f')} {verdict}"

    body = [[esc(r["name"]), *(cell(r["views"].get(v)) for v in views)] for r in rows]
    flagged = ["best" if any(c and not c["passed"] for c in r["views"].values()) else "" for r in rows]
    return ("<h2>The camera's view against the bulk</h2><p>Runs whose other view lies beside them. A closed bed "
            "keeps its depth-mean heavy share, so a view that samples it fairly does too: each cell gives the "
            "last third's drift from the initial share, the limit its counts allow, and the verdict. The "
            "figure <i>views</i> shows the maps side by side.</p>"
            + table(["run", *(f"{esc(v)} view: drift / limit" for v in views)], body, flagged, left=1))


def provenance_section(prov: Mapping[str, Any] | None) -> str:
    """The banner (synthetic or simulated data) and the provenance line of a page.

    ``prov`` is :func:`granseg.report.provenance.provenance`'s record: ``input``,
    ``granseg_version``, ``created`` (UTC), ``command`` (None when not run from
    the command line), ``synthetic`` and the ``origin`` of synthetic data.
    """
    if not prov:
        return ""
    parts = []
    if prov.get("synthetic"):
        origin = prov.get("origin") or "data generated by a model"
        parts.append(f"<p class='banner' role='note'>SYNTHETIC DATA &mdash; {esc(origin)}. No number on this "
                     "page is a laboratory measurement.</p>")
    created = str(prov.get("created", "")).replace("T", " ").replace("+00:00", " UTC")
    cmd = prov.get("command")
    parts.append(f"<p class='prov'>Input: <code>{esc(prov.get('input', '?'))}</code> &middot; granseg "
                 f"{esc(prov.get('granseg_version', '?'))} &middot; {esc(created)} &middot; command: "
                 + (f"<code>{esc(cmd)}</code>" if cmd else "not run from the command line (Python API)")
                 + "</p>")
    return "".join(parts)


def page_parts(title: str, body: Iterable[str]) -> Iterator[str]:
    """The pieces of :func:`page`, for writing a large page piece by piece (:func:`write_page`)."""
    yield (f'<!DOCTYPE html><html lang="en"><head><meta charset="utf-8">'
           f'<meta name="viewport" content="width=device-width,initial-scale=1">'
           f"<title>{esc(title)}</title><style>{CSS}</style><script>{SCRIPT}</script></head>"
           f"<body><main>")
    yield from body
    yield "</main></body></html>\n"


def page(title: str, body: str) -> str:
    """The whole HTML document: ``title`` (plain text) and ``body`` (HTML) in granseg's style."""
    return "".join(page_parts(title, [body]))


def write_page(path: Path, parts: Iterable[str], *, force: bool = False) -> Path:
    """Write the pieces of a page (:func:`page_parts`) to ``path`` atomically, one at a time."""

    def write(tmp: Path) -> None:
        # a path that is not valid UTF-8 (lone surrogates) is written escaped, as atomic_write_text does
        with open(tmp, "w", encoding="utf-8", errors="backslashreplace") as fh:
            for part in parts:
                fh.write(part)

    return atomic_write(path, write, force=force)
