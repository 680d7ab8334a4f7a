"""Type stubs of granseg's compiled core (Rust, PyO3). The contract of the
extension: thin conversions only; granseg.model wraps it with validation.

SI units throughout. Parameter dicts map MODEL.md names (see ``defaults()``)
to floats; missing names take their defaults.

Limits (``limits()``, src/limits.rs): sizes are checked before anything is
allocated; a call whose outputs would exceed ``max_bytes`` (4 GiB), more than
``max_cells`` cells, ``max_output_times`` times per run or ``max_threads``
threads raises ValueError naming the parameter (and the bytes); an allocation
that still fails raises MemoryError. Ctrl-C stops simulate, steady_state and
sweep within about 0.1 s plus one step (KeyboardInterrupt), when called from
the main thread.
"""

from typing import TypedDict

import numpy as np
import numpy.typing as npt

class SolverError(RuntimeError):
    """The numerical core could not complete a solve.

    Internal: ``granseg.model`` re-raises it as ``granseg.errors.SolverError``
    (a ``GransegError`` and a ``RuntimeError``), the only one users see.
    """

class SolverStats(TypedDict):
    """Counters of one run (``stepper::Stats``, converted in ``bindings.rs``)."""

    steps: int
    rejected: int
    newton_iters: int
    newton_failures: int
    rhs_evals: int
    jacobians: int
    clipped: int
    max_clip: float
    """Largest amount of c clipped from one cell (states and outputs)."""

def defaults() -> dict[str, float]:
    """Default value of every model parameter (MODEL.md), SI units."""

def differentiable() -> list[str]:
    """The scalar parameters a sweep's tangents may move (besides the law knots)."""

def lagged(x: npt.NDArray[np.float64], survival: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """A view's dwell on an (n_t, n_cols) map: y[0] = x[0], y[t] = (1 - s) x[t] + s y[t-1] per column."""

def law_keys() -> list[str]:
    """Parameter names of every knot of the open-world law corrections (default 0)."""

def materials() -> dict[str, float]:
    """Material densities of MODEL.md, kg/m^3."""

class Limits(TypedDict):
    """Ceilings of one call (``limits.rs``)."""

    max_bytes: int
    max_cells: int
    max_output_times: int
    max_sub_steps: int
    max_threads: int

def limits() -> Limits:
    """The ceilings of one call: output bytes, cells, output times per run, steady-state
    sub-steps per cell, sweep threads."""

def default_tolerances() -> tuple[float, float]:
    """Default (rtol, atol) of the adaptive stepper."""

def validate(params: dict[str, float]) -> None:
    """Raise ValueError naming the first parameter out of its range."""

def derived(params: dict[str, float]) -> dict[str, float]:
    """v0 [m/s], P_load [Pa], A [m^2], omega [rad/s]."""

def velocity_profile(
    params: dict[str, float], z: npt.NDArray[np.float64], t: float
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Velocity [m/s] and shear rate [1/s] at heights z [m], time t [s].

    ValueError unless every z lies in [0, H]."""

def simulate_layers(
    params: dict[str, float],
    t: npt.NDArray[np.float64],
    n_cells: int,
    rtol: float,
    atol: float,
    n_layers: int = 15,
) -> tuple[npt.NDArray[np.float64], SolverStats]:
    """One run reduced to its layer means as it is stepped: (layers (n_t, n_layers), solver
    stats), the full field never built. GIL released; the limits and Ctrl-C as ``simulate``."""

def simulate(
    params: dict[str, float],
    t: npt.NDArray[np.float64],
    n_cells: int,
    rtol: float,
    atol: float,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], SolverStats]:
    """One run: (z (n_cells,), c (n_t, n_cells), solver stats). GIL released.

    ValueError before any allocation if c would exceed ``max_bytes`` (naming len(t),
    n_cells and the bytes), n_cells > ``max_cells`` or len(t) > ``max_output_times``;
    KeyboardInterrupt on Ctrl-C."""

def steady_state(
    params: dict[str, float], n_cells: int, sub_steps: int = 16
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Zero-flux profile as cell averages: (z, c). GIL released.

    ValueError for n_cells outside 15..``max_cells`` or sub_steps > ``max_sub_steps``;
    KeyboardInterrupt on Ctrl-C."""

def layer_means(c: npt.NDArray[np.float64], n_layers: int = 15) -> npt.NDArray[np.float64]:
    """(n_t, n_cells) profiles -> (n_t, n_layers) means over equal layers."""

def moving_average(x: npt.NDArray[np.float64], width: int) -> npt.NDArray[np.float64]:
    """Centred moving average along axis 0 (odd width), shrinking at the ends."""

def sweep(
    params: list[dict[str, float]],
    t: list[npt.NDArray[np.float64]],
    measured: list[npt.NDArray[np.float64] | None],
    smoothing: list[int],
    n_layers: list[int],
    n_cells: int,
    rtol: float,
    atol: float,
    threads: int | None = None,
    tangents: list[list[dict[str, float]] | None] | None = None,
) -> tuple[list[npt.NDArray[np.float64]], npt.NDArray[np.float64], list[SolverStats],
           list[npt.NDArray[np.float64]]]:
    """Runs in parallel (rayon, GIL released): (layers per run, RMSD per run, stats,
    sensitivities per run (n_tangents, n_t, n_layers) along that run's ``tangents``).

    ValueError before any thread starts for threads outside 1..``max_threads``, n_cells >
    ``max_cells`` or layer maps above ``max_bytes`` in all; KeyboardInterrupt on Ctrl-C."""

def _panic_for_testing() -> None:
    """Test hook: a deliberate panic inside the core, raised as _core.SolverError."""
