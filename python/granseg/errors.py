"""Exceptions granseg raises besides ValueError / FileNotFoundError."""

from __future__ import annotations

__all__ = ["GransegError", "SolverError", "FitError", "FlaggedMapError", "QualityWarning"]


class GransegError(Exception):
    """Base class of granseg's own errors."""


class SolverError(GransegError, RuntimeError):
    """The time stepper could not continue (Newton failed even at tiny steps)."""


class FitError(GransegError):
    """A fit or calibration could not produce a result at all."""


class FlaggedMapError(GransegError, ValueError):
    """A map failed its frame-analysis quality checks and was not accepted (names map and checks)."""


class QualityWarning(UserWarning):
    """A map's quality record has a failed check (the map may be wrong)."""
