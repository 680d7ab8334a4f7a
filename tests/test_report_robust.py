"""``granseg report`` neither aborts, hangs nor hides (issue 14).

A name that looks like mathtext is drawn as written; a failed report leaves
nothing that blocks the rerun; a full disk is one line naming the file; a bad
--c0 or a taken output folder is refused before any work; and the figures are
drawn, saved and freed one at a time, so memory does not grow with the
campaign (counted in live figures, not timed).
"""

from __future__ import annotations

import errno
import functools
import gc
import os
import weakref
from pathlib import Path

import pytest
from matplotlib.figure import Figure

pytest.importorskip("granseg._core", reason="the Rust extension is not built (maturin develop)")

from granseg.cli import main  # noqa: E402
from granseg.synth.virtual import Condition, campaign  # noqa: E402

NASTY = r"G-$\foo{$-50"  # mathtext would parse it (and fail); the page must escape it too
HTMLISH = "PP<b>&-25"
FAST = ["-q", "--n-cells", "48", "--no-refine"]


def _campaign(out: Path, names: tuple[str, str]) -> Path:
    conds = [Condition("glass", "PP", 0.5, 2.04, name=names[0]), Condition("steel", "PP", 0.5, 5.25),
             Condition("ceramic", "PP", 0.25, 2.3, name=names[1])]
    campaign(out, conditions=conds, seed=1, noise="independent", fps=0.05, duration=2400.0, n_cells=48)
    return out


@pytest.fixture(scope="module")
def nasty(tmp_path_factory) -> Path:
    """Three small virtual experiments, one named like a formula, one like markup."""
    return _campaign(tmp_path_factory.mktemp("nasty"), (NASTY, HTMLISH))


@pytest.fixture(scope="module")
def camp(tmp_path_factory) -> Path:
    """Three small virtual experiments with plain names (each test below fails for its own reason)."""
    return _campaign(tmp_path_factory.mktemp("campaign"), ("G-PP-50", "C-PP-25"))


@pytest.fixture(scope="module")
def cal(camp):
    from granseg.calibration import calibrate
    from granseg.maps import load_campaign

    return calibrate(load_campaign(camp), refine=False, n_cells=48, progress=False)


def no_partial(folder: Path) -> list[Path]:
    return sorted(folder.glob(".*.partial"))


def test_a_name_like_mathtext_or_markup_is_shown_as_written(nasty, tmp_path, capsys):
    from granseg import plot
    from granseg.maps import load_campaign
    from granseg.report.html import esc

    out = tmp_path / "rep"
    assert main(["report", str(nasty), "--out", str(out), *FAST]) == 0, capsys.readouterr().err
    page = (out / "index.html").read_text()
    assert esc(NASTY) in page and esc(HTMLISH) in page and HTMLISH not in page
    assert any("foo" in p.name for p in (out / "figures").glob("map_*.png"))
    # what matplotlib shows: the name itself, not a formula (Text._preprocess_math is what it draws)
    maps = load_campaign(nasty)
    fig = plot.bottom_fits(list(maps), {})
    labels = [t for ax in fig.get_axes() if ax.get_legend() for t in ax.get_legend().get_texts()]
    shown = {t._preprocess_math(t.get_text())[0].removesuffix(" (no fit)") for t in labels}
    assert {NASTY, HTMLISH} <= shown


def test_a_failed_report_leaves_nothing_and_the_rerun_works(camp, cal, tmp_path, monkeypatch):
    from granseg.report import build_report, html

    real = html.save_figure
    calls = []

    def failing(fig, stem, **kw):
        calls.append(stem)
        if len(calls) == 3:
            raise ValueError("mathtext could not parse this name")  # what the name did
        return real(fig, stem, **kw)

    out = tmp_path / "rep"
    monkeypatch.setattr(html, "save_figure", failing)
    with pytest.raises(ValueError, match="mathtext"):
        build_report(camp, out, calibration=cal, progress=False)
    assert not out.exists() and not no_partial(tmp_path)
    # an existing (empty) folder is left as it was
    out.mkdir()
    calls.clear()
    with pytest.raises(ValueError, match="mathtext"):
        build_report(camp, out, calibration=cal, progress=False)
    assert list(out.iterdir()) == [] and not no_partial(tmp_path)
    monkeypatch.setattr(html, "save_figure", real)
    page = build_report(camp, out, calibration=cal, progress=False)
    assert page == out / "index.html" and page.is_file() and (out / "report.json").is_file()
    assert not no_partial(out) and not no_partial(tmp_path)


def test_a_full_disk_is_one_line_naming_the_file(camp, tmp_path, monkeypatch, capsys):
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    real = FigureCanvasAgg.print_png

    @functools.wraps(real)  # matplotlib passes the keywords the signature names
    def full(self, filename_or_obj, *args, **kwargs):
        if Path(str(filename_or_obj)).name == "laws.png":
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))  # what a write says: no file name
        return real(self, filename_or_obj, *args, **kwargs)

    monkeypatch.setattr(FigureCanvasAgg, "print_png", full)
    out = tmp_path / "rep"
    assert main(["report", str(camp), "--out", str(out), *FAST]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert err.startswith("granseg report: error:") and os.strerror(errno.ENOSPC) in err
    assert str(out / "figures" / "laws.png") in err and ".partial" not in err
    assert not out.exists() and not no_partial(tmp_path)


def _no_work(monkeypatch) -> None:
    import granseg.report.calibration as rc

    def work(*args, **kwargs):
        raise AssertionError("the campaign was read or calibrated before the arguments were checked")

    monkeypatch.setattr(rc, "load_campaign", work)
    monkeypatch.setattr(rc, "calibrate", work)
    monkeypatch.setattr(rc, "fit_campaign", work)


@pytest.mark.parametrize("bad", ["5", "-0.5", "nan"])
def test_c0_out_of_range_is_refused_before_any_work(camp, tmp_path, monkeypatch, capsys, bad):
    _no_work(monkeypatch)
    with pytest.raises(SystemExit) as stop:
        main(["report", str(camp), "--out", str(tmp_path / "rep"), "--c0", bad, *FAST])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert "--c0" in err and "Traceback" not in err
    assert not (tmp_path / "rep").exists()


def test_c0_minus_one_and_the_api_check(camp, tmp_path, monkeypatch, capsys):
    from granseg.report import build_report

    _no_work(monkeypatch)
    with pytest.raises(ValueError, match="fits_c0"):
        build_report(camp, tmp_path / "rep", fits_c0=5.0)
    # -1 (all experiments) is accepted: the work starts (and meets the stand-in above)
    assert main(["report", str(camp), "--out", str(tmp_path / "rep"), "--c0", "-1", *FAST]) == 4
    assert "before the arguments were checked" in capsys.readouterr().err


def test_a_taken_or_unwritable_output_is_refused_before_any_work(camp, tmp_path, monkeypatch, capsys):
    _no_work(monkeypatch)
    taken = tmp_path / "taken"
    (taken / "figures").mkdir(parents=True)  # what a failed report used to leave behind
    assert main(["report", str(camp), "--out", str(taken), *FAST]) == 2
    err = capsys.readouterr().err
    assert str(taken) in err and "figures" in err and "--force" in err
    a_file = tmp_path / "a_file"
    a_file.write_text("mine")
    for out, what in ((a_file, "not a directory"), (a_file / "rep", "not a directory"),
                      (tmp_path / "missing" / "rep", "does not exist")):
        assert main(["report", str(camp), "--out", str(out), *FAST]) == 2
        err = capsys.readouterr().err
        assert what in err and str(out.parent if out != a_file else out) in err, err
    assert a_file.read_text() == "mine" and not (tmp_path / "missing").exists()
    if os.geteuid() != 0:  # root writes anywhere
        locked = tmp_path / "locked"
        locked.mkdir(mode=0o500)
        assert main(["report", str(camp), "--out", str(locked / "rep"), *FAST]) == 2
        assert "not writable" in capsys.readouterr().err


@pytest.mark.parametrize("paged", [False, True])
def test_figures_are_drawn_saved_and_freed_one_at_a_time(camp, cal, tmp_path, monkeypatch, paged):
    """Memory flat in the number of experiments: at every save, at most the figure being
    saved is alive (counted after a full garbage collection), and every figure saved before
    is gone or emptied. ``paged``: the maps on pages (what a large campaign gets)."""
    import json

    import granseg.report.calibration as rc
    from granseg.report import build_report, html

    if paged:  # three experiments drawn as a large campaign's are: one page of maps, PNG only
        monkeypatch.setattr(rc, "ONE_FIGURE_PER_EXPERIMENT_UP_TO", 2)
    real = html.save_figure
    gc.collect()
    before = sum(isinstance(o, Figure) for o in gc.get_objects())
    alive, saved = [], []

    def counting(fig, stem, **kw):
        gc.collect()
        alive.append(sum(isinstance(o, Figure) for o in gc.get_objects()) - before)
        assert all(r() is None or not r().axes for r in saved), "a saved figure still holds its axes"
        saved.append(weakref.ref(fig))  # not a reference that would keep it alive
        return real(fig, stem, **kw)

    monkeypatch.setattr(html, "save_figure", counting)
    page = build_report(camp, tmp_path / "rep", calibration=cal, progress=False)
    # bottom fits, laws, RMSD grid, profiles, and three map comparisons or one page of them
    assert len(saved) == (5 if paged else 7)
    assert max(alive) <= 1, alive
    assert all(r() is None or not r().axes for r in saved)
    figs = json.loads((tmp_path / "rep" / "report.json").read_text())["figures"]
    assert page.read_text().count('<img class="fig"') == len(figs) == len(saved)
    if paged:
        (maps,) = [f for f in figs if f["id"].startswith("maps_")]
        assert "pdf" not in maps and (tmp_path / "rep" / maps["png"]).is_file()
        assert "experiments 1-3 of 3" in maps["caption"]
