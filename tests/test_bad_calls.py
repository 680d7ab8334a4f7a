"""Bad calls to the public API get one clear error naming what is wrong (issue 14)."""

from __future__ import annotations

import numpy as np
import pytest

import granseg


def _measured(**over):
    t = np.arange(5) * 60.0
    c = np.full((5, 15), 0.5)
    return {"c": c, "t": t, "smoothing_frames": 1, **over}


@pytest.mark.parametrize("over, message", [
    ({"smoothing_frames": 3.7}, "whole number of frames"),
    ({"smoothing_frames": 4}, "odd number"),
    ({"smoothing_frames": "three"}, "not a number"),
    ({"c": np.full((5, 15), 1.5)}, r"c\[0, 0\] = 1.5 is not a share"),
    ({"c": np.where(np.eye(5, 15) > 0, np.inf, 0.5)}, "not a share"),
])
def test_sweep_refuses_a_bad_measured_map_naming_the_field(over, message):
    with pytest.raises(ValueError, match=message):
        granseg.sweep({"k": [0.7]}, measured=[_measured(**over)], t=np.arange(5) * 60.0)


def test_sweep_takes_a_whole_float_window_and_missing_readings():
    c = np.full((5, 15), 0.5)
    c[2, 3] = np.nan  # a missing reading is allowed
    r = granseg.sweep({"k": [0.7]}, measured=[_measured(c=c, smoothing_frames=3.0)], t=np.arange(5) * 60.0)
    assert np.isfinite(r.rmsd).all()


@pytest.mark.parametrize("campaign, message", [
    ([1, 2, 3], r"campaign\[0\]: expected a granseg Map"),
    (42, "expected a campaign folder"),
    ([], "no maps"),
])
def test_calibrate_names_a_campaign_that_is_not_one(campaign, message):
    with pytest.raises(ValueError, match=message):
        granseg.calibrate(campaign, progress=False)


@pytest.mark.parametrize("error, code, words", [
    (RuntimeError("boom"), 4, "internal error: RuntimeError: boom"),
    (MemoryError(), 1, "out of memory"),
    (OverflowError("int too large"), 4, "OverflowError: int too large"),
])
def test_the_cli_ends_any_failure_in_one_line(monkeypatch, capsys, error, code, words):
    """Whatever goes wrong, the command line says it in one line; -v adds the traceback."""
    from granseg.cli import init_experiment, main

    def fail(args):
        raise error

    monkeypatch.setattr(init_experiment, "run", fail)
    assert main(["init-experiment", "somewhere"]) == code
    err = capsys.readouterr().err
    assert words in err and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert main(["-v", "init-experiment", "somewhere"]) == code
    assert "Traceback" in capsys.readouterr().err
