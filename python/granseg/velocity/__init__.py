"""Streamwise velocity profiles measured, not assumed (issue 12): the profile type and its
shear-band fit (:mod:`.profile`)."""

from granseg.velocity.profile import VelocityProfile, load_profile

__all__ = ["VelocityProfile", "load_profile"]
