//! Would another (scheme, rtol) pair keep the defaults' promise? The largest
//! 15-layer error against a refined solution and the run time, over cases
//! drawn across the physical ranges of tests/test_model.py (density ratio
//! 1.4-8.25, c0 0.1-0.9, k 0.4-1.0, delta/H 0.15-0.3), for today's default
//! (ESDIRK3, rtol 3e-5) and a candidate (issue 15).
//!
//!   cargo run --release --example default_survey [-- CASES [SCHEME RTOL]]
use std::sync::Arc;
use std::time::Instant;

use _core::stepper::{layer_map_with_scheme, Scheme};
use _core::sweep::{run_one, RunSpec};
use _core::{Params, Tolerances};

/// A small deterministic generator (the cases are fixed by the seed, no crate needed).
struct Lcg(u64);
impl Lcg {
    fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        lo + (hi - lo) * ((self.0 >> 11) as f64 / (1u64 << 53) as f64)
    }
}

fn run(p: &Params, t: &[f64], scheme: Scheme, rtol: f64) -> (Vec<f64>, f64) {
    let start = Instant::now();
    let tol = Tolerances {
        rtol,
        atol: rtol / 10.0,
    };
    let (map, _) = layer_map_with_scheme(p, 180, t, tol, scheme, 15).unwrap();
    (map, start.elapsed().as_secs_f64())
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let cases: usize = args.get(1).and_then(|a| a.parse().ok()).unwrap_or(24);
    let scheme = match args.get(2).map(String::as_str) {
        Some(name) => Scheme::from_name(name).unwrap(),
        None => Scheme::Esdirk4,
    };
    let rtol: f64 = args.get(3).and_then(|a| a.parse().ok()).unwrap_or(1e-4);
    let t: Vec<f64> = (0..=1800).map(|i| i as f64 * 2.0).collect();
    let mut rng = Lcg(20261125);
    let (mut worst_default, mut worst_candidate, mut time_default, mut time_candidate) =
        (0.0f64, 0.0f64, 0.0, 0.0);
    println!(
        "    cargo run --release --example default_survey -- {cases} {} {rtol:e}\n",
        scheme.tableau().name
    );
    println!(
        "| delta_R | c0 | k | delta/H | error ESDIRK3 3e-5 | error {} {rtol:e} | time ratio |",
        scheme.tableau().name
    );
    println!("|---|---|---|---|---|---|---|");
    for _ in 0..cases {
        let p = Params {
            rho_h: rng.uniform(1.4, 8.25) * 946.0,
            rho_l: 946.0,
            c0: rng.uniform(0.1, 0.9),
            k: rng.uniform(0.4, 1.0),
            delta_over_h: rng.uniform(0.15, 0.3),
            ..Params::default()
        };
        let spec = RunSpec {
            params: p,
            t_out: Arc::new(t.clone()),
            measured: None,
            n_layers: 15,
            tangents: Default::default(),
        };
        let reference = run_one(
            &spec,
            1440,
            Tolerances {
                rtol: 1e-9,
                atol: 1e-11,
            },
        )
        .unwrap()
        .layers;
        let err = |got: &[f64]| {
            got.iter()
                .zip(&reference)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max)
        };
        // best of 5 for each, interleaved
        let (mut td, mut tc) = (f64::INFINITY, f64::INFINITY);
        let (mut ed, mut ec) = (0.0, 0.0);
        for _ in 0..5 {
            let (a, s) = run(&p, &t, Scheme::Esdirk3, 3e-5);
            td = td.min(s);
            ed = err(&a);
            let (b, s) = run(&p, &t, scheme, rtol);
            tc = tc.min(s);
            ec = err(&b);
        }
        worst_default = worst_default.max(ed);
        worst_candidate = worst_candidate.max(ec);
        time_default += td;
        time_candidate += tc;
        println!(
            "| {:.2} | {:.2} | {:.2} | {:.3} | {ed:.2e} | {ec:.2e} | {:.2} |",
            p.rho_h / p.rho_l,
            p.c0,
            p.k,
            p.delta_over_h,
            tc / td
        );
    }
    println!(
        "\nlargest error: ESDIRK3 3e-5 {worst_default:.2e}, {} {rtol:e} {worst_candidate:.2e}; total time {:.1} ms against {:.1} ms ({:.2}x)",
        scheme.tableau().name, time_candidate * 1e3, time_default * 1e3, time_candidate / time_default
    );
}
