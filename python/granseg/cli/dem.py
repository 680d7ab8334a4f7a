"""``granseg dem RUN_DIR...``: DEM runs (LAMMPS / LIGGGHTS dumps) as maps and velocity profiles."""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``dem`` command."""
    p = subparsers.add_parser(
        "dem", help="turn DEM runs (LAMMPS dump custom files) into maps and velocity profiles",
        description="Read each run's dump files (a directory, or dump files) with the config that names "
        "the particle types, units, axes and cell (docs/formats.md), and write one concentration map per run and "
        "view (OUT/bulk/NAME.npz, OUT/wall/NAME.npz: each view's folder is a campaign) with the run's own "
        "cell, and the run's velocity profile (OUT/velocity/NAME.json, as granseg velocity writes it).")
    p.add_argument("runs", nargs="+", metavar="RUN", help="run directory (or dump file)")
    p.add_argument("--config", metavar="DEM.json",
                   help="types, units, axes and cell (default: dem.json beside each run's dumps)")
    p.add_argument("--out", metavar="DIR", required=True, help="directory for the maps and profiles")
    p.add_argument("--view", choices=("bulk", "wall", "both"), default="both",
                   help="which grains the maps count: all (bulk), those at the side walls (wall), or both "
                   "(default)")
    p.add_argument("--t-from", type=float, default=None, metavar="SECONDS",
                   help="average the velocity profile from this time on (default: the later half of the run)")
    p.add_argument("--force", action="store_true", help="overwrite existing output files")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from granseg.dem.run import check_products, load_run, write_products

    views = ("bulk", "wall") if args.view == "both" else (args.view,)
    runs = [load_run(r, config=args.config) for r in args.runs]  # every run is read before anything is written
    names = [r.name for r in runs]
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        raise ValueError(f"two runs share the name {dupes[0]!r}; give each run its own directory")
    check_products(args.out, [f"{f}/{n}.{ext}" for n in names
                              for f, ext in [*((v, "npz") for v in views), ("velocity", "json")]], args.force)
    products = {}
    for k, r in enumerate(runs, 1):  # everything is computed before anything is written
        print(f"[{k}/{len(runs)}] {r.name}: {len(r.snapshots)} snapshots over {r.t[-1]:.3g} s, "
              f"{r.n_layers} layers, H = {r.H * 1e3:.1f} mm")
        for note in r.notes:
            print(f"  note: {note}")
        got = r.products(views, t_from=args.t_from)
        prof = got[f"velocity/{r.name}.json"]
        p, e = prof.fit.params, prof.fit.stderr
        print(f"  shear band ({prof.conditions['view']}): delta/H = {p['delta_over_H']:.3f} +- "
              f"{e['delta_over_H']:.3f}, v0 = {p['v0']:.3f} m/s (rms residual {prof.fit.mse ** 0.5:.1f} errors)")
        for note in prof.fit_notes:
            print(f"  note: {note}")
        products.update(got)
    for path in write_products(args.out, products, force=args.force):
        print(f"wrote {path}")
    return 0
