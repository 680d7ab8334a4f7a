//! What a measurement sees: layer means, the centred moving average and the
//! RMSD between a measured and a model map (docs/model.md, docs/formats.md).

use crate::error::SolveError;

/// Cell-to-layer averaging weights for `n_layers` equal layers over the bed.
/// Exact for piecewise-constant cell values, for any n_cells >= 1.
pub struct LayerMap {
    n_layers: usize,
    /// First cell of each layer, and where its weights start in `weights`
    /// (n_layers + 1 offsets): a layer covers contiguous cells, so its mean
    /// is a short dot product.
    first_cell: Vec<usize>,
    offsets: Vec<usize>,
    /// Weights of each layer's cells, summing to 1 per layer.
    weights: Vec<f64>,
}

impl LayerMap {
    pub fn new(n_cells: usize, n_layers: usize) -> Self {
        let mut first_cell = Vec::with_capacity(n_layers);
        let mut offsets = Vec::with_capacity(n_layers + 1);
        let mut weights = Vec::with_capacity(n_cells + n_layers);
        offsets.push(0);
        // Work in units of 1 / (n_cells * n_layers) of the height: exact.
        let (nc, nl) = (n_cells as u64, n_layers as u64);
        for layer in 0..nl {
            let (l0, l1) = (layer * nc, (layer + 1) * nc);
            let first = (l0 / nl) as usize;
            let last = (l1.div_ceil(nl) as usize).min(n_cells);
            first_cell.push(first);
            for cell in first..last {
                let (c0, c1) = (cell as u64 * nl, (cell as u64 + 1) * nl);
                let overlap = c1.min(l1).saturating_sub(c0.max(l0));
                weights.push(overlap as f64 / nc as f64);
            }
            offsets.push(weights.len());
        }
        LayerMap {
            n_layers,
            first_cell,
            offsets,
            weights,
        }
    }

    pub fn n_layers(&self) -> usize {
        self.n_layers
    }

    /// Layer means of one profile into `out` (length n_layers).
    ///
    /// Called at every output time of every run, so it is kept fast: the
    /// earlier (layer, cell, weight) scatter was one dependent add chain per
    /// layer and cost more than writing the whole field (0.5 of 1.4 ms for a
    /// G-PP run with 1801 outputs, issue 15); four partial sums break the chain.
    pub fn apply(&self, profile: &[f64], out: &mut [f64]) {
        for (layer, v) in out.iter_mut().enumerate().take(self.n_layers) {
            let w = &self.weights[self.offsets[layer]..self.offsets[layer + 1]];
            let start = self.first_cell[layer];
            *v = dot(w, &profile[start..start + w.len()]);
        }
    }
}

/// Dot product with four partial sums (independent add chains).
#[inline]
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let (mut s0, mut s1, mut s2, mut s3) = (0.0, 0.0, 0.0, 0.0);
    let (ca, cb) = (a.chunks_exact(4), b.chunks_exact(4));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        s0 += x[0] * y[0];
        s1 += x[1] * y[1];
        s2 += x[2] * y[2];
        s3 += x[3] * y[3];
    }
    for (x, y) in ra.iter().zip(rb) {
        s0 += x * y;
    }
    (s0 + s1) + (s2 + s3)
}

/// What a view that keeps a layer's grains for several frames shows of a map
/// (n_t, n_cols) row-major: per column, y[0] = x[0] and y[t] = (1 - s) x[t] +
/// s y[t-1] with that column's survival per frame s (columns with s <= 0 are
/// left as they are). The fits' dwell model (`granseg.fitting.dwell`) calls it
/// for every model map: in Rust it costs microseconds, not scipy's per-column
/// filter calls (most of a diagnosis's time before).
pub fn lagged(map: &[f64], n_t: usize, n_cols: usize, survival: &[f64]) -> Vec<f64> {
    let mut out = map.to_vec();
    for t in 1..n_t {
        let (prev, cur) = out.split_at_mut(t * n_cols);
        let prev = &prev[(t - 1) * n_cols..];
        for (j, &s) in survival.iter().enumerate().take(n_cols) {
            if s > 0.0 {
                cur[j] = (1.0 - s) * cur[j] + s * prev[j];
            }
        }
    }
    out
}

/// Centred moving average over time of an (n_t, n_cols) row-major map with
/// odd window `width` (1 = none; callers reject even widths, which cannot be
/// centred). The half-width is (width - 1) / 2 and shrinks
/// symmetrically at the ends of the series, as docs/formats.md specifies.
pub fn moving_average(map: &[f64], n_t: usize, n_cols: usize, width: usize) -> Vec<f64> {
    let half = width.saturating_sub(1) / 2;
    if half == 0 {
        return map.to_vec();
    }
    // Whole rows at a time (contiguous). The shrinking windows at both ends are
    // summed directly; the full-width ones slide (add the row entering, drop the
    // one leaving): O(n_t n_cols) whatever the width, ~1e-15 from the direct sums.
    let nc = n_cols.max(1);
    let mut out = vec![0.0; map.len()];
    let row = |r: usize| &map[r * n_cols..(r + 1) * n_cols];
    let mut window = vec![0.0; n_cols];
    for (i, o) in out.chunks_exact_mut(nc).enumerate().take(n_t) {
        let hw = half.min(i).min(n_t - 1 - i);
        if hw < half {
            window.iter_mut().for_each(|w| *w = 0.0);
            for r in (i - hw)..=(i + hw) {
                window.iter_mut().zip(row(r)).for_each(|(w, v)| *w += v);
            }
        } else if i == half {
            window.iter_mut().for_each(|w| *w = 0.0);
            for r in 0..=2 * half {
                window.iter_mut().zip(row(r)).for_each(|(w, v)| *w += v);
            }
        } else {
            let (enter, leave) = (row(i + half), row(i - half - 1));
            for ((w, a), b) in window.iter_mut().zip(enter).zip(leave) {
                *w += a - b;
            }
        }
        let inv = 1.0 / (2 * hw + 1) as f64;
        o.iter_mut().zip(&window).for_each(|(o, w)| *o = w * inv);
    }
    out
}

/// Root-mean-square deviation over the entries the measurement has (NaN in
/// `measured` is skipped). NaN if it has none.
pub fn rmsd(measured: &[f64], model: &[f64]) -> Result<f64, SolveError> {
    if measured.len() != model.len() {
        return Err(SolveError::InvalidInput(format!(
            "measured map has {} entries, model map {}",
            measured.len(),
            model.len()
        )));
    }
    let (mut s, mut n) = (0.0, 0usize);
    for (a, b) in measured.iter().zip(model) {
        if a.is_finite() {
            s += (a - b) * (a - b);
            n += 1;
        }
    }
    Ok(if n == 0 {
        f64::NAN
    } else {
        (s / n as f64).sqrt()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layer_means_are_exact_averages() {
        // cells aligned with layers: a linear profile averages to the centres
        for &n in &[15usize, 45, 180] {
            let lm = LayerMap::new(n, 15);
            let prof: Vec<f64> = (0..n).map(|i| (i as f64 + 0.5) / n as f64).collect();
            let mut out = vec![0.0; 15];
            lm.apply(&prof, &mut out);
            for (j, v) in out.iter().enumerate() {
                assert!(
                    (v - (j as f64 + 0.5) / 15.0).abs() < 1e-12,
                    "n={n} j={j} {v}"
                );
            }
        }
        // misaligned cells: compare with a fine sampling of the step function
        for &n in &[16usize, 37, 100] {
            let lm = LayerMap::new(n, 15);
            let prof: Vec<f64> = (0..n).map(|i| ((i * 7919) % 13) as f64).collect();
            let mut out = vec![0.0; 15];
            lm.apply(&prof, &mut out);
            let fine = 15 * n * 8;
            for (j, v) in out.iter().enumerate() {
                let samples = (j * fine / 15..(j + 1) * fine / 15).map(|s| prof[s * n / fine]);
                let mean = samples.sum::<f64>() / (fine / 15) as f64;
                assert!((v - mean).abs() < 1e-12, "n={n} j={j} {v} {mean}");
            }
        }
    }

    #[test]
    fn moving_average_shrinks_at_the_ends() {
        let x = [1.0, 2.0, 6.0, 4.0, 10.0];
        let y = moving_average(&x, 5, 1, 3);
        for (a, b) in y.iter().zip([1.0, 3.0, 4.0, 20.0 / 3.0, 10.0]) {
            assert!((a - b).abs() < 1e-14, "{y:?}");
        }
        assert_eq!(moving_average(&x, 5, 1, 1), x.to_vec());
    }

    #[test]
    fn rmsd_skips_nan() {
        let r = rmsd(&[0.0, f64::NAN, 1.0], &[0.5, 3.0, 0.5]).unwrap();
        assert!((r - 0.5).abs() < 1e-15);
        assert!(rmsd(&[f64::NAN], &[1.0]).unwrap().is_nan());
    }
}
