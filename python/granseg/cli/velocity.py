"""``granseg velocity RECORDING...`` and ``granseg velocity-law DIR``: shear bands measured."""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``velocity`` and ``velocity-law`` commands."""
    p = subparsers.add_parser(
        "velocity", help="measure the streamwise velocity profile from high-speed footage",
        description="Find and link the spheres of one or several recordings of the same bed "
        "(frames directories or videos with experiment.json, any frame rates), measure the speed "
        "of every one-diameter layer at the wall, join the recordings and fit "
        "v(z) = v1 + (v0 - v1) exp(-z / delta).")
    p.add_argument("recordings", nargs="+", metavar="RECORDING", help="frames directory, TIFF stack or video file")
    p.add_argument("--json", metavar="OUT.json", required=True, help="profile and fit to write")
    p.add_argument("--figure", metavar="STEM", help="write the profile figure as STEM.png and STEM.pdf")
    p.add_argument("--preview", metavar="DIR", help="write each recording's tracks drawn on its first frame")
    p.add_argument("--D-p", dest="D_p", type=float, default=None, help="sphere diameter [m] (default 0.006)")
    p.add_argument("--H", type=float, default=None, help="bed height [m] (default: layers x D_p)")
    p.add_argument("--workers", metavar="N", type=int, help="parallel workers (default: all cores)")
    p.add_argument("--force", action="store_true", help="overwrite existing output files")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)

    q = subparsers.add_parser(
        "velocity-law", help="fit delta/H against the normalised load over several beds",
        description="Read the profiles (granseg velocity JSON files) in DIR, each carrying its bed's "
        "M_g and M_w, and fit delta/H = (delta/H)_ref (M~ / 0.5)^(-exponent), M~ = M_w / M_g.")
    q.add_argument("directory", metavar="DIR", help="directory of velocity JSON files")
    q.add_argument("--json", metavar="OUT.json", help="write the law's fit")
    q.add_argument("--figure", metavar="STEM", help="write the figure as STEM.png and STEM.pdf")
    q.add_argument("--force", action="store_true", help="overwrite existing output files")
    q.set_defaults(func=run_law)


def run(args: argparse.Namespace) -> int:
    from granseg._io import check_writable
    from granseg.constants import D_P
    from granseg.velocity import measure_velocity

    check_writable(args.json, args.force)
    prof, recs = measure_velocity(args.recordings, D_p=args.D_p or D_P, H=args.H, workers=args.workers,
                                  progress=not args.no_progress)
    p, e = prof.fit.params, prof.fit.stderr
    for r in recs:
        used = int(sum(1 for v in r.v if v == v))
        print(f"{r.source}: {r.fps:g} fps, {len(r.detected.spheres)} frames, "
              f"{len(set(r.tracks[:, 1].astype(int)))} tracks, {used} layers measured")
    print(f"delta/H = {p['delta_over_H']:.4f} +- {e['delta_over_H']:.4f}, v0 = {p['v0']:.4f} +- {e['v0']:.4f} m/s"
          + (f", v1 = {p['v1']:.4f} +- {e['v1']:.4f} m/s" if "v1" in p else "")
          + f" (rms residual {prof.fit.mse ** 0.5:.2f} errors)")
    for note in [*prof.notes, *prof.fit_notes]:
        print(f"  note: {note}")
    print(f"wrote {prof.save(args.json, force=args.force)}")
    if args.figure:
        from granseg.plot import save_figure
        from granseg.plot.velocity import velocity_profile

        print("wrote " + ", ".join(str(f) for f in save_figure(velocity_profile(prof), args.figure, force=args.force)))
    if args.preview:
        for path in _previews(recs, Path(args.preview), args.force):
            print(f"wrote {path}")
    return 0


def _previews(recs, out: Path, force: bool) -> list[Path]:
    """Each recording's first frame, undistorted, with its tracks."""
    from granseg.measure.camera import Undistorter
    from granseg.measure.sources import open_frames
    from granseg.plot import save_figure
    from granseg.plot.velocity import tracks_on_frame

    out.mkdir(parents=True, exist_ok=True)
    written = []
    for r in recs:
        exp = r.detected.experiment
        source, _ = open_frames(r.source)
        # a directory decodes on demand; a video gives its frames in order
        image = source.read(0) if hasattr(source, "read") else next(img for _, img in source.frames())
        h, w = image.shape[:2]
        flat = Undistorter(exp.camera_matrix, exp.dist_coeffs, (w, h), (0, 0, w, h))(image)
        first = int(r.tracks[:, 0].min())
        fig = tracks_on_frame(flat, r.tracks, exp.window, frame=first)
        written += save_figure(fig, out / f"tracks_{Path(r.source).name}", force=force)
    return written


def run_law(args: argparse.Namespace) -> int:
    import numpy as np

    from granseg._io import save_json
    from granseg.fit import fit_shear_band_law
    from granseg.velocity import load_profile

    files = sorted(Path(args.directory).glob("*.json"))
    if not files:
        raise FileNotFoundError(f"{args.directory}: no velocity JSON files")
    profs = [load_profile(f) for f in files]
    missing = [str(f) for f, p in zip(files, profs, strict=True) if p.M_tilde is None]
    if missing:
        raise ValueError(f"{', '.join(missing)}: 'conditions' must give M_g and M_w (the bed's load)")
    m = np.array([p.M_tilde for p in profs])
    d = np.array([p.delta_over_H for p in profs])
    e = np.array([p.fit.stderr["delta_over_H"] for p in profs])
    law = fit_shear_band_law(m, d, e)
    for f, p, mi in zip(files, profs, m, strict=True):
        print(f"  {f.name}: M~ = {mi:.3f}, delta/H = {p.delta_over_H:.4f} +- {p.fit.stderr['delta_over_H']:.4f}")
    lp, le = law.params, law.stderr
    print(f"delta/H = ({lp['delta_over_H_ref']:.4f} +- {le['delta_over_H_ref']:.4f}) x (M~/0.5)^"
          f"-({lp['exponent']:.3f} +- {le['exponent']:.3f}) over {len(files)} beds")
    if args.json:
        out = {"law": "delta/H = delta_over_H_ref * (M_tilde / 0.5)^(-exponent)", **law.to_dict(),
               "beds": [{"file": f.name, "M_tilde": float(mi), "delta_over_H": float(di), "stderr": float(ei)}
                        for f, mi, di, ei in zip(files, m, d, e, strict=True)]}
        print(f"wrote {save_json(args.json, json.loads(json.dumps(out, default=float)), force=args.force)}")
    if args.figure:
        from granseg.plot import save_figure
        from granseg.plot.velocity import shear_band_law

        fig = shear_band_law(m, d, e, law, labels=[f.stem for f in files])
        print("wrote " + ", ".join(str(f) for f in save_figure(fig, args.figure, force=args.force)))
    return 0
