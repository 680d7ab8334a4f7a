"""Constants that light modules share with heavy ones, in pure Python.

The Rust core (``granseg.model.defaults()``) is the source of every model
constant. The frame pipeline (``granseg.measure``) must run without the
compiled solver, so it reads two of them from here instead; a test
(``tests/test_model.py``) checks they equal the core's.

The calibration's error methods are named here too, so that the command line
can offer them without importing the fitting layer (scipy.optimize and
scipy.stats: about a second on every ``granseg`` command, ``--help`` included).
"""

from __future__ import annotations

__all__ = ["DEFAULT_ERRORS", "D_P", "ERRORS", "ERROR_METHODS", "N_LAYERS"]

#: Layers of a concentration map, bottom to top (each one sphere diameter
#: high: N_LAYERS * D_P is the bed height H).
N_LAYERS = 15

#: Sphere diameter D_p [m] (docs/model.md; the core's default ``D_p``): the height
#: of one map layer, so layer j's centre is at z = (j + 0.5) * D_P.
D_P = 6.0e-3

#: How a fit states its standard errors (granseg.fitting.uncertainty): entries
#: counted as independent, experiments as clusters, or leave one experiment out.
ERROR_METHODS = ("jacobian", "cluster", "jackknife")

#: Error method of a calibration: "auto" takes the experiments as clusters when
#: there are at least MIN_CLUSTERS (granseg.fitting.solve) of them, else counts
#: entries ("jacobian", with a note). Chosen by coverage (benches/bench_coverage.py):
#: with 16 experiments the cluster errors match the estimates' actual spread under
#: every noise process, where "jacobian" states them 2-4 x too small once grains
#: persist in view (BENCHMARKS.md "Uncertainty").
DEFAULT_ERRORS = "auto"

#: The error methods calibrate accepts.
ERRORS = ("auto", *ERROR_METHODS)
