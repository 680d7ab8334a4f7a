//! The alternative Newton matrix: face pressures carried as extra unknowns.
//!
//! The overburden pressure couples each cell to every cell above it, so the
//! exact Jacobian in c alone is dense above the diagonal. With the face
//! pressures as unknowns, P_f - P_{f+1} = g phi_s dz rho_m(c_{f+1}), the
//! augmented system
//!
//!   [ I - s Jc   -s Jp ] [dc]   [r]
//!   [   -B        L    ] [dP] = [0]
//!
//! is sparse and banded, and eliminating dP gives exactly the Newton matrix
//! with the pressure coupling included. It is factorised with faer's sparse
//! LU, the symbolic analysis done once per run and reused at every step.
//!
//! `benches/solver.rs` runs the same integrator with this matrix and with
//! the default tridiagonal one (pressure lagged in the Jacobian only): the
//! converged solutions agree to solver tolerance, and the tridiagonal path
//! is the faster (BENCHMARKS.md), which is why it is the default.

use faer::linalg::solvers::Solve;
use faer::sparse::linalg::solvers::{Lu, SymbolicLu};
use faer::sparse::{Argsort, Pair, SparseColMat, SymbolicSparseColMat};
use faer::{Mat, Par};

use crate::error::SolveError;
use crate::flux::Operator;
use crate::params::Params;
use crate::stepper::{simulate_with, validate_run, NewtonMatrix, Stats, Tolerances};

/// Newton matrix of the augmented (c, P) system, factorised by faer.
pub struct PressureCoupled {
    n: usize,
    sub: Vec<f64>,
    diag: Vec<f64>,
    sup: Vec<f64>,
    /// dR_f/dP_f and dR_{f+1}/dP_f per face
    dr_dp: Vec<(f64, f64)>,
    da_dp: Vec<f64>,
    /// -g phi_s dz (rho_h - rho_l): dP-row coefficient of dc_{f+1}
    weight: f64,
    symbolic: SymbolicSparseColMat<usize>,
    argsort: Argsort<usize>,
    symbolic_lu: SymbolicLu<usize>,
    values: Vec<f64>,
    lu: Option<Lu<usize, f64>>,
    rhs: Mat<f64>,
}

/// The fixed sparsity pattern, in the order `fill_values` writes values.
fn pattern(n: usize) -> Vec<Pair<usize, usize>> {
    let nf = n - 1;
    let mut idx = Vec::with_capacity(5 * n + 3 * nf);
    for i in 0..n {
        if i > 0 {
            idx.push(Pair::new(i, i - 1));
        }
        idx.push(Pair::new(i, i));
        if i + 1 < n {
            idx.push(Pair::new(i, i + 1));
        }
        if i > 0 {
            idx.push(Pair::new(i, n + i - 1)); // face below cell i
        }
        if i < nf {
            idx.push(Pair::new(i, n + i)); // face above cell i
        }
    }
    for f in 0..nf {
        idx.push(Pair::new(n + f, n + f));
        if f + 1 < nf {
            idx.push(Pair::new(n + f, n + f + 1));
        }
        idx.push(Pair::new(n + f, f + 1));
    }
    idx
}

impl PressureCoupled {
    pub fn new(p: &Params, n: usize) -> Result<Self, SolveError> {
        // Small systems, and callers may already run in parallel: keep faer
        // sequential so that only an outer sweep uses the cores.
        faer::set_global_parallelism(Par::Seq);
        let m = 2 * n - 1;
        let idx = pattern(n);
        let (symbolic, argsort) = SymbolicSparseColMat::try_new_from_indices(m, m, &idx)
            .map_err(|e| SolveError::InvalidInput(format!("sparsity pattern: {e:?}")))?;
        let symbolic_lu = SymbolicLu::try_new(symbolic.as_ref())
            .map_err(|e| SolveError::InvalidInput(format!("symbolic LU: {e:?}")))?;
        let dz = p.h / n as f64;
        Ok(PressureCoupled {
            n,
            sub: vec![0.0; n],
            diag: vec![0.0; n],
            sup: vec![0.0; n],
            dr_dp: vec![(0.0, 0.0); n - 1],
            da_dp: vec![0.0; n - 1],
            weight: -p.g * p.phi_s * dz * (p.rho_h - p.rho_l),
            symbolic,
            argsort,
            symbolic_lu,
            values: vec![0.0; idx.len()],
            lu: None,
            rhs: Mat::zeros(m, 1),
        })
    }

    fn fill_values(&mut self, s: f64) {
        let (n, nf) = (self.n, self.n - 1);
        let v = &mut self.values;
        let mut k = 0;
        let mut put = |x: f64| {
            v[k] = x;
            k += 1;
        };
        for i in 0..n {
            if i > 0 {
                put(-s * self.sub[i]);
            }
            put(1.0 - s * self.diag[i]);
            if i + 1 < n {
                put(-s * self.sup[i]);
            }
            if i > 0 {
                put(-s * self.dr_dp[i - 1].1);
            }
            if i < nf {
                put(-s * self.dr_dp[i].0);
            }
        }
        for f in 0..nf {
            put(1.0);
            if f + 1 < nf {
                put(-1.0);
            }
            put(self.weight);
        }
    }
}

impl NewtonMatrix for PressureCoupled {
    fn update(&mut self, op: &Operator, c: &[f64]) {
        op.tridiagonal_jacobian(&mut self.sub, &mut self.diag, &mut self.sup);
        op.seg_coefficient_pressure_derivatives(c, &mut self.da_dp);
        let inv_dz = 1.0 / op.grid.dz;
        for f in 0..self.n - 1 {
            // F_f = -a_f up (1 - dn) - ...; R_f = -(F_f - F_{f-1}) / dz
            let df_dp = -self.da_dp[f] * op.c_up[f] * (1.0 - op.c_dn[f]);
            self.dr_dp[f] = (-df_dp * inv_dz, df_dp * inv_dz);
        }
    }

    fn factor(&mut self, s: f64) -> bool {
        self.fill_values(s);
        let Ok(mat) =
            SparseColMat::new_from_argsort(self.symbolic.clone(), &self.argsort, &self.values)
        else {
            return false;
        };
        match Lu::try_new_with_symbolic(self.symbolic_lu.clone(), mat.as_ref()) {
            Ok(lu) => {
                self.lu = Some(lu);
                true
            }
            Err(_) => false,
        }
    }

    fn solve(&mut self, x: &mut [f64]) {
        let n = self.n;
        for i in 0..self.rhs.nrows() {
            self.rhs[(i, 0)] = if i < n { x[i] } else { 0.0 };
        }
        if let Some(lu) = &self.lu {
            lu.solve_in_place(self.rhs.as_mut());
        }
        for (i, v) in x.iter_mut().enumerate() {
            *v = self.rhs[(i, 0)];
        }
    }
}

/// `stepper::simulate` with the pressure-coupled Newton matrix.
pub fn simulate(
    p: &Params,
    n_cells: usize,
    t_out: &[f64],
    tol: Tolerances,
) -> Result<(Vec<f64>, Stats), SolveError> {
    p.validate()?;
    validate_run(n_cells, t_out, &tol)?;
    simulate_with(p, n_cells, t_out, tol, PressureCoupled::new(p, n_cells)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_solution_as_the_tridiagonal_path_and_conserves_mass() {
        let p = Params {
            rho_h: 7800.0,
            rho_l: 946.0,
            c0: 0.5,
            ..Params::default()
        };
        let t: Vec<f64> = (0..=30).map(|i| i as f64 * 60.0).collect();
        let tol = Tolerances {
            rtol: 1e-7,
            atol: 1e-9,
        };
        let (a, sa) = simulate(&p, 90, &t, tol).unwrap();
        let (b, sb) = crate::stepper::simulate(&p, 90, &t, tol).unwrap();
        let diff = a
            .iter()
            .zip(&b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max);
        assert!(diff < 1e-5, "{diff}");
        let m0: f64 = a[..90].iter().sum();
        let m1: f64 = a[a.len() - 90..].iter().sum();
        assert!(((m1 - m0) / m0).abs() < 1e-12);
        // the exact pressure coupling should not need more Newton iterations
        assert!(
            sa.newton_iters as f64 <= 1.1 * sb.newton_iters as f64,
            "{sa:?} {sb:?}"
        );
    }
}
