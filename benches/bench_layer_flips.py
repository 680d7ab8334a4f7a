"""Why spheres on layer boundaries are counted one layer off: bias or scatter?

    PYTHONPATH=python python benches/bench_layer_flips.py --scenes apparatus-S-POM-25-mp4v \
        apparatus-S-PP-75-jpeg apparatus-C-PP-50-h264 --seeds 7 8

For each run of the 2-D renderer's scenes the spheres found are matched to
the truth (within 0.3 D) and their height error dh [D] (measured minus true,
up positive) is split:

- the mean over the run, and per class: a shift that is the same for every
  sphere of a kind (the shading of its lower side);
- within a sphere (its scatter from frame to frame: the renderer's spheres
  that do not move are seen again in every frame) and between spheres (the
  spread of their means: what a sphere's neighbours and its place do to it).

and the classes' relative shift read from touching pairs and taken off by
the pipeline (``class_shift_px``, :func:`granseg.measure.outline.class_shift`)
is set beside the truth's (light minus heavy, before it was taken off).

The per-frame layer count error (mean |n - n_true| / n_true) is given
as measured, with the classes' shift put back (as it was before
``pipeline._level_classes``), and as it would be if the error were smaller, each by an oracle
that reads the truth (so none of them can be used, they only say which part
of the error matters): every centre moved by the run's mean dh; by its
class's mean dh; every centre's height averaged with its matches in the
neighbouring frames (within 0.1 D, up to ``--window`` frames either way),
which cuts the scatter from frame to frame and keeps the rest.

Last, without truth: the scatter of the still spheres' heights from frame to
frame [px] and the count error it alone would cause (each sphere's normal
chance of crossing its layer's boundaries; :func:`_predicted_count_error`),
set beside the count error found, to see whether a run could tell its own.
``--pbr FOLDER --looks ...`` gives those two and the count error found for
physically based looks (``python -m granseg.synth.pbr fixtures FOLDER``;
their frames are new packings, so the other columns do not apply)::

    PYTHONPATH=python python benches/bench_layer_flips.py --pbr /tmp/pbr-tune --looks ceramic-pom pom-pp

``--variants`` renders every scene once per named set of render settings
(as in ``bench_measure_accuracy.py``), the same packing each time: e.g. a
lossy-video scene with its video switched off tells the codec's share of
the error from the look's::

    PYTHONPATH=python python benches/bench_layer_flips.py --scenes apparatus-S-POM-25-mp4v \
        apparatus-C-PP-50-h264 --seeds 7 8 \
        --variants '{"as-rendered": {}, "lossless": {"video": null}}'
"""

from __future__ import annotations

import argparse
import itertools
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree
from scipy.stats import foldnorm, norm

from granseg.measure import analyze
from granseg.measure.layers import height, in_window
from granseg.synth.pbr import load_fixture
from granseg.synth.scenes import render_scene

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_measure_accuracy import _variants, frame_count_error, recount  # noqa: E402


def _still_links(spheres, d: float) -> list[np.ndarray]:
    """Per pair of neighbouring frames, each sphere's match in the next frame if it lies within 0.1 D
    (it stood still), else -1."""
    ahead = []
    for s0, s1 in zip(spheres[:-1], spheres[1:], strict=True):
        dist, j = cKDTree(np.column_stack([s1.x, s1.y])).query(np.column_stack([s0.x, s0.y]))
        ahead.append(np.where(dist < 0.1 * d, j, -1))
    return ahead


def _predicted_count_error(spheres, window, d: float, n_layers: int = 15) -> tuple[float, float]:
    """What the counts' error would be if the centres' only error were their scatter from frame to
    frame (no truth read): sigma [px], the robust sd of the still spheres' height steps over sqrt 2,
    and the mean over layers and frames of E|n - n_true| / n, each sphere leaving its layer for the
    next with the normal chance of an error reaching that boundary (a sum of independent flips,
    taken as normal)."""
    steps = [s1.y[j[j >= 0]] - s0.y[j >= 0] for s0, s1, j in zip(spheres[:-1], spheres[1:], _still_links(spheres, d),
                                                                   strict=True)]
    dy = np.concatenate(steps)
    sigma = 1.4826 * float(np.median(np.abs(dy - np.median(dy)))) / np.sqrt(2)
    layer_px = (window[3] - window[1]) / n_layers
    errors = []
    for s in spheres:
        h = height(s.y[in_window(s.x, s.y, window)], window, n_layers)
        j = np.clip(np.floor(h).astype(int), 0, n_layers - 1)
        up = norm.sf((j + 1 - h) * layer_px / sigma) * (j < n_layers - 1)
        down = norm.sf((h - j) * layer_px / sigma) * (j > 0)
        per_layer = lambda w, j=j: np.bincount(j, w, minlength=n_layers)  # noqa: E731
        n = per_layer(None)
        # a layer's count loses its leavers and gains its neighbours' arrivals: mean and variance
        net = -per_layer(up + down) + np.r_[0, per_layer(up)[:-1]] + np.r_[per_layer(down)[1:], 0]
        var = (per_layer((up + down) * (1 - up - down)) + np.r_[0, per_layer(up * (1 - up))[:-1]]
               + np.r_[per_layer(down * (1 - down))[1:], 0])
        expected = foldnorm.mean(np.abs(net) / np.sqrt(var + 1e-12), scale=np.sqrt(var + 1e-12))  # E|change|
        errors.append(expected[n > 0] / n[n > 0])
    return sigma, float(np.mean(np.concatenate(errors)))


def _time_averaged(spheres, d: float, k: int) -> list[np.ndarray]:
    """Each sphere's y averaged with its still matches (< 0.1 D apart) up to k frames either way."""
    n_t = len(spheres)
    ahead = _still_links(spheres, d)
    behind = []
    for i, a in enumerate(ahead):
        b = np.full(len(spheres[i + 1].x), -1)
        ok = a >= 0
        b[a[ok]] = np.nonzero(ok)[0]
        behind.append(b)
    out = []
    for i, s in enumerate(spheres):
        total, count = s.y.copy(), np.ones(len(s.y))
        for links, step in ((ahead, 1), (behind, -1)):
            idx = np.arange(len(s.y))
            for m in range(1, k + 1):
                t = i + step * m
                if not 0 <= t < n_t:
                    break
                table = links[t - 1] if step == 1 else links[t]
                idx = np.where(idx >= 0, table[np.maximum(idx, 0)], -1)
                ok = idx >= 0
                total[ok] += spheres[t].y[idx[ok]]
                count[ok] += 1
        out.append(total / count)
    return out


def one_run(scene: str, seed: int, window: int, changes: dict | None = None) -> dict:
    with tempfile.TemporaryDirectory() as tmp, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = render_scene(scene, 6, seed=seed, out_dir=tmp, **(changes or {}))
        a = analyze(r.source, smooth=1, save=False, progress=False, workers=2)
    win, d = r.experiment["window"], r.experiment["particle_diameter_px"]
    p0 = r.particles[0]
    by_sphere = np.full((len(p0), len(r.particles)), np.nan)  # dh of each still truth sphere, per frame
    dh_all, dh_heavy, dh_light = [], [], []
    for i, (s, p) in enumerate(zip(a.spheres, r.particles, strict=True)):
        dist, k = cKDTree(p[:, :2]).query(np.column_stack([s.x, s.y]))
        ok = (dist < 0.3 * d) & (p[k, 4] > 0)
        dh = height(s.y[ok], win) - height(p[k[ok], 1], win)
        dh_all.append(dh)
        dh_heavy.append(dh[s.heavy[ok]])
        dh_light.append(dh[~s.heavy[ok]])
        gap, j0 = cKDTree(p0[:, :2]).query(p[k[ok], :2])
        still = gap < 0.05 * d  # the same sphere, not moved since the first frame
        by_sphere[j0[still], i] = dh[still]
    dh = np.concatenate(dh_all)
    mean_h, mean_l = float(np.concatenate(dh_heavy).mean()), float(np.concatenate(dh_light).mean())
    seen = np.isfinite(by_sphere).all(axis=1)
    table = by_sphere[seen]
    per_layer = win[3] - win[1]
    shift = lambda s, v: s.y + v * per_layer / 15  # noqa: E731  (height lowered by v D: y grows downward)
    taken = a.quality.figures["class_shift_px"] / (per_layer / 15)  # [D], light found higher than heavy
    return {
        "scene": scene, "seed": seed,
        "dh_mean": float(dh.mean()), "dh_heavy": mean_h, "dh_light": mean_l,
        "within_sphere_sd": float((table - table.mean(axis=1, keepdims=True)).std()),
        "between_sphere_sd": float(table.mean(axis=1).std()),
        "shift_read": float(taken), "shift_true": mean_l - mean_h + float(taken),
        "count": frame_count_error(a.n, r.n),
        "count_shift_put_back": frame_count_error(recount(
            a.spheres, [shift(s, np.where(s.heavy, 0.5, -0.5) * taken) for s in a.spheres], win), r.n),
        "count_run_mean_removed": frame_count_error(recount(a.spheres, [shift(s, dh.mean()) for s in a.spheres], win), r.n),
        "count_class_mean_removed": frame_count_error(recount(
            a.spheres, [shift(s, np.where(s.heavy, mean_h, mean_l)) for s in a.spheres], win), r.n),
        "count_time_averaged": frame_count_error(recount(a.spheres, _time_averaged(a.spheres, d, window), win), r.n),
        **dict(zip(("scatter_px", "count_predicted"), _predicted_count_error(a.spheres, win, d), strict=True)),
    }


def pbr_run(folder: Path, look: str) -> dict:
    """The truth-free scatter, the count error it predicts and the count error found, of one
    physically based look."""
    truth = load_fixture(folder / look)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        a = analyze(folder / look, smooth=1, save=False, progress=False, workers=2)
    window, d = a.experiment.window, a.experiment.particle_diameter_px
    sigma, predicted = _predicted_count_error(a.spheres, window, d, truth.n.shape[1])
    return {"look": look, "scatter_px": sigma, "count_predicted": predicted, "count": frame_count_error(a.n, truth.n)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", nargs="+", default=[])
    ap.add_argument("--pbr", type=Path, help="a folder of physically based looks (with --looks)")
    ap.add_argument("--looks", nargs="+", default=[])
    ap.add_argument("--seeds", nargs="+", type=int, default=[7, 8])
    ap.add_argument("--window", type=int, default=2, help="frames either way averaged by the time oracle")
    ap.add_argument("--variants", type=_variants, default={"": {}}, metavar="JSON",
                    help="render every scene once per variant: a JSON object {name: {setting: value}} "
                         "(or a .json file holding one)")
    args = ap.parse_args()
    if not args.scenes and not (args.pbr and args.looks):
        ap.error("give --scenes, or --pbr FOLDER with --looks")
    for look in args.looks if args.pbr else []:
        o = pbr_run(args.pbr, look)
        print(f"{look:20s} scatter {o['scatter_px']:.2f} px  count predicted {o['count_predicted']:.3f}  "
              f"found {o['count']:.3f}", flush=True)
    if not args.scenes:
        return
    print("scene                                        seed  dh [D]: run  heavy  light | sd within between |"
          " shift [D]: read  true | count: as is  shift put back  run-mean  class-mean  time-avg |"
          " scatter [px], count predicted from it")
    for scene in args.scenes:
        for (variant, changes), seed in itertools.product(args.variants.items(), args.seeds):
            o = one_run(scene, seed, args.window, changes)
            name = f"{scene}+{variant}" if variant else scene
            print(f"{name:44s} {seed:4d}  {o['dh_mean']:+.4f} {o['dh_heavy']:+.4f} {o['dh_light']:+.4f} | "
                  f"{o['within_sphere_sd']:.4f} {o['between_sphere_sd']:.4f} | "
                  f"{o['shift_read']:+.4f} {o['shift_true']:+.4f} | {o['count']:.3f}  {o['count_shift_put_back']:.3f}  "
                  f"{o['count_run_mean_removed']:.3f}  {o['count_class_mean_removed']:.3f}  "
                  f"{o['count_time_averaged']:.3f} | {o['scatter_px']:.2f} {o['count_predicted']:.3f}", flush=True)


if __name__ == "__main__":
    main()
