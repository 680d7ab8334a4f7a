"""Every exception granseg raises of its own, all under :class:`GransegError`.

Each also keeps the built-in base a user would catch without knowing granseg
(``MapFormatError`` is a ``ValueError``, ``OutputExistsError`` a
``FileExistsError``), so ``except GransegError`` catches every granseg error
and ``except ValueError`` still catches bad input. Plain ``ValueError`` /
``FileNotFoundError`` are raised as they are for bad arguments and missing files.
"""

from __future__ import annotations

__all__ = [
    "GransegError",
    "SolverError",
    "FitError",
    "FlaggedMapError",
    "MapFormatError",
    "DemFormatError",
    "OutputExistsError",
    "BadFrame",
    "QualityWarning",
    "StaleFileWarning",
    "CameraWarning",
]


class GransegError(Exception):
    """Base class of granseg's own errors."""


class SolverError(GransegError, RuntimeError):
    """The time stepper could not continue (Newton failed even at tiny steps).

    The only solver exception users see: :mod:`granseg.model` re-raises the
    compiled core's internal ``_core.SolverError`` as this class.
    """


class FitError(GransegError):
    """A fit or calibration could not produce a result at all."""


class FlaggedMapError(GransegError, ValueError):
    """A map failed its frame-analysis quality checks and was not accepted (names map and checks)."""


class MapFormatError(GransegError, ValueError):
    """A map file or map data break the docs/formats.md format (names file and field)."""


class DemFormatError(GransegError, ValueError):
    """A DEM dump or its config cannot be read as docs/formats.md says (names file, snapshot or key)."""


class OutputExistsError(GransegError, FileExistsError):
    """An output file exists and overwriting was not asked for (``force=True``, CLI ``--force``)."""


class BadFrame(GransegError, ValueError):
    """One frame cannot be used (unreadable, truncated, wrong size, no spheres).

    Raised by the frame sources (``FrameDirectory.read``) and the per-frame
    steps; ``analyze`` turns it into a NaN map row with a ``BadFrameWarning``.
    """


class QualityWarning(UserWarning):
    """A map's quality record has a failed check (the map may be wrong)."""


class StaleFileWarning(UserWarning):
    """A reader skipped a hidden temporary file or folder (``.NAME.npz.<random>.partial``, or an
    older ``.NAME.npz.<random>.npz``) that an interrupted write left behind; the warning names it
    so it can be deleted."""


class CameraWarning(UserWarning):
    """A camera calibration was made but is poorly constrained (the warning gives the figures)."""


def short_repr(value: object) -> str:
    """(A helper for the messages, not an error class, so not in ``__all__``.)
    ``repr`` of a value for an error message, cut to a readable length: a 400-digit integer
    from a JSON file stays one line."""
    text = repr(value)
    return text if len(text) <= 40 else f"{text[:20]}...({len(text)} characters)"
