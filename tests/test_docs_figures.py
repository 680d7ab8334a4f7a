"""docs/make_figures.py's helpers: browser lookup, the refusal without a browser, atomic writes,
--force, and the cut of a screenshot at white space (the full run is too slow for CI)."""

from __future__ import annotations

import importlib.util
import os
import stat
from pathlib import Path

import numpy as np
import pytest

SCRIPT = Path(__file__).resolve().parent.parent / "docs" / "make_figures.py"


@pytest.fixture(scope="module")
def mf():
    spec = importlib.util.spec_from_file_location("make_figures", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _fake_browser(folder: Path, name: str = "chromium") -> Path:
    exe = folder / name
    exe.write_text("#!/bin/sh\nexit 0\n")
    exe.chmod(exe.stat().st_mode | stat.S_IXUSR)
    return exe


def test_find_browser(mf, tmp_path):
    assert mf.find_browser(path=str(tmp_path)) is None
    exe = _fake_browser(tmp_path, "chromium-browser")
    assert mf.find_browser(path=str(tmp_path)) == str(exe)


def test_no_browser_exits_2_with_a_clear_message(mf, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("PATH", str(tmp_path))
    assert mf.main(["--out", str(tmp_path / "figs")]) == 2
    err = capsys.readouterr().err
    assert "no headless browser" in err and "chromium" in err and "apt-get install chromium" in err
    assert not (tmp_path / "figs").exists()


def test_existing_pngs_are_kept_without_force(mf, tmp_path, monkeypatch, capsys):
    _fake_browser(tmp_path)
    monkeypatch.setenv("PATH", str(tmp_path))
    out = tmp_path / "figs"
    out.mkdir()
    for name in mf.PAGES:
        (out / name).write_bytes(b"old")
    assert mf.main(["--out", str(out)]) == 1  # nothing to do: no campaign is simulated
    said = capsys.readouterr().out
    assert all(f"{out / name} exists; pass --force to replace it" in said for name in mf.PAGES)
    assert all((out / name).read_bytes() == b"old" for name in mf.PAGES)


def test_blocked(mf, tmp_path):
    a, b = tmp_path / "a.png", tmp_path / "b.png"
    a.write_bytes(b"x")
    assert mf.blocked([a, b], force=False) == [a]
    assert mf.blocked([a, b], force=True) == []


def test_atomic_write_force_and_failure(mf, tmp_path):
    dest = tmp_path / "sub" / "shot.png"
    mf.atomic_write(dest, lambda tmp: tmp.write_bytes(b"one"), force=False)
    assert dest.read_bytes() == b"one"
    with pytest.raises(FileExistsError, match="--force"):
        mf.atomic_write(dest, lambda tmp: tmp.write_bytes(b"two"), force=False)
    assert dest.read_bytes() == b"one"

    def fail(tmp: Path) -> None:
        tmp.write_bytes(b"half")
        raise RuntimeError("browser crashed")

    with pytest.raises(RuntimeError, match="crashed"):
        mf.atomic_write(dest, fail, force=True)
    assert dest.read_bytes() == b"one"  # the old file, untouched
    mf.atomic_write(dest, lambda tmp: tmp.write_bytes(b"two"), force=True)
    assert dest.read_bytes() == b"two"
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(dest.stat().st_mode) == 0o666 & ~umask  # not mkstemp's private 0600
    assert os.listdir(dest.parent) == ["shot.png"]  # no temporary file left behind


def test_figures_loaded(mf):
    assert mf.figures_loaded('<body data-figures-loaded="7/7">') == (7, 7)
    assert mf.figures_loaded('<body data-figures-loaded="3/7">') == (3, 7)
    assert mf.figures_loaded("<body>") is None


def test_clean_cut(mf):
    assert mf.clean_cut([False, True, False, False]) == 2
    assert mf.clean_cut([False, False, True]) == 3
    assert mf.clean_cut([False] * 5) == 5
    assert mf.clean_cut([True] + [False] * 10, slack=5) == 11  # a blank row too far up is not used


def test_finish_png_cuts_at_white_space_and_limits_width(mf, tmp_path):
    from PIL import Image

    a = np.full((300, 2000, 3), 255, np.uint8)
    a[20:200, 300:1700] = (200, 30, 30)  # a block of content, white below it
    a[240:300, 300:1700] = (30, 30, 200)  # the next block, cut off by the window's edge
    png = tmp_path / "shot.png"
    Image.fromarray(a).save(png)
    mf.finish_png(png, max_width=1000)
    with Image.open(png) as im:
        assert im.width == 1000
        assert im.height == round(240 * 1000 / 2000)  # ends above the cut-off block
        b = np.asarray(im.convert("RGB"))
    assert (b[-1] == 255).all() and (b[50, 400] != 255).any()
