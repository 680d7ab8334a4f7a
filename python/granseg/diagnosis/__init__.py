"""What the model gets wrong, why, and how much a better model gains.

``diagnose(campaign)`` takes a campaign of measured maps and

1. starts from the baseline's calibration (:func:`granseg.calibrate`: the
   paper's factorial, then least squares on every map at once);
2. estimates the measurement-noise floor [-] from the maps' own counts and
   frame-to-frame scatter (:mod:`~granseg.diagnosis.noise`);
3. gathers the misfit evidence (:mod:`~granseg.diagnosis.evidence`);
4. fits every cause of the catalogue (:mod:`granseg.fitting.causes`) and
   compares them by leave-one-experiment-out prediction, with a significance
   rule calibrated on null campaigns (:mod:`~granseg.diagnosis.selection`);
5. names the cause (a catalogue name, ``none`` or ``unexplained``) with the
   fitted law, its uncertainty and the gain in and out of sample
   (:mod:`~granseg.diagnosis.run`);
6. optionally writes the JSON contract (:mod:`~granseg.diagnosis.result`)
   and an HTML report with the evidence figures.

Example::

    >>> d = granseg.diagnose("campaign/", json="diagnosis.json", report="diag/")  # doctest: +SKIP
    >>> d.cause, d.result["gain"]["rmsd_held_out"]                               # doctest: +SKIP
    ('load_dependent_shear_band', 0.019)
"""

from granseg.diagnosis.run import Diagnosis, diagnose

__all__ = ["Diagnosis", "diagnose"]
