"""Safe output files: atomic writes that never silently replace a user's file.

Every writer in granseg goes through :func:`atomic_write` (or the helpers built
on it). The data are written to a temporary file in the destination folder and
moved into place with ``os.replace``, so a crash or a full disk leaves either
the old file or the new one, never half of one.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from granseg.errors import OutputExistsError

__all__ = [
    "OutputExistsError",
    "atomic_write",
    "atomic_path",
    "check_writable",
    "prepare_output_dir",
    "save_json",
    "save_npz",
]


def check_writable(path: str | os.PathLike, force: bool = False) -> Path:
    """Return ``path`` as a Path after checking it may be written.

    Raises OutputExistsError if the file exists and ``force`` is false, and
    FileNotFoundError if its folder does not exist.
    """
    p = Path(path)
    if p.exists() and not force:
        raise OutputExistsError(
            f"{p}: output file exists; pass force=True (CLI: --force) to overwrite it"
        )
    if p.exists() and p.is_dir():
        raise IsADirectoryError(f"{p}: is a directory, expected a file path")
    if not p.parent.exists():
        raise FileNotFoundError(f"{p.parent}: output folder does not exist")
    return p


def prepare_output_dir(out: str | os.PathLike, names: Sequence[str], force: bool = False, *,
                       folders: Sequence[str] = ()) -> Path:
    """Return folder ``out`` as a Path, ready for outputs ``names`` (files or folders in it).

    Raises NotADirectoryError if ``out`` is a file, FileNotFoundError if its
    parent does not exist, and OutputExistsError if any of ``names`` exists
    and ``force`` is false; nothing is created until all checks pass. Then
    ``out`` and its sub-folders ``folders`` are made.
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise NotADirectoryError(f"{out}: exists and is not a directory")
    if not out.parent.exists():
        raise FileNotFoundError(f"{out.parent}: output folder does not exist")
    clash = [n for n in names if (out / n).exists()]
    if clash and not force:
        raise OutputExistsError(f"{out}: already holds {clash}; pass force=True (CLI: --force)")
    for sub in (".", *folders):
        (out / sub).mkdir(exist_ok=True)
    return out


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, force: bool = False, suffix: str = "") -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success move it into place.

    ``suffix`` is the extension the temporary file needs for writers that
    choose a format by name (e.g. ``.png``, ``.npz``).
    """
    dest = check_writable(path, force)
    fd, tmp = tempfile.mkstemp(prefix=f".{dest.name}.", suffix=suffix or dest.suffix, dir=dest.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        if not force and dest.exists():
            raise OutputExistsError(f"{dest}: appeared while writing; not overwritten")
        # mkstemp creates 0600; give the file the permissions a plain open() would
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp_path, 0o666 & ~umask)
        os.replace(tmp_path, dest)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def atomic_write(path: str | os.PathLike, write: Callable[[Path], Any], force: bool = False) -> Path:
    """Call ``write(tmp_path)`` and move the result to ``path`` atomically."""
    with atomic_path(path, force) as tmp:
        write(tmp)
    return Path(path)


def save_npz(path: str | os.PathLike, arrays: dict[str, Any], force: bool = False) -> Path:
    """Write a NumPy ``.npz`` archive atomically."""

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)

    return atomic_write(path, write, force)


def save_json(path: str | os.PathLike, obj: Any, force: bool = False) -> Path:
    """Write JSON atomically (NaN written as null, numpy scalars as numbers)."""

    def default(o: Any) -> Any:
        if isinstance(o, np.generic):
            return o.item()
        if isinstance(o, np.ndarray):
            return o.tolist()
        if isinstance(o, Path):
            return str(o)
        raise TypeError(f"cannot write {type(o).__name__} to JSON")

    text = json.dumps(_nan_to_none(obj), indent=2, default=default, allow_nan=False)

    def write(tmp: Path) -> None:
        tmp.write_text(text + "\n", encoding="utf-8")

    return atomic_write(path, write, force)


def _nan_to_none(obj: Any) -> Any:
    if isinstance(obj, float | np.floating) and not np.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {k: _nan_to_none(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_nan_to_none(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _nan_to_none(obj.tolist())
    return obj
