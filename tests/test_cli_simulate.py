"""``granseg simulate`` as a user runs it."""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

import granseg
import granseg.model
from granseg.cli import main
from granseg.maps import load_map


def test_simulate_prints_a_summary_and_writes_figure_and_map(tmp_path, capsys):
    out = tmp_path / "run"
    npz = tmp_path / "run.npz"
    code = main(["simulate", "--heavy", "ceramic", "--light", "PP", "--c0", "0.75",
                 "--t-end", "600", "--dt", "5", "--n-cells", "90", "--out", str(out), "--npz", str(npz)])
    assert code == 0
    text = capsys.readouterr().out
    assert "delta_R = 3.700" in text and "mass drift" in text and "layer 14" in text
    for ext in (".png", ".pdf"):
        assert (tmp_path / f"run{ext}").stat().st_size > 10_000
    m = load_map(npz)
    assert m.c.shape == (121, 15) and abs(m.delta_R - 3500 / 946) < 1e-12
    assert np.all((m.c >= 0) & (m.c <= 1))
    # grain mass from the core's annulus area: phi_s A H rho_solid
    p = granseg.model.defaults()
    area = np.pi * (p["D_out"] ** 2 - p["D_in"] ** 2) / 4
    assert m.M_g == pytest.approx(p["phi_s"] * area * p["H"] * (3500 * 0.75 + 946 * 0.25), rel=1e-12)
    assert m.M_w == p["M_w"]


def test_simulate_refuses_to_overwrite_and_names_bad_input(tmp_path, capsys):
    out = tmp_path / "run"
    (tmp_path / "run.png").write_bytes(b"keep me")
    assert main(["simulate", "--t-end", "10", "--out", str(out)]) == 2
    assert (tmp_path / "run.png").read_bytes() == b"keep me"
    assert "exists" in capsys.readouterr().err
    assert main(["simulate", "--heavy", "gold", "--out", str(tmp_path / "x")]) == 2
    assert "gold" in capsys.readouterr().err
    assert main(["simulate", "--set", "k=-1", "--t-end", "10", "--out", str(tmp_path / "y")]) == 2
    assert "parameter k" in capsys.readouterr().err


@pytest.mark.parametrize("argv", [["--help"], ["simulate", "--help"]])
def test_help_works(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 0
    assert "granseg" in capsys.readouterr().out


def test_version_is_the_packages(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0 and capsys.readouterr().out == f"granseg {granseg.__version__}\n"


def test_the_parser_needs_nothing_but_numpy():
    # every command builds the whole parser first; scipy.optimize and scipy.stats, imported by the
    # fitting layer to name the causes and error methods, made that 1.9 s of `granseg --help` (0.4 s now)
    code = ("import sys; from granseg.cli import build_parser; build_parser(); "
            "print(sorted({m.split('.')[0] for m in sys.modules if not m.startswith('_')} - set(sys.stdlib_module_names)))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert r.stdout.strip() == "['granseg', 'numpy']", r.stdout


def test_the_command_exits_quickly_with_its_files_whole_and_its_exit_status(tmp_path):
    # console() freezes the heap before Python exits (0.5 s less per command): what a run wrote
    # must still be complete, and the exit status what main returned
    root = Path(__file__).resolve().parents[1]
    entry = tomllib.loads((root / "pyproject.toml").read_text())["project"]["scripts"]["granseg"]
    assert entry == "granseg.cli:console"
    code = "import sys; from granseg.cli import console; sys.exit(console())"
    run = [sys.executable, "-c", code, "simulate", "--t-end", "600", "--out", str(tmp_path / "run"),
           "--npz", str(tmp_path / "run.npz")]
    assert subprocess.run(run, capture_output=True).returncode == 0
    assert load_map(tmp_path / "run.npz").c.shape[1] == 15
    assert all((tmp_path / f"run.{ext}").stat().st_size > 1000 for ext in ("png", "pdf"))
    assert subprocess.run(run, capture_output=True).returncode == 2  # the map is there: refused


def _raising(first: BaseException):
    """A stand-in for a command's code that raises SystemError while handling ``first``."""
    def call(*_):
        try:
            raise first
        except BaseException as exc:
            raise SystemError("initialization of _core raised unreported exception") from exc
    return call


@pytest.mark.parametrize("where", ["command", "parser"])  # while it runs; while its module registers
def test_an_error_raised_because_of_ctrl_c_ends_as_interrupted(monkeypatch, capsys, where):
    # Ctrl-C while a C extension loads can surface as a SystemError from the KeyboardInterrupt: once
    # in 60 interrupts that ended a command as an internal error (BENCHMARKS "Ctrl-C at any moment")
    import granseg.cli.export
    import granseg.cli.simulate

    if where == "command":
        monkeypatch.setattr(granseg.cli.simulate, "run", _raising(KeyboardInterrupt()))
    else:
        monkeypatch.setattr(granseg.cli.export, "register", _raising(KeyboardInterrupt()))
    assert main(["simulate", "--t-end", "10"]) == 130
    assert capsys.readouterr().err == "granseg: interrupted\n"


def test_the_same_error_from_anything_else_is_still_a_bug(monkeypatch, capsys):
    import granseg.cli.simulate

    monkeypatch.setattr(granseg.cli.simulate, "run", _raising(ValueError("no interrupt")))
    assert main(["simulate", "--t-end", "10"]) == 4
    assert "internal error: SystemError" in capsys.readouterr().err
