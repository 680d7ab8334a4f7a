//! A Rosenbrock-W scheme with the exact Jacobian, for the scheme comparison
//! of issue 15 (not the default: `examples/work_precision.rs` decides).
//!
//! ROS34PW2 (Rang & Angermann 2005): four stages, order 3 with an order-2
//! embedded solution, L-stable, stiffly accurate. Each stage is one linear
//! solve with I - h gamma J, J the exact Jacobian at the step's start
//! (`exact_jacobian.rs`, factored once per step), and one right-hand side:
//! no Newton iteration. Written in Hairer & Wanner's transformed variables
//! u_i = sum_j gamma_ij k_j, so J is never multiplied by a vector:
//!
//!   (I - h gamma J) u_i = h gamma (f(t + c_i h, y + sum_j at_ij u_j) + sum_j c_ij / h u_j)
//!   y_new = y + sum_i m_i u_i
//!
//! with at = A G^-1, c = diag(1 / gamma) - G^-1, m = b' G^-1 (G the lower
//! triangular gamma matrix, diagonal included). The time derivative term
//! (gamma_i h^2 df/dt) is left out: the baseline's right-hand side does not
//! depend on t (only a drifting band or a time law makes it so).
//! Outputs: the cubic Hermite interpolant with f at both ends, reduced to
//! layer means once per step, as in `stepper.rs`.

use crate::error::SolveError;
use crate::exact_jacobian::ExactStageMatrix;
use crate::flux::Operator;
use crate::layers::LayerMap;
use crate::limits;
use crate::model::initial_condition;
use crate::params::Params;
use crate::stepper::{enforce_bounds, validate_run, Stats, Tolerances};

const S: usize = 4;
const GAMMA: f64 = 4.358_665_215_084_59e-1;
/// Propagation table A (strictly lower).
const A: [[f64; S]; S] = [
    [0.0; S],
    [8.717_330_430_169_18e-1, 0.0, 0.0, 0.0],
    [
        8.445_706_001_536_942e-1,
        -1.129_906_423_648_418_5e-1,
        0.0,
        0.0,
    ],
    [0.0, 0.0, 1.0, 0.0],
];
/// Off-diagonal gamma_ij (strictly lower).
const G: [[f64; S]; S] = [
    [0.0; S],
    [-8.717_330_430_169_18e-1, 0.0, 0.0, 0.0],
    [
        -9.033_805_701_304_408e-1,
        5.418_067_238_809_533e-2,
        0.0,
        0.0,
    ],
    [
        2.421_238_070_609_535e-1,
        -1.223_250_583_904_514_7,
        5.452_602_553_351_021e-1,
        0.0,
    ],
];
const B: [f64; S] = [
    2.421_238_070_609_535e-1,
    -1.223_250_583_904_514_7,
    1.545_260_255_335_102,
    4.358_665_215_084_59e-1,
];
const B_HAT: [f64; S] = [
    3.781_090_314_581_937e-1,
    -9.604_229_221_242_318e-2,
    0.5,
    2.179_332_607_542_295e-1,
];
const C: [f64; S] = [0.0, 8.717_330_430_169_18e-1, 7.315_799_577_888_524e-1, 1.0];

/// The transformed coefficients (at, c, m, m - m_hat).
struct Transformed {
    at: [[f64; S]; S],
    c: [[f64; S]; S],
    m: [f64; S],
    e: [f64; S],
}

fn transformed() -> Transformed {
    // G^-1 of the lower triangular G (diagonal gamma), by forward substitution
    let mut full = G;
    for (i, row) in full.iter_mut().enumerate() {
        row[i] = GAMMA;
    }
    let mut inv = [[0.0; S]; S];
    for col in 0..S {
        for i in col..S {
            let mut v = if i == col { 1.0 } else { 0.0 };
            for k in col..i {
                v -= full[i][k] * inv[k][col];
            }
            inv[i][col] = v / full[i][i];
        }
    }
    let mut t = Transformed {
        at: [[0.0; S]; S],
        c: [[0.0; S]; S],
        m: [0.0; S],
        e: [0.0; S],
    };
    for i in 0..S {
        for j in 0..S {
            t.at[i][j] = (0..S).map(|k| A[i][k] * inv[k][j]).sum();
            t.c[i][j] = if i == j { 1.0 / GAMMA } else { 0.0 } - inv[i][j];
        }
        t.m[i] = (0..S).map(|k| B[k] * inv[k][i]).sum();
        t.e[i] = (0..S).map(|k| (B[k] - B_HAT[k]) * inv[k][i]).sum();
    }
    t
}

fn wrms(x: &[f64], scale: &[f64]) -> f64 {
    let s: f64 = x.iter().zip(scale).map(|(v, s)| (v / s) * (v / s)).sum();
    (s / x.len() as f64).sqrt()
}

/// One run with ROS34PW2 reduced to its layer map (n_t x n_layers, row-major).
pub fn layer_map_rosenbrock(
    p: &Params,
    n_cells: usize,
    t_out: &[f64],
    tol: Tolerances,
    n_layers: usize,
) -> Result<(Vec<f64>, Stats), SolveError> {
    p.validate()?;
    validate_run(n_cells, t_out, &tol)?;
    let len = limits::check_buffer(
        "the layer map",
        &[("len(t)", t_out.len()), ("n_layers", n_layers)],
    )?;
    let tr = transformed();
    let n = n_cells;
    let map = LayerMap::new(n, n_layers);
    let mut layers = limits::zeroed(len, "the layer map")?;
    let mut op = Operator::new(*p, n);
    let mut stage = ExactStageMatrix::new(n);
    let mut stats = Stats::default();
    let z = || vec![0.0; n];
    let (mut y, mut fy, mut y_new, mut f_new) = (initial_condition(p, &op.grid), z(), z(), z());
    let (mut ys, mut fs, mut err, mut scale) = (z(), z(), z(), z());
    let mut u: Vec<Vec<f64>> = (0..S).map(|_| z()).collect();
    let mut herm = [z(), z(), z()];
    let mut coef = vec![0.0; 4 * n_layers];
    let mut next = 0;
    while next < t_out.len() && t_out[next] == 0.0 {
        map.apply(&y, &mut layers[next * n_layers..(next + 1) * n_layers]);
        next += 1;
    }
    let t_end = *t_out.last().unwrap();
    let mut t = 0.0;
    op.rhs(t, &y, &mut fy);
    let mut h = {
        let sc: Vec<f64> = y.iter().map(|v| tol.atol + tol.rtol * v.abs()).collect();
        (0.01 * wrms(&y, &sc) / wrms(&fy, &sc).max(1e-10)).clamp(1e-8, t_end)
    };
    let mut face_at_y = true;
    while next < t_out.len() {
        if stats.steps + stats.rejected > 1_000_000 {
            return Err(SolveError::NewtonFailure {
                t,
                reason: "more than 1000000 steps".into(),
            });
        }
        let last = t + h >= t_end * (1.0 - 1e-12);
        if last {
            h = t_end - t;
        }
        if !face_at_y {
            op.rhs(t, &y, &mut fy);
        }
        let hg = h * GAMMA;
        stage.face_state(&op, &y);
        stats.jacobians += 1;
        if !stage.factor(&op, hg) {
            return Err(SolveError::NewtonFailure {
                t,
                reason: "the stage matrix is singular".into(),
            });
        }
        for i in 0..S {
            for c in 0..n {
                let mut acc = y[c];
                for (j, uj) in u[..i].iter().enumerate() {
                    acc += tr.at[i][j] * uj[c];
                }
                ys[c] = acc;
            }
            if i == 0 {
                fs.copy_from_slice(&fy);
            } else {
                op.rhs(t + C[i] * h, &ys, &mut fs);
            }
            let (done, rest) = u.split_at_mut(i);
            let ui = &mut rest[0];
            for c in 0..n {
                let mut acc = fs[c];
                for (j, uj) in done.iter().enumerate() {
                    acc += tr.c[i][j] / h * uj[c];
                }
                ui[c] = hg * acc;
            }
            stage.solve(ui);
        }
        face_at_y = false;
        for c in 0..n {
            let (mut v, mut e) = (y[c], 0.0);
            for i in 0..S {
                v += tr.m[i] * u[i][c];
                e += tr.e[i] * u[i][c];
            }
            y_new[c] = v;
            err[c] = e;
            scale[c] = tol.atol + tol.rtol * y[c].abs().max(v.abs());
        }
        let e = wrms(&err, &scale);
        if !(e.is_finite() && e <= 1.0) {
            stats.rejected += 1;
            h *= if e.is_finite() {
                (0.9 * e.powf(-1.0 / 3.0)).clamp(0.1, 0.5)
            } else {
                0.25
            };
            if h < 1e-10 {
                return Err(SolveError::NewtonFailure {
                    t,
                    reason: format!("error test failed even at step size {h:.3e} s"),
                });
            }
            continue;
        }
        let t_new = if last { t_end } else { t + h };
        let clip = enforce_bounds(&mut y_new);
        if clip > 0.0 {
            stats.clipped += 1;
            stats.max_clip = stats.max_clip.max(clip);
        }
        op.rhs(t_new, &y_new, &mut f_new);
        face_at_y = true;
        if next < t_out.len() && t_out[next] <= t_new {
            for c in 0..n {
                let dy = y_new[c] - y[c];
                let (a, b) = (h * fy[c], h * f_new[c]);
                herm[0][c] = a;
                herm[1][c] = 3.0 * dy - 2.0 * a - b;
                herm[2][c] = -2.0 * dy + a + b;
            }
            let (c0, rest) = coef.split_at_mut(n_layers);
            let (c1, rest) = rest.split_at_mut(n_layers);
            let (c2, c3) = rest.split_at_mut(n_layers);
            map.apply(&y, c0);
            map.apply(&herm[0], c1);
            map.apply(&herm[1], c2);
            map.apply(&herm[2], c3);
            while next < t_out.len() && t_out[next] <= t_new {
                let th = ((t_out[next] - t) / h).clamp(0.0, 1.0);
                let row = &mut layers[next * n_layers..(next + 1) * n_layers];
                for (l, v) in row.iter_mut().enumerate() {
                    *v = (c0[l] + th * (c1[l] + th * (c2[l] + th * c3[l]))).clamp(0.0, 1.0);
                }
                next += 1;
            }
        }
        std::mem::swap(&mut y, &mut y_new);
        std::mem::swap(&mut fy, &mut f_new);
        t = t_new;
        stats.steps += 1;
        h *= (0.9 * e.max(1e-10).powf(-1.0 / 3.0)).clamp(0.2, 4.0);
    }
    stats.rhs_evals = op.n_rhs;
    Ok((layers, stats))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sweep::{run_one, RunSpec};
    use std::sync::Arc;

    #[test]
    fn coefficients_are_consistent() {
        // the weights of both solutions sum to one; the stiffly accurate last row
        assert!((B.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        assert!((B_HAT.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        for i in 0..S {
            assert!((A[i].iter().sum::<f64>() - C[i]).abs() < 1e-12, "row {i}");
        }
    }

    #[test]
    fn converges_to_the_reference_map() {
        let t: Vec<f64> = (0..=60).map(|i| i as f64 * 60.0).collect();
        let p = Params::default();
        let spec = RunSpec {
            params: p,
            t_out: Arc::new(t.clone()),
            measured: None,
            n_layers: 15,
            tangents: Default::default(),
        };
        let tight = Tolerances {
            rtol: 1e-9,
            atol: 1e-11,
        };
        let reference = run_one(&spec, 90, tight).unwrap().layers;
        let mut errors = vec![];
        for rtol in [1e-3, 1e-5] {
            let tol = Tolerances {
                rtol,
                atol: rtol / 10.0,
            };
            let (got, _) = layer_map_rosenbrock(&p, 90, &t, tol, 15).unwrap();
            let e = got
                .iter()
                .zip(&reference)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            errors.push(e);
        }
        assert!(
            errors[1] < 1e-4 && errors[1] < errors[0] / 5.0,
            "{errors:?}"
        );
    }
}
