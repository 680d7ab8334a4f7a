"""The solver's physics invariants and its agreement with an independent
implementation (tests/reference_mol.py)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import granseg
from reference_mol import Reference

RHO_L = 946.0


def floats(lo, hi):
    return st.floats(lo, hi, allow_nan=False, allow_infinity=False)


physical = dict(
    delta_r=floats(1.0, 12.0),
    c0=floats(0.05, 0.95),
    k=floats(0.2, 2.0),
    d=floats(0.05, 0.6),
)


@given(**physical)
def test_mass_is_conserved_and_c_stays_in_bounds(delta_r, c0, k, d):
    sol = granseg.simulate(rho_h=delta_r * RHO_L, rho_l=RHO_L, c0=c0, k=k, delta_over_H=d,
                           t=[0.0, 30.0, 300.0, 3600.0], n_cells=60, field=True)
    mean = sol.c.mean(axis=1)
    assert np.max(np.abs(mean - mean[0]) / mean[0]) <= 1e-12
    assert abs(mean[0] - c0) < 1e-12
    assert sol.c.min() >= 0.0 and sol.c.max() <= 1.0


@given(c0=floats(0.05, 0.95), k=floats(0.2, 2.0), d=floats(0.15, 0.6))
def test_equal_densities_tend_to_the_mixed_state(c0, k, d):
    sol = granseg.simulate(rho_h=2450, rho_l=2450, c0=c0, k=k, delta_over_H=d,
                           t=[0.0, 1e7], n_cells=45, field=True)
    assert np.max(np.abs(sol.c[-1] - c0)) < 1e-3
    z, c = granseg.steady_state(rho_h=2450, rho_l=2450, c0=c0, k=k, delta_over_H=d, n_cells=45)
    np.testing.assert_allclose(c, c0, atol=1e-12)


@given(delta_r=floats(1.4, 8.25), c0=floats(0.1, 0.9), k=floats(0.4, 1.0), d=floats(0.15, 0.3))
def test_long_time_solution_lands_on_the_steady_state(delta_r, c0, k, d):
    p = dict(rho_h=delta_r * RHO_L, rho_l=RHO_L, c0=c0, k=k, delta_over_H=d)
    sol = granseg.simulate(**p, t=[0.0, 2e6], n_cells=720, rtol=1e-6, atol=1e-8)
    z, c = granseg.steady_state(**p, n_cells=720)
    assert abs(c.mean() - c0) < 1e-12
    steady = granseg.Solution(t=np.zeros(1), z=z, c=c[None], params=p).layers()[0]
    assert np.max(np.abs(sol.layers()[-1] - steady)) < 1e-4


@pytest.mark.parametrize("params", [
    dict(rho_h=7800, rho_l=946, c0=0.5),                                 # S-PP, delta_R = 8.25
    dict(rho_h=12 * 946, rho_l=946, c0=0.3, k=0.2, delta_over_H=0.3),    # cell Peclet ~ 20
])
def test_sharp_fronts_do_not_ring(params):
    # a scheme that rings adds total variation on a coarse grid; the limited,
    # species-upwinded flux must not exceed the variation of a fine solution
    t = np.linspace(0, 600, 61)
    coarse = granseg.simulate(**params, t=t, n_cells=30, field=True)
    fine = granseg.simulate(**params, t=t, n_cells=480, rtol=1e-6, atol=1e-8, field=True)

    def tv(c):
        return np.abs(np.diff(c, axis=1)).sum(axis=1)

    assert np.all(tv(coarse.c) <= tv(fine.c) + 1e-9)


def test_grid_convergence_is_second_order():
    t = np.arange(0, 1801, 30.0)
    maps = {n: granseg.simulate(t=t, n_cells=n, rtol=1e-8, atol=1e-10).layers() for n in (45, 90, 180, 360)}
    errs = [np.abs(maps[n] - maps[2 * n]).max() for n in (45, 90, 180)]
    orders = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    assert np.all(orders > 1.6), (errs, orders)


@pytest.mark.parametrize(
    "rho_h, rho_l, c0",
    [(2450, 946, 0.5), (3500, 946, 0.75), (7800, 1750, 0.25), (2450, 1750, 0.5), (7800, 946, 0.9)],
)
def test_agrees_with_an_independent_scipy_method_of_lines(rho_h, rho_l, c0):
    t = np.arange(0, 2401, 20.0)
    ref = Reference(rho_h, rho_l, c0, n=300)
    expected = ref.layers(ref.solve(t, rtol=1e-7, atol=1e-9))
    got = granseg.simulate(rho_h=rho_h, rho_l=rho_l, c0=c0, t=t).layers()
    assert np.max(np.abs(got - expected)) < 1e-3


# The two hardest of 48 cases drawn across the physical ranges by the
# default_survey example (seed 20261125): few heavy grains, a bed at steady
# state long before 3600 s. They missed 1e-3 (2.6e-3 and 1.1e-3) while a clip
# of the state re-evaluated its derivative (stepper::clipped_derivative).
SURVEYED_HARD = [
    dict(rho_h=5528.923646192358, c0=0.2000662011898057, k=0.5509447371591336, delta_over_H=0.16216022093156965),
    dict(rho_h=6149.4041183836325, c0=0.1587395006306096, k=0.5407121128359318, delta_over_H=0.2311835645426109),
]


@pytest.mark.parametrize("case", [{}, *SURVEYED_HARD], ids=["G-PP", "survey-c0-0.20", "survey-c0-0.16"])
def test_default_tolerances_meet_1e3_on_the_layer_maps(case):
    t = np.arange(0, 3601, 2.0)
    fine = granseg.simulate(**case, t=t, n_cells=1440, rtol=1e-9, atol=1e-11).layers()
    assert np.abs(granseg.simulate(**case, t=t).layers() - fine).max() < 1e-3


def test_initial_profile_and_layers():
    sol = granseg.simulate(c0=0.3, t=[0.0], n_cells=90)
    layers = sol.layers()[0]
    # heavy on top: the upper 30 % of the bed (4.5 layers) is heavy
    assert layers[-4:].min() > 0.99 and layers[:10].max() < 0.01
    assert sol.layers().shape == (1, 15)


@pytest.mark.parametrize(
    "kwargs, needle",
    [
        (dict(delta_over_H=0.0), "delta_over_H"),
        (dict(delta_over_H=-1.0), "delta_over_H"),
        (dict(k=0.0), "k"),
        (dict(c0=1.0), "c0"),
        (dict(c0=0.0), "c0"),
        (dict(rho_h=900.0), "rho_h"),
        (dict(k=float("nan")), "k"),
        (dict(n_cells=10), "n_cells"),
        (dict(t=[0.0, 5.0, 5.0]), "increasing"),
        (dict(t=[-1.0, 5.0]), "t"),
        (dict(rtol=0.0), "rtol"),
        (dict(atol=-1.0), "atol"),
        (dict(bogus=1.0), "bogus"),
        (dict(k="soft"), "k"),
    ],
)
def test_bad_input_names_the_parameter(kwargs, needle):
    args = dict(t=[0.0, 10.0])
    args.update(kwargs)
    with pytest.raises(ValueError, match=needle):
        granseg.simulate(**args)


def test_a_rust_panic_becomes_a_python_exception():
    from granseg import _core

    with pytest.raises(_core.SolverError, match="panic"):
        _core._panic_for_testing()


def test_the_cores_solver_error_reaches_users_as_granseg_solver_error():
    from granseg import _core, model

    with pytest.raises(granseg.SolverError, match="panic") as info:
        model._call(_core._panic_for_testing)
    assert not isinstance(info.value, _core.SolverError)
    assert info.value.__cause__ is None


def test_solver_error_is_a_granseg_runtime_error():
    assert issubclass(granseg.SolverError, RuntimeError)
    assert issubclass(granseg.SolverError, granseg.GransegError)


def test_sweep_matches_single_runs_and_orders_case_major():
    t = np.arange(0, 1201, 60.0)
    cases = [dict(rho_h=3500, rho_l=946, c0=0.5), dict(rho_h=2450, rho_l=1750, c0=0.5)]
    grid = {"k": [0.5, 0.7], "delta_over_H": [0.18, 0.22]}
    res = granseg.sweep(grid, cases=cases, t=t, n_cells=90)
    assert res.layers.shape == (8, t.size, 15)
    assert list(res.case_index) == [0, 0, 0, 0, 1, 1, 1, 1]
    assert res.grid_points[1] == {"k": 0.5, "delta_over_H": 0.22}
    one = granseg.simulate(**cases[1], k=0.7, delta_over_H=0.18, t=t, n_cells=90).layers()
    np.testing.assert_allclose(res.layers[6], one, atol=1e-14)


def test_sweep_takes_output_times_per_case():
    cases = [dict(c0=0.3), dict(c0=0.6)]
    times = [np.arange(0, 601, 60.0), np.array([5.0, 50.0, 500.0])]
    res = granseg.sweep({"k": [0.6]}, cases=cases, t=times, n_cells=60)
    assert [lay.shape for lay in res.layers] == [(11, 15), (3, 15)]
    one = granseg.simulate(**cases[1], k=0.6, t=times[1], n_cells=60).layers()
    np.testing.assert_allclose(res.layers[1], one, atol=1e-14)
    with pytest.raises(ValueError, match="2 cases"):
        granseg.sweep(None, cases=cases, t=[times[0]])
    with pytest.raises(ValueError, match=r"t\[1\]"):
        granseg.sweep(None, cases=cases, t=[times[0], [3.0, 1.0]])


def test_sweep_rmsd_against_measured_maps():
    t = np.arange(0, 1201, 30.0)
    truth = granseg.simulate(k=0.6, delta_over_H=0.2, t=t, n_cells=90).layers()
    measured = truth.copy()
    measured[::7, 3] = np.nan  # missing readings are skipped
    res = granseg.sweep({"k": [0.5, 0.6, 0.7]}, base=dict(delta_over_H=0.2),
                        measured=[dict(c=measured, t=t)], n_cells=90)
    assert np.argmin(res.rmsd) == 1 and res.rmsd[1] < 1e-12
    manual = np.sqrt(np.nanmean((measured - res.layers[0]) ** 2))
    assert abs(res.rmsd[0] - manual) < 1e-14


def test_sweep_smooths_the_model_like_the_map():
    t = np.arange(0, 601, 10.0)
    raw = granseg.simulate(t=t, n_cells=60).layers()
    res = granseg.sweep(None, base={}, measured=[dict(c=raw, t=t, smoothing_frames=5)], n_cells=60)
    smoothed = res.layers[0]
    i = 20
    np.testing.assert_allclose(smoothed[i], raw[i - 2 : i + 3].mean(axis=0), atol=1e-14)
    np.testing.assert_allclose(smoothed[0], raw[0])  # window shrinks at the ends
    np.testing.assert_allclose(smoothed[1], raw[0:3].mean(axis=0), atol=1e-14)


def test_sweep_rejects_bad_grids():
    with pytest.raises(ValueError, match="nope"):
        granseg.sweep({"nope": [1]}, base={}, t=[0, 1])
    with pytest.raises(ValueError, match="k"):
        granseg.sweep({"k": [0.5, -1.0]}, base={}, t=[0, 1])
    with pytest.raises(ValueError, match="measured"):
        granseg.sweep({"k": [0.5]}, cases=[{}, {}], measured=[dict(c=np.zeros((2, 15)), t=[0, 1])])


def test_threads_give_identical_results():
    t = np.arange(0, 601, 60.0)
    grid = {"k": [0.5, 0.6, 0.7], "delta_over_H": [0.18, 0.22]}
    one = granseg.sweep(grid, base={}, t=t, n_cells=60, threads=1)
    two = granseg.sweep(grid, base={}, t=t, n_cells=60, threads=2)
    np.testing.assert_array_equal(one.layers, two.layers)


def test_sweep_on_a_dask_cluster_matches_the_local_run():
    distributed = pytest.importorskip("distributed")
    t = np.arange(0, 601, 60.0)
    grid = {"k": [0.5, 0.7], "delta_over_H": [0.18, 0.2, 0.22]}
    local = granseg.sweep(grid, base={}, t=t, n_cells=60)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster, distributed.Client(cluster) as client:
        remote = granseg.sweep(grid, base={}, t=t, n_cells=60, client=client)
    np.testing.assert_array_equal(local.layers, remote.layers)


def test_steady_state_mass_and_shape():
    z, c = granseg.steady_state(rho_h=7800, rho_l=946, c0=0.25)
    assert z.shape == c.shape == (180,)
    assert abs(c.mean() - 0.25) < 1e-12
    assert np.all(np.diff(c) <= 0) and c[0] > 0.99


def test_velocity_profile_follows_model_md():
    v, g = granseg.model.velocity_profile(np.array([0.0, 0.09]))
    d = granseg.model.derived()
    assert abs(v[0] - d["v0"]) < 1e-12 and abs(d["v0"] - 0.2331900) < 1e-6
    assert abs(g[0] - d["v0"] / (0.18 * 0.09)) < 1e-9


def test_the_pure_python_constants_are_the_cores():
    from granseg import constants, model

    p = granseg.defaults()
    assert constants.D_P == p["D_p"]
    assert model.N_LAYERS == constants.N_LAYERS
    assert constants.N_LAYERS * constants.D_P == pytest.approx(p["H"], rel=1e-12)


def test_the_frame_pipeline_does_not_load_the_solver():
    import subprocess
    import sys

    code = ("import sys, granseg.measure, granseg.measure.pipeline, granseg.maps, granseg.synth.frames; "
            "assert 'granseg._core' not in sys.modules and 'granseg.model' not in sys.modules, "
            "sorted(m for m in sys.modules if m.startswith('granseg'))")
    subprocess.run([sys.executable, "-c", code], check=True)


law_tables = st.lists(floats(-2.0, 2.0), min_size=17, max_size=17)


@given(delta_r=floats(1.0, 8.0), c0=floats(0.1, 0.9), table=law_tables,
       law=st.sampled_from(["law_flux_c", "law_diff_z", "law_diff_t", "law_shear_z", "law_rate_t"]))
def test_law_corrections_keep_mass_and_bounds(delta_r, c0, table, law):
    knots = {f"{law}_{i}": v for i, v in enumerate(table)}
    sol = granseg.simulate(rho_h=delta_r * RHO_L, rho_l=RHO_L, c0=c0, t=[0.0, 30.0, 300.0, 1800.0],
                           n_cells=60, law_time=1800.0, field=True, **knots)
    mean = sol.c.mean(axis=1)
    assert np.max(np.abs(mean - mean[0]) / mean[0]) <= 1e-12
    assert sol.c.min() >= 0.0 and sol.c.max() <= 1.0


def test_law_corrections_are_the_baseline_at_zero_and_act_where_they_say():
    t = np.linspace(0.0, 1200.0, 41)
    base = granseg.simulate(t=t, n_cells=90).layers()
    zero = granseg.simulate(t=t, n_cells=90, **{k: 0.0 for k in granseg.model.LAW_KEYS}).layers()
    np.testing.assert_array_equal(base, zero)
    # more diffusion in the upper half only: the bottom layers do not feel it in the first minute
    upper = {f"law_diff_z_{i}": 1.5 for i in range(10, 17)}
    up = granseg.simulate(t=t, n_cells=90, **upper).layers()
    assert np.abs(up - base)[:3, :3].max() < 1e-3 < np.abs(up - base)[:, 9:].max()
    # a time table that is zero until 7/8 of law_time changes (next to) nothing before it
    late = granseg.simulate(t=t, n_cells=90, law_time=600.0, law_rate_t_16=1.0, law_rate_t_15=1.0).layers()
    assert np.abs(late - base)[t <= 0.8 * 600.0].max() < 1e-4 < np.abs(late - base).max()
    with pytest.raises(ValueError, match="law_flux_c_3"):
        granseg.simulate(t=t, law_flux_c_3=9.0)
    with pytest.raises(ValueError, match="law_time"):
        granseg.simulate(t=t, law_time=-1.0)
    with pytest.raises(ValueError, match="law"):
        granseg.steady_state(law_diff_z_2=0.5)


def test_the_layer_map_made_while_stepping_is_the_fields_layer_map():
    """Issue 15: simulate keeps only the layer map unless asked for the field; the two agree to
    rounding (the core reduces each step's interpolant once), and the solver takes the same steps."""
    t = np.arange(0.0, 1801.0, 30.0)
    lean = granseg.simulate(rho_h=7800, rho_l=946, c0=0.3, t=t, n_cells=90)
    full = granseg.simulate(rho_h=7800, rho_l=946, c0=0.3, t=t, n_cells=90, field=True)
    assert lean.c is None and full.c.shape == (t.size, 90)
    np.testing.assert_allclose(lean.layers(), full.layers(), rtol=0, atol=1e-14)
    np.testing.assert_allclose(lean.depth_mean, full.depth_mean, atol=1e-14)
    assert lean.stats == full.stats
    eleven = granseg.simulate(rho_h=7800, rho_l=946, c0=0.3, t=t, n_cells=90, n_layers=11)
    np.testing.assert_allclose(eleven.layers(11), full.layers(11), atol=1e-15)
    with pytest.raises(ValueError, match="field=True"):
        lean.layers(11)
    with pytest.raises(ValueError, match="field"):
        granseg.simulate(t=t, field="yes")
    lean.layers()[0, 0] = -1.0  # a copy: the run's own map is not changed through it
    assert lean.layers()[0, 0] >= 0.0
