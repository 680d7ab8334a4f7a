"""Virtual experiments: a campaign of maps from the model, with a chosen effect hidden in it.

``campaign(...)`` runs the segregation-diffusion model for a list of
conditions (default: the 16 of the paper's Table 1) with one effect of the
diagnosis catalogue switched on at a chosen strength, and turns each run into
a map in the docs/formats.md format through a realistic measurement (``noise=``,
default the ``persistent`` process):

* **counting** - each of the 15 layers of the 9 D_p wide window holds 9 to 11
  spheres per frame (drawn uniformly each frame; the process's
  ``n_particles``);
* **binomial sampling** - each sphere in view is heavy with the probability
  the wall shows (the bed's layer mean, or the effect's wall view);
* **persistence** - a sphere stays in view from one frame to the next unless
  the flow carries it out of the window: the survival probability of layer j
  is exp(-v(z_j) dt / W), v the model's velocity at the layer centre [m/s],
  dt = 1 / fps [s], W = 9 D_p [m]. Near the driven bottom every frame shows
  new spheres; near the almost rigid top the same spheres stay for minutes,
  so the counting noise there is strongly correlated in time;
* **moving average** - ``c`` is the centred moving average of ``c_raw`` over
  ``smoothing_frames`` (about ``smoothing_s`` seconds), as the paper smooths;
  it skips missing frames, which stay NaN in ``c`` as in ``c_raw`` (docs/formats.md).

Noise processes (``noise=``: a name of :data:`NOISE_PROCESSES`, a
:class:`NoiseProcess`, ``True`` = ``"persistent"``, ``False`` = the exact
wall view with no counting and no smoothing):

===================  ==========================================================
``independent``       every frame draws new spheres (no persistence): counts
                      independent binomial from frame to frame
``persistent``        the default: spheres stay in view with the depth-
                      dependent turnover above
``misclassified``     persistent, and each sphere is recorded as the other
                      kind with probability ``misclassified`` = 0.05, for as
                      long as it stays in view (c_seen = f + (1 - 2f) c)
``boundary_flips``    persistent, and in each frame each sphere in view is
                      counted in a neighbouring layer (up or down, equally
                      likely; never through the bottom or the top) with
                      probability ``boundary_flips`` = 0.05: counts and heavy
                      counts move between adjacent layers, the frame's total
                      is kept
``dropped_frames``    persistent, and a share ``dropped_frames`` = 0.03 of
                      the frames (round(share x n_t), chosen at random) is
                      missing: n = n_heavy = 0, c_raw = c = NaN in those rows
``variable_counts``   persistent with 8 to 12 spheres per layer and frame
``no_counts``         persistent, and the map keeps only the smoothed ``c`` (no
                      ``n``, ``n_heavy``, ``c_raw``): the noise floor can then
                      only be bounded from the map's scatter
===================  ==========================================================

Every process has the fields of :class:`NoiseProcess` (``persistent``,
``n_particles``, ``misclassified``, ``boundary_flips``, ``dropped_frames``,
``counts``),
so mechanisms combine, e.g. ``NoiseProcess(persistent=False,
misclassified=0.1)``; ``campaign.json`` records the process used.

Frame rates follow the paper: 1.5 fps for delta_R >= 3 (steel and ceramic
mixtures), 0.5 fps otherwise; each run lasts until its model map has been
within 0.02 of its final state for half as long again (at least 600 s, at most
MAX_DURATION = 2 h, so a very slow case may end before its steady state).

Effects (``effect=`` and the meaning of ``strength``):

=============================  ===============================================
``None`` / ``"none"``           the baseline of docs/model.md
``load_dependent_shear_band``   exponent p: delta/H = delta/H_ref (M~/0.5)^-p
``evolving_shear_band``         delta_drift [-] (time scale ``drift_time`` s,
                                default 600 s)
``sidewall_excess``             s: c_wall = c + a c (1-c), a = s M~/0.5
``material_friction``           s: k_pair = k exp(s r_pair), r_pair the mean of
                                the two materials' roughness (ROUGHNESS)
``spin_up_delay``               t_d [s]
``diffusivity_scale``           factor: b = 0.041 x factor
``misclassification``           f: a share f of spheres of each kind is taken
                                for the other (c_seen = f + (1 - 2f) c) in the
                                wall view itself; NOT in the diagnosis
                                catalogue (for testing "unexplained"); the
                                ``misclassified`` noise process is the same
                                error per sphere, in the counting
=============================  ===============================================

Example::

    >>> maps = campaign("camp/", effect="load_dependent_shear_band", strength=0.5,
    ...                 seed=1)                                    # doctest: +SKIP
    >>> maps = campaign(noise="dropped_frames", seed=2)           # doctest: +SKIP
    >>> maps = campaign(noise=NoiseProcess(misclassified=0.1, n_particles=(8, 12)))  # doctest: +SKIP
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from granseg._io import check_writable, save_json
from granseg.fitting import REGISTRY, Baseline, Effect, ExpInfo, causes, shifted_times
from granseg.fitting.causes import ROUGHNESS
from granseg.maps import Map, moving_average, save_map
from granseg.model import MATERIALS, defaults, derived, simulate, velocity_profile
from granseg.synth import departures  # noqa: F401  (registers the open-world test effects)

DEFAULTS = defaults()

__all__ = ["EFFECTS", "EFFECT_RANGES", "NOISE_PROCESSES", "ROUGHNESS", "TABLE1", "Condition",
           "NoiseProcess", "campaign", "fill_mass", "frame_rate", "noise_process", "random_conditions",
           "random_effect"]

WINDOW_WIDTH_DP = 9.0
#: Longest run [s]: a practical experiment's length (slow cases may end short of the steady state).
MAX_DURATION = 7200.0
#: "none" and every registered effect (the diagnosis catalogue plus the effects
#: only hidden, such as misclassification).
EFFECTS = ("none", *causes.names(catalogued_only=False))


@dataclass(frozen=True)
class Condition:
    """One experiment to simulate: materials, c0 [-], grain mass M_g [kg], lid load M_w [kg]."""

    heavy: str
    light: str
    c0: float
    M_g: float
    M_w: float = 1.093
    name: str = ""

    def label(self) -> str:
        """Experiment id, e.g. ``G-PP-50``."""
        if self.name:
            return self.name
        short = {"steel": "S", "ceramic": "C", "glass": "G"}
        return f"{short.get(self.heavy, self.heavy)}-{short.get(self.light, self.light)}-{round(100 * self.c0)}"


def _table1() -> list[Condition]:
    rows = {
        ("steel", "PP"): {0.50: 5.25, 0.75: 7.30, 0.90: 8.54},
        ("steel", "POM"): {0.10: 2.83, 0.25: 3.92, 0.50: 5.73, 0.75: 7.55, 0.90: 8.64},
        ("ceramic", "PP"): {0.50: 2.67, 0.75: 3.43, 0.90: 3.89},
        ("glass", "PP"): {0.50: 2.04, 0.75: 2.49, 0.90: 2.76},
        ("POM", "PP"): {0.50: 1.62},
        ("glass", "POM"): {0.50: 2.52},
    }
    return [Condition(h, lt, c0, mg) for (h, lt), d in rows.items() for c0, mg in d.items()]


#: The 16 conditions of the paper's Table 1 (materials, c0, M_g [kg]).
TABLE1: tuple[Condition, ...] = tuple(_table1())


def fill_mass(heavy: str, light: str, c0: float) -> float:
    """Mass of grains [kg] filling the bed (H = 15 D_p, phi_s = 0.6) with heavy share c0."""
    p = defaults()
    rho = MATERIALS[heavy] * c0 + MATERIALS[light] * (1 - c0)
    return p["phi_s"] * derived()["A"] * p["H"] * rho


def random_conditions(n: int, seed: int | None = None) -> list[Condition]:
    """``n`` distinct random conditions: a Table-1 material pair, c0 in {0.25, 0.5, 0.75},
    M_g [kg] the fill mass with a 3 % scatter (Table 1 agrees with it to about 1-3 %)."""
    rng = np.random.default_rng(seed)
    pairs = sorted({(c.heavy, c.light) for c in TABLE1})
    combos = [(h, lt, c0) for h, lt in pairs for c0 in (0.25, 0.5, 0.75)]
    if not 1 <= n <= len(combos):
        raise ValueError(f"n = {n}: random_conditions draws 1 to {len(combos)} distinct conditions")
    picks = rng.choice(len(combos), size=n, replace=False)
    out = []
    for i in sorted(picks):
        h, lt, c0 = combos[i]
        out.append(Condition(h, lt, c0, round(fill_mass(h, lt, c0) * rng.uniform(0.97, 1.03), 3)))
    return out


def frame_rate(rho_h: float, rho_l: float) -> float:
    """The paper's camera rate [1/s]: 1.5 fps for delta_R >= 3, else 0.5 fps."""
    return 1.5 if rho_h / rho_l >= 3.0 else 0.5


# --------------------------------------------------------------------------- noise processes

#: Upper bounds of the noise shares (a share of 0.5 or more would erase the signal).
_SHARE_LIMITS = {"misclassified": (0.5, False), "boundary_flips": (0.5, True), "dropped_frames": (0.5, True)}


@dataclass(frozen=True)
class NoiseProcess:
    """How the virtual camera counts the wall (see the module doc's table).

    persistent : spheres stay in view with the depth-dependent turnover from
        the model's velocity (False: every frame draws new spheres).
    n_particles : (min, max) spheres per layer and frame, drawn uniformly.
    misclassified : probability [-] that a sphere is recorded as the other
        kind, drawn once per sphere (it persists with the sphere), in [0, 0.5).
    boundary_flips : probability [-] per frame that a sphere in view is counted
        in a neighbouring layer, in [0, 0.5].
    dropped_frames : share [-] of the frames missing (n = 0, c_raw = c = NaN),
        in [0, 0.5].
    counts : the map records its counts (``n``, ``n_heavy``, ``c_raw``);
        False writes only the smoothed ``c``, as a map from other software may.
    name : a label recorded in ``campaign.json``.

    Bad values raise ValueError naming the field.
    """

    name: str = "custom"
    persistent: bool = True
    n_particles: tuple[int, int] = (9, 11)
    misclassified: float = 0.0
    boundary_flips: float = 0.0
    dropped_frames: float = 0.0
    counts: bool = True

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.strip():
            raise ValueError(f"noise.name = {self.name!r}: need a non-empty string")
        if not isinstance(self.persistent, bool | np.bool_):
            raise ValueError(f"noise.persistent = {self.persistent!r}: need True or False")
        object.__setattr__(self, "persistent", bool(self.persistent))
        if not isinstance(self.counts, bool | np.bool_):
            raise ValueError(f"noise.counts = {self.counts!r}: need True or False")
        object.__setattr__(self, "counts", bool(self.counts))
        object.__setattr__(self, "n_particles", _n_range(self.n_particles))
        for key, (hi, closed) in _SHARE_LIMITS.items():
            value = getattr(self, key)
            try:
                v = float(value)
            except (TypeError, ValueError):
                v = math.nan
            if isinstance(value, bool) or not (0.0 <= v <= hi if closed else 0.0 <= v < hi):
                raise ValueError(f"noise.{key} = {value!r}: need 0 <= {key} {'<=' if closed else '<'} {hi}")
            object.__setattr__(self, key, v)

    def record(self) -> dict[str, Any]:
        """The process as JSON-ready fields (``campaign.json``)."""
        out = asdict(self)
        out["n_particles"] = list(self.n_particles)
        return out


def _n_range(value: Any) -> tuple[int, int]:
    try:
        lo, hi = value
        ok = all(not isinstance(v, bool) and float(v).is_integer() for v in (lo, hi)) and 1 <= lo <= hi
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise ValueError(f"noise.n_particles = {value!r}: need two integers 1 <= min <= max")
    return int(lo), int(hi)


#: The named measurement-noise processes (module doc's table), name -> process.
NOISE_PROCESSES: dict[str, NoiseProcess] = {p.name: p for p in (
    NoiseProcess("independent", persistent=False),
    NoiseProcess("persistent"),
    NoiseProcess("misclassified", misclassified=0.05),
    NoiseProcess("boundary_flips", boundary_flips=0.05),
    NoiseProcess("dropped_frames", dropped_frames=0.03),
    NoiseProcess("variable_counts", n_particles=(8, 12)),
    NoiseProcess("no_counts", counts=False),
)}


def noise_process(noise: bool | str | NoiseProcess | None) -> NoiseProcess | None:
    """The process ``noise`` names: None for False / None (exact wall view),
    ``persistent`` for True, a :data:`NOISE_PROCESSES` entry by name, or the
    :class:`NoiseProcess` itself."""
    if noise is None or isinstance(noise, bool | np.bool_):
        return NOISE_PROCESSES["persistent"] if noise else None
    if isinstance(noise, NoiseProcess):
        return noise
    if isinstance(noise, str) and noise in NOISE_PROCESSES:
        return NOISE_PROCESSES[noise]
    raise ValueError(f"noise = {noise!r}: unknown noise process; choose True, False, a NoiseProcess "
                     f"or one of {', '.join(NOISE_PROCESSES)}")


# --------------------------------------------------------------------------- effects


def _exp_info(cond: Condition, cell: Mapping[str, float]) -> ExpInfo:
    return ExpInfo(cond.label(), cond.heavy, cond.light, MATERIALS[cond.heavy], MATERIALS[cond.light],
                   cond.c0, cond.M_g, cond.M_w, cell=dict(cell))


def _effect(effect: str | None, strength: float | None) -> tuple[Effect, float]:
    """The registered effect (baseline for None / "none") and its checked strength."""
    name = "none" if effect is None else str(effect)
    if name == "none":
        return Baseline(), 0.0
    chosen = _cause(name)
    return chosen, chosen.check_strength(strength)


def _cause(name: str) -> Effect:
    """A registered effect other than the baseline, by name, else ValueError listing them."""
    if name == "baseline" or name not in REGISTRY:
        raise ValueError(f"effect = {name!r}: unknown; choose one of {', '.join(causes.names(catalogued_only=False))}")
    return causes.get(name)


# --------------------------------------------------------------------------- one experiment


def _truth(params: Mapping[str, float], t: np.ndarray, shift: float, n_cells: int, n_layers: int) -> np.ndarray:
    """Bed layer means (n_t, n_layers) at plate times t [s] with segregation delayed by ``shift``."""
    request, index = shifted_times(t, shift)
    return simulate(t=request, n_cells=n_cells, rtol=1e-5, atol=1e-7, n_layers=n_layers, **params).layers(n_layers)[index]


def _duration(params: Mapping[str, float], shift: float, n_cells: int) -> float:
    """Run length [s]: 1.5 x the time the layer map needs to settle within 0.02, in [600 s, MAX_DURATION]."""
    t = np.arange(0.0, 8 * 3600.0 + 1, 20.0)
    lay = simulate(t=t, n_cells=min(n_cells, 90), **params).layers()
    dev = np.abs(lay - lay[-1]).max(axis=1)
    unsettled = np.nonzero(dev >= 0.02)[0]
    t_ss = t[unsettled[-1] + 1] if unsettled.size else 0.0
    return float(min(MAX_DURATION, max(600.0, math.ceil(1.5 * (t_ss + shift) / 60.0) * 60.0)))


def _persistence(params: Mapping[str, float], t: np.ndarray, fps: float, n_layers: int) -> np.ndarray:
    """Survival probability (n_t, n_layers) of a sphere in view from one frame to the next."""
    H, D_p = params.get("H", DEFAULTS["H"]), params.get("D_p", DEFAULTS["D_p"])
    z = (np.arange(n_layers) + 0.5) * H / n_layers
    times = [0.0, float(t[-1])] if not params.get("delta_drift") else list(t)
    v = np.array([velocity_profile(z, tt, **params)[0] for tt in times])
    if len(times) == 2:
        v = np.repeat(v[:1], t.size, axis=0)
    return np.exp(-np.abs(v) / fps / (WINDOW_WIDTH_DP * D_p))


def _count(seen: np.ndarray, survive: np.ndarray, proc: NoiseProcess, rng: np.random.Generator
           ) -> tuple[np.ndarray, np.ndarray]:
    """Spheres counted (n) and heavy ones (n_heavy) per frame and layer under ``proc``.

    Each layer has ``max`` slots, the first n of them in view; a slot keeps its
    sphere (kind and misclassification) with probability ``survive``, else a
    new one is drawn. The draws of the persistent process come first and in a
    fixed order, so its maps do not depend on the other mechanisms' code.
    """
    n_t, n_l = seen.shape
    lo, hi = proc.n_particles
    f_mis, p_flip = proc.misclassified, proc.boundary_flips
    slots = rng.random((n_l, hi)) < seen[0][:, None]
    n = rng.integers(lo, hi + 1, size=(n_t, n_l))
    mislabelled = rng.random((n_l, hi)) < f_mis if f_mis else None
    n_heavy = np.empty((n_t, n_l), dtype=np.int64)
    counted = n.copy() if p_flip else n
    cols = np.arange(hi)[None, :]
    for i in range(n_t):
        if i:
            fresh = rng.random((n_l, hi)) >= survive[i][:, None]
            draws = rng.random((n_l, hi)) < seen[i][:, None]
            slots = np.where(fresh, draws, slots)
            if mislabelled is not None:
                mislabelled = np.where(fresh, rng.random((n_l, hi)) < f_mis, mislabelled)
        in_view = cols < n[i][:, None]
        heavy = (slots ^ mislabelled if mislabelled is not None else slots) & in_view
        n_heavy[i] = heavy.sum(axis=1)
        if p_flip:
            counted[i], n_heavy[i] = _flip(in_view, heavy, p_flip, rng)
    if proc.dropped_frames:
        k = min(n_t - 1, int(round(proc.dropped_frames * n_t)))
        lost = rng.choice(n_t, size=k, replace=False)
        counted[lost] = 0
        n_heavy[lost] = 0
    return counted, n_heavy


def _flip(in_view: np.ndarray, heavy: np.ndarray, p: float, rng: np.random.Generator
          ) -> tuple[np.ndarray, np.ndarray]:
    """Counts (n, n_heavy) per layer of one frame after each sphere in view has moved to the
    layer above or below with probability ``p`` (up or down equally; none through the walls)."""
    moves = in_view & (rng.random(in_view.shape) < p)
    up = rng.random(in_view.shape) < 0.5
    up_moves, down_moves = moves & up, moves & ~up
    up_moves[-1] = False
    down_moves[0] = False
    out = []
    for mask in (in_view, heavy):
        u, d = (up_moves & mask).sum(axis=1), (down_moves & mask).sum(axis=1)
        total = mask.sum(axis=1) - u - d
        total[1:] += u[:-1]
        total[:-1] += d[1:]
        out.append(total)
    return out[0], out[1]


def _experiment(cond: Condition, effect: Effect, strength: float, base: Mapping[str, float],
                effect_params: Mapping[str, float], rng: np.random.Generator, opts: Mapping[str, Any]
                ) -> dict[str, Any]:
    """The map arrays (docs/formats.md keys) of one virtual experiment."""
    exp = _exp_info(cond, opts["cell"])
    x = {**base, **effect.hidden(strength, exp, effect_params)}
    params, shift = effect.solver_params(x, exp), effect.time_shift(x, exp)
    fps = float(opts["fps"] or frame_rate(params["rho_h"], params["rho_l"]))
    duration = float(opts["duration"] or _duration(params, shift, opts["n_cells"]))
    t = np.arange(0.0, duration + 0.5 / fps, 1.0 / fps)
    bed = _truth(params, t, shift, opts["n_cells"], opts["n_layers"])
    seen = np.clip(effect.observe(x, exp, bed), 0.0, 1.0)
    H = params.get("H", DEFAULTS["H"])
    z = (np.arange(bed.shape[1]) + 0.5) * H / bed.shape[1]
    out = dict(t=t, z=z, name=cond.label(), heavy=cond.heavy, light=cond.light,
               rho_h=params["rho_h"], rho_l=params["rho_l"], c0=cond.c0, M_g=cond.M_g,
               M_w=cond.M_w, fps=fps, **opts["cell"])
    proc = opts["noise"]
    if proc is None:
        return {**out, "c": seen, "smoothing_frames": 1}
    window = max(1, int(round(opts["smoothing_s"] * fps)) // 2 * 2 + 1)
    survive = _persistence(params, t, fps, bed.shape[1]) if proc.persistent else np.zeros(seen.shape)
    n, n_heavy = _count(seen, survive, proc, rng)
    with np.errstate(invalid="ignore", divide="ignore"):
        c_raw = np.where(n > 0, n_heavy / np.maximum(n, 1), np.nan)
    c = np.clip(moving_average(c_raw, window), 0.0, 1.0)
    c[np.isnan(c_raw)] = np.nan  # no reading stays no reading (as the frame analysis writes it)
    if not proc.counts:
        return {**out, "c": c, "smoothing_frames": window}
    return {**out, "c": c, "c_raw": c_raw, "n": n, "n_heavy": n_heavy, "smoothing_frames": window}


# --------------------------------------------------------------------------- public


def _conditions(conditions: Sequence[Any] | None) -> list[Condition]:
    if conditions is None:
        return list(TABLE1)
    out = []
    for i, c in enumerate(conditions):
        if isinstance(c, Condition):
            out.append(c)
        elif isinstance(c, Mapping):
            try:
                out.append(Condition(**c))
            except TypeError as exc:
                raise ValueError(f"conditions[{i}]: {exc}") from None
        else:
            raise ValueError(f"conditions[{i}]: expected a Condition or a dict, got {type(c).__name__}")
    if not out:
        raise ValueError("conditions is empty")
    for i, c in enumerate(out):
        for key in ("heavy", "light"):
            if getattr(c, key) not in MATERIALS:
                raise ValueError(f"conditions[{i}].{key} = {getattr(c, key)!r}: unknown material; "
                                 f"known: {', '.join(MATERIALS)}")
        if not (0 < c.c0 < 1) or not (c.M_g > 0) or not (c.M_w >= 0):
            raise ValueError(f"conditions[{i}]: need 0 < c0 < 1, M_g > 0 kg, M_w >= 0 kg; got {c}")
    names = [c.label() for c in out]
    if len(set(names)) != len(names):
        raise ValueError(f"conditions: duplicate experiment names {names}")
    return out


def campaign(
    out_dir: str | os.PathLike | None = None,
    *,
    conditions: Sequence[Condition | Mapping[str, Any]] | None = None,
    effect: str | None = None,
    strength: float | None = None,
    seed: int | None = 0,
    noise: bool | str | NoiseProcess = True,
    n_particles: tuple[int, int] | None = None,
    smoothing_s: float = 10.0,
    fps: float | None = None,
    duration: float | None = None,
    k: float = 0.70,
    delta_over_H: float = 0.18,
    effect_params: Mapping[str, float] | None = None,
    n_cells: int = 180,
    cell: Mapping[str, float] | None = None,
    n_layers: int = 15,
    force: bool = False,
) -> list[Any]:
    """Simulate a campaign of virtual experiments with one effect hidden in it.

    Parameters
    ----------
    out_dir : directory to write one map ``NAME.npz`` per experiment (docs/formats.md)
        and ``campaign.json`` (the ground truth); created if missing; existing
        files are kept unless ``force``. None: only return the maps.
    conditions : list of :class:`Condition` (or dicts with heavy, light, c0,
        M_g [kg], optional M_w [kg], name); default :data:`TABLE1`.
    effect, strength : the hidden effect and its size (see the module doc).
    seed : random seed of the measurement noise.
    noise : the measurement-noise process: a name of :data:`NOISE_PROCESSES`
        or a :class:`NoiseProcess`; True = ``"persistent"`` (the default);
        False gives the exact wall view (no counting, no smoothing).
    n_particles : (min, max) spheres per layer and frame, replacing the
        process's ``n_particles`` (default: the process's own).
    smoothing_s : moving-average length [s] (odd number of frames).
    fps : frame rate [1/s] for every run (default: the paper's, per delta_R).
    duration : run length [s] for every run (default: to the steady state).
    k, delta_over_H : the baseline's friction correction [-] and band width [-].
    effect_params : extra settings (``drift_time`` [s] of evolving_shear_band).
    n_cells : cells of the simulation behind the maps.
    cell : another cell than docs/model.md's, by docs/model.md names (``H``, ``D_p``,
        ``D_in``, ``D_out``, ``rpm``, ``v1``, ``phi_s``, ``g``; SI): the runs use
        it and the maps carry it (docs/formats.md).
    n_layers : layers of the maps (15: the paper's window).

    Returns the list of :class:`granseg.maps.Map`, in condition order.
    """
    chosen, s = _effect(effect, strength)
    conds = _conditions(conditions)
    proc = noise_process(noise)
    if n_particles is not None and proc is not None:
        proc = replace(proc, n_particles=n_particles)
    if not smoothing_s >= 0:
        raise ValueError(f"smoothing_s = {smoothing_s!r} s must be >= 0")
    cell = _cell(cell)
    if isinstance(n_layers, bool) or not isinstance(n_layers, int) or n_layers < 1:
        raise ValueError(f"n_layers = {n_layers!r} must be a whole number >= 1")
    opts = dict(noise=proc, smoothing_s=float(smoothing_s), fps=fps, duration=duration, n_cells=int(n_cells),
                cell=cell, n_layers=n_layers)
    base = {"k": float(k), "delta_over_H": float(delta_over_H)}
    rng = np.random.default_rng(seed)
    arrays = [_experiment(c, chosen, s, base, dict(effect_params or {}), rng, opts) for c in conds]
    maps = [Map.from_arrays(a) for a in arrays]
    if out_dir is not None:
        _write(Path(out_dir), arrays, save_map, force,
               {"effect": "none" if isinstance(chosen, Baseline) else chosen.name, "strength": s, "seed": seed, "baseline": base,
                "effect_params": dict(effect_params or {}),
                "noise": proc.record() if proc is not None else False,
                "n_particles": list(proc.n_particles) if proc is not None else None,
                "smoothing_s": smoothing_s,
                "experiments": [a["name"] for a in arrays], "synthetic": True})
    return maps


def _cell(cell: Mapping[str, float] | None) -> dict[str, float]:
    """The cell constants, checked by name (docs/model.md's geometry, speed and material constants)."""
    from granseg.maps import CELL_KEYS

    out = {}
    for key, value in (cell or {}).items():
        if key not in CELL_KEYS:
            raise ValueError(f"cell: {key!r} is not a cell constant; those are {', '.join(CELL_KEYS)}")
        out[key] = float(value)
    return out


def _write(out: Path, arrays: list[dict[str, Any]], save_map: Any, force: bool, truth: dict[str, Any]) -> None:
    out.mkdir(parents=True, exist_ok=True)
    targets = [out / f"{a['name']}.npz" for a in arrays] + [out / "campaign.json"]
    for p in targets:
        check_writable(p, force)
    for a, p in zip(arrays, targets, strict=False):
        save_map(p, force=force, **a)
    save_json(out / "campaign.json", truth, force=force)


#: Strength ranges of the hidden-effect draws (:func:`random_effect`): sizes a
#: 16-experiment campaign at the paper's noise can resolve (each effect's ``draw_range``).
EFFECT_RANGES: dict[str, tuple[float, float]] = {
    n: REGISTRY[n].draw_range for n in EFFECTS[1:] if REGISTRY[n].draw_range is not None}


def random_effect(effect: str, seed: int | None = None) -> tuple[float, dict[str, float]]:
    """A seeded random ``(strength, effect_params)`` for ``effect`` (its ``draw``)."""
    return _cause(effect).draw(np.random.default_rng(seed))
