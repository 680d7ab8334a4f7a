"""Safe output files: atomic writes that never silently replace a user's file.

Every writer in granseg goes through :func:`atomic_write` (or the helpers built
on it). The data are written to a temporary file in the destination folder and
moved into place with ``os.replace``, so a crash or a full disk leaves either
the old file or the new one, never half of one. The temporary file lives in a
hidden ``.NAME.<random>.partial`` folder (:data:`PARTIAL_SUFFIX`), so one left
by a killed process is never read as a map, frame or image.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from granseg.errors import OutputExistsError

__all__ = [
    "OutputExistsError",
    "PARTIAL_SUFFIX",
    "atomic_write",
    "atomic_path",
    "check_writable",
    "cv2_path",
    "prepare_output_dir",
    "save_json",
    "save_npz",
]


def cv2_path(path: str | os.PathLike) -> str:
    """``path`` as the text OpenCV's file functions take; ValueError naming it when it is not valid
    UTF-8 (a name such as ``b"G-\\xff.png"``): OpenCV's imread, imwrite, VideoCapture and VideoWriter
    end the process with a segmentation fault on such a name (issue 14)."""
    text = os.fspath(path)
    text = os.fsdecode(text) if isinstance(text, bytes) else text
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        raise ValueError(f"{text.encode('utf-8', 'backslashreplace').decode()}: the path is not valid UTF-8, "
                         "which OpenCV cannot open; rename the file or folder") from None
    return text


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


#: Ending of the hidden folder an unfinished write lives in (``.NAME.<random>.partial/NAME``).
#: No reader globs it: a write cut short (crash, kill, full disk) leaves that folder behind, never
#: a file a map, frame or image reader could mistake for a finished one.
PARTIAL_SUFFIX = ".partial"


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, force: bool = False, suffix: str = "") -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success move it into place.

    The temporary file is ``.NAME.<random>.partial/NAME`` in the destination
    folder: it keeps the destination's name and extension (writers that
    choose a format by name, e.g. ``.png`` or ``.mp4``, see the right one),
    sits on the same file system (so ``os.replace`` is atomic), and lives in
    a hidden folder whose name no reader globs. ``suffix`` is appended when
    the name does not already end in it (for a writer that needs another
    extension than the destination's). The folder is removed afterwards,
    whether the write succeeded or not.
    """
    dest = check_writable(path, force)
    tmp_dir = Path(tempfile.mkdtemp(prefix=f".{dest.name}.", suffix=PARTIAL_SUFFIX, dir=dest.parent))
    tmp_path = tmp_dir / (dest.name if not suffix or dest.name.endswith(suffix) else dest.name + suffix)
    try:
        tmp_path.touch()  # writers get an existing, empty file, as they did from mkstemp
        yield tmp_path
        if not tmp_path.is_file():
            raise OSError(f"{dest}: the writer left no file; nothing written")
        if not force and dest.exists():
            raise OutputExistsError(f"{dest}: appeared while writing; not overwritten")
        # give the file the permissions a plain open() would (whatever the writer used)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp_path, 0o666 & ~umask)
        os.replace(tmp_path, dest)
    finally:
        shutil.rmtree(tmp_dir, ignore_errors=True)


def atomic_write(path: str | os.PathLike, write: Callable[[Path], Any], force: bool = False) -> Path:
    """Call ``write(tmp_path)`` and move the result to ``path`` atomically."""
    with atomic_path(path, force) as tmp:
        write(tmp)
    return Path(path)


def save_npz(path: str | os.PathLike, arrays: dict[str, Any], force: bool = False) -> Path:
    """Write a NumPy ``.npz`` archive atomically."""

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as fh:  # a handle: np.savez would add ".npz" to a bare path lacking it
            np.savez(fh, **arrays)

    return atomic_write(path, write, force)


def read_json(path: str | os.PathLike, what: str, hint: str = "") -> Any:
    """The JSON document at ``path``; FileNotFoundError / ValueError name the file and ``what``
    it should hold (e.g. "experiment.json"), with ``hint`` on where one comes from."""
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"{p}: {what} not found" + (f" ({hint})" if hint else ""))
    try:
        return json.loads(p.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{p}: not valid JSON ({exc})") from None


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
