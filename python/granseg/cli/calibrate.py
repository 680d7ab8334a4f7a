"""``granseg calibrate CAMPAIGN_DIR``: factorial design, refinement, JSON result."""

from __future__ import annotations

import argparse
import contextlib
from collections.abc import Iterator
from typing import Any

import numpy as np

from granseg.constants import DEFAULT_ERRORS, ERRORS

__all__ = ["register", "run", "parse_grid", "parse_bounds", "add_calibration_options"]


def parse_grid(items: list[str] | None) -> dict[str, list[float]] | None:
    """``["k=0.5,0.6,0.7", "delta_over_H=0.18,0.2"]`` -> {name: [values]}."""
    if not items:
        return None
    out: dict[str, list[float]] = {}
    for item in items:
        name, sep, values = item.partition("=")
        if not sep or not name.strip():
            raise ValueError(f"--grid {item!r}: expected NAME=V1,V2,...")
        try:
            out[name.strip()] = [float(v) for v in values.split(",") if v.strip()]
        except ValueError:
            raise ValueError(f"--grid {item!r}: values of {name.strip()!r} must be numbers") from None
    return out


def parse_bounds(items: list[str] | None) -> dict[str, tuple[float, float]] | None:
    """``["k=0.3:0.9"]`` -> {"k": (0.3, 0.9)}."""
    if not items:
        return None
    out: dict[str, tuple[float, float]] = {}
    for item in items:
        name, sep, rng = item.partition("=")
        lo, sep2, hi = rng.partition(":")
        try:
            if not (sep and sep2):
                raise ValueError
            out[name.strip()] = (float(lo), float(hi))
        except ValueError:
            raise ValueError(f"--bounds {item!r}: expected NAME=LO:HI") from None
    return out


def add_calibration_options(p: argparse.ArgumentParser) -> None:
    """Options shared by ``calibrate`` and ``report``."""
    p.add_argument("--grid", action="append", metavar="NAME=V1,V2,..",
                   help="factorial values of a model parameter (repeat per parameter; "
                        "default k=0.5,0.6,0.7 and delta_over_H=0.18,0.20,0.22)")
    p.add_argument("--bounds", action="append", metavar="NAME=LO:HI",
                   help="refinement bounds (default: grid range widened by its width)")
    p.add_argument("--no-refine", action="store_true", help="factorial design only")
    p.add_argument("--per-experiment", action="store_true", help="also each experiment's own optimum")
    p.add_argument("--n-cells", type=int, default=None, help="finite volumes over the depth")
    p.add_argument("--rtol", type=float, default=None, help="solver relative tolerance")
    p.add_argument("--max-nfev", type=int, default=40, help="cap on refinement evaluations")
    p.add_argument("--errors", choices=ERRORS, default=DEFAULT_ERRORS,
                   help="standard errors and 95 %% intervals: auto (default: experiments as clusters "
                        "from 8 experiments on), cluster, jackknife (leave one experiment out), or "
                        "jacobian (entries counted as independent)")
    p.add_argument("--dask", metavar="ADDRESS", default=None,
                   help="dask scheduler address ('local' starts a threaded LocalCluster)")
    p.add_argument("--accept-flagged", action="store_true",
                   help="use maps that failed their frame-analysis quality checks (refused by default)")
    p.add_argument("--velocity", metavar="V.json", default=None,
                   help="a measured shear band in place of fitting delta/H: a `granseg velocity` profile or a "
                        "`granseg velocity-law --json` law, or a folder of one profile per map (NAME.json, as "
                        "`granseg dem` writes them)")
    p.add_argument("--velocity-shape", choices=("exponential", "tabulated"), default="exponential",
                   help="with a measured profile: its exponential fit (default) or its own shear rate -dv/dz "
                        "as the model's (a band of any shape)")
    p.add_argument("--no-dwell", action="store_true",
                   help="compare the model with the maps as they are, without the view's dwell (the lag "
                        "of grains staying in view, measured from the counts; on by default)")


def calibration_kwargs(args: argparse.Namespace) -> dict[str, Any]:
    """Keyword arguments of granseg.calibrate from parsed options."""
    return dict(grid=parse_grid(args.grid), bounds=parse_bounds(args.bounds),
                refine=not args.no_refine, per_experiment=args.per_experiment,
                n_cells=args.n_cells, rtol=args.rtol, max_nfev=args.max_nfev,
                errors=args.errors, accept_flagged=args.accept_flagged, view_dwell=not args.no_dwell,
                velocity=args.velocity, velocity_shape=args.velocity_shape)


@contextlib.contextmanager
def dask_client(address: str | None) -> Iterator[Any]:
    """A dask client for ``--dask`` (None when not asked for)."""
    if address is None:
        yield None
        return
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError:
        raise ValueError("--dask: dask[distributed] is not installed (pip install granseg[dask])") from None
    if address == "local":
        with LocalCluster(processes=False) as cluster, Client(cluster) as client:
            yield client
    else:
        with Client(address) as client:
            yield client


def register(subparsers: Any) -> None:
    p = subparsers.add_parser("calibrate", help="calibrate the model against a campaign of maps",
                              description=__doc__)
    p.add_argument("campaign", metavar="CAMPAIGN_DIR", help="directory of map .npz files")
    add_calibration_options(p)
    p.add_argument("--json", metavar="OUT.json", default=None, help="write the result as JSON")
    p.add_argument("--force", action="store_true", help="overwrite OUT.json if it exists")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from granseg._io import check_writable, save_json
    from granseg.calibration import calibrate
    from granseg.maps import load_campaign

    if args.json:
        check_writable(args.json, args.force)
    camp = load_campaign(args.campaign)
    with dask_client(args.dask) as client:
        cal = calibrate(camp, client=client, progress=not args.quiet, **calibration_kwargs(args))
    print(cal.table())
    print(summary(cal))
    if args.json:
        save_json(args.json, cal.to_json(), force=args.force)
        print(f"wrote {args.json}")
    return 0


def summary(cal: Any) -> str:
    """Human-readable lines for the optimum (and per-experiment optima)."""
    what = "refined optimum" if cal.refined else "best grid point"
    pars = ", ".join(f"{k} = {v:.4f} +- {cal.stderr[k]:.4f}" for k, v in cal.best.items())
    lines = [f"\n{what}: {pars}; mean RMSD {cal.rmsd_mean:.4f}"
             + ("" if cal.converged else f" ({cal.message})")]
    u = cal.uncertainty
    if u is not None:
        lo, hi = u.interval
        ivs = ", ".join(f"{k} in [{a:.4f}, {b:.4f}]" for k, a, b in zip(u.names, lo, hi, strict=True))
        lines.append(f"  {100 * u.level:.0f} % intervals ({u.method} errors, {u.dof:.0f} degrees of freedom): {ivs}"
                     if np.isfinite(u.dof) else f"  {100 * u.level:.0f} % intervals ({u.method} errors): {ivs}")
        lines += [f"  note: {w}" for w in u.warnings()]
    for k in cal.at_bound:
        lines.append(f"  note: {k} ended on a bound of its range {cal.settings['bounds'][k]}: the optimum may "
                     f"lie beyond it; widen it with --bounds {k}=LO:HI")
    for name, r in cal.rmsd.items():
        lines.append(f"  {name:>12}  RMSD {r:.4f}")
    if cal.per_experiment:
        lines.append("per-experiment optima:")
        for name, p in cal.per_experiment.items():
            pp = ", ".join(f"{k} = {v:.4f} +- {p.stderr[k]:.4f}" for k, v in p.best.items())
            lines.append(f"  {name:>12}  {pp}; RMSD {p.rmsd:.4f}" + ("" if p.converged else " (not converged)"))
    return "\n".join(lines)
