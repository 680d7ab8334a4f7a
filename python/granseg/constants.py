"""The two constants the frame pipeline shares with the model, in pure Python.

The Rust core (``granseg.model.defaults()``) is the source of every model
constant. The frame pipeline (``granseg.measure``) must run without the
compiled solver, so it reads these two from here instead; a test
(``tests/test_model.py``) checks they equal the core's.
"""

from __future__ import annotations

__all__ = ["N_LAYERS", "D_P"]

#: Layers of a concentration map, bottom to top (each one sphere diameter
#: high: N_LAYERS * D_P is the bed height H).
N_LAYERS = 15

#: Sphere diameter D_p [m] (docs/model.md; the core's default ``D_p``): the height
#: of one map layer, so layer j's centre is at z = (j + 0.5) * D_P.
D_P = 6.0e-3
