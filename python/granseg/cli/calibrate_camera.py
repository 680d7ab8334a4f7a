"""``granseg calibrate-camera DIR``: checkerboard photos -> camera model for experiment.json."""

from __future__ import annotations

import argparse
from pathlib import Path


def _pattern(text: str) -> tuple[int, int]:
    try:
        cols, rows = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected COLSxROWS inner corners, e.g. 9x6, got {text!r}") from None
    if cols < 2 or rows < 2:
        raise argparse.ArgumentTypeError(f"need at least 2x2 inner corners, got {text!r}")
    return cols, rows


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``calibrate-camera`` command."""
    p = subparsers.add_parser(
        "calibrate-camera", help="camera matrix and distortion from checkerboard photos",
        description="Find the checkerboard in every image of DIR (cv2.findChessboardCorners), "
        "calibrate (cv2.calibrateCamera) and write camera_matrix and dist_coeffs as JSON, "
        "ready to paste into experiment.json.")
    p.add_argument("directory", metavar="DIR", help="directory of checkerboard photos")
    p.add_argument("--pattern", type=_pattern, default=(9, 6), help="inner corners COLSxROWS (default 9x6)")
    p.add_argument("--out", metavar="FILE", help="JSON file to write (default DIR/camera.json)")
    p.add_argument("--force", action="store_true", help="overwrite an existing output file")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Calibrate, write the JSON and report the reprojection error."""
    from granseg._io import save_json
    from granseg.measure import calibrate_camera

    out = Path(args.out) if args.out else Path(args.directory) / "camera.json"
    from granseg._io import check_writable

    check_writable(out, args.force)
    result = calibrate_camera(args.directory, pattern=args.pattern)
    save_json(out, result, force=args.force)
    print(f"{len(result['images_used'])} images used, {len(result['images_skipped'])} skipped")
    print(f"reprojection error: {result['reprojection_error_px']:.3f} px (RMS)")
    print(f"camera model written to {out}")
    return 0
