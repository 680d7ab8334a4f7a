"""granseg: density-driven granular segregation in an annular shear cell.

The public API, chosen rather than whatever is importable::

    granseg.simulate(...)        one run of the segregation-diffusion model
    granseg.steady_state(...)    the long-time profile, solved directly in z
    granseg.sweep(grid, ...)     a parallel full-factorial of runs (Rust, rayon)
    granseg.analyze(path, ...)   camera frames or video -> concentration map
    granseg.load_map(path)       a measured map (.npz), validated
    granseg.load_campaign(dir)   every map of a campaign directory
    granseg.calibrate(...)       factorial design + refinement of (k, delta/H)
    granseg.diagnose(...)        what the model gets wrong, and why
    granseg.measure_velocity(...) high-speed footage -> velocity profile and shear band
    granseg.load_dem(dumps, config) a DEM run (LAMMPS dumps) -> maps and velocity profile
    granseg.fit, granseg.synth   curve fits; synthetic frames and campaigns

SI units throughout (m, s, kg, Pa). Names are imported lazily so that the
command line starts fast and the frame pipeline does not load the solver.
"""

from __future__ import annotations

from granseg._lazy import lazy_names
from granseg.errors import FitError as FitError
from granseg.errors import GransegError as GransegError
from granseg.errors import SolverError as SolverError

__version__ = "0.1.0"

# public name -> (module, attribute or None for the module itself)
_LAZY: dict[str, tuple[str, str | None]] = {
    "simulate": ("granseg.model", "simulate"),
    "steady_state": ("granseg.model", "steady_state"),
    "sweep": ("granseg.model", "sweep"),
    "defaults": ("granseg.model", "defaults"),
    "Solution": ("granseg.model", "Solution"),
    "SweepResult": ("granseg.model", "SweepResult"),
    "MATERIALS": ("granseg.model", "MATERIALS"),
    "analyze": ("granseg.measure", "analyze"),
    "load_map": ("granseg.maps", "load_map"),
    "load_campaign": ("granseg.maps", "load_campaign"),
    "Map": ("granseg.maps", "Map"),
    "calibrate": ("granseg.calibration", "calibrate"),
    "diagnose": ("granseg.diagnosis", "diagnose"),
    "measure_velocity": ("granseg.velocity", "measure_velocity"),
    "load_velocity": ("granseg.velocity", "load_velocity"),
    "load_dem": ("granseg.dem", "load_run"),
    "fit": ("granseg.fit", None),
    "synth": ("granseg.synth", None),
    "plot": ("granseg.plot", None),
}

__all__ = sorted([*_LAZY, "SolverError", "FitError", "GransegError", "__version__"])

__getattr__, __dir__ = lazy_names(__name__, _LAZY, __all__)
