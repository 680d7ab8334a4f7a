"""A second instrument: does the shear band the diagnosis fitted to concentration maps agree
with the one measured from footage (``granseg velocity`` / ``velocity-law``)?

The diagnosis keeps fitting delta/H from the maps, so the two estimates are independent;
they agree when they differ by at most :data:`AGREE_Z` combined standard errors.
Compared: with a measured law, the load-dependent cause's exponent and reference delta/H
(when that cause was fitted); with one bed's profile, the baseline's delta/H.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

__all__ = ["AGREE_Z", "compare"]

#: Largest |difference| / combined standard error called agreement.
AGREE_Z = 2.0


def _pair(name: str, fitted: float, fitted_se: float | None, measured: float, measured_se: float | None
          ) -> dict[str, Any]:
    se = math.sqrt((fitted_se or 0.0) ** 2 + (measured_se or 0.0) ** 2)
    z = (fitted - measured) / se if se > 0 else float("nan")
    return {"parameter": name, "fitted": fitted, "fitted_stderr": fitted_se, "measured": measured,
            "measured_stderr": measured_se, "z": z if math.isfinite(z) else None,
            "agrees": bool(math.isfinite(z) and abs(z) <= AGREE_Z)}


def compare(velocity: Any, baseline: tuple[Mapping[str, float], Mapping[str, float]],
            load_law: tuple[Mapping[str, float], Mapping[str, float]] | None) -> dict[str, Any]:
    """The comparison record (JSON-ready): ``baseline`` and ``load_law`` are (values, errors) of
    the baseline fit and of the load-dependent shear band's fit (None if not fitted)."""
    from granseg.velocity import ShearBandLaw

    pairs = []
    if isinstance(velocity, ShearBandLaw):
        if load_law is not None:
            x, e = load_law
            pairs.append(_pair("exponent", x["exponent"], e.get("exponent"), velocity.exponent,
                               velocity.stderr.get("exponent")))
            pairs.append(_pair("delta_over_H_ref", x["delta_over_H"], e.get("delta_over_H"),
                               velocity.delta_over_H_ref, velocity.stderr.get("delta_over_H_ref")))
        kind = "law"
    else:
        x, e = baseline
        pairs.append(_pair("delta_over_H", x["delta_over_H"], e.get("delta_over_H"), velocity.delta_over_H,
                           velocity.fit.stderr.get("delta_over_H")))
        kind = "profile"
    agrees = all(p["agrees"] for p in pairs) if pairs else None
    return {"measured": kind, "pairs": pairs, "agrees": agrees,
            "note": None if pairs else "the load-dependent shear band was not among the causes fitted"}
