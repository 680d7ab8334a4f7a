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
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("granseg: interrupted", file=sys.stderr)
        return 130
    except (ValueError, FileNotFoundError, FileExistsError, OSError) as exc:
        # Bad input: one clear line, no traceback.
        print(f"granseg {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except Exception as exc:  # noqa: BLE001 - SolverError and friends
        from granseg.errors import GransegError

        if isinstance(exc, GransegError):
            print(f"granseg {args.command}: error: {exc}", file=sys.stderr)
            return 1
        raise


if __name__ == "__main__":
    sys.exit(main())
