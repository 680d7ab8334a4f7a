"""``granseg init-experiment PATH``: write experiment.json for a new recording."""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``init-experiment`` command."""
    p = subparsers.add_parser(
        "init-experiment", help="write experiment.json (annotated) for a frames folder or video",
        description="Write experiment.json beside the frames (or the video) from what is known: materials "
        "(densities from the model's table), c0, masses, frame rate, the camera model from "
        "`granseg calibrate-camera`, the window. Every field is explained in the file's _help; fields left "
        "null are listed. NAME_window.png, beside the frames folder or video, shows the first frame undistorted with a pixel ruler (and the "
        "window when given): read the window's corners off it and run again with --window and --force. "
        "Formats: docs/formats.md.")
    p.add_argument("path", metavar="PATH", help="frames directory, TIFF stack or video file")
    p.add_argument("--name", help="experiment name (default: the folder's or video's name)")
    p.add_argument("--heavy", metavar="MATERIAL", help="heavy material (glass, ceramic, POM, steel, PP, or any name "
                   "with --rho-h)")
    p.add_argument("--light", metavar="MATERIAL", help="light material")
    p.add_argument("--rho-h", type=float, metavar="KG_M3", help="heavy density (default: the material's)")
    p.add_argument("--rho-l", type=float, metavar="KG_M3", help="light density (default: the material's)")
    p.add_argument("--c0", type=float, help="heavy share of the bed by volume")
    p.add_argument("--M-g", dest="M_g", type=float, metavar="KG", help="mass of the grains in the cell")
    p.add_argument("--M-w", dest="M_w", type=float, metavar="KG", help="load on the lid")
    rate = p.add_mutually_exclusive_group()
    rate.add_argument("--fps", type=float, help="frames per second (a video's own rate is used by default)")
    rate.add_argument("--interval", type=float, metavar="S", help="seconds between stills (instead of --fps)")
    p.add_argument("--camera", metavar="CAMERA.json", help="the camera model granseg calibrate-camera wrote")
    p.add_argument("--window", metavar="X0,Y0,X1,Y1", help="investigation window in undistorted px (lid at Y0, "
                   "plate at Y1)")
    p.add_argument("--diameter-px", type=float, help="sphere diameter in undistorted px (default: window height / 15)")
    p.add_argument("--no-preview", action="store_true", help="do not write the window preview")
    p.add_argument("--force", action="store_true", help="replace an existing experiment.json")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from granseg.measure.init import init_experiment, preview_path

    window = None
    if args.window is not None:
        try:
            window = [float(v) for v in args.window.split(",")]
        except ValueError:
            raise ValueError(f"--window: expected X0,Y0,X1,Y1 numbers, got {args.window!r}") from None
    path, missing = init_experiment(
        args.path, name=args.name, heavy=args.heavy, light=args.light, rho_h=args.rho_h, rho_l=args.rho_l,
        c0=args.c0, M_g=args.M_g, M_w=args.M_w, fps=args.fps, interval=args.interval, camera=args.camera,
        window=window, particle_diameter_px=args.diameter_px, preview=not args.no_preview, force=args.force)
    print(f"wrote {path}")
    if not args.no_preview:
        print(f"wrote {preview_path(args.path)} (first frame undistorted, ruler every 50 px)")
    if missing:
        print(f"still to fill in before `granseg analyze`: {', '.join(missing)} (see _help in the file)")
    else:
        print(f"complete: granseg analyze {args.path} --out CAMPAIGN/")
    return 0
