"""The HTML reports: one package, two pages in one style.

- :mod:`~granseg.report.html`: the pieces both pages are made of (style,
  script, numbers, tables, embedded figures, the page itself);
- :mod:`~granseg.report.calibration`: the calibration page of a campaign,
  :func:`build_report` (``granseg report``);
- :mod:`~granseg.report.diagnosis`: the diagnosis page, :func:`write_report`
  (``granseg diagnose --report``).

Each page builder refuses to replace existing outputs unless ``force``
(:func:`granseg._io.check_output_dir`, before any work), draws and saves one
figure at a time, and builds the report in a hidden folder moved into place at
the end (:func:`granseg._io.staged_output_dir`): a failure leaves no half
report. The builders are loaded on first use, so ``import granseg.report``
stays light.

Example::

    >>> build_report("campaign/", "report/")                     # doctest: +SKIP
    PosixPath('report/index.html')
"""

from __future__ import annotations

from granseg._lazy import lazy_names

__all__ = ["build_report", "report_data", "write_report"]

_LAZY = {"build_report": ("granseg.report.calibration", "build_report"),
         "report_data": ("granseg.report.calibration", "report_data"),
         "write_report": ("granseg.report.diagnosis", "write_report")}
__getattr__, __dir__ = lazy_names(__name__, _LAZY, __all__)
