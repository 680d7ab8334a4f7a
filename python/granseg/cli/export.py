"""``granseg export INPUT... --out DIR``: maps, calibrations and diagnoses as CSV (and maps as .mat)."""

from __future__ import annotations

import argparse
from typing import Any

__all__ = ["register", "run"]


def register(subparsers: Any) -> None:
    """Add the ``export`` subcommand."""
    p = subparsers.add_parser(
        "export", help="write maps, calibration and diagnosis results as CSV tables (maps also as MATLAB .mat)",
        description="Write each INPUT as files a spreadsheet or MATLAB opens: a map .npz as NAME_c.csv "
                    "(time by layer), NAME_n.csv and NAME_n_heavy.csv (counts, where present), "
                    "NAME_conditions.csv and NAME.mat; a campaign directory as every map of it; a diagnosis "
                    "JSON (granseg diagnose --json) or a calibration JSON (granseg calibrate --json) as its "
                    "tables (diagnosis_*.csv, calibration_*.csv; always CSV). Everything is checked before "
                    "anything is written; existing files are kept unless --force.")
    p.add_argument("inputs", nargs="+", metavar="INPUT",
                   help="a map .npz, a campaign directory, or a diagnosis / calibration JSON")
    p.add_argument("--out", required=True, metavar="DIR", help="folder for the exported files (created if missing)")
    p.add_argument("--format", choices=("csv", "mat", "both"), default="both",
                   help="what to write for maps (default both; JSON tables are always CSV)")
    p.add_argument("--force", action="store_true", help="overwrite existing output files")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from granseg.export import FORMATS, export_paths

    formats = FORMATS if args.format == "both" else (args.format,)
    for path in export_paths(args.inputs, args.out, formats=formats, force=args.force):
        print(f"wrote {path}")
    return 0
