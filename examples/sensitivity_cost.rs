//! What a direction of forward sensitivities costs beside the run itself.
//!
//!     cargo run --release --example sensitivity_cost
//!
//! G-PP and S-PP, 3600 s with outputs every 2 s, 90 cells (the fits' grid),
//! default tolerances, 15 layers: best of 15 wall times with 0 to 4 tangents
//! (k, delta/H, b, one law knot). A forward difference costs one more run per
//! parameter; a sensitivity direction costs the increment printed here.

use _core::params::Params;
use _core::sensitivity::{layer_map_with_sensitivities, Tangent};
use _core::stepper::Tolerances;
use std::time::Instant;
fn main() {
    let t: Vec<f64> = (0..=1800).map(|i| i as f64 * 2.0).collect();
    for rho_h in [2450.0, 7800.0] {
        let p = Params {
            rho_h,
            ..Params::default()
        };
        let tol = Tolerances::default();
        let stop = std::sync::atomic::AtomicBool::new(false);
        let keys = ["k", "delta_over_H", "b", "law_flux_c_3"];
        for m in 0..=4 {
            let tg: Vec<Tangent> = keys[..m]
                .iter()
                .map(|k| Tangent::from_pairs([(*k, 1.0)]).unwrap())
                .collect();
            let mut best = f64::INFINITY;
            let mut st = None;
            for _ in 0..15 {
                let t0 = Instant::now();
                let r =
                    layer_map_with_sensitivities(&p, 90, &t, tol, 15, tg.clone(), &stop).unwrap();
                best = best.min(t0.elapsed().as_secs_f64());
                st = Some(r.2);
            }
            println!(
                "rho_h {rho_h}, {m} tangents: {:.3} ms ({} steps)",
                best * 1e3,
                st.unwrap().steps
            );
        }
    }
}
