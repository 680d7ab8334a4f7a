//! Banded LU with partial pivoting (LAPACK's dgbtf2 / dgbtrs, written out):
//! the exact stage matrix of the forward sensitivities (`sensitivity.rs`).
//!
//! That matrix, I - h gamma J with the overburden pressure carried by extra
//! unknowns, has 4 bands either side; its rows mix a stage equation with the
//! definition of a cumulative sum, so it is not diagonally dominant and is
//! factored with row pivoting. faer has no banded LU (its sparse LU cost more
//! per step than the Newton iterations it saved, `pressure_coupled.rs`); at a
//! few hundred unknowns this O(n kl (kl + ku)) elimination is a few microseconds.

/// Band storage and pivots of an n x n matrix with kl sub- and ku super-diagonals.
pub struct BandLu {
    n: usize,
    kl: usize,
    ku: usize,
    /// Column-major band, leading dimension 2 kl + ku + 1: A(i, j) at
    /// `ab[j * ld + kl + ku + i - j]`; the first kl rows take the fill-in.
    ab: Vec<f64>,
    ipiv: Vec<usize>,
}

impl BandLu {
    pub fn new(n: usize, kl: usize, ku: usize) -> Self {
        BandLu {
            n,
            kl,
            ku,
            ab: vec![0.0; n * (2 * kl + ku + 1)],
            ipiv: vec![0; n],
        }
    }

    fn ld(&self) -> usize {
        2 * self.kl + self.ku + 1
    }

    /// Zero the matrix (and its fill-in rows) before it is assembled again.
    pub fn clear(&mut self) {
        self.ab.iter_mut().for_each(|v| *v = 0.0);
    }

    /// Add v to A(i, j); (i, j) must lie in the band.
    #[inline]
    pub fn add(&mut self, i: usize, j: usize, v: f64) {
        debug_assert!(i + self.ku >= j && j + self.kl >= i && i < self.n && j < self.n);
        let ld = self.ld();
        self.ab[j * ld + self.kl + self.ku + i - j] += v;
    }

    /// Factor in place (PA = LU). False if a pivot is zero or not finite.
    pub fn factor(&mut self) -> bool {
        let (n, kl, ku) = (self.n, self.kl, self.ku);
        let (ld, kv) = (self.ld(), kl + ku);
        let mut ju = 0;
        for j in 0..n {
            let km = kl.min(n - 1 - j);
            let col = j * ld + kv;
            let mut jp = 0;
            for q in 1..=km {
                if self.ab[col + q].abs() > self.ab[col + jp].abs() {
                    jp = q;
                }
            }
            self.ipiv[j] = j + jp;
            let pivot = self.ab[col + jp];
            if pivot == 0.0 || !pivot.is_finite() {
                return false;
            }
            ju = ju.max((j + ku + jp).min(n - 1));
            if jp != 0 {
                for c in j..=ju {
                    let base = c * ld + kv;
                    self.ab.swap(base + j - c, base + j + jp - c);
                }
            }
            let inv = 1.0 / self.ab[col];
            for q in 1..=km {
                self.ab[col + q] *= inv;
            }
            for c in j + 1..=ju {
                let base = c * ld + kv;
                let ajc = self.ab[base + j - c];
                if ajc != 0.0 {
                    for q in 1..=km {
                        self.ab[base + j + q - c] -= self.ab[col + q] * ajc;
                    }
                }
            }
        }
        true
    }

    /// Solve A x = b in place with the factors.
    pub fn solve(&self, b: &mut [f64]) {
        let (n, kl, ku) = (self.n, self.kl, self.ku);
        let (ld, kv) = (self.ld(), kl + ku);
        for j in 0..n.saturating_sub(1) {
            let lm = kl.min(n - 1 - j);
            let l = self.ipiv[j];
            if l != j {
                b.swap(l, j);
            }
            let bj = b[j];
            let col = j * ld + kv;
            for q in 1..=lm {
                b[j + q] -= self.ab[col + q] * bj;
            }
        }
        for j in (0..n).rev() {
            let col = j * ld + kv;
            b[j] /= self.ab[col];
            let bj = b[j];
            for i in j.saturating_sub(kv)..j {
                b[i] -= self.ab[col + i - j] * bj;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Dense Gaussian elimination with partial pivoting, for reference.
    fn dense_solve(mut a: Vec<Vec<f64>>, mut b: Vec<f64>) -> Vec<f64> {
        let n = b.len();
        for k in 0..n {
            let p = (k..n)
                .max_by(|&x, &y| a[x][k].abs().total_cmp(&a[y][k].abs()))
                .unwrap();
            a.swap(k, p);
            b.swap(k, p);
            for i in k + 1..n {
                let f = a[i][k] / a[k][k];
                for j in k..n {
                    a[i][j] -= f * a[k][j];
                }
                b[i] -= f * b[k];
            }
        }
        for k in (0..n).rev() {
            for j in k + 1..n {
                b[k] -= a[k][j] * b[j];
            }
            b[k] /= a[k][k];
        }
        b
    }

    #[test]
    fn matches_dense_elimination_including_pivoting() {
        // small diagonal entries force row exchanges
        let (n, kl, ku) = (23, 4, 3);
        let mut lu = BandLu::new(n, kl, ku);
        let mut dense = vec![vec![0.0; n]; n];
        let mut seed = 12345_u64;
        let mut rnd = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((seed >> 11) as f64 / (1u64 << 53) as f64) - 0.5
        };
        for i in 0..n {
            for j in i.saturating_sub(kl)..(i + ku + 1).min(n) {
                let v = if i == j { 1e-3 * rnd() } else { rnd() };
                dense[i][j] = v;
                lu.add(i, j, v);
            }
        }
        let b: Vec<f64> = (0..n).map(|i| (i as f64).sin()).collect();
        assert!(lu.factor());
        let mut x = b.clone();
        lu.solve(&mut x);
        let want = dense_solve(dense, b);
        for (u, v) in x.iter().zip(&want) {
            assert!((u - v).abs() < 1e-9 * (1.0 + v.abs()), "{u} vs {v}");
        }
    }

    #[test]
    fn singular_matrix_is_reported() {
        let mut lu = BandLu::new(3, 1, 1);
        lu.add(0, 0, 1.0);
        lu.add(1, 1, 1.0);
        assert!(!lu.factor());
    }
}
