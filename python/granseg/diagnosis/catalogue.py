"""The catalogue of candidate causes: named, physical extensions of the baseline model.

Each entry is a small object (:class:`Extension`) that knows

* its ``name`` and a one-paragraph physical ``description``;
* its extra parameters (:class:`Param`: name, bounds, start, finite-difference
  step, unit), fitted on top of the baseline's global ``k`` [-] and
  ``delta_over_H`` [-];
* how a parameter set and one experiment's covariates become solver
  parameters (:meth:`Extension.solver_params`), a time shift
  (:meth:`Extension.time_shift`, s) and an observation transform applied to
  the model's layer means before the map's moving average
  (:meth:`Extension.observe`).

With every extra parameter at its neutral value each extension is exactly the
baseline of MODEL.md. Extensions are stateless apart from the list of
material pairs :class:`MaterialFriction` is built for.

Example::

    >>> ext = get("load_dependent_shear_band")
    >>> [p.name for p in ext.params(exps)]                    # doctest: +SKIP
    ['k', 'delta_over_H', 'exponent']
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from granseg.maps import Conditions

__all__ = [
    "CATALOGUE",
    "M_TILDE_REF",
    "Baseline",
    "DiffusivityScale",
    "EvolvingShearBand",
    "ExpInfo",
    "Extension",
    "LoadDependentShearBand",
    "MaterialFriction",
    "Param",
    "SidewallExcess",
    "SpinUpDelay",
    "build",
    "get",
    "names",
    "sidewall_view",
]

#: Reference normalised load M~ = M_w / M_g [-] of the laws below (the paper's
#: three calibration cases sit at 0.41-0.54).
M_TILDE_REF = 0.5
B_LITERATURE = 0.041


@dataclass(frozen=True)
class ExpInfo(Conditions):
    """The covariates of one experiment the extensions may use (SI units)."""

    @property
    def pair(self) -> str:
        """Material pair label, e.g. ``glass-PP``."""
        return f"{self.heavy}-{self.light}"

    @classmethod
    def of(cls, m: Any) -> ExpInfo:
        """From a :class:`granseg.maps.Map` (or anything with the same attributes)."""
        return cls(str(m.name), str(m.heavy), str(m.light), float(m.rho_h), float(m.rho_l),
                   float(m.c0), float(m.M_g), float(m.M_w))

    def case(self) -> dict[str, float]:
        """Solver parameters this experiment fixes."""
        return {"rho_h": self.rho_h, "rho_l": self.rho_l, "c0": self.c0, "M_w": self.M_w}


@dataclass(frozen=True)
class Param:
    """One fitted parameter: bounds, start, finite-difference step, unit, prior width.

    ``prior_sd`` (same unit) adds a weak Gaussian pull towards ``start`` to the
    fit; None means no prior.
    """

    name: str
    lo: float
    hi: float
    start: float
    step: float
    unit: str = "-"
    prior_sd: float | None = None


BASE_PARAMS = (
    Param("k", 0.2, 1.6, 0.70, 4e-3, "-"),
    Param("delta_over_H", 0.05, 0.6, 0.18, 1.5e-3, "-"),
)


class Extension:
    """Base class: the baseline model of MODEL.md (no extra parameter)."""

    name = "baseline"
    description = "MODEL.md as it stands: one k and one delta/H for every experiment."
    #: the covariate this cause is expected to correlate with (for the evidence figures)
    covariate: str | None = None

    def extra(self, exps: Sequence[ExpInfo]) -> list[Param]:
        """Extra parameters beyond the baseline's ``k`` and ``delta_over_H``."""
        return []

    def params(self, exps: Sequence[ExpInfo]) -> list[Param]:
        """Every fitted parameter, baseline ones first."""
        return [*BASE_PARAMS, *self.extra(exps)]

    def solver_params(self, x: Mapping[str, float], exp: ExpInfo) -> dict[str, float]:
        """Solver keyword parameters for experiment ``exp`` at parameters ``x``."""
        return {**exp.case(), "k": x["k"], "delta_over_H": x["delta_over_H"]}

    def time_shift(self, x: Mapping[str, float], exp: ExpInfo) -> float:
        """Delay [s] between the plate start and the model's t = 0."""
        return 0.0

    def observe(self, x: Mapping[str, float], exp: ExpInfo, layers: np.ndarray) -> np.ndarray:
        """What the camera sees given the bed's layer means (n_t, n_layers); identity here."""
        return layers

    def law(self, x: Mapping[str, float], err: Mapping[str, float]) -> str:
        """A one-line, human-readable statement of the fitted extension."""
        return f"k = {_pm(x['k'], err.get('k'))}, delta/H = {_pm(x['delta_over_H'], err.get('delta_over_H'))}"


def _pm(v: float, e: float | None, fmt: str = ".3g") -> str:
    if e is None or not math.isfinite(e):
        return f"{v:{fmt}}"
    return f"{v:{fmt}} ± {e:.2g}"


class Baseline(Extension):
    """The baseline itself (used as the reference of every comparison)."""


class LoadDependentShearBand(Extension):
    """delta/H follows the normalised load: a power law in M~ = M_w / M_g."""

    name = "load_dependent_shear_band"
    covariate = "M_tilde"
    description = (
        "The shear band's decay length is not one constant: under the same lid a lighter bed "
        "(larger M~ = M_w/M_g) localises shear in a thinner band. "
        "delta/H = (delta/H)_ref * (M~ / 0.5)^(-exponent)."
    )

    def extra(self, exps: Sequence[ExpInfo]) -> list[Param]:
        return [Param("exponent", -2.0, 3.0, 0.0, 0.01, "-")]

    def solver_params(self, x: Mapping[str, float], exp: ExpInfo) -> dict[str, float]:
        out = super().solver_params(x, exp)
        dh = x["delta_over_H"] * (exp.M_tilde / M_TILDE_REF) ** (-x["exponent"])
        out["delta_over_H"] = float(np.clip(dh, 0.02, 1.0))
        return out

    def law(self, x: Mapping[str, float], err: Mapping[str, float]) -> str:
        return (f"delta/H = {_pm(x['delta_over_H'], err.get('delta_over_H'))} x (M~/{M_TILDE_REF})"
                f"^-({_pm(x['exponent'], err.get('exponent'))}), k = {_pm(x['k'], err.get('k'))}")


class EvolvingShearBand(Extension):
    """delta drifts within a run: delta(t) = delta (1 + drift (1 - exp(-t / T)))."""

    name = "evolving_shear_band"
    covariate = "time"
    description = (
        "The shear band changes as the bed re-stratifies (heavy grains collect at the driven "
        "bottom): delta(t) = delta * (1 + drift * (1 - exp(-t / T))), the same drift and time "
        "scale T [s] in every experiment."
    )

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
        return (f"delta(t) = delta (1 + ({_pm(x['delta_drift'], err.get('delta_drift'))}) "
                f"(1 - exp(-t / {T:.0f} s))), delta/H = {_pm(x['delta_over_H'], err.get('delta_over_H'))}")


def sidewall_view(c: np.ndarray, a: float) -> np.ndarray:
    """Heavy share seen at the outer wall for bed share ``c`` [-] and excess ``a`` [-].

    c_wall = c + a c (1 - c): no change where the bed is pure (c = 0 or 1), the
    largest excess (a/4) where it is fully mixed; monotone and inside [0, 1]
    for |a| <= 1.
    """
    return c + a * c * (1.0 - c)


class SidewallExcess(Extension):
    """The outer wall shows more heavy grains than the bulk where the bed is mixed."""

    name = "sidewall_excess"
    covariate = "depth_mean"
    description = (
        "A 3-D recirculation carries rising light grains away from the outer wall, so the wall "
        "over-represents heavy grains wherever the bed is mixed: c_wall = c + a c (1 - c), with "
        "a = s * M~ / 0.5 growing with the normalised load (radial forces grow as the band "
        "thins). The measured depth-mean then exceeds c0 during mixing."
    )

    def extra(self, exps: Sequence[ExpInfo]) -> list[Param]:
        return [Param("s", -1.0, 1.5, 0.0, 0.01, "-")]

    @staticmethod
    def strength(x: Mapping[str, float], exp: ExpInfo) -> float:
        """The excess coefficient a [-] of experiment ``exp``."""
        return float(np.clip(x["s"] * exp.M_tilde / M_TILDE_REF, -1.0, 1.0))

    def observe(self, x: Mapping[str, float], exp: ExpInfo, layers: np.ndarray) -> np.ndarray:
        return sidewall_view(layers, self.strength(x, exp))

    def law(self, x: Mapping[str, float], err: Mapping[str, float]) -> str:
        return (f"c_wall = c + a c (1 - c), a = ({_pm(x['s'], err.get('s'))}) x M~/{M_TILDE_REF}; "
                + super().law(x, err))


class MaterialFriction(Extension):
    """k depends on the material pair: k_pair = k exp(u_pair), weak prior on u."""

    name = "material_friction"
    covariate = "pair"
    description = (
        "The friction correction k reflects grain surfaces, so it differs between material "
        "pairs: k_pair = k * exp(u_pair), one u per pair in the campaign, each with a weak "
        "prior (sd 0.3) towards the common k so that a pair seen once stays identifiable."
    )
    PRIOR_SD = 0.3

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


class SpinUpDelay(Extension):
    """Segregation starts only after the flow has spun up: a delay t_d [s]."""

    name = "spin_up_delay"
    covariate = "time"
    description = (
        "The bed needs time to dilate and establish the shear profile after the plate starts; "
        "segregation begins only after a delay t_d [s] (model run at max(t - t_d, 0))."
    )

    def extra(self, exps: Sequence[ExpInfo]) -> list[Param]:
        return [Param("t_delay", 0.0, 900.0, 1.0, 2.0, "s")]

    def time_shift(self, x: Mapping[str, float], exp: ExpInfo) -> float:
        return max(0.0, float(x["t_delay"]))

    def law(self, x: Mapping[str, float], err: Mapping[str, float]) -> str:
        return f"segregation starts {_pm(x['t_delay'], err.get('t_delay'))} s after the plate; " + super().law(x, err)


class DiffusivityScale(Extension):
    """The diffusion constant b differs from the literature's 0.041."""

    name = "diffusivity_scale"
    covariate = "delta_R"
    description = (
        "Shear-induced diffusion of these grains is stronger or weaker than the literature's "
        "b = 0.041: D = b gdot D_p^2 with b = 0.041 exp(log_b_scale), one b for all."
    )

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
        return f"b = {_pm(b, eb)} (literature 0.041); " + super().law(x, err)


#: The named causes, in the order they are reported.
CATALOGUE: dict[str, type[Extension]] = {
    cls.name: cls
    for cls in (LoadDependentShearBand, EvolvingShearBand, SidewallExcess, MaterialFriction,
                SpinUpDelay, DiffusivityScale)
}


def names() -> list[str]:
    """The catalogue's cause names."""
    return list(CATALOGUE)


def get(name: str) -> Extension:
    """A fresh extension object by name (``baseline`` or a catalogue name)."""
    if name == "baseline":
        return Baseline()
    try:
        return CATALOGUE[name]()
    except KeyError:
        raise ValueError(f"unknown cause {name!r}; the catalogue has {', '.join(CATALOGUE)}") from None


def build(selected: Sequence[str] | None = None) -> list[Extension]:
    """The extensions to try (default: the whole catalogue), validated by name."""
    chosen = names() if selected is None else list(selected)
    return [get(n) for n in chosen]
