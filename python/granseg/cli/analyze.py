"""``granseg analyze PATH``: camera frames or a video -> concentration map (.npz)."""

from __future__ import annotations

import argparse
import warnings

# The light over the view, taken off, is said when its best-lit place is this
# many times as bright as its dimmest or more: a tenth, what the eye sees.
LIGHT_SAID = 1.1


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``analyze`` command."""
    p = subparsers.add_parser(
        "analyze", help="measure the concentration map from frames or a video",
        description="Undistort, detect and classify the spheres in every frame and write the "
        "heavy-concentration map (docs/formats.md). PATH is a directory of PNG/JPEG/TIFF frames holding "
        "experiment.json, or a video file with experiment.json beside it.")
    p.add_argument("path", metavar="PATH", help="frames directory, TIFF stack or video file")
    p.add_argument("--out", metavar="FILE|DIR/",
                   help="map file to write (default: map.npz beside experiment.json); a folder (existing, or "
                        "ending in /) gets NAME.npz after the experiment's name, so recordings analysed into "
                        "one folder make a campaign")
    smooth = p.add_mutually_exclusive_group()
    smooth.add_argument("--smooth-frames", "--smooth", dest="smooth", metavar="N", type=int, default=5,
                        help="centred moving average over N frames (odd; 1 = none; default 5). Frames, not "
                             "seconds: at one frame every 2 min, 5 frames span 10 min")
    smooth.add_argument("--smooth-seconds", metavar="S", type=float,
                        help="the same average over S seconds of recording (the odd frame count nearest "
                             "S x fps)")
    every = p.add_mutually_exclusive_group()
    every.add_argument("--every", metavar="N", type=int, default=1,
                       help="analyse every N-th frame, the first included (default 1: all); the map's rows are "
                            "then N frames apart, and --smooth-frames counts them")
    every.add_argument("--every-seconds", metavar="S", type=float,
                       help="the same as a time: one frame each S seconds of recording (the whole frame count "
                            "nearest S x fps)")
    p.add_argument("--preview", metavar="DIR", help="write annotated preview images to DIR")
    p.add_argument("--preview-count", metavar="K", type=int, default=6,
                   help="number of preview frames spread over the run (default 6)")
    p.add_argument("--detections", metavar="FILE.csv",
                   help="also write every sphere counted: frame, x, y (undistorted px), r (px), class, "
                        "p_heavy, layer")
    p.add_argument("--ends-unmixed", action="store_true",
                   help="the run ends un-mixed (a large density ratio: heavy below c0 H, light above): learn "
                        "the classes from its last frame too, so that a look changing with height is not "
                        "taken for the material")
    p.add_argument("--follow-walls", action="store_true",
                   help="count each frame in a window whose lines follow the walls: moved with the view where "
                        "the camera or cell moved during the run, and the lid line with the lid where the bed "
                        "rose or settled (what the view_steady and bed_steady checks read)")
    p.add_argument("--reduce", metavar="K", type=int,
                   help="analyse the frames reduced K times (each pixel the mean of a K x K block; 1 = as they "
                        "are). Default: the largest K that leaves the spheres at least 40 px across")
    p.add_argument("--strict", action="store_true",
                   help="exit with status 3 when the map fails a quality check (the map is still written)")
    p.add_argument("--workers", metavar="N", type=int, help="parallel workers (default: all cores)")
    p.add_argument("--force", action="store_true", help="overwrite existing output files")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the analysis, print a short summary and the quality report."""
    import sys

    from granseg.errors import QualityWarning
    from granseg.measure import BadFrameWarning, analyze

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", BadFrameWarning)
        warnings.simplefilter("ignore", QualityWarning)  # the report below says it, in full
        result = analyze(args.path, out=args.out, smooth=args.smooth, smooth_seconds=args.smooth_seconds,
                         every=args.every, every_seconds=args.every_seconds, preview=args.preview,
                         preview_count=args.preview_count, force=args.force,
                         workers=args.workers, progress=not args.no_progress, detections=args.detections,
                         ends_unmixed=args.ends_unmixed, reduce=args.reduce, follow_walls=args.follow_walls)
    for w in caught:
        print(f"warning: {w.message}")
    good = len(result.frame_names) - len(result.bad_frames)
    step = float(result.t[1] - result.t[0]) if len(result.t) > 1 else 0.0
    print(f"{len(result.frame_names)} frames, {good} analysed, {len(result.bad_frames)} bad frames")
    if result.first:
        print(f"the first {result.first} frames, filmed before the plate started (t0 < 0), left out")
    if result.every > 1:
        print(f"one frame in {result.every} analysed: the map's rows are {step:.4g} s apart")
    print(f"spheres per frame in the window: {result.n.sum(axis=1)[result.n.sum(axis=1) > 0].mean():.1f}")
    reduced = result.quality.figures.get("frames_reduced", 1)
    if reduced > 1:
        print(f"analysed in frames reduced {reduced} times (spheres "
              f"{result.experiment.particle_diameter_px / reduced:.0f} px across; --reduce 1: as they are)")
    bits = result.quality.figures.get("sample_bits")
    if bits is not None:
        print(f"16-bit frames whose samples are {bits} bits deep: read as their top 8 bits (docs/formats.md)")
    wall = result.quality.figures.get("wall_detections_per_frame", 0.0)
    if wall:
        print(f"left out as hemispheres of the lid or plate: {wall:.1f} per frame")
    glare = result.quality.figures.get("wall_glare_grey_levels", 0.0)
    if glare >= 10:
        print(f"lamp reflections on the wall taken off: up to {glare:.0f} grey levels")
    figures = result.quality.figures
    if figures.get("exposure_matched"):
        low, high = figures["exposure_gain_range"]
        print(f"camera exposure changed over the run: {low:.2f} to {high:.2f} times the first frame's; every "
              "frame was brought back to the first's (measure.exposure)")
    if figures.get("blur_disagreements"):  # the classes learned with and without smeared copies differ
        kept = ("also learned from smeared copies (motion blur not ruled out)" if figures["classes_learned_smeared"]
                else "learned from sharp spheres only (motion blur ruled out)")
        print(f"classes {kept}: of the {figures['blur_disagreements']} spheres the two sets of classes "
              f"class differently, {figures['blur_disagreements_near_plate']} lie within 3 diameters of the plate")
    if figures.get("light_over_view", 1.0) >= LIGHT_SAID:  # a lamp above or at the sides, vignetting
        print(f"uneven light over the view taken off before classifying: the best-lit place "
              f"{figures['light_over_view']:.2f} times as bright as the dimmest (classify.LightField)")
    if figures.get("classes_learned_from_the_end"):
        print("classes learned from the first frame and from the last (the run ends un-mixed)"
              + (", with each sphere's height" if result.classes.uses_height else ""))
    if figures.get("gloss_at_learned_spots"):  # the first frame showed a speck lighting a maximum
        print("gloss read where the first frame's glossy spheres show the lamps, not at each sphere's "
              "brightest point (it told the first frame's spheres apart better)")
    if figures.get("placed_by_template_match"):  # a material learned from the other's matches
        print(f"{100 * figures['placed_by_template_match']:.0f} % of the spheres placed where their template "
              "matches best, not by their outline (mirror-like spheres, whose rim reflects their neighbours); "
              "centres_settled still judges their outline fit")
    if figures.get("x_by_nominal_circle"):  # lamps at both sides light the spheres from the side
        print(f"{100 * figures['x_by_nominal_circle']:.0f} % of the spheres placed across the view by a circle "
              "of their nominal size: lamps at both sides light them from the side, and a circle free in size "
              "would follow the lit limb outward")
    if figures.get("y_by_own_symmetry"):  # a kind of sphere whose outline fit stays where it starts
        print(f"{100 * figures['y_by_own_symmetry']:.0f} % of the spheres placed up and down where their own "
              "look is symmetric: their outline gives the fit nothing to hold to (transparent spheres)")
    print(f"map written to {result.out} (smoothing: {result.smoothing_frames} frames = "
          f"{result.smoothing_frames * step:.4g} s of recording)")
    if result.detections is not None:
        print(f"detections written to {result.detections}")
    if result.previews:
        print(f"{len(result.previews)} preview images in {result.previews[0].parent}")
    print(result.quality.report())
    if not result.quality.ok:
        names = ", ".join(c.name for c in result.quality.failed)
        print(f"\n*** WARNING: this map failed {len(result.quality.failed)} quality check(s): {names}.\n"
              f"*** It may be wrong. Look at the preview"
              f"{' in ' + str(result.previews[0].parent) if result.previews else ''} before using it; "
              f"calibrate and diagnose refuse it unless given --accept-flagged.", file=sys.stderr)
        if args.strict:
            return 3
    return 0
