"""The ``window_lines`` check (issue 9): a window whose lid or plate line is moved by a known amount.

A user reads the window off a ruled preview by hand, so its lines can miss the
lid and the plate by a few pixels. For every 2-D scene and seed (rendered with
:func:`granseg.synth.scenes.render_scene`) and every physically based look in
the ``--pbr`` folders, ``granseg analyze`` runs on the window as rendered, then
on the window with its lid line (y0) or its plate line (y1) moved by each of
``--shifts`` diameters out of the bed and into it. Per case: what the check
reads at each wall (``quality.wall_lines``: where the spheres resting on it lie,
less half a diameter; positive: the line lies outside the bed), its verdict,
every failed check, and what the move costs the map against the truth of the
window as rendered (c_raw RMSD, per-frame layer count error). The summary:
false flags of the windows as rendered, and per size of move how many were
flagged and how many of those were read in the wrong direction.

    PYTHONPATH=python python benches/bench_window_lines.py --scenes S-POM-25 POM-PP-50 --seeds 7 8 \\
        [--pbr FOLDER ...] [--shifts 0.1 0.15 0.2] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import warnings
from collections import Counter
from pathlib import Path

import numpy as np

from granseg._io import save_json
from granseg.measure import analyze
from granseg.synth.scenes import render_scene, scene_names


def moves(shifts: list[float]) -> dict[str, tuple[str, float]]:
    """Name -> (line, move [d], positive = out of the bed) of every case; "as rendered" first."""
    out = {"as rendered": ("", 0.0)}
    for k in shifts:
        for line in ("lid", "plate"):
            out[f"{line} out {k:g}"] = (line, k)
            out[f"{line} in {k:g}"] = (line, -k)
    return out


def measure(source: Path, truth_n: np.ndarray, truth_c: np.ndarray, shifts: list[float]) -> dict[str, dict]:
    """Every case of one rendered run: ``source`` its frames directory or video (its
    experiment.json, beside it, rewritten in place and restored after)."""
    exp_path = (source if source.is_dir() else source.parent) / "experiment.json"
    original = exp_path.read_text(encoding="utf-8")
    exp = json.loads(original)
    d = float(exp["particle_diameter_px"])
    out = {}
    try:
        for name, (line, k) in moves(shifts).items():
            w = list(exp["window"])
            if line == "lid":
                w[1] -= k * d  # out of the bed: up
            elif line == "plate":
                w[3] += k * d  # out of the bed: down
            exp_path.write_text(json.dumps({**exp, "window": w}), encoding="utf-8")
            out[name] = _case(source, truth_n, truth_c)
    finally:
        exp_path.write_text(original, encoding="utf-8")
    return out


def _case(source: Path, truth_n: np.ndarray, truth_c: np.ndarray) -> dict:
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            a = analyze(source, smooth=1, save=False, progress=False, workers=2)
    except ValueError as exc:  # e.g. a line moved so far that the first frame is not stratified
        return {"error": str(exc)[-160:]}
    walls = a.quality.figures["window_lines_d"]  # what the check read (quality.wall_lines)
    check = next((c for c in a.quality.checks if c.name == "window_lines"), None)
    ok = truth_n > 0
    return {**{k: float("nan") if v is None else round(v, 4) for k, v in walls.items()},
            "flagged": check is not None and not check.passed,
            "failed_checks": [c.name for c in a.quality.failed],
            "rmsd": round(float(np.sqrt(np.nanmean((a.c_raw - truth_c) ** 2))), 4),
            "frame_layer_count_error": round(float(np.mean(np.abs(a.n - truth_n)[ok] / truth_n[ok])), 4)}


def summary(results: dict[str, dict[str, dict]]) -> list[str]:
    false, plain = 0, 0
    flagged, total, wrong = Counter(), Counter(), Counter()
    for cases in results.values():
        for name, c in cases.items():
            if "error" in c:
                continue
            if name == "as rendered":
                plain += 1
                false += c["flagged"]
                continue
            line, way, size = name.split()
            total[size] += 1
            if c["flagged"]:
                flagged[size] += 1
                wrong[size] += (c[line] > 0) != (way == "out")
    lines = [f"windows as rendered: {false} of {plain} flagged"]
    lines += [f"one line moved {s} d: {flagged[s]} of {total[s]} flagged, {wrong[s]} of them read in the wrong "
              f"direction" for s in sorted(total, key=float)]
    return lines


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenes", nargs="*", default=[], choices=[*scene_names(), "all"])
    p.add_argument("--seeds", nargs="*", type=int, default=[7, 8])
    p.add_argument("--pbr", nargs="*", type=Path, default=[], help="folders of physically based looks")
    p.add_argument("--shifts", nargs="*", type=float, default=[0.1, 0.15, 0.2])
    p.add_argument("--frames", type=int, default=6)
    p.add_argument("--json", type=Path)
    args = p.parse_args()
    scenes = scene_names() if "all" in args.scenes else args.scenes
    results: dict[str, dict[str, dict]] = {}
    runs = [(sc, seed) for sc in scenes for seed in args.seeds]
    looks = [look for folder in args.pbr for look in sorted(folder.iterdir()) if (look / "truth.npz").is_file()]
    done = 0
    for sc, seed in runs:
        with tempfile.TemporaryDirectory() as tmp:
            r = render_scene(sc, args.frames, seed=seed, out_dir=Path(tmp))
            results[f"{sc} {seed}"] = measure(Path(r.source), r.n, r.c_raw, args.shifts)
        done += 1
        print(f"[{done}/{len(runs) + len(looks)}] {sc} seed {seed}", flush=True)
    if looks:
        from granseg.synth.pbr import load_fixture
    for look in looks:
        truth = load_fixture(look)
        with tempfile.TemporaryDirectory() as tmp:  # the committed fixtures are never rewritten
            copy = Path(tmp) / look.name
            shutil.copytree(look, copy)
            results[f"{look.parent.name}/{look.name}"] = measure(copy, truth.n, truth.c_raw, args.shifts)
        done += 1
        print(f"[{done}/{len(runs) + len(looks)}] {look}", flush=True)
    for name, cases in results.items():
        for case, c in cases.items():
            print(f"{name:38s} {case:16s} " + (c["error"] if "error" in c else
                  f"plate {c['plate']:+.3f} lid {c['lid']:+.3f} {'FLAGGED' if c['flagged'] else 'ok     '} "
                  f"RMSD {c['rmsd']:.3f} counts {c['frame_layer_count_error']:.3f} {','.join(c['failed_checks'])}"))
    lines = summary(results)
    print("\n".join(lines))
    if args.json:
        save_json(args.json, {"command": " ".join(sys.argv), "summary": lines, "results": results}, force=True)


if __name__ == "__main__":
    main()
