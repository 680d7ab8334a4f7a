"""The curated public API stays what it says, whatever has been imported.

Importing a submodule binds its name on the package. A public function must
therefore never share its name with a submodule: after every module of the
package is imported, each public name must still be the object
``granseg.__init__`` promises.
"""

from __future__ import annotations

import importlib
import inspect
import pkgutil

import granseg


def test_public_names_survive_importing_every_submodule():
    for info in pkgutil.walk_packages(granseg.__path__, prefix="granseg."):
        importlib.import_module(info.name)
    for name, (module, attr) in granseg._LAZY.items():
        value = getattr(granseg, name)
        if attr is None:
            assert inspect.ismodule(value), name
        else:
            assert value is getattr(importlib.import_module(module), attr), name
    for name in ("simulate", "steady_state", "sweep", "analyze", "calibrate", "diagnose",
                 "load_map", "load_campaign"):
        assert callable(getattr(granseg, name)) and not inspect.ismodule(getattr(granseg, name)), name
    assert callable(granseg.synth.campaign) and not inspect.ismodule(granseg.synth.campaign)


def test_every_public_name_is_listed():
    assert set(granseg._LAZY) <= set(granseg.__all__)
    assert set(dir(granseg)) == set(granseg.__all__)
