"""Exceptions granseg raises besides ValueError / FileNotFoundError."""

from __future__ import annotations

__all__ = ["GransegError", "SolverError", "FitError"]


class GransegError(Exception):
    """Base class of granseg's own errors."""


class SolverError(GransegError, RuntimeError):
    """The time stepper could not continue (Newton failed even at tiny steps)."""


class FitError(GransegError):
    """A fit or calibration could not produce a result at all."""
