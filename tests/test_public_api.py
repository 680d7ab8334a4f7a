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
import re
import subprocess
import sys
import tomllib
from pathlib import Path

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


def test_every_granseg_error_derives_from_granseg_error():
    from granseg import _io, errors, maps
    from granseg.measure import sources

    classes = [getattr(errors, name) for name in errors.__all__]
    exceptions = [c for c in classes if issubclass(c, BaseException) and not issubclass(c, Warning)]
    assert {c.__name__ for c in exceptions} >= {
        "SolverError", "FitError", "FlaggedMapError", "MapFormatError", "OutputExistsError", "BadFrame"}
    for cls in exceptions:
        assert issubclass(cls, errors.GransegError), cls
    # re-exported where they were first defined, as the same classes
    assert maps.MapFormatError is errors.MapFormatError
    assert _io.OutputExistsError is errors.OutputExistsError
    assert sources.BadFrame is errors.BadFrame
    assert granseg.SolverError is errors.SolverError
    # and each keeps the built-in base a user would catch without knowing granseg
    assert issubclass(errors.MapFormatError, ValueError)
    assert issubclass(errors.FlaggedMapError, ValueError)
    assert issubclass(errors.BadFrame, ValueError)
    assert issubclass(errors.OutputExistsError, FileExistsError)
    assert issubclass(errors.SolverError, RuntimeError)


def test_every_exception_class_in_the_package_derives_from_granseg_error():
    for info in pkgutil.walk_packages(granseg.__path__, prefix="granseg."):
        module = importlib.import_module(info.name)
        for name, value in vars(module).items():
            if (inspect.isclass(value) and issubclass(value, Exception)
                    and not issubclass(value, Warning) and value.__module__.startswith("granseg.")):
                # (the core's own _core.SolverError has module "_core": granseg.model re-raises it)
                assert issubclass(value, granseg.GransegError), f"{info.name}.{name}"


def test_one_version_everywhere():
    # granseg --version, the wheel (pyproject.toml) and the core (Cargo.toml) name one release
    root = Path(__file__).resolve().parents[1]
    wheel = tomllib.loads((root / "pyproject.toml").read_text())["project"]["version"]
    core = tomllib.loads((root / "Cargo.toml").read_text())["package"]["version"]
    assert granseg.__version__ == wheel == core, (granseg.__version__, wheel, core)
    assert re.fullmatch(r"\d+\.\d+\.\d+", granseg.__version__)


def test_the_frame_pipelines_names_load_when_asked_and_its_light_parts_without_the_detector():
    import granseg.measure

    for name in granseg.measure.__all__:
        module, attr = granseg.measure._LAZY[name]
        assert getattr(granseg.measure, name) is getattr(importlib.import_module(module), attr)
    # init-experiment and calibrate-camera took 3.4 s, 2.5 s of it scikit-learn and scipy.stats
    # for the detector they do not use (BENCHMARKS "The command line's start")
    code = ("import sys, granseg.measure.init, granseg.measure.camera; "
            "print(sorted(m for m in sys.modules if m.startswith(('sklearn', 'scipy.stats', 'granseg.measure.detect'))))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert r.stdout.strip() == "[]", r.stdout
