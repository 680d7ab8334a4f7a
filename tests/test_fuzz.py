"""The fuzz suite of issue 14, "nothing aborts, hangs or hides".

Hypothesis draws damaged map files, campaign folders, experiment.json and dem.json documents,
frame folders, argument vectors of every ``granseg`` subcommand and keyword arguments of the
public API (strategies and the registry of fault kinds: tests/fuzz_strategies.py). Whatever is
drawn, granseg must

- never end in an exception other than the documented ones: ValueError (granseg.errors.* among
  them), OSError, GransegError, MemoryError with a message; the command line never exits 4
  ("internal error"), never prints a traceback, and ends a failure in one line
  ``granseg CMD: error: ...``;
- name the file (and the field or key, where one is at fault) in the error;
- never run a pickle from a map file, never take longer than :data:`HANG_S` on these small inputs
  (a watchdog ends the process with every thread's traceback on the run's stderr when one call
  reaches :data:`WATCHDOG_S`, instead of a silent hang).

Two profiles, registered here: ``fuzz-fast`` (the default, what CI runs: the whole file in well
under 3 minutes on 2 cores) and ``fuzz-long`` (``GRANSEG_FUZZ=long``: 25x the examples). Known open
bugs (fuzz_strategies.KNOWN, fixed elsewhere) are accepted for the recipes that hit them and
counted in :data:`KNOWN_HITS`; every other finding has a regression test in
tests/test_fuzz_regressions.py.
"""

from __future__ import annotations

import contextlib
import faulthandler
import io
import json
import os
import shutil
import sys
import tempfile
import time
import warnings
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

import fuzz_strategies as fs
from granseg.errors import GransegError

# --------------------------------------------------------------------------- profiles

_HC = [HealthCheck.too_slow, HealthCheck.filter_too_much, HealthCheck.data_too_large,
       HealthCheck.function_scoped_fixture]
settings.register_profile("fuzz-fast", deadline=None, max_examples=1, suppress_health_check=_HC,
                          derandomize=bool(os.environ.get("CI")), database=None, print_blob=True,
                          # no shrinking: a CLI example takes a second, and a recipe reads as it is
                          phases=[Phase.explicit, Phase.reuse, Phase.generate])
settings.register_profile("fuzz-long", deadline=None, max_examples=25, suppress_health_check=_HC,
                          print_blob=True)
LONG = os.environ.get("GRANSEG_FUZZ", "fast") == "long"
PROFILE = settings.get_profile("fuzz-long" if LONG else "fuzz-fast")


def fuzz(n: int) -> settings:
    """The profile with ``n`` examples (the fast count; the long profile runs 25 times more)."""
    return settings(PROFILE, max_examples=n * (25 if LONG else 1))


#: Longest any one call may take on these small inputs [s]; the watchdog's limit is wider.
HANG_S = 90.0
WATCHDOG_S = 600.0
#: Open bugs accepted for the recipes that hit them: tag -> count (printed at the end).
KNOWN_HITS: Counter[str] = Counter()
#: Warnings the calls let through that are not granseg's (numpy's RuntimeWarning, ...).
STRAY_WARNINGS: Counter[str] = Counter()
ALLOWED = (ValueError, OSError, GransegError)
#: API edge values of another type than the parameter's (a TypeError is Python's answer to them)
WRONG_TYPES = {"zero", "negative", "nan", "inf", "-inf", "huge-int", "huge-float", "tiny", "string-number", "string",
               "empty-string", "bool", "null", "list", "dict", "zero-array", "2d-array", "object", "bytes",
               "path-missing", "very-negative-int", "numpy-int", "complex"}
TYPE_ERRORS: Counter[str] = Counter()
#: API edge values of the parameter's own type (a number, a path): an error must name the parameter
VALUE_CLASSES = {"zero", "negative", "nan", "inf", "-inf", "huge-int", "huge-float", "tiny", "very-negative-int",
                 "numpy-int", "path-missing"}


_WATCHDOG_FILE: int | None = None  # where the watchdog writes: the run's stderr, set for the module


@pytest.fixture(autouse=True, scope="module")
def _watchdog(terminal_stderr):
    """Where a hang's tracebacks go (:func:`call` arms the watchdog), and the counts at the end."""
    global _WATCHDOG_FILE
    _WATCHDOG_FILE = terminal_stderr
    yield
    _WATCHDOG_FILE = None
    if KNOWN_HITS or STRAY_WARNINGS or TYPE_ERRORS:
        print(f"\nfuzz: known open bugs hit {dict(KNOWN_HITS)}\nstray warnings {dict(STRAY_WARNINGS)}\n"
              f"TypeErrors of wrong-typed API arguments {dict(TYPE_ERRORS)}")


# --------------------------------------------------------------------------- the world


@pytest.fixture(scope="module")
def world(tmp_path_factory) -> Path:
    """Valid inputs of every entry point, made once; each example works on a copy."""
    from granseg.synth import TABLE1, campaign, render_frames
    from test_dem import _config, _run_dir

    w = tmp_path_factory.mktemp("world")
    campaign(w / "camp", conditions=TABLE1[:3], n_cells=30, duration=600, fps=1 / 60)
    (w / "camp" / "campaign.json").unlink(missing_ok=True)
    shutil.copy(sorted((w / "camp").glob("*.npz"))[0], w / "map.npz")
    c = np.tile((np.arange(15) >= 8).astype(float), (3, 1))
    render_frames(c, particle_diameter_px=20, image_size=(400, 420), out_dir=w / "frames", fps=0.5)
    (w / "frames" / "experiment.json").write_text(json.dumps(fs.EXPERIMENT_BASE))
    _run_dir(w, "dem-run")
    (w / "dem.json").write_text(json.dumps(_config()))
    shutil.copytree(Path(__file__).parent / "fixtures" / "dem" / "velocity", w / "velocity")
    (w / "camera.json").write_text(json.dumps({k: fs.EXPERIMENT_BASE[k] for k in ("camera_matrix", "dist_coeffs")}))
    return w


@contextlib.contextmanager
def scratch(world: Path | None = None):
    """A fresh folder (with a copy of the world in ``world/``), the working directory meanwhile."""
    root = Path(tempfile.mkdtemp(prefix="fuzz-"))
    old = os.getcwd()
    try:
        if world is not None:
            shutil.copytree(world, root / "world", symlinks=True)
        os.chdir(root)
        yield root
    finally:
        os.chdir(old)
        for dirpath, dirnames, _ in os.walk(root):  # a fuzzed chmod must not block the clean-up
            for d in dirnames:
                with contextlib.suppress(OSError):
                    os.chmod(os.path.join(dirpath, d), 0o755)
        shutil.rmtree(root, ignore_errors=True)


def call(fn, *args, **kwargs) -> tuple[Any, BaseException | None]:
    """Run ``fn``; return (result, exception), with warnings recorded (never raised) and timed."""
    t0 = time.perf_counter()
    result, error = None, None
    # a call that hangs ends the run with every thread's traceback instead of
    # blocking CI (armed per call: the long profile's module runs for hours)
    faulthandler.dump_traceback_later(WATCHDOG_S, exit=True, file=_WATCHDOG_FILE or sys.stderr)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            result = fn(*args, **kwargs)
        except KeyboardInterrupt:
            raise
        except BaseException as exc:  # noqa: BLE001 - the point: see everything
            error = exc
        finally:
            faulthandler.cancel_dump_traceback_later()
    took = time.perf_counter() - t0
    assert took < HANG_S, f"{getattr(fn, '__name__', fn)} took {took:.0f} s on a small input (a hang?)"
    for w in caught:
        if not w.category.__module__.startswith("granseg"):
            STRAY_WARNINGS[f"{w.category.__name__}: {str(w.message)[:60]}"] += 1
    return result, error


def check(recipe: fs.Recipe, error: BaseException | None, *about: str, known: str | None = None) -> None:
    """The contract: no error, or an allowed one whose message names each of ``about`` (paths)
    and, when the recipe targets one, the field or option. A failure on a recipe tagged with a
    known open bug is counted, not raised."""
    if error is None:
        return
    problem = None
    msg = str(error)
    if isinstance(error, MemoryError):
        problem = None if msg else "MemoryError without a message"
    elif not isinstance(error, ALLOWED):
        problem = f"{type(error).__name__}: {msg}"
    elif isinstance(error, ValueError | OSError):  # a GransegError of valid input (SolverError) need not
        missing = [a for a in about if a and a not in msg]
        if recipe.names and not any(n in msg for n in recipe.names):
            missing.append(" or ".join(recipe.names))
        if missing:
            problem = f"the message does not name {missing}: {type(error).__name__}: {msg}"
    if problem is None or _known_open_bug(recipe, known):
        return
    raise AssertionError(f"{recipe}\n  -> {problem}") from error


def _known_open_bug(recipe: fs.Recipe, known: str | None) -> bool:
    """Whether a failure belongs to an open bug tracked elsewhere (fs.KNOWN): then it is counted."""
    known = known or recipe.known
    if known in fs.KNOWN:
        KNOWN_HITS[known] += 1
        return True
    return False


# --------------------------------------------------------------------------- (a) map files


@fuzz(60)
@given(recipe=fs.map_recipes())
def test_load_map_refuses_damaged_files_naming_them(recipe):
    from granseg.maps import Map, load_map

    with scratch() as root:
        path = root / "G-PP-50.npz"
        marker = root / "pickle-ran"
        fs.build_map(recipe, path, str(marker))
        m, error = call(load_map, path)
        assert not marker.exists(), "a pickle in a map file was executed"
        if recipe.kind == "valid":
            assert error is None, error
        if error is None:
            assert isinstance(m, Map) and np.isfinite(m.c).any()
            assert m.c.shape == (m.t.size, m.z.size)
        check(recipe, error, str(path))


@fuzz(30)
@given(recipe=fs.map_recipes().filter(lambda r: r.kind not in ("truncated", "flipped-bytes", "not-a-zip",
                                                                 "huge-header", "junk-members")))
def test_save_map_and_from_arrays_refuse_bad_fields_naming_them(recipe):
    """The writers check what the reader checks: a bad field is named before anything is written."""
    from granseg.maps import Map, save_map

    with scratch() as root:
        arrays = fs._mutated_arrays(recipe, str(root / "pickle-ran"))
        _, error = call(Map.from_arrays, arrays)
        check(recipe, error)
        required = {k: arrays.pop(k) for k in fs.MAP_KEYS if k in arrays}
        if len(required) == len(fs.MAP_KEYS):
            _, error2 = call(save_map, root / "out.npz", **required, **arrays)
            check(recipe, error2, str(root / "out.npz"))
            assert (error2 is None) == (root / "out.npz").exists()
        assert not (root / "pickle-ran").exists()


# --------------------------------------------------------------------------- (b) campaign folders


@fuzz(40)
@given(recipe=fs.campaign_recipes())
def test_load_campaign_reads_every_map_or_names_what_is_wrong(recipe):
    from granseg.maps import load_campaign

    with scratch() as root:
        d, expected = fs.build_campaign(recipe, root, str(root / "pickle-ran"))
        camp, error = call(load_campaign, d)
        assert not (root / "pickle-ran").exists()
        if error is None:
            assert len(camp) == expected, "a map was dropped (or something not a map read) silently"
        # the error names the folder or one entry in it
        check(recipe, error)
        if error is not None and isinstance(error, ALLOWED):
            assert str(d) in str(error), error


# --------------------------------------------------------------------------- (c) experiment.json, frames


@fuzz(60)
@given(recipe=fs.experiment_recipes())
def test_load_experiment_names_the_file_and_field(recipe):
    from granseg.measure.experiment import load_experiment

    with scratch() as root:
        path = root / "experiment.json"
        fs.write_json_recipe(recipe, path)
        _, error = call(load_experiment, path)
        if recipe.kind == "valid":
            assert error is None, error
        check(recipe, error, str(path), known=fs.known_of_experiment(recipe) if recipe.kind == "huge-number" else None)


@fuzz(30)
@given(data=st.data())
def test_dem_config_names_the_key(data, world):
    from granseg.dem import load_config

    base = json.loads((world / "dem.json").read_text())
    recipe = data.draw(fs.dem_config_recipes(base))
    with scratch() as root:
        path = root / "dem.json"
        fs.write_json_recipe(recipe, path)
        _, error = call(load_config, path)
        if recipe.kind == "valid":
            assert error is None, error
        # nested fields are named by their path ('units.time_s'): any mention of the key will do
        names = tuple(n.strip("'") for n in recipe.names)
        check(fs.Recipe(recipe.entry, recipe.kind, recipe.target, recipe.args, names), error, str(path),
              known="overflow-json" if recipe.kind == "huge-number" else None)


@fuzz(5)
@given(recipe=fs.experiment_recipes())
def test_analyze_cli_on_a_bad_experiment_json_exits_with_one_line(recipe, world):
    with scratch(world) as root:
        frames = root / "world" / "frames"
        fs.write_json_recipe(recipe, frames / "experiment.json")
        rc, err = run_cli(["analyze", str(frames), "--out", str(root / "a.npz"), "--no-progress", "--workers", "1"])
        check_cli(recipe, "analyze", rc, err, known=fs.known_of_experiment(recipe))
        if rc == 2 and recipe.names and recipe.kind != "not-an-object":
            assert any(n in err for n in recipe.names) or fs.known_of_experiment(recipe) in fs.KNOWN, err


@fuzz(6)
@given(recipe=fs.frames_recipes())
def test_analyze_survives_damaged_frame_folders(recipe, world):
    import cv2

    with scratch(world) as root:
        frames = root / "world" / "frames"
        pngs = sorted(frames.glob("*.png"))
        victim = pngs[0] if recipe.args["which"] == "first" else pngs[-1]
        k = recipe.kind
        if k == "truncated-frame":
            data = victim.read_bytes()
            victim.write_bytes(data[: int(len(data) * recipe.args["keep"])])
        elif k == "empty-frame":
            victim.write_bytes(b"")
        elif k == "not-an-image":
            victim.write_text("hello")
        elif k == "grayscale-frame":
            cv2.imwrite(str(victim), cv2.imread(str(victim), cv2.IMREAD_GRAYSCALE))
        elif k == "other-size-frame":
            cv2.imwrite(str(victim), cv2.resize(cv2.imread(str(victim)), (200, 210)))
        elif k == "dir-named-png":
            (frames / "frame_0001b.png").mkdir()
        elif k == "no-frames":
            for p in pngs:
                p.unlink()
        elif k == "non-utf8-frame":
            os.rename(victim, os.fsencode(frames) + b"/frame_\xff.png")
        elif k == "hidden-frame":
            (frames / "._frame_0000.png").write_bytes(b"\x00\x05\x16\x07 AppleDouble")
        rc, err = run_cli(["analyze", str(frames), "--out", str(root / "a.npz"), "--no-progress", "--workers", "1"])
        check_cli(recipe, "analyze", rc, err)
        if recipe.kind == "valid":
            assert rc == 0, err


# --------------------------------------------------------------------------- (d) the command line


def run_cli(argv: list[str]) -> tuple[int, str]:
    """``granseg.cli.main(argv)`` in this process; (exit code, stderr)."""
    from granseg.cli import main

    out, err = io.StringIO(), io.StringIO()

    def go():
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                return main(argv)
            except SystemExit as exc:  # argparse's usage errors
                return exc.code

    rc, error = call(go)
    if error is not None:
        raise AssertionError(f"granseg {' '.join(map(str, argv))}: {type(error).__name__} escaped main(): "
                             f"{error}") from error
    return rc, err.getvalue()


def check_cli(recipe: fs.Recipe, command: str, rc: Any, err: str, known: str | None = None,
              strict: bool = False) -> None:
    """Exit 0, 1, 2 (or 130); a failure ends in one line 'granseg CMD: error: ...'; never 4. With
    ``strict`` (`analyze --strict`), also 3 where the map was written and stderr says it failed a
    quality check (the README's table of exit statuses)."""
    problem = None
    lines = [ln for ln in err.splitlines() if ln.strip()]
    if rc not in (0, 1, 2, 130) and not (strict and rc == 3):
        problem = f"exit code {rc!r}"
    elif "Traceback" in err:
        problem = "a traceback on stderr"
    elif rc == 3 and "*** WARNING: this map failed" not in err:
        problem = "exit 3 without saying which quality check failed"
    elif rc in (1, 2) and not (lines and lines[-1].startswith((f"granseg {command}: error: ", "granseg: error: "))):
        problem = "the failure does not end in one 'granseg CMD: error:' line"
    if problem is None or _known_open_bug(recipe, known):
        return
    raise AssertionError(f"{recipe}\n  -> {problem}\n  stderr: {err[-2000:]}")


#: options that make a command cheap, added unless the drawn vector sets the same option
CHEAP = {
    "simulate": ["--n-cells", "30", "--t-end", "600", "--dt", "60"],
    "calibrate": ["--n-cells", "20", "--max-nfev", "3", "--grid", "k=0.6,0.7", "-q"],
    "report": ["--n-cells", "20", "--max-nfev", "3", "--grid", "k=0.6,0.7", "-q"],
    "diagnose": ["--n-cells", "20", "--quiet", "--causes", "diffusivity_scale"],
    "analyze": ["--no-progress", "--workers", "1"],
    "velocity": ["--no-progress", "--workers", "1"],
    "init-experiment": [],
}
#: the valid input of each positional argument and input option, in the world
VALID_INPUT = {"campaign": "camp", "path": "frames", "recordings": "frames", "runs": "dem-run", "inputs": "map.npz",
               "directory": "frames", "--like": "map.npz", "--velocity": "velocity/dem-r2-F150.json",
               "--camera": "camera.json", "--config": "dem.json"}
#: options that name something granseg writes
OUTPUTS = {"--out", "--json", "--npz", "--report", "--preview", "--figure", "--detections"}
VALID_TEXT = {"--heavy": "glass", "--light": "PP", "--name": "fuzz"}


def _value(command: str, opt: str, cls: str, action, root: Path) -> str:
    family, _ = fs.option_kinds(action)
    w = root / "world"
    if family == "number":
        return fs.BAD_ARG_NUMBERS[cls]
    if family == "choice":
        return {"valid": str(list(action.choices)[0]), "bogus": "bogus", "empty": ""}[cls]
    if family == "special":
        return fs.SPECIAL_VALUES[opt][cls][0]
    if family == "text":
        return {"empty": "", "spaces": "   ", "dash": "-x", "non-utf8": os.fsdecode(b"G-\xff"), "huge": "x" * 10_000,
                "valid": VALID_TEXT.get(opt, "glass")}[cls]
    is_output = opt in OUTPUTS
    suffix = {"--json": ".json", "--npz": ".npz", "--detections": ".csv"}.get(opt, "")
    if command == "velocity-law" and opt == "directory":
        valid = w / "velocity"
    elif command == "calibrate-camera" and opt == "--out":
        valid = root / "camera-out.json"
    elif is_output:
        valid = root / f"new-{opt.strip('-')}{suffix}"
    else:
        valid = w / VALID_INPUT.get(opt, "map.npz")
    if cls == "valid":
        return str(valid)
    if cls == "missing":
        return str(root / "no-such" / f"x{suffix}")
    if cls == "under-a-file":
        return str(root / "a-file" / f"x{suffix}")
    if cls == "proc":
        return f"/proc/granseg-fuzz{suffix}" if is_output else "/proc/self/status"
    if cls == "existing":
        p = root / f"existing{suffix}"
        return str(p)
    if cls == "directory":
        return str(root / "a-dir")
    if cls == "empty":
        return ""
    if cls == "dev-null":
        return "/dev/null"
    if cls == "long-name":
        return str(root / ("x" * 300 + suffix))
    if cls == "non-utf8":
        name = os.fsencode(root) + b"/G-\xff" + (os.fsencode(valid.name) if not is_output else suffix.encode())
        if not is_output and valid.exists():
            (shutil.copytree if valid.is_dir() else shutil.copy)(valid, os.fsdecode(name))
        return os.fsdecode(name)
    raise AssertionError(cls)


def _known_cli(command: str, chosen: list[tuple[str, str]], argv: list[str]) -> str | None:
    d = dict(chosen)
    if any(os.fsencode(a) != a.encode("utf-8", "replace") for a in argv if isinstance(a, str)) or \
            "non-utf8" in d.values():
        return "non-utf8-name"
    if d.get("--workers") in ("zero", "negative", "huge-int"):
        return "workers-0"
    if "--preview-count" in d:
        return "preview-count"
    if d.get("--set") == "out-of-range":
        return "set-D_p"
    if command == "report" and "--c0" in d:
        return "report-c0"
    outs = {o: c for o, c in d.items() if o in OUTPUTS}
    if outs and any(c in ("existing", "under-a-file", "proc", "directory", "dev-null") for c in outs.values()):
        return "late-output-clash"
    return None


def cli_argv(recipe: fs.Recipe, command: str, root: Path) -> list[str]:
    """The argument vector of a CLI recipe, with the world's valid inputs where nothing is drawn."""
    p = fs.cli_parsers()[command]
    actions = {(max(a.option_strings, key=len) if a.option_strings else a.dest): a for a in fs.cli_actions(p)}
    (root / "a-file").write_text("a file")
    (root / "a-dir").mkdir()
    for suffix in ("", ".json", ".npz", ".csv"):
        (root / f"existing{suffix}").write_text("{}")
    chosen = dict(recipe.args["chosen"])
    if recipe.kind == "no-arguments":
        return [command]
    positional, options = [], []
    for name, action in actions.items():
        if action.option_strings:
            continue
        cls = chosen.get(name, "valid")
        positional.append(_value(command, name, cls, action, root))
    for name, action in actions.items():
        if not action.option_strings:
            continue
        if name in chosen:
            if action.nargs == 0:
                options.append(name)
            else:
                options += [name, _value(command, name, chosen[name], action, root)]
        elif action.required:
            options += [name, _value(command, name, "valid", action, root)]
    cheap = list(CHEAP.get(command, []))
    i = 0
    while i < len(cheap):  # drop a cheap default the draw sets itself
        step = 1 if i + 1 >= len(cheap) or cheap[i + 1].startswith("-") else 2
        if cheap[i] not in chosen and not (cheap[i] == "-q" and "--quiet" in chosen):
            options += cheap[i:i + step]
        i += step
    argv = [command, *options, "--", *positional] if positional else [command, *options]
    if recipe.kind == "unknown-option":
        argv.insert(1, "--no-such-option")
    elif recipe.kind == "duplicate-option" and options:
        argv[1:1] = options[:2]
    return argv


def _cli_test(command: str, n: int):
    @fuzz(n)
    @given(recipe=fs.cli_recipes(command))
    def test(recipe, world):
        with scratch(world) as root:
            argv = cli_argv(recipe, command, root)
            rc, err = run_cli(argv)
            known = _known_cli(command, recipe.args["chosen"], argv)
            if command == "diagnose" and recipe.target in ("campaign",):
                known = known or "diagnose-layers"
            check_cli(recipe, command, rc, err, known=known, strict=command == "analyze" and "--strict" in argv)

    test.__name__ = f"test_cli_{command.replace('-', '_')}_never_ends_in_an_internal_error"
    return test


CLI_EXAMPLES = {"simulate": 25, "calibrate": 10, "report": 3, "diagnose": 4, "analyze": 6, "velocity": 4,
                "velocity-law": 8, "export": 10, "init-experiment": 10, "calibrate-camera": 6, "dem": 8}
for _command in fs.cli_parsers():
    globals()[f"test_cli_{_command.replace('-', '_')}"] = _cli_test(_command, CLI_EXAMPLES.get(_command, 5))


def test_every_subcommand_is_fuzzed():
    """A new subcommand is fuzzed from the parser; this is a reminder to size its examples."""
    assert set(fs.cli_parsers()) <= set(CLI_EXAMPLES), set(fs.cli_parsers()) - set(CLI_EXAMPLES)


# --------------------------------------------------------------------------- (e) the public API


def _edge(cls: str, root: Path) -> Any:
    v = fs.API_EDGES[cls]
    return v.copy() if isinstance(v, np.ndarray) else v


def _api_call(entry: str, kwargs: dict[str, Any], root: Path):
    import granseg

    w = root / "world"
    name = entry.split(".", 1)[1]
    fn = getattr(granseg, name)
    if name == "simulate":
        return fn, (), {"t": np.linspace(0.0, 600.0, 4), "n_cells": 30, **kwargs}
    if name == "steady_state":
        return fn, (), {"n_cells": 30, **kwargs}
    if name == "sweep":
        base = {"grid": {"k": [0.7]}, "t": [0.0, 60.0, 120.0], "n_cells": 30, "threads": 1, "progress": False}
        return fn, (), {**base, **kwargs}
    if name == "calibrate":
        base = {"grid": {"k": [0.7], "delta_over_H": [0.18]}, "refine": False, "n_cells": 20, "progress": False}
        return fn, (w / "camp",), {**base, **kwargs}
    if name == "diagnose":
        base = {"n_cells": 20, "causes": ["diffusivity_scale"], "progress": False, "max_nfev": 5}
        return fn, (w / "camp",), {**base, **kwargs}
    if name == "analyze":
        return fn, (w / "frames",), {"progress": False, "workers": 1, "save": False, **kwargs}
    if name == "measure_velocity":
        return fn, (w / "frames",), {"progress": False, "workers": 1, **kwargs}
    if name == "load_dem":
        return fn, (), {"dumps": w / "dem-run", **kwargs}
    return fn, (), kwargs


#: entries whose world input fails anyway (stills at 0.5 fps are no velocity recording): any message will do
BASE_FAILS = {"granseg.measure_velocity"}


def _api_test(entry: str, n: int):
    @fuzz(n)
    @given(recipe=fs.api_recipes(entry))
    def test(recipe, world):
        with scratch(world) as root:
            kwargs = {kw: _edge(cls, root) for kw, cls in recipe.args["chosen"].items()}
            fn, args, kw = _api_call(entry, kwargs, root)
            _, error = call(fn, *args, **kw)
            if isinstance(error, TypeError) and any(cls in WRONG_TYPES for cls in recipe.args["chosen"].values()):
                # Python's own answer to an argument of the wrong type (load_map(0), n_cells=[1, 2]);
                # counted, not failed: the contract is about values, files and the command line
                TYPE_ERRORS[f"{entry}: {type(error).__name__}: {str(error)[:70]}"] += 1
                return
            # the message names one of the parameters drawn, or the path given in one
            names = (*recipe.args["chosen"], *(str(v) for v in kwargs.values() if isinstance(v, str | Path) and str(v)))
            if entry in BASE_FAILS or not set(recipe.args["chosen"].values()) <= VALUE_CLASSES or any(isinstance(v, str | Path) and not str(v) for v in kwargs.values()):
                names = ()  # "" is the current folder, named as "."
            check(fs.Recipe(recipe.entry, recipe.kind, recipe.target, recipe.args, names), error)

    test.__name__ = f"test_api_{entry.split('.', 1)[1]}_raises_only_documented_errors"
    return test


API_EXAMPLES = {"granseg.simulate": 30, "granseg.steady_state": 15, "granseg.sweep": 15, "granseg.calibrate": 10,
                "granseg.diagnose": 3, "granseg.load_map": 10, "granseg.load_campaign": 10, "granseg.analyze": 4,
                "granseg.load_velocity": 10, "granseg.measure_velocity": 3, "granseg.load_dem": 8}
for _entry in fs.API_KWARGS:
    globals()[f"test_api_{_entry.split('.', 1)[1]}"] = _api_test(_entry, API_EXAMPLES.get(_entry, 5))


def test_the_count_script_lists_every_entry_point():
    table = fs.count_table()
    for entry in fs.FAULTS:
        assert f"`{entry}`" in table
    assert sum(len(k) for k in fs.FAULTS.values()) > 1000
