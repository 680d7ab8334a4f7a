//! Parallel runs (rayon): the factorial sweeps behind calibration and
//! diagnosis. Each run returns its layer map at its output times and, given
//! a measured map, the RMSD against it, so only small arrays leave the core.

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::Arc;

use rayon::prelude::*;

use crate::error::SolveError;
use crate::layers::{self, LayerMap};
use crate::params::Params;
use crate::stepper::{self, Stats, Tolerances};

/// A measured map to compare a run with: (n_t, n_layers) row-major, NaN =
/// no reading, at the run's output times, with the smoothing it records.
#[derive(Clone, Debug)]
pub struct Measured {
    pub c: Vec<f64>,
    pub n_layers: usize,
    pub smoothing_frames: usize,
}

/// The paper's window: 15 layers of one particle diameter.
pub const N_LAYERS: usize = 15;

/// One run of a sweep.
#[derive(Clone, Debug)]
pub struct RunSpec {
    pub params: Params,
    pub t_out: Arc<Vec<f64>>,
    pub measured: Option<Arc<Measured>>,
    /// Layers of the output map without a measured map (a map sets its own).
    pub n_layers: usize,
}

/// What a run gives back.
#[derive(Clone, Debug)]
pub struct RunResult {
    /// Layer map (n_t, n_layers) row-major; smoothed like the measured map
    /// when there is one, so that it is exactly what the RMSD compares.
    pub layers: Vec<f64>,
    pub n_layers: usize,
    pub rmsd: Option<f64>,
    pub stats: Stats,
}

/// Solve one run and reduce it to layers (and RMSD).
pub fn run_one(spec: &RunSpec, n_cells: usize, tol: Tolerances) -> Result<RunResult, SolveError> {
    let n_layers = spec.measured.as_ref().map_or(spec.n_layers, |m| m.n_layers);
    let n_t = spec.t_out.len();
    if n_layers == 0 {
        return Err(SolveError::InvalidInput("n_layers must be >= 1".into()));
    }
    if let Some(m) = &spec.measured {
        if m.n_layers == 0 || m.c.len() != n_t * m.n_layers {
            return Err(SolveError::InvalidInput(format!(
                "measured map has {} entries, expected {} times x {} layers",
                m.c.len(),
                n_t,
                m.n_layers
            )));
        }
        if m.smoothing_frames == 0 {
            return Err(SolveError::InvalidInput(
                "smoothing_frames must be >= 1".into(),
            ));
        }
    }
    let lm = LayerMap::new(n_cells, n_layers);
    let mut out = vec![0.0; n_t * n_layers];
    let stats = stepper::integrate(&spec.params, n_cells, &spec.t_out, tol, |k, prof| {
        lm.apply(prof, &mut out[k * n_layers..(k + 1) * n_layers]);
    })?;
    let (layers, rmsd) = match &spec.measured {
        Some(m) => {
            let smooth = layers::moving_average(&out, n_t, n_layers, m.smoothing_frames);
            let r = layers::rmsd(&m.c, &smooth)?;
            (smooth, Some(r))
        }
        None => (out, None),
    };
    Ok(RunResult {
        layers,
        n_layers,
        rmsd,
        stats,
    })
}

/// `run_one` with any panic turned into an error, so that one bad run can
/// never take the caller (or the Python interpreter) down.
pub fn run_guarded(
    spec: &RunSpec,
    n_cells: usize,
    tol: Tolerances,
) -> Result<RunResult, SolveError> {
    match catch_unwind(AssertUnwindSafe(|| run_one(spec, n_cells, tol))) {
        Ok(r) => r,
        Err(panic) => {
            let msg = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "unknown panic".into());
            Err(SolveError::NewtonFailure {
                t: f64::NAN,
                reason: format!("internal error: {msg}"),
            })
        }
    }
}

/// Run every spec in parallel. `threads` = None uses rayon's global pool
/// (RAYON_NUM_THREADS or all cores); Some(n) a private pool of n threads.
pub fn sweep(
    specs: &[RunSpec],
    n_cells: usize,
    tol: Tolerances,
    threads: Option<usize>,
) -> Vec<Result<RunResult, SolveError>> {
    let work = || {
        specs
            .par_iter()
            .map(|s| run_guarded(s, n_cells, tol))
            .collect()
    };
    match threads {
        Some(n) => match rayon::ThreadPoolBuilder::new()
            .num_threads(n.max(1))
            .build()
        {
            Ok(pool) => pool.install(work),
            Err(e) => specs
                .iter()
                .map(|_| {
                    Err(SolveError::InvalidInput(format!(
                        "cannot start {n} threads: {e}"
                    )))
                })
                .collect(),
        },
        None => work(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sweep_matches_single_runs_and_rmsd_is_zero_against_itself() {
        let t = Arc::new((0..=60).map(|i| i as f64 * 20.0).collect::<Vec<_>>());
        let specs: Vec<RunSpec> = [0.5, 0.7]
            .iter()
            .map(|&k| RunSpec {
                params: Params {
                    k,
                    ..Params::default()
                },
                t_out: t.clone(),
                measured: None,
                n_layers: N_LAYERS,
            })
            .collect();
        let res = sweep(&specs, 60, Tolerances::default(), Some(2));
        let single = run_one(&specs[1], 60, Tolerances::default()).unwrap();
        let r1 = res[1].as_ref().unwrap();
        assert_eq!(r1.layers, single.layers);
        let meas = Arc::new(Measured {
            c: single.layers.clone(),
            n_layers: 15,
            smoothing_frames: 1,
        });
        let spec = RunSpec {
            measured: Some(meas),
            ..specs[1].clone()
        };
        let r = run_one(&spec, 60, Tolerances::default()).unwrap();
        assert!(r.rmsd.unwrap() < 1e-15);
    }

    #[test]
    fn any_layer_count_averages_the_same_profile() {
        let t = Arc::new(vec![0.0, 600.0]);
        let spec = |n_layers| RunSpec {
            params: Params::default(),
            t_out: t.clone(),
            measured: None,
            n_layers,
        };
        let (a, b) = (
            run_one(&spec(11), 66, Tolerances::default()).unwrap(),
            run_one(&spec(1), 66, Tolerances::default()).unwrap(),
        );
        assert_eq!((a.n_layers, a.layers.len()), (11, 22));
        // one layer is the depth mean: the mean of eleven equal layers
        for k in 0..2 {
            let mean: f64 = a.layers[k * 11..(k + 1) * 11].iter().sum::<f64>() / 11.0;
            assert!((mean - b.layers[k]).abs() < 1e-12);
        }
        assert!(run_one(&spec(0), 66, Tolerances::default()).is_err());
    }

    #[test]
    fn a_bad_run_fails_alone() {
        let t = Arc::new(vec![0.0, 100.0]);
        let good = RunSpec {
            params: Params::default(),
            t_out: t.clone(),
            measured: None,
            n_layers: N_LAYERS,
        };
        let bad = RunSpec {
            params: Params {
                c0: 2.0,
                ..Params::default()
            },
            t_out: t,
            measured: None,
            n_layers: N_LAYERS,
        };
        let res = sweep(&[good, bad], 30, Tolerances::default(), None);
        assert!(res[0].is_ok());
        assert!(res[1].as_ref().unwrap_err().is_input_error());
    }
}
