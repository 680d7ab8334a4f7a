"""Degenerate camera calibrations are refused or warned with the figures (issue 14).

Reported: four copies of one photo gave fx = 352 (true 720) with a 0.14 px
reprojection error and no warning; ``--pattern 100000x100000`` ended in a
MemoryError traceback; a missing photo folder was reported as a missing
output folder.
"""

from __future__ import annotations

import json
import shutil
import time
import warnings

import cv2
import numpy as np
import pytest

from granseg.cli import main
from granseg.errors import CameraWarning
from granseg.measure import calibrate_camera
from granseg.synth import default_camera, render_checkerboard

SIZE = (640, 480)
# the six well-spread poses of tests/test_measure_inputs.py::_boards (tilts span ~43 degrees)
GOOD = [((0.1, -0.2, 0.05), (-3.5, -2.5, 14)), ((-0.3, 0.1, -0.1), (-5, -3, 13)),
        ((0.25, 0.3, 0.2), (-4, -4, 15)), ((-0.1, -0.35, 0.0), (-2, -2.5, 12)),
        ((0.35, 0.0, -0.2), (-6, -2, 14)), ((0.0, 0.2, 0.3), (-3, -5, 16))]
# three views tilted by only ~3 degrees each, about different axes: fx known to ~10 %, span ~7 degrees
WEAK = [((0.05, 0.0, 0.0), (-4, -3, 14)), ((0.0, 0.05, 0.0), (-4, -3, 14)),
        ((-0.05, -0.05, 0.0), (-4, -3, 14))]


@pytest.fixture(scope="module")
def photos(tmp_path_factory):
    """Every pose rendered once (supersample 1 keeps it fast): {"good0": path, ..., "weak0": ...}."""
    k, dist = default_camera(SIZE)
    root = tmp_path_factory.mktemp("boards")
    out = {}
    for tag, poses in (("good", GOOD), ("weak", WEAK)):
        for i, (r, t) in enumerate(poses):
            out[f"{tag}{i}"] = p = root / f"{tag}{i}.png"
            cv2.imwrite(str(p), render_checkerboard(k, dist, SIZE, r, t, supersample=1))
    return out


def _folder(tmp_path, photos, names):
    """A folder holding copies of ``photos[names]`` as board_00.png, board_01.png, ..."""
    for i, name in enumerate(names):
        shutil.copy(photos[name], tmp_path / f"board_{i:02d}.png")
    return tmp_path


def test_four_copies_of_one_photo_are_refused(tmp_path, photos):
    d = _folder(tmp_path, photos, ["good0"] * 4)
    with pytest.raises(ValueError, match=r"the 4 photos .* show the board in one pose") as err:
        calibrate_camera(d)
    assert "tilted differently" in str(err.value)


def test_near_identical_photos_are_one_pose(tmp_path, photos):
    # a slight shift of the board (well under a pixel in the image) is still one pose
    k, dist = default_camera(SIZE)
    (r, t) = GOOD[0]
    _folder(tmp_path, photos, ["good0"])
    t2 = (t[0] + 0.01, t[1], t[2])
    cv2.imwrite(str(tmp_path / "board_01.png"), render_checkerboard(k, dist, SIZE, r, t2, supersample=1))
    shutil.copy(photos["good0"], tmp_path / "board_02.png")
    with pytest.raises(ValueError, match="the 3 photos .* one pose"):
        calibrate_camera(tmp_path)


def test_two_distinct_views_are_refused(tmp_path, photos):
    d = _folder(tmp_path, photos, ["good0", "good1", "good0", "good1"])
    with pytest.raises(ValueError, match=r"need at least 3 .*distinct poses.* found the board in 4 of 4 "
                                         r"images, 2 distinct pose\(s\) used"):
        calibrate_camera(d)
    # and with only two photos at all
    for p in (d / "board_02.png", d / "board_03.png"):
        p.unlink()
    with pytest.raises(ValueError, match=r"found the board in 2 of 2 images, 2 distinct"):
        calibrate_camera(d)


def test_six_good_views_are_accepted_with_small_standard_errors(tmp_path, photos):
    k, _ = default_camera(SIZE)
    d = _folder(tmp_path, photos, [f"good{i}" for i in range(6)] + ["good2"])  # one repeated
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        res = calibrate_camera(d)
    assert len(res["images_used"]) == 6
    assert any("same pose as board_02.png" in s for s in res["images_skipped"])
    km = np.array(res["camera_matrix"])
    assert np.allclose(km[[0, 1], [0, 1]], k[[0, 1], [0, 1]], rtol=0.02)
    se = res["stderr"]
    assert set(se) == {"fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"}
    assert 0 < se["fx"] < 0.01 * km[0, 0] and 0 < se["fy"] < 0.01 * km[1, 1]
    assert 0 < se["cx"] < 0.01 * SIZE[0] and 0 < se["cy"] < 0.01 * SIZE[1]
    # the true focal length lies within a few standard errors
    assert abs(km[0, 0] - k[0, 0]) < 5 * se["fx"]
    assert res["tilt_span_deg"] > 30


def test_weakly_constrained_views_warn_with_the_figures(tmp_path, photos):
    d = _folder(tmp_path, photos, ["weak0", "weak1", "weak2"])
    with pytest.warns(CameraWarning) as rec:
        res = calibrate_camera(d)
    msg = str(rec[0].message)
    fx, se = res["camera_matrix"][0][0], res["stderr"]["fx"]
    assert se / fx > 0.02  # the case the warning is for
    assert f"fx = {fx:.1f} ± {se:.1f} px ({100 * se / fx:.1f} %)" in msg
    assert "tilts span only" in msg and f"{res['tilt_span_deg']:.1f}°" in msg
    assert res["tilt_span_deg"] < 10


def test_cli_prints_the_standard_errors_and_writes_them(tmp_path, photos, capsys):
    d = _folder(tmp_path, photos, [f"good{i}" for i in range(3)])
    assert main(["calibrate-camera", str(d), "--pattern", "9x6"]) == 0
    out = capsys.readouterr().out
    assert "standard errors: fx = " in out and "board tilts span" in out
    saved = json.loads((d / "camera.json").read_text())
    assert saved["stderr"]["fx"] > 0 and saved["tilt_span_deg"] > 10


def test_huge_pattern_is_refused_quickly(tmp_path, photos, capsys):
    d = _folder(tmp_path, photos, ["good0"])
    t0 = time.perf_counter()
    with pytest.raises(ValueError, match=r"pattern 100000x100000: .* between 2 and 100"):
        calibrate_camera(d, pattern=(100000, 100000))
    for bad in [(1, 6), (9, 101), (9.5, 6), "9x6", (9, 6, 1)]:
        with pytest.raises(ValueError, match="pattern"):
            calibrate_camera(d, pattern=bad)
    with pytest.raises(SystemExit) as exit_:
        main(["calibrate-camera", str(d), "--pattern", "100000x100000"])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert "argument --pattern" in err and "between 2 and 100" in err and "Traceback" not in err
    assert time.perf_counter() - t0 < 5
    assert not (d / "camera.json").exists()


def test_missing_folder_is_named(tmp_path, capsys):
    missing = tmp_path / "no-such-photos"
    with pytest.raises(FileNotFoundError, match="no-such-photos: checkerboard photo folder not found"):
        calibrate_camera(missing)
    assert main(["calibrate-camera", str(missing)]) == 2
    err = capsys.readouterr().err
    assert "no-such-photos: checkerboard photo folder not found" in err
    assert "output folder" not in err
