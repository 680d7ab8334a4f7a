"""What an effect is: the one object the fit and the virtual experiment share.

An :class:`Effect` is a named, physical change of the baseline model of
docs/model.md. It knows

* its fitted parameters (:class:`Param`: bounds, start, finite-difference
  step, unit, optional prior), the baseline's ``k`` [-] and ``delta_over_H``
  [-] first;
* how a parameter set and one experiment's covariates (:class:`ExpInfo`)
  become solver parameters (:meth:`Effect.solver_params`), a delay of the
  model's clock (:meth:`Effect.time_shift`, s) and what the camera sees of
  the bed's layer means (:meth:`Effect.observe`, applied before the map's
  moving average);
* for the virtual experiments of :mod:`granseg.synth`, which parameters a
  hidden effect of a given ``strength`` means (:meth:`Effect.hidden`), the
  strengths it accepts and the range a random draw comes from.

With every extra parameter at its neutral value an effect is exactly the
baseline. Effects register themselves by name with :func:`register`; the
diagnosis fits every registered effect whose ``catalogued`` is true. Adding
a cause is one class in one file (see :mod:`granseg.fitting.causes`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from granseg.maps import Conditions
from granseg.model import PARAMETERS

__all__ = ["BASE_PARAMS", "REGISTRY", "Baseline", "Effect", "ExpInfo", "Param", "plus_minus", "register"]


@dataclass(frozen=True)
class ExpInfo(Conditions):
    """The covariates of one experiment that an effect may use (SI units)."""

    @property
    def pair(self) -> str:
        """Material pair label, e.g. ``glass-PP``."""
        return f"{self.heavy}-{self.light}"

    @classmethod
    def of(cls, m: Any) -> ExpInfo:
        """From a :class:`granseg.maps.Map` (or anything with the same attributes)."""
        return cls(str(m.name), str(m.heavy), str(m.light), float(m.rho_h), float(m.rho_l),
                   float(m.c0), float(m.M_g), float(m.M_w), cell=dict(getattr(m, "cell", {})))


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


#: The baseline's global parameters and their physical search ranges.
BASE_PARAMS = (
    Param("k", 0.2, 1.6, 0.70, 4e-3, "-"),
    Param("delta_over_H", 0.05, 0.6, 0.18, 1.5e-3, "-"),
)


def plus_minus(v: float, e: float | None, fmt: str = ".3g") -> str:
    """``v ± e`` for the laws' text (just ``v`` when the error is unknown)."""
    if e is None or not math.isfinite(e):
        return f"{v:{fmt}}"
    return f"{v:{fmt}} ± {e:.2g}"


class Effect:
    """Base class and the baseline model itself (no extra parameter)."""

    name: ClassVar[str] = "baseline"
    description: ClassVar[str] = "docs/model.md as it stands: one k and one delta/H for every experiment."
    #: the covariate this cause is expected to correlate with (for the evidence figures)
    covariate: ClassVar[str | None] = None
    #: fitted by the diagnosis (False: only hidden in virtual campaigns, to test "unexplained")
    catalogued: ClassVar[bool] = True
    #: strengths a virtual campaign accepts, and the range :meth:`draw` picks |strength| from
    strength_limits: ClassVar[tuple[float, float]] = (-5.0, 5.0)
    draw_range: ClassVar[tuple[float, float] | None] = None

    # ------------------------------------------------------------------ the fit

    def extra(self, exps: Sequence[ExpInfo]) -> list[Param]:
        """Extra parameters beyond the baseline's ``k`` and ``delta_over_H``."""
        return []

    def params(self, exps: Sequence[ExpInfo]) -> list[Param]:
        """Every fitted parameter, baseline ones first."""
        return [*BASE_PARAMS, *self.extra(exps)]

    def solver_params(self, x: Mapping[str, float], exp: ExpInfo) -> dict[str, float]:
        """Solver keyword parameters for experiment ``exp`` at parameters ``x``.

        The baseline passes ``k``, ``delta_over_H`` and any other model
        parameter of docs/model.md in ``x`` (a calibration may free e.g. ``b``) to
        the solver unchanged; an extension turns its own parameters into
        model parameters.
        """
        return {**exp.case(), **{k: float(v) for k, v in x.items() if k in PARAMETERS}}

    def time_shift(self, x: Mapping[str, float], exp: ExpInfo) -> float:
        """Delay [s] between the plate start and the model's t = 0."""
        return 0.0

    def observe(self, x: Mapping[str, float], exp: ExpInfo, layers: np.ndarray) -> np.ndarray:
        """What the camera sees given the bed's layer means (n_t, n_layers); identity here."""
        return layers

    def law(self, x: Mapping[str, float], err: Mapping[str, float]) -> str:
        """A one-line, human-readable statement of the fitted effect."""
        return (f"k = {plus_minus(x['k'], err.get('k'))}, "
                f"delta/H = {plus_minus(x['delta_over_H'], err.get('delta_over_H'))}")

    # ------------------------------------------------------------------ virtual campaigns

    def hidden(self, strength: float, exp: ExpInfo, settings: Mapping[str, float]) -> dict[str, float]:
        """The extra parameters that hide this effect at ``strength`` in experiment ``exp``.

        ``settings`` are the campaign's ``effect_params`` (e.g. a time scale).
        By default the strength is the value of the effect's one extra
        parameter (none for the baseline); an effect with several, or with a
        strength in other units, says how.
        """
        extra = self.extra([exp])
        if len(extra) > 1:
            raise NotImplementedError(f"effect {self.name!r}: hidden() must say what a strength means")
        return {p.name: strength for p in extra}

    def draw(self, rng: np.random.Generator) -> tuple[float, dict[str, float]]:
        """A random ``(strength, settings)`` a 16-experiment campaign can resolve."""
        if self.draw_range is None:
            raise ValueError(f"effect {self.name!r} has no range for random strengths")
        return float(rng.uniform(*self.draw_range)), {}

    def check_strength(self, strength: float | None) -> float:
        """``strength`` as a float inside :attr:`strength_limits`, else ValueError naming it."""
        if strength is None or not math.isfinite(float(strength)):
            raise ValueError(f"strength: a finite number is required for effect {self.name!r}")
        lo, hi = self.strength_limits
        if not lo <= float(strength) <= hi:
            raise ValueError(f"strength = {strength} for {self.name!r} is out of range [{lo}, {hi}]")
        return float(strength)


class Baseline(Effect):
    """The baseline itself (the reference of every comparison)."""


#: Every effect by name (the baseline under ``baseline``), filled by :func:`register`.
REGISTRY: dict[str, type[Effect]] = {"baseline": Baseline}


def register(cls: type[Effect]) -> type[Effect]:
    """Class decorator: make an effect known to the diagnosis and the virtual campaigns."""
    if not (isinstance(cls, type) and issubclass(cls, Effect)):
        raise TypeError(f"register: {cls!r} is not an Effect subclass")
    if cls.name in REGISTRY and REGISTRY[cls.name] is not cls:
        raise ValueError(f"register: an effect named {cls.name!r} is already registered")
    REGISTRY[cls.name] = cls
    return cls
