"""Open-world corrections: each constitutive law of docs/model.md made flexible in turn.

When no catalogue cause explains a misfit, the diagnosis asks every law
whether a smooth correction of it predicts the held-out experiments better:

================== ============================================ ==========
law (JSON name)    what is corrected                            variable
================== ============================================ ==========
segregation_flux   the segregation speed w, as a factor of c    c
diffusivity        the diffusivity D, as a factor of depth      z / H
diffusivity        the diffusivity D, as a factor of time       t / T
shear_profile      the shear rate (so w and D), factor of depth z / H
rates_in_time      both w and D, as a factor of time            t / T
observation        the wall's view: c_wall = c + s(z/H) c(1-c)  z / H
================== ============================================ ==========

T is the campaign's median run length (later times keep the factor at T). A
correction is a log-factor on the core's 17-knot tables (``src/laws.rs``; the
observation's s lives here in Python), spanned by :data:`N_BASIS` quadratic
B-splines with evenly spaced interior knots, orthonormalised so that one unit of a coefficient is an RMS
log-factor of 1 over the knots. A ridge prior (sd :data:`PRIOR_SD` per
coefficient, :class:`~granseg.fitting.effects.Param` ``prior_sd``) keeps the
shape smooth and small unless the data insist. The flux's constant level is
removed from its basis: it is the baseline's k.

Every correction is an :class:`~granseg.fitting.effects.Effect` (not in the
catalogue), so it is fitted through the same sweep, the same least squares
and the same leave-one-experiment-out as the catalogue causes.
:func:`shape` turns a fit into the law's factor with its 95 % band,
:func:`sentence` into words, :func:`literature_form` into a known form with
its fitted constants where one lies inside the band.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from granseg.fitting.effects import Effect, ExpInfo, Param
from granseg.fitting.solve import Fit

__all__ = ["KNOTS", "LAWS", "N_BASIS", "PRIOR_SD", "LawCorrection", "basis", "build", "literature_form",
           "sentence", "shape", "table_params"]

#: The core's table knots on [0, 1] (``N_KNOTS`` in src/laws.rs).
KNOTS = np.linspace(0.0, 1.0, 17)
#: Quadratic B-splines per law (7 for the flux, whose constant is k): 8 resolve a burst of mixing a
#: quarter of T long, where 6 left a misfit 1.07 x the counted floor (mixing_burst, seed 2001,
#: independent noise; that campaign has since been part of the tuning set).
N_BASIS = 8
#: Prior sd of each coefficient (an RMS log-factor over the knots).
PRIOR_SD = 1.0
#: Largest |log-factor| the core accepts.
MAX_LOG_FACTOR = 6.0
#: The band of :func:`shape`: +- this many standard errors (95 %).
Z_BAND = 1.96


def basis(n: int = N_BASIS, centred: bool = False) -> np.ndarray:
    """(17, r) basis at :data:`KNOTS`: n quadratic B-splines, orthonormalised and scaled to RMS 1.

    ``centred`` removes the constant (r = n - 1), for a law whose overall
    level another parameter already sets.
    """
    deg = 2
    inner = np.linspace(0.0, 1.0, n - deg + 1)
    t = np.concatenate([[0.0] * deg, inner, [1.0] * deg])
    from scipy.interpolate import BSpline  # here: see granseg.fitting on import time

    B = BSpline.design_matrix(KNOTS, t, deg).toarray()
    if centred:
        B = B - B.mean(axis=0)
    U, sv, _ = np.linalg.svd(B, full_matrices=False)
    return U[:, sv > 1e-9 * sv.max()] * math.sqrt(KNOTS.size)


def table_params(table: str, log_factor: np.ndarray, time_scale: float) -> dict[str, float]:
    """Solver parameters setting the core's ``table`` to ``log_factor`` at the 17 knots (clipped to
    the core's limit) and the time tables' scale ``law_time`` [s]."""
    knots = np.clip(np.asarray(log_factor, dtype=float), -MAX_LOG_FACTOR, MAX_LOG_FACTOR)
    return {**{f"{table}_{j}": float(v) for j, v in enumerate(knots)}, "law_time": float(time_scale)}


class LawCorrection(Effect):
    """A smooth correction of one law (module doc); ``time_scale`` [s] is T of the time laws."""

    name: ClassVar[str] = "law"
    #: the JSON ``departure.law``
    law_name: ClassVar[str] = ""
    #: the core's table (None: applied in :meth:`observe`)
    table: ClassVar[str | None] = None
    #: what the table's [0, 1] stands for
    variable: ClassVar[str] = ""
    centred: ClassVar[bool] = False
    catalogued = False
    #: what the factor multiplies, for the figures and the sentence
    quantity: ClassVar[str] = ""

    def __init__(self, time_scale: float = 3600.0) -> None:
        if not (math.isfinite(time_scale) and time_scale > 0):
            raise ValueError(f"time_scale = {time_scale!r}: a positive duration in seconds is required")
        self.time_scale = float(time_scale)
        self.phi = basis(N_BASIS, self.centred)

    def extra(self, exps: Sequence[ExpInfo]) -> list[Param]:
        return [Param(f"a{j}", -4.0, 4.0, 0.0, 0.01, "-", prior_sd=PRIOR_SD) for j in range(self.phi.shape[1])]

    def coefficients(self, x: Mapping[str, float]) -> np.ndarray:
        return np.array([float(x[f"a{j}"]) for j in range(self.phi.shape[1])])

    def log_factor(self, x: Mapping[str, float]) -> np.ndarray:
        """The correction at the 17 knots (log of the factor; s itself for the observation)."""
        return self.phi @ self.coefficients(x)

    def solver_params(self, x: Mapping[str, float], exp: ExpInfo) -> dict[str, float]:
        out = super().solver_params(x, exp)
        if self.table is not None:
            out.update(table_params(self.table, self.log_factor(x), self.time_scale))
        return out

    def factor(self, log_factor: np.ndarray) -> np.ndarray:
        """The reported factor for a log-factor (the observation overrides)."""
        return np.exp(log_factor)

    def law(self, x: Mapping[str, float], err: Mapping[str, float]) -> str:
        f = self.factor(self.log_factor(x))
        i = int(np.argmax(np.abs(np.log(f))))
        return (f"{self.quantity} x a smooth factor of {self.variable}: {f.min():.3g} to {f.max():.3g} "
                f"(furthest from 1 at {self.variable} = {self._x_label(KNOTS[i])})")

    def _x_label(self, x: float) -> str:
        if self.variable == "t/T":
            return f"{x:.2f} ({x * self.time_scale / 60:.0f} min)"
        return f"{x:.2f}"


class SegregationFlux(LawCorrection):
    name = "law_segregation_flux"
    law_name = "segregation_flux"
    table = "law_flux_c"
    variable = "c"
    centred = True
    quantity = "the segregation speed w"
    description = "The segregation flux w c (1 - c) times a smooth factor of the heavy share c (not only c (1 - c))."


class DiffusivityDepth(LawCorrection):
    name = "law_diffusivity_depth"
    law_name = "diffusivity"
    table = "law_diff_z"
    variable = "z/H"
    quantity = "the diffusivity D"
    description = "The diffusivity b gdot D_p^2 times a smooth factor of the height z/H above the driven plate."


class DiffusivityTime(LawCorrection):
    name = "law_diffusivity_time"
    law_name = "diffusivity"
    table = "law_diff_t"
    variable = "t/T"
    quantity = "the diffusivity D"
    description = "The diffusivity b gdot D_p^2 times a smooth factor of the time since the plate started."


class ShearProfile(LawCorrection):
    name = "law_shear_profile"
    law_name = "shear_profile"
    table = "law_shear_z"
    variable = "z/H"
    quantity = "the shear rate"
    description = "The exponential shear-rate profile times a smooth factor of z/H (so w, D and I follow it)."


class RatesInTime(LawCorrection):
    name = "law_rates_in_time"
    law_name = "rates_in_time"
    table = "law_rate_t"
    variable = "t/T"
    quantity = "both rates (w and D)"
    description = "The segregation speed and the diffusivity together times a smooth factor of time."


class Observation(LawCorrection):
    name = "law_observation"
    law_name = "observation"
    variable = "z/H"
    quantity = "the heavy share the wall shows"
    description = "The wall's view of the bulk: c_wall = c + s(z/H) c (1 - c), a smooth s of the height."

    def observe(self, x: Mapping[str, float], exp: ExpInfo, layers: np.ndarray) -> np.ndarray:
        n = layers.shape[1]
        s = np.clip(np.interp((np.arange(n) + 0.5) / n, KNOTS, self.log_factor(x)), -1.0, 1.0)
        return layers + s * layers * (1.0 - layers)

    def factor(self, log_factor: np.ndarray) -> np.ndarray:
        # c_wall / c where the bed is half mixed: 1 + s / 2
        return 1.0 + 0.5 * np.clip(log_factor, -1.0, 1.0)


#: Every correction, in the order the diagnosis tries them.
LAWS: tuple[type[LawCorrection], ...] = (SegregationFlux, DiffusivityDepth, DiffusivityTime, ShearProfile,
                                         RatesInTime, Observation)


def build(time_scale: float, selected: Sequence[str] | None = None) -> list[LawCorrection]:
    """The corrections to try (default all), ``time_scale`` [s] the T of the time laws."""
    known = {cls.name: cls for cls in LAWS}
    chosen = list(known) if selected is None else list(selected)
    for n in chosen:
        if n not in known:
            raise ValueError(f"unknown law correction {n!r}; known: {', '.join(known)}")
    return [known[n](time_scale) for n in chosen]


# --------------------------------------------------------------------------- the fitted shape


def _coefficient_block(f: Fit) -> tuple[np.ndarray, np.ndarray]:
    keys = f.keys
    idx = [keys.index(f"a{j}") for j in range(f.effect.phi.shape[1])]  # type: ignore[attr-defined]
    return f.x[idx], f.cov[np.ix_(idx, idx)]


def shape(f: Fit) -> dict[str, Any]:
    """The fitted factor at the knots with its 95 % band (cluster covariance), JSON-ready."""
    law: LawCorrection = f.effect  # type: ignore[assignment]
    a, cov = _coefficient_block(f)
    g = law.phi @ a
    sd = np.sqrt(np.clip(np.einsum("ij,jk,ik->i", law.phi, np.nan_to_num(cov), law.phi), 0.0, None))
    out: dict[str, Any] = {
        "variable": law.variable, "x": KNOTS.tolist(), "factor": law.factor(g).tolist(),
        "lo": law.factor(g - Z_BAND * sd).tolist(), "hi": law.factor(g + Z_BAND * sd).tolist(),
        "log_sd": sd.tolist(), "band": "95 % (cluster-robust covariance over experiments)",
    }
    if law.variable == "t/T":
        out["time_scale_s"] = law.time_scale
    return out


def _significant(sh: Mapping[str, Any]) -> np.ndarray:
    lo, hi = np.asarray(sh["lo"]), np.asarray(sh["hi"])
    return (lo > 1.0) | (hi < 1.0)


def sentence(f: Fit, sh: Mapping[str, Any] | None = None) -> str:
    """One quotable sentence about the fitted departure."""
    law: LawCorrection = f.effect  # type: ignore[assignment]
    sh = shape(f) if sh is None else sh
    x, fac = np.asarray(sh["x"]), np.asarray(sh["factor"])
    if law.law_name == "segregation_flux":
        lo_c, hi_c = float(np.interp(0.1, x, fac)), float(np.interp(0.9, x, fac))
        r = lo_c / hi_c
        if r >= 1.0:
            return (f"Heavy grains sink through a light-rich bed faster than light grains rise through a "
                    f"heavy-rich one: the segregation speed is {r:.2g} times higher at c = 0.1 than at c = 0.9.")
        return (f"Light grains rise through a heavy-rich bed faster than heavy grains sink through a "
                f"light-rich one: the segregation speed is {1 / r:.2g} times higher at c = 0.9 than at c = 0.1.")
    sig = _significant(sh)
    if not sig.any():
        return (f"{law.quantity[0].upper()}{law.quantity[1:]} departs from the baseline's by at most a factor "
                f"{float(np.exp(np.abs(np.log(fac)).max())):.2g}, within the 95 % band everywhere.")
    peaks = _extremes(np.log(fac), sig)
    if law.law_name == "observation":
        parts = [f"{fac[i]:.2g} times the bulk's at z/H = {law._x_label(float(x[i]))}" for i in peaks]
        return ("The wall does not show the bulk: where the bed is half mixed, the wall's heavy share is "
                + " and ".join(parts) + ".")
    what = {"diffusivity": "Mixing by diffusion is", "shear_profile": "The shear rate is",
            "rates_in_time": "Segregation and mixing are both"}[law.law_name]
    base = {"diffusivity": "than b gdot D_p^2 gives", "shear_profile": "than the exponential profile gives",
            "rates_in_time": "than the baseline's rates"}[law.law_name]
    up, down = ("higher", "lower") if law.law_name == "shear_profile" else ("stronger", "weaker")
    parts = [f"{max(fac[i], 1 / fac[i]):.2g} times {up if fac[i] > 1 else down} at {law.variable} = "
             f"{law._x_label(float(x[i]))}" for i in peaks]
    return f"{what} " + " and ".join(parts) + f" {base}."


def _extremes(g: np.ndarray, sig: np.ndarray) -> list[int]:
    """Up to two knots where the log-factor ``g`` peaks (largest |g| first) among the significant ones,
    returned in order of x."""
    idx = [i for i in range(g.size) if sig[i]
           and (i == 0 or abs(g[i]) >= abs(g[i - 1]) or np.sign(g[i]) != np.sign(g[i - 1]))
           and (i == g.size - 1 or abs(g[i]) >= abs(g[i + 1]) or np.sign(g[i]) != np.sign(g[i + 1]))]
    idx = sorted(idx or [int(np.argmax(np.where(sig, np.abs(g), -1.0)))], key=lambda i: -abs(g[i]))
    first = idx[0]
    other = [i for i in idx[1:] if np.sign(g[i]) != np.sign(g[first]) or abs(i - first) > 3]
    return sorted([first, *other[:1]])


# --------------------------------------------------------------------------- literature forms


@dataclass(frozen=True)
class Form:
    """A known functional form of a law's log-factor g(x; constants, delta/H)."""

    law: str
    variable: str
    name: str
    expression: str
    reference: str
    constants: tuple[str, ...]
    start: tuple[float, ...]
    g: Callable[[np.ndarray, np.ndarray, float], np.ndarray]
    lower: tuple[float, ...]
    upper: tuple[float, ...]
    centred: bool = False


def _asym(x: np.ndarray, p: np.ndarray, d: float) -> np.ndarray:
    return np.log(np.clip(1.0 + p[0] * (1.0 - 2.0 * x), 1e-6, None))


def _power(x: np.ndarray, p: np.ndarray, d: float) -> np.ndarray:
    # D ~ gdot^q with gdot ~ exp(-z/delta): log-factor = C + (1 - q) z / delta
    return p[0] + (1.0 - p[1]) * x / d


def _gauss(x: np.ndarray, p: np.ndarray, d: float) -> np.ndarray:
    # gdot ~ exp(-(z / w)^2) instead of exp(-z / delta): log-factor = C + z/delta - (z/w)^2
    return p[0] + x / d - (x / p[1]) ** 2


FORMS: tuple[Form, ...] = (
    Form("segregation_flux", "c", "asymmetric flux", "w c (1 - c) (1 + A (1 - 2 c))",
         "asymmetric segregation flux in the spirit of Gajjar & Gray (2014, J. Fluid Mech. 757)",
         ("A",), (0.0,), _asym, (-0.99,), (0.99,), centred=True),
    Form("diffusivity", "z/H", "power of the shear rate", "D = b' gdot^q D_p^2 (gdot in 1/s)",
         "shear-rate scaling of self-diffusion, q = 1 in Utter & Behringer (2004, Phys. Rev. E 69)",
         ("C", "q"), (0.0, 1.0), _power, (-np.inf, -np.inf), (np.inf, np.inf)),
    Form("shear_profile", "z/H", "Gaussian shear band", "gdot ~ exp(-(z / w)^2), w in units of H",
         "error-function velocity profiles of wide shear zones, Fenistein & van Hecke (2003, Nature 425)",
         ("C", "w"), (0.0, 0.3), _gauss, (-np.inf, 1e-3), (np.inf, np.inf)),
)


def literature_form(f: Fit, sh: Mapping[str, Any] | None = None) -> dict[str, Any] | None:
    """The known form (:data:`FORMS`) whose best fit lies inside the fitted band at every knot, if any."""
    from scipy.optimize import least_squares  # here: see granseg.fitting on import time

    law: LawCorrection = f.effect  # type: ignore[assignment]
    sh = shape(f) if sh is None else sh
    a, _ = _coefficient_block(f)
    g = law.phi @ a
    sd = np.maximum(np.asarray(sh["log_sd"]), 1e-6)
    d = float(f.values().get("delta_over_H", 0.18))
    best = None
    for form in FORMS:
        if form.law != law.law_name or form.variable != law.variable:
            continue

        def resid(p: np.ndarray, form: Form = form) -> np.ndarray:
            h = form.g(KNOTS, p, d)
            if form.centred:
                h = h - h.mean()
            return (h - g) / sd

        sol = least_squares(resid, np.array(form.start, dtype=float), bounds=(form.lower, form.upper))
        dev = np.abs(sol.fun)
        if np.all(dev <= Z_BAND) and (best is None or dev.max() < best[0]):
            consts = dict(zip(form.constants, map(float, sol.x), strict=True))
            curve = sol.fun * sd + g  # the form's log-factor at the knots
            best = (float(dev.max()), {"name": form.name, "expression": form.expression,
                                       "reference": form.reference, "constants": consts,
                                       "max_deviation_sd": float(dev.max()),
                                       "factor": law.factor(curve).tolist()})
    return None if best is None else best[1]
