"""``granseg diagnose CAMPAIGN_DIR --json OUT.json --report DIR``: name what the model gets wrong."""

from __future__ import annotations

import argparse
from typing import Any

__all__ = ["register", "run"]


def register(subparsers: Any) -> None:
    """Add the ``diagnose`` subcommand."""
    from granseg.fitting.causes import names

    p = subparsers.add_parser(
        "diagnose",
        help="find what the model gets wrong on a campaign, name the cause, measure the gain",
        description="Calibrate the baseline model on every map of CAMPAIGN_DIR, estimate the "
                    "measurement-noise floor, fit each catalogued cause and compare them by "
                    "leave-one-experiment-out prediction. Causes: " + ", ".join(names()) + ".",
    )
    p.add_argument("campaign", metavar="CAMPAIGN_DIR", help="directory of map .npz files (docs/formats.md)")
    p.add_argument("--json", metavar="OUT.json", help="write the machine-readable diagnosis here")
    p.add_argument("--report", metavar="DIR", help="write the HTML report and figures into DIR")
    p.add_argument("--causes", nargs="+", metavar="NAME", choices=names(),
                   help="only consider these causes (default: all)")
    p.add_argument("--n-cells", type=int, default=72, help="model cells over the bed height (default 72)")
    p.add_argument("--force", action="store_true", help="replace existing output files")
    p.add_argument("--accept-flagged", action="store_true",
                   help="use maps that failed their frame-analysis quality checks (refused by default)")
    p.add_argument("--velocity", metavar="V.json",
                   help="a shear band measured from footage (`granseg velocity` profile or `velocity-law` "
                        "law): the diagnosis still fits delta/H from the maps and says whether the two agree")
    p.add_argument("--quiet", action="store_true", help="no progress log")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the diagnosis and print the verdict."""
    import logging

    logging.getLogger("fontTools").setLevel(logging.WARNING)  # PDF font subsetting chatter
    from granseg._io import check_output_dir, check_writable
    from granseg.diagnosis import diagnose
    from granseg.report.diagnosis import OUTPUTS, write_outputs
    from granseg.report.provenance import command_line

    if args.json is not None:
        check_writable(args.json, args.force)  # before the work, not after it
    if args.report is not None:
        check_output_dir(args.report, OUTPUTS, args.force)
    d = diagnose(args.campaign, force=args.force, causes=args.causes, n_cells=args.n_cells,
                 progress=not args.quiet, accept_flagged=args.accept_flagged, velocity=args.velocity)
    # the outputs carry the provenance, this command line included
    write_outputs(d, report=args.report, json=args.json, force=args.force, command=command_line("diagnose"))
    r = d.result
    print(f"cause: {r['cause']}  (misfit explained: {'yes' if r['explained'] else 'no'})")
    print(r["summary"])
    g = r["gain"]
    print(f"noise floor {r['noise_floor']:.4f}; mean RMSD baseline {r['baseline']['rmsd_mean']:.4f}; "
          f"gain in sample {g['rmsd_in_sample']:+.4f}, held out {g['rmsd_held_out']:+.4f}")
    for p in (r.get("velocity_check") or {}).get("pairs", []):
        print(f"shear band, maps against footage: {p['parameter']} {p['fitted']:.3f} vs measured "
              f"{p['measured']:.3f}: {'agree' if p['agrees'] else 'DISAGREE'}")
    if args.report:
        print(f"report: {r.get('report')}")
    return 0
