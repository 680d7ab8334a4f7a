"""The fits run with one BLAS thread (granseg.fitting.threads), and the limit is lifted after."""

from __future__ import annotations

import os
import subprocess
import sys
import warnings

import pytest
from threadpoolctl import threadpool_info

import granseg
import granseg.fitting.solve as solve
from granseg.synth.virtual import TABLE1, campaign


def _blas_threads() -> set[int]:
    return {lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"}


@pytest.mark.parametrize("entry", ["calibrate", "diagnose"])
def test_the_fits_use_one_blas_thread_and_give_the_rest_back(monkeypatch, entry):
    before = _blas_threads()
    if not before:
        pytest.skip("no BLAS library that threadpoolctl can see")
    seen: list[set[int]] = []
    compress = solve.compress

    def spy(res, jac):
        seen.append(_blas_threads())
        return compress(res, jac)

    monkeypatch.setattr(solve, "compress", spy)
    maps = campaign(conditions=TABLE1[:3], seed=3, duration=1200, fps=1 / 30)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a 3-experiment campaign is small: its warnings say so
        if entry == "calibrate":
            granseg.calibrate(maps, progress=False, max_nfev=3)
        else:
            granseg.diagnose(maps, progress=False, causes=["diffusivity_scale"], n_cells=30)
    assert seen and all(s == {1} for s in seen), seen
    assert _blas_threads() == before


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="one core: BLAS runs one thread anyway")
def test_the_limit_holds_for_a_blas_the_first_fit_loads():
    # scipy's OpenBLAS loads with scipy, which the fitting layer imports inside its functions: a
    # limit set before it loaded would not reach it, and the process's first fit ran on every core
    code = """if True:
        from threadpoolctl import threadpool_info
        from granseg.fitting.threads import one_blas_thread

        @one_blas_thread
        def first_fit():
            import scipy.optimize  # as the fitting layer imports it, on the first fit
            return {lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"}

        print(sorted(first_fit()))
    """
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert r.stdout.strip() == "[1]", r.stdout
