"""Model selection: leave-one-experiment-out comparison and a significance rule calibrated on null data.

Every candidate (and the baseline) predicts each experiment with parameters
fitted on the *other* experiments (:func:`granseg.fitting.loo_predict`).
Its held-out gain is the mean over experiments of (baseline held-out RMSD -
candidate held-out RMSD) [-]; positive is better.

The verdict:

* the best candidate is **significant** when its held-out gain exceeds
  ``GAIN_THRESHOLD`` x the noise floor;
* a significant candidate is the cause; ``explained`` is true when its
  in-sample mean RMSD is within ``EXCESS_THRESHOLD`` x the noise floor;
* with no significant candidate the verdict is ``none`` when the baseline's
  mean RMSD is within ``EXCESS_THRESHOLD`` x the noise floor, else
  ``unexplained`` (a misfit beyond noise that no candidate removes).

Calibration of the two thresholds (``benches/calibrate_diagnose.py``, results
in ``benches/results/diagnose_null_calibration.json``): baseline-only
campaigns of the paper's 16 conditions with independent noise seeds were
diagnosed with the thresholds switched off; The largest best-candidate held-out gain
seen was 0.0013 x floor (a nested candidate cannot gain much held out when
there is nothing to find) and the largest baseline RMSD / floor 1.009 (the
floor estimate is good to a few per cent). GAIN_THRESHOLD = max(0.02, 10 x
the largest null gain) and EXCESS_THRESHOLD = 1.05 x the largest null ratio,
rounded: no null campaign of the calibration set comes near either. The false-alarm rate on fresh seeds is reported by the slow suite
(``benches/bench_diagnose_matrix.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["EXCESS_THRESHOLD", "GAIN_THRESHOLD", "Verdict", "decide"]

#: Minimum held-out gain of the best candidate, in units of the noise floor.
GAIN_THRESHOLD = 0.02
#: Largest mean RMSD / noise floor still counted as "within the noise".
EXCESS_THRESHOLD = 1.06


@dataclass(frozen=True)
class Verdict:
    """The decision: ``cause`` (catalogue name, ``none`` or ``unexplained``),
    ``explained``, the best candidate, its gain in floor units, the margin to the
    runner-up [-], and the reasons in words."""

    cause: str
    explained: bool
    best: str | None
    gain_ratio: float
    excess_ratio: float
    runner_up: str | None
    margin: float
    reason: str


def decide(held_out_gain: dict[str, float], noise_floor: float, baseline_rmsd_mean: float,
           extended_rmsd_mean: dict[str, float], *, gain_threshold: float = GAIN_THRESHOLD,
           excess_threshold: float = EXCESS_THRESHOLD) -> Verdict:
    """Name the cause from held-out gains [-], the noise floor [-] and mean RMSDs [-]."""
    if not held_out_gain:
        raise ValueError("decide: no candidate was fitted")
    order = sorted(held_out_gain, key=held_out_gain.get, reverse=True)
    best = order[0]
    runner = order[1] if len(order) > 1 else None
    floor = max(noise_floor, 1e-9)
    ratio = held_out_gain[best] / floor
    margin = held_out_gain[best] - (held_out_gain[runner] if runner else 0.0)
    excess = baseline_rmsd_mean / floor
    if ratio > gain_threshold:
        explained = extended_rmsd_mean[best] / floor <= excess_threshold
        reason = (f"{best} lowers the held-out RMSD by {held_out_gain[best]:.4f} "
                  f"({ratio:.2f} x noise floor > threshold {gain_threshold:.2f})")
        return Verdict(best, bool(explained), best, ratio, excess, runner, margin, reason)
    if excess <= excess_threshold:
        reason = (f"baseline mean RMSD is {excess:.2f} x the noise floor (<= {excess_threshold:.2f}) "
                  f"and no candidate gains beyond {gain_threshold:.2f} x floor held out")
        return Verdict("none", True, best, ratio, excess, runner, margin, reason)
    reason = (f"baseline mean RMSD is {excess:.2f} x the noise floor (> {excess_threshold:.2f}) "
              f"but the best candidate ({best}) gains only {ratio:.2f} x floor held out")
    return Verdict("unexplained", False, best, ratio, excess, runner, margin, reason)


def held_out_gain(baseline_ho: np.ndarray, candidate_ho: np.ndarray) -> float:
    """Mean over experiments of baseline minus candidate held-out RMSD [-]."""
    return float(np.mean(np.asarray(baseline_ho) - np.asarray(candidate_ho)))
