//! Solver counters with the two Newton matrices on the benchmark case:
//!   cargo run --release --features pressure-coupled --example newton_matrices
use _core::{pressure_coupled, simulate, Params, Tolerances};

fn main() {
    let t: Vec<f64> = (0..=1800).map(|i| i as f64 * 2.0).collect();
    for (name, p) in [
        ("G-PP-50", Params::default()),
        (
            "S-PP-50",
            Params {
                rho_h: 7800.0,
                ..Params::default()
            },
        ),
    ] {
        let tol = Tolerances::default();
        let (a, sa) = simulate(&p, 180, &t, tol).unwrap();
        let (b, sb) = pressure_coupled::simulate(&p, 180, &t, tol).unwrap();
        let diff = a
            .iter()
            .zip(&b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max);
        println!("{name}: tridiagonal (P lagged in J): {} steps, {} Newton iterations, {} flux evaluations", sa.steps, sa.newton_iters, sa.rhs_evals);
        println!("{name}: pressure-coupled (faer LU):  {} steps, {} Newton iterations, {} flux evaluations", sb.steps, sb.newton_iters, sb.rhs_evals);
        println!("{name}: max |difference| of the profiles {diff:.1e}");
    }
}
