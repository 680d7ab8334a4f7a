"""``granseg analyze`` on physically based looks, look by look, and which polarities it chose (issue 9).

For every look of a folder rendered by ``python -m granseg.synth.pbr fixtures
FOLDER`` (the committed fixtures by default): recall of the spheres in the
window (a truth sphere with a detection within 0.4 D), c_raw RMSD and per-frame
layer counts (mean over frames and layers of |n - n_true| / n_true) against
the truth, the share of the spheres found in the wrong class, the ``centres_settled``, ``vacancies``,
``window_lines`` and ``ambiguous_spheres`` figures and the quality verdict. With
``--polarities`` also what the detector's learning saw in the first frame: the
polarity of each band of the stratified start, and, where they differ, how
well the spheres found by each set of templates pack (one polarity, each
material's own, each material learned from the other's matches: the worse
band's median nearest-neighbour distance [d]), whether a borrowed set was
kept, and otherwise the two bands' spheres per row with one polarity and with
each material's own (the richer band's over the other's) and which of those
two the criterion prefers (:func:`granseg.measure.detect.learn_templates`). A
band whose two polarities' contrasts tie is searched in both
(``band_polarities_tried``); then each material's own is one set per pair
of differing band polarities.
``--choice one`` / ``each`` keeps one polarity / each material's own wherever
the bands' polarities differ, whatever the criteria say: the maps of the
choice not taken; ``--choice no-borrowed`` never keeps a borrowed set (the
detector before it could).

    PYTHONPATH=python python benches/bench_pbr_looks.py [--dir FOLDER] [--looks glass-pom ...] \\
        [--polarities] [--choice auto|one|each|no-borrowed] [--smeared auto|always|never] [--json FILE]

The folders: ``tests/fixtures/pbr`` (the fixtures, judged on); the tuning
family (``--seed-offset 100``, developed on); a held-out family
(``--seed-offset 200``, rendered once to check a decision made on the tuning
family, then left alone).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np

import granseg.measure.detect as detect
from granseg._io import save_json
from granseg.measure import analyze
from granseg.synth.pbr import load_fixture

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_measure_accuracy import (  # noqa: E402
    _as_given,
    _blur_figures,
    _or_nan,
    force_light_field,
    force_smeared,
)

PBR = Path(__file__).resolve().parents[1] / "tests" / "fixtures" / "pbr"


def _spy_on_learning(choice: str = "auto") -> list[dict]:
    """Record what learn_templates decides: band polarities, each set's packing and the band
    imbalance, and which set ``detect._kept`` prefers; with ``choice`` "one" or "each" force that set
    to be kept where the bands' polarities differ, with "no-borrowed" never keep a borrowed set."""
    seen: list[dict] = []
    polarity, polarities = detect._polarity, detect._band_polarities
    imbalance, packing, kept = detect._band_imbalance, detect._packing, detect._kept
    if choice != "auto":
        detect.PACKED_NN = np.inf  # a borrowed set never wins

    def band_polarity(image, candidates, d):
        sign, seeds = polarity(image, candidates, d)
        seen.append({"polarity": sign})
        return sign, seeds

    def band_polarities(image, candidates, d):
        options = polarities(image, candidates, d)
        seen.append({"polarity": options[0][0] if options else 1, "tried": [s for s, _ in options]})
        return options

    def band_packing(spheres, d):
        value = packing(spheres, d)
        seen.append({"packing": value})
        return value

    def band_imbalance(spheres, bands):
        value = imbalance(spheres, bands)
        seen.append({"ratio": float(np.exp(value))})
        return value

    def kept_set(imbalances, packings, guessed, sharper):
        value = kept(imbalances, packings, guessed, sharper)
        seen.append({"kept": value})  # what the criterion prefers, even where a choice is forced
        return {"one": 0, "each": 1}.get(choice, value)

    detect._polarity, detect._band_polarities = band_polarity, band_polarities
    detect._band_imbalance, detect._packing, detect._kept = band_imbalance, band_packing, kept_set
    return seen


def measure(folder: Path, look: str, seen: list[dict], diameter_given: float = 1.0, pinhole: bool = False) -> dict:
    """The figures of one look, analysed with particle_diameter_px ``diameter_given`` times its own and,
    with ``pinhole``, granseg init's camera model for none instead of the lens's."""
    truth = load_fixture(folder / look)
    seen.clear()
    with warnings.catch_warnings(), tempfile.TemporaryDirectory() as tmp:
        warnings.simplefilter("ignore")
        source = folder / look
        if diameter_given != 1.0 or pinhole:  # a copy, the fixture left as it is
            source = Path(shutil.copytree(source, Path(tmp) / look))
            _as_given(source / "experiment.json", json.loads((source / "experiment.json").read_text()),
                      diameter_given, truth.images[0].shape[1::-1] if pinhole else None)
        a = analyze(source, smooth=1, save=False, progress=False, workers=2)
    d = truth.experiment["particle_diameter_px"]  # the true one, whatever diameter was given
    found = total = wrong = 0
    for i, s in enumerate(a.spheres):
        p = truth.particles[i]
        p = p[p[:, 4] > 0]
        if s is None or len(p) == 0:
            total += len(p)
            continue
        dist = np.hypot(*(p[:, None, :2] - np.column_stack([s.x, s.y])[None]).transpose(2, 0, 1))
        hit = dist.min(axis=1) < 0.4 * d
        found += int(hit.sum())
        total += len(p)
        wrong += int((s.heavy[dist.argmin(axis=1)[hit]] != (p[hit, 3] > 0)).sum())
    checks = {c.name: c for c in a.quality.checks}
    out = {"recall": found / max(total, 1), "wrong_class": wrong / max(found, 1),
           "rmsd": float(np.sqrt(np.nanmean((a.c_raw - truth.c_raw) ** 2))),
           "frame_layer_count_error": float(np.mean(np.abs(a.n - truth.n)[truth.n > 0] / truth.n[truth.n > 0])),
           "centres_settled": float(checks["centres_settled"].value) if "centres_settled" in checks else None,
           "vacancies": float(checks["vacancies"].value) if "vacancies" in checks else None,
           "window_lines": float(checks["window_lines"].value) if "window_lines" in checks else None,
           "ambiguous_spheres": float(checks["ambiguous_spheres"].value) if "ambiguous_spheres" in checks else None,
           "sphere_spacing_d": a.quality.figures.get("sphere_spacing_d"),
           "spacing_across_view": a.quality.figures.get("spacing_across_view"),
           "quality_ok": bool(a.quality.ok), "failed_checks": [c.name for c in a.quality.failed],
           **_blur_figures(a)}
    # the whole frame's polarity comes first, then one per band (learn_templates' order)
    bands = [e for e in seen if "polarity" in e][1:3]
    ratios = [e["ratio"] for e in seen if "ratio" in e]
    packing = [e["packing"] for e in seen if "packing" in e]
    out["band_polarities"] = [e["polarity"] for e in bands]
    tried = [e.get("tried", []) for e in bands]
    if any(len(t) > 1 for t in tried):  # a band whose two contrasts tie: both its polarities were tried
        out["band_polarities_tried"] = tried
    # one set of each its own polarity per pair of differing band polarities
    n_each = sum(a != b for a in tried[0] for b in tried[1]) if len(tried) == 2 else 0
    if packing:  # one polarity, each its own, then the borrowed sets (band 0's material, band 1's)
        each = packing[1:1 + n_each]
        out["packing"] = {"one": packing[0], "each_its_own": each[0] if n_each == 1 else each,
                          "borrowed": packing[1 + n_each:]}
        out["borrowed_kept"] = detect._lent(packing, 1 + n_each) is not None
    kept = [e["kept"] for e in seen if "kept" in e]
    if kept:
        out["spheres_per_row_ratio"] = {"one": ratios[0], "each_its_own": ratios[1] if n_each == 1 else ratios[1:]}
        out["criterion_prefers"] = "one" if kept[0] == 0 else "each its own" + (f" #{kept[0]}" if n_each > 1 else "")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--dir", type=Path, default=PBR, help="folder of rendered looks (default: the fixtures)")
    ap.add_argument("--looks", nargs="+", default=None, help="looks to measure (default: every one)")
    ap.add_argument("--polarities", action="store_true", help="also report the polarities learned")
    ap.add_argument("--choice", choices=("auto", "one", "each", "no-borrowed"), default="auto",
                    help="force the set of templates kept where the bands' polarities differ, or keep no "
                         "borrowed set (implies --polarities)")
    ap.add_argument("--smeared", choices=("auto", "always", "never"), default="auto",
                    help="keep the classes learned with smeared copies: as the blur test says, always, never")
    ap.add_argument("--no-light-field", action="store_true",
                    help="classes from the features as measured, the light over the view left on them")
    ap.add_argument("--diameter-given", type=float, default=1.0, metavar="F",
                    help="analyse each look with particle_diameter_px given F times its own (a copy of the look)")
    ap.add_argument("--pinhole", action="store_true",
                    help="analyse each look with granseg init's camera model for none (no lens taken off)")
    ap.add_argument("--json", type=Path, default=None, help="also write the figures here")
    args = ap.parse_args()
    force_smeared(args.smeared)
    force_light_field(not args.no_light_field)
    looks = args.looks or sorted(p.name for p in args.dir.iterdir() if (p / "truth.npz").is_file())
    args.polarities |= args.choice != "auto"
    seen = _spy_on_learning(args.choice) if args.polarities else []
    results = {}
    for look in looks:
        r = results[look] = measure(args.dir, look, seen, args.diameter_given, args.pinhole)
        settled = "-" if r["centres_settled"] is None else f"{r['centres_settled']:.2f}"
        vacant = "-" if r["vacancies"] is None else f"{r['vacancies']:.3f}"
        lines = "-" if r["window_lines"] is None else f"{r['window_lines']:.3f}"
        unsure = "-" if r["ambiguous_spheres"] is None else f"{r['ambiguous_spheres']:.3f}"
        line = (f"{look:18s} recall {r['recall']:.3f}  c_raw RMSD {r['rmsd']:.3f}  per-frame layer counts "
                f"{100 * r['frame_layer_count_error']:4.1f} %  wrong class {100 * r['wrong_class']:.1f} %  "
                f"centres_settled {settled}  vacancies {vacant}  window_lines {lines}  ambiguous {unsure}  "
                f"spacing {_or_nan(r['sphere_spacing_d']):.3f} d, far over near {_or_nan(r['spacing_across_view']):.3f}  "
                f"{'ok' if r['quality_ok'] else 'flagged: ' + ', '.join(r['failed_checks'])}  smeared classes "
                f"{'kept' if r['classes_learned_smeared'] else 'not kept'} "
                f"({r['blur_disagreements_near_plate']}/{r['blur_disagreements']} near the plate), gloss "
                f"{'at learned spots' if r['gloss_at_learned_spots'] else 'by maxima'}, light share "
                f"{_or_nan(r['light_share_of_class_gap']):.2f}"
                f"{' (taken off)' if r['light_over_view'] is not None else ''}")
        if args.polarities:
            line += f"  | bands {r['band_polarities']}"
            if "packing" in r:
                pk = r["packing"]
                each = np.atleast_1d(pk["each_its_own"])
                line += (f", packing {pk['one']:.3f} / {' '.join(f'{v:.3f}' for v in each)} / "
                         f"{' '.join(f'{v:.3f}' for v in pk['borrowed'])}, borrowed "
                         f"{'kept' if r['borrowed_kept'] else 'not kept'}")
            if "criterion_prefers" in r:
                ratio = r["spheres_per_row_ratio"]
                each = np.atleast_1d(ratio["each_its_own"])
                line += (f", spheres per row {ratio['one']:.3f} / {' '.join(f'{v:.3f}' for v in each)}, the criterion "
                         f"prefers: {r['criterion_prefers']}")
        print(line, flush=True)
    if args.json is not None:
        save_json(args.json, {"command": " ".join(sys.argv), "dir": str(args.dir), "choice": args.choice,
                              "smeared": args.smeared, "diameter_given": args.diameter_given,
                              "pinhole": args.pinhole,
                              "results": results}, force=True)


if __name__ == "__main__":
    main()
