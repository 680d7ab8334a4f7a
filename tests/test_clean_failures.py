"""Issue 14, the cases that ended in a traceback, were accepted silently or were blamed on the
wrong thing: each now ends in one error naming the field, option or file, before the work starts."""

from __future__ import annotations

import json
import os
import shutil
import warnings
from pathlib import Path

import cv2
import pytest

import granseg
from granseg.cli import main
from granseg.errors import OutputExistsError
from granseg.measure import GreyFramesWarning, analyze, load_experiment
from granseg.synth.virtual import TABLE1, campaign

PBR = Path(__file__).parent / "fixtures" / "pbr" / "steel-pp"
HUGE = 10**400  # what json.loads gives for a 401-digit number: an int beyond any float


# --------------------------------------------------------------------------- numbers beyond a float


@pytest.mark.parametrize("call, name", [
    (lambda: granseg.simulate(t=[0, 10], rho_h=HUGE), "rho_h"),
    (lambda: granseg.steady_state(k=HUGE), "parameter k"),
    (lambda: granseg.sweep({"k": [HUGE]}, t=[0, 1]), "grid: k"),
    (lambda: granseg.simulate(t=[0, HUGE]), "t must be an array"),
    (lambda: granseg.simulate(t=[0, 10], n_cells=HUGE), "n_cells"),
    (lambda: granseg.simulate(t=[0, 10], rtol=HUGE), "rtol"),
])
def test_a_number_beyond_a_float_is_named_not_an_overflow(call, name):
    with pytest.raises(ValueError, match=name) as err:
        call()
    assert len(str(err.value)) < 300  # the 401 digits are cut


def test_a_bed_thinner_than_two_grains_is_refused():
    with pytest.raises(ValueError, match=r"D_p = 1 is out of range"):
        granseg.simulate(t=[0, 10], D_p=1.0)
    granseg.simulate(t=[0, 10], D_p=0.045)  # H/2: still a bed


def test_the_cli_refuses_set_D_p_1(capsys, tmp_path):
    code = main(["simulate", "--set", "D_p=1", "--t-end", "10", "--out", str(tmp_path / "s")])
    assert code == 2
    assert "D_p = 1 is out of range" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


# --------------------------------------------------------------------------- experiment.json


def recording(tmp_path: Path, name: str = "rec", **fields) -> Path:
    """A copy of a rendered 4-frame recording with experiment.json fields replaced."""
    d = tmp_path / name
    shutil.copytree(PBR, d, ignore=shutil.ignore_patterns("truth.npz"))
    exp = json.loads((d / "experiment.json").read_text())
    exp.update(fields)
    # json.dumps writes a big int as its digits, as a hand-edited file would hold them
    (d / "experiment.json").write_text(json.dumps(exp))
    return d


@pytest.mark.parametrize("fields, message", [
    ({"rho_h": HUGE}, r"field 'rho_h': expected a finite number, got 1000.*characters"),
    ({"window": [0, 0, HUGE, 10]}, r"field 'window': expected finite numbers"),
    ({"particle_diameter_px": 5000}, r"field 'particle_diameter_px': 5000 px does not fit the window"),
    ({"particle_diameter_px": 300}, r"field 'particle_diameter_px': 300 px does not fit"),
])
def test_experiment_json_fields_are_named(tmp_path, fields, message):
    d = recording(tmp_path, **fields)
    with pytest.raises(ValueError, match=message):
        load_experiment(d / "experiment.json")


def test_a_huge_sphere_is_refused_before_opencv_allocates(tmp_path, capsys):
    d = recording(tmp_path, particle_diameter_px=5000)
    assert main(["analyze", str(d), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "particle_diameter_px" in err and "internal error" not in err


def test_a_start_after_the_last_frame_is_blamed_on_t0_not_on_the_map(tmp_path, capsys):
    """A negative t0 (the camera started before the plate) leaves frames out; one that leaves
    none is refused, naming t0 (issue 14 was t0 = -5 s blamed on the map's field t)."""
    d = recording(tmp_path, t0=-1e6)
    assert main(["analyze", str(d), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "'t0'" in err and "field 't'" not in err


# --------------------------------------------------------------------------- analyze's arguments


@pytest.mark.parametrize("kwargs, name", [
    ({"workers": 0}, "workers"),
    ({"workers": -3}, "workers"),
    ({"preview_count": -2}, "preview_count"),
    ({"preview_count": 0}, "preview_count"),
])
def test_analyze_refuses_counts_below_one_before_reading(tmp_path, kwargs, name):
    # a missing path: a count checked first is named, not the path
    with pytest.raises(ValueError, match=name):
        analyze(tmp_path / "missing", progress=False, **kwargs)


@pytest.mark.parametrize("args, option", [
    (["--workers", "0"], "--workers"),
    (["--preview-count", "-2", "--preview", "pv"], "--preview-count"),
])
def test_the_cli_names_the_option(tmp_path, capsys, args, option):
    assert main(["analyze", str(recording(tmp_path)), "--no-progress", *args]) == 2
    assert option in capsys.readouterr().err


def test_grey_frames_are_said_to_be_grey(tmp_path):
    d = recording(tmp_path)
    for f in sorted(d.glob("frame_*.jpg")):
        cv2.imwrite(str(f), cv2.cvtColor(cv2.imread(str(f)), cv2.COLOR_BGR2GRAY))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        analyze(d, save=False, progress=False, smooth=1)
    grey = [w for w in caught if issubclass(w.category, GreyFramesWarning)]
    assert len(grey) == 1 and "frame_0000.jpg" in str(grey[0].message)


def test_colour_frames_are_not_called_grey(tmp_path):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        analyze(recording(tmp_path), save=False, progress=False, smooth=1)
    assert not [w for w in caught if issubclass(w.category, GreyFramesWarning)]


def test_a_first_frame_of_another_size_is_blamed_not_the_window(tmp_path):
    d = recording(tmp_path)
    first = d / "frame_0000.jpg"
    cv2.imwrite(str(first), cv2.imread(str(first))[:300, :300])
    with pytest.raises(ValueError, match=r"frame_0000.jpg: the first frame is 300 x 300 px but frame_0001.jpg") as err:
        analyze(d, save=False, progress=False)
    assert "window" not in str(err.value)


# --------------------------------------------------------------------------- outputs checked first


@pytest.fixture
def no_work(monkeypatch):
    """Fail the test if the frames are analysed or the campaign diagnosed."""
    import granseg.diagnosis.run as run
    import granseg.measure.pipeline as pipeline

    def refuse(*a, **k):
        raise AssertionError("the work started before the outputs were checked")

    monkeypatch.setattr(pipeline, "_detect_all", refuse)
    monkeypatch.setattr(run, "_as_maps", refuse)


def test_a_preview_clash_is_found_before_the_frames_are_read(tmp_path, no_work):
    d = recording(tmp_path)
    pv = tmp_path / "pv"
    pv.mkdir()
    (pv / "preview_frame_0000.png").write_bytes(b"mine")
    with pytest.raises(OutputExistsError, match="preview_frame_0000.png"):
        analyze(d, preview=pv, out=tmp_path / "m.npz", progress=False)
    assert (pv / "preview_frame_0000.png").read_bytes() == b"mine"


@pytest.mark.parametrize("where, error", [
    ("a_file/map.npz", NotADirectoryError),
    ("a_file/sub/map.npz", NotADirectoryError),
])
def test_a_map_under_a_file_is_refused_before_the_frames_are_read(tmp_path, no_work, where, error):
    (tmp_path / "a_file").write_text("x")
    with pytest.raises(error, match="a_file"):
        analyze(recording(tmp_path), out=tmp_path / where, progress=False)


@pytest.mark.skipif(not Path("/proc/self").exists() or os.access("/proc", os.W_OK) and os.geteuid() != 0,
                    reason="needs a Linux /proc")
def test_json_under_proc_is_refused_before_the_diagnosis(tmp_path, no_work):
    with pytest.raises(PermissionError, match="/proc"):
        granseg.diagnose(tmp_path, json="/proc/diagnosis.json", progress=False)


def test_diagnose_outputs_are_checked_before_the_work(tmp_path, no_work):
    (tmp_path / "a_file").write_text("x")
    with pytest.raises(NotADirectoryError, match="a_file"):
        granseg.diagnose(tmp_path, json=tmp_path / "a_file" / "d.json", progress=False)
    report = tmp_path / "report"
    report.mkdir()
    (report / "index.html").write_text("mine")
    with pytest.raises(OutputExistsError, match="index.html"):
        granseg.diagnose(tmp_path, report=report, progress=False)


def test_the_diagnose_cli_checks_its_report_folder_first(tmp_path, no_work, capsys):
    report = tmp_path / "report"
    report.mkdir()
    (report / "diagnosis.json").write_text("mine")
    assert main(["diagnose", str(tmp_path), "--report", str(report), "--quiet"]) == 2
    assert "diagnosis.json" in capsys.readouterr().err
    assert (report / "diagnosis.json").read_text() == "mine"


# --------------------------------------------------------------------------- campaigns that were refused


@pytest.fixture(scope="module")
def small_campaign(tmp_path_factory):
    d = tmp_path_factory.mktemp("small") / "campaign"
    campaign(d, conditions=TABLE1[:3], seed=3, duration=2400, fps=1 / 30)
    return d


def test_a_folder_name_that_is_not_utf8_is_reported(small_campaign, tmp_path, capsys):
    try:
        odd = Path(os.fsdecode(os.fsencode(str(tmp_path)) + b"/camp\xff"))
        shutil.copytree(small_campaign, odd)
    except (OSError, UnicodeError):
        pytest.skip("this file system refuses non-UTF-8 names")
    out = Path(os.fsdecode(os.fsencode(str(tmp_path)) + b"/diag\xff"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a 3-experiment campaign is small; the warnings say so
        code = main(["diagnose", str(odd), "--json", str(out) + ".json", "--report", str(out), "--quiet"])
    assert code == 0, capsys.readouterr().err
    assert "\\udcff" in (out / "index.html").read_text(encoding="utf-8")
    json.loads(Path(str(out) + ".json").read_text(encoding="utf-8"))  # still valid JSON


def test_a_14_layer_campaign_is_diagnosed(tmp_path):
    d = tmp_path / "c14"
    campaign(d, conditions=TABLE1[:3], seed=3, duration=2400, fps=1 / 30, n_layers=14)
    assert {m.n_layers for m in granseg.load_campaign(d)} == {14}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        dg = granseg.diagnose(d, progress=False, n_cells=60)
    assert dg.result["baseline"]["rmsd_mean"] < 0.2
