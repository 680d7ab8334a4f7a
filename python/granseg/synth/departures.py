"""Effects outside the catalogue, to hide in virtual campaigns: the open world's test cases.

Each is a law of docs/model.md changed in a form of this generator's own, which
none of the diagnosis' fit bases contains (:mod:`granseg.fitting.laws` fits
quadratic B-splines; these are tanh steps, Gaussian bumps and smooth windows,
sampled onto the core's 17-knot tables):

================== ================== ==================================================
effect             law it departs     form (strength s)
================== ================== ==================================================
flux_asymmetry     segregation_flux   w factor exp(-s tanh((c - 1/2) / 0.3))
mixing_layer       diffusivity (z)    D factor 1 + s exp(-((z/H - z0) / 0.1)^2)
mixing_burst       diffusivity (t)    D factor 1 + s between t_on and t_off (60 s edges)
shear_gaussian     shear_profile      gdot ~ exp(-(z / (s H))^2) instead of exp(-z/delta)
camera_sag         none (unexplained) the camera drifts up by s layers over each run
================== ================== ==================================================

``camera_sag`` is the control: a time-dependent error of the observation that
no law correction can express, which the diagnosis must call ``unexplained``.
None is catalogued: the diagnosis never fits them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from granseg.fitting.effects import Effect, ExpInfo, Param, register
from granseg.fitting.laws import KNOTS, table_params
from granseg.model import defaults

__all__ = ["CameraSag", "FluxAsymmetry", "MixingBurst", "MixingLayer", "ShearGaussian"]

#: The time scale of the hidden time tables [s] (the knots' t = 1).
LAW_TIME = 3600.0


class _Departure(Effect):
    """A hidden law departure: strength (and settings) -> one core table."""

    catalogued = False
    table: str = ""
    #: the JSON law the diagnosis should name
    law: str = ""

    def extra(self, exps: Sequence[ExpInfo]) -> list[Param]:
        return [Param("strength", *self.strength_limits, 0.0, 0.01)]

    def hidden(self, strength: float, exp: ExpInfo, settings: Mapping[str, float]) -> dict[str, float]:
        return {"strength": strength, **{f"setting_{k}": float(v) for k, v in settings.items()}}

    def log_factor(self, x: Mapping[str, float]) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def solver_params(self, x: Mapping[str, float], exp: ExpInfo) -> dict[str, float]:
        return {**super().solver_params(x, exp), **table_params(self.table, self.log_factor(x), LAW_TIME)}


@register
class FluxAsymmetry(_Departure):
    name = "flux_asymmetry"
    law, table = "segregation_flux", "law_flux_c"
    description = "Heavy grains sink through a light-rich bed faster than light ones rise through a heavy-rich one."
    strength_limits = (-3.0, 3.0)
    draw_range = (0.6, 1.0)

    def log_factor(self, x: Mapping[str, float]) -> np.ndarray:
        return -x["strength"] * np.tanh((KNOTS - 0.5) / 0.3)


@register
class MixingLayer(_Departure):
    name = "mixing_layer"
    law, table = "diffusivity", "law_diff_z"
    description = "Extra mixing in a band of the bed (around z0 = 0.45 H unless set): D x (1 + s bump)."
    strength_limits = (0.0, 50.0)
    draw_range = (3.0, 6.0)

    def log_factor(self, x: Mapping[str, float]) -> np.ndarray:
        z0 = x.get("setting_z0", 0.45)
        return np.log1p(x["strength"] * np.exp(-(((KNOTS - z0) / 0.1) ** 2)))


@register
class MixingBurst(_Departure):
    name = "mixing_burst"
    law, table = "diffusivity", "law_diff_t"
    description = "Extra mixing for a while after the start (5 to 20 min unless set): D x (1 + s)."
    strength_limits = (0.0, 50.0)
    draw_range = (3.0, 6.0)

    def log_factor(self, x: Mapping[str, float]) -> np.ndarray:
        t = KNOTS * LAW_TIME
        on, off = x.get("setting_t_on", 300.0), x.get("setting_t_off", 1200.0)
        window = 0.5 * (np.tanh((t - on) / 60.0) - np.tanh((t - off) / 60.0))
        return np.log1p(x["strength"] * window)


@register
class ShearGaussian(_Departure):
    name = "shear_gaussian"
    law, table = "shear_profile", "law_shear_z"
    description = "A Gaussian shear band gdot ~ exp(-(z / (s H))^2) in place of the exponential."
    strength_limits = (0.05, 2.0)
    draw_range = (0.3, 0.45)

    def log_factor(self, x: Mapping[str, float]) -> np.ndarray:
        d = x.get("delta_over_H", defaults()["delta_over_H"])
        return KNOTS / d - (KNOTS / x["strength"]) ** 2


@register
class CameraSag(Effect):
    """The camera drifts up by ``s`` layers over each run: no law of the model can produce it."""

    name = "camera_sag"
    catalogued = False
    law = ""
    description = "The camera's view drifts up by s layers, linearly over each run (an observation error in time)."
    strength_limits = (-5.0, 5.0)
    draw_range = (1.0, 2.0)

    def extra(self, exps: Sequence[ExpInfo]) -> list[Param]:
        return [Param("sag", *self.strength_limits, 0.0, 0.01)]

    def observe(self, x: Mapping[str, float], exp: ExpInfo, layers: np.ndarray) -> np.ndarray:
        n_t, n = layers.shape
        j = np.arange(n, dtype=float)
        out = np.empty_like(layers)
        for i in range(n_t):
            # the camera's layer j sees the bed's layer j + shift (clamped at the walls)
            shift = x["sag"] * i / max(n_t - 1, 1)
            out[i] = np.interp(j + shift, j, layers[i])
        return out
