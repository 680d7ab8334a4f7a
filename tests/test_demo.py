"""The README's main command, ``granseg demo``, as a user runs it."""

from __future__ import annotations

import json

import pytest

from granseg.cli import main
from granseg.cli.demo import MARKER, _prepare


def test_demo_finds_the_hidden_cause_and_writes_the_report(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "SYNTHETIC" in text and "Open the report" in text
    result = json.loads((out / "diagnosis.json").read_text())
    assert result["cause"] == "load_dependent_shear_band"
    assert result["gain"]["rmsd_held_out"] > 0
    assert (out / "report" / "index.html").stat().st_size > 1000
    assert (out / "campaign" / "G-PP-50.npz").exists()


def test_demo_folder_rules(tmp_path):
    user = tmp_path / "user"
    user.mkdir()
    (user / "notes.txt").write_text("mine")
    with pytest.raises(FileExistsError, match="not empty"):
        _prepare(user, force=False)
    assert (user / "notes.txt").read_text() == "mine"
    own = tmp_path / "own"
    assert _prepare(own, force=False)
    (own / "old-result.json").write_text("{}")
    assert (own / MARKER).is_file() and _prepare(own, force=False)  # a demo folder is reusable
