"""``granseg report CAMPAIGN_DIR --out DIR``: the calibration report (HTML + JSON)."""

from __future__ import annotations

import argparse
import logging
from typing import Any

from granseg.cli.calibrate import add_calibration_options, calibration_kwargs, dask_client

__all__ = ["register", "run"]


def register(subparsers: Any) -> None:
    p = subparsers.add_parser("report", help="HTML + JSON report of a campaign's calibration",
                              description=__doc__)
    p.add_argument("campaign", metavar="CAMPAIGN_DIR", help="directory of map .npz files")
    p.add_argument("--out", required=True, metavar="DIR", help="folder for index.html, report.json, figures/")
    add_calibration_options(p)
    p.add_argument("--c0", type=_c0, default=0.5,
                   help="c0 of the experiments used for the A and tau laws, in [0, 1] (default 0.5; -1 = all)")
    p.add_argument("--force", action="store_true", help="replace an existing report in DIR")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=run)


def _c0(text: str) -> float:
    """--c0: a concentration in [0, 1], or -1 for all experiments (checked before any work)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if value != -1 and not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"{text}: expected a concentration in [0, 1], or -1 for all experiments")
    return value


def run(args: argparse.Namespace) -> int:
    from granseg._io import check_output_dir
    from granseg.report import build_report
    from granseg.report.calibration import OUTPUTS
    from granseg.report.provenance import command_line

    logging.getLogger("fontTools").setLevel(logging.WARNING)  # PDF font subsetting chatter
    check_output_dir(args.out, OUTPUTS, args.force)  # before the campaign is read or calibrated
    c0 = None if args.c0 < 0 else args.c0
    with dask_client(args.dask) as client:
        page = build_report(args.campaign, args.out, fits_c0=c0, force=args.force,
                            progress=not args.quiet, client=client, command=command_line("report"),
                            **calibration_kwargs(args))
    print(f"wrote {page} (open it in a browser) and {page.parent / 'report.json'}")
    return 0
