"""The ``granseg`` command line.

Each subcommand lives in its own module in this package and defines
``register(subparsers)``, which adds its parser and sets ``func`` to the
function that runs it. Modules are discovered here, so adding a command never
means editing this file.
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import importlib
import logging
import pkgutil
import sys
import warnings
from collections.abc import Iterator

from granseg import __version__
from granseg.errors import GransegError

__all__ = ["build_parser", "console", "main"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="granseg",
        description="Density-driven segregation in an annular shear cell: "
        "frames to maps, simulation, calibration and diagnosis.",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="more log output")
    parser.add_argument("--version", action="version", version=f"granseg {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for info in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{__name__}.{info.name}")
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    # Ctrl-C ends every command the same way (130), also while the commands' modules are
    # still being imported to build the parser (a few tenths of a second, before any work starts)
    try:
        with _interrupts_as_such():
            parser = build_parser()
        return _run(parser.parse_args(argv))
    except KeyboardInterrupt:
        print("granseg: interrupted", file=sys.stderr)
        return 130


def console() -> int:
    """The ``granseg`` command: :func:`main`, then a quick exit.

    At exit Python collects every reference cycle left in the heap; with matplotlib, the
    frame pipeline and scikit-learn loaded that took about half a second of each command
    (under a tenth with the heap frozen; BENCHMARKS "The command line's start"). Frozen cycles are never
    collected, which only matters to a process that goes on: the tests call :func:`main`.
    Files are closed by the code that writes them and atexit handlers (logging, temporary
    folders, a dask client) still run.
    """
    code = main()
    gc.freeze()
    return code


def _run(args: argparse.Namespace) -> int:
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(message)s",
    )
    # matplotlib's PDF backend logs every font subset at INFO through fontTools, and its own
    # font and backend chatter at DEBUG; -v is for granseg's log
    logging.getLogger("fontTools").setLevel(logging.WARNING)
    logging.getLogger("matplotlib").setLevel(logging.WARNING)
    # a path that is not valid UTF-8 (lone surrogates in Python) is printed escaped, not a crash
    if hasattr(sys.stdout, "reconfigure"):
        sys.stdout.reconfigure(errors="backslashreplace")
    # warnings as one line a user reads, not Python's "file:line: Class: ..." with a source line
    warnings.formatwarning = lambda message, category, *rest, **kw: f"granseg: warning: {message}\n"
    # Every failure ends as one line naming what went wrong; the traceback, which a bug
    # report needs, is printed only under -v (issue 14).
    try:
        with _interrupts_as_such():
            return int(args.func(args) or 0)
    except MemoryError as exc:
        _traceback(args)
        print(f"granseg {args.command}: error: out of memory ({exc or 'the request is too large'}); "
              "ask for less (fewer cells, output times or frames)", file=sys.stderr)
        return 1
    except (ValueError, OSError) as exc:
        _traceback(args)
        # Bad input: argument validation (ValueError), a bad map or frame
        # (MapFormatError, FlaggedMapError, BadFrame are ValueErrors), a user
        # file missing, unreadable or already there (OSError: FileNotFoundError,
        # OutputExistsError, PermissionError). One clear line (the traceback under -v).
        print(f"granseg {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except GransegError as exc:
        _traceback(args)
        # The input was fine but the work failed (SolverError, FitError).
        print(f"granseg {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except Exception as exc:  # noqa: BLE001 - the last resort: a bug, said in one line
        _traceback(args)
        print(f"granseg {args.command}: internal error: {type(exc).__name__}: {exc} (a bug in granseg; "
              "run again with -v for the traceback to report it)", file=sys.stderr)
        return 4


@contextlib.contextmanager
def _interrupts_as_such() -> Iterator[None]:
    """Raise as a KeyboardInterrupt an error raised because of one.

    Ctrl-C while a C extension loads or runs can surface as another exception
    (SystemError, ImportError) whose cause or context is the KeyboardInterrupt;
    the user pressed Ctrl-C, so the command ends as interrupted (130), not as a bug (4).
    """
    try:
        yield
    except Exception as exc:
        chain: list[BaseException] = [exc]
        while (link := chain[-1].__cause__ or chain[-1].__context__) is not None and link not in chain:
            chain.append(link)
        if any(isinstance(e, KeyboardInterrupt) for e in chain):
            raise KeyboardInterrupt from exc
        raise


def _traceback(args: argparse.Namespace) -> None:
    """Print the traceback of the exception being handled when asked for (-v)."""
    if getattr(args, "verbose", False):
        import traceback

        traceback.print_exc()


if __name__ == "__main__":
    sys.exit(main())
