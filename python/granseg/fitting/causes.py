"""The catalogue of candidate causes: named, physical extensions of the baseline model.

Each cause is one :class:`~granseg.fitting.effects.Effect` subclass, used both
by the diagnosis (fitted to a campaign) and by :func:`granseg.synth.campaign`
(hidden in a virtual one). To add a cause, write one class here (or in your
own module) and decorate it with :func:`~granseg.fitting.effects.register`;
only new physics in the solver needs the Rust parameters too.

Example::

    >>> cause = get("load_dependent_shear_band")
    >>> [p.name for p in cause.params([])]
    ['k', 'delta_over_H', 'exponent']
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from granseg.fit import M_TILDE_REF
from granseg.fitting.effects import REGISTRY, Baseline, Effect, ExpInfo, Param, plus_minus, register
from granseg.model import defaults

__all__ = [
    "B_LITERATURE",
    "M_TILDE_REF",
    "ROUGHNESS",
    "DiffusivityScale",
    "EvolvingShearBand",
    "LoadDependentShearBand",
    "MaterialFriction",
    "Misclassification",
    "SidewallExcess",
    "SpinUpDelay",
    "build",
    "get",
    "names",
    "sidewall_view",
]

#: The diffusion constant b [-] of docs/model.md (the core's default, from the literature).
B_LITERATURE = defaults()["b"]
#: Relative surface roughness of each material [-] (how a hidden material_friction
#: effect spreads k over the pairs of a virtual campaign).
ROUGHNESS: dict[str, float] = {"steel": -1.0, "ceramic": 1.0, "glass": -0.4, "POM": 0.6, "PP": 0.2}


@register
class LoadDependentShearBand(Effect):
    """delta/H follows the normalised load: a power law in M~ = M_w / M_g."""

    name = "load_dependent_shear_band"
    covariate = "M_tilde"
    description = (
        "The shear band's decay length is not one constant: under the same lid a lighter bed "
        "(larger M~ = M_w/M_g) localises shear in a thinner band. "
        "delta/H = (delta/H)_ref * (M~ / 0.5)^(-exponent)."
    )
    draw_range = (0.3, 0.7)

    def extra(self, exps: Sequence[ExpInfo]) -> list[Param]:
        return [Param("exponent", -2.0, 3.0, 0.0, 0.01, "-")]

    def solver_params(self, x: Mapping[str, float], exp: ExpInfo) -> dict[str, float]:
        out = super().solver_params(x, exp)
        dh = x["delta_over_H"] * (exp.M_tilde / M_TILDE_REF) ** (-x["exponent"])
        out["delta_over_H"] = float(np.clip(dh, 0.02, 1.0))
        return out

    def law(self, x: Mapping[str, float], err: Mapping[str, float]) -> str:
        return (f"delta/H = {plus_minus(x['delta_over_H'], err.get('delta_over_H'))} x (M~/{M_TILDE_REF})"
                f"^-({plus_minus(x['exponent'], err.get('exponent'))}), k = {plus_minus(x['k'], err.get('k'))}")


@register
class EvolvingShearBand(Effect):
    """delta drifts within a run: delta(t) = delta (1 + drift (1 - exp(-t / T)))."""

    name = "evolving_shear_band"
    covariate = "time"
    description = (
        "The shear band changes as the bed re-stratifies (heavy grains collect at the driven "
        "bottom): delta(t) = delta * (1 + drift * (1 - exp(-t / T))), the same drift and time "
        "scale T [s] in every experiment."
    )
    draw_range = (0.3, 0.6)  # |delta_drift|, sign drawn
    DRIFT_TIME = 600.0  # s, a hidden effect's time scale unless the campaign sets drift_time

    def extra(self, exps: Sequence[ExpInfo]) -> list[Param]:
        return [Param("delta_drift", -0.7, 2.0, 0.0, 0.01, "-"),
                Param("log10_drift_time", 1.5, 3.7, 2.7, 0.02, "log10 s", prior_sd=1.0)]

    def solver_params(self, x: Mapping[str, float], exp: ExpInfo) -> dict[str, float]:
        out = super().solver_params(x, exp)
        out["delta_drift"] = x["delta_drift"]
        out["delta_drift_time"] = 10.0 ** x["log10_drift_time"]
        return out

    def law(self, x: Mapping[str, float], err: Mapping[str, float]) -> str:
        T = 10.0 ** x["log10_drift_time"]
        return (f"delta(t) = delta (1 + ({plus_minus(x['delta_drift'], err.get('delta_drift'))}) "
                f"(1 - exp(-t / {T:.0f} s))), delta/H = {plus_minus(x['delta_over_H'], err.get('delta_over_H'))}")

    def hidden(self, strength: float, exp: ExpInfo, settings: Mapping[str, float]) -> dict[str, float]:
        drift_time = float(settings.get("drift_time", self.DRIFT_TIME))
        return {"delta_drift": strength, "log10_drift_time": math.log10(drift_time)}

    def draw(self, rng: np.random.Generator) -> tuple[float, dict[str, float]]:
        size, _ = super().draw(rng)
        sign = 1.0 if rng.random() < 0.5 else -1.0
        return sign * size, {"drift_time": float(rng.uniform(300.0, 900.0))}


def sidewall_view(c: np.ndarray, a: float) -> np.ndarray:
    """Heavy share seen at the outer wall for bed share ``c`` [-] and excess ``a`` [-].

    c_wall = c + a c (1 - c): no change where the bed is pure (c = 0 or 1), the
    largest excess (a/4) where it is fully mixed; monotone and inside [0, 1]
    for |a| <= 1.
    """
    return c + a * c * (1.0 - c)


@register
class SidewallExcess(Effect):
    """The outer wall shows more heavy grains than the bulk where the bed is mixed."""

    name = "sidewall_excess"
    covariate = "depth_mean"
    description = (
        "A 3-D recirculation carries rising light grains away from the outer wall, so the wall "
        "over-represents heavy grains wherever the bed is mixed: c_wall = c + a c (1 - c), with "
        "a = s * M~ / 0.5 growing with the normalised load (radial forces grow as the band "
        "thins). The measured depth-mean then exceeds c0 during mixing."
    )
    strength_limits = (-2.0, 2.0)
    draw_range = (0.3, 0.8)

    def extra(self, exps: Sequence[ExpInfo]) -> list[Param]:
        return [Param("s", -1.0, 1.5, 0.0, 0.01, "-")]

    @staticmethod
    def strength(x: Mapping[str, float], exp: ExpInfo) -> float:
        """The excess coefficient a [-] of experiment ``exp``."""
        return float(np.clip(x["s"] * exp.M_tilde / M_TILDE_REF, -1.0, 1.0))

    def observe(self, x: Mapping[str, float], exp: ExpInfo, layers: np.ndarray) -> np.ndarray:
        return sidewall_view(layers, self.strength(x, exp))

    def law(self, x: Mapping[str, float], err: Mapping[str, float]) -> str:
        return (f"c_wall = c + a c (1 - c), a = ({plus_minus(x['s'], err.get('s'))}) x M~/{M_TILDE_REF}; "
                + super().law(x, err))


@register
class MaterialFriction(Effect):
    """k depends on the material pair: k_pair = k exp(u_pair), weak prior on u."""

    name = "material_friction"
    covariate = "pair"
    description = (
        "The friction correction k reflects grain surfaces, so it differs between material "
        "pairs: k_pair = k * exp(u_pair), one u per pair in the campaign, each with a weak "
        "prior (sd 0.3) towards the common k so that a pair seen once stays identifiable."
    )
    PRIOR_SD = 0.3
    draw_range = (0.3, 0.6)

    def extra(self, exps: Sequence[ExpInfo]) -> list[Param]:
        pairs = sorted({e.pair for e in exps})
        return [Param(f"u[{p}]", -1.2, 1.2, 0.0, 0.01, "-", prior_sd=self.PRIOR_SD) for p in pairs]

    def solver_params(self, x: Mapping[str, float], exp: ExpInfo) -> dict[str, float]:
        out = super().solver_params(x, exp)
        out["k"] = x["k"] * math.exp(x.get(f"u[{exp.pair}]", 0.0))
        return out

    def law(self, x: Mapping[str, float], err: Mapping[str, float]) -> str:
        parts = [f"{key[2:-1]}: {x['k'] * math.exp(v):.3g}" for key, v in x.items() if key.startswith("u[")]
        return "k per pair: " + ", ".join(parts)

    def hidden(self, strength: float, exp: ExpInfo, settings: Mapping[str, float]) -> dict[str, float]:
        r = 0.5 * (ROUGHNESS.get(exp.heavy, 0.0) + ROUGHNESS.get(exp.light, 0.0))
        return {f"u[{exp.pair}]": strength * r}


@register
class SpinUpDelay(Effect):
    """Segregation starts only after the flow has spun up: a delay t_d [s]."""

    name = "spin_up_delay"
    covariate = "time"
    description = (
        "The bed needs time to dilate and establish the shear profile after the plate starts; "
        "segregation begins only after a delay t_d [s] (model run at max(t - t_d, 0))."
    )
    strength_limits = (0.0, 3600.0)
    draw_range = (60.0, 240.0)  # s

    def extra(self, exps: Sequence[ExpInfo]) -> list[Param]:
        return [Param("t_delay", 0.0, 900.0, 1.0, 2.0, "s")]

    def time_shift(self, x: Mapping[str, float], exp: ExpInfo) -> float:
        return max(0.0, float(x["t_delay"]))

    def law(self, x: Mapping[str, float], err: Mapping[str, float]) -> str:
        return (f"segregation starts {plus_minus(x['t_delay'], err.get('t_delay'))} s after the plate; "
                + super().law(x, err))


@register
class DiffusivityScale(Effect):
    """The diffusion constant b differs from the literature's."""

    name = "diffusivity_scale"
    covariate = "delta_R"
    description = (
        f"Shear-induced diffusion of these grains is stronger or weaker than the literature's "
        f"b = {B_LITERATURE:g}: D = b gdot D_p^2 with b = {B_LITERATURE:g} exp(log_b_scale), one b for all."
    )
    #: a hidden effect's strength is the factor on b
    strength_limits = (1e-3, 1e3)
    draw_range = (0.5, 1.0)  # |log factor|, sign drawn

    def extra(self, exps: Sequence[ExpInfo]) -> list[Param]:
        return [Param("log_b_scale", -2.5, 2.5, 0.0, 0.01, "-")]

    def solver_params(self, x: Mapping[str, float], exp: ExpInfo) -> dict[str, float]:
        out = super().solver_params(x, exp)
        out["b"] = B_LITERATURE * math.exp(x["log_b_scale"])
        return out

    def law(self, x: Mapping[str, float], err: Mapping[str, float]) -> str:
        b = B_LITERATURE * math.exp(x["log_b_scale"])
        e = err.get("log_b_scale")
        eb = None if e is None or not math.isfinite(e) else b * e
        return f"b = {plus_minus(b, eb)} (literature {B_LITERATURE:g}); " + super().law(x, err)

    def hidden(self, strength: float, exp: ExpInfo, settings: Mapping[str, float]) -> dict[str, float]:
        return {"log_b_scale": math.log(strength)}

    def draw(self, rng: np.random.Generator) -> tuple[float, dict[str, float]]:
        size, _ = super().draw(rng)
        sign = 1.0 if rng.random() < 0.5 else -1.0
        return float(math.exp(sign * size)), {}


@register
class Misclassification(Effect):
    """A share f of the spheres of each kind is taken for the other: c_seen = f + (1 - 2f) c.

    Not in the catalogue: the diagnosis does not fit it, and a campaign with it
    hidden tests that a misfit outside the catalogue is called ``unexplained``.
    """

    name = "misclassification"
    catalogued = False
    description = "The frame analysis takes a share f of each kind for the other: c_seen = f + (1 - 2 f) c."
    strength_limits = (0.0, 0.5)
    draw_range = (0.08, 0.15)

    def extra(self, exps: Sequence[ExpInfo]) -> list[Param]:
        return [Param("f", 0.0, 0.5, 0.0, 0.005, "-")]

    def observe(self, x: Mapping[str, float], exp: ExpInfo, layers: np.ndarray) -> np.ndarray:
        return x["f"] + (1.0 - 2.0 * x["f"]) * layers


def names(*, catalogued_only: bool = True) -> list[str]:
    """Registered cause names (default: those the diagnosis fits), in registration order."""
    return [n for n, cls in REGISTRY.items()
            if cls is not Baseline and (cls.catalogued or not catalogued_only)]


def get(name: str) -> Effect:
    """A fresh effect object by name (``baseline`` or any registered cause)."""
    try:
        return REGISTRY[name]()
    except KeyError:
        raise ValueError(f"unknown cause {name!r}; known: {', '.join(REGISTRY)}") from None


def build(selected: Sequence[str] | None = None) -> list[Effect]:
    """The causes to try (default: the whole catalogue), validated by name."""
    chosen = names() if selected is None else list(selected)
    return [get(n) for n in chosen]
