"""A measured streamwise velocity profile and its shear-band fit: what ``granseg velocity``
writes, what a DEM run's dumps give, and what ``--velocity`` reads back.

The profile is one value per one-diameter layer: heights ``z`` [m] above the
plate, mean streamwise speed ``v`` [m/s] at the outer wall (or in the bulk, for
a DEM run) and its standard error ``v_err``. The fit is docs/model.md's
v(z) = v1 + (v0 - v1) exp(-z / delta) (:func:`granseg.fit.fit_shear_band`).

JSON (``to_dict`` / :func:`load_profile`)::

    {"delta_over_H": 0.18, "delta_over_H_stderr": 0.004, "v0": 0.233, "v0_stderr": ...,
     "v1": 0.0, "v1_stderr": ..., "H": 0.09, "layer_correlation": 0.5,
     "profile": {"z": [...], "v": [...], "v_err": [...], "n": [...]},
     "fit": {...the intervals...}, "conditions": {"name": ..., "M_g": ..., "M_w": ...},
     "sources": [...], "notes": [...the measurement's...], "fit_notes": [...the fit's...]}
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from granseg._io import save_json
from granseg.errors import MapFormatError
from granseg.fit import FitResult, fit_shear_band, shear_band_law

__all__ = ["ShearBandLaw", "VelocityProfile", "load_profile", "load_velocity", "measured_params"]


@dataclass(frozen=True, eq=False)
class VelocityProfile:
    """One bed's measured profile (SI units) and its shear-band fit.

    ``n`` counts the displacements (or grains) behind each layer's value; ``conditions``
    holds what identifies the bed (name, heavy, light, M_g, M_w, ...: a
    :class:`granseg.maps.Conditions`' fields, those known); ``sources`` the recordings or
    dumps it came from; ``notes`` what a reader must know (layers left out, a poor fit).
    """

    z: np.ndarray
    v: np.ndarray
    v_err: np.ndarray
    H: float
    fit: FitResult
    n: np.ndarray | None = None
    conditions: Mapping[str, Any] = field(default_factory=dict)
    sources: Sequence[str] = ()
    notes: Sequence[str] = ()
    layer_correlation: float = 0.0

    @classmethod
    def fitted(cls, z: Any, v: Any, v_err: Any, H: float, *, layer_correlation: float = 0.0,
               **kw: Any) -> VelocityProfile:
        """The profile with its fit (layers without a value, NaN, are kept and skipped by the fit).

        ``layer_correlation``: the correlation of neighbouring layers' errors the fit assumes
        (:func:`granseg.fit.fit_shear_band`); 0 for independent layers (a DEM run's bulk)."""
        z, v, v_err = (np.asarray(a, dtype=float).ravel() for a in (z, v, v_err))
        ok = np.isfinite(v) & np.isfinite(v_err)
        fit = fit_shear_band(z[ok], v[ok], v_err[ok], H=H, layer_correlation=layer_correlation)
        return cls(z, v, v_err, float(H), fit, layer_correlation=float(layer_correlation), **kw)

    @property
    def delta_over_H(self) -> float:
        return self.fit.params["delta_over_H"]

    @property
    def fit_notes(self) -> list[str]:
        """What the fit says of itself (not converged, an interval cut by a bound)."""
        out = [] if self.fit.converged else [f"the shear-band fit did not converge: {self.fit.message}"]
        return out + (self.fit.uncertainty.warnings() if self.fit.uncertainty is not None else [])

    @property
    def M_tilde(self) -> float | None:
        """Normalised load M~ = M_w / M_g [-] when the conditions give both."""
        c = self.conditions
        return float(c["M_w"]) / float(c["M_g"]) if "M_w" in c and "M_g" in c else None

    def to_dict(self) -> dict[str, Any]:
        p, e = self.fit.params, self.fit.stderr
        out: dict[str, Any] = {}
        for name in ("delta_over_H", "v0", "v1"):
            out[name] = p.get(name, self.conditions.get(name))
            out[f"{name}_stderr"] = e.get(name)
        out.update({
            "H": self.H,
            "profile": {"z": self.z.tolist(), "v": self.v.tolist(), "v_err": self.v_err.tolist(),
                        **({"n": np.asarray(self.n).tolist()} if self.n is not None else {})},
            "fit": self.fit.uncertainty.to_dict() if self.fit.uncertainty is not None else None,
            "rms_residual_in_errors": float(np.sqrt(self.fit.mse)),
            "layer_correlation": self.layer_correlation,
            "conditions": dict(self.conditions),
            "sources": list(self.sources),
            "notes": list(self.notes),
            "fit_notes": self.fit_notes,
        })
        return out

    def save(self, path: str | os.PathLike, force: bool = False) -> Path:
        """Write the JSON atomically (an existing file is kept unless ``force``)."""
        return save_json(path, self.to_dict(), force=force)


def load_profile(path: str | os.PathLike) -> VelocityProfile:
    """Read a profile JSON written by :meth:`VelocityProfile.save` and refit it, so the numbers
    used are those of the data in the file; a file without the keys raises
    :class:`granseg.MapFormatError` naming the file and the key."""
    path = Path(path)
    try:
        raw = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise MapFormatError(f"{path}: cannot read a velocity profile ({exc})") from None
    prof = raw.get("profile") if isinstance(raw, dict) else None
    if not isinstance(prof, dict):
        raise MapFormatError(f"{path}: 'profile': missing (expected z, v, v_err lists)")
    arrays = {}
    for key in ("z", "v", "v_err"):
        try:
            arrays[key] = np.asarray([np.nan if x is None else x for x in prof[key]], dtype=float)
        except (KeyError, TypeError, ValueError):
            raise MapFormatError(f"{path}: 'profile.{key}': missing or not a list of numbers") from None
    if not (arrays["z"].shape == arrays["v"].shape == arrays["v_err"].shape) or arrays["z"].size < 3:
        raise MapFormatError(f"{path}: 'profile': z, v and v_err need the same length, at least 3")
    H = raw.get("H")
    if not isinstance(H, (int, float)) or not H > 0:
        raise MapFormatError(f"{path}: 'H': the bed height [m] must be a number > 0, got {H!r}")
    phi = raw.get("layer_correlation") or 0.0  # files written before it was recorded: independent layers
    if not isinstance(phi, (int, float)) or not 0 <= phi < 1:
        raise MapFormatError(f"{path}: 'layer_correlation': must be a number in [0, 1), got {phi!r}")
    return VelocityProfile.fitted(arrays["z"], arrays["v"], arrays["v_err"], float(H), layer_correlation=float(phi),
                                  n=np.asarray(prof["n"]) if prof.get("n") is not None else None,
                                  conditions=raw.get("conditions") or {}, sources=raw.get("sources") or [],
                                  notes=raw.get("notes") or [])


@dataclass(frozen=True)
class ShearBandLaw:
    """delta/H = delta_over_H_ref (M~ / 0.5)^(-exponent) measured over several beds
    (``granseg velocity-law``), with the standard errors of both."""

    delta_over_H_ref: float
    exponent: float
    stderr: Mapping[str, float] = field(default_factory=dict)
    source: str = ""

    def delta_over_H(self, M_tilde: float) -> float:
        return float(shear_band_law(M_tilde, self.delta_over_H_ref, self.exponent))


def load_velocity(path: str | os.PathLike) -> VelocityProfile | ShearBandLaw:
    """A ``--velocity`` file: one bed's profile (``granseg velocity``) or a law over beds
    (``granseg velocity-law --json``), told apart by their keys."""
    path = Path(path)
    try:
        raw = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise MapFormatError(f"{path}: cannot read a velocity file ({exc})") from None
    if isinstance(raw, dict) and "profile" in raw:
        return load_profile(path)
    try:
        params = raw["params"]
        ref, exp = float(params["delta_over_H_ref"]), float(params["exponent"])
    except (KeyError, TypeError, ValueError):
        raise MapFormatError(f"{path}: neither a velocity profile ('profile') nor a shear-band law "
                             f"('params' with delta_over_H_ref and exponent)") from None
    if not (ref > 0 and np.isfinite(exp)):
        raise MapFormatError(f"{path}: 'params': delta_over_H_ref must be > 0 and exponent finite")
    return ShearBandLaw(ref, exp, {k: float(v) for k, v in (raw.get("stderr") or {}).items() if v is not None},
                        str(path))


SHAPES = ("exponential", "tabulated")


def measured_params(velocity: VelocityProfile | ShearBandLaw, M_tilde: Sequence[float], *,
                    shape: str = "exponential", cells: Sequence[Mapping[str, float]] | None = None
                    ) -> list[dict[str, float]]:
    """The model parameters a measurement fixes for experiments of normalised loads ``M_tilde``:
    delta/H (a profile: its own for every experiment; a law: at each one's M~) and, for a
    profile whose fit freed it, the lid's speed v1 [m/s].

    ``shape="tabulated"`` (a profile only) makes the model's shear rate the measured one, not its
    exponential fit: the measured -dv/dz enters as the shear-profile law's factor on the
    exponential (``law_shear_z_*``, 17 knots in z/H), so a linear or S-shaped band is modelled
    as it is. ``cells`` gives each experiment's model constants (docs/model.md names: the plate speed
    and bed height the factor is taken against; default docs/model.md's)."""
    if shape not in SHAPES:
        raise ValueError(f"velocity shape {shape!r}: choose one of {', '.join(SHAPES)}")
    if isinstance(velocity, ShearBandLaw):
        if shape == "tabulated":
            raise ValueError("velocity shape 'tabulated' needs a measured profile, not a shear-band law")
        return [{"delta_over_H": velocity.delta_over_H(m)} for m in M_tilde]
    out = {"delta_over_H": velocity.delta_over_H}
    if "v1" in velocity.fit.params:
        out["v1"] = max(0.0, velocity.fit.params["v1"])
    if shape == "exponential":
        return [dict(out) for _ in M_tilde]
    cells = list(cells) if cells is not None else [{} for _ in M_tilde]
    return [{**out, **_shear_factor(velocity, {**out, **cell})} for cell in cells]


def _shear_factor(prof: VelocityProfile, params: Mapping[str, float]) -> dict[str, float]:
    """law_shear_z_* so that the model's shear rate is the profile's -dv/dz (clipped where the
    bed barely moves: the factor's range is the core's, |log| <= 6)."""
    from granseg.fitting.laws import KNOTS, MAX_LOG_FACTOR
    from granseg.model import defaults

    p = {**defaults(), **params}
    v0 = p["rpm"] * 2 * np.pi / 60 * p["D_out"] / 2
    ok = np.isfinite(prof.v)
    z, v = prof.z[ok], prof.v[ok]
    if z.size < 2:
        raise ValueError("velocity shape 'tabulated': the profile has fewer than two measured layers")
    mid = (z[1:] + z[:-1]) / 2 / prof.H
    rate = np.maximum(-np.diff(v) / np.diff(z), 0.0)
    measured = np.interp(KNOTS, mid, rate)
    delta = p["delta_over_H"]
    reference = (v0 - p["v1"]) / (delta * p["H"]) * np.exp(-KNOTS / delta)
    with np.errstate(divide="ignore"):
        log_factor = np.log(measured / reference)
    log_factor = np.clip(np.nan_to_num(log_factor, neginf=-MAX_LOG_FACTOR), -MAX_LOG_FACTOR, MAX_LOG_FACTOR)
    return {f"law_shear_z_{j}": float(g) for j, g in enumerate(log_factor)}
