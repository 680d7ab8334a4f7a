"""LAMMPS / LIGGGHTS ``dump custom`` text files: snapshots of particle columns.

A file holds one or many snapshots, each::

    ITEM: TIMESTEP
    2000
    ITEM: NUMBER OF ATOMS
    2612
    ITEM: BOX BOUNDS pp pp ff            (or "xy xz yz pp pp ff": a tilted box, 3 numbers a line)
    0 20
    0 10
    -0.5 30
    ITEM: ATOMS id type x y z vx vy vz radius
    1 1 0.53 0.61 1.52 0.8 0.0 0.01 0.5
    ...

in any column order, plain or gzip-compressed (``.gz``). Positions may be wrapped (``x``),
unwrapped (``xu``) or scaled (``xs``, ``xsu``: orthogonal boxes only); the grain size is a
``radius`` or ``diameter`` column or, without one, the config's diameter; a ``mass`` column
is used when present. A snapshot cut short (a run stopped while writing) is an error naming
the file and the step, never a silently smaller bed.

The reader is plain numpy: a snapshot's block of numbers is split once and reshaped, which
reads a 2,600-grain snapshot in a few milliseconds; pandas' or LAMMPS' own Python readers
were not needed for that.
"""

from __future__ import annotations

import gzip
import os
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from granseg.errors import DemFormatError

__all__ = ["Snapshot", "read_dumps", "dump_files"]

AXES = ("x", "y", "z")
# the columns kept, by what they mean; the first name a dump has wins
POSITION = {a: (a, f"{a}u", f"{a}s", f"{a}su") for a in AXES}
VELOCITY = {a: (f"v{a}",) for a in AXES}


@dataclass(frozen=True, eq=False)
class Snapshot:
    """One dump snapshot: its step, the box's extent per axis (``lo``, ``hi``, orthogonal
    part of a tilted box), whether each axis is periodic, and the particles' columns
    (``id``, ``type`` as integers; ``x y z``, ``vx vy vz``, ``radius``, ``mass`` as floats,
    those the dump has), in dump units."""

    step: int
    lo: np.ndarray
    hi: np.ndarray
    periodic: tuple[bool, bool, bool]
    columns: dict[str, np.ndarray]
    source: str

    @property
    def n(self) -> int:
        return int(self.columns["id"].size)


def dump_files(paths: str | os.PathLike | Sequence[str | os.PathLike]) -> list[Path]:
    """The dump files named: files as given, a directory's files that begin as a dump does."""
    items = [paths] if isinstance(paths, (str, os.PathLike)) else list(paths)
    if not items:
        raise ValueError("no dump files or run directory given")
    out: list[Path] = []
    for item in map(Path, items):
        if item.is_dir():
            found = sorted(p for p in item.iterdir() if p.is_file() and _looks_like_dump(p))
            if not found:
                raise FileNotFoundError(f"{item}: no LAMMPS dump file in this directory "
                                        "(a dump begins with 'ITEM: TIMESTEP')")
            out.extend(found)
        elif item.is_file():
            out.append(item)
        else:
            raise FileNotFoundError(f"{item}: no such dump file or run directory")
    return out


def _open(path: Path):
    return gzip.open(path, "rt") if path.suffix == ".gz" else open(path)


def _looks_like_dump(path: Path) -> bool:
    try:
        with _open(path) as f:
            return f.readline().strip() == "ITEM: TIMESTEP"
    except (OSError, UnicodeDecodeError, EOFError):
        return False


def read_dumps(paths: str | os.PathLike | Sequence[str | os.PathLike]) -> list[Snapshot]:
    """Every snapshot of the dumps named (files or run directories), sorted by step.

    A step found twice (restarted runs overlap) is kept once if the two agree and is an
    error if they do not."""
    snaps: dict[int, Snapshot] = {}
    for path in dump_files(paths):
        for snap in _read_file(path):
            old = snaps.get(snap.step)
            if old is not None and not _same(old, snap):
                raise DemFormatError(f"{snap.source}: step {snap.step} is also in {old.source} with other "
                                     "particles; a run's dumps must agree where they overlap")
            snaps.setdefault(snap.step, snap)
    return [snaps[s] for s in sorted(snaps)]


def _same(a: Snapshot, b: Snapshot) -> bool:
    return a.columns.keys() == b.columns.keys() and all(
        np.array_equal(a.columns[k], b.columns[k]) for k in a.columns)


def _read_file(path: Path) -> Iterator[Snapshot]:
    try:
        with _open(path) as f:
            lines = f.read().splitlines()
    except (OSError, UnicodeDecodeError, EOFError) as exc:
        raise DemFormatError(f"{path}: cannot read this dump file ({exc})") from None
    i, found = 0, 0
    while i < len(lines):
        if not lines[i].strip():
            i += 1
            continue
        snap, i = _read_snapshot(lines, i, str(path))
        found += 1
        yield snap
    if not found:
        raise DemFormatError(f"{path}: no snapshot in this file (a dump begins with 'ITEM: TIMESTEP')")


def _item(lines: list[str], i: int, name: str, source: str, step: object) -> str:
    """The rest of the 'ITEM: name...' header at line i (an error if it is another line)."""
    where = f" (snapshot at step {step})" if step is not None else ""
    if i >= len(lines):
        raise DemFormatError(f"{source}: the file ends where 'ITEM: {name}' was expected{where}: "
                             "the snapshot is cut short")
    if not lines[i].startswith(f"ITEM: {name}"):
        raise DemFormatError(f"{source}, line {i + 1}: expected 'ITEM: {name}', found {lines[i][:60]!r}{where}")
    return lines[i][len(f"ITEM: {name}"):].strip()


def _int_line(lines: list[str], i: int, what: str, source: str) -> int:
    try:
        return int(lines[i].split()[0])
    except (IndexError, ValueError):
        raise DemFormatError(f"{source}, line {i + 1}: expected the {what} (a whole number)") from None


def _read_snapshot(lines: list[str], i: int, source: str) -> tuple[Snapshot, int]:
    _item(lines, i, "TIMESTEP", source, None)
    step = _int_line(lines, i + 1, "timestep", source)
    i += 2
    while i < len(lines) and lines[i].startswith(("ITEM: UNITS", "ITEM: TIME")) \
            and not lines[i].startswith("ITEM: TIMESTEP"):
        i += 2  # optional headers of dump_modify units/time: one value line each
    _item(lines, i, "NUMBER OF ATOMS", source, step)
    n = _int_line(lines, i + 1, "number of atoms", source)
    flags = _item(lines, i + 2, "BOX BOUNDS", source, step).split()
    lo, hi, periodic = _box(lines[i + 3:i + 6], flags, source, i + 4, step)
    names = _item(lines, i + 6, "ATOMS", source, step).split()
    start = i + 7
    block = lines[start:start + n]
    cut = next((k for k, line in enumerate(block) if line.startswith("ITEM:")), len(block))
    if cut < n:
        raise DemFormatError(f"{source}: the snapshot at step {step} is cut short: {n} atoms announced, "
                             f"{cut} found")
    values = " ".join(block).split()
    if len(values) != n * len(names):
        raise DemFormatError(f"{source}: the snapshot at step {step} is cut short or malformed: "
                             f"{n} atoms x {len(names)} columns announced, {len(values)} numbers found")
    try:
        table = np.array(values, dtype=float).reshape(n, len(names))
    except ValueError:
        raise DemFormatError(f"{source}: the snapshot at step {step} holds a value that is not a number") from None
    columns = _columns(table, names, lo, hi, flags, source, step)
    return Snapshot(step, lo, hi, periodic, columns, source), start + n


def _box(rows: list[str], flags: list[str], source: str, line: int, step: int
         ) -> tuple[np.ndarray, np.ndarray, tuple[bool, bool, bool]]:
    """Box extent per axis; a tilted box's bounds hold the tilt, taken out as LAMMPS documents."""
    tilted = flags[:3] == ["xy", "xz", "yz"]
    try:
        nums = np.array([[float(v) for v in r.split()] for r in rows])
    except ValueError:
        nums = np.empty((0, 0))
    if nums.shape != (3, 3 if tilted else 2):
        raise DemFormatError(f"{source}, line {line}: the box bounds of step {step} are not 3 lines of "
                             f"{3 if tilted else 2} numbers")
    lo, hi = nums[:, 0].copy(), nums[:, 1].copy()
    if tilted:
        xy, xz, yz = nums[:, 2]
        lo[0] -= min(0.0, xy, xz, xy + xz)
        hi[0] -= max(0.0, xy, xz, xy + xz)
        lo[1] -= min(0.0, yz)
        hi[1] -= max(0.0, yz)
    bounds = flags[3:] if tilted else flags
    periodic = tuple(b == "pp" for b in bounds[:3]) if len(bounds) >= 3 else (False, False, False)
    return lo, hi, (bool(periodic[0]), bool(periodic[1]), bool(periodic[2]))


def _columns(table: np.ndarray, names: list[str], lo: np.ndarray, hi: np.ndarray, flags: list[str],
             source: str, step: int) -> dict[str, np.ndarray]:
    index = {name: k for k, name in enumerate(names)}
    for need in ("id", "type"):
        if need not in index:
            raise DemFormatError(f"{source}: the dump has no '{need}' column (step {step}; columns: "
                                 f"{' '.join(names)}); dump custom needs at least id type x y z")
    out = {"id": table[:, index["id"]].astype(np.int64), "type": table[:, index["type"]].astype(np.int64)}
    for k, axis in enumerate(AXES):
        name = next((c for c in POSITION[axis] if c in index), None)
        if name is None:
            raise DemFormatError(f"{source}: the dump has no position column for {axis} (step {step}; "
                                 f"expected one of {' '.join(POSITION[axis])})")
        value = table[:, index[name]]
        if "s" in name[1:]:
            if flags[:3] == ["xy", "xz", "yz"]:
                raise DemFormatError(f"{source}: scaled positions ({name}) in a tilted box are not supported; "
                                     "dump x y z instead")
            value = lo[k] + value * (hi[k] - lo[k])
        out[axis] = value
        if VELOCITY[axis][0] in index:
            out[VELOCITY[axis][0]] = table[:, index[VELOCITY[axis][0]]]
    if "radius" in index:
        out["radius"] = table[:, index["radius"]]
    elif "diameter" in index:
        out["radius"] = table[:, index["diameter"]] / 2
    if "mass" in index:
        out["mass"] = table[:, index["mass"]]
    return out
