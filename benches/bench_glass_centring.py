"""Which groups of spheres the outline fit holds, and where the unheld ones are placed (issue 9).

For the first frame of each look, per group of spheres (template): how many
were found, how much of a start displaced by a tenth of a diameter its
outline fit keeps (``detect._follows``: 0 comes back, 1 stays), how far from
its centres [d] its mean look is most symmetric left to right and top to
bottom (``detect._centre_of_symmetry``), how far its look turns across the view
(``detect._turn``, radii; both what ``detect._level`` reads from the groups
the fit holds), and the mean and sd of the centres' error against the
truth [px], with the last step of learning (``detect._symmetric_where_unheld``:
a group that keeps more than ``FOLLOWS`` is centred where its mean look is
symmetric, where the held groups show lamps on both sides, level, and each
of its spheres then moved up or down to where its own look is symmetric,
``detect._y_by_own_symmetry``) and without it::

    PYTHONPATH=python python benches/bench_glass_centring.py --pbr /tmp/pbr-tune --looks glass-pp glass-pom pom-pp
    PYTHONPATH=python python benches/bench_glass_centring.py --scenes all --seeds 7 8
    PYTHONPATH=python python benches/bench_glass_centring.py --scenes POM-PP-50 --seeds 7 8 \
        --changes '{"exposure": 0.6, "noise": 6.0, "blur": 1.5}'

Physically based looks come from ``python -m granseg.synth.pbr fixtures FOLDER``
(the fixtures by default); 2-D scenes are rendered (two frames, the first read).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial import cKDTree

import granseg.measure.detect as detect
from granseg.measure.experiment import load_experiment
from granseg.measure.pipeline import _FrameWorker
from granseg.measure.sources import open_frames
from granseg.synth.pbr import load_fixture
from granseg.synth.scenes import render_scene, scene_names

PBR = Path(__file__).resolve().parents[1] / "tests" / "fixtures" / "pbr"


def groups(image: np.ndarray, truth: np.ndarray, exp, step: bool) -> list[dict]:
    """Per group: spheres found in ``image``, _follows, the centre of symmetry of its mean look (x, y)
    [d], mean and sd of the error (x, y) [px]."""
    keep = detect.FOLLOWS
    detect.FOLLOWS = keep if step else np.inf
    try:
        worker = _FrameWorker(exp, (image.shape[1], image.shape[0]))
        worker.learn(image)
        crop = worker._crop(image)[0]
    finally:
        detect.FOLLOWS = keep
    t, d = worker.templates, exp.particle_diameter_px
    smooth = detect._smooth(crop, d, t.signs)
    found = detect.detect_particles(crop, d, t, details=True)
    found[:, 0] += worker.crop[0]
    found[:, 1] += worker.crop[1]
    out = []
    for g in range(len(t.patches)):
        mine = found[found[:, 4] == g]
        dist, j = cKDTree(truth[:, :2]).query(mine[:, :2])
        ok = dist < 0.3 * d
        err = mine[ok, :2] - truth[j[ok], :2]
        local = mine.copy()
        local[:, 0] -= worker.crop[0]
        local[:, 1] -= worker.crop[1]
        seen = smooth[int(t.signs[g])]
        follows = detect._follows(seen, local, t, g) if len(mine) >= 3 else float("nan")
        symmetric = [detect._centre_of_symmetry(seen, local[:, :2], t, axis) / d if len(mine) else float("nan")
                     for axis in (0, 1)]
        turn = detect._turn(detect._smooth(crop, d)[1], local[:, :2], t) if len(mine) else float("nan")
        out.append({"n": len(mine), "follows": follows, "symmetric": symmetric, "turn": turn,
                    "mean": err.mean(axis=0) if ok.any() else [float("nan")] * 2,
                    "sd": err.std(axis=0) if ok.any() else [float("nan")] * 2})
    return out


def report(name: str, image: np.ndarray, truth: np.ndarray, exp) -> None:
    for g, (off, on) in enumerate(zip(groups(image, truth, exp, False), groups(image, truth, exp, True),
                                      strict=True)):
        print(f"{name:40s} group {g}: {off['n']:3d} spheres, fit keeps {off['follows']:.2f} of a displaced start, "
              f"look symmetric about ({off['symmetric'][0]:+.3f}, {off['symmetric'][1]:+.3f}) d, "
              f"turns {off['turn']:+.2f} radii across the view; "
              f"error x, y mean ({off['mean'][0]:+.2f}, {off['mean'][1]:+.2f}) sd ({off['sd'][0]:.2f}, "
              f"{off['sd'][1]:.2f}) px -> with the step ({on['mean'][0]:+.2f}, {on['mean'][1]:+.2f}) "
              f"sd ({on['sd'][0]:.2f}, {on['sd'][1]:.2f})", flush=True)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pbr", type=Path, default=None, help="folder of physically based looks (default: fixtures)")
    ap.add_argument("--looks", nargs="+", default=[])
    ap.add_argument("--scenes", nargs="+", default=[], help="2-D scenes, or all")
    ap.add_argument("--seeds", nargs="+", type=int, default=[7, 8])
    ap.add_argument("--changes", type=json.loads, default={}, metavar="JSON",
                    help="render-setting changes for the 2-D scenes, as in bench_measure_accuracy.py --variants")
    args = ap.parse_args(argv)
    for look in args.looks:
        folder = (args.pbr or PBR) / look
        image = cv2.imread(str(sorted(folder.glob("frame_*"))[0]))
        report(look, image, load_fixture(folder).particles[0], load_experiment(folder / "experiment.json"))
    scenes = scene_names() if args.scenes == ["all"] else args.scenes
    for scene in scenes:
        for seed in args.seeds:
            with tempfile.TemporaryDirectory() as tmp:
                r = render_scene(scene, 2, seed=seed, out_dir=Path(tmp), **args.changes)
                source, exp_path = open_frames(r.source)
                image = source.read(0) if hasattr(source, "read") else None
                if image is None:
                    image = next(im for _, im in source.frames() if im is not None)
                report(f"{scene} seed {seed}", image, r.particles[0], load_experiment(exp_path))


if __name__ == "__main__":
    sys.exit(main())
