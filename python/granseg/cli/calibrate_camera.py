"""``granseg calibrate-camera DIR``: checkerboard photos -> camera model for experiment.json."""

from __future__ import annotations

import argparse
from pathlib import Path

# as granseg.measure.camera.MAX_PATTERN (not imported here: the parser is built without OpenCV)
MAX_PATTERN = 100


def _pattern(text: str) -> tuple[int, int]:
    try:
        cols, rows = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected COLSxROWS inner corners, e.g. 9x6, got {text!r}") from None
    if not (2 <= cols <= MAX_PATTERN and 2 <= rows <= MAX_PATTERN):
        raise argparse.ArgumentTypeError(
            f"COLS and ROWS of inner corners must each be between 2 and {MAX_PATTERN}, got {text!r}")
    return cols, rows


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``calibrate-camera`` command."""
    p = subparsers.add_parser(
        "calibrate-camera", help="camera matrix and distortion from checkerboard photos",
        description="Find the checkerboard in every image of DIR (cv2.findChessboardCorners), "
        "calibrate (cv2.calibrateCamera) and write camera_matrix and dist_coeffs as JSON, "
        "ready to paste into experiment.json.")
    p.add_argument("directory", metavar="DIR", help="directory of checkerboard photos")
    p.add_argument("--pattern", type=_pattern, default=(9, 6),
                   help=f"inner corners COLSxROWS, each 2 to {MAX_PATTERN} (default 9x6)")
    p.add_argument("--out", metavar="FILE", help="JSON file to write (default DIR/camera.json)")
    p.add_argument("--force", action="store_true", help="overwrite an existing output file")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Calibrate, write the JSON and report the reprojection error and standard errors."""
    from granseg._io import check_writable, save_json
    from granseg.measure.camera import calibrate_camera, checkerboard_dir

    directory = checkerboard_dir(args.directory)  # the input first: a missing DIR is named as such
    out = Path(args.out) if args.out else directory / "camera.json"
    check_writable(out, args.force)
    result = calibrate_camera(directory, pattern=args.pattern)
    save_json(out, result, force=args.force)
    print(f"{len(result['images_used'])} images used, {len(result['images_skipped'])} skipped")
    print(f"reprojection error: {result['reprojection_error_px']:.3f} px (RMS)")
    k, se = result["camera_matrix"], result["stderr"]
    print("standard errors: " + ", ".join(
        f"{name} = {value:.1f} ± {'?' if se.get(name) is None else format(se[name], '.2f')} px"
        for name, value in (("fx", k[0][0]), ("fy", k[1][1]), ("cx", k[0][2]), ("cy", k[1][2]))))
    print(f"board tilts span {result['tilt_span_deg']:.1f}°")
    print(f"camera model written to {out}")
    return 0
