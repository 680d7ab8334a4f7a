//! Thin PyO3 layer: converts types, releases the GIL, maps errors. No
//! numerics here. Bad input becomes ValueError, a numerical failure
//! `_core.SolverError` (re-raised as granseg.SolverError by the package), and
//! any Rust panic is caught and turned into an exception rather than
//! aborting the interpreter. Sizes are checked by the core before anything is
//! allocated (`limits.rs`), and an allocation that still fails is a
//! MemoryError, not an abort.
//!
//! Ctrl-C: a long call (simulate, steady_state, sweep) runs on a worker
//! thread with the GIL released, while the calling thread waits for it in
//! slices of `SIGNAL_POLL` and, between slices, briefly takes the GIL to run
//! Python's signal handlers (`Python::check_signals`). When a handler raises
//! (KeyboardInterrupt on Ctrl-C), the core's stop flag is set, the worker
//! returns `SolveError::Interrupted` at its next poll (every step attempt,
//! every 256 cells of a steady-state pass, every run of a sweep), and the
//! handler's exception is raised. Signal handlers only run on Python's main
//! thread, so a call from another thread is not interrupted (as in numpy).

use std::collections::HashMap;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::sync::Arc;
use std::time::Duration;

use numpy::ndarray::{Array2, Array3};
use numpy::{
    IntoPyArray, PyArray1, PyArray2, PyArray3, PyReadonlyArray1, PyReadonlyArray2,
    PyUntypedArrayMethods,
};
use pyo3::exceptions::{PyKeyboardInterrupt, PyMemoryError, PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::error::SolveError;
use crate::params::{Params, FIELDS, MATERIALS};
use crate::sensitivity::Tangent;
use crate::stepper::{Stats, Tolerances};
use crate::sweep::{Measured, RunSpec};
use crate::{layers, limits, model, steady, stepper};

pyo3::create_exception!(
    _core,
    SolverError,
    PyRuntimeError,
    "The numerical core could not complete a solve."
);

fn to_py_err(e: SolveError) -> PyErr {
    match e {
        SolveError::Interrupted => PyKeyboardInterrupt::new_err("interrupted"),
        SolveError::OutOfMemory(_) => PyMemoryError::new_err(e.to_string()),
        _ if e.is_input_error() => PyValueError::new_err(e.to_string()),
        _ => SolverError::new_err(e.to_string()),
    }
}

/// How often a waiting call takes the GIL to run Python's signal handlers.
const SIGNAL_POLL: Duration = Duration::from_millis(100);

fn panic_error() -> PyErr {
    SolverError::new_err("internal error in the numerical core (a Rust panic was caught)")
}

/// Run `f(stop)` on a worker thread without the GIL, turning a panic into a
/// Python exception; Ctrl-C (any exception a signal handler raises) sets
/// `stop` and is raised once the worker has returned (module docs).
fn detached<T: Send>(
    py: Python<'_>,
    f: impl FnOnce(&AtomicBool) -> Result<T, SolveError> + Send,
) -> PyResult<T> {
    let stop = AtomicBool::new(false);
    std::thread::scope(|scope| {
        let (tx, mut rx) = mpsc::channel::<()>();
        let stop_ref = &stop;
        let worker = scope.spawn(move || {
            let out = catch_unwind(AssertUnwindSafe(|| f(stop_ref)));
            let _ = tx.send(()); // the receiver may be gone: nothing to tell
            out
        });
        let mut pending: Option<PyErr> = None;
        loop {
            let (back, waited) = py.detach(move || {
                let r = rx.recv_timeout(SIGNAL_POLL);
                (rx, r)
            });
            rx = back;
            if !matches!(waited, Err(mpsc::RecvTimeoutError::Timeout)) {
                break; // finished (or the worker is gone)
            }
            if pending.is_none() {
                if let Err(e) = py.check_signals() {
                    stop.store(true, Ordering::Relaxed);
                    pending = Some(e);
                }
            }
        }
        let out = py.detach(move || worker.join());
        if let Some(e) = pending {
            return Err(e);
        }
        match out {
            Ok(Ok(r)) => r.map_err(to_py_err),
            Ok(Err(_)) | Err(_) => Err(panic_error()),
        }
    })
}

fn params_from(map: &HashMap<String, f64>) -> Result<Params, SolveError> {
    Params::from_pairs(map.iter().map(|(k, v)| (k.as_str(), *v)))
}

fn tolerances(rtol: f64, atol: f64) -> Tolerances {
    Tolerances { rtol, atol }
}

fn stats_dict<'py>(py: Python<'py>, s: &Stats) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("steps", s.steps)?;
    d.set_item("rejected", s.rejected)?;
    d.set_item("newton_iters", s.newton_iters)?;
    d.set_item("newton_failures", s.newton_failures)?;
    d.set_item("rhs_evals", s.rhs_evals)?;
    d.set_item("jacobians", s.jacobians)?;
    d.set_item("clipped", s.clipped)?;
    d.set_item("max_clip", s.max_clip)?;
    Ok(d)
}

/// Default value of every model parameter (docs/model.md), SI units.
#[pyfunction]
fn defaults() -> HashMap<String, f64> {
    let p = Params::default();
    FIELDS
        .iter()
        .map(|f| (f.0.to_string(), (f.1)(&p)))
        .collect()
}

/// Parameter names of every law-correction knot (`laws.rs`), default 0.
#[pyfunction]
fn law_keys() -> Vec<String> {
    crate::laws::Laws::keys()
}

/// Material densities of docs/model.md, kg/m^3.
#[pyfunction]
fn materials() -> HashMap<String, f64> {
    MATERIALS.iter().map(|(n, r)| (n.to_string(), *r)).collect()
}

/// Default solver tolerances (rtol, atol).
#[pyfunction]
fn default_tolerances() -> (f64, f64) {
    let t = Tolerances::default();
    (t.rtol, t.atol)
}

/// Validate a parameter dict; raises ValueError naming the offender.
#[pyfunction]
fn validate(params: HashMap<String, f64>) -> PyResult<()> {
    params_from(&params).map(|_| ()).map_err(to_py_err)
}

/// Derived quantities of a parameter set: v0 [m/s], P_load [Pa], A [m^2].
#[pyfunction]
fn derived(params: HashMap<String, f64>) -> PyResult<HashMap<String, f64>> {
    let p = params_from(&params).map_err(to_py_err)?;
    Ok(HashMap::from([
        ("v0".to_string(), p.v0()),
        ("P_load".to_string(), p.p_load()),
        ("A".to_string(), p.area()),
        ("omega".to_string(), p.omega()),
    ]))
}

/// Velocity [m/s] (the exponential band) and shear rate [1/s] (with the shear-profile law's
/// factor, as the fluxes use it) at heights z [m], at time t [s].
#[pyfunction]
fn velocity_profile<'py>(
    py: Python<'py>,
    params: HashMap<String, f64>,
    z: PyReadonlyArray1<'py, f64>,
    t: f64,
) -> PyResult<(Bound<'py, PyArray1<f64>>, Bound<'py, PyArray1<f64>>)> {
    let p = params_from(&params).map_err(to_py_err)?;
    let delta = p.delta_at(t);
    let z = z.as_array();
    let slack = 1e-9 * p.h;
    if let Some((i, zz)) = z
        .iter()
        .enumerate()
        .find(|(_, &zz)| !(zz >= -slack && zz <= p.h + slack))
    {
        return Err(PyValueError::new_err(format!(
            "z must lie in [0, H] = [0, {}] m (the bed): z[{i}] = {zz}",
            p.h
        )));
    }
    let v: Vec<f64> = z.iter().map(|&zz| model::velocity(&p, delta, zz)).collect();
    // the shear rate the fluxes use: the exponential's times the shear-profile law's factor
    let g: Vec<f64> = z
        .iter()
        .map(|&zz| model::shear_rate(&p, delta, zz) * p.laws.shear_z.factor(zz / p.h))
        .collect();
    Ok((v.into_pyarray(py), g.into_pyarray(py)))
}

/// One run: returns (z [m], c (n_t, n_cells), stats).
#[pyfunction]
#[pyo3(signature = (params, t, n_cells, rtol, atol))]
fn simulate<'py>(
    py: Python<'py>,
    params: HashMap<String, f64>,
    t: PyReadonlyArray1<'py, f64>,
    n_cells: usize,
    rtol: f64,
    atol: f64,
) -> PyResult<(
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyDict>,
)> {
    let p = params_from(&params).map_err(to_py_err)?;
    let n_t = t.len();
    // sizes before anything is allocated, the copy of t included
    limits::check_buffer("the output c", &[("len(t)", n_t), ("n_cells", n_cells)])
        .map_err(to_py_err)?;
    limits::check_output_times("t", n_t).map_err(to_py_err)?;
    let t: Vec<f64> = t.as_array().to_vec();
    let (c, stats) = detached(py, move |stop| {
        stepper::simulate_stoppable(&p, n_cells, &t, tolerances(rtol, atol), stop)
    })?;
    let z = model::Grid::new(n_cells, p.h).centres();
    let c = Array2::from_shape_vec((n_t, n_cells), c)
        .map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
    Ok((
        z.into_pyarray(py),
        c.into_pyarray(py),
        stats_dict(py, &stats)?,
    ))
}

/// One run reduced to its layer map as it is stepped, without the full field
/// (issue 15): returns (layers (n_t, n_layers), stats). What every comparison
/// with a camera's map needs, at a fraction of the output's size.
#[pyfunction]
#[pyo3(signature = (params, t, n_cells, rtol, atol, n_layers=15))]
fn simulate_layers<'py>(
    py: Python<'py>,
    params: HashMap<String, f64>,
    t: PyReadonlyArray1<'py, f64>,
    n_cells: usize,
    rtol: f64,
    atol: f64,
    n_layers: usize,
) -> PyResult<(Bound<'py, PyArray2<f64>>, Bound<'py, PyDict>)> {
    let p = params_from(&params).map_err(to_py_err)?;
    let n_t = t.len();
    limits::check_output_times("t", n_t).map_err(to_py_err)?;
    let spec = RunSpec {
        params: p,
        t_out: Arc::new(t.as_array().to_vec()),
        measured: None,
        n_layers,
        tangents: Default::default(),
    };
    let tol = tolerances(rtol, atol);
    let r = detached(py, move |stop| {
        crate::sweep::run_guarded_stoppable(&spec, n_cells, tol, stop)
    })?;
    let layers = Array2::from_shape_vec((n_t, r.n_layers), r.layers)
        .map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
    Ok((layers.into_pyarray(py), stats_dict(py, &r.stats)?))
}

/// The steady profile (cell averages) on n_cells cells: (z [m], c).
#[pyfunction]
#[pyo3(signature = (params, n_cells, sub_steps=16))]
fn steady_state<'py>(
    py: Python<'py>,
    params: HashMap<String, f64>,
    n_cells: usize,
    sub_steps: usize,
) -> PyResult<(Bound<'py, PyArray1<f64>>, Bound<'py, PyArray1<f64>>)> {
    let p = params_from(&params).map_err(to_py_err)?;
    let c = detached(py, move |stop| {
        steady::steady_state_stoppable(&p, n_cells, sub_steps, stop)
    })?;
    let z = model::Grid::new(n_cells, p.h).centres();
    Ok((z.into_pyarray(py), c.into_pyarray(py)))
}

/// Layer means (n_t, n_layers) of profiles c (n_t, n_cells) over the bed.
#[pyfunction]
#[pyo3(signature = (c, n_layers=15))]
fn layer_means<'py>(
    py: Python<'py>,
    c: PyReadonlyArray2<'py, f64>,
    n_layers: usize,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let shape = c.shape();
    let (n_t, n_cells) = (shape[0], shape[1]);
    if n_layers == 0 || n_cells == 0 {
        return Err(PyValueError::new_err(
            "n_layers and the number of cells must be >= 1",
        ));
    }
    if n_layers > limits::MAX_CELLS {
        return Err(PyValueError::new_err(format!(
            "n_layers = {n_layers} is out of range: must be <= {}",
            limits::MAX_CELLS
        )));
    }
    limits::check_buffer("the layer means", &[("n_t", n_t), ("n_layers", n_layers)])
        .map_err(to_py_err)?;
    let lm = layers::LayerMap::new(n_cells, n_layers);
    let view = c.as_array();
    let mut out = Array2::<f64>::zeros((n_t, n_layers));
    let mut row = vec![0.0; n_cells];
    let mut buf = vec![0.0; n_layers];
    for (k, prof) in view.outer_iter().enumerate() {
        row.iter_mut().zip(prof.iter()).for_each(|(a, b)| *a = *b);
        lm.apply(&row, &mut buf);
        out.row_mut(k)
            .iter_mut()
            .zip(&buf)
            .for_each(|(a, b)| *a = *b);
    }
    Ok(out.into_pyarray(py))
}

/// Centred moving average over time (axis 0), window shrinking at the ends.
#[pyfunction]
fn moving_average<'py>(
    py: Python<'py>,
    x: PyReadonlyArray2<'py, f64>,
    width: usize,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    if width == 0 || width % 2 == 0 {
        return Err(PyValueError::new_err(format!(
            "width = {width} must be an odd number >= 1 (a centred window)"
        )));
    }
    let shape = x.shape();
    let data: Vec<f64> = x.as_array().iter().copied().collect();
    let out = layers::moving_average(&data, shape[0], shape[1], width);
    let out = Array2::from_shape_vec((shape[0], shape[1]), out)
        .map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
    Ok(out.into_pyarray(py))
}

/// A view's dwell: per column y[0] = x[0], y[t] = (1 - s) x[t] + s y[t-1] (layers.rs).
#[pyfunction]
fn lagged<'py>(
    py: Python<'py>,
    x: PyReadonlyArray2<'py, f64>,
    survival: PyReadonlyArray1<'py, f64>,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let shape = x.shape();
    let s: Vec<f64> = survival.as_array().to_vec();
    if s.len() != shape[1] {
        return Err(PyValueError::new_err(format!(
            "survival has {} entries for {} columns",
            s.len(),
            shape[1]
        )));
    }
    if let Some(v) = s.iter().find(|v| !(0.0..=1.0).contains(*v)) {
        return Err(PyValueError::new_err(format!(
            "survival = {v} is not a share of a frame in [0, 1]"
        )));
    }
    let data: Vec<f64> = x.as_array().iter().copied().collect();
    let out = layers::lagged(&data, shape[0], shape[1], &s);
    let out = Array2::from_shape_vec((shape[0], shape[1]), out)
        .map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
    Ok(out.into_pyarray(py))
}

type SweepOut<'py> = (
    Vec<Bound<'py, PyArray2<f64>>>,
    Bound<'py, PyArray1<f64>>,
    Vec<Bound<'py, PyDict>>,
    Vec<Bound<'py, PyArray3<f64>>>,
);

/// Many runs in parallel (rayon, GIL released).
///
/// params: one dict per run; t: one array per run; measured: per run None or
/// an (n_t, n_layers) map at that run's times; smoothing: per run window;
/// n_layers: per run, the layers of the output without a map (a map sets its own).
/// tangents: per run None or a list of {parameter: change} directions to
/// differentiate the layer map along (`sensitivity.rs`).
/// Returns (layers per run, rmsd per run (NaN without a map), stats per run,
/// sensitivities per run (n_tangents, n_t, n_layers)).
/// A failed run raises, naming the run index.
#[pyfunction]
#[pyo3(signature = (params, t, measured, smoothing, n_layers, n_cells, rtol, atol, threads=None, tangents=None))]
#[allow(clippy::too_many_arguments)]
fn sweep<'py>(
    py: Python<'py>,
    params: Vec<HashMap<String, f64>>,
    t: Vec<PyReadonlyArray1<'py, f64>>,
    measured: Vec<Option<PyReadonlyArray2<'py, f64>>>,
    smoothing: Vec<usize>,
    n_layers: Vec<usize>,
    n_cells: usize,
    rtol: f64,
    atol: f64,
    threads: Option<usize>,
    tangents: Option<Vec<Option<Vec<HashMap<String, f64>>>>>,
) -> PyResult<SweepOut<'py>> {
    let n = params.len();
    let tangents = tangents.unwrap_or_else(|| vec![None; n]);
    if t.len() != n
        || measured.len() != n
        || smoothing.len() != n
        || n_layers.len() != n
        || tangents.len() != n
    {
        return Err(PyValueError::new_err(
            "params, t, measured, smoothing, n_layers and tangents must have one entry per run",
        ));
    }
    let mut specs = Vec::with_capacity(n);
    for i in 0..n {
        let p = params_from(&params[i]).map_err(|e| to_py_err(prefix(i, e)))?;
        let m = measured[i].as_ref().map(|m| {
            Arc::new(Measured {
                c: m.as_array().iter().copied().collect(),
                n_layers: m.shape()[1],
                smoothing_frames: smoothing[i],
            })
        });
        let dirs = tangents[i]
            .iter()
            .flatten()
            .map(|d| Tangent::from_pairs(d.iter().map(|(k, v)| (k.as_str(), *v))))
            .collect::<Result<Vec<_>, _>>()
            .map_err(|e| to_py_err(prefix(i, e)))?;
        specs.push(RunSpec {
            params: p,
            t_out: Arc::new(t[i].as_array().to_vec()),
            measured: m,
            n_layers: n_layers[i],
            tangents: Arc::new(dirs),
        });
    }
    let results = detached(py, move |stop| {
        crate::sweep::sweep_stoppable(&specs, n_cells, tolerances(rtol, atol), threads, stop)
    })?;
    let mut layers_out = Vec::with_capacity(n);
    let mut rmsd = Vec::with_capacity(n);
    let mut stats = Vec::with_capacity(n);
    let mut sens = Vec::with_capacity(n);
    for (i, r) in results.into_iter().enumerate() {
        let r = r.map_err(|e| to_py_err(prefix(i, e)))?;
        let n_t = r.layers.len() / r.n_layers;
        let n_dir = r.sensitivities.len() / (n_t * r.n_layers).max(1);
        let s = Array3::from_shape_vec((n_dir, n_t, r.n_layers), r.sensitivities)
            .map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
        sens.push(s.into_pyarray(py));
        let arr = Array2::from_shape_vec((n_t, r.n_layers), r.layers)
            .map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
        layers_out.push(arr.into_pyarray(py));
        rmsd.push(r.rmsd.unwrap_or(f64::NAN));
        stats.push(stats_dict(py, &r.stats)?);
    }
    Ok((layers_out, rmsd.into_pyarray(py), stats, sens))
}

fn prefix(i: usize, e: SolveError) -> SolveError {
    match e {
        SolveError::InvalidInput(m) => SolveError::InvalidInput(format!("run {i}: {m}")),
        SolveError::NewtonFailure { t, reason } => SolveError::NewtonFailure {
            t,
            reason: format!("run {i}: {reason}"),
        },
        SolveError::SteadyFailure(m) => SolveError::SteadyFailure(format!("run {i}: {m}")),
        other => other,
    }
}

/// Test hook: panics inside the core, to check that a Rust panic reaches
/// Python as an exception instead of aborting the interpreter.
#[pyfunction]
fn _panic_for_testing(py: Python<'_>) -> PyResult<()> {
    detached(py, |_| -> Result<(), SolveError> {
        panic!("deliberate panic for the test suite")
    })
}

/// The ceilings of one call (`limits.rs`): max_bytes (of the outputs),
/// max_cells, max_output_times, max_sub_steps, max_threads.
#[pyfunction]
#[pyo3(name = "limits")]
fn call_limits() -> HashMap<String, usize> {
    HashMap::from([
        ("max_bytes".to_string(), limits::MAX_BYTES),
        ("max_cells".to_string(), limits::MAX_CELLS),
        ("max_output_times".to_string(), limits::MAX_OUTPUT_TIMES),
        ("max_sub_steps".to_string(), limits::MAX_SUB_STEPS),
        ("max_threads".to_string(), limits::MAX_THREADS),
    ])
}

/// The scalar parameters a sweep's tangents may move (besides the law knots).
#[pyfunction]
fn differentiable() -> Vec<&'static str> {
    crate::sensitivity::SCALARS.to_vec()
}

/// granseg's compiled core.
#[pymodule]
mod _core {
    #[pymodule_export]
    use super::{
        _panic_for_testing, call_limits, default_tolerances, defaults, derived, differentiable,
        lagged, law_keys, layer_means, materials, moving_average, simulate, simulate_layers,
        steady_state, sweep, validate, velocity_profile, SolverError,
    };
}
