//! Tridiagonal LU (Thomas algorithm) for the Newton iteration matrix
//! M = I - h gamma J. faer has no banded solver, and for a few hundred cells
//! an O(n) elimination beats any general sparse factorisation by far. No
//! pivoting is needed: M has a positive diagonal, non-positive off-diagonals
//! and unit column sums (column diagonal dominance).

/// Factorised tridiagonal matrix, allocated once and refactorised in place.
pub struct TridiagLu {
    sub: Vec<f64>,
    sup_scaled: Vec<f64>,
    inv_pivot: Vec<f64>,
}

impl TridiagLu {
    pub fn new(n: usize) -> Self {
        TridiagLu {
            sub: vec![0.0; n],
            sup_scaled: vec![0.0; n],
            inv_pivot: vec![0.0; n],
        }
    }

    /// Factorise M = I - s J for the Jacobian bands (sub, diag, sup).
    /// Returns false if a pivot is not positive and finite.
    pub fn factor_shifted(&mut self, s: f64, sub: &[f64], diag: &[f64], sup: &[f64]) -> bool {
        let n = diag.len();
        let mut prev_sup = 0.0;
        for i in 0..n {
            let a = -s * sub[i];
            let b = 1.0 - s * diag[i];
            let m = if i == 0 { b } else { b - a * prev_sup };
            if !(m > 0.0 && m.is_finite()) {
                return false;
            }
            let inv = 1.0 / m;
            self.sub[i] = a;
            self.inv_pivot[i] = inv;
            prev_sup = -s * sup[i] * inv;
            self.sup_scaled[i] = prev_sup;
        }
        true
    }

    /// Solve M x = rhs in place.
    pub fn solve(&self, x: &mut [f64]) {
        let n = x.len();
        x[0] *= self.inv_pivot[0];
        for i in 1..n {
            x[i] = (x[i] - self.sub[i] * x[i - 1]) * self.inv_pivot[i];
        }
        for i in (0..n - 1).rev() {
            x[i] -= self.sup_scaled[i] * x[i + 1];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solves_a_random_diagonally_dominant_system() {
        let n = 9;
        let sub: Vec<f64> = (0..n)
            .map(|i| if i == 0 { 0.0 } else { 0.3 + 0.01 * i as f64 })
            .collect();
        let sup: Vec<f64> = (0..n)
            .map(|i| {
                if i == n - 1 {
                    0.0
                } else {
                    0.2 + 0.02 * i as f64
                }
            })
            .collect();
        let diag: Vec<f64> = (0..n).map(|i| -(sub[i] + sup[i]) - 0.1).collect();
        let s = 2.5;
        let mut lu = TridiagLu::new(n);
        assert!(lu.factor_shifted(s, &sub, &diag, &sup));
        let xs: Vec<f64> = (0..n).map(|i| (i as f64).sin()).collect();
        // b = (I - sJ) x
        let mut b = vec![0.0; n];
        for i in 0..n {
            b[i] = (1.0 - s * diag[i]) * xs[i];
            if i > 0 {
                b[i] -= s * sub[i] * xs[i - 1];
            }
            if i + 1 < n {
                b[i] -= s * sup[i] * xs[i + 1];
            }
        }
        lu.solve(&mut b);
        for i in 0..n {
            assert!((b[i] - xs[i]).abs() < 1e-13);
        }
    }
}
