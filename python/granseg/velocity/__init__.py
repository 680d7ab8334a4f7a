"""Streamwise velocity profiles measured, not assumed (issue 12): the profile type and its
shear-band fit (:mod:`.profile`), and the measurement from footage (:mod:`.track`)."""

from granseg.velocity.profile import (
           ShearBandLaw,
           VelocityProfile,
           load_profile,
           load_velocity,
           measured_params,
)
from granseg.velocity.track import Recording, measure_velocity, track_recording

__all__ = ["Recording", "ShearBandLaw", "VelocityProfile", "load_profile", "load_velocity", "measure_velocity",
           "measured_params", "track_recording"]
