"""Type stubs of granseg's compiled core (Rust, PyO3). The contract of the
extension: thin conversions only; granseg.model wraps it with validation.

SI units throughout. Parameter dicts map MODEL.md names (see ``defaults()``)
to floats; missing names take their defaults.
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

def law_keys() -> list[str]:
    """Parameter names of every knot of the open-world law corrections (default 0)."""

def materials() -> dict[str, float]:
    """Material densities of MODEL.md, kg/m^3."""

def default_tolerances() -> tuple[float, float]:
    """Default (rtol, atol) of the adaptive stepper."""

def validate(params: dict[str, float]) -> None:
    """Raise ValueError naming the first parameter out of its range."""

def derived(params: dict[str, float]) -> dict[str, float]:
    """v0 [m/s], P_load [Pa], A [m^2], omega [rad/s]."""

def velocity_profile(
    params: dict[str, float], z: npt.NDArray[np.float64], t: float
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Velocity [m/s] and shear rate [1/s] at heights z [m], time t [s]."""

def simulate(
    params: dict[str, float],
    t: npt.NDArray[np.float64],
    n_cells: int,
    rtol: float,
    atol: float,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], SolverStats]:
    """One run: (z (n_cells,), c (n_t, n_cells), solver stats). GIL released."""

def steady_state(
    params: dict[str, float], n_cells: int, sub_steps: int = 16
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Zero-flux profile as cell averages: (z, c)."""

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
) -> tuple[list[npt.NDArray[np.float64]], npt.NDArray[np.float64], list[SolverStats]]:
    """Runs in parallel (rayon, GIL released): (layers per run, RMSD per run, stats)."""

def _panic_for_testing() -> None:
    """Test hook: a deliberate panic inside the core, raised as _core.SolverError."""
