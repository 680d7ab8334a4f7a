//! Work-precision of the time-stepping schemes (issue 15): for each scheme and
//! a ladder of tolerances, the largest error of the 15-layer map against a
//! refined solution, and the best-of-N wall time of the run (layers made
//! while stepping, as `granseg.simulate` does). Pure Rust: the same call for
//! every scheme, so the Python overhead, equal for all, is left out.
//!
//!   cargo run --release --example work_precision [-- REPEATS]
//!
//! Cases: G-PP (glass/PP, c0 = 0.5) and S-PP (steel/PP, c0 = 0.9, the
//! hardest tested case), 3600 s, outputs every 2 s, 180 cells. Beside the
//! ESDIRKs: ROS34PW2, a Rosenbrock-W scheme with the exact Jacobian
//! (`rosenbrock.rs`: one linear solve per stage, no Newton iteration).
use std::sync::Arc;
use std::time::Instant;

use _core::rosenbrock::layer_map_rosenbrock;
use _core::stepper::{layer_map_with_scheme, Scheme};
use _core::sweep::{run_one, RunSpec};
use _core::{Params, Tolerances};

/// A scheme of the stepper, or the Rosenbrock-W one (None).
fn layers(
    p: &Params,
    n_cells: usize,
    t: &[f64],
    tol: Tolerances,
    scheme: Option<Scheme>,
) -> (Vec<f64>, usize) {
    let (map, stats) = match scheme {
        Some(s) => layer_map_with_scheme(p, n_cells, t, tol, s, 15).unwrap(),
        None => layer_map_rosenbrock(p, n_cells, t, tol, 15).unwrap(),
    };
    (map, stats.steps)
}

fn main() {
    let repeats: usize = std::env::args()
        .nth(1)
        .and_then(|a| a.parse().ok())
        .unwrap_or(15);
    let t: Vec<f64> = (0..=1800).map(|i| i as f64 * 2.0).collect();
    let cases = [
        ("G-PP-50", Params::default()),
        (
            "S-PP-90",
            Params {
                rho_h: 7800.0,
                c0: 0.9,
                ..Params::default()
            },
        ),
    ];
    println!("    cargo run --release --example work_precision -- {repeats}\n");
    println!("| case | scheme | rtol | steps | wall time | largest layer error |");
    println!("|---|---|---|---|---|---|");
    for (name, p) in cases {
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
        let schemes = [
            Some(Scheme::Esdirk3),
            Some(Scheme::Esdirk4),
            Some(Scheme::Esdirk5),
            None,
        ];
        for scheme in schemes {
            for rtol in [1e-3, 3e-4, 1e-4, 3e-5, 1e-5, 3e-6] {
                let tol = Tolerances {
                    rtol,
                    atol: rtol / 10.0,
                };
                let (got, steps) = layers(&p, 180, &t, tol, scheme);
                let err = got
                    .iter()
                    .zip(&reference)
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0, f64::max);
                let mut best = f64::INFINITY;
                for _ in 0..repeats {
                    let start = Instant::now();
                    std::hint::black_box(layers(&p, 180, &t, tol, scheme));
                    best = best.min(start.elapsed().as_secs_f64());
                }
                println!(
                    "| {name} | {} | {rtol:e} | {steps} | {:.3} ms | {err:.2e} |",
                    scheme.map_or("ros34pw2", |s| s.tableau().name),
                    best * 1e3
                );
            }
        }
    }
}
