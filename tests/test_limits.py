"""Nothing aborts, hangs or hides (issue 14): sizes are refused before anything is allocated,
naming the parameter and the bytes; threads are bounded; Ctrl-C stops the core's long loops;
layers and velocity_profile name what they refuse.

The calls that used to abort the process (SIGABRT on a failed allocation) or run for hours
also run in a subprocess, so that a regression fails a test instead of killing the suite."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

import granseg
from granseg import _core, model


def _run(code: str, timeout: float = 60.0) -> subprocess.CompletedProcess:
    """Run Python code in a fresh interpreter; the test fails (not the suite) on an abort."""
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True,
                          timeout=timeout)


def test_limits_come_from_the_core():
    lim = _core.limits()
    assert lim["max_bytes"] == 4 * 2**30 == model.MAX_BYTES
    assert lim["max_cells"] == model.MAX_CELLS == 100_000
    assert model.MAX_OUTPUT_TIMES == lim["max_output_times"] and model.MAX_THREADS == lim["max_threads"]


def test_simulate_with_two_million_cells_is_refused_naming_it_and_the_bytes():
    t0 = time.perf_counter()
    with pytest.raises(ValueError, match=r"n_cells = 2000000.*28816000000 bytes"):
        granseg.simulate(t=np.arange(0.0, 3601.0, 2.0), n_cells=2_000_000, field=True)
    assert time.perf_counter() - t0 < 2.0
    # without the field (the default) the layer map is small, and the cell count is what is refused
    with pytest.raises(ValueError, match=r"n_cells = 2000000 is out of range: must be <= 100000"):
        granseg.simulate(t=np.arange(0.0, 3601.0, 2.0), n_cells=2_000_000)
    # the core on its own (no Python check in front of it) refuses it too
    with pytest.raises(ValueError, match=r"len\(t\) = 1801 x n_cells = 2000000.*28816000000 bytes"):
        _core.simulate(model.defaults(), np.arange(0.0, 3601.0, 2.0), 2_000_000, 3e-5, 3e-6)
    with pytest.raises(ValueError, match=r"n_cells = 200000 is out of range: must be <= 100000.*bytes"):
        granseg.simulate(t=[0.0, 1.0], n_cells=200_000)


@pytest.mark.parametrize("t", [
    np.linspace(0.0, 1e9, 3_000_001),  # --t-end 1e9: too many outputs
    np.arange(0.0, 3.6, 1e-6),         # --dt 1e-6: too many outputs
])
def test_too_many_output_times_are_refused_naming_t_and_the_bytes(t):
    n = t.size
    t0 = time.perf_counter()
    with pytest.raises(ValueError, match=rf"t has {n} output times: at most 1000000 .*{n * 180 * 8} bytes"):
        granseg.simulate(t=t)
    with pytest.raises(ValueError, match=r"len\(t\)|t has"):
        _core.simulate(model.defaults(), t, 180, 3e-5, 3e-6)
    assert time.perf_counter() - t0 < 5.0


def test_the_calls_that_aborted_now_raise_in_a_live_process():
    r = _run("""
        import numpy as np
        from granseg import _core, model
        p = model.defaults()
        for t, n in ((np.arange(0.0, 3601.0, 2.0), 2_000_000), (np.linspace(0, 1e9, 4_000_001), 180),
                     (np.array([0.0, 1.0]), 2**62)):
            try:
                _core.simulate(p, t, n, 3e-5, 3e-6)
            except ValueError as e:
                print("refused:", e)
        try:
            _core.steady_state(p, 10**8)
        except ValueError as e:
            print("refused:", e)
        print("alive")
    """)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert lines[-1] == "alive" and sum(x.startswith("refused:") for x in lines) == 4, r.stdout
    assert "28816000000 bytes" in lines[0] and "bytes" in lines[1] and "more than" in lines[2]


def test_the_cli_refuses_huge_runs_with_one_line(tmp_path):
    for args, what in ((["--n-cells", "2000000"], "28816000000 bytes"), (["--t-end", "1e7"], "output times"),
                      (["--t-end", "1e9"], "output times"), (["--dt", "1e-6"], "output times")):
        r = subprocess.run([sys.executable, "-c", "import sys; from granseg.cli import main; sys.exit(main(sys.argv[1:]))",
                            "simulate", *args, "--out", str(tmp_path / "x")], capture_output=True, text=True, timeout=120)
        assert r.returncode == 2, r.stderr
        assert what in r.stderr and "Traceback" not in r.stderr, r.stderr


def test_steady_state_bounds_n_cells():
    t0 = time.perf_counter()
    with pytest.raises(ValueError, match=r"n_cells = 100000000 is out of range: must be <= 100000"):
        granseg.steady_state(n_cells=100_000_000)
    with pytest.raises(ValueError, match="n_cells = 100000000"):
        _core.steady_state(model.defaults(), 100_000_000)
    with pytest.raises(ValueError, match="sub_steps"):
        _core.steady_state(model.defaults(), 180, 10**9)
    assert time.perf_counter() - t0 < 2.0


def test_sweep_refuses_ten_thousand_threads_at_once():
    t0 = time.perf_counter()
    with pytest.raises(ValueError, match=r"threads = 10000"):
        granseg.sweep({"k": [0.6, 0.7]}, t=[0.0, 60.0], n_cells=30, threads=10_000)
    with pytest.raises(ValueError, match=r"threads = 10000 is out of range"):
        _core.sweep([model.defaults()], [np.array([0.0, 60.0])], [None], [1], [15], 30, 3e-5, 3e-6, 10_000)
    assert time.perf_counter() - t0 < 2.0
    for bad in (0, True, 2.5):
        with pytest.raises(ValueError, match="threads"):
            granseg.sweep({"k": [0.6]}, t=[0.0, 60.0], n_cells=30, threads=bad)
    assert granseg.sweep({"k": [0.6]}, t=[0.0, 60.0], n_cells=30, threads=model.MAX_THREADS // 64).n_runs == 1


def test_sweep_refuses_layer_maps_beyond_the_byte_ceiling():
    t, n = np.linspace(0.0, 60.0, 1000), 30  # 30 runs x 1000 times x 90000 layers x 8 bytes: 21.6 GB
    t0 = time.perf_counter()
    with pytest.raises(ValueError, match=r"layer maps of the sweep's 30 runs .* 21600000000 bytes"):
        _core.sweep([model.defaults()] * n, [t] * n, [None] * n, [1] * n, [90_000] * n, 30, 3e-5, 3e-6)
    assert time.perf_counter() - t0 < 2.0


def test_layers_refuses_a_count_below_one_naming_it():
    sol = granseg.simulate(t=[0.0, 60.0], n_cells=30, field=True)
    for bad in (-3, 0, -3.0, 2.5, float("nan"), True, "5", 10**6):
        with pytest.raises(ValueError, match="n_layers"):
            sol.layers(bad)
    assert sol.layers(np.int64(5)).shape == sol.layers(5.0).shape == (2, 5)


def test_velocity_profile_refuses_heights_outside_the_bed():
    H = model.defaults()["H"]
    for bad in ([-0.01, 0.0], [0.0, 2 * H], [np.nan], [[0.0, 0.01], [0.02, -1e-3]]):
        with pytest.raises(ValueError, match=r"z must lie in \[0, H\]"):
            model.velocity_profile(bad)
    with pytest.raises(ValueError, match=r"z must lie in \[0, H\]"):
        _core.velocity_profile(model.defaults(), np.array([-0.05]), 0.0)
    v, g = model.velocity_profile([0.0, H])  # both walls are in the bed
    assert np.all(np.isfinite(v)) and v[0] > v[1] >= 0


def _interrupt_after(code: str, wait: float = 1.0) -> tuple[subprocess.CompletedProcess, float]:
    """Start ``code`` (which prints 'go' before its long call), SIGINT it ``wait`` s later;
    return the finished process and how long it took to end after the signal."""
    # SIGINT handled as under a terminal: tests run in the background of a script (`./dev.sh
    # test &`) hand the child SIGINT ignored, and a Python started so never installs the handler
    # that raises KeyboardInterrupt, so every test here would wait out its timeout. Set in the
    # child, not by preexec_fn, which is unsafe in a parent with threads.
    as_in_a_terminal = "import signal\nsignal.signal(signal.SIGINT, signal.default_int_handler)\n"
    pr = subprocess.Popen([sys.executable, "-c", as_in_a_terminal + textwrap.dedent(code)],
                          stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert pr.stdout.readline().strip() == "go"
        time.sleep(wait)
        assert pr.poll() is None, "the call ended before the signal: make it longer"
        t0 = time.perf_counter()
        os.kill(pr.pid, signal.SIGINT)
        out, err = pr.communicate(timeout=30)
        return subprocess.CompletedProcess(pr.args, pr.returncode, out, err), time.perf_counter() - t0
    finally:
        if pr.poll() is None:
            pr.kill()
            pr.communicate()


@pytest.mark.skipif(sys.platform == "win32", reason="SIGINT to a child process is POSIX")
@pytest.mark.parametrize("call", [
    # each runs for tens of seconds uninterrupted
    "_core.steady_state(model.defaults(), 100_000, 4096)",
    "granseg.simulate(t=[0.0, 3600.0], n_cells=100_000, rtol=1e-10, atol=1e-12)",
    "granseg.sweep({'k': [0.5, 0.6, 0.7, 0.8]}, t=[0.0, 3600.0], n_cells=100_000, rtol=1e-10, atol=1e-12, threads=2)",
])
def test_ctrl_c_stops_the_core_with_keyboard_interrupt(call):
    r, took = _interrupt_after(f"""
        import sys
        import granseg
        from granseg import _core, model
        print("go", flush=True)
        try:
            {call}
        except KeyboardInterrupt:
            print("KeyboardInterrupt", flush=True)
            sys.exit(130)
        print("finished", flush=True)
    """)
    assert r.returncode == 130 and r.stdout.splitlines()[-1] == "KeyboardInterrupt", (r.stdout, r.stderr)
    assert took < 5.0, took


@pytest.mark.skipif(not Path("/proc/self/status").is_file(), reason="reads the peak memory from /proc (Linux)")
def test_a_long_runs_output_is_filled_as_it_is_written_not_before():
    # 1801 times x 100 000 cells is a 1.44 GB field; stopped after a second, the run has
    # touched only the rows it wrote (zeroing it all first took a second that Ctrl-C had to
    # wait). The peak is the child's own, VmHWM: ru_maxrss also counts the parent's memory at
    # the fork, over a gigabyte late in a test session.
    r, took = _interrupt_after("""
        import re
        import granseg
        print("go", flush=True)
        try:
            granseg.simulate(t=[2.0 * i for i in range(1801)], n_cells=100_000, rtol=1e-10, atol=1e-12, field=True)
        except KeyboardInterrupt:
            with open("/proc/self/status") as f:
                print(re.search(r"VmHWM:\\s*(\\d+) kB", f.read()).group(1), flush=True)
    """)
    assert r.returncode == 0, (r.stdout, r.stderr)
    assert int(r.stdout.split()[-1]) < 600_000, r.stdout  # kB
    assert took < 5.0, took


@pytest.mark.skipif(sys.platform == "win32", reason="SIGINT to a child process is POSIX")
@pytest.mark.parametrize("wait", [0.1, 3.0])  # while the commands' modules load; while it solves
def test_ctrl_c_in_the_cli_prints_interrupted_and_exits_130(tmp_path, wait):
    r, took = _interrupt_after(f"""
        import sys
        from granseg.cli import main
        print("go", flush=True)
        sys.exit(main(["simulate", "--n-cells", "100000", "--rtol", "1e-10", "--atol", "1e-12",
                       "--out", {str(tmp_path / "x")!r}]))
    """, wait=wait)
    assert r.returncode == 130, (r.stdout, r.stderr)
    assert "granseg: interrupted" in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert took < 5.0, took
