"""Exports a lab uses: maps, calibrations and diagnoses as CSV tables (and maps as MATLAB ``.mat``).

Every table is a CSV file a spreadsheet opens as it is: UTF-8, comma-separated,
one header row, ``.`` as decimal mark, no index column; numbers are written
with full (``repr``) precision, a missing value (NaN, ``null``) is an empty
cell, a yes/no is ``true``/``false``.

A map ``NAME`` (its experiment name; characters a file name should not hold
become ``_``) gives

- ``NAME_c.csv``: the heavy share [-], one row per frame: ``t_s`` (time [s])
  then one column per layer, named by its centre height above the bottom plate
  in metres (``z_0.003134m``; the exact heights are in the ``.mat``);
- ``NAME_n.csv``, ``NAME_n_heavy.csv``, ``NAME_c_raw.csv``: the counts and the
  unsmoothed share in the same layout, where the map holds them;
- ``NAME_conditions.csv``: ``key,value,unit`` rows (materials, densities,
  c0, masses, frame rate, smoothing, view, and the map's own cell constants);
- ``NAME.mat`` (:func:`scipy.io.savemat`): ``c`` (n_t x n_layers), ``t`` and
  ``z`` (column vectors), ``n``, ``n_heavy``, ``c_raw`` where present (as
  doubles, so ``n_heavy ./ n`` divides as expected), every scalar and text of
  the conditions by its docs/formats.md name, and ``units``, a struct naming
  each variable's unit.

A diagnosis JSON (``granseg diagnose --json``) gives ``diagnosis_candidates.csv``,
``diagnosis_experiments.csv``, ``diagnosis_parameters.csv`` and, when laws were
explored, ``diagnosis_laws.csv``; a calibration JSON (``granseg calibrate --json``)
gives ``calibration_parameters.csv``, ``calibration_experiments.csv`` and
``calibration_grid.csv``.

Every destination is checked before anything is written, each file is written
atomically (:mod:`granseg._io`), and an existing file is only replaced with
``force=True`` (else :class:`~granseg.errors.OutputExistsError` names it).

Example::

    >>> export_map("G-PP-50.npz", "exports")                 # doctest: +SKIP
    [PosixPath('exports/G-PP-50_c.csv'), ..., PosixPath('exports/G-PP-50.mat')]
"""

from __future__ import annotations

import csv
import json
import math
import os
import re
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from granseg._io import atomic_write, prepare_output_dir
from granseg.maps import CELL_KEYS, Campaign, Map, load_campaign, load_map

__all__ = ["FORMATS", "export_map", "export_campaign", "export_json_tables", "export_paths"]

#: The formats a map can be exported to.
FORMATS = ("csv", "mat")

# unit of each conditions key (docs/formats.md)
UNITS: dict[str, str] = {
    "name": "", "heavy": "", "light": "", "rho_h": "kg/m^3", "rho_l": "kg/m^3", "c0": "-",
    "M_g": "kg", "M_w": "kg", "fps": "1/s", "smoothing_frames": "frames", "view": "",
    "H": "m", "D_p": "m", "D_in": "m", "D_out": "m", "rpm": "rev/min", "v1": "m/s", "phi_s": "-", "g": "m/s^2",
}
_ARRAY_UNITS = {"c": "-", "t": "s", "z": "m", "n": "count", "n_heavy": "count", "c_raw": "-", "quality": "JSON"}

_Writer = Callable[[Path], None]
_Plan = list[tuple[str, _Writer]]  # (file name in the output folder, writer of a temporary path)


# --------------------------------------------------------------------------- public


def export_map(map_or_path: Map | str | os.PathLike, out_dir: str | os.PathLike, *,
               formats: str | Sequence[str] = FORMATS, force: bool = False) -> list[Path]:
    """Write one map's tables (``formats``: ``"csv"``, ``"mat"`` or both) into ``out_dir``.

    ``map_or_path`` is a :class:`~granseg.maps.Map` or a map ``.npz``. Returns the
    paths written. Raises OutputExistsError naming the files that exist (unless
    ``force``), before anything is written.
    """
    m = map_or_path if isinstance(map_or_path, Map) else load_map(map_or_path)
    return _write(out_dir, _map_plan(m, _formats(formats)), force)


def export_campaign(dir_or_campaign: Campaign | Sequence[Map] | str | os.PathLike, out_dir: str | os.PathLike, *,
                    formats: str | Sequence[str] = FORMATS, force: bool = False) -> list[Path]:
    """Write every map of a campaign (a directory, a :class:`~granseg.maps.Campaign` or a list
    of maps) into ``out_dir``, as :func:`export_map` does; all or nothing is checked first."""
    return _write(out_dir, _campaign_plan(dir_or_campaign, _formats(formats)), force)


def export_json_tables(json_path: str | os.PathLike, out_dir: str | os.PathLike, *,
                       force: bool = False) -> list[Path]:
    """Write the tables of a diagnosis or calibration JSON as CSV files into ``out_dir``.

    The kind is told by the JSON's keys; a JSON of another kind, or one that is
    not valid JSON, is a ValueError naming the file.
    """
    return _write(out_dir, _json_plan(Path(json_path)), force)


def export_paths(inputs: Iterable[str | os.PathLike], out_dir: str | os.PathLike, *,
                 formats: str | Sequence[str] = FORMATS, force: bool = False) -> list[Path]:
    """Export each input, told apart by what it is: a map ``.npz``, a campaign directory or a
    diagnosis / calibration JSON (whose tables are always CSV). Every input is read and every
    destination checked before anything is written; two inputs that would write the same
    file are a ValueError."""
    fmts = _formats(formats)
    plan: _Plan = []
    owner: dict[str, Path] = {}
    for item in inputs:
        p = Path(item)
        if p.is_dir():
            part = _campaign_plan(p, fmts)
        elif not p.exists():
            raise FileNotFoundError(f"{p}: no such file or directory")
        elif p.suffix.lower() == ".npz":
            part = _map_plan(load_map(p), fmts)
        elif p.suffix.lower() == ".json":
            part = _json_plan(p)
        else:
            raise ValueError(f"{p}: not a map (.npz), a campaign directory or a diagnosis/calibration JSON")
        for name, _ in part:
            if owner.get(name, p) != p:
                raise ValueError(f"{owner[name]} and {p} would both write {Path(out_dir) / name}; "
                                 "export them into separate folders")
            owner[name] = p
        plan += part
    return _write(out_dir, plan, force)


# --------------------------------------------------------------------------- writing


def _formats(formats: str | Sequence[str]) -> tuple[str, ...]:
    fmts = (formats,) if isinstance(formats, str) else tuple(formats)
    bad = [f for f in fmts if f not in FORMATS]
    if bad or not fmts:
        raise ValueError(f"formats = {formats!r}: choose from {', '.join(FORMATS)}")
    return fmts


def _write(out_dir: str | os.PathLike, plan: _Plan, force: bool) -> list[Path]:
    """Check every destination of ``plan``, then write each file atomically."""
    names = [name for name, _ in plan]
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        raise ValueError(f"{out_dir}: two exports would both write {dupes[0]}; export them into separate folders")
    out = prepare_output_dir(out_dir, names, force)
    return [atomic_write(out / name, writer, force) for name, writer in plan]


def _text(v: Any) -> str:
    """One CSV cell: repr precision for numbers, empty for a missing value."""
    if v is None:
        return ""
    if isinstance(v, bool | np.bool_):
        return "true" if v else "false"
    if isinstance(v, int | np.integer):
        return str(int(v))
    if isinstance(v, float | np.floating):
        return repr(float(v)) if math.isfinite(v) else ("" if math.isnan(v) else repr(float(v)))
    if isinstance(v, str):
        return v
    return json.dumps(v)  # a list or object inside a table cell


def _csv(header: Sequence[str], rows: Iterable[Sequence[Any]]) -> _Writer:
    lines = [list(header)] + [[_text(v) for v in row] for row in rows]

    def write(tmp: Path) -> None:
        with open(tmp, "w", encoding="utf-8", newline="") as fh:
            csv.writer(fh, lineterminator="\n").writerows(lines)

    return write


# --------------------------------------------------------------------------- maps


def _stem(name: str) -> str:
    """A file name from an experiment name (letters, digits, ``.``, ``-``, ``_``)."""
    return re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._") or "map"


def _layer_columns(z: np.ndarray) -> list[str]:
    """Column names of the layers, ``z_<centre in m>m``, with as many digits as tell them apart."""
    for digits in range(4, 18):
        cols = [f"z_{v:.{digits}g}m" for v in z]
        if len(set(cols)) == len(cols):
            return cols
    return [f"z_{v!r}m" for v in z]


def _map_plan(m: Map, formats: tuple[str, ...]) -> _Plan:
    stem = _stem(m.name)
    plan: _Plan = []
    if "csv" in formats:
        header = ["t_s", *_layer_columns(m.z)]
        for key in ("c", "n", "n_heavy", "c_raw"):
            a = getattr(m, key)
            if a is not None:
                plan.append((f"{stem}_{key}.csv", _csv(header, ([t, *row] for t, row in zip(m.t, a.tolist(),
                                                                                              strict=True)))))
        plan.append((f"{stem}_conditions.csv", _csv(["key", "value", "unit"],
                                                    ([k, v, UNITS.get(k, "")] for k, v in _conditions(m).items()))))
    if "mat" in formats:
        plan.append((f"{stem}.mat", _mat(m)))
    return plan


def _conditions(m: Map) -> dict[str, Any]:
    keys = ("name", "heavy", "light", "rho_h", "rho_l", "c0", "M_g", "M_w", "fps", "smoothing_frames", "view")
    out = {k: getattr(m, k) for k in keys}
    out.update({k: m.cell[k] for k in CELL_KEYS if k in m.cell})
    return out


def _mat(m: Map) -> _Writer:
    import scipy.io

    arrays: dict[str, Any] = {"c": m.c, "t": m.t, "z": m.z}
    for key in ("n", "n_heavy", "c_raw"):
        a = getattr(m, key)
        if a is not None:
            arrays[key] = np.asarray(a, dtype=float)
    meta = {k: (float(v) if isinstance(v, int | float) else v) for k, v in _conditions(m).items() if v is not None}
    if m.quality is not None:
        meta["quality"] = m.quality
    data = {**arrays, **meta}
    units = {**UNITS, **_ARRAY_UNITS}
    data["units"] = {k: units[k] for k in data if units.get(k)}  # every number's unit (texts have none)

    def write(tmp: Path) -> None:
        scipy.io.savemat(tmp, data, appendmat=False, oned_as="column", do_compression=True)

    return write


def _campaign_plan(campaign: Campaign | Sequence[Map] | str | os.PathLike, formats: tuple[str, ...]) -> _Plan:
    maps = load_campaign(campaign) if isinstance(campaign, str | os.PathLike) else list(campaign)
    return [step for m in maps for step in _map_plan(m, formats)]


# --------------------------------------------------------------------------- JSON tables


def _json_plan(path: Path) -> _Plan:
    if not path.is_file():
        raise FileNotFoundError(f"{path}: JSON file not found")
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from None
    keys = set(doc) if isinstance(doc, dict) else set()
    if {"cause", "baseline", "candidates"} <= keys:
        kind, build = "diagnosis", _diagnosis_tables
    elif {"best", "stderr", "rmsd", "grid"} <= keys:
        kind, build = "calibration", _calibration_tables
    else:
        raise ValueError(f"{path}: neither a diagnosis JSON (granseg diagnose --json) nor a calibration JSON "
                         "(granseg calibrate --json); no tables to export")
    try:
        tables = build(doc)
    except (KeyError, TypeError, AttributeError, ValueError) as exc:
        raise ValueError(f"{path}: malformed {kind} JSON ({type(exc).__name__}: {exc})") from None
    return [(name, _csv(header, rows)) for name, (header, rows) in tables.items()]


_Table = tuple[list[str], list[list[Any]]]


def _param_columns(records: Iterable[Mapping[str, Any]]) -> list[str]:
    """Parameter names over every record's ``params``, in order of first appearance."""
    seen: dict[str, None] = {}
    for r in records:
        seen.update(dict.fromkeys(r.get("params") or {}))
    return list(seen)


def _diagnosis_tables(d: Mapping[str, Any]) -> dict[str, _Table]:
    cands = list(d["candidates"])
    params = _param_columns(cands)
    head = ["name", "rmsd", "rmsd_held_out", "gain_in_sample", "gain_held_out"]
    candidates = (head + [c for p in params for c in (p, f"{p}_stderr")] + ["law", "description"],
                  [[c.get(k) for k in head]
                   + [v for p in params for v in (c["params"].get(p), (c.get("stderr") or {}).get(p))]
                   + [c.get("law"), c.get("description")] for c in cands])

    base, ext = d["baseline"], d.get("extended")
    floors = (d.get("noise") or {}).get("per_experiment") or {}
    covariates = {e["name"]: e for e in d.get("experiments") or []}
    cov_keys = ["heavy", "light", "c0", "M_g", "M_w"] if covariates else []
    experiments = (["experiment", "baseline_rmsd", "baseline_rmsd_held_out", "extended_rmsd",
                    "extended_rmsd_held_out", "noise_floor", *cov_keys],
                   [[n, base["rmsd"][n], base["rmsd_held_out"].get(n),
                     None if ext is None else ext["rmsd"].get(n),
                     None if ext is None else ext["rmsd_held_out"].get(n), floors.get(n)]
                    + [covariates.get(n, {}).get(k) for k in cov_keys] for n in base["rmsd"]])

    rows = [["baseline", "baseline", p, v, base["stderr"].get(p)] for p, v in base["params"].items()]
    if ext is not None:
        rows += [["extended", ext.get("model"), p, v, ext["stderr"].get(p)] for p, v in ext["params"].items()]
    tables = {"diagnosis_candidates.csv": candidates, "diagnosis_experiments.csv": experiments,
              "diagnosis_parameters.csv": (["model", "effect", "parameter", "value", "stderr"], rows)}

    ow = d.get("open_world")
    if ow:
        laws = list(ow["laws"])
        cols: dict[str, None] = {}
        for r in laws:
            cols.update(dict.fromkeys(r))
        tables["diagnosis_laws.csv"] = (list(cols), [[r.get(k) for k in cols] for r in laws])
    return tables


def _calibration_tables(cal: Mapping[str, Any]) -> dict[str, _Table]:
    best, stderr, at_bound = cal["best"], cal["stderr"], set(cal.get("at_bound") or [])
    intervals = cal.get("intervals")
    head = ["parameter", "value", "stderr", "at_bound"]
    if intervals:
        head += ["lo", "hi", "level"]
    rows = []
    for p, v in best.items():
        row = [p, v, stderr.get(p), p in at_bound]
        if intervals:
            iv = intervals["params"].get(p) or {}
            row += [iv.get("lo"), iv.get("hi"), intervals.get("level")]
        rows.append(row)
    tables = {"calibration_parameters.csv": (head, rows)}

    own = cal.get("per_experiment") or {}
    own_params = _param_columns({"params": o["best"]} for o in own.values())
    own_cols = [c for p in own_params for c in (f"own_{p}", f"own_{p}_stderr")]
    own_cols += ["own_rmsd", "own_converged"] if own else []
    exp_rows = []
    for n, v in cal["rmsd"].items():
        row = [n, v]
        if own:
            o = own.get(n) or {"best": {}, "stderr": {}}
            row += [x for p in own_params for x in (o["best"].get(p), o["stderr"].get(p))]
            row += [o.get("rmsd"), o.get("converged")]
        exp_rows.append(row)
    tables["calibration_experiments.csv"] = (["experiment", "rmsd", *own_cols], exp_rows)

    grid = list(cal["grid"])
    keys = [k for k in (grid[0] if grid else {}) if k not in ("rmsd", "rmsd_mean")]
    names = list(grid[0]["rmsd"]) if grid else []
    tables["calibration_grid.csv"] = (
        ["point", *keys, *(f"rmsd_{n}" for n in names), "rmsd_mean"],
        [[i, *(g[k] for k in keys), *(g["rmsd"][n] for n in names), g["rmsd_mean"]]
         for i, g in enumerate(grid, 1)])
    return tables
