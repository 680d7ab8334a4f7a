"""The ``granseg`` command line.

Each subcommand lives in its own module in this package and defines
``register(subparsers)``, which adds its parser and sets ``func`` to the
function that runs it. Modules are discovered here, so adding a command never
means editing this file.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import pkgutil
import sys
import warnings

from granseg.errors import GransegError

__all__ = ["main", "build_parser"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="granseg",
        description="Density-driven segregation in an annular shear cell: "
        "frames to maps, simulation, calibration and diagnosis.",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="more log output")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for info in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{__name__}.{info.name}")
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(message)s",
    )
    # matplotlib's PDF backend logs every font subset at INFO through fontTools
    logging.getLogger("fontTools").setLevel(logging.WARNING)
    # warnings as one line a user reads, not Python's "file:line: Class: ..." with a source line
    warnings.formatwarning = lambda message, category, *rest, **kw: f"granseg: warning: {message}\n"
    # Only granseg's errors and the built-ins bad input raises are caught; any
    # other exception is a bug in granseg, and its traceback is what a bug
    # report needs, so it is not hidden behind a last-resort handler.
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("granseg: interrupted", file=sys.stderr)
        return 130
    except (ValueError, OSError) as exc:
        # Bad input: argument validation (ValueError), a bad map or frame
        # (MapFormatError, FlaggedMapError, BadFrame are ValueErrors), a user
        # file missing, unreadable or already there (OSError: FileNotFoundError,
        # OutputExistsError, PermissionError). One clear line, no traceback.
        print(f"granseg {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except GransegError as exc:
        # The input was fine but the work failed (SolverError, FitError).
        print(f"granseg {args.command}: error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
