"""The measurement's confusion of the two kinds, measured where the truth is known.

Every run starts stratified (docs/model.md): heavy grains above the interface,
light below. Until the shear mixes them, the layers well away from the
interface are pure, and the model says which ones and for how long. Any heavy
grain a map reports in a pure light layer there (or light grain in a pure
heavy layer) is a classification error, not physics. With a share f of each
kind taken for the other the camera shows c_seen = f + (1 - 2 f) c
(the ``misclassified`` noise process of :mod:`granseg.synth.virtual`, and what
a frame analysis with overlapping colour classes does).

:func:`measure` pools those entries per material pair (one camera and one
pair of looks: one confusion) over the first :data:`EARLY_WINDOWS` smoothing
windows of every run, and no later than :data:`EARLY_SECONDS` after its first
frame (sparse footage has windows minutes long), where physical mixing has not
yet reached the layers the model calls pure; later times are not used, so an effect that mixes the bed
more than the model (extra diffusion, a wider band) cannot pass for
confusion. The fitting layer applies the measured f in the observation step
(:func:`granseg.fitting.observe.model_maps`) when it is resolved
(f > :data:`MIN_SHARE` and more than :data:`MIN_SIGMAS` standard errors).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from granseg.maps import Map

__all__ = ["EARLY_SECONDS", "EARLY_WINDOWS", "MIN_SHARE", "MIN_SIGMAS", "PURE", "Confusion", "measure"]

#: A model layer mean this close to 0 or 1 counts as pure [-].
PURE = 2e-3
#: How many smoothing windows (at least 3 frames each) from the start are used...
EARLY_WINDOWS = 3
#: ...within this time [s] of the first frame: a model error (a wider band, extra mixing)
#: can mix a layer the model still calls pure within minutes, and its grains are not confused.
EARLY_SECONDS = 60.0
#: The smallest share worth correcting [-], and the resolution it needs [standard errors].
MIN_SHARE = 0.005
MIN_SIGMAS = 3.0


@dataclass(frozen=True)
class Confusion:
    """The measured confusion share per experiment [-] (0 where not applied),
    per material pair the raw estimate, its standard error and the grains
    counted, and whether it is applied."""

    share: np.ndarray
    by_pair: dict[str, dict[str, float | bool]]

    def to_dict(self) -> dict[str, dict[str, float | bool]]:
        """JSON-ready per-pair record."""
        return {k: dict(v) for k, v in self.by_pair.items()}


def _early_pure(m: Map, model: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Masks of the entries in the first windows that the model calls pure light / pure heavy."""
    frames = EARLY_WINDOWS * max(m.smoothing_frames, 3)
    early = np.zeros(m.n_times, dtype=bool)
    early[:frames] = True
    early &= m.t - m.t[0] <= EARLY_SECONDS
    return (model < PURE) & early[:, None], (model > 1.0 - PURE) & early[:, None]


def _tally(m: Map, model: np.ndarray) -> tuple[float, float, float]:
    """(wrong grains, grains, effective independent grains) over the early pure entries.

    Without counts every map entry counts as one grain. Where the bed is
    pure it barely moves, so the same grains stay in view through the early
    window: the effective count is one frame's grains per layer (conservative).
    """
    light, heavy = _early_pure(m, model)
    if m.n is not None and (m.n_heavy is not None or m.c_raw is not None):
        n = m.n.astype(float)
        share = m.c_raw if m.c_raw is not None else np.where(n > 0, m.n_heavy / np.maximum(n, 1), np.nan)
    else:
        n, share = np.ones_like(m.c), m.c
    ok = np.isfinite(share) & (n > 0)
    wrong = float((share * n)[light & ok].sum() + ((1.0 - share) * n)[heavy & ok].sum())
    used = (light | heavy) & ok
    total = float(n[used].sum())
    per_layer = [n[used[:, j], j].mean() for j in range(n.shape[1]) if used[:, j].any()]
    return wrong, total, float(np.sum(per_layer))


def measure(maps: list[Map], layers: list[np.ndarray], pairs: list[str]) -> Confusion:
    """The confusion share of every experiment from the model maps ``layers`` of a fit."""
    tallies: dict[str, list[float]] = {}
    for m, model, pair in zip(maps, layers, pairs, strict=True):
        t = tallies.setdefault(pair, [0.0, 0.0, 0.0])
        for j, v in enumerate(_tally(m, model)):
            t[j] += v
    by_pair: dict[str, dict[str, float | bool]] = {}
    for pair, (wrong, total, eff) in tallies.items():
        f = wrong / total if total > 0 else 0.0
        se = float(np.sqrt(max(f * (1 - f), 1e-4) / eff)) if eff > 0 else float("inf")
        applied = bool(total > 0 and f > MIN_SHARE and f > MIN_SIGMAS * se)
        by_pair[pair] = {"share": float(f), "stderr": se, "grains": total, "applied": applied}
    share = np.array([float(by_pair[p]["share"]) if by_pair[p]["applied"] else 0.0 for p in pairs])
    return Confusion(np.clip(share, 0.0, 0.49), by_pair)
