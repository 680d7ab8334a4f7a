"""A view that moves during the run, is turned, or a lid that rises: `view_steady`, `window_level`, `bed_steady`.

`window_lines` reads the walls in the first frame only. A camera knocked (or a
cell that shifts) halfway through a run moves every later frame against the
window, and the map's later rows are binned by lines off the walls. This bench
renders 2-D scenes, analyses each run as rendered (the check's figure where
nothing moved: its false alarms), then with the second half of its frames moved
down (or up) by each of ``--moves`` pixels (the check's figure, its verdict, the
other checks that fail, and the moved rows' layer counts and c_raw against the
truth of the frames as rendered, which the window was drawn for):

    PYTHONPATH=python python benches/bench_view_move.py --scenes S-PP-75 bumps-S-PP --seeds 7 8 \\
        --frames 24 --moves 1.5 3 -3 6 [--turns 0.5 1 -1] [--json benches/results/view_move.json]

``--follow`` also counts each run as rendered, moved or risen in windows that
follow the walls (``analyze(..., follow_walls=True)``), scored the same way.
``--turns`` also analyses the run with every frame turned by each angle [deg,
counter-clockwise] about the image's centre: a camera that is not level (the
`window_level` check; counts and c_raw then over every row). ``--rises`` [px]
raises the lid in the second half of the frames, the bed stretched evenly above
the plate (a bed that dilates under shear: the `bed_steady` check). The frames
are altered by :mod:`granseg.synth.mishaps`, as the tests alter theirs.

Moves are applied to frames saved as stills; scenes rendered as video are read
as rendered only. No truth is read by `analyze`; the truth only scores the map.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np

from granseg._io import save_json
from granseg.measure import analyze
from granseg.synth.mishaps import move_view, raise_lid, turn_view
from granseg.synth.scenes import render_scene, scene_names


def _read(source, truth, rows: slice, judged: str = "view_steady", follow: bool = False) -> dict:
    a = _analyze(source)
    checks = {c.name: c for c in a.quality.checks}
    check = checks.get(judged)
    figures = {name: None if checks.get(name) is None else round(checks[name].value, 4)
               for name in ("view_steady", "window_level", "bed_steady")}
    out = {**figures, judged: None if check is None else round(check.value, 4),
           "flagged": bool(check is not None and not check.passed),
           "other_failed": [c.name for c in a.quality.failed if c.name != judged], **_scored(a, truth, rows)}
    if follow:  # the same frames counted in windows that follow the walls
        f = _analyze(source, follow_walls=True)
        out["followed"] = {"view_followed_d": round(f.quality.figures["view_followed_d"], 4),
                           "bed_followed_d": round(f.quality.figures["bed_followed_d"], 4),
                           "failed": [c.name for c in f.quality.failed], **_scored(f, truth, rows)}
    return out


def _analyze(source, **options):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return analyze(source, save=False, progress=False, **options)


def _scored(a, truth, rows: slice) -> dict:
    """The map's layer counts and c_raw over ``rows`` against the truth of the frames as rendered."""
    n, n_true = a.n[rows], truth.n[rows]
    return {"counts_moved_rows": round(float(np.nanmean(np.abs(n - n_true) / np.maximum(n_true, 1))), 4),
            "c_raw_rmsd_moved_rows": round(float(np.sqrt(np.nanmean((a.c_raw[rows] - truth.c_raw[rows]) ** 2))), 4)}


def run(scene: str, seed: int, frames: int, moves: list[float], turns: list[float], work: Path,
        rises: list[float] = (), follow: bool = False) -> dict:
    base = work / f"{scene}-{seed}"
    truth = render_scene(scene, frames, seed=seed, out_dir=base)
    rows = slice(frames // 2, frames)
    out = {"as rendered": _read(truth.source, truth, rows, follow=follow)}
    d = float(truth.experiment["particle_diameter_px"])
    if Path(truth.source).is_dir():
        for dy in moves:
            moved = work / f"{scene}-{seed}-moved"
            shutil.rmtree(moved, ignore_errors=True)
            shutil.copytree(base, moved)
            move_view(moved, dy, first=frames // 2)
            out[f"moved {dy:+g} px ({dy / d:+.3f} d)"] = _read(moved, truth, rows, follow=follow)
        for dy in rises:
            risen = work / f"{scene}-{seed}-risen"
            shutil.rmtree(risen, ignore_errors=True)
            shutil.copytree(base, risen)
            raise_lid(risen, dy, truth.experiment["window"], first=frames // 2)
            out[f"lid up {dy:g} px ({dy / d:.3f} d)"] = _read(risen, truth, rows, judged="bed_steady", follow=follow)
        for deg in turns:
            turned = work / f"{scene}-{seed}-turned"
            shutil.rmtree(turned, ignore_errors=True)
            shutil.copytree(base, turned)
            turn_view(turned, deg)
            out[f"turned {deg:+g} deg"] = _read(turned, truth, slice(0, frames), judged="window_level")
    shutil.rmtree(base, ignore_errors=True)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", nargs="+", default=["S-PP-75"], help="2-D scenes, or 'all'")
    ap.add_argument("--seeds", nargs="+", type=int, default=[7])
    ap.add_argument("--frames", type=int, default=24)
    ap.add_argument("--moves", nargs="*", type=float, default=[1.5, 3.0, -3.0, 6.0],
                    help="vertical moves [px, down positive] of the second half of the frames")
    ap.add_argument("--turns", nargs="*", type=float, default=[],
                    help="angles [deg, counter-clockwise] every frame is turned by, each in turn")
    ap.add_argument("--rises", nargs="*", type=float, default=[],
                    help="how far [px] the lid rises in the second half of the frames, the bed dilating evenly")
    ap.add_argument("--follow", action="store_true",
                    help="also count each run as rendered, moved or risen with analyze's follow_walls")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    scenes = scene_names() if args.scenes == ["all"] else args.scenes
    results: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        for scene in scenes:
            for seed in args.seeds:
                r = run(scene, seed, args.frames, args.moves, args.turns, Path(tmp), args.rises, args.follow)
                results[f"{scene} seed {seed}"] = r
                for name, v in r.items():
                    judged = ("window_level" if name.startswith("turned") else
                              "bed_steady" if name.startswith("lid up") else "view_steady")
                    level = "".join(f" {k} {v[k]}" for k in ("view_steady", "window_level", "bed_steady")
                                    if k != judged)
                    print(f"{scene:34s} {seed:3d} {name:26s} {judged} {v[judged]}"
                          f"{' FLAGGED' if v['flagged'] else ''}{level}  rows judged: counts {100 * v['counts_moved_rows']:.1f} %"
                          f" c_raw {v['c_raw_rmsd_moved_rows']:.3f}  other failed {v['other_failed']}", flush=True)
                    if "followed" in v:
                        f = v["followed"]
                        print(f"{'':34s} {'':3s} {'followed':26s} view {f['view_followed_d']} bed {f['bed_followed_d']}"
                              f"  rows judged: counts {100 * f['counts_moved_rows']:.1f} % c_raw "
                              f"{f['c_raw_rmsd_moved_rows']:.3f}  failed {f['failed']}", flush=True)
    as_rendered = [r["as rendered"]["view_steady"] for r in results.values() if r["as rendered"]["view_steady"] is not None]
    if as_rendered:
        print(f"as rendered: largest view_steady {max(as_rendered):.4f} over {len(as_rendered)} runs; "
              f"flagged {sum(r['as rendered']['flagged'] for r in results.values())}")
    levels = [r["as rendered"]["window_level"] for r in results.values() if r["as rendered"]["window_level"] is not None]
    if levels:
        print(f"as rendered: largest window_level {max(levels):.4f} over {len(levels)} runs; flagged "
              f"{sum('window_level' in r['as rendered']['other_failed'] for r in results.values())}")
    beds = [r["as rendered"]["bed_steady"] for r in results.values() if r["as rendered"]["bed_steady"] is not None]
    if beds:
        print(f"as rendered: largest bed_steady {max(beds):.4f} over {len(beds)} runs; flagged "
              f"{sum('bed_steady' in r['as rendered']['other_failed'] for r in results.values())}")
    if args.json:
        save_json(args.json, {"command": " ".join(sys.argv), "frames": args.frames,
                              "moves_px": args.moves, "turns_deg": args.turns, "rises_px": args.rises, "results": results}, force=True)


if __name__ == "__main__":
    main()
