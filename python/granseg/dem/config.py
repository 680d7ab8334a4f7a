"""What a DEM run's dumps do not say: which particle type is which material, the units, the
axes and the cell (docs/formats.md, "DEM particle dumps").

The config is a small JSON beside the dumps (``dem.json`` by default)::

    {"types": {"1": "PP", "2": {"name": "heavy", "density": 3.0}},
     "units": {"length_m": 0.006, "time_s": 0.0247, "density_kg_m3": 946},
     "flow_axis": "x", "up_axis": "z", "side_walls": {"y": [0.0, 20.0]},
     "bottom_z": 0.5, "timestep": 2.0e-4, "lid_force": 1500.0, "plate_speed": 2.0,
     "diameter": 1.0}

Every length, time, density, force and speed is in the dump's own units (LAMMPS ``lj`` or
SI, ``"units": "si"``) and converted here, once: the rest of :mod:`granseg.dem` works in SI.
Optional keys: ``gravity`` (dump units; default 9.81 m/s^2), ``start_step`` (the step at
which the plate started; earlier snapshots are the settling and are left out, default 0),
``wall_depth`` (how close to a side wall, in diameters, a grain's centre must be for the
camera to see it; default 1.0, between the touching row at 0.5 and the next row at about
1.3), ``name`` (the run's name; default the run directory's).
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from granseg.errors import DemFormatError, short_repr

__all__ = ["DemConfig", "Material", "load_config"]

AXES = ("x", "y", "z")
REQUIRED = ("types", "units", "flow_axis", "up_axis", "bottom_z", "timestep", "lid_force", "plate_speed",
            "diameter")
UNIT_KEYS = ("length_m", "time_s", "density_kg_m3")
G_SI = 9.81


@dataclass(frozen=True)
class Material:
    """A particle type's material: its name and solid density [kg/m^3]."""

    name: str
    density: float


@dataclass(frozen=True)
class DemConfig:
    """A validated config, converted to SI: lengths [m], times [s], forces [N], speeds [m/s].

    ``bottom_z`` and ``side_walls`` stay in dump units too (``*_dump``) because they are
    compared with the dump's coordinates; :meth:`length` converts."""

    types: Mapping[int, Material]
    length_m: float
    time_s: float
    density_kg_m3: float
    flow_axis: str
    up_axis: str
    wall_axis: str
    side_walls_dump: tuple[float, float] | None
    bottom_z_dump: float
    dt: float
    lid_force: float
    plate_speed: float
    D_p: float
    g: float
    gravity_given: bool
    start_step: int
    wall_depth: float
    name: str | None
    source: str

    def length(self, value: float) -> float:
        """A dump-unit length in metres."""
        return float(value) * self.length_m

    @property
    def speed_unit(self) -> float:
        """One dump-unit speed in m/s."""
        return self.length_m / self.time_s

    @property
    def M_w(self) -> float:
        """The lid load as a mass [kg]: lid force / g."""
        return self.lid_force / self.g


def load_config(config: str | os.PathLike | Mapping[str, Any]) -> DemConfig:
    """Read and validate a DEM config (a JSON path or an already loaded dict); raise
    :class:`granseg.DemFormatError` naming the file and the key."""
    if isinstance(config, Mapping):
        return _parse(dict(config), "DEM config")
    path = Path(config)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: DEM config not found (docs/formats.md: a JSON beside the dumps)")
    try:
        raw = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DemFormatError(f"{path}: not a readable JSON file ({exc})") from None
    if not isinstance(raw, dict):
        raise DemFormatError(f"{path}: expected a JSON object")
    return _parse(raw, str(path))


def _fail(source: str, key: str, msg: str) -> DemFormatError:
    return DemFormatError(f"{source}: '{key}': {msg}")


def _number(source: str, raw: Mapping[str, Any], key: str, positive: bool = True, where: str = "") -> float:
    value = raw.get(key)
    label = where + key
    if isinstance(value, bool) or not isinstance(value, (int, float)) or value != value:
        raise _fail(source, label, f"expected a number, got {value!r}")
    if positive and not value > 0:
        raise _fail(source, label, f"must be > 0, got {value!r}")
    try:
        number = float(value)
    except OverflowError:  # an int beyond any float, e.g. 10**400 written in the JSON
        raise _fail(source, label, f"{short_repr(value)} is beyond any float") from None
    if number in (float("inf"), float("-inf")):
        raise _fail(source, label, f"expected a finite number, got {value!r}")
    return number


def _parse(raw: dict[str, Any], source: str) -> DemConfig:
    for key in REQUIRED:
        if key not in raw:
            hint = ' (e.g. {"length_m": 0.006, "time_s": 0.0247, "density_kg_m3": 946}, or "si")' \
                if key == "units" else ""
            raise _fail(source, key, f"missing (required by docs/formats.md){hint}")
    units = _units(source, raw["units"])
    flow, up = (_axis(source, raw, k) for k in ("flow_axis", "up_axis"))
    if flow == up:
        raise _fail(source, "up_axis", f"the same axis as flow_axis ({flow!r})")
    wall_axis, walls = _side_walls(source, raw.get("side_walls"), flow, up)
    L, T, R = units
    force_unit = R * L**4 / T**2
    gravity_given = raw.get("gravity") is not None
    g = _number(source, raw, "gravity") * L / T**2 if gravity_given else G_SI
    start = raw.get("start_step", 0)
    if isinstance(start, bool) or not isinstance(start, int) or start < 0:
        raise _fail(source, "start_step", f"expected a whole number >= 0, got {start!r}")
    depth = _number(source, raw, "wall_depth") if raw.get("wall_depth") is not None else 1.0
    name = raw.get("name")
    if name is not None and (not isinstance(name, str) or not name.strip()):
        raise _fail(source, "name", f"expected a non-empty string, got {name!r}")
    return DemConfig(
        types=_types(source, raw["types"], R), length_m=L, time_s=T, density_kg_m3=R,
        flow_axis=flow, up_axis=up, wall_axis=wall_axis, side_walls_dump=walls,
        bottom_z_dump=_number(source, raw, "bottom_z", positive=False),
        dt=_number(source, raw, "timestep") * T, lid_force=_number(source, raw, "lid_force") * force_unit,
        plate_speed=_number(source, raw, "plate_speed") * L / T, D_p=_number(source, raw, "diameter") * L,
        g=g, gravity_given=gravity_given, start_step=start, wall_depth=depth, name=name, source=source)


def _units(source: str, value: Any) -> tuple[float, float, float]:
    if isinstance(value, str) and value.lower() == "si":
        return 1.0, 1.0, 1.0
    if not isinstance(value, Mapping):
        raise _fail(source, "units", f'expected "si" or an object with {list(UNIT_KEYS)}, got {value!r}')
    missing = [k for k in UNIT_KEYS if k not in value]
    if missing:
        raise _fail(source, "units", f"missing {missing} (one dump unit of length in m, of time in s, "
                                     "of density in kg/m^3)")
    L, T, R = (_number(source, value, k, where="units.") for k in UNIT_KEYS)
    return L, T, R


def _axis(source: str, raw: Mapping[str, Any], key: str) -> str:
    value = raw.get(key)
    if value not in AXES:
        raise _fail(source, key, f"expected one of {list(AXES)}, got {value!r}")
    return str(value)


def _side_walls(source: str, value: Any, flow: str, up: str) -> tuple[str, tuple[float, float] | None]:
    """The wall-normal axis and the two walls' positions (dump units), if the cell has walls."""
    third = next(a for a in AXES if a not in (flow, up))
    if value is None:
        return third, None
    if not isinstance(value, Mapping) or list(value) != [third]:
        raise _fail(source, "side_walls", f'expected {{"{third}": [low, high]}} (the axis across the flow), '
                                          f"got {value!r}")
    pos = value[third]
    if (not isinstance(pos, (list, tuple)) or len(pos) != 2
            or not all(isinstance(p, (int, float)) and not isinstance(p, bool) for p in pos) or pos[1] <= pos[0]):
        raise _fail(source, "side_walls", f"expected [low, high] with low < high, got {pos!r}")
    try:
        return third, (float(pos[0]), float(pos[1]))
    except OverflowError:  # an int beyond any float
        raise _fail(source, "side_walls", "a position is beyond any float") from None


def _types(source: str, value: Any, density_unit: float) -> dict[int, Material]:
    from granseg.model import MATERIALS

    if not isinstance(value, Mapping) or not value:
        raise _fail(source, "types", 'expected an object like {"1": "PP", "2": {"name": "heavy", "density": 3.0}}')
    known = {k.lower(): (k, v) for k, v in MATERIALS.items()}
    out: dict[int, Material] = {}
    for key, spec in value.items():
        where = f"types.{key}"
        try:
            t = int(key)
        except ValueError:
            raise _fail(source, where, "a particle type must be a whole number") from None
        if isinstance(spec, str):
            if spec.lower() not in known:
                raise _fail(source, where, f"unknown material {spec!r}; name one of {list(MATERIALS)} or give "
                                           '{"name": ..., "density": ...} in dump units')
            name, rho = known[spec.lower()]
            out[t] = Material(name, float(rho))
        elif isinstance(spec, Mapping) and isinstance(spec.get("name"), str) and spec["name"].strip():
            out[t] = Material(spec["name"], _number(source, spec, "density", where=f"{where}.") * density_unit)
        else:
            raise _fail(source, where, f'expected a material name or {{"name": ..., "density": ...}}, got {spec!r}')
    return out
