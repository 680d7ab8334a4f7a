//! Criterion benchmarks of the numerical core (no Python):
//!   cargo bench --bench solver
//! (add `--features pressure-coupled` for the faer pressure-coupled run)
//! Figures are recorded in BENCHMARKS.md.

use std::hint::black_box;
use std::sync::Arc;

use _core::flux::Operator;
use _core::model::initial_condition;
#[cfg(feature = "pressure-coupled")]
use _core::pressure_coupled;
use _core::sweep::{sweep, RunSpec};
use _core::{simulate, Params, Tolerances};
use criterion::{criterion_group, criterion_main, Criterion};

fn gpp() -> Params {
    Params {
        rho_h: 2450.0,
        rho_l: 946.0,
        c0: 0.5,
        k: 0.7,
        delta_over_h: 0.18,
        ..Params::default()
    }
}

fn output_times() -> Vec<f64> {
    (0..=1800).map(|i| i as f64 * 2.0).collect()
}

/// The paper's 3 x 3 factorial for its three cases (C-PP, G-PP, G-POM at 50 %).
fn paper_sweep() -> Vec<RunSpec> {
    let t = Arc::new(output_times());
    let cases = [(3500.0, 946.0), (2450.0, 946.0), (2450.0, 1750.0)];
    let mut specs = Vec::new();
    for &(rho_h, rho_l) in &cases {
        for &k in &[0.5, 0.6, 0.7] {
            for &d in &[0.18, 0.20, 0.22] {
                let params = Params {
                    rho_h,
                    rho_l,
                    c0: 0.5,
                    k,
                    delta_over_h: d,
                    ..Params::default()
                };
                specs.push(RunSpec {
                    params,
                    t_out: t.clone(),
                    measured: None,
                    n_layers: _core::sweep::N_LAYERS,
                    tangents: Default::default(),
                });
            }
        }
    }
    specs
}

fn bench_rhs(c: &mut Criterion) {
    let p = gpp();
    let mut op = Operator::new(p, 180);
    let y = initial_condition(&p, &op.grid);
    let mut out = vec![0.0; 180];
    c.bench_function("rhs_180_cells", |b| {
        b.iter(|| op.rhs(0.0, black_box(&y), &mut out))
    });
}

fn bench_single_run(c: &mut Criterion) {
    let p = gpp();
    let t = output_times();
    let tol = Tolerances::default();
    c.bench_function("gpp_3600s_every_2s_180_cells", |b| {
        b.iter(|| simulate(black_box(&p), 180, &t, tol).unwrap())
    });
    let t_end = [0.0, 3600.0];
    c.bench_function("gpp_3600s_no_outputs_180_cells", |b| {
        b.iter(|| simulate(black_box(&p), 180, &t_end, tol).unwrap())
    });
    #[cfg(feature = "pressure-coupled")]
    c.bench_function("gpp_3600s_pressure_coupled_faer_180_cells", |b| {
        b.iter(|| pressure_coupled::simulate(black_box(&p), 180, &t_end, tol).unwrap())
    });
}

fn bench_sweep(c: &mut Criterion) {
    let specs = paper_sweep();
    let tol = Tolerances::default();
    let mut group = c.benchmark_group("paper_sweep_27_runs");
    group.sample_size(20);
    for threads in [1usize, 2] {
        group.bench_function(format!("{threads}_threads"), |b| {
            b.iter(|| sweep(black_box(&specs), 180, tol, Some(threads)))
        });
    }
    group.finish();
}

criterion_group!(benches, bench_rhs, bench_single_run, bench_sweep);
criterion_main!(benches);
