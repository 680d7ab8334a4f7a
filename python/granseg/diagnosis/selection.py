"""Model selection: held-out prediction, coherence across experiments, and a noise model kept honest.

Every candidate (and the baseline) predicts each experiment with parameters
fitted on the *other* experiments (:func:`granseg.fitting.loo_predict`).

Two questions decide the verdict, and neither hangs on one absolute noise
number alone:

1. **Does a candidate predict better?** Its relative held-out gain, mean over
   experiments of (baseline - candidate held-out RMSD) over the baseline's
   mean held-out RMSD, must exceed ``GAIN_THRESHOLD``. A relative gain needs
   no noise model: on data with nothing to find a nested candidate gains
   nothing held out, however the noise is made.
2. **Is a misfit left, beyond the measurement's noise?** A model's misfit is
   called structured when either test says so:

   * **coherent across experiments** (:func:`coherence`): the residual maps,
     binned in normalised time and depth, are regressed on the covariates
     (1, log M~, log delta_R, c0) and the statistic is the residual energy
     the regression explains; a model error shows up as a pattern
     shared by experiments or changing with a covariate, measurement noise
     - however persistent within one run - is independent between runs. The
     p-value comes from flipping the sign of whole experiments' residuals
     (valid for any noise correlation inside an experiment), with the
     directions the fitted parameters can produce projected out (their own
     fitting error is shared by every experiment). Structured when p <
     ``COHERENCE_ALPHA`` *and* the shared patterns hold more than
     ``COHERENCE_SHARE`` of the residual energy beyond chance: with 16
     experiments the test also finds patterns too small to matter, such as
     the lag that grains staying in view for minutes leave in a map;
   * **beyond the counted noise**: the mean RMSD over the noise floor of
     :mod:`granseg.diagnosis.noise` exceeds ``EXCESS_THRESHOLD``. Only when
     the maps carry their counts: the floor then models persistence with each
     layer's measured decorrelation. Without counts it is a lower bound and
     this test is not used (the verdict says so).

The verdict: the best candidate by held-out gain is the cause when it passes
(1) and its own misfit is not structured by (2); with no candidate passing,
``none`` when the baseline's misfit is not structured, else ``unexplained``.
A candidate that passes (1) but leaves a structured misfit helps without
explaining: after the open world below, such a verdict is ``unexplained``
(:func:`settle`), the partial cause named in ``best``.

When the catalogue leaves a structured misfit (``unexplained``, or a cause
that does not explain it), :func:`extend` asks the law corrections of
:mod:`granseg.fitting.laws` (fitted in :mod:`granseg.diagnosis.open_world`):
the best becomes the cause ``new_law`` when it passes (1) by a clear margin
over the catalogue's best and leaves no structured misfit by (2).

The thresholds are calibrated on null campaigns under every named noise
process of :data:`granseg.synth.virtual.NOISE_PROCESSES`
(``benches/bench_diagnose_noise.py``; the figures and the seeds used in
BENCHMARKS.md).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from granseg.fitting import Data, ExpInfo, Fit
from granseg.fitting.solve import blocks
from granseg.maps import Map

__all__ = ["COHERENCE_ALPHA", "COHERENCE_SHARE", "EXCESS_THRESHOLD", "GAIN_THRESHOLD", "Coherence", "Misfit",
           "Verdict", "coherence", "decide", "extend", "misfit", "model_jacobians", "needs_open_world", "settle"]

#: Minimum held-out gain of the best candidate, relative to the baseline's held-out RMSD.
GAIN_THRESHOLD = 0.02
#: Largest mean RMSD / counted noise floor still counted as "within the noise".
EXCESS_THRESHOLD = 1.06
#: Sign-flip p-value below which a misfit counts as coherent across experiments...
COHERENCE_ALPHA = 1e-3
#: ...when the coherent patterns also hold this share of the residual energy [-]
#: (persistent grains alone leave a small coherent lag: up to 0.25 on null campaigns).
COHERENCE_SHARE = 0.35
#: Normalised-time bins and depth bands of the coherence features.
TIME_BINS, DEPTH_BANDS = 6, 5
N_FLIPS = 9999


@dataclass(frozen=True)
class Coherence:
    """The cross-experiment test: sign-flip ``p`` [-] and the ``share`` [-] of the residual
    energy the covariate patterns hold beyond what flipped residuals give (0 for noise)."""

    p: float
    share: float


@dataclass(frozen=True)
class Misfit:
    """Is a model's misfit structured? ``excess`` mean RMSD / floor (NaN without a
    counted floor), ``coherence_p`` and ``coherence_share`` the cross-experiment
    test (:class:`Coherence`), ``structured`` the answer and ``why`` in words."""

    excess: float
    coherence_p: float
    coherence_share: float
    structured: bool
    why: str


@dataclass(frozen=True)
class Verdict:
    """The decision: ``cause`` (catalogue name, ``none`` or ``unexplained``),
    ``explained``, the best candidate, its relative held-out gain, the
    baseline's and the cause's misfit tests, the margin to the runner-up [-],
    and the reasons in words."""

    cause: str
    explained: bool
    best: str | None
    gain_relative: float
    baseline: Misfit
    extended: Misfit | None
    runner_up: str | None
    margin: float
    reason: str
    #: the law correction named when ``cause`` is ``new_law`` (:mod:`granseg.fitting.laws`)
    law: str | None = None


def _binned(m: Map, values: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Mean of ``values`` (n_t, n_layers, q) over the entries ``ok`` of each normalised-time bin
    and depth band: (TIME_BINS * DEPTH_BANDS, q), 0 where a block has no reading."""
    tb = np.minimum((m.t / m.t[-1] * TIME_BINS).astype(int), TIME_BINS - 1)
    db = np.minimum(np.arange(m.n_layers) * DEPTH_BANDS // m.n_layers, DEPTH_BANDS - 1)
    out = np.zeros((TIME_BINS, DEPTH_BANDS, values.shape[2]))
    for b in range(TIME_BINS):
        for d in range(DEPTH_BANDS):
            sel = np.ix_(tb == b, db == d)
            w = ok[sel]
            if w.any():
                out[b, d] = values[sel][w].mean(axis=0)
    return out.reshape(TIME_BINS * DEPTH_BANDS, -1)


def _features(m: Map, model: np.ndarray, jac: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Binned residual (measured - model) and binned model Jacobian (F, q) of one experiment."""
    r = m.c - model
    ok = np.isfinite(r)
    q = 0 if jac is None else jac.shape[2]
    both = np.concatenate([np.where(ok, r, 0.0)[:, :, None], np.zeros(r.shape + (q,)) if jac is None else jac],
                          axis=2)
    b = _binned(m, both, ok)
    return b[:, 0], b[:, 1:]


def _design(exps: Sequence[ExpInfo]) -> np.ndarray:
    """Intercept plus the standardised covariates that vary in the campaign."""
    cols = [np.ones(len(exps))]
    for v in (np.log([e.M_tilde for e in exps]), np.log([e.delta_R for e in exps]), [e.c0 for e in exps]):
        v = np.asarray(v, dtype=float)
        if np.ptp(v) > 1e-9 * max(1.0, float(np.abs(v).max())):
            cols.append((v - v.mean()) / v.std())
    X = np.column_stack(cols)
    # drop covariates that repeat another (e.g. delta_R when each pair has one load)
    keep = [0]
    for j in range(1, X.shape[1]):
        if np.linalg.matrix_rank(X[:, keep + [j]]) == len(keep) + 1 and len(keep) + 1 < len(exps) - 1:
            keep.append(j)
    return X[:, keep]


def coherence(maps: Sequence[Map], exps: Sequence[ExpInfo], layers: Sequence[np.ndarray],
              jacobians: Sequence[np.ndarray] | None = None, seed: int = 0) -> Coherence:
    """Sign-flip p-value [-] that the residuals share a pattern across experiments (module doc).

    ``jacobians[i]`` (n_t, n_layers, q): the model map's derivatives by the q
    fitted parameters. A parameter fitted to all experiments is off by its
    error in all of them alike, which is itself a shared pattern; those
    directions are projected out before the test (the effective-score form
    of the sign-flip test), so only what no fitted parameter can produce counts.
    """
    feats = [_features(m, lay, None if jacobians is None else jacobians[i])
             for i, (m, lay) in enumerate(zip(maps, layers, strict=True))]
    n, F = len(maps), feats[0][0].size
    r = np.concatenate([f[0] for f in feats])  # (n F,)
    Qx, _ = np.linalg.qr(_design(exps))
    C = np.kron(Qx, np.eye(F))  # the covariate-patterned directions, (n F, p F)
    if jacobians is not None:
        N = np.concatenate([f[1] for f in feats])  # (n F, q): the fitted parameters' directions
        C = C - N @ np.linalg.lstsq(N, C, rcond=None)[0]
    U, sv, _ = np.linalg.svd(C, full_matrices=False)
    Q = U[:, sv > 1e-9 * sv.max()]
    observed = float(np.sum((Q.T @ r) ** 2))
    rng = np.random.default_rng(seed)
    signs = np.repeat(rng.choice([-1.0, 1.0], size=(N_FLIPS, n)), F, axis=1)
    stats = np.sum(((signs * r) @ Q) ** 2, axis=1)
    p = float((1 + np.sum(stats >= observed * (1 - 1e-12))) / (N_FLIPS + 1))
    share = float((observed - stats.mean()) / max(float(r @ r), 1e-300))
    return Coherence(p, share)


def model_jacobians(data: Data, f: Fit) -> list[np.ndarray]:
    """The model maps' derivatives (n_t, n_layers, q) by a fit's parameters, from its
    weighted residual Jacobian (:class:`granseg.fitting.Fit`; evaluated again for a
    :func:`granseg.fitting.compact` one)."""
    out = []
    _, jac = blocks(data, f)
    for k, i in enumerate(f.which):
        full = np.zeros(data.maps[i].c.shape + (jac[k].shape[1],))
        full[data.masks[i]] = jac[k] / data.weights[i]
        out.append(full)
    return out


def misfit(rmsd_mean: float, floor: float, counted: bool, coh: Coherence, *,
           excess_threshold: float = EXCESS_THRESHOLD, coherence_alpha: float = COHERENCE_ALPHA,
           coherence_share: float = COHERENCE_SHARE) -> Misfit:
    """Decide whether one model's misfit is structured (module doc, question 2)."""
    excess = rmsd_mean / max(floor, 1e-9) if counted else float("nan")
    coherent = coh.p < coherence_alpha and coh.share > coherence_share
    beyond = counted and excess > excess_threshold
    parts = [f"a residual pattern shared across experiments holds {100 * max(coh.share, 0):.0f} % of the "
             f"residual energy, p = {coh.p:.4f} ({'coherent' if coherent else 'not coherent'}: needs "
             f"p < {coherence_alpha:g} and > {100 * coherence_share:.0f} %)"]
    parts.append(f"RMSD {excess:.2f} x the counted noise floor ({'>' if beyond else '<='} {excess_threshold:.2f})"
                 if counted else "no counts in the maps: the noise floor is a lower bound and not used")
    return Misfit(excess, coh.p, coh.share, bool(coherent or beyond), "; ".join(parts))


def decide(held_out_gain: dict[str, float], baseline_held_out_mean: float, baseline: Misfit,
           candidate_misfit: Callable[[str], Misfit], *, gain_threshold: float = GAIN_THRESHOLD) -> Verdict:
    """Name the cause from the candidates' held-out gains [-] and the misfit tests
    (``candidate_misfit(name)`` is asked for the best candidate only, when it passes)."""
    if not held_out_gain:  # no catalogue cause was tried (the diagnosis of a flagged window)
        cause = "unexplained" if baseline.structured else "none"
        return Verdict(cause, not baseline.structured, None, 0.0, baseline, None, None, 0.0,
                       f"no catalogue cause tried; baseline misfit {'' if baseline.structured else 'not '}"
                       f"structured ({baseline.why})")
    order = sorted(held_out_gain, key=held_out_gain.get, reverse=True)
    best = order[0]
    runner = order[1] if len(order) > 1 else None
    relative = held_out_gain[best] / max(baseline_held_out_mean, 1e-9)
    margin = held_out_gain[best] - (held_out_gain[runner] if runner else 0.0)
    if relative > gain_threshold:
        ext = candidate_misfit(best)
        reason = (f"{best} lowers the held-out RMSD by {held_out_gain[best]:.4f} ({100 * relative:.1f} % "
                  f"> {100 * gain_threshold:.1f} %); left after it: {ext.why}")
        return Verdict(best, not ext.structured, best, relative, baseline, ext, runner, margin, reason)
    tail = f"no candidate gains more than {100 * gain_threshold:.1f} % held out (best: {best}, " \
           f"{100 * relative:.2f} %)"
    if not baseline.structured:
        return Verdict("none", True, best, relative, baseline, None, runner, margin,
                       f"baseline misfit not structured ({baseline.why}); {tail}")
    return Verdict("unexplained", False, best, relative, baseline, None, runner, margin,
                   f"baseline misfit structured ({baseline.why}); {tail}")


def needs_open_world(v: Verdict) -> bool:
    """True when the catalogue leaves a structured misfit (``unexplained``, or a cause not explaining it)."""
    return v.cause != "none" and not v.explained


def extend(v: Verdict, law_gains: dict[str, float], baseline_held_out_mean: float,
           law_misfit: Callable[[str], Misfit], *, gain_threshold: float = GAIN_THRESHOLD) -> Verdict:
    """The verdict after the open world (:mod:`granseg.diagnosis.open_world`).

    The best law correction becomes the cause (``new_law``) when its relative
    held-out gain passes ``gain_threshold``, beats the catalogue's best by
    more than ``gain_threshold`` (a catalogue cause, with fewer parameters,
    wins when it predicts about as well) and leaves no structured misfit.
    Otherwise the catalogue's verdict stands, with the reason extended.
    """
    if not law_gains:
        return v
    best = max(law_gains, key=law_gains.get)
    rel = law_gains[best] / max(baseline_held_out_mean, 1e-9)
    catalogue = v.gain_relative if v.best is not None else 0.0
    head = f"open world: best law correction {best} gains {100 * rel:.1f} % held out"
    if rel <= gain_threshold:
        return replace(v, reason=f"{v.reason}; {head} (needs > {100 * gain_threshold:.1f} %)")
    if rel <= catalogue + gain_threshold:
        return replace(v, reason=f"{v.reason}; {head}, not clearly more than {v.best} "
                                 f"({100 * catalogue:.1f} %, fewer parameters)")
    m = law_misfit(best)
    if m.structured:
        return replace(v, reason=f"{v.reason}; {head} but leaves a structured misfit ({m.why})")
    margin = law_gains[best] - catalogue * baseline_held_out_mean
    return Verdict("new_law", True, v.best, rel, v.baseline, m, v.best, margin,
                   f"{v.reason}; {head} (> {100 * gain_threshold:.1f} % and more than the catalogue's "
                   f"{100 * catalogue:.1f} %) and leaves no structured misfit ({m.why})", law=best)


def settle(v: Verdict) -> Verdict:
    """The final verdict: a catalogue cause that gains held out but leaves a structured misfit
    does not explain it, so the cause is ``unexplained`` (the partial cause stays in ``best``)."""
    if v.cause in ("none", "unexplained", "new_law") or v.explained:
        return v
    return replace(v, cause="unexplained",
                   reason=f"{v.reason}; {v.best} helps but does not explain the misfit: unexplained")


def held_out_gain(baseline_ho: np.ndarray, candidate_ho: np.ndarray) -> float:
    """Mean over experiments of baseline minus candidate held-out RMSD [-]."""
    return float(np.mean(np.asarray(baseline_ho) - np.asarray(candidate_ho)))
