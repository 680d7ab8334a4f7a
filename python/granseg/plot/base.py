"""What every granseg figure shares: the style, the axis labels, map cell edges and saving.

Figures are built without pyplot (no GUI, no global state, Agg canvas) inside
:func:`style`; :func:`save_figure` writes each as ``STEM.png`` and
``STEM.pdf`` atomically, refusing to replace existing files unless ``force``,
and :func:`release` frees a saved figure at once (a report of hundreds of
figures holds one at a time).

Text a user supplied (an experiment's name, a material, a parameter name) is
put in a figure through :func:`literal`, so that it is shown as written: a
``$`` in a name never starts matplotlib's mathtext.
"""

from __future__ import annotations

import contextlib
import math
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import matplotlib
import numpy as np
from matplotlib.figure import Figure

from granseg._io import atomic_path, check_writable

__all__ = ["STYLE", "C_LABEL", "T_LABEL", "H_LABEL", "style", "new_figure", "save_figure", "release",
           "literal", "edges", "time_edges", "map_edges", "pm_text"]

STYLE: dict[str, Any] = {
    "font.size": 8.5,
    "axes.labelsize": 9,
    "axes.titlesize": 9,
    "legend.fontsize": 7.5,
    "xtick.labelsize": 8,
    "ytick.labelsize": 8,
    "axes.spines.top": False,
    "axes.spines.right": False,
    "axes.linewidth": 0.8,
    "lines.linewidth": 1.4,
    "lines.markersize": 4,
    "legend.frameon": False,
    "figure.dpi": 100,
    "savefig.dpi": 220,
    "savefig.bbox": "tight",
    "savefig.pad_inches": 0.03,
    "pdf.fonttype": 42,
    "image.cmap": "viridis",
    "axes.prop_cycle": matplotlib.cycler(color=[
        "#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00", "#56B4E9", "#F0E442", "#000000",
    ]),
}
C_LABEL = "heavy concentration c [-]"
T_LABEL = "time t [s]"
H_LABEL = r"height $H^* = z/H$ [-]"


@contextlib.contextmanager
def style() -> Iterator[None]:
    """Context in which figures get granseg's style (rcParams of :data:`STYLE`)."""
    with matplotlib.rc_context(STYLE):
        yield


def new_figure(width: float, height: float) -> Figure:
    """A new figure in inches, constrained layout (call inside :func:`style`)."""
    return Figure(figsize=(width, height), layout="constrained")


def literal(text: Any) -> str:
    """``text`` (a name, a material, any text a user supplied) escaped for a matplotlib label.

    Every ``$`` becomes ``\\$``, which matplotlib shows as a plain dollar sign
    whether or not the rest of the label holds mathtext (``$\\delta_R$``): a
    name such as ``G-$\\foo{$-50`` is shown as written instead of being parsed
    as a formula (and failing). Other characters need no escaping outside
    ``$...$``.
    """
    return str(text).replace("$", r"\$")


def save_figure(fig: Figure, stem: str | os.PathLike, *, force: bool = False,
                formats: tuple[str, ...] = ("png", "pdf")) -> list[Path]:
    """Write ``fig`` to ``STEM.png`` and ``STEM.pdf`` atomically; return both paths.

    Both destinations are checked before anything is written, so an existing
    file (without ``force``) leaves neither half written. ``formats`` chooses
    the files (in that order; PNG and PDF by default).
    """
    stem = Path(stem)
    paths = [stem.with_name(f"{stem.name}.{ext}") for ext in formats]
    for p in paths:
        check_writable(p, force)
    # a figure laid out by hand (no layout engine: a page of maps) fills its canvas as made; trimming
    # it would draw it twice
    bbox = {} if fig.get_layout_engine() is not None else {"bbox_inches": None}
    with style():
        for p in paths:
            with atomic_path(p, force=force) as tmp:
                fig.savefig(tmp, format=p.suffix[1:], **bbox)
    return paths


def release(fig: Figure) -> None:
    """Free saved figure ``fig`` now: its artists and data, and the canvas's pixel buffer.

    A figure's parts refer to each other, so dropping the last reference
    frees them only at the next full garbage collection; a report drawing
    hundreds of figures would hold them all until then. The figure is empty
    afterwards.
    """
    fig.clear()
    for attr in ("renderer", "_lastKey"):  # the Agg canvas's cached renderer holds the pixel buffer
        fig.canvas.__dict__.pop(attr, None)


def edges(x: np.ndarray, lo: float | None = None, hi: float | None = None) -> np.ndarray:
    """Cell edges around centres ``x`` (midpoints; ends extended by half a step)."""
    x = np.asarray(x, dtype=float)
    if x.size == 1:
        return np.array([x[0] - 0.5, x[0] + 0.5])
    mid = 0.5 * (x[1:] + x[:-1])
    first = x[0] - (mid[0] - x[0]) if lo is None else lo
    last = x[-1] + (x[-1] - mid[-1]) if hi is None else hi
    return np.concatenate([[first], mid, [last]])


def time_edges(t: np.ndarray) -> np.ndarray:
    """Cell edges of sampling times t [s]: half a median step before the first, never below 0."""
    t = np.asarray(t, dtype=float)
    step = float(np.median(np.diff(t))) if t.size > 1 else 1.0
    return edges(t, lo=max(t[0] - 0.5 * step, 0.0))


def map_edges(m: Any, H: float) -> tuple[np.ndarray, np.ndarray]:
    """Cell edges of map ``m``: time t [s] (:func:`time_edges`) and height H* = z / H [-]."""
    te = time_edges(m.t)
    ze = edges(m.z / H, lo=0.0) if m.z[0] > 0 else edges(m.z / H)
    return te, ze


def _finite(x: Any) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)


def pm_text(value: Any, err: Any, fmt: str = ".4g") -> str:
    """``value ± err`` as plain text, the digits set by the error.

    The error keeps two significant digits and the value is rounded to the
    same decimal place, so a value far below its error reads as what it is
    (``1.29e-06 ± 1.4`` gives ``0.0 ± 1.4``); very small or very large
    numbers share one power of ten (``(1.290 ± 0.020)e-06``). Without a
    usable error (None, NaN, zero) the value alone in format ``fmt``.
    """
    if not _finite(value):
        return "–" if value is None or isinstance(value, float) else str(value)
    if not _finite(err) or err <= 0:
        return format(value, fmt)
    err = float(err)
    value = float(value)
    top = math.floor(math.log10(max(abs(value), err)))
    scale = 0 if -3 <= top < 6 else top
    v, e = value / 10.0**scale, err / 10.0**scale
    places = 1 - math.floor(math.log10(e))  # decimals that keep two significant digits of the error
    e = round(e, places)
    if e > 0 and 1 - math.floor(math.log10(e)) < places:  # rounding carried (0.0996 -> 0.10)
        places -= 1
    v = round(v, places) + 0.0  # + 0.0: no "-0.0"
    d = max(places, 0)
    body = f"{v:.{d}f} ± {e:.{d}f}"
    return body if scale == 0 else f"({body})e{scale:+03d}"
