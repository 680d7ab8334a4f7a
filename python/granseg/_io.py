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
    "check_output_dir",
    "cv2_path",
    "prepare_output_dir",
    "staged_output_dir",
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
    """Return ``path`` as a Path after checking it may be written, before any work is done.

    Raises OutputExistsError if the file exists and ``force`` is false,
    IsADirectoryError if it is a folder, FileNotFoundError if its folder does
    not exist, NotADirectoryError if that "folder" is a file, and
    PermissionError if nothing can be created there (a read-only disk, /proc).
    """
    p = Path(path)
    if p.exists() and not force:
        raise OutputExistsError(
            f"{p}: output file exists; pass force=True (CLI: --force) to overwrite it"
        )
    if p.exists() and p.is_dir():
        raise IsADirectoryError(f"{p}: is a directory, expected a file path")
    _check_folder(p.parent, p)
    return p


def _check_folder(folder: Path, file: Path | None = None) -> None:
    """The folder exists, is a folder, and a file can be created in it (tried, then removed:
    permissions, read-only mounts and pseudo file systems all answer the same way). The error
    names ``file`` first when the folder is to hold it (an output file, or an output folder
    not made yet): the path the caller gave."""
    said = f"{file}: folder {folder}" if file is not None else f"{folder}: output folder"
    if not folder.exists():
        if any(parent.is_file() for parent in folder.parents):
            bad = next(parent for parent in folder.parents if parent.is_file())
            raise NotADirectoryError(f"{said} cannot be made, {bad} is a file (not a directory)")
        raise FileNotFoundError(f"{said} does not exist")
    if not folder.is_dir():
        raise NotADirectoryError(f"{said} is a file, not a directory")
    try:
        with tempfile.TemporaryFile(dir=folder, prefix=".granseg-probe."):
            pass
    except OSError as exc:
        raise PermissionError(f"{said}: cannot create a file there ({exc.strerror or exc})") from None


def check_creatable(folder: str | os.PathLike) -> Path:
    """Check that ``folder`` exists as a writable folder or can be made with its parents (the
    nearest existing ancestor is a writable folder); nothing is created."""
    folder = Path(folder)
    existing = folder
    while not existing.exists() and existing.parent != existing:
        existing = existing.parent
    if existing != folder and existing.is_file():
        raise NotADirectoryError(f"{folder}: cannot be made, {existing} is a file")
    _check_folder(existing, None if existing == folder else folder)
    return folder


def check_output_dir(out: str | os.PathLike, names: Sequence[str], force: bool = False) -> Path:
    """Check that folder ``out`` can receive outputs ``names`` without creating anything: what
    :func:`prepare_output_dir` checks, for callers that must fail before long work starts.

    Raises NotADirectoryError if ``out`` is a file, FileNotFoundError if its
    parent does not exist, PermissionError if it cannot be written, and
    OutputExistsError if any of ``names`` exists and ``force`` is false.
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise NotADirectoryError(f"{out}: exists and is not a directory")
    if out.exists():
        _check_folder(out)
    else:
        _check_folder(out.parent, out)
    clash = [n for n in names if (out / n).exists() or (out / n).is_symlink()]
    if clash and not force:
        raise OutputExistsError(f"{out}: already holds {clash}; pass force=True (CLI: --force)")
    return out


def prepare_output_dir(out: str | os.PathLike, names: Sequence[str], force: bool = False, *,
                       folders: Sequence[str] = ()) -> Path:
    """Return folder ``out`` as a Path, ready for outputs ``names`` (files or folders in it).

    Checks as :func:`check_output_dir` does; nothing is created until all
    checks pass. Then ``out`` and its sub-folders ``folders`` are made.
    """
    out = check_output_dir(out, names, force)
    for sub in (".", *folders):
        (out / sub).mkdir(exist_ok=True)
    return out


@contextlib.contextmanager
def staged_output_dir(out: str | os.PathLike, names: Sequence[str], force: bool = False, *,
                      folders: Sequence[str] = ()) -> Iterator[Path]:
    """Yield a hidden staging folder for outputs ``names`` of folder ``out``; on success move them in.

    For outputs made of many files (a report: a page, its JSON, a folder of
    figures): they are written into ``.OUT.<random>.partial`` (with its
    sub-folders ``folders`` made), on the same file system as ``out``, and
    only when the block ends without an exception are they moved into
    ``out``: the whole folder renamed into place when ``out`` does not exist,
    else each output replacing its old self (``force``). A failure, an
    interrupt or a full disk leaves no half output and nothing that blocks
    a rerun: the staging folder is removed whatever happens.

    ``out`` is checked first (:func:`check_output_dir`), before the block
    runs; the staging folder lives in ``out`` when it exists, else beside it.
    """
    dest = check_output_dir(out, names, force)
    home = dest if dest.is_dir() else dest.parent
    stage = Path(tempfile.mkdtemp(prefix=f".{dest.name or 'out'}.", suffix=PARTIAL_SUFFIX, dir=home))
    try:
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(stage, 0o777 & ~umask)  # the folder a plain mkdir would make (mkdtemp's is private)
        for sub in folders:
            (stage / sub).mkdir()
        try:
            yield stage
        except OSError as exc:
            # name the file as the user knows it (OUT/figures/x.png), not by its staging path
            where = exc.filename if isinstance(exc.filename, str) else ""
            if exc.errno is None or not where.startswith(str(stage)):
                raise
            raise OSError(exc.errno, exc.strerror, str(dest) + where[len(str(stage)):]) from exc
        check_output_dir(dest, names, force)  # nothing appeared meanwhile
        if not dest.exists():
            os.rename(stage, dest)
            return
        for name in names:
            new, old = stage / name, dest / name
            if not (new.exists() or new.is_symlink()):
                continue
            if old.is_dir() and not old.is_symlink():
                os.rename(old, stage / f".{name}.old")  # swapped out, removed with the stage
            os.replace(new, old)
    finally:
        shutil.rmtree(stage, ignore_errors=True)


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
        try:
            tmp_path.touch()  # writers get an existing, empty file, as they did from mkstemp
            yield tmp_path
        except OSError as exc:
            if exc.errno is None or exc.filename not in (None, str(tmp_path)):
                raise
            # a failed write (a full disk: ENOSPC) says what went wrong but not where: name the file
            raise OSError(exc.errno, f"{exc.strerror or exc}; nothing written", str(dest)) from exc
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
    return atomic_write_text(path, text + "\n", force)


def atomic_write_text(path: str | os.PathLike, text: str, force: bool = False) -> Path:
    """Write ``text`` as UTF-8, atomically. A file name that is not valid UTF-8 reaches Python
    as lone surrogates (``\\udcff``); they are written as that escape, readable, rather than
    failing the whole report or JSON at the last step."""
    return atomic_write(path, lambda tmp: tmp.write_text(text, encoding="utf-8", errors="backslashreplace"),
                        force)


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
