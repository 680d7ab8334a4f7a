"""A DEM run as data: its dumps and config turned into the maps and the velocity profile
that footage gives, so DEM runs and experiments go through the same calibration and
diagnosis.

Layers are one grain diameter high (the bed height measured from the dumps, rounded to whole
diameters, and split evenly), counted from the plate's surface ``bottom_z``. A grain belongs
to the layer that holds its centre. Two views:

- ``bulk``: every grain at that height (what a camera cannot see);
- ``wall``: the grains whose centre lies within ``wall_depth`` diameters of a side wall,
  those a camera at a transparent wall films.

The heavy share ``c`` is by solid volume (with equal sizes, by count); ``n`` and ``n_heavy``
count grains. The map carries the run's own cell (docs/formats.md): ``H``, ``D_p``, ``phi_s``, ``g``
when the config gives gravity, and ``D_in``, ``D_out``, ``rpm`` of the annulus equivalent to
the periodic box: the model uses the cell only through the lid pressure (M_w g / A) and the
plate speed at the camera wall (omega D_out / 2), so the box's area and plate speed are kept
exactly with D_in = D_out / 2.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from granseg.dem.config import DemConfig, Material, load_config
from granseg.dem.dump import Snapshot, dump_files, read_dumps
from granseg.errors import DemFormatError

__all__ = ["DemRun", "load_run", "write_products", "VIEWS"]

VIEWS = ("bulk", "wall")
BLOCKS = 10  # batch means for a layer speed's standard error (snapshots are correlated in time)
MIN_BLOCKS = 3
CONFIG_NAME = "dem.json"


@dataclass(frozen=True, eq=False)
class DemRun:
    """A run's snapshots (in time order, the plate running) and its config, in SI.

    Build with :func:`load_run`. ``notes`` says what was left out (types not in the
    config, snapshots before ``start_step``)."""

    config: DemConfig
    snapshots: Sequence[Snapshot]
    name: str
    sources: Sequence[str]
    notes: Sequence[str] = field(default_factory=tuple)
    #: per-view layer tables, computed once (both maps and the profile use the bulk's)
    _table_cache: dict[str, dict[str, np.ndarray]] = field(default_factory=dict, repr=False)

    # ---------------------------------------------------------------- the bed

    @property
    def t(self) -> np.ndarray:
        """Seconds since the plate started, one per snapshot."""
        steps = np.array([s.step for s in self.snapshots], dtype=float)
        return (steps - self.config.start_step) * self.config.dt

    def _grains(self, snap: Snapshot) -> np.ndarray:
        """Mask of the particles that are grains (their type is in the config)."""
        return np.isin(snap.columns["type"], list(self.config.types))

    def _radius(self, snap: Snapshot, mask: np.ndarray) -> np.ndarray:
        """Grain radii in dump units (the config's diameter when the dump has no size column)."""
        if "radius" in snap.columns:
            return snap.columns["radius"][mask]
        return np.full(int(mask.sum()), self.config.D_p / self.config.length_m / 2)

    def _height(self, snap: Snapshot, mask: np.ndarray) -> np.ndarray:
        """Grain centres above the plate's surface [m]."""
        return self.config.length(1.0) * (snap.columns[self.config.up_axis][mask] - self.config.bottom_z_dump)

    @cached_property
    def H(self) -> float:
        """Bed height [m]: the top of the highest grain above the plate, median over snapshots."""
        tops = []
        for snap in self.snapshots:
            g = self._grains(snap)
            tops.append(np.max(self._height(snap, g) + self.config.length(1.0) * self._radius(snap, g)))
        return float(np.median(tops))

    @cached_property
    def n_layers(self) -> int:
        """Whole grain diameters in the bed height (at least one)."""
        return max(1, int(round(self.H / self.config.D_p)))

    @property
    def area(self) -> float:
        """The cell's horizontal area [m^2]: periodic length along the flow times the gap
        between the side walls (or the box's width without walls)."""
        c, s = self.config, self.snapshots[0]
        k_flow, k_wall = "xyz".index(c.flow_axis), "xyz".index(c.wall_axis)
        width = (c.side_walls_dump[1] - c.side_walls_dump[0]) if c.side_walls_dump else s.hi[k_wall] - s.lo[k_wall]
        return c.length(s.hi[k_flow] - s.lo[k_flow]) * c.length(width)

    def materials(self) -> tuple[Material, Material]:
        """(heavy, light): the denser material is heavy; of two equally dense ones, the one on
        top at the start (every run starts heavy above light, docs/model.md)."""
        by_name: dict[str, Material] = {m.name: m for m in self.config.types.values()}
        if len(by_name) != 2:
            raise DemFormatError(f"{self.config.source}: 'types': a concentration map needs exactly two "
                                 f"materials, the config names {len(by_name)} ({', '.join(by_name)})")
        a, b = by_name.values()
        if a.density == b.density:
            a, b = sorted((a, b), key=self._mean_start_height, reverse=True)
        return (a, b) if a.density >= b.density else (b, a)

    @property
    def _binary(self) -> bool:
        """Whether the config names two materials (a mixture; else a pure bed)."""
        return len({m.name for m in self.config.types.values()}) == 2

    def _mean_start_height(self, material: Material) -> float:
        snap = self.snapshots[0]
        mask = np.isin(snap.columns["type"], self._types_of(material))
        return float(np.mean(snap.columns[self.config.up_axis][mask])) if mask.any() else -np.inf

    def _types_of(self, material: Material) -> list[int]:
        return [t for t, m in self.config.types.items() if m.name == material.name]

    # ---------------------------------------------------------------- per-snapshot sums

    def _view_mask(self, snap: Snapshot, grains: np.ndarray, view: str) -> np.ndarray:
        if view == "bulk":
            return grains
        c = self.config
        if c.side_walls_dump is None:
            raise DemFormatError(f"{c.source}: 'side_walls': the wall view needs the side walls' positions")
        w = snap.columns[c.wall_axis]
        reach = c.wall_depth * c.D_p / c.length_m
        lo, hi = c.side_walls_dump
        return grains & ((w - lo < reach) | (hi - w < reach))

    def _layer_of(self, snap: Snapshot, mask: np.ndarray) -> np.ndarray:
        h = self.H / self.n_layers
        return np.clip(np.floor(self._height(snap, mask) / h).astype(int), 0, self.n_layers - 1)

    def _tables(self, view: str) -> dict[str, np.ndarray]:
        """Per snapshot and layer: grains, heavy grains, solid volume, heavy volume [dump units],
        summed flow speed [m/s] (the mean is the sum over the count). Computed once per view."""
        if view not in VIEWS:
            raise ValueError(f"view must be one of {list(VIEWS)}, got {view!r}")
        if view not in self._table_cache:
            self._table_cache[view] = self._count(view)
        return self._table_cache[view]

    def _count(self, view: str) -> dict[str, np.ndarray]:
        heavy_types = self._types_of(self.materials()[0]) if self._binary else []
        L = self.n_layers
        out = {k: np.zeros((len(self.snapshots), L)) for k in ("n", "n_heavy", "vol", "vol_heavy", "v_sum")}
        for i, snap in enumerate(self.snapshots):
            m = self._view_mask(snap, self._grains(snap), view)
            layer = self._layer_of(snap, m)
            vol = self._radius(snap, m) ** 3
            heavy = np.isin(snap.columns["type"][m], heavy_types)
            out["n"][i] = np.bincount(layer, minlength=L)
            out["n_heavy"][i] = np.bincount(layer, heavy, minlength=L)
            out["vol"][i] = np.bincount(layer, vol, minlength=L)
            out["vol_heavy"][i] = np.bincount(layer, vol * heavy, minlength=L)
            vkey = f"v{self.config.flow_axis}"
            if vkey in snap.columns:
                out["v_sum"][i] = np.bincount(layer, snap.columns[vkey][m], minlength=L) * self.config.speed_unit
            else:
                out["v_sum"][i] = np.nan
        return out

    # ---------------------------------------------------------------- the map

    def cell(self) -> dict[str, float]:
        """The run's cell by docs/model.md name (SI), as a map carries it (see the module doc)."""
        c = self.config
        D_out = math.sqrt(16 * self.area / (3 * math.pi))
        out = {"H": self.H, "D_p": c.D_p, "D_in": D_out / 2, "D_out": D_out,
               "rpm": c.plate_speed / (D_out / 2) * 60 / (2 * math.pi), "phi_s": self._phi_s()}
        if c.gravity_given:
            out["g"] = c.g
        return out

    def _phi_s(self) -> float:
        """Solids fraction of the bed: grain volume over area x height, median over snapshots."""
        vols = [4 / 3 * math.pi * float(np.sum(self._radius(s, self._grains(s)) ** 3)) for s in self.snapshots]
        return min(1.0, float(np.median(vols)) * self.config.length_m ** 3 / (self.area * self.H))

    def grain_mass(self) -> float:
        """M_g [kg]: the grains' mass (from a ``mass`` column, else density x volume), first snapshot."""
        snap = self.snapshots[0]
        g = self._grains(snap)
        if "mass" in snap.columns:
            return float(np.sum(snap.columns["mass"][g])) * self.config.density_kg_m3 * self.config.length_m ** 3
        rho = np.array([self.config.types[int(t)].density for t in snap.columns["type"][g]])
        return float(np.sum(rho * 4 / 3 * math.pi * (self._radius(snap, g) * self.config.length_m) ** 3))

    def to_map(self, view: str = "bulk", name: str | None = None) -> Any:
        """The run's concentration map (:class:`granseg.Map`) seen in ``view`` (``bulk`` or ``wall``)."""
        from granseg.maps import Map

        heavy, light = self.materials()
        for m in (heavy, light):
            if not any(np.isin(s.columns["type"], self._types_of(m)).any() for s in self.snapshots):
                raise DemFormatError(f"{self.sources[0]}: no grain of the {'heavy' if m is heavy else 'light'} "
                                     f"material {m.name!r} (type {', '.join(map(str, self._types_of(m)))}) "
                                     "in any snapshot; a map needs both")
        tab = self._tables(view)
        with np.errstate(invalid="ignore", divide="ignore"):
            c = np.where(tab["vol"] > 0, tab["vol_heavy"] / tab["vol"], np.nan)
        h = self.H / self.n_layers
        t = self.t
        steps = np.diff(t)
        fps = {"fps": 1 / steps[0]} if steps.size and np.allclose(steps, steps[0], rtol=1e-6) else {}
        bulk = tab if view == "bulk" else self._tables("bulk")
        c0 = float(bulk["vol_heavy"][0].sum() / bulk["vol"][0].sum())
        return Map(c=c, t=t, z=(np.arange(self.n_layers) + 0.5) * h, name=name or self.name,
                   heavy=heavy.name, light=light.name, rho_h=heavy.density, rho_l=light.density, c0=c0,
                   M_g=self.grain_mass(), M_w=self.config.M_w, n=tab["n"].astype(np.int64),
                   n_heavy=tab["n_heavy"].astype(np.int64), smoothing_frames=1, view=view,
                   cell=self.cell(), quality=_quality(tab, bulk, view), **fps)

    # ---------------------------------------------------------------- the velocity profile

    def velocity_profile(self, view: str = "bulk", t_from: float | None = None) -> Any:
        """Mean flow speed per layer over the snapshots from ``t_from`` [s] on (default: the
        later half of the run, once the band has formed), with batch-means standard errors,
        and its shear-band fit (:class:`granseg.velocity.VelocityProfile`)."""
        from granseg.velocity.profile import VelocityProfile

        t = self.t
        t_from = t[-1] / 2 if t_from is None else float(t_from)
        use = t >= t_from
        if use.sum() < 1:
            raise ValueError(f"t_from = {t_from} s leaves no snapshot (the run ends at {t[-1]:.4g} s)")
        tab = self._tables(view)
        if np.all(np.isnan(tab["v_sum"])):
            raise DemFormatError(f"{self.sources[0]}: the dump has no v{self.config.flow_axis} column; "
                                 "a velocity profile needs the velocities (dump custom ... vx vy vz)")
        v, err = _layer_means(tab["v_sum"][use], tab["n"][use])
        h = self.H / self.n_layers
        notes = [*self.notes, f"mean over {int(use.sum())} snapshots from t = {t[use][0]:.4g} s to "
                              f"{t[use][-1]:.4g} s ({view} view)"]
        heavy_light = {}
        if self._binary:
            heavy, light = self.materials()
            heavy_light = {"heavy": heavy.name, "light": light.name}
        conditions = {"name": self.name, **heavy_light, "M_g": self.grain_mass(), "M_w": self.config.M_w,
                      "view": view, "plate_speed": self.config.plate_speed}
        return VelocityProfile.fitted((np.arange(self.n_layers) + 0.5) * h, v, err, self.H,
                                      n=tab["n"][use].sum(0).astype(int), conditions=conditions,
                                      sources=list(self.sources), notes=notes)

    # ---------------------------------------------------------------- files

    def products(self, views: Sequence[str] = ("bulk",), velocity: bool = True, t_from: float | None = None
                 ) -> dict[str, Any]:
        """What :meth:`save` writes, by path in the output folder: ``VIEW/NAME.npz`` per view
        (each view's folder is a campaign) and ``velocity/NAME.json``."""
        out: dict[str, Any] = {f"{v}/{self.name}.npz": self.to_map(v) for v in views}
        if velocity:
            out[f"velocity/{self.name}.json"] = self.velocity_profile(t_from=t_from)
        return out

    def save(self, out: str | os.PathLike, views: Sequence[str] = ("bulk",), velocity: bool = True,
             force: bool = False, t_from: float | None = None) -> list[Path]:
        """Write :meth:`products` into folder ``out``, each file atomically, after all are
        computed; an existing file is kept unless ``force``."""
        return write_products(out, self.products(views, velocity, t_from), force)


def check_products(out: str | os.PathLike, names: Sequence[str], force: bool = False) -> None:
    """Check, before the runs are reduced, that ``out`` can take products ``names`` (relative
    paths such as ``bulk/NAME.npz``): no clash unless ``force``, a folder that can be made."""
    from granseg._io import check_creatable, check_output_dir

    out = Path(out)
    check_creatable(out)
    for folder in sorted({Path(n).parent for n in names}):
        if (out / folder).is_dir():
            check_output_dir(out / folder, [Path(n).name for n in names if Path(n).parent == folder], force)
        else:
            check_creatable(out / folder)


def write_products(out: str | os.PathLike, products: Mapping[str, Any], force: bool = False) -> list[Path]:
    """Write maps and profiles (anything with ``.save(path, force)``) by their relative paths
    into ``out``: every clash is refused before the first file is written."""
    from granseg._io import prepare_output_dir

    folders = sorted({str(Path(name).parent) for name in products} - {"."})
    d = prepare_output_dir(out, list(products), force=force, folders=folders)
    return [obj.save(d / name, force=force) for name, obj in products.items()]


def _quality(tab: Mapping[str, np.ndarray], bulk: Mapping[str, np.ndarray], view: str) -> str:
    """The map's quality record: whether the view keeps the bed's depth-mean heavy share (by
    count, the bulk's at the start: equal to c0 by volume when the sizes are equal)."""
    from granseg.measure.quality import Quality, depth_mean_check

    share0 = float(bulk["n_heavy"][0].sum() / bulk["n"][0].sum())
    check = depth_mean_check(tab["n"], tab["n_heavy"], share0)
    return Quality((check,), {"source": "DEM", "view": view}).to_json()


def _layer_means(v_sum: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per layer: mean speed over snapshots, and its standard error from BLOCKS batch means
    (consecutive snapshots of a sheared bed are correlated, so the snapshot-to-snapshot spread
    would understate it); with fewer than MIN_BLOCKS snapshots, the grains' spread."""
    with np.errstate(invalid="ignore", divide="ignore"):
        per_snap = v_sum / n
    S, L = per_snap.shape
    mean = np.nanmean(np.where(n > 0, per_snap, np.nan), axis=0) if S else np.full(L, np.nan)
    err = np.full(L, np.nan)
    if S >= MIN_BLOCKS:
        blocks = np.array_split(np.arange(S), min(BLOCKS, S))
        for j in range(L):
            bm = np.array([np.nanmean(per_snap[b, j]) if np.any(n[b, j] > 0) else np.nan for b in blocks])
            bm = bm[np.isfinite(bm)]
            if bm.size >= MIN_BLOCKS:
                err[j] = np.std(bm, ddof=1) / np.sqrt(bm.size)
    return mean, err


def load_run(dumps: str | os.PathLike | Sequence[str | os.PathLike],
             config: str | os.PathLike | Mapping[str, Any] | None = None, name: str | None = None) -> DemRun:
    """Read a DEM run: its dump files (or a run directory of them) and its config (a path, a
    dict, or by default ``dem.json`` beside the dumps).

    Raises :class:`granseg.DemFormatError` naming the file, step or key at fault: a snapshot
    cut short, a column missing, a config without units, a configured type absent from every
    snapshot."""
    files = dump_files(dumps)
    if config is None:
        config = files[0].parent / CONFIG_NAME
    cfg = load_config(config)
    snaps = read_dumps(files)
    notes = []
    early = [s for s in snaps if s.step < cfg.start_step]
    if early:
        notes.append(f"{len(early)} snapshot(s) before start_step {cfg.start_step} left out (settling)")
        snaps = [s for s in snaps if s.step >= cfg.start_step]
    if not snaps:
        raise DemFormatError(f"{files[0]}: no snapshot at or after start_step {cfg.start_step}")
    present = set(np.unique(np.concatenate([s.columns["type"] for s in snaps])).tolist())
    absent = sorted(set(cfg.types) - present)
    if absent:
        raise DemFormatError(f"{cfg.source}: 'types': type(s) {absent} named in the config but absent from "
                             f"every snapshot of {files[0]}{' ...' if len(files) > 1 else ''} "
                             f"(types present: {sorted(present)})")
    ignored = sorted(present - set(cfg.types))
    if ignored:
        notes.append(f"type(s) {ignored} not in the config: not grains (walls, plate, lid), left out")
    first = Path(dumps if isinstance(dumps, (str, os.PathLike)) else list(dumps)[0])
    run_name = name or cfg.name or (first.name if first.is_dir() else first.name.split(".")[0])
    return DemRun(cfg, snaps, run_name, [str(f) for f in files], tuple(notes))
