//! Thin PyO3 layer: converts types, releases the GIL, maps errors. No
//! numerics here. Bad input becomes ValueError, a numerical failure
//! `_core.SolverError` (re-raised as granseg.SolverError by the package), and
//! any Rust panic is caught and turned into an exception rather than
//! aborting the interpreter.

use std::collections::HashMap;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::Arc;

use numpy::ndarray::Array2;
use numpy::{
    IntoPyArray, PyArray1, PyArray2, PyReadonlyArray1, PyReadonlyArray2, PyUntypedArrayMethods,
};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::error::SolveError;
use crate::params::{Params, FIELDS, MATERIALS};
use crate::stepper::{Stats, Tolerances};
use crate::sweep::{Measured, RunSpec};
use crate::{layers, model, steady, stepper};

pyo3::create_exception!(
    _core,
    SolverError,
    PyRuntimeError,
    "The numerical core could not complete a solve."
);

fn to_py_err(e: SolveError) -> PyErr {
    if e.is_input_error() {
        PyValueError::new_err(e.to_string())
    } else {
        SolverError::new_err(e.to_string())
    }
}

/// Run `f` without the GIL, turning a panic into a Python exception.
fn detached<T: Send>(
    py: Python<'_>,
    f: impl FnOnce() -> Result<T, SolveError> + Send,
) -> PyResult<T> {
    let out = py.detach(move || catch_unwind(AssertUnwindSafe(f)));
    match out {
        Ok(r) => r.map_err(to_py_err),
        Err(_) => Err(SolverError::new_err(
            "internal error in the numerical core (a Rust panic was caught)",
        )),
    }
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
    let t: Vec<f64> = t.as_array().to_vec();
    let p = params_from(&params).map_err(to_py_err)?;
    let n_t = t.len();
    let (c, stats) = detached(py, move || {
        stepper::simulate(&p, n_cells, &t, tolerances(rtol, atol))
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
    let c = detached(py, move || steady::steady_state(&p, n_cells, sub_steps))?;
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

type SweepOut<'py> = (
    Vec<Bound<'py, PyArray2<f64>>>,
    Bound<'py, PyArray1<f64>>,
    Vec<Bound<'py, PyDict>>,
);

/// Many runs in parallel (rayon, GIL released).
///
/// params: one dict per run; t: one array per run; measured: per run None or
/// an (n_t, n_layers) map at that run's times; smoothing: per run window;
/// n_layers: per run, the layers of the output without a map (a map sets its own).
/// Returns (layers per run, rmsd per run (NaN without a map), stats per run).
/// A failed run raises, naming the run index.
#[pyfunction]
#[pyo3(signature = (params, t, measured, smoothing, n_layers, n_cells, rtol, atol, threads=None))]
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
) -> PyResult<SweepOut<'py>> {
    let n = params.len();
    if t.len() != n || measured.len() != n || smoothing.len() != n || n_layers.len() != n {
        return Err(PyValueError::new_err(
            "params, t, measured, smoothing and n_layers must have one entry per run",
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
        specs.push(RunSpec {
            params: p,
            t_out: Arc::new(t[i].as_array().to_vec()),
            measured: m,
            n_layers: n_layers[i],
        });
    }
    let results = detached(py, move || {
        Ok(crate::sweep::sweep(
            &specs,
            n_cells,
            tolerances(rtol, atol),
            threads,
        ))
    })?;
    let mut layers_out = Vec::with_capacity(n);
    let mut rmsd = Vec::with_capacity(n);
    let mut stats = Vec::with_capacity(n);
    for (i, r) in results.into_iter().enumerate() {
        let r = r.map_err(|e| to_py_err(prefix(i, e)))?;
        let n_t = r.layers.len() / r.n_layers;
        let arr = Array2::from_shape_vec((n_t, r.n_layers), r.layers)
            .map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
        layers_out.push(arr.into_pyarray(py));
        rmsd.push(r.rmsd.unwrap_or(f64::NAN));
        stats.push(stats_dict(py, &r.stats)?);
    }
    Ok((layers_out, rmsd.into_pyarray(py), stats))
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
    detached(py, || -> Result<(), SolveError> {
        panic!("deliberate panic for the test suite")
    })
}

/// granseg's compiled core.
#[pymodule]
mod _core {
    #[pymodule_export]
    use super::{
        _panic_for_testing, default_tolerances, defaults, derived, law_keys, layer_means,
        materials, moving_average, simulate, steady_state, sweep, validate, velocity_profile,
        SolverError,
    };
}
