//! Parallel runs (rayon): the factorial sweeps behind calibration and
//! diagnosis. Each run returns its layer map at its output times and, given
//! a measured map, the RMSD against it, so only small arrays leave the core.

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use rayon::prelude::*;

use crate::error::SolveError;
use crate::layers;
use crate::limits;
use crate::params::Params;
use crate::sensitivity::{self, Tangent};
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
    /// Directions to differentiate the layer map along (`sensitivity.rs`); none: no sensitivities.
    pub tangents: Arc<Vec<Tangent>>,
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
    /// Layer maps of the sensitivities (n_tangents, n_t, n_layers), smoothed like `layers`.
    pub sensitivities: Vec<f64>,
}

/// Solve one run and reduce it to layers (and RMSD).
pub fn run_one(spec: &RunSpec, n_cells: usize, tol: Tolerances) -> Result<RunResult, SolveError> {
    run_one_stoppable(spec, n_cells, tol, limits::never())
}

/// The layer values a run's output takes: n_t x n_layers (`None` on overflow).
fn output_len(spec: &RunSpec) -> Option<usize> {
    let n_layers = spec.measured.as_ref().map_or(spec.n_layers, |m| m.n_layers);
    spec.t_out.len().checked_mul(n_layers)
}

/// `run_one`, polling `stop` before every step attempt.
pub fn run_one_stoppable(
    spec: &RunSpec,
    n_cells: usize,
    tol: Tolerances,
    stop: &AtomicBool,
) -> Result<RunResult, SolveError> {
    let n_layers = spec.measured.as_ref().map_or(spec.n_layers, |m| m.n_layers);
    let n_t = spec.t_out.len();
    if n_layers == 0 {
        return Err(SolveError::InvalidInput("n_layers must be >= 1".into()));
    }
    if n_layers > limits::MAX_CELLS {
        return Err(SolveError::InvalidInput(format!(
            "n_layers = {n_layers} is out of range: must be <= {}",
            limits::MAX_CELLS
        )));
    }
    // sizes before any allocation
    limits::check_cells(n_cells)?;
    limits::check_output_times("t", n_t)?;
    limits::check_buffer("the layer map", &[("len(t)", n_t), ("n_layers", n_layers)])?;
    if let Some(m) = &spec.measured {
        if m.n_layers == 0 || Some(m.c.len()) != n_t.checked_mul(m.n_layers) {
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
    spec.params.validate()?;
    stepper::validate_run(n_cells, &spec.t_out, &tol)?;
    let (out, sens, stats) = sensitivity::layer_map_with_sensitivities(
        &spec.params,
        n_cells,
        &spec.t_out,
        tol,
        n_layers,
        spec.tangents.to_vec(),
        stop,
    )?;
    let (layers, rmsd, sensitivities) = match &spec.measured {
        Some(m) => {
            let smooth = layers::moving_average(&out, n_t, n_layers, m.smoothing_frames);
            let r = layers::rmsd(&m.c, &smooth)?;
            let block = n_t * n_layers;
            let sens = sens
                .chunks(block.max(1))
                .flat_map(|s| layers::moving_average(s, n_t, n_layers, m.smoothing_frames))
                .collect();
            (smooth, Some(r), sens)
        }
        None => (out, None, sens),
    };
    Ok(RunResult {
        layers,
        n_layers,
        rmsd,
        stats,
        sensitivities,
    })
}

/// `run_one` with any panic turned into an error, so that one bad run can
/// never take the caller (or the Python interpreter) down.
pub fn run_guarded(
    spec: &RunSpec,
    n_cells: usize,
    tol: Tolerances,
) -> Result<RunResult, SolveError> {
    run_guarded_stoppable(spec, n_cells, tol, limits::never())
}

/// `run_guarded`, polling `stop`.
pub fn run_guarded_stoppable(
    spec: &RunSpec,
    n_cells: usize,
    tol: Tolerances,
    stop: &AtomicBool,
) -> Result<RunResult, SolveError> {
    match catch_unwind(AssertUnwindSafe(|| {
        run_one_stoppable(spec, n_cells, tol, stop)
    })) {
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
/// An error of the whole call (`sweep_stoppable`'s) is returned for every run.
pub fn sweep(
    specs: &[RunSpec],
    n_cells: usize,
    tol: Tolerances,
    threads: Option<usize>,
) -> Vec<Result<RunResult, SolveError>> {
    match sweep_stoppable(specs, n_cells, tol, threads, limits::never()) {
        Ok(r) => r,
        Err(e) => specs.iter().map(|_| Err(e.clone())).collect(),
    }
}

/// Check what a whole sweep asks for before any run starts: `threads` in
/// 1..=`limits::MAX_THREADS`, `n_cells` at most `limits::MAX_CELLS`, and the
/// layer maps of all runs together (twice for the runs with a measured map,
/// smoothed and raw) within `limits::MAX_BYTES`.
pub fn check_sweep(
    specs: &[RunSpec],
    n_cells: usize,
    threads: Option<usize>,
) -> Result<(), SolveError> {
    if let Some(n) = threads {
        limits::check_threads(n)?;
    }
    limits::check_cells(n_cells)?;
    let total = specs.iter().try_fold(0usize, |acc, s| {
        // the maps of the run and of its sensitivities, and the sensitivities' running
        // state (S and 4 stages' K per direction and cell: `sensitivity.rs`)
        let work = s.tangents.len().checked_mul(5)?.checked_mul(n_cells)?;
        let len = output_len(s)?
            .checked_mul(1 + s.tangents.len())?
            .checked_add(work)?;
        let len = if s.measured.is_some() {
            len.checked_mul(2)?
        } else {
            len
        };
        acc.checked_add(len)
    });
    let bytes = total.and_then(limits::f64_bytes);
    match bytes {
        Some(b) if b <= limits::MAX_BYTES => Ok(()),
        _ => Err(SolveError::InvalidInput(format!(
            "the layer maps of the sweep's {} runs (n_t x n_layers values per run, x 8 bytes)              would need {}, more than the {} bytes (4 GiB) one call may allocate:              fewer runs, output times (t) or n_layers",
            specs.len(),
            bytes.map_or_else(|| "more than usize::MAX bytes".into(), |b| format!("{b} bytes")),
            limits::MAX_BYTES
        ))),
    }
}

/// `sweep`, refusing a call that is too large as a whole (`check_sweep`)
/// before any thread is started, and returning `SolveError::Interrupted`
/// soon after `stop` is set (polled before every run and inside each run).
pub fn sweep_stoppable(
    specs: &[RunSpec],
    n_cells: usize,
    tol: Tolerances,
    threads: Option<usize>,
    stop: &AtomicBool,
) -> Result<Vec<Result<RunResult, SolveError>>, SolveError> {
    check_sweep(specs, n_cells, threads)?;
    let work = || -> Vec<Result<RunResult, SolveError>> {
        specs
            .par_iter()
            .map(|s| {
                limits::check_stop(stop)?;
                run_guarded_stoppable(s, n_cells, tol, stop)
            })
            .collect()
    };
    let out = match threads {
        Some(n) => match rayon::ThreadPoolBuilder::new().num_threads(n).build() {
            Ok(pool) => pool.install(work),
            Err(e) => {
                return Err(SolveError::InvalidInput(format!(
                    "threads = {n}: cannot start them: {e}"
                )))
            }
        },
        None => work(),
    };
    limits::check_stop(stop)?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layers_made_while_stepping_equal_the_fields_layers() {
        // the per-step reduction of the interpolant (issue 15) against the field reduced
        // output by output, in a gentle case and in one that clips (sharp fronts)
        for (rho_h, n_cells) in [(2450.0, 180), (12.0 * 946.0, 30)] {
            let params = Params {
                rho_h,
                ..Params::default()
            };
            let t: Vec<f64> = (0..=900).map(|i| i as f64 * 4.0).collect();
            let tol = Tolerances {
                rtol: 3e-4,
                atol: 3e-5,
            };
            let spec = RunSpec {
                params,
                t_out: Arc::new(t.clone()),
                measured: None,
                n_layers: N_LAYERS,
                tangents: Default::default(),
            };
            let lean = run_one(&spec, n_cells, tol).unwrap();
            let (field, stats) = stepper::simulate(&params, n_cells, &t, tol).unwrap();
            assert_eq!(lean.stats.steps, stats.steps);
            let map = layers::LayerMap::new(n_cells, N_LAYERS);
            let mut row = vec![0.0; N_LAYERS];
            for (k, prof) in field.chunks_exact(n_cells).enumerate() {
                map.apply(prof, &mut row);
                for (l, v) in row.iter().enumerate() {
                    let got = lean.layers[k * N_LAYERS + l];
                    assert!((got - v).abs() < 1e-14, "t[{k}] layer {l}: {got} vs {v}");
                    assert!((0.0..=1.0).contains(&got));
                }
            }
        }
    }

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
                tangents: Default::default(),
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
            tangents: Default::default(),
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

    fn spec(t: Vec<f64>, n_layers: usize) -> RunSpec {
        RunSpec {
            params: Params::default(),
            t_out: Arc::new(t),
            measured: None,
            n_layers,
            tangents: Default::default(),
        }
    }

    #[test]
    fn threads_and_sizes_are_refused_before_any_thread_starts() {
        let specs = vec![spec(vec![0.0, 10.0], 15); 2];
        let tol = Tolerances::default();
        for bad in [0, 10_000] {
            let e = sweep_stoppable(&specs, 30, tol, Some(bad), limits::never()).unwrap_err();
            assert!(e.to_string().contains(&format!("threads = {bad}")), "{e}");
            // the old entry point reports it for every run
            let res = sweep(&specs, 30, tol, Some(bad));
            assert!(res.iter().all(|r| r.as_ref().unwrap_err().is_input_error()));
        }
        // 5000 runs x 1000 times x 120000 layers: far beyond 4 GiB
        let big = spec((0..1000).map(|i| i as f64).collect(), 120_000);
        let e = check_sweep(&vec![big.clone(); 5000], 30, None).unwrap_err();
        assert!(
            e.to_string().contains("5000 runs") && e.to_string().contains("bytes"),
            "{e}"
        );
        let e = run_one(&big, 30, tol).unwrap_err();
        assert!(e.to_string().contains("n_layers = 120000"), "{e}");
        let e = check_sweep(&specs, 1 << 30, None).unwrap_err();
        assert!(e.to_string().contains("n_cells"), "{e}");
    }

    #[test]
    fn a_set_stop_flag_interrupts_the_sweep() {
        let specs = vec![spec(vec![0.0, 3600.0], 15); 4];
        let stop = AtomicBool::new(true);
        let e = sweep_stoppable(&specs, 30, Tolerances::default(), Some(2), &stop).unwrap_err();
        assert_eq!(e, SolveError::Interrupted);
    }

    #[test]
    fn a_bad_run_fails_alone() {
        let t = Arc::new(vec![0.0, 100.0]);
        let good = RunSpec {
            params: Params::default(),
            t_out: t.clone(),
            measured: None,
            n_layers: N_LAYERS,
            tangents: Default::default(),
        };
        let bad = RunSpec {
            params: Params {
                c0: 2.0,
                ..Params::default()
            },
            t_out: t,
            measured: None,
            n_layers: N_LAYERS,
            tangents: Default::default(),
        };
        let res = sweep(&[good, bad], 30, Tolerances::default(), None);
        assert!(res[0].is_ok());
        assert!(res[1].as_ref().unwrap_err().is_input_error());
    }
}
