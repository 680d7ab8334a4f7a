"""The calibration report of a campaign: one self-contained HTML page plus JSON.

:func:`build_report` loads a campaign, fits the bottom curves and the
A / tau laws, calibrates the model (or takes a given calibration), draws the
figures and writes into ``OUT``::

    OUT/index.html      the page (figures embedded as PNG; opens offline)
    OUT/report.json     every number the page shows, machine-readable
    OUT/figures/*.png   the same figures as files, with a PDF beside each

The HTML is rendered from the JSON document, so the two cannot disagree.
Nothing existing is replaced unless ``force=True``.

Example::

    >>> build_report("campaign/", "report/")                     # doctest: +SKIP
    PosixPath('report/index.html')
"""

from __future__ import annotations

import datetime as _dt
import os
import re
from pathlib import Path
from typing import Any

import numpy as np

from granseg._io import OutputExistsError, atomic_write, save_json
from granseg.report.html import render

__all__ = ["build_report", "report_data"]

OUTPUTS = ("index.html", "report.json", "figures")


def _prepare_out(out: Path, force: bool) -> Path:
    if out.exists() and not out.is_dir():
        raise NotADirectoryError(f"{out}: exists and is not a directory")
    if not out.parent.exists():
        raise FileNotFoundError(f"{out.parent}: output folder does not exist")
    clash = [n for n in OUTPUTS if (out / n).exists()]
    if clash and not force:
        raise OutputExistsError(f"{out}: already holds {clash}; pass force=True (CLI: --force)")
    (out / "figures").mkdir(parents=True, exist_ok=True)
    return out


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
    **calibrate_kwargs: Any,
) -> Path:
    """Write the report of ``campaign`` (directory or Campaign) into folder ``out``.

    ``calibration`` is a :class:`granseg.calibration.Calibration` to reuse;
    otherwise :func:`granseg.calibration.calibrate` runs with
    ``calibrate_kwargs``. ``fits_c0`` selects the experiments whose A and
    tau are fitted with the laws (None = all). Returns the HTML path.
    """
    from granseg.calibration import calibrate
    from granseg.fit import fit_campaign
    from granseg.maps import load_campaign

    camp = campaign if hasattr(campaign, "maps") else load_campaign(campaign)
    out = _prepare_out(Path(out), force)
    fits = fit_campaign(camp, c0=fits_c0)
    cal = calibration or calibrate(camp, progress=progress, **calibrate_kwargs)
    figures = _draw_figures(camp, fits, cal, out / "figures", force, progress)
    data = report_data(camp, fits, cal, figures)
    save_json(out / "report.json", data, force=force)
    page = render(data, out)
    atomic_write(out / "index.html", lambda tmp: tmp.write_text(page, encoding="utf-8"), force=force)
    return out / "index.html"


def _model_constants(cal: Any) -> dict[str, float]:
    import granseg

    params = dict(granseg.defaults())
    params.update(cal.settings.get("base", {}))
    params.update(cal.best)
    return params


def _initial_profile(m: Any, params: dict[str, Any], n_cells: int) -> tuple[np.ndarray, np.ndarray]:
    import granseg

    sol = granseg.simulate(**{**params, **m.case()}, t=np.array([0.0]), n_cells=n_cells)
    return np.asarray(sol.z), np.asarray(sol.c)[0]


def _draw_figures(camp: Any, fits: Any, cal: Any, folder: Path, force: bool,
                  progress: bool) -> list[dict[str, str]]:
    from granseg import plot

    params = _model_constants(cal)
    H = float(params["H"])
    figs: list[tuple[str, str, Any]] = [
        ("bottom_fits", "Bottom-layer concentration with tanh fits", plot.bottom_fits(list(camp), fits.tanh)),
        ("laws", "Final concentration A and time tau against density ratio", plot.laws(fits)),
    ]
    if len(cal.keys) == 2:
        figs.append(("rmsd_grid", "Mean RMSD over the factorial grid",
                     plot.rmsd_grid(cal.grid_points, cal.grid_mean, best=cal.best if cal.refined else None,
                                    stderr=cal.stderr if cal.refined else None)))
    dgrid = cal.settings["grid"].get("delta_over_H", [])
    figs.append(("profiles", "Velocity and shear-rate profiles of the calibrated model",
                 plot.profiles(params, deltas=dgrid, delta_err=_finite(cal.stderr.get("delta_over_H")))))
    n_cells = int(cal.settings.get("n_cells", 180))
    for i, (m, lay) in enumerate(zip(camp, cal.model_layers, strict=True)):
        init = _initial_profile(m, params, n_cells)
        fig = plot.map_comparison(m, lay, H=H, rmsd=cal.rmsd[m.name], initial=init)
        figs.append((_slug(i, m.name), f"{m.name}: measured and model maps", fig))
    out = []
    for n, (stem, caption, fig) in enumerate(figs, 1):
        png, pdf = plot.save_figure(fig, folder / stem, force=force)
        out.append({"id": stem, "caption": caption, "png": f"figures/{png.name}", "pdf": f"figures/{pdf.name}"})
        if progress:
            print(f"[report] figure {n}/{len(figs)}: {png.name}", flush=True)
    return out


def _finite(x: Any) -> float | None:
    return float(x) if x is not None and np.isfinite(x) else None


def report_data(camp: Any, fits: Any, cal: Any, figures: list[dict[str, str]]) -> dict[str, Any]:
    """The JSON document of the report: every number the page shows."""
    import granseg

    return {
        "granseg_version": granseg.__version__,
        "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "campaign": str(getattr(camp, "directory", "")),
        "experiments": [_experiment(m) for m in camp],
        "fits": fits.to_dict(),
        "calibration": cal.to_json(),
        "model": {k: v for k, v in _model_constants(cal).items() if isinstance(v, int | float)},
        "figures": figures,
    }


def _experiment(m: Any) -> dict[str, Any]:
    return {
        "name": m.name, "heavy": m.heavy, "light": m.light, "rho_h": m.rho_h, "rho_l": m.rho_l,
        "delta_R": m.delta_R, "c0": m.c0, "M_g": m.M_g, "M_w": m.M_w, "M_tilde": m.M_tilde,
        "n_times": m.n_times, "n_layers": m.n_layers, "t_end": float(m.t[-1]),
        "smoothing_frames": m.smoothing_frames, "file": None if m.path is None else str(m.path),
    }
