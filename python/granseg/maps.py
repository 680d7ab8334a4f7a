"""Measured concentration maps and campaigns: the ``.npz`` formats of docs/formats.md.

A *map* is one experiment: the heavy share ``c`` [-] of each horizontal layer
(``z`` [m], layer centres above the bottom wall) at each time ``t`` [s], plus
the materials, densities [kg/m^3], the overall heavy fraction ``c0`` [-] and
the masses ``M_g`` (grains) and ``M_w`` (lid load) [kg]. A *campaign* is a
directory of such maps.

Readers validate everything and reject a bad file with one message that names
the file and the field; they never guess a missing value. Writers are atomic
and refuse to replace an existing file unless ``force=True``.

Example::

    >>> m = load_map("G-PP-50.npz")                         # doctest: +SKIP
    >>> m.delta_R, m.M_tilde, m.n_layers                    # doctest: +SKIP
    (2.59, 0.536, 15)

:func:`moving_average` is the one centred moving average of the project (the
window shrinks symmetrically at the ends of the series); the frame pipeline,
the calibration and the plots all use it.
"""

from __future__ import annotations

import json
import math
import os
import struct
import warnings
import zipfile
import zlib
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from granseg._io import PARTIAL_SUFFIX, save_npz
from granseg.errors import FlaggedMapError, MapFormatError, QualityWarning, StaleFileWarning

__all__ = [
    "Map",
    "Campaign",
    "MapFormatError",
    "save_map",
    "load_map",
    "load_campaign",
    "views_of",
    "check_accepted",
    "moving_average",
]

REQUIRED = ("c", "t", "z", "name", "heavy", "light", "rho_h", "rho_l", "c0", "M_g", "M_w")
OPTIONAL = ("n", "n_heavy", "c_raw", "fps", "smoothing_frames", "quality", "view")
# A cell that is not docs/model.md's (another apparatus, a DEM run) names its own
# geometry, speed and material constants by their docs/model.md names (SI units).
CELL_KEYS = ("H", "D_p", "D_in", "D_out", "rpm", "v1", "phi_s", "g")
VIEWS = ("wall", "bulk")


# --------------------------------------------------------------------------- smoothing


def moving_average(x: Any, n: int, axis: int = 0) -> np.ndarray:
    """Centred moving average of width ``n`` along ``axis`` (time, for a map).

    At sample ``i`` of a series of length ``N`` the window is
    ``x[i - h : i + h + 1]`` with ``h = min((n - 1) // 2, i, N - 1 - i)``: it
    shrinks symmetrically near the ends, so the first and last samples are
    kept as they are. ``n`` must be a positive odd integer (1 = no smoothing).
    NaN entries (no reading) are skipped; a window with no finite value gives
    NaN. Units are those of ``x``.

    >>> moving_average([0.0, 1.0, 2.0, 6.0], 3).tolist()
    [0.0, 1.0, 3.0, 6.0]
    """
    n = _check_window(n)
    a = np.asarray(x, dtype=float)
    if a.ndim == 0:
        raise ValueError("moving_average: x must have at least one dimension")
    a = np.moveaxis(a, axis, 0)
    out = _centred_mean(a, (n - 1) // 2)
    return np.moveaxis(out, 0, axis)


def _check_window(n: Any) -> int:
    if isinstance(n, bool) or not isinstance(n, int | np.integer):
        raise ValueError(f"smoothing window n must be an odd integer >= 1, got {n!r}")
    if n < 1 or n % 2 == 0:
        raise ValueError(
            f"smoothing window n must be an odd integer >= 1 (centred, symmetric), got {n}"
        )
    return int(n)


def _centred_mean(a: np.ndarray, half: int) -> np.ndarray:
    """Mean over rows ``i-h .. i+h`` with ``h = min(half, i, N-1-i)``, NaN-aware.

    Sums the shifted rows directly (no running sums), so a window of equal
    values returns exactly that value and width 1 returns the input. Row i
    takes shift d when |d| <= h(i), i.e. for i in [|d|, N-1-|d|]: one slice
    per shift (this runs for every model map of every fit).
    """
    n_rows = a.shape[0]
    # no row has more than (N - 1) // 2 neighbours either side: a wider window
    # (a smoothing of 10**9 frames asked for) would only loop over empty shifts
    half = min(half, max(n_rows - 1, 0) // 2)
    finite = np.isfinite(a)
    if finite.all():  # model maps: the count is 2 h(i) + 1, no masks to carry
        total = np.zeros(a.shape)
        for d in range(-half, half + 1):
            lo, hi = abs(d), n_rows - abs(d)
            if lo < hi:
                total[lo:hi] += a[lo + d:hi + d]
        i = np.arange(n_rows)
        width = 2 * np.minimum(np.minimum(i, n_rows - 1 - i), half) + 1
        return total / width.reshape((-1,) + (1,) * (a.ndim - 1))
    filled = np.where(finite, a, 0.0)
    total = np.zeros(a.shape)
    count = np.zeros(a.shape)
    for d in range(-half, half + 1):
        lo, hi = abs(d), n_rows - abs(d)
        if lo >= hi:
            continue
        total[lo:hi] += filled[lo + d:hi + d]
        count[lo:hi] += finite[lo + d:hi + d]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / np.maximum(count, 1), np.nan)


# --------------------------------------------------------------------------- objects


@dataclass(frozen=True)
class Conditions:
    """What defines one experiment apart from its measurements (SI units):
    its id, materials, densities [kg/m^3], heavy fraction c0 [-], grain mass
    M_g and lid load M_w [kg]. Maps, frame experiments and the diagnosis
    catalogue all carry these, and the derived covariates below."""

    name: str
    heavy: str
    light: str
    rho_h: float
    rho_l: float
    c0: float
    M_g: float
    M_w: float
    #: the experiment's own cell constants by docs/model.md name (SI; docs/formats.md's optional
    #: geometry keys): empty for docs/model.md's cell. Every model run made for it uses them.
    cell: Mapping[str, float] = field(default_factory=dict, kw_only=True, compare=False)

    @property
    def delta_R(self) -> float:
        """Density ratio rho_h / rho_l [-]."""
        return self.rho_h / self.rho_l

    @property
    def M_tilde(self) -> float:
        """Normalised load M~ = M_w / M_g [-]."""
        return self.M_w / self.M_g

    def case(self) -> dict[str, float]:
        """Model parameters this experiment fixes: rho_h, rho_l, c0, M_w and its cell's."""
        return {"rho_h": self.rho_h, "rho_l": self.rho_l, "c0": self.c0, "M_w": self.M_w, **self.cell}


@dataclass(frozen=True, eq=False)
class Map(Conditions):
    """One experiment's measured concentration map (SI units).

    Arrays: ``c`` (n_t, n_layers) heavy share [-] (NaN = no reading), ``t``
    (n_t,) [s], ``z`` (n_layers,) layer centres [m]; optional ``n``,
    ``n_heavy`` (particle counts), ``c_raw`` (share before smoothing).
    Metadata: ``name``, ``heavy``, ``light``, ``rho_h``, ``rho_l`` [kg/m^3],
    ``c0`` [-], ``M_g``, ``M_w`` [kg], ``fps`` [1/s] or None,
    ``smoothing_frames`` (width of the moving average already in ``c``),
    ``quality`` (the frame analysis' checks, a JSON object as text, or None),
    ``view`` (``wall`` or ``bulk``: what the layers sample; None = wall),
    ``cell`` (the map's own geometry and constants by docs/model.md name, SI units,
    e.g. ``{"H": 0.066, "rpm": 40.0}``; empty = docs/model.md's cell).
    """

    c: np.ndarray
    t: np.ndarray
    z: np.ndarray
    n: np.ndarray | None = None
    n_heavy: np.ndarray | None = None
    c_raw: np.ndarray | None = None
    fps: float | None = None
    smoothing_frames: int = 1
    quality: str | None = None
    view: str | None = None
    path: Path | None = None
    extra: Mapping[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        """Validate (a Map built in code obeys docs/formats.md like one read from a file)."""
        source = _source(self.path, self.name)
        for key, value in _validate(source, self.to_arrays()).items():
            object.__setattr__(self, key, value)

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, Any], path: Path | None = None,
                    extra: Mapping[str, Any] | None = None) -> Map:
        """A map from docs/formats.md's flat keys, as a file holds them (the cell constants as
        top-level keys ``H``, ``rpm``, ...; a key set to None is absent)."""
        source = _source(path, arrays.get("name"))
        return cls(**_validate(source, arrays), path=path, extra=dict(extra or {}))

    @property
    def n_layers(self) -> int:
        """Number of horizontal layers (15 for the paper's window)."""
        return int(self.c.shape[1])

    @property
    def n_times(self) -> int:
        """Number of frames (rows of ``c``)."""
        return int(self.c.shape[0])

    @property
    def failed_checks(self) -> list[str]:
        """Names of the quality checks this map failed (empty if it passed or carries none)."""
        if self.quality is None:
            return []
        record = json.loads(self.quality)
        if record.get("ok", True):
            return []
        return [k for k, v in record.get("checks", {}).items() if not v.get("passed", True)] or ["ok"]

    @property
    def bottom(self) -> np.ndarray:
        """The bottom-layer series c[:, 0] [-] (the "bottom concentration")."""
        return self.c[:, 0]

    def measured(self) -> dict[str, Any]:
        """The dict ``granseg.sweep(measured=[...])`` takes for this map."""
        return {"c": self.c, "t": self.t, "smoothing_frames": self.smoothing_frames}

    def to_arrays(self) -> dict[str, Any]:
        """Every docs/formats.md key of this map (optional ones only when present)."""
        out: dict[str, Any] = {k: getattr(self, k) for k in REQUIRED}
        for key in OPTIONAL:
            value = getattr(self, key)
            if value is not None:
                out[key] = value
        out.update(self.cell)
        return out

    def save(self, path: str | os.PathLike, force: bool = False) -> Path:
        """Write this map to ``path`` (``.npz``), atomically; see :func:`save_map`."""
        return save_map(path, force=force, **self.to_arrays())


@dataclass(frozen=True, eq=False)
class Campaign:
    """Every map of a campaign directory, sorted by experiment name."""

    maps: tuple[Map, ...]
    directory: Path

    def __len__(self) -> int:
        return len(self.maps)

    def __iter__(self) -> Iterator[Map]:
        return iter(self.maps)

    def __getitem__(self, key: int | str) -> Map:
        if isinstance(key, str):
            for m in self.maps:
                if m.name == key:
                    return m
            raise KeyError(f"{self.directory}: no experiment named {key!r}")
        return self.maps[key]

    @property
    def names(self) -> list[str]:
        """Experiment names, in campaign order."""
        return [m.name for m in self.maps]

    @property
    def n_layers(self) -> int:
        """Layer count shared by every map."""
        return self.maps[0].n_layers


# --------------------------------------------------------------------------- validation


def _source(path: Path | None, name: Any) -> str:
    """How an error names a map: its file, else ``map 'NAME'`` (a numpy string as the text it holds)."""
    if path is not None:
        return str(path)
    if isinstance(name, np.ndarray) and name.ndim == 0:
        name = name.item()
    return f"map {str(name)!r}" if isinstance(name, str) else f"map {name!r}"


def _fail(source: str, key: str, msg: str) -> MapFormatError:
    return MapFormatError(f"{source}: field '{key}': {msg}")


def _float_array(source: str, key: str, value: Any, ndim: int) -> np.ndarray:
    arr = np.asarray(value)
    if arr.dtype.kind not in "fiu" or arr.dtype.kind == "b":
        raise _fail(source, key, f"expected a numeric array, got dtype {arr.dtype}")
    if arr.ndim != ndim:
        raise _fail(source, key, f"expected {ndim} dimension(s), got shape {arr.shape}")
    return np.array(arr, dtype=float)


def _scalar(source: str, key: str, value: Any, lo: float, hi: float, lo_open: bool) -> float:
    arr = np.asarray(value)
    if arr.shape != () or arr.dtype.kind not in "fiu":
        raise _fail(source, key, f"expected a number, got {value!r}")
    v = float(arr)
    bad_lo = v <= lo if lo_open else v < lo
    if not np.isfinite(v) or bad_lo or v > hi:
        bracket = "(" if lo_open else "["
        raise _fail(source, key, f"value {v} outside {bracket}{lo}, {hi}]")
    return v


def _text(source: str, key: str, value: Any) -> str:
    arr = np.asarray(value)
    if arr.shape != () or arr.dtype.kind not in "US":
        raise _fail(source, key, f"expected a string, got {value!r}")
    try:
        text = str(arr.item() if arr.dtype.kind == "U" else arr.item().decode())
    except UnicodeDecodeError as exc:
        raise _fail(source, key, f"expected UTF-8 text, got bytes {arr.item()[:40]!r} ({exc.reason})") from None
    if key == "name" and not text.strip():
        raise _fail(source, key, "experiment name is empty")
    return text


def _increasing(source: str, key: str, a: np.ndarray, lo: float) -> None:
    if a.size == 0:
        raise _fail(source, key, "is empty")
    if not np.all(np.isfinite(a)):
        raise _fail(source, key, "contains NaN or infinite values")
    if np.any(a < lo):
        raise _fail(source, key, f"contains values below {lo}")
    if np.any(np.diff(a) <= 0):
        raise _fail(source, key, "is not strictly increasing")


def _share(source: str, key: str, a: np.ndarray, shape: tuple[int, ...]) -> None:
    if a.shape != shape:
        raise _fail(source, key, f"shape {a.shape} does not match (n_t, n_layers) = {shape}")
    finite = a[~np.isnan(a)]
    if np.any(~np.isfinite(finite)) or np.any((finite < 0) | (finite > 1)):
        raise _fail(source, key, "values must lie in [0, 1] (NaN = no reading)")


def _counts(source: str, key: str, value: Any, shape: tuple[int, ...]) -> np.ndarray:
    arr = np.asarray(value)
    if arr.dtype.kind not in "iu":
        raise _fail(source, key, f"expected an integer array, got dtype {arr.dtype}")
    if arr.shape != shape:
        raise _fail(source, key, f"shape {arr.shape} does not match (n_t, n_layers) = {shape}")
    if np.any(arr < 0):
        raise _fail(source, key, "counts must be >= 0")
    return np.array(arr, dtype=np.int64)


def _validate(source: str, raw: Mapping[str, Any]) -> dict[str, Any]:
    """Check every docs/formats.md field of ``raw``; return clean typed values."""
    for key in REQUIRED:
        if key not in raw:
            raise _fail(source, key, "missing (required by docs/formats.md)")
    out = _validate_arrays(source, raw)
    out.update(_validate_metadata(source, raw))
    out.update(_validate_optional(source, raw, out["c"].shape))
    return out


def _validate_arrays(source: str, raw: Mapping[str, Any]) -> dict[str, Any]:
    c = _float_array(source, "c", raw["c"], 2)
    t = _float_array(source, "t", raw["t"], 1)
    z = _float_array(source, "z", raw["z"], 1)
    if c.shape[0] == 0 or c.shape[1] == 0:
        raise _fail(source, "c", f"empty map, shape {c.shape}")
    _share(source, "c", c, c.shape)
    if np.all(np.isnan(c)):
        raise _fail(source, "c", "every entry is NaN (no reading at all)")
    _increasing(source, "t", t, 0.0)
    _increasing(source, "z", z, 0.0)
    if t.shape[0] != c.shape[0]:
        raise _fail(source, "t", f"length {t.shape[0]} != rows of c ({c.shape[0]})")
    if z.shape[0] != c.shape[1]:
        raise _fail(source, "z", f"length {z.shape[0]} != columns of c ({c.shape[1]})")
    return {"c": c, "t": t, "z": z}


def _validate_metadata(source: str, raw: Mapping[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {k: _text(source, k, raw[k]) for k in ("name", "heavy", "light")}
    # rho_h, rho_l, c0 and M_w are model parameters: their ranges are the core's
    # (src/params.rs, Params::validate), so a map that passes here is one the
    # model accepts (tests/test_maps.py checks the two agree). Maps cannot ask
    # the core itself: the frame pipeline writes maps without the solver.
    out["rho_h"] = _scalar(source, "rho_h", raw["rho_h"], 0.0, np.inf, True)
    out["rho_l"] = _scalar(source, "rho_l", raw["rho_l"], 0.0, np.inf, True)
    if out["rho_h"] < out["rho_l"]:
        raise MapFormatError(f"{source}: fields 'rho_h' and 'rho_l': {out['rho_h']} < {out['rho_l']} "
                             "(the heavy grains must not be the lighter)")
    out["c0"] = _scalar(source, "c0", raw["c0"], 0.0, 1.0, True)
    if out["c0"] >= 1.0:
        raise _fail(source, "c0", f"value {out['c0']} outside (0, 1)")
    out["M_g"] = _scalar(source, "M_g", raw["M_g"], 0.0, np.inf, True)
    out["M_w"] = _scalar(source, "M_w", raw["M_w"], 0.0, np.inf, True)
    return out


def _validate_optional(source: str, raw: Mapping[str, Any], shape: tuple[int, ...]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    if raw.get("n") is not None:
        out["n"] = _counts(source, "n", raw["n"], shape)
    if raw.get("n_heavy") is not None:
        out["n_heavy"] = _counts(source, "n_heavy", raw["n_heavy"], shape)
        if "n" in out and np.any(out["n_heavy"] > out["n"]):
            raise _fail(source, "n_heavy", "more heavy particles than particles counted (n)")
    if raw.get("c_raw") is not None:
        out["c_raw"] = _float_array(source, "c_raw", raw["c_raw"], 2)
        _share(source, "c_raw", out["c_raw"], shape)
    if raw.get("fps") is not None:
        out["fps"] = _scalar(source, "fps", raw["fps"], 0.0, np.inf, True)
    if raw.get("smoothing_frames") is not None:
        out["smoothing_frames"] = _smoothing(source, raw["smoothing_frames"])
    if raw.get("quality") is not None:
        out["quality"] = _quality(source, raw["quality"])
    if raw.get("view") is not None:
        out["view"] = _text(source, "view", raw["view"])
        if out["view"] not in VIEWS:
            raise _fail(source, "view", f"{out['view']!r} is not one of {list(VIEWS)}")
    out["cell"] = _cell(source, raw)
    return out


def _cell(source: str, raw: Mapping[str, Any]) -> dict[str, float]:
    """The map's own cell constants (docs/formats.md), range-checked as the core checks them."""
    cell = {k: _scalar(source, k, raw[k], 0.0, np.inf, k != "v1") for k in CELL_KEYS if raw.get(k) is not None}
    if cell.get("phi_s", 0.0) > 1.0:
        raise _fail(source, "phi_s", f"value {cell['phi_s']} outside (0, 1]")
    if "D_in" in cell and "D_out" in cell and cell["D_out"] <= cell["D_in"]:
        raise _fail(source, "D_out", f"{cell['D_out']} <= D_in = {cell['D_in']}")
    return cell


def _quality(source: str, value: Any) -> str:
    """The quality record: a JSON object (as text) with a boolean ``ok``."""
    text = _text(source, "quality", value)
    try:
        record = json.loads(text)
    except json.JSONDecodeError as exc:
        raise _fail(source, "quality", f"not valid JSON ({exc})") from None
    if not isinstance(record, dict) or not isinstance(record.get("ok"), bool):
        raise _fail(source, "quality", 'expected a JSON object with a boolean "ok"')
    checks = record.get("checks", {})
    if not isinstance(checks, dict) or not all(isinstance(v, dict) for v in checks.values()):
        raise _fail(source, "quality", '"checks" must be a JSON object of one object per check')
    return text


def _smoothing(source: str, value: Any) -> int:
    """The moving-average width: an integer (a whole float such as 3.0 is taken as 3; 3.7 is
    refused, never truncated)."""
    arr = np.asarray(value)
    if arr.shape != () or arr.dtype.kind not in "iuf":
        raise _fail(source, "smoothing_frames", f"expected an integer, got {value!r}")
    if arr.dtype.kind == "f":
        v = float(arr)
        if not (np.isfinite(v) and v.is_integer()):
            raise _fail(source, "smoothing_frames",
                        f"expected a whole number of frames, got {v!r} (a window width is not rounded)")
    try:
        return _check_window(int(arr))
    except ValueError as exc:
        raise _fail(source, "smoothing_frames", str(exc)) from None


# --------------------------------------------------------------------------- files


def save_map(
    path: str | os.PathLike,
    *,
    c: Any,
    t: Any,
    z: Any,
    name: str,
    heavy: str,
    light: str,
    rho_h: float,
    rho_l: float,
    c0: float,
    M_g: float,
    M_w: float,
    force: bool = False,
    **optional: Any,
) -> Path:
    """Validate a map and write it to ``path`` (``.npz``) atomically.

    Units as in docs/formats.md: ``c`` [-] (n_t, n_layers), ``t`` [s], ``z`` [m],
    densities [kg/m^3], masses [kg]. ``optional`` may hold ``n``,
    ``n_heavy``, ``c_raw``, ``fps`` [1/s], ``smoothing_frames``, ``quality``,
    ``view`` and the cell keys of docs/formats.md (``H``, ``D_p``, ...); any other
    key is refused (so a typo is not silently dropped). Refuses to replace an
    existing file unless ``force``. Returns the path written.
    """
    unknown = sorted(set(optional) - set(OPTIONAL) - set(CELL_KEYS))
    if unknown:
        raise MapFormatError(f"{path}: unknown field(s) {unknown}; optional fields are "
                             f"{list(OPTIONAL) + list(CELL_KEYS)}")
    raw = dict(c=c, t=t, z=z, name=name, heavy=heavy, light=light, rho_h=rho_h,
               rho_l=rho_l, c0=c0, M_g=M_g, M_w=M_w, **optional)
    clean = _validate(str(path), raw)
    clean.update(clean.pop("cell"))
    arrays = {k: (np.str_(v) if isinstance(v, str) else v) for k, v in clean.items()}
    return save_npz(path, arrays, force=force)


#: Largest array a map file may declare (per key), checked from the .npy header before anything
#: is allocated: a real map is a few MB (frames x 15 layers of float64), so a header claiming more
#: is a damaged or forged file, refused instead of ending in a MemoryError (or an OS swap storm).
MAX_ARRAY_BYTES = 2 * 1024**3
#: Largest sum of all arrays of one map file (same reason, for many moderately large keys).
MAX_MAP_BYTES = 4 * 1024**3

#: What reading a damaged archive can raise (zipfile, zlib, numpy's .npy reader, the OS); load_map
#: turns each into a MapFormatError naming the file (and the key when one is being read).
_ARCHIVE_ERRORS = (zipfile.BadZipFile, zlib.error, EOFError, ValueError, OSError, MemoryError,
                   OverflowError, KeyError, RuntimeError, NotImplementedError, struct.error)


def load_map(path: str | os.PathLike) -> Map:
    """Read and validate one map ``.npz`` (docs/formats.md); raise MapFormatError naming the field.

    Unknown keys are kept in ``Map.extra`` and otherwise ignored. A file that is not a readable
    archive (truncated, not a zip, a damaged member, an array header declaring more than
    :data:`MAX_ARRAY_BYTES`) is refused with a MapFormatError naming the file and, where one is
    at fault, the key; FileNotFoundError names a missing file or a dangling symbolic link.
    """
    p = Path(path)
    if not p.is_file():
        if p.is_symlink():
            raise FileNotFoundError(f"{p}: map file not found: a symbolic link to {os.readlink(p)}, "
                                    "which does not exist")
        if p.is_dir():
            raise MapFormatError(f"{p}: is a directory, not a map file (.npz)")
        raise FileNotFoundError(f"{p}: map file not found")
    raw = _read_npz(p)
    extra = {k: v for k, v in raw.items() if k not in REQUIRED and k not in OPTIONAL and k not in CELL_KEYS}
    try:
        m = Map.from_arrays(raw, path=p, extra=extra)
    except MapFormatError:
        raise
    except (ValueError, TypeError, OverflowError) as exc:  # e.g. a text field that is not UTF-8
        raise MapFormatError(f"{p}: invalid map data ({type(exc).__name__}: {exc})") from None
    if m.failed_checks:
        warnings.warn(f"{p}: this map failed its frame-analysis quality checks: {', '.join(m.failed_checks)}",
                      QualityWarning, stacklevel=2)
    return m


def _read_npz(p: Path) -> dict[str, np.ndarray]:
    """Every array of the ``.npz`` at ``p`` by key; every header is checked before any array is
    read, so a forged or damaged size is refused without allocating it."""
    key = None
    try:
        with zipfile.ZipFile(p) as zf:
            members = []
            total = 0
            for info in zf.infolist():
                if info.is_dir():
                    continue
                key = info.filename[:-4] if info.filename.endswith(".npy") else info.filename
                total += _declared_bytes(p, zf, info, key)
                if total > MAX_MAP_BYTES:
                    raise MapFormatError(f"{p}: its arrays declare {total / 2**30:.3g} GiB in all (up to key "
                                         f"'{key}'), above the {MAX_MAP_BYTES / 2**30:g} GiB a map may hold; "
                                         "the file is damaged or not a map")
                members.append((key, info))
            out = {}
            for key, info in members:
                with zf.open(info) as fh:
                    out[key] = np.lib.format.read_array(fh, allow_pickle=False)
            return out
    except MapFormatError:
        raise
    except _ARCHIVE_ERRORS as exc:
        where = "" if key is None else f" (at key '{key}')"
        raise MapFormatError(f"{p}: not a readable .npz archive{where}: {type(exc).__name__}: {exc}; "
                             "the file is truncated or damaged (rewrite it from its source)") from None


def _declared_bytes(p: Path, zf: zipfile.ZipFile, info: zipfile.ZipInfo, key: str) -> int:
    """Bytes the .npy header of member ``info`` declares, refused above MAX_ARRAY_BYTES or above
    what the member holds (read from the header only; nothing of that size is allocated)."""
    with zf.open(info) as fh:
        version = np.lib.format.read_magic(fh)
        if version == (1, 0):
            shape, _, dtype = np.lib.format.read_array_header_1_0(fh)
        elif version == (2, 0):
            shape, _, dtype = np.lib.format.read_array_header_2_0(fh)
        else:  # 3.0 (UTF-8 field names) has no public reader; numpy's own is used when present
            read = getattr(np.lib.format, "_read_array_header", None)
            if read is None:
                raise MapFormatError(f"{p}: field '{key}': .npy format version {version} is not supported")
            shape, _, dtype = read(fh, version)
        header = fh.tell()
    nbytes = math.prod(int(n) for n in shape) * dtype.itemsize  # Python ints: no overflow
    if nbytes > MAX_ARRAY_BYTES:
        raise MapFormatError(f"{p}: field '{key}': the array header declares shape {tuple(shape)} of {dtype} "
                             f"({nbytes / 2**30:.3g} GiB), above the {MAX_ARRAY_BYTES / 2**30:g} GiB "
                             "limit for one array; the file is damaged or not a map")
    if not dtype.hasobject and header + nbytes > info.file_size:
        raise MapFormatError(f"{p}: field '{key}': the array header declares shape {tuple(shape)} of {dtype} "
                             f"({nbytes} bytes) but the archive holds {info.file_size - header}; "
                             "the file is truncated or damaged")
    return nbytes


def views_of(m: Map) -> dict[str, Map]:
    """Every view of the run map ``m`` shows, by view name (``m`` itself included), or {} if none
    lies beside it. ``granseg dem`` writes a run's views as ``OUT/<view>/NAME.npz``, so a map in a
    folder named after its view finds its siblings in the neighbouring view folders; a sibling that
    is not a readable map is passed over (the map asked about is what the caller loaded)."""
    if m.view is None or m.path is None or m.path.parent.name != m.view:
        return {}
    found = {m.view: m}
    for view in VIEWS:
        other = m.path.parent.parent / view / m.path.name
        if view == m.view or not other.is_file():
            continue
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", QualityWarning)  # the window check is what is compared
                found[view] = load_map(other)
        except MapFormatError:
            continue
    return found if len(found) > 1 else {}


def check_accepted(maps: Iterator[Map] | list[Map], accept_flagged: bool) -> None:
    """Refuse maps that failed their quality checks unless ``accept_flagged``.

    Raises FlaggedMapError naming every flagged map and its failed checks.
    """
    flagged = [m for m in maps if m.failed_checks]
    if flagged and not accept_flagged:
        names = "; ".join(f"{m.path or m.name}: {', '.join(m.failed_checks)}" for m in flagged)
        raise FlaggedMapError(f"{len(flagged)} map(s) failed their frame-analysis quality checks ({names}); "
                              "look at the analysis preview, fix the cause, or accept them explicitly "
                              "(accept_flagged=True, CLI: --accept-flagged)")


def load_campaign(directory: str | os.PathLike) -> Campaign:
    """Load every ``*.npz`` map in ``directory``, sorted by experiment name.

    Hidden entries (names starting with ".") are not maps and are skipped; one that looks like a
    temporary file of an interrupted write (``.NAME.npz.<random>.partial``, or an older
    ``.NAME.npz.<random>.npz``) is named in a :class:`~granseg.errors.StaleFileWarning`.

    Raises FileNotFoundError for a missing directory or a ``*.npz`` that is a dangling symbolic
    link, and MapFormatError for a directory with no maps, a ``*.npz`` entry that is not a file,
    a bad map (naming its file and field), maps with different layer counts, or two maps with
    the same experiment name: no experiment is ever dropped silently.
    """
    d = Path(directory)
    if not d.is_dir():
        raise FileNotFoundError(f"{d}: campaign directory not found")
    files = []
    for f in sorted(d.iterdir()):
        if f.name.startswith("."):
            if f.name.endswith((".npz", PARTIAL_SUFFIX)):
                warnings.warn(f"{f}: skipped, a hidden temporary file of an interrupted (or still running) "
                              "write, not a map; delete it once no granseg command is writing here",
                              StaleFileWarning, stacklevel=2)
            continue
        if not f.name.endswith(".npz"):
            continue
        if not f.is_file():
            if f.is_symlink():
                raise FileNotFoundError(f"{f}: map file not found: a symbolic link to {os.readlink(f)}, which "
                                        "does not exist (restore its target or remove the link)")
            raise MapFormatError(f"{f}: is not a file; a map must be an .npz file (rename or move it)")
        files.append(f)
    if not files:
        raise MapFormatError(f"{d}: campaign has no map files (*.npz)")
    maps = [load_map(f) for f in files]
    _check_unique(d, maps)
    _check_layers(d, maps)
    maps.sort(key=lambda m: m.name)
    return Campaign(maps=tuple(maps), directory=d)


def _check_unique(d: Path, maps: list[Map]) -> None:
    seen: dict[str, Path | None] = {}
    for m in maps:
        if m.name in seen:
            raise MapFormatError(
                f"{d}: duplicate experiment name {m.name!r} in {seen[m.name]} and {m.path}"
            )
        seen[m.name] = m.path


def _check_layers(d: Path, maps: list[Map]) -> None:
    """Maps in docs/model.md's cell share one window, so one layer count (a mismatch is a mistake);
    a map that carries its own bed height (DEM runs, other apparatus) has as many as it has."""
    plain = [m for m in maps if "H" not in m.cell]
    for m in plain[1:]:
        if m.n_layers != plain[0].n_layers:
            raise MapFormatError(
                f"{d}: mismatched layer counts: {plain[0].path} has {plain[0].n_layers}, "
                f"{m.path} has {m.n_layers} (only maps that carry their own bed height H may differ)"
            )
