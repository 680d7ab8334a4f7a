"""The segregation-diffusion model: one run, the steady state, sweeps.

Thin, validating wrappers over the Rust core (``granseg._core``). Every model
parameter of docs/model.md is a keyword with its default from :func:`defaults`
(SI units: densities kg/m^3, lengths m, speeds m/s, times s, loads kg).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from granseg import _core
from granseg.constants import N_LAYERS
from granseg.errors import SolverError, short_repr

__all__ = [
    "DIFFERENTIABLE",
    "MATERIALS",
    "LAW_KEYS",
    "PARAMETERS",
    "Solution",
    "SweepResult",
    "defaults",
    "derived",
    "simulate",
    "steady_state",
    "sweep",
    "velocity_profile",
]

#: Material densities of docs/model.md, kg/m^3 (from the core, never copied).
MATERIALS: dict[str, float] = dict(_core.materials())
_DEFAULTS: dict[str, float] = dict(_core.defaults())
#: Names of every model parameter, in docs/model.md's notation.
PARAMETERS: tuple[str, ...] = tuple(sorted(_DEFAULTS))
#: Knots of the open-world law corrections (``law_flux_c_0`` ...; default 0, i.e. docs/model.md):
#: log-factors of the segregation speed by c, the diffusivity by z/H and by t/law_time, the
#: shear rate by z/H and both rates by t/law_time, 17 knots each (see the core's laws.rs).
LAW_KEYS: tuple[str, ...] = tuple(_core.law_keys())
_LAW_KEY_SET = frozenset(LAW_KEYS)
#: The scalar parameters :func:`sweep` can differentiate by (``tangents``), besides every law knot.
DIFFERENTIABLE: tuple[str, ...] = tuple(_core.differentiable())
RTOL, ATOL = _core.default_tolerances()
N_CELLS = 180
#: Ceilings of one call, from the core (src/limits.rs): the bytes its outputs may take (4 GiB),
#: cells, output times per run, worker threads of a sweep. Checked before anything is allocated.
_LIMITS: dict[str, int] = dict(_core.limits())
MAX_BYTES, MAX_CELLS = _LIMITS["max_bytes"], _LIMITS["max_cells"]
MAX_OUTPUT_TIMES, MAX_THREADS = _LIMITS["max_output_times"], _LIMITS["max_threads"]


def defaults() -> dict[str, float]:
    """Default value of every model parameter (docs/model.md), SI units."""
    return dict(_DEFAULTS)


def _params(overrides: Mapping[str, Any], where: str = "") -> dict[str, float]:
    """Defaults updated with ``overrides``, checked by name, type and range."""
    out = dict(_DEFAULTS)
    for name, value in overrides.items():
        if name not in _DEFAULTS and name not in _LAW_KEY_SET:
            raise ValueError(
                f"{where}unknown model parameter {name!r}; known: {', '.join(PARAMETERS)}"
            )
        try:
            out[name] = float(value)
        except (TypeError, ValueError):
            raise ValueError(f"{where}parameter {name} = {value!r} is not a number") from None
        except OverflowError:  # an int beyond any float, e.g. 10**400 from JSON
            raise ValueError(f"{where}parameter {name} = {short_repr(value)} is too large for a number") from None
    try:
        _core.validate(out)
    except ValueError as exc:
        raise ValueError(f"{where}{exc}") from None
    return out



def _times(t: Any, name: str = "t", n_cells: int | None = None) -> np.ndarray:
    try:
        arr = np.ascontiguousarray(t, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"{name} must be an array of times in seconds (finite numbers)") from None
    if arr.ndim != 1 or arr.size == 0:
        raise ValueError(f"{name} must be a non-empty 1-D array of times in seconds, got shape {arr.shape}")
    if arr.size > MAX_OUTPUT_TIMES:  # before any check that copies it
        need = (f"the output c alone would need {arr.size} x {n_cells} x 8 = {arr.size * n_cells * 8} bytes"
                if n_cells is not None else f"{arr.size * 8} bytes for the times alone")
        raise ValueError(f"{name} has {arr.size} output times: at most {MAX_OUTPUT_TIMES} per run ({need}); "
                         "use a longer output step")
    if not np.all(np.isfinite(arr)) or np.any(arr < 0):
        raise ValueError(f"{name} must hold finite times >= 0 s")
    if np.any(np.diff(arr) <= 0):
        raise ValueError(f"{name} is not strictly increasing")
    return arr


def _case_times(t: Any, n_cases: int) -> list[np.ndarray]:
    """Output times of every case: ``t`` is one array for all, or a list of one array per case."""
    per_case = isinstance(t, list | tuple) and len(t) > 0 and all(np.ndim(ti) == 1 for ti in t)
    if not per_case:
        common = _times(t)
        return [common] * n_cases
    if len(t) != n_cases:
        raise ValueError(f"t has {len(t)} time arrays but there are {n_cases} cases")
    return [_times(ti, f"t[{i}]") for i, ti in enumerate(t)]


def _solver_options(n_cells: Any, rtol: float | None, atol: float | None) -> tuple[int, float, float]:
    if isinstance(n_cells, bool) or not isinstance(n_cells, int | np.integer):
        raise ValueError(f"n_cells = {n_cells!r} must be an integer >= 15")
    # the core checks the upper limit (naming the bytes asked for); a number beyond its integers stops here
    if not 15 <= n_cells < 2**63:
        raise ValueError(f"n_cells = {short_repr(n_cells)} is out of range: must be in 15..{MAX_CELLS} "
                         "(one cell per layer at least)")
    tols = {}
    for name, v in (("rtol", rtol), ("atol", atol)):
        try:
            tols[name] = v = (RTOL if name == "rtol" else ATOL) if v is None else float(v)
        except (TypeError, ValueError, OverflowError):
            raise ValueError(f"{name} = {short_repr(v)} is not a number") from None
        if not (math.isfinite(v) and 0 < v < 1):
            raise ValueError(f"{name} = {v} is out of range: must be in (0, 1)")
    return int(n_cells), tols["rtol"], tols["atol"]


def _call(fn, *args, **kwargs):
    """Call the core, re-raising its numerical failures as granseg.errors.SolverError.

    Every core call that can fail numerically (simulate, steady_state, sweep)
    goes through here, so ``_core.SolverError`` never reaches a user.
    """
    try:
        return fn(*args, **kwargs)
    except _core.SolverError as exc:
        raise SolverError(str(exc)) from None


@dataclass(frozen=True)
class Solution:
    """One model run.

    Attributes
    ----------
    t : (n_t,) output times, s
    z : (n_cells,) cell centres, m above the bottom wall
    c : (n_t, n_cells) heavy share of the solids (cell averages), in [0, 1]; None unless the
        run was asked for its field (``simulate(..., field=True)``)
    params : every model parameter used (SI units)
    stats : solver counters (steps, rejected, newton_iters, rhs_evals, ...:
        ints; max_clip, the largest amount of c clipped from one cell, a float)
    """

    t: np.ndarray
    z: np.ndarray
    c: np.ndarray | None
    params: dict[str, float]
    stats: dict[str, float] = field(default_factory=dict)
    #: layer maps already made, by number of layers (the run's own, reduced as it was stepped)
    layer_maps: dict[int, np.ndarray] = field(default_factory=dict, repr=False, compare=False)

    def layers(self, n_layers: int = N_LAYERS) -> np.ndarray:
        """Mean of c over each of ``n_layers`` equal layers (D_p high for 15):
        (n_t, n_layers), layer 0 at the bottom, as a camera would see it.

        The run's own layer count (``simulate(n_layers=)``, 15 by default) is
        a lookup; another count needs the field (``field=True``)."""
        whole = (not isinstance(n_layers, bool) and isinstance(n_layers, int | float | np.integer | np.floating)
                 and math.isfinite(n_layers) and n_layers == int(n_layers))  # 15.0 is 15; 2.5 is refused
        if not whole or not 1 <= n_layers <= MAX_CELLS:
            raise ValueError(f"n_layers = {n_layers!r} must be a whole number in 1..{MAX_CELLS}")
        n_layers = int(n_layers)
        if n_layers not in self.layer_maps:
            if self.c is None:
                have = ", ".join(str(n) for n in sorted(self.layer_maps)) or "none"
                raise ValueError(f"n_layers = {n_layers}: this run kept the layer maps of {have} layers only; "
                                 f"simulate(..., n_layers={n_layers}) gives these, field=True any")
            self.layer_maps[n_layers] = np.asarray(_core.layer_means(np.ascontiguousarray(self.c), n_layers))
        return self.layer_maps[n_layers].copy()

    @property
    def depth_mean(self) -> np.ndarray:
        """Depth-mean of c at each output time (conserved: equals c0); equal layers average to
        the same, so it is known without the field."""
        if self.c is not None:
            return self.c.mean(axis=1)
        n = min(self.layer_maps)
        return self.layer_maps[n].mean(axis=1)


def simulate(
    *,
    t: Any,
    n_cells: int = N_CELLS,
    rtol: float | None = None,
    atol: float | None = None,
    field: bool = False,
    n_layers: int = N_LAYERS,
    **params: float,
) -> Solution:
    """Solve the segregation-diffusion model from the stratified initial state.

    Parameters
    ----------
    t : output times, s (>= 0, strictly increasing; t = 0 gives the initial profile)
    n_cells : finite-volume cells over the bed height (>= 15)
    rtol, atol : step-size control tolerances (defaults meet 1e-3 on the
        15-layer maps)
    field : also keep the full field ``c`` (n_t, n_cells). By default only the
        ``n_layers`` layer map is kept, reduced in the core as the run is
        stepped: what every comparison with a camera's map needs, n_cells /
        n_layers times smaller.
    n_layers : layers of the map kept (15, the paper's window, by default).
    **params : any model parameter of docs/model.md by name, e.g. ``rho_h=2450``
        (kg/m^3), ``rho_l=946``, ``c0=0.5``, ``k=0.7``, ``delta_over_H=0.18``.

    Example
    -------
    >>> sol = simulate(rho_h=2450, rho_l=946, c0=0.5, t=np.arange(0, 3601, 2.0))
    >>> sol.layers().shape
    (1801, 15)
    >>> simulate(rho_h=2450, rho_l=946, c0=0.5, t=[0.0, 60.0], field=True).c.shape
    (2, 180)
    """
    p = _params(params)
    n_cells, rtol, atol = _solver_options(n_cells, rtol, atol)
    if not isinstance(field, bool | np.bool_):
        raise ValueError(f"field = {field!r} must be True or False")
    whole = not isinstance(n_layers, bool) and isinstance(n_layers, int | np.integer)
    if not whole or not 1 <= n_layers <= MAX_CELLS:
        raise ValueError(f"n_layers = {n_layers!r} must be a whole number in 1..{MAX_CELLS}")
    times = _times(t, n_cells=n_cells)
    z = (np.arange(n_cells) + 0.5) * (p["H"] / n_cells)
    # the core refuses an output above MAX_BYTES (naming len(t), n_cells and the bytes), more
    # than MAX_CELLS cells, and stops at Ctrl-C (KeyboardInterrupt)
    if field:
        z, c, stats = _call(_core.simulate, p, times, n_cells, rtol, atol)
        return Solution(t=times, z=np.asarray(z), c=np.asarray(c), params=p, stats=dict(stats))
    layer_map, stats = _call(_core.simulate_layers, p, times, n_cells, rtol, atol, int(n_layers))
    return Solution(t=times, z=z, c=None, params=p, stats=dict(stats),
                    layer_maps={int(n_layers): np.asarray(layer_map)})


def steady_state(*, n_cells: int = N_CELLS, **params: float) -> tuple[np.ndarray, np.ndarray]:
    """The long-time profile (zero flux everywhere), solved directly in z.

    Returns ``(z, c)``: cell centres in m and cell averages of c on
    ``n_cells`` cells (15 to ``MAX_CELLS``), with depth-mean exactly c0. Ctrl-C stops it.
    """
    p = _params(params)
    n_cells, _, _ = _solver_options(n_cells, None, None)
    z, c = _call(_core.steady_state, p, n_cells)
    return np.asarray(z), np.asarray(c)


def derived(**params: float) -> dict[str, float]:
    """Derived constants: v0 [m/s], P_load [Pa], A [m^2], omega [rad/s]."""
    return dict(_core.derived(_params(params)))


def velocity_profile(z: Any, t: float = 0.0, **params: float) -> tuple[np.ndarray, np.ndarray]:
    """Velocity v(z) [m/s] and shear rate [1/s] at heights z [m] and time t [s].

    The shear rate is the one the model's fluxes use: the exponential band's times the
    shear-profile law's factor (``law_shear_z_*``, e.g. from a tabulated measured profile).
    The velocity is the one that shear rate gives, v0 at the plate minus its integral up to
    z (the exponential band itself when the law is not set)."""
    z = np.ascontiguousarray(z, dtype=np.float64)
    full = _params(params)
    H = full["H"]
    outside = ~((z >= -1e-9 * H) & (z <= H * (1 + 1e-9)))  # NaN is outside too
    if outside.any():
        j = tuple(int(i) for i in np.argwhere(outside)[0])
        raise ValueError(f"z must lie in [0, H] = [0, {H}] m (the bed): z{list(j)} = {float(z[j])!r}")
    v, g = _core.velocity_profile(full, z.ravel(), float(t))
    if any(k.startswith("law_shear_z_") and float(params[k]) != 0.0 for k in params):
        v = _integrated_velocity(full, z.ravel(), float(t))
    return np.asarray(v).reshape(z.shape), np.asarray(g).reshape(z.shape)


def _integrated_velocity(full: dict[str, float], z: np.ndarray, t: float) -> np.ndarray:
    """v(z) = v(0) - integral_0^z of the model's shear rate.

    Written as the exponential band's exact profile minus the integral of what the law
    adds to its shear rate (trapezoids on a fine grid), so that the quadrature error
    scales with the law's departure and vanishes with it: integrating the whole shear
    rate numerically put a step of ~1e-7 m/s between a law of zero and none, which the
    fits' derivatives through the view's dwell (steps of ~1e-6) read as a slope of 0.1.
    """
    plain = {k: v for k, v in full.items() if not k.startswith("law_shear_z_")}
    top = max(float(np.max(z, initial=0.0)), 0.0)
    fine = np.linspace(0.0, top, 4001) if top > 0 else np.zeros(1)
    g_law = np.asarray(_core.velocity_profile(full, fine, t)[1])
    g_band = np.asarray(_core.velocity_profile(plain, fine, t)[1])
    extra = g_law - g_band
    drop = np.concatenate([[0.0], np.cumsum(0.5 * (extra[1:] + extra[:-1]) * np.diff(fine))])
    return np.asarray(_core.velocity_profile(plain, z, t)[0]) - np.interp(z, fine, drop)


# --------------------------------------------------------------------- sweep


@dataclass(frozen=True)
class SweepResult:
    """Runs of a sweep, ordered case-major (each case crossed with the grid).

    Attributes
    ----------
    params : list of the full parameter dict of each run
    grid_points : list of the grid coordinates of each run
    case_index : (n_runs,) index of the case (experiment) of each run
    t : common output times (n_t,), or a list of per-run times
    layers : (n_runs, n_t, n_layers) model layer maps when all runs share times
        and layer counts, else a list of (n_t_i, n_layers_i) arrays. With measured maps these are
        smoothed like the map, i.e. exactly what the RMSD compares.
    rmsd : (n_runs,) RMSD against each run's measured map, or None
    stats : solver counters per run
    sensitivities : with ``tangents``, per run the (n_tangents, n_t, n_layers)
        derivatives of its layer map along its case's tangents (smoothed like
        ``layers``), else None
    """

    params: list[dict[str, float]]
    grid_points: list[dict[str, float]]
    case_index: np.ndarray
    t: Any
    layers: Any
    rmsd: np.ndarray | None
    stats: list[dict[str, float]]
    sensitivities: list[np.ndarray] | None = None

    @property
    def n_runs(self) -> int:
        return len(self.params)

    def table(self) -> list[dict[str, Any]]:
        """One row per run: case index, grid point and RMSD (if any)."""
        rows = []
        for i, gp in enumerate(self.grid_points):
            row: dict[str, Any] = {"case": int(self.case_index[i]), **gp}
            if self.rmsd is not None:
                row["rmsd"] = float(self.rmsd[i])
            rows.append(row)
        return rows


def _grid_points(grid: Mapping[str, Iterable[float]] | None) -> list[dict[str, float]]:
    if not grid:
        return [{}]
    if not isinstance(grid, Mapping):
        raise ValueError("grid must be a dict mapping parameter names to lists of values")
    keys, values = [], []
    for name, vals in grid.items():
        if name not in _DEFAULTS and name not in _LAW_KEY_SET:
            raise ValueError(f"grid: unknown model parameter {name!r}; known: {', '.join(PARAMETERS)}")
        vals = list(np.atleast_1d(np.asarray(vals, dtype=object)))
        if not vals:
            raise ValueError(f"grid: {name} has no values")
        keys.append(name)
        values.append([_finite(v, f"grid: {name} value") for v in vals])
    return [dict(zip(keys, combo, strict=True)) for combo in itertools.product(*values)]


def _finite(v: Any, where: str) -> float:
    """``v`` as a finite float, else ValueError: "<where> <v> is not a finite number"."""
    try:
        f = float(v)
    except (TypeError, ValueError, OverflowError):
        f = math.nan
    if not math.isfinite(f):
        raise ValueError(f"{where} {short_repr(v)} is not a finite number")
    return f


def _measured_entry(m: Any, i: int) -> tuple[np.ndarray, np.ndarray, int]:
    """(c, t, smoothing_frames) of a measured map given as dict or Map."""
    get = (lambda k, d=None: m.get(k, d)) if isinstance(m, Mapping) else (lambda k, d=None: getattr(m, k, d))
    c, t, s = get("c"), get("t"), get("smoothing_frames", 1)
    if c is None or t is None:
        raise ValueError(f"measured[{i}] needs the arrays c and t (docs/formats.md layout)")
    c = np.ascontiguousarray(c, dtype=np.float64)
    t = _times(t, f"measured[{i}].t")
    if c.ndim != 2 or c.shape[0] != t.size:
        raise ValueError(f"measured[{i}].c must have shape (n_t, n_layers) = ({t.size}, n_layers), got {c.shape}")
    if c.shape[1] < 1 or not np.any(np.isfinite(c)):
        raise ValueError(f"measured[{i}].c has no finite entry")
    # NaN marks a missing reading (docs/formats.md); anything else must be a share
    bad = ~np.isnan(c) & ~((c >= 0) & (c <= 1))
    if bad.any():
        j = tuple(int(v) for v in np.argwhere(bad)[0])
        raise ValueError(f"measured[{i}].c[{j[0]}, {j[1]}] = {float(c[j])!r} is not a share in [0, 1] (NaN = no reading)")
    s = _odd_window(1 if s is None else s, f"measured[{i}].smoothing_frames")
    return c, t, s


def _odd_window(s: Any, where: str) -> int:
    """A smoothing window [frames]: an odd integer >= 1 (3.0 is 3; 3.7 is refused, not truncated)."""
    try:
        v = float(s)
    except (TypeError, ValueError):
        raise ValueError(f"{where} = {s!r} is not a number of frames") from None
    if isinstance(s, bool) or not np.isfinite(v) or v != int(v):
        raise ValueError(f"{where} = {s!r} must be a whole number of frames")
    s = int(v)
    if s < 1 or s % 2 == 0:
        raise ValueError(f"{where} = {s} must be an odd number >= 1 (a centred window)")
    return s


def _run_chunk(payload: dict[str, Any]
               ) -> tuple[list[np.ndarray], np.ndarray, list[dict[str, float]], list[np.ndarray]]:
    """Solve a list of runs with the Rust sweep (also what Dask workers run)."""
    layers, rmsd, stats, sens = _call(
        _core.sweep,
        payload["params"],
        payload["t"],
        payload["measured"],
        payload["smoothing"],
        payload["n_layers"],
        payload["n_cells"],
        payload["rtol"],
        payload["atol"],
        payload.get("threads"),
        payload.get("tangents"),
    )
    return ([np.asarray(x) for x in layers], np.asarray(rmsd), [dict(s) for s in stats],
            [np.asarray(x) for x in sens])


def _mapping(value: Any, what: str) -> dict[str, Any]:
    """``value`` as a dict of parameters; ValueError naming ``what`` if it is not a mapping."""
    if not isinstance(value, Mapping):
        raise ValueError(f"{what} must be a dict of model parameters, got {value!r}")
    return dict(value)


def _case_layers(n_layers: int | Sequence[int], n_cases: int) -> list[int]:
    """One layer count per case (each a whole number >= 1)."""
    values = [n_layers] * n_cases if np.ndim(n_layers) == 0 else list(n_layers)
    if len(values) != n_cases:
        raise ValueError(f"n_layers has {len(values)} entries but there are {n_cases} cases")
    for v in values:
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 1 <= v <= MAX_CELLS:
            raise ValueError(f"n_layers = {short_repr(v)} must be a whole number in 1..{MAX_CELLS}")
    return [int(v) for v in values]


def _case_tangents(tangents: Any, n_cases: int) -> list[list[dict[str, float]] | None]:
    """One list of tangent dicts per case (None: no sensitivities), names and values checked."""
    if tangents is None:
        return [None] * n_cases
    if isinstance(tangents, Mapping | str | bytes) or not isinstance(tangents, Sequence):
        raise ValueError("tangents must be a list (one per case) of lists of {parameter: change} dicts")
    if len(tangents) != n_cases:
        raise ValueError(f"tangents has {len(tangents)} entries but there are {n_cases} cases")
    out: list[list[dict[str, float]] | None] = []
    for ci, dirs in enumerate(tangents):
        if isinstance(dirs, Mapping) or not isinstance(dirs, Sequence):
            raise ValueError(f"tangents[{ci}] must be a list of {{parameter: change}} dicts")
        case = []
        for j, d in enumerate(dirs):
            d = _mapping(d, f"tangents[{ci}][{j}]")
            for k, v in d.items():
                if k not in DIFFERENTIABLE and k not in _LAW_KEY_SET:
                    raise ValueError(f"tangents[{ci}][{j}]: no sensitivity to {k!r}; the core differentiates "
                                     f"by {', '.join(DIFFERENTIABLE)} and the law knots")
                d[k] = _finite(v, f"tangents[{ci}][{j}][{k!r}] =")
            case.append(d)
        out.append(case)
    return out


def _chunks(n: int, size: int) -> list[slice]:
    return [slice(i, min(i + size, n)) for i in range(0, n, size)]


def sweep(
    grid: Mapping[str, Iterable[float]] | None = None,
    *,
    base: Mapping[str, float] | None = None,
    cases: Sequence[Mapping[str, float]] | None = None,
    t: Any = None,
    measured: Sequence[Any] | None = None,
    n_layers: int | Sequence[int] = N_LAYERS,
    n_cells: int = N_CELLS,
    rtol: float | None = None,
    atol: float | None = None,
    threads: int | None = None,
    client: Any = None,
    progress: bool | None = None,
    tangents: Sequence[Sequence[Mapping[str, float]]] | None = None,
) -> SweepResult:
    """Run the full factorial of ``grid`` for one or several experiments, in parallel.

    Parameters
    ----------
    grid : {parameter name: list of values}; the full factorial is run
        (``itertools.product`` order, last key fastest).
    base : parameters of a single experiment (alternative to ``cases``).
    cases : one parameter dict per experiment; every case is crossed with the grid.
    t : output times, s: one array for every case, or a list of one array per
        case. Required unless ``measured`` is given.
    measured : one measured map per case (dict or Map with ``c`` (n_t, n_layers),
        ``t`` (n_t,), optional ``smoothing_frames``). The model is evaluated at
        the map's times, smoothed like the map, and its RMSD returned.
    n_layers : layers of the output maps without a measured map (a map sets
        its own): one number for every case, or one per case.
    n_cells, rtol, atol : solver settings as in :func:`simulate`.
    threads : worker threads for this call, at most ``MAX_THREADS`` (default:
        RAYON_NUM_THREADS or all cores).
    client : a ``dask.distributed.Client``; the runs are split into chunks,
        each solved by the Rust sweep on a worker.
    progress : show a progress bar (default: for large sweeps on a terminal).
    tangents : per case, a list of directions ``{parameter: change}`` to
        differentiate its runs' layer maps along (forward sensitivities,
        computed with the run: :data:`DIFFERENTIABLE` and the law knots);
        returned as ``sensitivities``.
    """
    if base is not None and cases is not None:
        raise ValueError("give either base= (one experiment) or cases= (several), not both")
    case_list = [_mapping(base or {}, "base")] if cases is None else None
    if case_list is None:
        if isinstance(cases, Mapping | str | bytes) or not isinstance(cases, Iterable):
            raise ValueError(f"cases must be a list of parameter dicts (one per experiment), got {cases!r}")
        case_list = [_mapping(c, f"cases[{i}]") for i, c in enumerate(cases)]
    if not case_list:
        raise ValueError("cases is empty: give at least one experiment")
    points = _grid_points(grid)
    n_cells, rtol, atol = _solver_options(n_cells, rtol, atol)
    if threads is not None and (isinstance(threads, bool) or not isinstance(threads, int | np.integer)
                                or not 1 <= threads <= MAX_THREADS):
        raise ValueError(f"threads = {threads!r} must be a whole number in 1..{MAX_THREADS}")
    threads = None if threads is None else int(threads)

    if measured is not None:
        if len(measured) != len(case_list):
            raise ValueError(f"measured has {len(measured)} maps but there are {len(case_list)} cases")
        meas = [_measured_entry(m, i) for i, m in enumerate(measured)]
        case_t = [m[1] for m in meas]
    else:
        if t is None:
            raise ValueError("t (output times, s) is required when no measured maps are given")
        case_t = _case_times(t, len(case_list))
        meas = [None] * len(case_list)
    case_layers = _case_layers(n_layers, len(case_list))
    case_tangents = _case_tangents(tangents, len(case_list))

    run_params, run_points, run_case = [], [], []
    for ci, case in enumerate(case_list):
        for gp in points:
            run_params.append(_params({**case, **gp}, where=f"case {ci}, grid point {gp}: "))
            run_points.append(dict(gp))
            run_case.append(ci)
    n = len(run_params)
    payload = {
        "params": run_params,
        "t": [case_t[c] for c in run_case],
        "measured": [None if meas[c] is None else meas[c][0] for c in run_case],
        "smoothing": [1 if meas[c] is None else meas[c][2] for c in run_case],
        "n_layers": [case_layers[c] if meas[c] is None else meas[c][0].shape[1] for c in run_case],
        "tangents": [case_tangents[c] for c in run_case],
        "n_cells": n_cells,
        "rtol": rtol,
        "atol": atol,
        "threads": threads,
    }
    layers, rmsd, stats, sens = _execute(payload, n, client, progress)

    same_t = all(ct is case_t[0] or np.array_equal(ct, case_t[0]) for ct in case_t)
    same_shape = same_t and len({np.shape(x) for x in layers}) == 1
    layers_out: Any = np.stack(layers) if same_shape else layers
    return SweepResult(
        params=run_params,
        grid_points=run_points,
        case_index=np.asarray(run_case, dtype=np.int64),
        t=case_t[0] if same_t else [case_t[c] for c in run_case],
        layers=layers_out,
        rmsd=rmsd if measured is not None else None,
        stats=stats,
        sensitivities=sens if tangents is not None else None,
    )


def _execute(payload: dict[str, Any], n: int, client: Any, progress: bool | None):
    """Run the payload locally (rayon) or on a Dask client, in chunks."""
    keys = ("params", "t", "measured", "smoothing", "n_layers", "tangents")

    def sub(sl: slice) -> dict[str, Any]:
        return {**payload, **{k: payload[k][sl] for k in keys}}

    if client is not None:
        n_workers = max(1, len(client.scheduler_info().get("workers", {})))
        slices = _chunks(n, max(1, math.ceil(n / (2 * n_workers))))
        futures = client.map(_run_chunk, [sub(s) for s in slices], pure=False)
        parts = client.gather(futures)
    else:
        import sys

        show = progress if progress is not None else (n >= 64 and sys.stderr.isatty())
        if not show:
            parts = [_run_chunk(payload)]
        else:
            from tqdm.auto import tqdm

            slices = _chunks(n, max(4, math.ceil(n / 20)))
            parts = []
            with tqdm(total=n, desc="granseg sweep", unit="run") as bar:
                for s in slices:
                    parts.append(_run_chunk(sub(s)))
                    bar.update(s.stop - s.start)
    layers = [x for p in parts for x in p[0]]
    rmsd = np.concatenate([p[1] for p in parts])
    stats = [s for p in parts for s in p[2]]
    sens = [x for p in parts for x in p[3]]
    return layers, rmsd, stats, sens
