"""``analyze`` on several packings of each physically based look, and two trees compared packing by packing (issue 9).

One packing of a look holds about a hundred spheres a frame, so a change of
the detector that moves a handful of them moves the map's figures by about
as much as the change itself does: on 2026-11-29 one rule gained on every
tuning packing and lost on half of the unseen ones (BENCHMARKS.md, "One
sphere per place kept by the sharpness of its rim"). This bench measures
every look in several folders of packings (each from the fixtures command
with its own seed offset) with ``bench_glass_own_symmetry.measure`` (the map
``analyze`` makes: window counts and c_raw RMSD, and both averaged over
twenty layer grids shifted through a layer), and prints each look's mean and
spread over the packings. ``--compare`` reads two such files (say, a tree
and its parent) and says, look by look, by how much the second differs and
on how many packings it is better.

::

    python -m granseg.synth.pbr fixtures /tmp/pbr-300 --looks glass-pp,glass-pom,ceramic-glass \
        --seed-offset 300 --no-verify      # and 400, ...: packings no change was tuned on
    PYTHONPATH=python python benches/bench_pbr_packings.py --dirs /tmp/pbr-300 /tmp/pbr-400 \
        --looks glass-pp glass-pom ceramic-glass --json /tmp/before.json
    # ... change the detector, run it again with --json /tmp/after.json, then
    PYTHONPATH=python python benches/bench_pbr_packings.py --compare /tmp/before.json /tmp/after.json
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from granseg._io import save_json

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_glass_own_symmetry import measure  # noqa: E402

FIGURES = (("grid_counts", 100, ".2f", " %"), ("grid_rmsd", 1, ".4f", ""), ("counts", 100, ".2f", " %"), ("rmsd", 1, ".4f", ""))


def measure_all(dirs: list[Path], looks: list[str]) -> dict[str, dict[str, dict]]:
    """{look: {folder: figures}} for every look found in every folder (a counted log line each)."""
    jobs = [(look, folder) for look in looks for folder in dirs if (folder / look / "truth.npz").exists()]
    missing = [f"{folder}/{look}" for look in looks for folder in dirs if not (folder / look / "truth.npz").exists()]
    if missing:
        print("not rendered, skipped: " + ", ".join(missing), flush=True)
    results: dict[str, dict[str, dict]] = {}
    for i, (look, folder) in enumerate(jobs, 1):
        results.setdefault(look, {})[str(folder)] = measure(folder / look, own=True)
        print(f"[{i}/{len(jobs)}] {look} in {folder}", flush=True)
    return results


def summary(results: dict[str, dict[str, dict]]) -> None:
    """Each look's mean (and sd over its packings) of every figure."""
    print(f"{'look':15s} packings | " + " | ".join(f"{k} (mean +- sd)" for k, *_ in FIGURES))
    for look, by_dir in results.items():
        cells = []
        for key, scale, fmt, unit in FIGURES:
            v = scale * np.array([f[key] for f in by_dir.values()])
            cells.append(f"{v.mean():{fmt}} +- {v.std(ddof=1) if len(v) > 1 else 0.0:{fmt}}{unit}")
        print(f"{look:15s} {len(by_dir):8d} | " + " | ".join(cells))


def compare(before: dict, after: dict) -> None:
    """Look by look, over the packings both files measured: the mean change of every figure and on how
    many packings the second file's is lower (better)."""
    print(f"{'look':15s} packings | " + " | ".join(f"{k}: mean change, better in" for k, *_ in FIGURES))
    for look in before:
        shared = sorted(set(before[look]) & set(after.get(look, {})))
        if not shared:
            continue
        cells = []
        for key, scale, fmt, unit in FIGURES:
            diff = scale * np.array([after[look][p][key] - before[look][p][key] for p in shared])
            cells.append(f"{diff.mean():+{fmt}}{unit}, {int((diff < 0).sum())} of {len(diff)}")
        print(f"{look:15s} {len(shared):8d} | " + " | ".join(cells))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--dirs", type=Path, nargs="+", help="folders of rendered looks, one packing of each per folder")
    ap.add_argument("--looks", nargs="+", default=["glass-pp", "glass-pom", "ceramic-glass"])
    ap.add_argument("--json", type=Path, help="also write the figures here")
    ap.add_argument("--compare", type=Path, nargs=2, metavar=("BEFORE", "AFTER"),
                    help="compare two files this bench wrote instead of measuring")
    args = ap.parse_args()
    if args.compare:
        before, after = (json.loads(p.read_text())["results"] for p in args.compare)
        compare(before, after)
        return
    if not args.dirs:
        ap.error("give --dirs (or --compare)")
    results = measure_all(args.dirs, args.looks)
    summary(results)
    if args.json:
        save_json(args.json, {"command": " ".join(sys.argv), "dirs": [str(d) for d in args.dirs],
                              "results": results}, force=True)


if __name__ == "__main__":
    main()
