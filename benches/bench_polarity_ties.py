"""A band whose polarity ties, made to tip: does the choice of templates still find each material? (issue 9)

Each material's polarity is learned from its band of the stratified first
frame, as the sign whose seeds show the larger contrast
(``detect._contrasts``); transparent glass shows nearly the same contrast
either way, and once tipped to bright beside bright ceramic (the packing at
seed offset 300). Where the two contrasts tie (``detect.POLARITY_TIE``),
both polarities are tried, and a set of templates resting on the weaker one
is kept only if it balances the bands' spheres per row better by
``detect.TIE_BALANCE`` (``detect._choose_templates``).

For every look of the folders, the first frame is learned twice: as
``analyze`` learns it (``now``), and with the band nearer a tie (relative
gap below 0.3) made to tip (``tipped``: its two contrasts swapped and set
1 % apart, as glass's were at offset 300). Each line gives the bands'
relative gaps (the stronger contrast less the weaker, over the sum of their
sizes), the signs kept, the first frame's recall per class (true centres
with a sphere found within 0.3 D; heavy / light), and, where sets were
compared, each set's
packing (``detect._packing``) and spheres-per-row ratio
(``detect._band_imbalance``): one polarity first, then each material's own.
Last, the rim a set's spheres show where it differs from one polarity's:
in each band whose sign it gives differently, the median rim score
(``detect._examine``) of the candidates of that sign it finds there, against
one polarity's candidates there: where they differ by ``detect.RIM_CLEAR``
or more, the sharper set is kept (``detect._kept``; ``--rim-clear inf``
leaves the choice to balance and packing, as before the rims decided).
With ``--maps``, every tipped look whose first frame then misses a class
(recall below 0.9) is analysed with the same tip: the map's recall, counts
and c_raw RMSD, and whether ``analyze``'s quality checks flag it.

::

    PYTHONPATH=python python benches/bench_polarity_ties.py --dirs /tmp/pbr-tune /tmp/pbr-hold tests/fixtures/pbr \
        /tmp/pbr-300 /tmp/pbr-400 /tmp/pbr-500 /tmp/pbr-600 /tmp/pbr-700 /tmp/pbr-800 /tmp/pbr-900 \
        /tmp/pbr-sg500 /tmp/pbr-sg600 --maps --json benches/results/polarity_ties.json

(the folders from ``python -m granseg.synth.pbr fixtures FOLDER --looks ... --seed-offset N --no-verify``).
"""

from __future__ import annotations

import argparse
import sys
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial import cKDTree

from granseg._io import save_json
from granseg.measure import detect
from granseg.measure.experiment import load_experiment
from granseg.measure.pipeline import _FrameWorker
from granseg.synth.pbr import load_fixture

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_pbr_looks import measure  # noqa: E402

NEAR_TIE = 0.3  # a band this close to a tie (relative gap) may be made to tip
MISSED = 0.9  # a first frame finding less of a class than this (recall) went wrong: --maps analyses it


def _relative_gap(ranked: list) -> float:
    """The stronger contrast less the weaker over the sum of their sizes (inf with fewer than two polarities)."""
    if len(ranked) < 2:
        return float("inf")
    return (ranked[0][0] - ranked[1][0]) / (abs(ranked[0][0]) + abs(ranked[1][0]))


def _tip(ranked: list) -> list:
    """The two polarities swapped, their contrasts 1 % of their mean apart (a tie tipped the other way)."""
    (_, sign, seeds), (_, other, others) = ranked
    mean = 0.5 * (ranked[0][0] + ranked[1][0])
    return [(mean + 0.005 * abs(mean), other, others), (mean - 0.005 * abs(mean), sign, seeds)]


@contextmanager
def _patched(tip_band: int | None) -> Iterator[dict]:
    """While inside, the detector's learning records each band's relative gap, each set's packing and
    spheres-per-row ratio (yielded), with band ``tip_band``'s two contrasts tipped, if given."""
    contrasts, packing, imbalance = detect._contrasts, detect._packing, detect._band_imbalance
    band_spheres = detect._band_spheres
    seen = {"gaps": [], "packing": [], "ratio": [], "rims": []}

    def spy_contrasts(image, candidates, d):
        ranked = contrasts(image, candidates, d)
        band = len(seen["gaps"]) - 1  # the frame's own call comes first, then one per band
        seen["gaps"].append(_relative_gap(ranked))
        return _tip(ranked) if band == tip_band and len(ranked) == 2 else ranked

    def spy_band_spheres(image, templates, bands):
        spheres, rims = band_spheres(image, templates, bands)
        seen["rims"].append({"signs": templates.signs.tolist(), "rim": rims})  # a set's signs, its rims by band
        return spheres, rims

    def spy_packing(spheres, d):
        seen["packing"].append(packing(spheres, d))
        return seen["packing"][-1]

    def spy_imbalance(spheres, bands):
        seen["ratio"].append(float(np.exp(imbalance(spheres, bands))))
        return np.log(seen["ratio"][-1])

    detect._contrasts, detect._packing, detect._band_imbalance = spy_contrasts, spy_packing, spy_imbalance
    detect._band_spheres = spy_band_spheres
    try:
        yield seen
    finally:
        detect._contrasts, detect._packing, detect._band_imbalance = contrasts, packing, imbalance
        detect._band_spheres = band_spheres


def _rim_where_differing(rims: list[dict]) -> list[list]:
    """Per set after the first (one polarity) with two groups: [band, one's median rim there, the
    set's] for each band whose sign the set gives differently from one polarity's."""
    if not rims:
        return []
    one = rims[0]["signs"][0]
    out = []
    for r in rims[1:]:
        if len(r["signs"]) != 2:
            continue
        out.append([[k, rims[0]["rim"][k].get(one, float("nan")), r["rim"][k].get(r["signs"][k], float("nan"))]
                    for k in (0, 1) if r["signs"][k] != one])
    return out


def learn(look: Path, tip_band: int | None) -> dict:
    """Learn the look's first frame (band ``tip_band`` tipped, if given); what was seen and kept."""
    truth = load_fixture(look)
    exp = load_experiment(look / "experiment.json")
    image = cv2.imread(str(sorted(look.glob("frame_0000.*"))[0]))
    with _patched(tip_band) as seen, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        worker = _FrameWorker(exp, (image.shape[1], image.shape[0]))
        worker.learn(image)
        first = worker("frame_0000", image)[0]
    rows = truth.particles[0]
    found = np.column_stack([first.x, first.y])
    recall = []
    for heavy in (1, 0):
        true = rows[(rows[:, 4] > 0) & (rows[:, 3] == heavy)]
        dist, _ = cKDTree(found).query(true[:, :2])
        recall.append(float(np.mean(dist < 0.3 * exp.particle_diameter_px)))
    return {"band_gaps": seen["gaps"][1:3], "signs": worker.templates.signs.tolist(), "recall": recall,
            "packing": seen["packing"], "ratio": seen["ratio"], "rim_where_differing": _rim_where_differing(seen["rims"])}


def the_map(look: Path, tip_band: int | None) -> dict:
    """The map ``analyze`` makes of the look (band ``tip_band`` tipped, if given): window counts and
    c_raw RMSD against the truth, and its quality verdict (``bench_pbr_looks.measure``)."""
    with _patched(tip_band):
        r = measure(look.parent, look.name, [])
    return {k: r[k] for k in ("recall", "rmsd", "frame_layer_count_error", "quality_ok", "failed_checks")}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--dirs", type=Path, nargs="+", required=True, help="folders of rendered looks")
    ap.add_argument("--looks", nargs="+", default=["ceramic-glass", "glass-pom", "glass-pp", "steel-glass"])
    ap.add_argument("--maps", action="store_true",
                    help="also analyse every tipped look whose first frame missed a class (recall < 0.9): "
                         "the map's figures and whether its quality checks flag it")
    ap.add_argument("--rim-clear", type=float, default=detect.RIM_CLEAR,
                    help="how much sharper [log] a set's rims must be to decide (detect.RIM_CLEAR; inf: never)")
    ap.add_argument("--json", type=Path, default=None, help="also write the figures here")
    args = ap.parse_args()
    detect.RIM_CLEAR = args.rim_clear
    results = {}
    for folder in args.dirs:
        for name in args.looks:
            look = folder / name
            if not (look / "truth.npz").is_file():
                continue
            now = learn(look, None)
            gaps = now["band_gaps"]
            nearer = int(np.argmin(gaps))
            tipped = learn(look, nearer) if gaps[nearer] < NEAR_TIE else None
            results[str(look)] = {"now": now, "tipped": tipped, "tipped_band": nearer if tipped else None}
            for mode, r in (("now", now), ("tipped", tipped)):
                if r is None:
                    continue
                print(f"{str(look):34s} {mode:6s} gaps {' '.join(f'{g:.3f}' for g in r['band_gaps'])} -> signs "
                      f"{r['signs']} recall {r['recall'][0]:.2f} / {r['recall'][1]:.2f}  packing "
                      f"{' '.join(f'{p:.3f}' for p in r['packing'])}  spheres per row "
                      f"{' '.join(f'{x:.3f}' for x in r['ratio'])}  rim where a set differs (band: one / set) "
                      f"{' ; '.join(', '.join(f'{k}: {a:.2f} / {b:.2f}' for k, a, b in d) for d in r['rim_where_differing'])}",
                      flush=True)
            if args.maps and tipped is not None and min(tipped["recall"]) < MISSED:
                m = results[str(look)]["tipped_map"] = the_map(look, nearer)
                print(f"{str(look):34s} tipped map: recall {m['recall']:.3f}, c_raw RMSD {m['rmsd']:.3f}, counts "
                      f"{100 * m['frame_layer_count_error']:.1f} %, "
                      f"{'ok' if m['quality_ok'] else 'flagged: ' + ', '.join(m['failed_checks'])}", flush=True)
    if args.json is not None:
        save_json(args.json, {"command": " ".join(sys.argv), "polarity_tie": detect.POLARITY_TIE,
                              "tie_balance": detect.TIE_BALANCE, "rim_clear": detect.RIM_CLEAR,
                              "results": results}, force=True)


if __name__ == "__main__":
    main()
