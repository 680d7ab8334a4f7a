//! The exact Jacobian of the semi-discrete operator, as the banded stage
//! matrix I - h gamma J (used by the forward sensitivities, `sensitivity.rs`).
//!
//! The default Newton matrix (`flux::Operator::tridiagonal_jacobian`) keeps
//! only the upwind and diffusion couplings. The exact J adds the limiter's
//! slopes (so a face couples cells f-1 .. f+2), a(c) through the face density,
//! and the overburden pressure, which every face feels from all the cells above.
//! The pressure is carried by extra unknowns Q_m = sum_{j>=m} x_j, interleaved
//! x_0, Q_1, x_1, Q_2, ...: the matrix then has 4 bands either side and one
//! banded LU with pivoting (`banded.rs`) solves it in O(n).

use crate::banded::BandLu;
use crate::flux::Operator;
use crate::model;

/// Derivative of the van Leer slope vl(a, b) = 2ab / (a + b) (0 unless ab > 0).
#[inline]
fn van_leer_partials(a: f64, b: f64) -> (f64, f64) {
    if a * b > 0.0 {
        let s = a + b;
        let inv = 1.0 / (s * s);
        (2.0 * b * b * inv, 2.0 * a * a * inv)
    } else {
        (0.0, 0.0)
    }
}

/// I - h gamma J with the exact J at a state, factored; and the face data it is made of.
pub struct ExactStageMatrix {
    n: usize,
    lu: BandLu,
    /// d ln mu / d ln I at each face
    pub(crate) e: Vec<f64>,
    /// d ln a / d c_face at each face
    dlna_dc: Vec<f64>,
    /// dF / dP at each face
    beta: Vec<f64>,
    /// van Leer slope partials at each cell
    va: Vec<f64>,
    vb: Vec<f64>,
    /// the augmented right-hand side / solution
    x: Vec<f64>,
}

impl ExactStageMatrix {
    pub fn new(n: usize) -> Self {
        let z = || vec![0.0; n];
        ExactStageMatrix {
            n,
            lu: BandLu::new(2 * n - 1, 4, 4),
            e: z(),
            dlna_dc: z(),
            beta: z(),
            va: z(),
            vb: z(),
            x: vec![0.0; 2 * n - 1],
        }
    }

    /// Face and cell data of J at the state of the operator's last `rhs` call (c).
    pub fn face_state(&mut self, op: &Operator, c: &[f64]) {
        let p = &op.p;
        let n = self.n;
        let drho = p.rho_h - p.rho_l;
        for i in 0..n {
            (self.va[i], self.vb[i]) = if i == 0 || i + 1 == n {
                (0.0, 0.0)
            } else {
                van_leer_partials(c[i] - c[i - 1], c[i + 1] - c[i])
            };
        }
        for f in 0..n - 1 {
            let c_face = 0.5 * (c[f] + c[f + 1]);
            let rho = p.rho_m(c_face);
            let pres = op.pressure[f];
            let inertial = op.inertia[f] * (rho / pres).sqrt();
            // e = d ln mu / d ln I
            let e = model::dmu_di(p, inertial) * inertial / model::mu_of_i(p, inertial);
            self.e[f] = e;
            self.dlna_dc[f] = -0.5 * e * drho / rho + p.laws.flux_c.log_factor_slope(c_face);
            // dF/dP = dF/da * a * d ln a / d P
            let up = op.c_up[f];
            let dn = op.c_dn[f];
            self.beta[f] = -up * (1.0 - dn) * op.a[f] * (-(1.0 - 0.5 * e) / pres);
        }
    }

    /// Assemble and factor I - hg J (exact J, pressure through Q) at the face state.
    pub fn factor(&mut self, op: &Operator, hg: f64) -> bool {
        let n = self.n;
        let p = &op.p;
        let inv_dz = 1.0 / op.grid.dz;
        let w_rho = p.g * p.phi_s * op.grid.dz * (p.rho_h - p.rho_l);
        let u = |i: usize| 2 * i;
        let q = |m: usize| 2 * m - 1;
        self.lu.clear();
        for i in 0..n {
            self.lu.add(u(i), u(i), 1.0);
        }
        for m in 1..n {
            self.lu.add(q(m), q(m), 1.0);
            self.lu.add(q(m), u(m), -1.0);
            if m + 1 < n {
                self.lu.add(q(m), q(m + 1), -1.0);
            }
        }
        for f in 0..n - 1 {
            let (a, up, dn, d) = (op.a[f], op.c_up[f], op.c_dn[f], op.diff[f]);
            let a1 = -a * (1.0 - dn); // dF/d up
            let a2 = a * up; // dF/d dn
            let a3c = -up * (1.0 - dn) * a * 0.5 * self.dlna_dc[f]; // dF/da da/dc (either cell)
            let (va_f, vb_f, va_u, vb_u) = (self.va[f], self.vb[f], self.va[f + 1], self.vb[f + 1]);
            // dF_f / dc_j for j = f-1 .. f+2
            let cols = [
                (f.wrapping_sub(1), -0.5 * a2 * va_f),
                (
                    f,
                    0.5 * a1 * va_u + a2 * (1.0 + 0.5 * (va_f - vb_f)) + a3c + d,
                ),
                (
                    f + 1,
                    a1 * (1.0 - 0.5 * (va_u - vb_u)) + 0.5 * a2 * vb_f + a3c - d,
                ),
                (f + 2, -0.5 * a1 * vb_u),
            ];
            for (j, dfdc) in cols {
                if j < n && dfdc != 0.0 {
                    // R_f = -(F_f - F_{f-1}) / dz, R_{f+1} = -(F_{f+1} - F_f) / dz
                    let v = hg * dfdc * inv_dz;
                    self.lu.add(u(f), u(j), v);
                    self.lu.add(u(f + 1), u(j), -v);
                }
            }
            let v = hg * self.beta[f] * w_rho * inv_dz;
            self.lu.add(u(f), q(f + 1), v);
            self.lu.add(u(f + 1), q(f + 1), -v);
        }
        self.lu.factor()
    }

    /// Solve (I - h gamma J) x = b in place (b has n entries), after `factor`.
    pub fn solve(&mut self, b: &mut [f64]) {
        self.x.iter_mut().for_each(|v| *v = 0.0);
        for (i, v) in b.iter().enumerate() {
            self.x[2 * i] = *v;
        }
        self.lu.solve(&mut self.x);
        for (i, v) in b.iter_mut().enumerate() {
            *v = self.x[2 * i];
        }
    }
}
