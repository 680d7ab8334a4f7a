"""Plain regression tests for what the fuzz suite (tests/test_fuzz.py) found (issue 14).

Each failed on the code before its fix. Process crashes run in a subprocess, so that a
regression fails one test instead of killing the run."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import granseg
from granseg.errors import MapFormatError
from granseg.maps import Map, load_map
from test_maps import fields


def test_a_text_field_that_is_not_utf8_is_named(tmp_path):
    """Was: "invalid map data (UnicodeDecodeError: ...)", naming no field."""
    raw = {k: (np.str_(v) if isinstance(v, str) else v) for k, v in fields().items()}
    raw["heavy"] = np.bytes_(b"gl\xffss")
    with open(tmp_path / "a.npz", "wb") as fh:
        np.savez(fh, **raw)
    with pytest.raises(MapFormatError, match=r"a\.npz: field 'heavy': expected UTF-8 text") as info:
        load_map(tmp_path / "a.npz")
    assert str(tmp_path / "a.npz") in str(info.value)
    with pytest.raises(MapFormatError, match="field 'name': expected UTF-8"):
        Map.from_arrays({**fields(), "name": np.bytes_(b"\xfe")})


@pytest.mark.parametrize("call, name", [
    (lambda: granseg.steady_state(n_cells=30, delta_over_H=10**400), "delta_over_H"),
    (lambda: granseg.simulate(t=[0.0, 60.0], n_cells=30, k=10**400), "k"),
    (lambda: granseg.simulate(t=[0.0, 10**400], n_cells=30), "t"),
    (lambda: granseg.simulate(t=[0.0, 60.0], n_cells=10**400), "n_cells"),
    (lambda: granseg.simulate(t=[0.0, 60.0], n_cells=30, rtol=10**400), "rtol"),
    (lambda: granseg.simulate(t=[0.0, 60.0], n_cells=30, atol="abc"), "atol"),
    (lambda: granseg.sweep({"k": [10**400]}, t=[0.0, 60.0], n_cells=30), "k"),
])
def test_integers_beyond_float_are_refused_naming_the_parameter(call, name):
    """Was: OverflowError ('int too large to convert to float'), or a ValueError naming nothing."""
    with pytest.raises(ValueError, match=name):
        call()


@pytest.mark.parametrize("name", ["rpm", "D_out"])
def test_a_zero_rotation_or_outer_diameter_is_named_as_itself(name):
    """Was: 'parameter v1 = 0 is out of range: must be < v0', naming a parameter not given."""
    with pytest.raises(ValueError, match=rf"parameter {name} = 0(\.0)? is out of range"):
        granseg.simulate(t=[0.0, 60.0], n_cells=30, **{name: 0})


@pytest.mark.parametrize("cases, words", [
    ("2.5", "cases must be a list of parameter dicts"),
    ({"k": 0.7}, "cases must be a list of parameter dicts"),
    ([{"k": 0.7}, 3], r"cases\[1\] must be a dict"),
])
def test_sweep_names_cases_that_are_not_dicts(cases, words):
    """Was: "dictionary update sequence element #0 has length 1; 2 is required"."""
    with pytest.raises(ValueError, match=words):
        granseg.sweep({"k": [0.7]}, cases=cases, t=[0.0, 60.0], n_cells=30)
    with pytest.raises(ValueError, match="base must be a dict"):
        granseg.sweep({"k": [0.7]}, base="2.5", t=[0.0, 60.0], n_cells=30)


def _run(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True, errors="replace",
                          timeout=120)


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX file names are bytes")
def test_a_folder_name_that_is_not_utf8_does_not_crash_opencv(tmp_path):
    """Was: a segmentation fault in cv2.imread / cv2.imwrite / cv2.VideoCapture (the process died)
    for calibrate-camera on such a folder, analyze --preview into one, and a video under one."""
    import cv2

    d = os.fsencode(tmp_path) + b"/photos-\xff"
    os.mkdir(d)
    cv2.imwrite(str(tmp_path / "board.png"), np.zeros((40, 40, 3), np.uint8))
    os.rename(tmp_path / "board.png", d + b"/board.png")
    video = os.fsencode(tmp_path) + b"/clip-\xff.mp4"
    with open(video, "wb") as fh:
        fh.write(b"not really a video")
    r = _run(f"""
        import os
        from granseg.measure import calibrate_camera
        from granseg.measure.sources import VideoFrames
        from granseg._io import cv2_path
        from pathlib import Path
        for call in (lambda: calibrate_camera(os.fsdecode({d!r})),
                     lambda: VideoFrames(Path(os.fsdecode({video!r}))),
                     lambda: cv2_path(Path(os.fsdecode({d!r})) / "preview.png")):
            try:
                call()
            except ValueError as exc:
                print("refused:", exc)
        print("alive")
    """)
    assert r.returncode == 0, r.stderr[-2000:]
    lines = r.stdout.splitlines()
    assert lines[-1] == "alive"
    assert "no 9x6 checkerboard" in r.stdout or "found the board in 0 of 1" in r.stdout, r.stdout
    assert sum("not valid UTF-8" in x for x in lines) == 2, r.stdout


@pytest.mark.parametrize("window", [[-1e6, -1e6, 1e6, 1e6], [0.0, 0.0, 5000.0, 300.0]])
def test_a_window_far_larger_than_the_frames_is_named_before_any_table(tmp_path, window):
    """Was: exit 4, OpenCV asked for 16 TB of undistortion tables for a window of 2e6 px (the crop
    is tabled before the window was checked against the image)."""
    import json

    import cv2

    from fuzz_strategies import EXPERIMENT_BASE
    from granseg.measure import analyze
    from granseg.measure.camera import Undistorter

    frame = np.random.default_rng(0).integers(0, 256, (415, 405, 3), dtype=np.uint8)
    cv2.imwrite(str(tmp_path / "frame_0000.png"), frame)
    (tmp_path / "experiment.json").write_text(json.dumps(EXPERIMENT_BASE | {"window": window}))
    with pytest.raises(ValueError, match=r"field 'window': .* is outside the image \(405 x 415 px\)"):
        analyze(tmp_path, save=False, progress=False)
    with pytest.raises(ValueError, match="more than 3 times the image"):
        Undistorter(np.eye(3), np.zeros(5), (405, 415), (0, 0, 1216, 100))
    Undistorter(np.eye(3), np.zeros(5), (405, 415), (-405, -415, 810, 830))  # three frames: tabled


@pytest.mark.parametrize("fields, words", [({"t0": 1e308}, "2 s apart from t0 = 1e+308 s"),
                                          ({"t0": 1.0, "fps": 1e300}, "1e-300 s apart from t0 = 1 s")])
def test_a_first_frame_time_that_leaves_no_room_between_rows_is_named_before_any_frame(tmp_path, fields, words):
    """Was: t0 = 1e308 s in experiment.json gave every row one time, and only saving the map
    after the whole analysis said so, naming the map's field 't' (the long fuzz profile, seed 7331)."""
    import json

    from fuzz_strategies import EXPERIMENT_BASE
    from granseg.cli import main
    from granseg.measure import analyze

    (tmp_path / "frame_0000.png").write_bytes(b"never read")  # read only after the check
    (tmp_path / "experiment.json").write_text(json.dumps(EXPERIMENT_BASE | fields))
    with pytest.raises(ValueError, match=r"experiment.json: fields 't0' and 'fps': frames " + re.escape(words)):
        analyze(tmp_path, save=False, progress=False)
    assert main(["analyze", str(tmp_path), "--no-progress"]) == 2


def test_a_smoothing_wider_than_the_run_is_the_run_wide_one():
    """Was: a hang, `analyze --smooth 1000000001` looped over every shift of the window in
    Python (the watchdog of the long fuzz profile ended it after 10 minutes). Shifts beyond
    the run's middle reach no row; in a subprocess, so that a regression fails instead of hanging."""
    r = _run("""
        import numpy as np
        from granseg.maps import moving_average
        x = np.arange(14.0).reshape(7, 2) ** 2
        gaps = x.copy()
        gaps[3, 1] = np.nan
        for a in (x, gaps):
            assert np.array_equal(moving_average(a, 10**15 + 1), moving_average(a, 7), equal_nan=True)
        print("same")
    """)
    assert r.returncode == 0 and r.stdout.strip() == "same", r.stderr[-2000:]


def test_densities_in_the_wrong_order_name_both_fields_and_the_map_by_its_text(tmp_path):
    """Was: only 'rho_h' was named when 'rho_l' was the one mistyped (1e308), and a map built from
    a file's arrays was named ``map np.str_('G-PP-50')``."""
    import json

    from fuzz_strategies import EXPERIMENT_BASE
    from granseg.measure.experiment import load_experiment

    arrays = fields()
    arrays["name"], arrays["rho_l"] = np.str_("G-PP-50"), 1e308
    with pytest.raises(MapFormatError) as err:
        Map.from_arrays(arrays)
    assert str(err.value).startswith("map 'G-PP-50': fields 'rho_h' and 'rho_l': "), err.value
    (tmp_path / "experiment.json").write_text(json.dumps(EXPERIMENT_BASE | {"rho_l": 1e308}))
    with pytest.raises(ValueError, match="fields 'rho_h' and 'rho_l'"):
        load_experiment(tmp_path / "experiment.json")


def test_an_output_under_a_missing_folder_is_named_as_given(tmp_path):
    """Was: ``granseg.diagnose(report='/no/such/path.npz')`` said "/no/such: output folder does not
    exist", naming neither the path given nor the parameter (the checks every output goes through)."""
    from granseg._io import check_creatable, check_output_dir, check_writable

    given = tmp_path / "no" / "such" / "path.npz"
    for check in (check_writable, lambda p: check_output_dir(p, ["report.html"]), check_creatable):
        if check is check_creatable:
            (tmp_path / "no").write_text("a file where a folder should be")
        with pytest.raises(OSError) as err:
            check(given)
        assert str(err.value).startswith(f"{given}: "), err.value


def test_a_quality_record_whose_checks_are_not_objects_is_named(tmp_path):
    """Was: AttributeError ("'int' object has no attribute 'items'") from Map.failed_checks."""
    for checks in ("5", "[1, 2]", '{"a": 3}'):
        with pytest.raises(MapFormatError, match=r"field 'quality': \"checks\" must be a JSON object"):
            Map.from_arrays({**fields(), "quality": '{"ok": false, "checks": ' + checks + "}"})
    m = Map.from_arrays({**fields(), "quality": '{"ok": false, "checks": {"a": {"passed": false}}}'})
    assert m.failed_checks == ["a"]


def test_a_zero_finite_difference_step_is_named():
    """Was: numpy.linalg.LinAlgError 'SVD did not converge' from the fit (found by tests/test_fuzz.py)."""
    for bad in (0.0, -1e-3, float("nan"), 2.0, True):
        with pytest.raises(ValueError, match="fd_rel"):
            granseg.calibrate([], fd_rel=bad, progress=False)
    with pytest.raises(ValueError, match="max_nfev"):
        granseg.calibrate([], max_nfev=0, progress=False)


def test_a_layer_count_beyond_the_cores_integers_is_named():
    """Was: OverflowError 'int too big to convert' from the core (found by tests/test_fuzz.py)."""
    with pytest.raises(ValueError, match=r"n_layers = 1000.*must be a whole number in 1\.\.100000"):
        granseg.sweep(t=[0.0, 60.0], n_layers=10**30, n_cells=30)


@pytest.mark.parametrize("name, bad", [("excess_threshold", 10**400), ("gain_threshold", float("nan")),
                                       ("coherence_share", 1.5), ("coherence_alpha", "x"),
                                       ("excess_threshold", True)])
def test_a_decision_threshold_out_of_range_is_named_before_any_work(name, bad):
    """Was: OverflowError 'int too large to convert to float' at the end of a whole diagnosis
    (found by tests/test_fuzz.py)."""
    with pytest.raises(ValueError, match=name):
        granseg.diagnose([], progress=False, **{name: bad})


@pytest.mark.parametrize("name, bad", [("H", 10**400), ("H", 0.0), ("H", "tall"), ("H", float("inf")),
                                       ("D_p", 10**400), ("D_p", "6 mm"), ("D_p", -1.0)],
                         ids=lambda v: str(v)[:12])
def test_a_velocity_length_out_of_range_is_named_before_any_tracking(tmp_path, name, bad):
    """Was: OverflowError 'int too large to convert to float' for H = 10**400, raised only after
    every recording had been tracked (found by tests/test_fuzz.py, long profile, seed 2026). The
    recording here does not exist: the length must be refused before it is looked at."""
    from granseg.velocity import measure_velocity
    with pytest.raises(ValueError, match=rf"measure_velocity: {name} = "):
        measure_velocity(tmp_path / "no-such-recording", progress=False, **{name: bad})


@pytest.mark.parametrize("kwargs, words", [
    ({"every": 10**400}, r"every \(CLI --every\): expected a whole number from 1 to 2147483647, got 1000"),
    ({"every": 2**31}, r"every \(CLI --every\): expected a whole number from 1 to 2147483647, got 2147483648"),
    ({"every_seconds": 1e308}, r"every_seconds \(CLI --every-seconds\): 1e\+308 s at 0.5 fps is more than"),
], ids=["every-huge-int", "every-2^31", "every-seconds-1e308"])
def test_a_stride_beyond_any_recording_is_named_before_any_frame(tmp_path, kwargs, words):
    """Was: OverflowError 'int too large to convert to float' from the map's frame rate, for
    every = 10**400 (the long fuzz profile, seed 4242); every_seconds = 1e308 s overflowed the
    same way when made a whole number of frames."""
    import json

    from fuzz_strategies import EXPERIMENT_BASE
    from granseg.measure import analyze

    (tmp_path / "frame_0000.png").write_bytes(b"never read")  # read only after the check
    (tmp_path / "experiment.json").write_text(json.dumps(EXPERIMENT_BASE))
    with pytest.raises(ValueError, match=words):
        analyze(tmp_path, save=False, progress=False, **kwargs)
