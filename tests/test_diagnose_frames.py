"""End to end through the frames (issue 11): virtual experiments -> camera frames -> analyze -> diagnose.

The maps the diagnosis gets here are not the model's: each virtual
experiment's exact wall view (``campaign(noise=None)``) is drawn as
side-wall camera frames (:func:`granseg.synth.render_frames`, in the looks of
the paper's mixtures the detector is tested on, ``MIXTURE_SCENES``) and
measured back by the frame pipeline (:func:`granseg.measure.analyze`). So
the maps carry what a measurement adds: whole spheres per layer (about nine
in a layer of the window: the renderer sets each layer's heavy share to the
nearest sphere), spheres missed, doubled or put in the neighbouring layer, and
spheres of one kind taken for the other. None of that is physics, and the
diagnosis must not call it a cause; a real cause hidden in the same
measurement must still be named.

Times are subsampled: N_FRAMES frames spread over each run (one every 0.5 to 5
minutes), analysed without smoothing (``smooth=1``: the campaign's 10 s
average is far shorter than a frame step). Frames are deleted once their map
is written.

What the verdicts rest on here: the counted noise floor is binomial (about
0.12), but a layer's heavy count in these frames is the nearest whole sphere,
not a binomial draw, so a perfect model's RMSD is about 0.03 and the
"beyond the counted noise" test cannot fire (RMSD / floor 0.25 on the null
campaign). The held-out gain and the coherence across experiments are what the
pipeline's errors must not trip.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from granseg.diagnosis import diagnose, selection
from granseg.measure import analyze
from granseg.synth import MIXTURE_SCENES, render_frames
from granseg.synth.virtual import campaign, random_conditions

N_FRAMES = 24  # per experiment (render + analysis: about 5 s per experiment on 2 cores)
# The null campaign needs at least 11 experiments for the coherence test to be able to fire at all:
# its sign-flip p-value cannot go below 2 / 2^n (a pattern and its negative give the same statistic),
# and 2 / 2^10 is above COHERENCE_ALPHA = 1e-3. With fewer, "none" would rest on the gain test alone.
N_NULL = 12
N_CAUSE = 8  # a strong cause is named on fewer (the verdict then rests on the held-out gain)

# The tested look of each material pair of the campaign (tests/test_measure_accuracy.py renders them all).
PAIR_SCENE = {("steel", "PP"): "S-PP-75", ("steel", "POM"): "S-POM-25", ("ceramic", "PP"): "C-PP-90",
              ("glass", "PP"): "G-PP-50", ("POM", "PP"): "POM-PP-50", ("glass", "POM"): "G-POM-50"}


def _look(heavy: str, light: str) -> dict:
    scene = MIXTURE_SCENES[PAIR_SCENE[(heavy, light)]]
    return {k: v for k, v in scene.items() if k not in ("c0", "experiment")}


def _measured_campaign(root: Path, n: int, seed: int, effect: str | None = None,
                       strength: float | None = None) -> tuple[Path, dict[str, float]]:
    """Render and analyse a virtual campaign; the maps directory and the pipeline's errors.

    Errors against the rendered truth, over every experiment: ``c_raw_rmsd`` the
    per-frame heavy share's RMSD, ``miscounted`` the share of (frame, layer)
    entries whose count or heavy count is wrong, ``truth_rmsd`` the map's RMSD
    against the exact wall view it was drawn from.
    """
    truth = campaign(conditions=random_conditions(n, seed), effect=effect, strength=strength, noise=None,
                     seed=seed)
    maps = root / "maps"
    maps.mkdir(parents=True)
    sq_raw, sq_truth, wrong, entries = [], [], 0, 0
    for i, m in enumerate(truth):
        step = max(1, (m.n_times - 1) // (N_FRAMES - 1))
        rows = np.arange(0, m.n_times, step)[:N_FRAMES]
        c = np.clip(m.c[rows], 0.0, 1.0)
        frames = root / "frames" / m.name
        r = render_frames(c, **_look(m.heavy, m.light), fps=m.fps / step, seed=100 * seed + i, out_dir=frames,
                          experiment={"name": m.name, "heavy": m.heavy, "light": m.light, "rho_h": m.rho_h,
                                      "rho_l": m.rho_l, "c0": m.c0, "M_g": m.M_g, "M_w": m.M_w})
        # a QualityWarning (a flagged map) would fail the test here: every map must pass its checks
        a = analyze(r.source, out=maps / f"{m.name}.npz", smooth=1, progress=False, workers=2)
        assert a.quality.ok, (m.name, a.quality.report())
        np.testing.assert_allclose(a.t, m.t[rows], rtol=1e-9, atol=1e-6)
        sq_raw.append((a.c_raw - r.c_raw)[np.isfinite(r.c_raw)] ** 2)
        sq_truth.append((a.c - c)[np.isfinite(a.c)] ** 2)
        wrong += int(np.sum((a.n != r.n) | (a.n_heavy != r.n_heavy)))
        entries += a.n.size
        shutil.rmtree(frames)
    errors = {"c_raw_rmsd": float(np.sqrt(np.mean(np.concatenate(sq_raw)))),
              "miscounted": wrong / entries,
              "truth_rmsd": float(np.sqrt(np.mean(np.concatenate(sq_truth))))}
    return maps, errors


def test_the_pipelines_own_errors_are_not_called_physics(tmp_path):
    assert 2.0 / 2.0**N_NULL < selection.COHERENCE_ALPHA  # the coherence test can fire (see N_NULL)
    maps, errors = _measured_campaign(tmp_path, N_NULL, seed=12)
    # the diagnosis does see measurement errors: the pipeline miscounts some layers of some frames
    # (seed 12: 7.5 % of the (frame, layer) counts wrong, c_raw RMSD 0.010 against the rendered counts,
    # map RMSD 0.030 against the wall view)
    assert errors["miscounted"] > 0.01 and errors["c_raw_rmsd"] > 0.003, errors
    assert errors["c_raw_rmsd"] <= 0.03, errors  # ... and works as tested (issue 9's target)
    r = diagnose(maps, progress=False).result
    assert r["decision"]["noise_floor_counted"] is True  # the analysed maps carry their counts
    # seed 12: best candidate gains 0.05 % held out (threshold 2 %); coherence p 0.12, share 6 %
    assert r["cause"] == "none", r["decision"]
    assert r["explained"] is True and r["extended"] is None
    # the pipeline's confusion of the two kinds, measured where the model says the bed is pure, is small
    conf = r["noise"]["confusion"]
    assert len(conf) >= 4 and all(v["share"] < 0.02 for v in conf.values()), conf


# Strong causes, well inside what a campaign resolves (each effect's draw_range).
SHEAR_BAND = ("load_dependent_shear_band", 0.6)  # the paper's finding (the demo hides 0.5); range 0.3-0.7
SPIN_UP = ("spin_up_delay", 180.0)  # [s]; range 60-240 s
CAUSES = [pytest.param(SHEAR_BAND, id="load_dependent_shear_band"),
          pytest.param(SPIN_UP, id="spin_up_delay", marks=pytest.mark.slow)]


@pytest.fixture(scope="module")
def hidden(request, tmp_path_factory):
    """(effect, pipeline errors, diagnosis JSON) of a campaign with ``request.param`` hidden, measured from frames."""
    effect, strength = request.param
    maps, errors = _measured_campaign(tmp_path_factory.mktemp(effect), N_CAUSE, seed=21, effect=effect,
                                      strength=strength)
    return effect, errors, diagnose(maps, progress=False).result


@pytest.mark.parametrize("hidden", CAUSES, indirect=True)
def test_a_cause_hidden_behind_the_pipeline_is_named(hidden):
    effect, errors, r = hidden
    assert errors["miscounted"] > 0.01 and errors["c_raw_rmsd"] <= 0.03, errors
    assert r["cause"] == effect, r["decision"]
    assert r["extended"]["model"] == effect
    assert r["gain"]["rmsd_held_out"] > 0, r["gain"]
    # seed 21: 76 % (shear band) and 51 % (spin-up) of the baseline's held-out RMSD
    assert r["decision"]["gain_relative"] > 5 * r["decision"]["gain_threshold"], r["decision"]


@pytest.mark.parametrize("hidden", [pytest.param(SHEAR_BAND, id="load_dependent_shear_band")], indirect=True)
def test_a_hidden_cause_is_not_measured_as_a_confusion_of_the_kinds(hidden):
    _, _, r = hidden
    conf = r["noise"]["confusion"]
    assert not any(v["applied"] for v in conf.values()), conf
