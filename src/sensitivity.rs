//! Forward sensitivities of the layer maps to the fitted parameters (issue 15).
//!
//! A *tangent* v is a direction in parameter space (`Tangent`: k, delta/H, b,
//! the shear band's drift and every law knot). Along the run, S = dc/dv obeys
//! the derivative of the discrete scheme itself: every ESDIRK stage
//! Y_s = base_s + h gamma f(t_s, Y_s) gives
//!
//!   (I - h gamma J(Y_s)) S_s = S_base,s + h gamma f_v(t_s, Y_s),
//!   S_base,s = S_n + h sum_{j<s} a_sj K_j,    K_s = (S_s - S_base,s) / (h gamma),
//!
//! with the *exact* Jacobian J: the limiter's slopes, a(c) through the face
//! density and the overburden pressure P, which every face feels from all the
//! cells above. The pressure is carried by extra unknowns Q_m = sum_{j>=m} S_j,
//! which makes the stage matrix banded (4 bands either side, interleaved
//! S_0, Q_1, S_1, Q_2, ...) and cheap to factor once per stage for every
//! direction (`banded.rs`). Outputs use the same cubic Hermite interpolant as
//! the solution, with K at both ends, then the same layer means.
//!
//! So the derivative is that of the solver's own answer for its step sequence
//! (to the Newton tolerance), not of a second run at a shifted point: it has no
//! step-size noise, and one run gives every direction. The stages are
//! differentiated after a step is accepted (rejected attempts cost nothing).
//! Clipping a state back into [0, 1] (rare, a fraction of the tolerance) is
//! not differentiated.

use crate::error::SolveError;
use crate::exact_jacobian::ExactStageMatrix;
use crate::flux::Operator;
use crate::laws::Laws;
use crate::layers::LayerMap;
use crate::limits;
use crate::params::Params;
use crate::stepper::Tableau;

/// The scalar parameters a tangent may move (besides the law knots).
pub const SCALARS: [&str; 5] = ["k", "delta_over_H", "b", "delta_drift", "delta_drift_time"];

/// A direction in parameter space: the change of each differentiable parameter.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Tangent {
    pub k: f64,
    pub delta_over_h: f64,
    pub b: f64,
    pub delta_drift: f64,
    pub delta_drift_time: f64,
    /// Changes of the law knots (log-factors); `time_scale` is not used.
    pub laws: Laws,
}

impl Tangent {
    /// Build from (name, change) pairs; a name the core cannot differentiate
    /// by is refused by name.
    pub fn from_pairs<'a>(
        pairs: impl IntoIterator<Item = (&'a str, f64)>,
    ) -> Result<Self, SolveError> {
        let mut v = Tangent::default();
        for (name, value) in pairs {
            if !value.is_finite() {
                return Err(SolveError::InvalidParameter {
                    name: format!("tangent {name}"),
                    value,
                    range: "a finite change".into(),
                });
            }
            match name {
                "k" => v.k = value,
                "delta_over_H" => v.delta_over_h = value,
                "b" => v.b = value,
                "delta_drift" => v.delta_drift = value,
                "delta_drift_time" => v.delta_drift_time = value,
                _ => {
                    if v.laws.set(name, value).is_none() {
                        return Err(SolveError::InvalidInput(format!(
                            "no sensitivity to {name:?}: the core differentiates by {} and the law knots (law_*_0 .. law_*_16)",
                            SCALARS.join(", ")
                        )));
                    }
                }
            }
        }
        Ok(v)
    }
}

/// Running state of the sensitivities of one run, and their layer maps.
pub struct Sensitivities {
    tangents: Vec<Tangent>,
    n: usize,
    n_t: usize,
    map: LayerMap,
    /// Layer maps of the directions, (n_dir, n_t, n_layers) row-major.
    pub layers: Vec<f64>,
    /// S at the start of the step, per direction.
    s_y: Vec<Vec<f64>>,
    /// Stage derivatives K_s, per direction and stage.
    k: Vec<Vec<Vec<f64>>>,
    /// I - h gamma J with the exact J, factored once per stage for every direction
    stage: ExactStageMatrix,
    // scratch
    y_stage: Vec<f64>,
    f_scratch: Vec<f64>,
    base: Vec<f64>,
    fp: Vec<f64>,
    dflux: Vec<f64>,
    out: Vec<f64>,
    /// layer means of the step's interpolant coefficients (4 x n_layers)
    coef: Vec<f64>,
}

impl Sensitivities {
    /// Workspace for `tangents` on `n_cells` cells, `n_t` outputs of
    /// `n_layers` layers, a scheme of `stages` stages. Sizes are checked
    /// before anything is allocated.
    pub fn new(
        tangents: Vec<Tangent>,
        n_cells: usize,
        n_t: usize,
        n_layers: usize,
        stages: usize,
    ) -> Result<Self, SolveError> {
        limits::check_cells(n_cells)?;
        let m = tangents.len();
        let len = limits::check_buffer(
            "the sensitivity maps",
            &[("tangents", m), ("len(t)", n_t), ("n_layers", n_layers)],
        )?;
        // the running state of every direction (S and each stage's K), before it exists
        limits::check_buffer(
            "the sensitivities' workspace",
            &[
                ("tangents", m),
                ("stages + 1", stages + 1),
                ("n_cells", n_cells),
            ],
        )?;
        let n = n_cells;
        let z = || vec![0.0; n];
        Ok(Sensitivities {
            n,
            n_t,
            map: LayerMap::new(n_cells, n_layers),
            layers: limits::zeroed(len, "the sensitivity maps")?,
            s_y: (0..m).map(|_| z()).collect(),
            k: (0..m).map(|_| (0..stages).map(|_| z()).collect()).collect(),
            stage: ExactStageMatrix::new(n),
            y_stage: z(),
            f_scratch: z(),
            base: z(),
            fp: z(),
            dflux: z(),
            out: z(),
            coef: Vec::new(),
            tangents,
        })
    }

    pub fn n_dir(&self) -> usize {
        self.tangents.len()
    }

    /// f_v(t, c): the change of dc/dt along tangent `d` at the face state, into `fp`.
    fn parameter_rhs(&mut self, op: &Operator, c: &[f64], t: f64, d: usize) {
        let p = &op.p;
        let v = &self.tangents[d];
        let n = self.n;
        let delta = p.delta_at(t);
        // delta(t) = delta_over_H H (1 + drift (1 - exp(-t / T)))
        let decay = (-t / p.delta_drift_time).exp();
        let grow = 1.0 - decay;
        let d_grow = -decay * t / (p.delta_drift_time * p.delta_drift_time) * v.delta_drift_time;
        let d_delta = p.h
            * (v.delta_over_h * (1.0 + p.delta_drift * grow)
                + p.delta_over_h * (v.delta_drift * grow + p.delta_drift * d_grow));
        let u = t / p.laws.time_scale;
        let rate = v.laws.rate_t.log_factor(u);
        let diff_t = v.laws.diff_t.log_factor(u);
        let (dk, db) = (v.k / p.k, v.b / p.b);
        // most tangents move one parameter: leave out the tables they do not touch
        let (shear_z, diff_z, flux_c) = (
            (!v.laws.shear_z.is_zero()).then_some(&v.laws.shear_z),
            (!v.laws.diff_z.is_zero()).then_some(&v.laws.diff_z),
            (!v.laws.flux_c.is_zero()).then_some(&v.laws.flux_c),
        );
        let band = d_delta / delta;
        for f in 0..n - 1 {
            let z = op.grid.face(f);
            let zh = z / p.h;
            let mut dln_g = if band != 0.0 {
                band * (z / delta - 1.0)
            } else {
                0.0
            };
            if let Some(tab) = shear_z {
                dln_g += tab.log_factor(zh);
            }
            let dln_seg = dln_g - dk + rate;
            let mut dln_diff = dln_g + db + diff_t + rate;
            if let Some(tab) = diff_z {
                dln_diff += tab.log_factor(zh);
            }
            let mut dln_a = dln_seg - self.stage.e[f] * dln_g;
            if let Some(tab) = flux_c {
                dln_a += tab.log_factor(0.5 * (c[f] + c[f + 1]));
            }
            self.dflux[f] = -op.a[f] * dln_a * op.c_up[f] * (1.0 - op.c_dn[f])
                - op.diff[f] * dln_diff * (c[f + 1] - c[f]);
        }
        let inv_dz = 1.0 / op.grid.dz;
        let mut below = 0.0;
        for i in 0..n {
            let above = if i + 1 < n { self.dflux[i] } else { 0.0 };
            self.fp[i] = -(above - below) * inv_dz;
            below = above;
        }
    }

    /// At t = 0 (S = 0): K_0 = f_v(0, y0), from the operator's `rhs` at y0.
    pub fn start(&mut self, op: &Operator, y: &[f64]) {
        self.stage.face_state(op, y);
        for d in 0..self.n_dir() {
            self.parameter_rhs(op, y, 0.0, d);
            self.s_y[d].iter_mut().for_each(|v| *v = 0.0);
            self.k[d][0].copy_from_slice(&self.fp);
        }
    }

    /// Differentiate the accepted step from (t, y) of size h (stage
    /// derivatives `k`, last stage = the new state) and write the outputs
    /// t_out[next..] that fall in (t, t_new].
    #[allow(clippy::too_many_arguments)]
    pub fn step(
        &mut self,
        op: &mut Operator,
        tab: &Tableau,
        t: f64,
        h: f64,
        t_new: f64,
        y: &[f64],
        k: &[Vec<f64>],
        t_out: &[f64],
        next: usize,
    ) -> Result<(), SolveError> {
        let n = self.n;
        let hg = h * tab.gamma;
        let stages = tab.stages();
        for s in 1..stages {
            let ts = t + tab.c[s] * h;
            for i in 0..n {
                let mut acc = y[i] + hg * k[s][i];
                for (j, kj) in k[..s].iter().enumerate() {
                    acc += h * tab.a[s][j] * kj[i];
                }
                self.y_stage[i] = acc;
            }
            let ys = std::mem::take(&mut self.y_stage);
            op.rhs(ts, &ys, &mut self.f_scratch);
            self.stage.face_state(op, &ys);
            if !self.stage.factor(op, hg) {
                self.y_stage = ys;
                return Err(SolveError::NewtonFailure {
                    t,
                    reason: "the sensitivities' stage matrix is singular".into(),
                });
            }
            for d in 0..self.n_dir() {
                self.parameter_rhs(op, &ys, ts, d);
                for i in 0..n {
                    let mut acc = self.s_y[d][i];
                    for j in 0..s {
                        acc += h * tab.a[s][j] * self.k[d][j][i];
                    }
                    self.base[i] = acc;
                }
                for i in 0..n {
                    self.out[i] = self.base[i] + hg * self.fp[i];
                }
                self.stage.solve(&mut self.out);
                let inv = 1.0 / hg;
                for i in 0..n {
                    self.k[d][s][i] = (self.out[i] - self.base[i]) * inv;
                }
            }
            self.y_stage = ys;
        }
        let last = stages - 1;
        let nl = self.map.n_layers();
        let has_outputs = next < t_out.len() && t_out[next] <= t_new;
        for d in 0..self.n_dir() {
            // S_new = the last stage (stiffly accurate): S_n + h sum_j a_last,j K_j
            for i in 0..n {
                self.base[i] = h * stage_sum(tab, &self.k[d], last, i);
            }
            if has_outputs {
                // cubic Hermite in theta with K at both ends, reduced to layer means
                // once per step (it is linear in its coefficients), then evaluated
                // at each output: S_n + theta (a + theta (b + theta c))
                let kd = &self.k[d];
                for i in 0..n {
                    let (a0, b0, ds) = (h * kd[0][i], h * kd[last][i], self.base[i]);
                    self.fp[i] = a0;
                    self.dflux[i] = 3.0 * ds - 2.0 * a0 - b0;
                    self.out[i] = -2.0 * ds + a0 + b0;
                }
                self.coef.resize(4 * nl, 0.0);
                let (c0, rest) = self.coef.split_at_mut(nl);
                let (c1, rest) = rest.split_at_mut(nl);
                let (c2, c3) = rest.split_at_mut(nl);
                self.map.apply(&self.s_y[d], c0);
                self.map.apply(&self.fp, c1);
                self.map.apply(&self.dflux, c2);
                self.map.apply(&self.out, c3);
                let mut idx = next;
                while idx < t_out.len() && t_out[idx] <= t_new {
                    let theta = ((t_out[idx] - t) / h).clamp(0.0, 1.0);
                    let row = (d * self.n_t + idx) * nl;
                    for (l, v) in self.layers[row..row + nl].iter_mut().enumerate() {
                        *v = c0[l] + theta * (c1[l] + theta * (c2[l] + theta * c3[l]));
                    }
                    idx += 1;
                }
            }
            for i in 0..n {
                self.s_y[d][i] += self.base[i];
            }
            let (first, rest) = self.k[d].split_at_mut(1);
            first[0].copy_from_slice(&rest[last - 1]);
        }
        Ok(())
    }
}

/// sum_j a_last,j K_j at cell i (the last row of a stiffly accurate tableau
/// gives the step's increment / h).
#[inline]
fn stage_sum(tab: &Tableau, k: &[Vec<f64>], last: usize, i: usize) -> f64 {
    (0..=last).map(|j| tab.a[last][j] * k[j][i]).sum()
}

/// The parameters moved along a tangent by `eps` (for finite-difference checks).
pub fn shifted(p: &Params, v: &Tangent, eps: f64) -> Params {
    let mut q = *p;
    q.k += eps * v.k;
    q.delta_over_h += eps * v.delta_over_h;
    q.b += eps * v.b;
    q.delta_drift += eps * v.delta_drift;
    q.delta_drift_time += eps * v.delta_drift_time;
    for key in Laws::keys() {
        let dv = v.laws.get(&key).unwrap_or(0.0);
        if dv != 0.0 {
            let cur = q.laws.get(&key).unwrap_or(0.0);
            q.laws.set(&key, cur + eps * dv);
        }
    }
    q
}

/// One run reduced to its layer map and the layer maps of its sensitivities
/// along `tangents` (none: an empty second map, nothing differentiated): (layers (n_t, n_layers), sensitivities (n_dir, n_t,
/// n_layers), stats), all row-major.
#[allow(clippy::too_many_arguments)]
pub fn layer_map_with_sensitivities(
    p: &Params,
    n_cells: usize,
    t_out: &[f64],
    tol: crate::stepper::Tolerances,
    n_layers: usize,
    tangents: Vec<Tangent>,
    stop: &std::sync::atomic::AtomicBool,
) -> Result<(Vec<f64>, Vec<f64>, crate::stepper::Stats), SolveError> {
    use crate::stepper::{self, Scheme};
    p.validate()?;
    stepper::validate_run(n_cells, t_out, &tol)?;
    let scheme = Scheme::default();
    if tangents.is_empty() {
        let (layers, stats) =
            stepper::layer_map_run(p, n_cells, t_out, tol, scheme, n_layers, None, stop)?;
        return Ok((layers, Vec::new(), stats));
    }
    let stages = scheme.tableau().stages();
    let mut sens = Sensitivities::new(tangents, n_cells, t_out.len(), n_layers, stages)?;
    let (layers, stats) = stepper::layer_map_run(
        p,
        n_cells,
        t_out,
        tol,
        scheme,
        n_layers,
        Some(&mut sens),
        stop,
    )?;
    Ok((layers, sens.layers, stats))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stepper::Tolerances;

    fn run(p: &Params, t: &[f64], tangents: Vec<Tangent>) -> (Vec<f64>, Vec<f64>) {
        let tol = Tolerances {
            rtol: 1e-9,
            atol: 1e-10,
        };
        let (l, s, _) =
            layer_map_with_sensitivities(p, 48, t, tol, 15, tangents, limits::never()).unwrap();
        (l, s)
    }

    /// Every kind of tangent against central differences of the whole solver
    /// (tight tolerances, so that the step-size noise is far below the check).
    #[test]
    fn sensitivities_match_central_differences_of_the_solver() {
        let t: Vec<f64> = (0..=30).map(|i| i as f64 * 60.0).collect();
        let mut p = Params {
            rho_h: 7800.0,
            c0: 0.4,
            delta_drift: 0.3,
            ..Params::default()
        };
        // non-zero laws, so that their factors and slopes enter J and f_v
        p.laws.flux_c.0[5] = 0.4;
        p.laws.flux_c.0[9] = -0.3;
        p.laws.shear_z.0[4] = 0.2;
        p.laws.time_scale = 1800.0;
        let tangents: Vec<(&str, Tangent)> = [
            ("k", "k", 1.0),
            ("delta_over_H", "delta_over_H", 1.0),
            ("b", "b", 1.0),
            ("delta_drift", "delta_drift", 1.0),
            ("delta_drift_time", "delta_drift_time", 100.0),
            ("flux_c", "law_flux_c_7", 1.0),
            ("diff_z", "law_diff_z_3", 1.0),
            ("diff_t", "law_diff_t_4", 1.0),
            ("shear_z", "law_shear_z_2", 1.0),
            ("rate_t", "law_rate_t_1", 1.0),
        ]
        .into_iter()
        .map(|(label, key, v)| (label, Tangent::from_pairs([(key, v)]).unwrap()))
        .collect();
        let (base, sens) = run(&p, &t, tangents.iter().map(|x| x.1).collect());
        let m = base.len();
        for (d, (label, v)) in tangents.iter().enumerate() {
            // about 1e-3 of each parameter's size (1e-2 for the log-factors, whose
            // effects are small): the solver's own noise (~1e-7 at these
            // tolerances) over eps stays below the check, as does eps^2
            let eps = match *label {
                "k" | "delta_drift" | "delta_drift_time" => 1e-3,
                "delta_over_H" => 2e-4,
                "b" => 4e-5,
                _ => 1e-2,
            };
            let (up, _) = run(&shifted(&p, v, eps), &t, vec![]);
            let (dn, _) = run(&shifted(&p, v, -eps), &t, vec![]);
            let s = &sens[d * m..(d + 1) * m];
            let scale = s.iter().fold(0.0_f64, |a, x| a.max(x.abs()));
            assert!(scale > 0.0, "{label}: zero sensitivity");
            let worst = (0..m)
                .map(|i| ((up[i] - dn[i]) / (2.0 * eps) - s[i]).abs())
                .fold(0.0_f64, f64::max);
            assert!(
                worst < 2e-3 * scale,
                "{label}: FD differs by {worst:.3e}, scale {scale:.3e}"
            );
        }
    }

    #[test]
    fn no_tangent_changes_nothing_and_bad_names_are_refused() {
        let t: Vec<f64> = (0..=10).map(|i| i as f64 * 120.0).collect();
        let p = Params::default();
        let (a, _) = run(&p, &t, vec![]);
        let (b, s) = run(&p, &t, vec![Tangent::from_pairs([("k", 1.0)]).unwrap()]);
        assert_eq!(s.len(), a.len());
        // the extra rhs calls leave the Newton matrix at least as good: same answer
        let worst = a
            .iter()
            .zip(&b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max);
        assert!(worst < 1e-6, "{worst}");
        let err = Tangent::from_pairs([("rho_h", 1.0)])
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("rho_h") && err.contains("delta_over_H"),
            "{err}"
        );
        assert!(Tangent::from_pairs([("k", f64::NAN)]).is_err());
    }

    #[test]
    fn too_many_tangents_are_refused_before_allocation() {
        let t = [0.0, 60.0];
        // 20 000 directions x 5 x 10 000 cells x 8 bytes = 8 GB of running state
        let many = vec![Tangent::default(); 20_000];
        let err = layer_map_with_sensitivities(
            &Params::default(),
            10_000,
            &t,
            Tolerances::default(),
            15,
            many,
            limits::never(),
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("tangents"), "{err}");
    }

    #[test]
    fn equal_densities_have_no_sensitivity_to_k() {
        // w = 0: k does not enter the model at all
        let p = Params {
            rho_h: 946.0,
            rho_l: 946.0,
            ..Params::default()
        };
        let t: Vec<f64> = (0..=10).map(|i| i as f64 * 120.0).collect();
        let (_, s) = run(&p, &t, vec![Tangent::from_pairs([("k", 1.0)]).unwrap()]);
        assert!(s.iter().all(|v| v.abs() < 1e-12));
    }
}
