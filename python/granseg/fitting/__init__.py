"""The one fitting layer under calibration and diagnosis.

* :mod:`~granseg.fitting.effects`: what an effect (a cause, or the baseline)
  is, the registry of effects;
* :mod:`~granseg.fitting.causes`: the catalogue of named causes, shared by
  the diagnosis and the virtual campaigns of :mod:`granseg.synth`;
* :mod:`~granseg.fitting.observe`: the observation step (time shift, model
  layers, observation transform, the map's moving average, residual);
* :mod:`~granseg.fitting.confusion`: the two kinds' confusion, measured on
  the stratified start of every run and applied in the observation step;
* :mod:`~granseg.fitting.dwell`: how long grains stay in view, measured from
  the counts' decorrelation and applied in the observation step;
* :mod:`~granseg.fitting.uncertainty`: standard errors, intervals and
  correlations (cluster sandwich, jackknife, entries);
* :mod:`~granseg.fitting.solve`: one bounded least squares with standard
  errors, the factorial table, leave-one-experiment-out.

``granseg.calibrate`` is the factorial table plus ``fit(data, Baseline())``;
``granseg.diagnose`` starts from that calibration.

scipy.optimize and scipy.stats are imported inside the functions that use
them, not at the top of these modules: importing them takes about a second,
and the command line names the causes (``granseg diagnose --causes``) to build
its parser on every command, ``granseg --help`` included. A test keeps it so.
"""

from granseg.fitting import causes, confusion, dwell
from granseg.fitting.effects import (
    BASE_PARAMS,
    REGISTRY,
    Baseline,
    Effect,
    ExpInfo,
    Param,
    register,
)
from granseg.fitting.observe import DEFAULT_N_CELLS, Data, model_maps, residual, rmsd, shifted_times
from granseg.fitting.solve import (
    Fit,
    compact,
    covariance,
    evaluate,
    factorial,
    fit,
    intervals,
    loo_params,
    loo_predict,
)

__all__ = [
    "BASE_PARAMS",
    "DEFAULT_N_CELLS",
    "REGISTRY",
    "Baseline",
    "Data",
    "Effect",
    "ExpInfo",
    "Fit",
    "Param",
    "compact",
    "causes",
    "confusion",
    "dwell",
    "covariance",
    "intervals",
    "evaluate",
    "factorial",
    "fit",
    "loo_params",
    "loo_predict",
    "model_maps",
    "register",
    "residual",
    "rmsd",
    "shifted_times",
]
